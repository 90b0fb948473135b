/* phireman: the relay rotation panel of the operator's page (live and replay).
 *
 * Draws the frame's `rotation` key (mission/view/live/rotation.py; absent without batteries):
 * counters, each vehicle's rotation phase, the pads with the vehicle on each and its swap timer,
 * the swap requests with a Confirm button for the ground crew (live, with the operator key: the
 * operator action `confirm_swap`, POST /api/action like every other action), who is relieving
 * whom and the relays next due, the base's batteries and the latest rotation events.
 * app.js announces every frame it draws with the DOM event "phireman:frame".
 */
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"}[c]));
  const PHASES = ["air", "inbound", "returning", "landed", "swapping", "no_battery", "ready", "lost"];
  const PHASE_TEXT = {air: "in the plan", inbound: "inbound spares", returning: "flying home",
    landed: "landed, waiting for a pad", swapping: "on a pad (swap)", no_battery: "waiting for a battery",
    ready: "charged spares at the base", lost: "lost"};
  let meta = null, frame = null;
  const sent = new Map();  // vehicle id -> what the last Confirm answered

  const label = (id) => {
    if (!frame || id === null || id === undefined) return "?";
    const i = frame.v.id.indexOf(id);
    return i < 0 ? id : frame.v.label[i];
  };
  const dur = (s) => (s === null || s === undefined) ? "-"
    : s >= 60 ? `${Math.floor(s / 60)}:${String(s % 60).padStart(2, "0")}` : `${s} s`;
  const fmtT = (t) => t === null || t === undefined ? "-" : `t+${Math.round(t)} s`;

  function pads(R, canAct) {
    const onPads = new Set(R.pads.map((p) => p.vehicle).filter((v) => v));
    for (const v of [...sent.keys()]) if (!onPads.has(v)) sent.delete(v);  // its swap is over
    const rows = R.pads.map((p) => {
      if (!p.vehicle) return `<tr data-pad="${p.pad}" data-vehicle=""><td>pad ${p.pad}</td><td class="muted">free</td><td></td></tr>`;
      const who = esc(label(p.vehicle));
      const timer = `${dur(p.elapsed_s)} of ${dur(Math.round(R.swap_time_s))}` + (p.left_s === 0 ? " (over)" : "");
      return `<tr data-pad="${p.pad}" data-vehicle="${esc(p.vehicle)}" data-confirmed="${p.confirmed}"><td>pad ${p.pad}</td>` +
        `<td><b>vehicle ${who}</b></td><td>${timer}</td></tr>`;
    });
    const reqs = R.pads.filter((p) => p.vehicle).map((p) => {
      const who = esc(label(p.vehicle)), id = esc(p.vehicle);
      if (p.confirmed) {
        return `<div class="swapreq confirmed" data-vehicle="${id}">swap confirmed by the crew: vehicle ${who} on pad ${p.pad} ` +
          `<span class="muted">(ready once heard with a charged battery)</span></div>`;
      }
      const how = R.swap_confirm === "manual" ? "waits for the crew" : "confirmed by the station when it comes back powered and full, or by the crew";
      const btn = canAct ? ` <button class="confirm-swap" data-confirm="${id}">Confirm</button>` : "";
      const note = sent.has(p.vehicle) ? ` <span class="muted">${esc(sent.get(p.vehicle))}</span>` : "";
      return `<div class="swapreq" data-vehicle="${id}"><b>swap requested: vehicle ${who} on pad ${p.pad}</b>${btn}` +
        `<div class="muted small">${how}</div>${note}</div>`;
    });
    return reqs.join("") + `<table id="rotation-pads"><tbody>${rows.join("")}</tbody></table>`;
  }

  function render(f, m) {
    frame = f; meta = m;
    const box = $("rotation"), R = f.rotation;
    if (!box) return;
    if (!R) { box.hidden = true; return; }
    box.hidden = false;
    const canAct = meta.mode === "live" && meta.actions && !!(sessionStorage.getItem("phireman-key") || "");
    const c = R.counters;
    $("rotation-mode").textContent = `swaps: ${R.swap_confirm === "manual" ? "confirmed by the ground crew" : "automatic (or the crew)"}`;
    const minb = c.min_battery_in_air === null || c.min_battery_in_air === undefined ? "-" : `${Math.round(100 * c.min_battery_in_air)} %`;
    $("rotation-counters").innerHTML =
      `<span data-k="rotations"><b>${c.rotations}</b> rotations</span> · <span data-k="swaps"><b>${c.swaps}</b> swaps` +
      (c.swaps_confirmed_by_crew ? ` (${c.swaps_confirmed_by_crew} by the crew)` : "") + `</span> · ` +
      `<span data-k="min">min battery in the air <b>${minb}</b></span> · ` +
      `<span data-k="failsafes" class="${c.battery_failsafes_in_air ? "bad" : ""}"><b>${c.battery_failsafes_in_air}</b> battery failsafes</span> · ` +
      `<span data-k="away" class="${c.landed_away ? "bad" : ""}"><b>${c.landed_away}</b> landed away</span>`;
    $("rotation-pads-box").innerHTML = pads(R, canAct);
    // who is relieving whom, then who is next
    const q = R.queue.map((x) => `<li data-spare="${esc(x.spare)}" data-relay="${esc(x.relay)}">vehicle ${esc(label(x.spare))} &rarr; relieves ${esc(label(x.relay))}` +
      `${x.dist_m === null ? "" : `: ${x.dist_m} m, ETA ${dur(x.eta_s)}`}</li>`);
    const due = R.due.map((x) => `<li class="muted" data-relay="${esc(x.relay)}">vehicle ${esc(label(x.relay))}: reserve in ${dur(x.reserve_in_s)}</li>`);
    const wait = R.waiting.length ? [`<li class="warn">waiting at the base: ${R.waiting.map((v) => esc(label(v))).join(", ")}</li>`] : [];
    $("rotation-queue").innerHTML = (q.concat(wait, due).join("")) || `<li class="muted">nobody due</li>`;
    // phases, each vehicle named
    const by = {};
    R.phase.forEach((ph, i) => { if (ph) (by[ph] = by[ph] || []).push(f.v.label[i]); });
    $("rotation-phases").innerHTML = PHASES.filter((ph) => by[ph]).map((ph) =>
      `<div class="rphase" data-phase="${ph}"><span class="n">${by[ph].length}</span> ${esc(PHASE_TEXT[ph])}: ` +
      `<span class="muted">${by[ph].map(esc).join(" ")}</span></div>`).join("");
    // batteries
    const b = R.batteries, left = b.charging_left_s.slice().sort((x, y) => x - y);
    $("rotation-batteries").innerHTML = `<span data-k="charged"><b>${b.charged}</b> charged on the shelf</span> · ` +
      `<b>${left.length}</b> of ${b.chargers} chargers busy` + (left.length ? ` (next in ${dur(left[0])}${left.length > 1 ? `, last in ${dur(left[left.length - 1])}` : ""})` : "") +
      (b.queued ? ` · <b>${b.queued}</b> waiting for a charger` : "");
    $("rotation-events").innerHTML = R.events.slice().reverse().map((e) =>
      `<li class="${esc(e.kind)}"><span class="t">${fmtT(e.t_mission_s)}</span> ${esc(e.text)}</li>`).join("");
  }

  async function confirmSwap(vid) {
    const key = sessionStorage.getItem("phireman-key") || "";
    sent.set(vid, "sending…");
    try {
      const r = await fetch("/api/action", {method: "POST", headers: {"Content-Type": "application/json",
        "X-Operator-Key": key}, body: JSON.stringify({action: "confirm_swap", vehicle: vid})});
      const text = r.ok ? (await r.json()).done.map((x) => x.result).join(", ") : `refused: ${await r.text()}`;
      sent.set(vid, text);
      $("rotation-msg").textContent = `vehicle ${label(vid)}: ${text}`;
    } catch (e) { sent.set(vid, `failed: ${e}`); }
  }

  document.addEventListener("click", (ev) => {
    const b = ev.target.closest && ev.target.closest("button[data-confirm]");
    if (b && !b.disabled) { b.disabled = true; confirmSwap(b.dataset.confirm); }
  });
  document.addEventListener("phireman:frame", (ev) => render(ev.detail.frame, ev.detail.meta));
})();

/* phireman: what a pilot watches, on the live page (docs/live_view.md, "Vehicle health").
 *
 * app.js calls four hooks: phiremanHealth.setup(meta, key) once, cells(V, i) for each vehicle
 * table row, panel(V, i) for the selected vehicle, afterRender(frame, map) after each frame
 * (fading and hiding lost vehicles, the alert banner). Coordinates are formatted here
 * (decimal degrees, degrees-minutes, MGRS, USNG: PhiremanCoords, tested against the Python
 * `mgrs` package in tests/mission/test_live_health.py).
 */
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"}[c]));
  const nz = (x) => x !== null && x !== undefined;

  // ------------------------------------------------------------------ coordinates
  const WGS84_A = 6378137.0, WGS84_F = 1 / 298.257223563, K0 = 0.9996;
  const BANDS = "CDEFGHJKLMNPQRSTUVWXX";
  const COLS = ["STUVWXYZ", "ABCDEFGH", "JKLMNPQR"];  // by zone % 3
  const ROWS = "ABCDEFGHJKLMNPQRSTUV";

  function utmZone(lat, lon) {
    let z = Math.floor((lon + 180) / 6) + 1;
    if (z > 60) z = 60;
    if (lat >= 56 && lat < 64 && lon >= 3 && lon < 12) z = 32;  // Norway
    if (lat >= 72 && lat < 84) {  // Svalbard
      if (lon >= 0 && lon < 9) z = 31; else if (lon >= 9 && lon < 21) z = 33;
      else if (lon >= 21 && lon < 33) z = 35; else if (lon >= 33 && lon < 42) z = 37;
    }
    return z;
  }
  // Transverse Mercator, Krueger series to n^4 (sub-millimetre within a zone).
  function toUtm(lat, lon) {
    const zone = utmZone(lat, lon), lon0 = (zone - 1) * 6 - 180 + 3;
    const f = WGS84_F, n = f / (2 - f), n2 = n * n, n3 = n2 * n, n4 = n3 * n;
    const A = WGS84_A / (1 + n) * (1 + n2 / 4 + n4 / 64);
    const al = [0, n / 2 - 2 * n2 / 3 + 5 * n3 / 16 + 41 * n4 / 180, 13 * n2 / 48 - 3 * n3 / 5 + 557 * n4 / 1440,
      61 * n3 / 240 - 103 * n4 / 140, 49561 * n4 / 161280];
    const e = Math.sqrt(f * (2 - f));
    const phi = lat * Math.PI / 180, dl = (lon - lon0) * Math.PI / 180;
    const t = Math.sinh(Math.atanh(Math.sin(phi)) - e * Math.atanh(e * Math.sin(phi)));
    const xi = Math.atan2(t, Math.cos(dl)), eta = Math.atanh(Math.sin(dl) / Math.sqrt(1 + t * t));
    let x = eta, y = xi;
    for (let j = 1; j <= 4; j++) {
      x += al[j] * Math.cos(2 * j * xi) * Math.sinh(2 * j * eta);
      y += al[j] * Math.sin(2 * j * xi) * Math.cosh(2 * j * eta);
    }
    const easting = 500000 + K0 * A * x;
    const northing = K0 * A * y + (lat < 0 ? 10000000 : 0);
    return {zone, easting, northing};
  }
  function mgrsParts(lat, lon, digits) {
    if (!(lat >= -80 && lat <= 84)) return null;  // polar: UPS, not drawn here
    const u = toUtm(lat, lon);
    const band = BANDS[Math.min(20, Math.floor((lat + 80) / 8))];
    const col = COLS[u.zone % 3][Math.floor(u.easting / 100000) - 1];
    const row = ROWS[(Math.floor(u.northing / 100000) + (u.zone % 2 === 0 ? 5 : 0)) % 20];
    const div = Math.pow(10, 5 - digits);
    const pad = (v) => String(Math.floor((v % 100000) / div)).padStart(digits, "0");
    return [`${u.zone}${band}`, `${col}${row}`, pad(u.easting), pad(u.northing)];
  }
  function dm(v, pos, neg, w) {
    const h = v < 0 ? neg : pos, a = Math.abs(v);
    let d = Math.floor(a), mnt = (a - d) * 60;
    if (+mnt.toFixed(3) >= 60) { d += 1; mnt = 0; }
    return `${String(d).padStart(w, "0")}°${mnt.toFixed(3).padStart(6, "0")}′${h}`;
  }
  const Coords = {
    dd: (lat, lon) => `${lat.toFixed(6)}, ${lon.toFixed(6)}`,
    dm: (lat, lon) => `${dm(lat, "N", "S", 2)} ${dm(lon, "E", "W", 3)}`,
    // MGRS as GeoTrans writes it (zone on two digits: 01G...); USNG without the leading zero.
    mgrs: (lat, lon, digits = 5) => { const p = mgrsParts(lat, lon, digits); return p ? p[0].padStart(3, "0") + p.slice(1).join("") : "-"; },
    usng: (lat, lon, digits = 5) => { const p = mgrsParts(lat, lon, digits); return p ? p.join(" ") : "-"; },
    toUtm,
  };
  window.PhiremanCoords = Coords;
  const FORMATS = {dd: "decimal degrees", dm: "degrees, minutes", mgrs: "MGRS", usng: "USNG"};
  const store = {  // localStorage, where the page may have one
    get: (k) => { try { return localStorage.getItem(k); } catch (e) { return null; } },
    set: (k, v) => { try { localStorage.setItem(k, v); } catch (e) { /* private mode */ } },
  };
  let fmt = store.get("phireman-coords") || "dd";
  if (!FORMATS[fmt]) fmt = "dd";
  const coord = (V, i) => (nz(V.lat) && nz(V.lat[i]) ? Coords[fmt](V.lat[i], V.lon[i]) : "-");

  // ------------------------------------------------------------------ per-vehicle text
  const GPS = {0: "no GPS", 1: "no fix", 2: "2D", 3: "3D", 4: "DGPS", 5: "RTK float", 6: "RTK fixed", 7: "static", 8: "PPP"};
  let meta = null, key = "", lowPct = 25, hideLost = false, lastFrame = null;
  const FADE_S = 60;  // a lost vehicle fades out over this many seconds since last heard

  function problems(V, i) {
    const out = [];
    if (V.sensors_bad && V.sensors_bad[i]) out.push(V.sensors_bad[i]);
    if (V.ekf && V.ekf[i] && V.ekf[i] !== "ok") out.push(`EKF: ${V.ekf[i]}`);
    if (V.gps && nz(V.gps[i]) && V.gps[i] < 3) out.push(`GPS ${GPS[V.gps[i]] || V.gps[i]}`);
    return out;
  }
  function cells(V, i) {
    if (!V.bat) return "";
    const b = V.bat[i], low = nz(b) && b < lowPct;
    const bat = nz(b) ? `${b} %` : "-";
    const loss = nz(V.loss[i]) ? `${V.loss[i].toFixed(0)} %` : "-";
    const since = nz(V.since[i]) ? `${V.since[i] < 10 ? V.since[i].toFixed(1) : Math.round(V.since[i])} s` : "-";
    const gps = nz(V.gps[i]) ? `${GPS[V.gps[i]] || V.gps[i]}${nz(V.sats[i]) ? " " + V.sats[i] : ""}` : "-";
    const p = problems(V, i);
    const ok = V.ekf[i] === null && !V.sensors_bad[i] ? "-" : (p.length ? "" : "ok");
    return `<td class="bat${low ? " bad" : ""}" data-bat="${nz(b) ? b : ""}">${bat}</td>` +
      `<td class="lnk" title="packet loss, time since last heard">${loss} ${since}</td>` +
      `<td class="gpscell" data-sats="${nz(V.sats[i]) ? V.sats[i] : ""}">${gps}</td>` +
      `<td class="hl${p.length ? " bad" : ""}" title="${esc(p.join("; "))}">${p.length ? esc(p.join("; ")) : ok}</td>`;
  }
  function panel(V, i) {
    if (!V.bat) return "";
    const b = V.bat[i];
    const res = nz(V.res_min[i]) ? `, ${V.res_min[i] >= 100 ? Math.round(V.res_min[i]) : V.res_min[i].toFixed(1)} min to reserve` : "";
    const radio = nz(V.rssi[i]) || nz(V.remrssi[i]) ? `RSSI ${nz(V.rssi[i]) ? V.rssi[i] : "-"} / remote ${nz(V.remrssi[i]) ? V.remrssi[i] : "-"}; ` : "";
    const p = problems(V, i);
    const rows = [
      ["battery", nz(b) ? `<span id="h-bat">${b}</span> %${nz(V.volt[i]) ? `, ${V.volt[i].toFixed(2)} V` : ""}${res}` : "not reported"],
      ["link", `${radio}loss ${nz(V.loss[i]) ? V.loss[i].toFixed(1) + " %" : "-"} (last 10 s), heard <span id="h-since">${nz(V.since[i]) ? V.since[i].toFixed(1) : "-"}</span> s ago`],
      ["GPS", nz(V.gps[i]) ? `<span id="h-fix">${GPS[V.gps[i]] || V.gps[i]}</span>, <span id="h-sats">${nz(V.sats[i]) ? V.sats[i] : "-"}</span> satellites${nz(V.hdop[i]) ? `, HDOP ${V.hdop[i].toFixed(2)}` : ""}` : "not reported"],
      ["health", V.ekf[i] === null && !V.sensors_bad[i] ? "not reported" : (p.length ? `<b class="bad">${esc(p.join("; "))}</b>` : `sensors ok, EKF ok`)],
      ["altitude", `${nz(V.ahome[i]) ? Math.round(V.ahome[i]) : "-"} m above home, ${nz(V.amsl[i]) ? Math.round(V.amsl[i]) : "-"} m AMSL`],
      ["speed", `${nz(V.gs[i]) ? V.gs[i].toFixed(1) : "-"} m/s over ground`],
      ["position", `<span id="h-coord">${esc(coord(V, i))}</span> <span class="muted small">(${FORMATS[fmt]})</span>`],
    ];
    return `<table id="health" data-vid="${esc(V.id[i])}">` + rows.map(([k, v]) => `<tr><th>${k}</th><td>${v}</td></tr>`).join("") + `</table>`;
  }

  // ------------------------------------------------------------------ fading and hiding
  function fade(f) {
    const pm = window.phiremanMap;
    if (!pm || !pm.vmark) return;
    const V = f.v;
    for (let i = 0; i < V.id.length; i++) {
      const mk = pm.vmark.get(V.id[i]), lb = pm.vlabel && pm.vlabel.get(V.id[i]);
      if (!mk) continue;
      const lost = V.state[i] === "lost";
      const hide = lost && hideLost;
      if (hide) {
        if (pm.layers.vehicles.hasLayer(mk)) pm.layers.vehicles.removeLayer(mk);
        if (lb && pm.layers.labels.hasLayer(lb)) pm.layers.labels.removeLayer(lb);
      } else {
        if (!pm.layers.vehicles.hasLayer(mk)) pm.layers.vehicles.addLayer(mk);
        if (lb && !pm.layers.labels.hasLayer(lb) && pm.map.hasLayer(pm.layers.labels)) pm.layers.labels.addLayer(lb);
      }
      const since = V.since ? V.since[i] : null;
      const op = lost ? Math.max(0.12, 1 - (nz(since) ? since : FADE_S) / FADE_S) : 1;
      mk.setStyle({opacity: op, fillOpacity: lost ? 0.15 * op : 0.95});
      mk.options.fade = op;
    }
    document.querySelectorAll("#vtable tr[data-state=lost]").forEach((tr) => { tr.hidden = hideLost; });
  }

  // ------------------------------------------------------------------ alerts
  let seen = new Set(), audio = null, beeps = 0, lastBeep = -1e9;
  function beep() {
    beeps += 1;
    try {
      audio = audio || new (window.AudioContext || window.webkitAudioContext)();
      const o = audio.createOscillator(), g = audio.createGain();
      o.type = "square"; o.frequency.value = 880;
      g.gain.setValueAtTime(0.0001, audio.currentTime);
      g.gain.exponentialRampToValueAtTime(0.2, audio.currentTime + 0.02);
      g.gain.exponentialRampToValueAtTime(0.0001, audio.currentTime + 0.5);
      o.connect(g); g.connect(audio.destination); o.start(); o.stop(audio.currentTime + 0.55);
    } catch (e) { /* no audio device: the banner still shows */ }
  }
  async function ack(id) {
    try {
      const r = await fetch("/api/ack", {method: "POST", headers: {"Content-Type": "application/json", "X-Operator-Key": key},
        body: JSON.stringify({alert: id})});
      if (!r.ok) { $("alert-msg").textContent = `not acknowledged: ${await r.text()}`; return; }
      $("alert-msg").textContent = "";
    } catch (e) { $("alert-msg").textContent = `not acknowledged: ${e}`; }
  }
  function renderAlerts(f) {
    const bar = $("alertbar");
    const A = f.alerts;
    if (!bar || !A) return;
    const open = A.open || [];
    const fresh = open.filter((a) => !seen.has(a.id));
    open.forEach((a) => seen.add(a.id));
    const now = performance.now();
    // A new alert beeps at once; open ones again every 15 s until acknowledged.
    if (meta.mode === "live" && (fresh.length || (open.length && now - lastBeep > 15000))) { beep(); lastBeep = now; }
    bar.hidden = !open.length;
    const canAck = meta.actions && !!key;
    $("alert-list").innerHTML = open.map((a) => `<li class="alert ${a.kind}" data-id="${a.id}" data-kind="${a.kind}" data-subject="${esc(a.subject)}">` +
      `<b>${esc(a.kind.toUpperCase())}</b> ${esc(a.text)}${a.cleared ? " <i>(cleared)</i>" : ""} ` +
      `<button data-ack="${a.id}" ${canAck ? "" : "disabled title=\"needs the operator key\""}>Acknowledge</button></li>`).join("");
    $("alert-list").querySelectorAll("[data-ack]").forEach((b) => { b.onclick = () => ack(b.dataset.ack); });
    $("ack-all").disabled = !canAck;
  }

  // ------------------------------------------------------------------ hooks
  function setup(m, k) {
    meta = m; key = k || "";
    const th = $("vtable").tHead.rows[0];
    if (!th.querySelector(".hcol")) th.insertAdjacentHTML("beforeend", '<th class="hcol" title="battery">batt</th><th class="hcol" title="packet loss · since last heard">link</th><th class="hcol">GPS</th><th class="hcol">health</th>');
    const sel = $("coordfmt");
    sel.innerHTML = Object.entries(FORMATS).map(([v, t]) => `<option value="${v}"${v === fmt ? " selected" : ""}>${t}</option>`).join("");
    sel.onchange = () => { fmt = sel.value; store.set("phireman-coords", fmt); if (window.phiremanRedraw) window.phiremanRedraw(); };
    $("hidelost").onchange = (e) => { hideLost = e.target.checked; if (lastFrame) fade(lastFrame); };
    $("ack-all").onclick = () => ack("all");
    $("sound").onclick = () => { beep(); };
  }
  function afterRender(f) {
    lastFrame = f;
    if (f.alerts && f.alerts.battery_low_pct) lowPct = f.alerts.battery_low_pct;
    fade(f); renderAlerts(f);
  }
  window.phiremanHealth = {setup, cells, panel, afterRender, setKey: (k) => { key = k || ""; },
    get beeps() { return beeps; }, get hideLost() { return hideLost; }, format: () => fmt};
})();

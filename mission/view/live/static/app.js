/* phireman: the operator's live picture (and its replay). Plain JS, Leaflet vendored, no CDN.
 *
 * Map frame. Without imagery the map uses Leaflet's CRS.Simple with 1 unit = 1 metre in the
 * mission's north-east frame (lat = north, lng = east): positions are drawn exactly as the
 * station holds them, the metric grid and the scale bar need no projection, and nothing is
 * fetched. With --tiles the map is in real lat/lon (EPSG:3857, what XYZ tiles are cut in) and
 * mission metres are placed around the origin with a local flat-earth conversion (error well
 * under a metre over a few kilometres).
 */
"use strict";
(function () {
  const COLORS = {networked: "#1f6fd1", reclaimed: "#12a4b4", held: "#8e44ad",
                  returning: "#ff8c00", landed: "#808080", lost: "#d62728"};
  const $ = (id) => document.getElementById(id);
  const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"}[c]));
  let meta = null, map = null, geo = false, frame = null, selected = null;
  let key = sessionStorage.getItem("phireman-key") || "";
  const m = /(?:^|[#&])key=([^&]+)/.exec(location.hash);
  if (m) { key = decodeURIComponent(m[1]); sessionStorage.setItem("phireman-key", key); history.replaceState(null, "", location.pathname + location.search); }

  const R = 6378137.0;
  function ll(n, e) {
    if (!geo) return L.latLng(n, e);
    const o = meta.origin;
    return L.latLng(o.lat_deg + (n / R) * 180 / Math.PI,
                    o.lon_deg + (e / (R * Math.cos(o.lat_deg * Math.PI / 180))) * 180 / Math.PI);
  }
  function toNE(latlng) {
    if (!geo) return [latlng.lat, latlng.lng];
    const o = meta.origin;
    return [(latlng.lat - o.lat_deg) * Math.PI / 180 * R,
            (latlng.lng - o.lon_deg) * Math.PI / 180 * R * Math.cos(o.lat_deg * Math.PI / 180)];
  }
  const fmtT = (t) => t === null || t === undefined ? "-" : (t < 0 ? `t${Math.round(t)} s` : `t+${Math.round(t)} s`);
  const pct = (x) => x === null || x === undefined ? "-" : (100 * x).toFixed(1) + " %";

  // ------------------------------------------------------------------ map and static layers
  const layers = {};
  function setupMap() {
    geo = !!meta.tiles;
    const opts = {preferCanvas: true, zoomSnap: 0.25, zoomDelta: 0.5, attributionControl: !!geo};
    if (!geo) Object.assign(opts, {crs: L.CRS.Simple, minZoom: -5, maxZoom: 5});
    map = L.map("map", opts);
    if (geo) {
      L.tileLayer(meta.tiles.url, {maxZoom: 22, minZoom: meta.tiles.min_zoom || 0,
        maxNativeZoom: meta.tiles.max_zoom || 19, attribution: "imagery: --tiles"}).addTo(map);
    }
    const f = meta.geofence || {};
    const h = Math.max(meta.radio_range_m * 3, 300);
    const b = [[f.n_min ?? -h, f.e_min ?? -h], [f.n_max ?? h, f.e_max ?? h]];
    map.fitBounds(L.latLngBounds(ll(b[0][0] - 20, b[0][1] - 20), ll(b[1][0] + 20, b[1][1] + 20)));
    L.control.scale({metric: true, imperial: false, maxWidth: 160, position: "bottomleft"}).addTo(map);
    const North = L.Control.extend({onAdd() { const d = L.DomUtil.create("div", "north");
      d.innerHTML = '<div class="arrow">&#9650;</div>N'; d.title = "north is up"; return d; }});
    new North({position: "topright"}).addTo(map);
    const Legend = L.Control.extend({onAdd() { const d = L.DomUtil.create("div", "maplegend");
      d.innerHTML = '<span class="sw" style="border-color:#7fb0e8"></span>radio link (vehicle-vehicle)<br>' +
        '<span class="sw" style="border-color:#2ca02c"></span>radio link to a crew<br>' +
        '<span class="sw" style="border-color:#222"></span>radio link to base<br>' +
        '<span class="sw" style="border-color:#c2185b;border-top-style:dashed"></span>task tree<br>' +
        '<span class="sw" style="border-color:#555;border-top-style:dotted"></span>planned target<br>' +
        '<span class="sw" style="border-color:#e67e00;border-top-style:dashed"></span>geofence<br>' +
        '<span class="sw" style="border-color:#d62728;border-top-width:8px;opacity:.4"></span>hazard zone';
      return d; }});
    new Legend({position: "bottomright"}).addTo(map);

    layers.grid = L.layerGroup().addTo(map);
    layers.static = L.layerGroup().addTo(map);
    layers.vv = L.polyline([], {color: "#7fb0e8", weight: 1, opacity: 0.55, interactive: false}).addTo(map);
    layers.vb = L.polyline([], {color: "#222", weight: 1.2, opacity: 0.6, interactive: false});
    layers.vc = L.polyline([], {color: "#2ca02c", weight: 1.6, opacity: 0.8, interactive: false});
    // One group, on the map and in the layer control: the checkbox shows what is drawn.
    layers.crewbase = L.layerGroup([layers.vb, layers.vc]).addTo(map);
    window.phiremanMap = {map, layers};  // for tests and the curious
    layers.tree = L.polyline([], {color: "#c2185b", weight: 3, opacity: 0.75, dashArray: "8 6", interactive: false}).addTo(map);
    layers.targets = L.polyline([], {color: "#555", weight: 1, opacity: 0.7, dashArray: "2 4", interactive: false}).addTo(map);
    layers.tracks = L.layerGroup().addTo(map);
    layers.heading = L.polyline([], {color: "#111", weight: 2, opacity: 0.9, interactive: false}).addTo(map);
    layers.truth = L.layerGroup();
    layers.vehicles = L.layerGroup().addTo(map);
    layers.crews = L.layerGroup().addTo(map);
    layers.labels = L.layerGroup();
    if ((meta.vehicles_expected || 0) <= 80) layers.labels.addTo(map);
    layers.control = L.control.layers(null, {"vehicle ids": layers.labels, "radio links": layers.vv,
      "links to crews / base": layers.crewbase, "task tree": layers.tree,
      "planned targets": layers.targets, "crew tracks": layers.tracks, "metric grid": layers.grid},
      {position: "topleft", collapsed: true}).addTo(map);

    // zones, fence, base
    for (const z of meta.hazard_zones) {
      const style = {color: "#d62728", weight: 1.5, fillColor: "#d62728", fillOpacity: 0.18};
      const shape = z.kind === "circle"
        ? (geo ? L.circle(ll(z.n, z.e), {radius: z.r, ...style}) : L.circle([z.n, z.e], {radius: z.r, ...style}))
        : L.polygon(z.pts.map((p) => ll(p[0], p[1])), style);
      shape.bindTooltip(esc(z.label)); shape._zone = z; shape.addTo(layers.static);
    }
    if (meta.geofence && meta.geofence.n_min !== null) {
      L.polygon([ll(f.n_min, f.e_min), ll(f.n_min, f.e_max), ll(f.n_max, f.e_max), ll(f.n_max, f.e_min)],
        {color: "#e67e00", weight: 2, dashArray: "10 6", fill: false, interactive: false}).addTo(layers.static);
      L.marker(ll(f.n_max, f.e_min), {icon: L.divIcon({className: "grid-label", html: "<b>geofence" +
        (f.max_alt_m ? ` (ceiling ${Math.round(f.max_alt_m)} m)` : "") + "</b>", iconAnchor: [-4, -4]}),
        interactive: false}).addTo(layers.static);
    }
    L.circle(ll(0, 0), {radius: meta.base_range_m, color: "#222", weight: 1, dashArray: "3 5", fill: false, interactive: false}).addTo(layers.static);
    L.circleMarker(ll(0, 0), {radius: 9, color: "#000", weight: 2, fillColor: "#ffd400", fillOpacity: 1})
      .bindTooltip("BASE (command post)", {permanent: true, direction: "right", className: "base-label", offset: [8, 0]})
      .addTo(layers.static);
    map.on("moveend zoomend", drawGrid);
    drawGrid();
  }

  function niceStep(span) {
    const raw = span / 8, p = Math.pow(10, Math.floor(Math.log10(raw)));
    for (const k of [1, 2, 2.5, 5, 10]) if (k * p >= raw) return k * p;
    return 10 * p;
  }
  function drawGrid() {
    layers.grid.clearLayers();
    const bnd = map.getBounds();
    const sw = toNE(bnd.getSouthWest()), ne = toNE(bnd.getNorthEast());
    const step = niceStep(Math.max(ne[0] - sw[0], ne[1] - sw[1]));
    const style = {color: "#8a8a8a", weight: 0.6, opacity: 0.6, interactive: false};
    const n0 = Math.floor(sw[0] / step) * step, e0 = Math.floor(sw[1] / step) * step;
    for (let e = e0; e <= ne[1]; e += step) {
      L.polyline([ll(sw[0], e), ll(ne[0], e)], e === 0 ? {...style, weight: 1.2} : style).addTo(layers.grid);
      L.marker(ll(sw[0], e), {icon: L.divIcon({className: "grid-label", html: e === 0 ? "0" : `${Math.abs(e)} m ${e > 0 ? "E" : "W"}`, iconAnchor: [-2, 14]}), interactive: false}).addTo(layers.grid);
    }
    for (let n = n0; n <= ne[0]; n += step) {
      L.polyline([ll(n, sw[1]), ll(n, ne[1])], n === 0 ? {...style, weight: 1.2} : style).addTo(layers.grid);
      L.marker(ll(n, sw[1]), {icon: L.divIcon({className: "grid-label", html: n === 0 ? "0" : `${Math.abs(n)} m ${n > 0 ? "N" : "S"}`, iconAnchor: [-2, 12]}), interactive: false}).addTo(layers.grid);
    }
  }

  // ------------------------------------------------------------------ panel pieces
  function setupPanel() {
    $("mname").textContent = meta.name;
    document.title = `${meta.name} - phireman ${meta.mode}`;
    if (meta.mode === "replay") { $("badge").textContent = "REPLAY"; $("badge").classList.add("replay"); }
    const c = $("counts");
    c.innerHTML = meta.states.map((s) => `<div class="chip" data-state="${s}"><span class="dot" style="background:${COLORS[s]}"></span>` +
      `<span class="n" id="count-${s}">0</span><span>${esc(meta.state_labels[s])}</span></div>`).join("");
    const sf = $("statefilter");
    for (const s of meta.states) sf.insertAdjacentHTML("beforeend", `<option value="${s}">${s}</option>`);
    sf.onchange = () => frame && renderTable();
    if (meta.mode === "live") {
      if (meta.actions) {
        $("actions-all").hidden = false;
        $("keybox").hidden = !!key;
        $("key").value = key;
        $("key").oninput = (ev) => { key = ev.target.value.trim(); sessionStorage.setItem("phireman-key", key); updateButtons(); if (window.phiremanHealth) window.phiremanHealth.setKey(key); };
      } else $("readonly").hidden = false;
    }
    document.querySelectorAll("[data-all]").forEach((b) => b.onclick = () => ask(b.dataset.all, "all"));
    $("cancel").onclick = () => { $("modal").hidden = true; };
    if (window.phiremanHealth) window.phiremanHealth.setup(meta, key);
  }

  const ACTION_TEXT = {hold: "HOLD (hover where it is, out of the plan)", rtl: "RETURN TO LAUNCH (RTL)",
    land: "LAND where it is", release: "RELEASE from the plan (keeps its last target)",
    rejoin: "RETURN TO THE PLAN"};
  function ask(action, vid) {
    const who = vid === "all" ? "ALL vehicles heard" : `vehicle ${labelOf(vid)}`;
    $("modaltext").innerHTML = `<p><b>${esc(ACTION_TEXT[action])}</b></p><p>for <b>${esc(who)}</b>?</p>`;
    $("modal").hidden = false;
    $("confirm").onclick = async () => {
      $("modal").hidden = true;
      try {
        const r = await fetch("/api/action", {method: "POST", headers: {"Content-Type": "application/json",
          "X-Operator-Key": key}, body: JSON.stringify({action, vehicle: vid})});
        if (!r.ok) { alertLine(`action refused: ${await r.text()}`); return; }
        const d = await r.json();
        alertLine(`${action} sent: ` + d.done.map((x) => `${x.vehicle} ${x.result}`).join(", "));
      } catch (e) { alertLine(`action failed: ${e}`); }
    };
  }
  function alertLine(text) {
    const li = document.createElement("li"); li.className = "action"; li.textContent = text;
    $("events").prepend(li);
  }
  function updateButtons() {
    const ok = meta.mode === "live" && meta.actions && !!key;
    document.querySelectorAll("button[data-act], button[data-all]").forEach((b) => b.disabled = !ok);
  }
  function labelOf(vid) {
    if (!frame) return vid;
    const i = frame.v.id.indexOf(vid);
    return i < 0 ? vid : frame.v.label[i];
  }

  // ------------------------------------------------------------------ drawing a frame
  const vmark = new Map(), vlabel = new Map(), cmark = [];
  const H = window.phiremanHealth;  // vehicle health, alerts, coordinates (health.js)
  window.phiremanRedraw = () => { if (frame) { renderTable(); renderSelected(); } };
  function render(f) {
    frame = f;
    window.phiremanFrame = f;  // for tests and the curious
    const V = f.v, n = V.id.length;
    const pos = (i) => (V.n[i] === null ? null : ll(V.n[i], V.e[i]));
    // vehicles
    const seen = new Set(), head = [], tgt = [];
    const zoomPx = 16;
    for (let i = 0; i < n; i++) {
      const p = pos(i), id = V.id[i], s = V.state[i];
      if (!p) continue;
      seen.add(id);
      let mk = vmark.get(id);
      const style = {radius: s === "lost" ? 5 : 6, color: s === "lost" ? COLORS.lost : "#111", weight: s === "lost" ? 2 : 1,
        fillColor: COLORS[s], fillOpacity: s === "lost" ? 0.15 : 0.95};
      if (!mk) {
        mk = L.circleMarker(p, style).addTo(layers.vehicles);
        mk.on("click", () => select(id));
        vmark.set(id, mk);
        const lb = L.tooltip({permanent: true, direction: "right", className: "veh-label", offset: [5, 0], interactive: false}).setLatLng(p).setContent(esc(V.label[i]));
        vlabel.set(id, lb); layers.labels.addLayer(lb);
      } else { mk.setLatLng(p); mk.setStyle(style); vlabel.get(id).setLatLng(p); }
      mk.options.vid = id;
      if (V.hdg[i] !== null && s !== "lost" && s !== "landed") {
        const a = map.latLngToLayerPoint(p), r = V.hdg[i] * Math.PI / 180;
        head.push([p, map.layerPointToLatLng(L.point(a.x + zoomPx * Math.sin(r), a.y - zoomPx * Math.cos(r)))]);
      }
      if (V.tn[i] !== null && (s === "networked" || s === "reclaimed" || s === "held")) tgt.push([p, ll(V.tn[i], V.te[i])]);
    }
    for (const [id, mk] of vmark) if (!seen.has(id)) { layers.vehicles.removeLayer(mk); layers.labels.removeLayer(vlabel.get(id)); vmark.delete(id); vlabel.delete(id); }
    layers.heading.setLatLngs(head);
    layers.targets.setLatLngs(tgt);
    // links
    const seg = (a, b) => [a, b];
    // Over terrain a link has a status (0 ok); the others are drawn by terrain.js.
    const up = (st, j) => !st || st[j] === 0;
    const vv = [], L1 = f.links.vv;
    for (let k = 0; k < L1.length; k += 2) { const a = pos(L1[k]), b = pos(L1[k + 1]); if (a && b && up(f.links.vv_status, k / 2)) vv.push(seg(a, b)); }
    layers.vv.setLatLngs(vv);
    const vc = [], L2 = f.links.vc;
    for (let k = 0; k < L2.length; k += 2) { const a = pos(L2[k]); if (a && f.crews.n[L2[k + 1]] !== null && up(f.links.vc_status, k / 2)) vc.push(seg(a, ll(f.crews.n[L2[k + 1]], f.crews.e[L2[k + 1]]))); }
    layers.vc.setLatLngs(vc);
    layers.vb.setLatLngs(f.links.vb.map((i, j) => up(f.links.vb_status, j) && pos(i)).filter((a) => a).map((a) => seg(a, ll(0, 0))));
    if (window.phiremanTerrain) window.phiremanTerrain.render(f);  // terrain.js
    // tree
    const tr = [];
    if (f.tree) for (let k = 1; k < f.tree.nodes.length; k++) { const pa = f.tree.parent[k]; if (pa >= 0) tr.push([ll(...f.tree.nodes[pa]), ll(...f.tree.nodes[k])]); }
    layers.tree.setLatLngs(tr);
    $("treesrc").textContent = f.tree ? `Task tree: ${f.tree.source}.` : "";
    // crews
    const names = meta.crews;
    for (let k = 0; k < f.crews.n.length; k++) {
      const ok = f.crews.connected[k], has = f.crews.n[k] !== null;
      const style = {radius: 8, color: ok ? "#0b5d0b" : "#b00000", weight: 3, fillColor: ok ? "#2ca02c" : "#fff", fillOpacity: 1};
      if (!cmark[k]) {
        cmark[k] = L.circleMarker([0, 0], style).bindTooltip(esc(names[k] || `crew ${k + 1}`), {permanent: true, direction: "top", offset: [0, -8], className: "crew-label"});
      }
      if (has) { cmark[k].setLatLng(ll(f.crews.n[k], f.crews.e[k])); cmark[k].setStyle(style); if (!layers.crews.hasLayer(cmark[k])) layers.crews.addLayer(cmark[k]); }
      const el = cmark[k].getTooltip() && cmark[k].getTooltip().getElement();
      if (el) el.classList.toggle("no", !ok);
    }
    if (f.crew_tracks) {
      layers.tracks.clearLayers();
      f.crew_tracks.forEach((t) => t.length > 1 && L.polyline(t.map((p) => ll(p[0], p[1])), {color: "#2ca02c", weight: 1.5, opacity: 0.5, interactive: false}).addTo(layers.tracks));
    }
    // zones active?
    layers.static.eachLayer((l) => { if (l._zone) { const z = l._zone, t = f.t_mission_s ?? 0;
      const on = t >= z.start_s && (z.end_s === null || t < z.end_s);
      l.setStyle({fillOpacity: on ? 0.22 : 0.05, dashArray: on ? null : "4 4", color: on ? "#d62728" : "#999"}); } });
    // truth (replay)
    layers.truth.clearLayers();
    if (f.truth) f.truth.n.forEach((nn, i) => L.circleMarker(ll(nn, f.truth.e[i]), {radius: 3, color: "#000", weight: 1, fillColor: f.truth.alive[i] ? "#fff" : "#000", fillOpacity: 1, interactive: false}).addTo(layers.truth));
    renderPanel(f);
    if (H) { Object.assign(window.phiremanMap, {vmark, vlabel}); H.afterRender(f); }
    document.dispatchEvent(new CustomEvent("phireman:frame", {detail: {frame: f, meta}}));  // rotation.js
  }

  // After the mission time the station ends the flight (OperationsConfig.end): phase "end" while
  // the vehicles return (RTL) or land, "done" once they are down.
  const missionOver = (f) => f.phase === "end" || f.phase === "done" ||
    (f.t_mission_s !== null && f.t_mission_s > meta.duration_s + 1e-6);
  const endText = () => (meta.end_action === "land" ? "vehicles landing where they are" : "vehicles returning to launch (RTL)");
  function renderBadge(f) {
    const b = $("badge");
    let text = "REPLAY", cls = "replay";
    if (meta.mode === "live") {
      if (f.phase === "done") { text = "ENDED"; cls = "ended"; }
      else if (missionOver(f)) { text = meta.end_action === "land" ? "LANDING" : "RTL"; cls = "ending"; }
      else if (f.phase === "refused") { text = "REFUSED"; cls = "ended"; }
      else { text = "LIVE"; cls = ""; }
    }
    b.textContent = text; b.className = "badge" + (cls ? " " + cls : ""); b.dataset.phase = f.phase;
  }
  function renderPanel(f) {
    const dur = Math.round(meta.duration_s);
    $("clock").textContent = f.t_mission_s === null ? `before launch (station t=${Math.round(f.t_s)} s)`
      : missionOver(f) ? `mission over at t+${dur} s (now ${fmtT(f.t_mission_s)})` : `${fmtT(f.t_mission_s)} of ${dur} s`;
    const phaseText = f.phase === "done" ? "done — flight over" : missionOver(f) ? `${f.phase} — mission over, ${endText()}` : f.phase;
    $("phase").textContent = `phase: ${phaseText}` + (f.links.vv_total > f.links.vv.length / 2 ? ` — ${f.links.vv_total} radio links, ${f.links.vv.length / 2} shortest drawn` : "");
    renderBadge(f);
    $("tu1").textContent = pct(f.tu1); $("tu2").textContent = pct(f.tu2);
    $("crews-connected").textContent = `${f.crews_connected} / ${f.crews.n.length}`;
    for (const s of meta.states) $(`count-${s}`).textContent = f.counts[s] || 0;
    $("crew-list").innerHTML = meta.crews.map((nm, k) => {
      const ok = f.crews.connected[k];
      return `<li class="${ok ? "ok" : "no"}" data-name="${esc(nm)}" data-connected="${ok}"><span class="legend-dot" style="background:${ok ? "#2ca02c" : "#fff"};border-color:${ok ? "#0b5d0b" : "#b00"}"></span>${esc(nm)}<span class="st">${ok ? "connected" : "NOT connected"}</span></li>`;
    }).join("");
    $("events").innerHTML = f.events.slice().reverse().map((e) => `<li class="${e.kind}"><span class="t">${e.t_mission_s === null ? "launch" : fmtT(e.t_mission_s)}</span> ${esc(e.text)}</li>`).join("");
    renderTable(); renderSelected(); drawPlot(f); updateButtons();
  }

  function renderTable() {
    const V = frame.v, want = $("statefilter").value;
    const order = [...V.id.keys()].sort((a, b) => meta.states.indexOf(V.state[a]) - meta.states.indexOf(V.state[b]) || a - b);
    const rows = [];
    for (const i of order) {
      if (want && V.state[i] !== want) continue;
      const tdist = V.tn[i] === null || V.n[i] === null ? "-" : `${Math.round(Math.hypot(V.tn[i] - V.n[i], V.te[i] - V.e[i]))} m`;
      rows.push(`<tr data-vid="${V.id[i]}" data-state="${V.state[i]}" class="${V.id[i] === selected ? "sel" : ""}"><td>${esc(V.label[i])}</td>` +
        `<td><span class="legend-dot" style="background:${COLORS[V.state[i]]}"></span> ${V.state[i]}</td><td>${esc(V.mode[i])}</td>` +
        `<td>${V.alt[i] === null ? "-" : Math.round(V.alt[i])} m (L${V.layer[i] + 1})</td><td>${V.hdg[i] === null ? "-" : Math.round(V.hdg[i]) + "°"}</td><td>${tdist}</td>${H ? H.cells(V, i) : ""}</tr>`);
    }
    const tb = $("vtable").tBodies[0];
    tb.innerHTML = rows.join("");
    tb.onclick = (ev) => { const tr = ev.target.closest("tr"); if (tr) select(tr.dataset.vid); };
  }

  function select(id) { selected = id; if (frame) { renderTable(); renderSelected(); } }
  function renderSelected() {
    const box = $("selected");
    if (!selected || !frame) return;
    const V = frame.v, i = V.id.indexOf(selected);
    if (i < 0) { box.textContent = "vehicle not in view"; return; }
    $("sel-title").textContent = `Vehicle ${V.label[i]}`;
    const alt = V.alt[i] === null ? "-" : `${Math.round(V.alt[i])} m`;
    const tgt = V.tn[i] === null ? "none" : `${Math.round(V.tn[i])} m N, ${Math.round(V.te[i])} m E, ${Math.round(V.talt[i])} m up`;
    let html = `<div data-vid="${V.id[i]}" id="selected-state" data-state="${V.state[i]}"><b style="color:${COLORS[V.state[i]]}">${esc(meta.state_labels[V.state[i]])}</b><br>` +
      `mode ${esc(V.mode[i])}${V.released[i] ? ` (${V.released[i].startsWith("taken by ") ? "" : "operator: "}${esc(V.released[i])})` : ""}; altitude ${alt}, layer ${V.layer[i] + 1} of ${meta.layers.n} (${V.layer_alt[i]} m)<br>` +
      `heading ${V.hdg[i] === null ? "-" : Math.round(V.hdg[i]) + "°"}; position ${V.n[i] === null ? "-" : `${Math.round(V.n[i])} m N, ${Math.round(V.e[i])} m E`}<br>planned target: ${tgt}</div>` + (H ? H.panel(V, i) : "");
    if (meta.mode === "live" && meta.actions) {
      html += `<div class="btns">` + [["hold", "Hold"], ["rtl", "RTL", "warn"], ["land", "Land", "warn"], ["release", "Release from plan"], ["rejoin", "Return to plan"]]
        .map(([a, t, c]) => `<button data-act="${a}" class="${c || ""}">${t}</button>`).join("") + `</div>`;
    }
    box.innerHTML = html; box.classList.remove("muted");
    box.querySelectorAll("[data-act]").forEach((b) => b.onclick = () => ask(b.dataset.act, selected));
    updateButtons();
  }

  function drawPlot(f) {
    const cv = $("plot"), g = cv.getContext("2d"), W = cv.width, H = cv.height;
    g.clearRect(0, 0, W, H);
    const s = f.series, pad = {l: 34, r: 34, t: 16, b: 20};
    const T = Math.max(meta.duration_s, s.t.length ? s.t[s.t.length - 1] : 1);
    const NV = Math.max(meta.vehicles_expected || 1, ...s.networked, 1), NC = Math.max(meta.crews.length, 1);
    const x = (t) => pad.l + (W - pad.l - pad.r) * t / T;
    const yv = (v) => H - pad.b - (H - pad.t - pad.b) * v / NV, yc = (c) => H - pad.b - (H - pad.t - pad.b) * c / NC;
    g.strokeStyle = "#bbb"; g.lineWidth = 1; g.strokeRect(pad.l, pad.t, W - pad.l - pad.r, H - pad.t - pad.b);
    g.font = "10px sans-serif"; g.fillStyle = "#1f6fd1"; g.textAlign = "right";
    g.fillText(String(NV), pad.l - 3, pad.t + 8); g.fillText("0", pad.l - 3, H - pad.b);
    g.fillStyle = "#1a7f1a"; g.textAlign = "left";
    g.fillText(String(NC), W - pad.r + 3, pad.t + 8); g.fillText("0", W - pad.r + 3, H - pad.b);
    g.fillStyle = "#444"; g.textAlign = "center";
    g.fillText(`mission time (s), 0 - ${Math.round(T)}`, W / 2, H - 5);
    if (T > meta.duration_s) {  // after the mission end: shaded, the end marked
      g.fillStyle = "rgba(255, 140, 0, 0.12)"; g.fillRect(x(meta.duration_s), pad.t, x(T) - x(meta.duration_s), H - pad.t - pad.b);
      g.strokeStyle = "#e67e00"; g.setLineDash([4, 3]); g.beginPath(); g.moveTo(x(meta.duration_s), pad.t); g.lineTo(x(meta.duration_s), H - pad.b); g.stroke(); g.setLineDash([]);
      g.fillStyle = "#b35f00"; g.textAlign = "right"; g.fillText(meta.end_action === "land" ? "end: land" : "end: RTL", W - pad.r - 2, pad.t + 10);
    }
    const line = (ys, yf, color) => { g.strokeStyle = color; g.lineWidth = 2; g.beginPath();
      s.t.forEach((t, k) => (k ? g.lineTo(x(t), yf(ys[k])) : g.moveTo(x(t), yf(ys[k])))); g.stroke(); };
    if (s.t.length) { line(s.networked, yv, "#1f6fd1"); line(s.crews, yc, "#2ca02c"); }
    g.textAlign = "left"; g.fillStyle = "#1f6fd1"; g.fillText("networked vehicles (left)", pad.l + 4, 11);
    g.fillStyle = "#1a7f1a"; g.fillText("crews connected (right)", pad.l + 170, 11);
    if (f.t_mission_s !== null) { g.strokeStyle = "#c00"; g.lineWidth = 1; g.beginPath(); g.moveTo(x(f.t_mission_s), pad.t); g.lineTo(x(f.t_mission_s), H - pad.b); g.stroke(); }
  }

  // ------------------------------------------------------------------ live: SSE; replay: slider
  function live() {
    const es = new EventSource("/api/stream");
    es.onopen = () => { $("conn").textContent = "connected to the station"; };
    es.onmessage = (ev) => render(JSON.parse(ev.data));
    es.onerror = () => { $("conn").textContent = "station not reachable (flight over?) — retrying"; };
  }
  function replay() {
    const r = meta.replay; $("replaybar").hidden = false; $("mapwrap").classList.add("replay"); map.invalidateSize();
    $("conn").textContent = `recorded run: ${r.run_dir}`;
    if (r.has_truth) { $("truthlabel").hidden = false; $("truth").onchange = (e) => { truthOn = e.target.checked; if (truthOn) layers.truth.addTo(map); else map.removeLayer(layers.truth); load(idx); }; }
    const sl = $("slider"); sl.max = r.t.length - 1;
    let idx = 0, playing = false, truthOn = false, busy = false, last = 0, simT = r.t[0];
    async function load(i) {
      idx = i; sl.value = i;
      $("replaytime").textContent = fmtT(r.t[i]);
      busy = true;
      // Responses may come back out of order (a slider dragged, a load while the first frame is
      // still on its way): draw a frame only if it is still the one asked for last.
      try { const f = await (await fetch(`/api/frame?i=${i}${truthOn ? "&truth=1" : ""}`)).json(); if (i === idx) render(f); } finally { busy = false; }
    }
    window.phiremanReplay = {load, times: r.t};
    sl.oninput = () => { simT = r.t[+sl.value]; load(+sl.value); };
    $("play").onclick = () => { playing = !playing; $("play").innerHTML = playing ? "&#10074;&#10074;" : "&#9654;"; last = performance.now(); simT = r.t[idx]; };
    function tick(now) {
      if (playing && !busy) {
        simT += (now - last) / 1000 * +$("speed").value;
        let j = idx; while (j < r.t.length - 1 && r.t[j + 1] <= simT) j++;
        if (j !== idx) load(j);
        if (j >= r.t.length - 1) { playing = false; $("play").innerHTML = "&#9654;"; }
      }
      last = now; requestAnimationFrame(tick);
    }
    requestAnimationFrame(tick);
    load(0);
  }

  fetch("/api/meta").then((r) => r.json()).then((m) => {
    meta = m; setupMap(); setupPanel();
    if (window.phiremanTerrain) window.phiremanTerrain.setup(meta, {map, layers, ll});  // terrain.js
    if (meta.mode === "replay") replay(); else live();
  });
})();

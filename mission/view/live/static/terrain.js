/* phireman: the ground on the live page (a mission with radio.model: terrain; docs/terrain.md).
 *
 * app.js calls window.phiremanTerrain.setup(meta, ctx) once and .render(frame) per frame; both do
 * nothing for a mission without terrain (meta.terrain null).
 *
 *  - the shaded relief with contours, rendered once by the server (/api/terrain.png), laid under
 *    everything else as an image overlay at meta.terrain's bounds (mission metres);
 *  - links blocked by terrain (red, dashed) and links out of range (grey, dotted), from the
 *    frame's links.*_status; app.js draws only the links that close;
 *  - a link's profile: click a link, or shift-click two vehicles: /api/profile draws the ground,
 *    the line of sight, the first Fresnel zone and the part of it that must be clear, with the
 *    verdict, in a panel over the map (SVG).
 */
"use strict";
(function () {
  const OK = 0, BLOCKED = 1, FAR = 2;
  const STYLE = {
    [BLOCKED]: {color: "#e31a1c", weight: 1.3, opacity: 0.85, dashArray: "7 3 1 3", interactive: false},
    [FAR]: {color: "#777", weight: 1.2, opacity: 0.7, dashArray: "1 4", interactive: false},
  };
  let meta = null, ctx = null, frame = null, layers = null, pick = null, open = null;
  const esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"}[c]));

  function setup(m, c) {
    meta = m; ctx = c;
    const T = meta.terrain;
    if (!T) return;
    const map = ctx.map;
    map.createPane("terrain").style.zIndex = 250;  // above imagery tiles (200), under vectors (400)
    const bounds = L.latLngBounds(ctx.ll(T.n_min, T.e_min), ctx.ll(T.n_max, T.e_max));
    const relief = L.imageOverlay(T.url, bounds, {pane: "terrain", opacity: 0.75, interactive: false,
      className: "terrain-relief", alt: "shaded relief and contours"}).addTo(map);
    layers = {relief, blocked: L.polyline([], STYLE[BLOCKED]).addTo(map), far: L.polyline([], STYLE[FAR]).addTo(map),
      pick: L.layerGroup().addTo(map)};
    layers.far.bringToBack(); layers.blocked.bringToBack();  // under the vehicles and crews
    window.phiremanTerrainLayers = layers;  // for tests and the curious
    const lc = ctx.layers.control;  // app.js's layer control
    lc.addOverlay(relief, "terrain relief"); lc.addOverlay(layers.blocked, "links blocked by terrain");
    lc.addOverlay(layers.far, "links out of range");
    const Legend = L.Control.extend({onAdd() {
      const d = L.DomUtil.create("div", "maplegend terrain-legend");
      d.innerHTML = `<b>Terrain radio</b> (${Math.round(T.frequency_mhz)} MHz, ${Math.round(T.max_range_m)} m in free space)<br>` +
        '<span class="sw" style="border-color:#7fb0e8"></span>link ok<br>' +
        '<svg width="18" height="4" style="margin-right:4px;vertical-align:middle"><line x1="0" y1="2" x2="18" y2="2" stroke="#e31a1c" stroke-width="2" stroke-dasharray="7 3 1 3"/></svg>blocked by terrain<br>' +
        '<span class="sw" style="border-color:#777;border-top-style:dotted"></span>out of range<br>' +
        `relief: contours every ${T.contour_m} m, ${Math.round(T.h_min_m)}-${Math.round(T.h_max_m)} m AMSL<br>` +
        '<i>click a link, or shift-click two vehicles: its profile</i>';
      L.DomEvent.disableClickPropagation(d);
      return d; }});
    new Legend({position: "bottomright"}).addTo(map);
    const style = document.createElement("style");
    style.textContent = `#terrain-profile { position: absolute; left: 10px; bottom: 56px; max-width: 470px; z-index: 1001; background: rgba(255,255,255,.97);
      border: 1px solid #888; border-radius: 4px; padding: 6px 8px; font-size: 11px; box-shadow: 0 2px 10px rgba(0,0,0,.25); }
      #terrain-profile[hidden] { display: none; } #terrain-profile .head { display: flex; justify-content: space-between; gap: 8px; }
      #terrain-profile .verdict.ok { color: #1a7f1a; } #terrain-profile .verdict.no { color: #c00; }
      #terrain-profile button { padding: 0 6px; } .terrain-legend { max-width: 260px; }`;
    document.head.appendChild(style);
    const box = document.createElement("div");
    box.id = "terrain-profile"; box.hidden = true;
    document.getElementById("mapwrap").appendChild(box);
    L.DomEvent.disableClickPropagation(box);
    map.on("click", onClick);
  }

  // ------------------------------------------------------------------ links with a status
  function ends(f) {  // every drawn link: [kind, k, status, [n, e, h] a, [n, e, h] b]
    const V = f.v, C = f.crews, Lk = f.links, out = [];
    const v = (i) => (V.n[i] === null || V.amsl[i] === null ? null : [V.n[i], V.e[i], V.amsl[i]]);
    for (let k = 0; k < Lk.vv.length; k += 2) out.push(["vv", k / 2, Lk.vv_status[k / 2], v(Lk.vv[k]), v(Lk.vv[k + 1]), [Lk.vv[k], Lk.vv[k + 1]]]);
    for (let k = 0; k < Lk.vc.length; k += 2) {
      const c = Lk.vc[k + 1];
      out.push(["vc", k / 2, Lk.vc_status[k / 2], v(Lk.vc[k]), C.n[c] === null ? null : [C.n[c], C.e[c], C.amsl[c]], [Lk.vc[k], c]]);
    }
    Lk.vb.forEach((i, j) => out.push(["vb", j, Lk.vb_status[j], v(i), [0, 0, Lk.base_amsl], [i, -1]]));
    return out.filter((x) => x[3] && x[4]);
  }
  function render(f) {
    frame = f;
    if (!layers || !f.links.vv_status) return;
    const blocked = [], far = [];
    for (const [, , st, a, b] of ends(f)) {
      if (st === BLOCKED) blocked.push([ctx.ll(a[0], a[1]), ctx.ll(b[0], b[1])]);
      else if (st === FAR) far.push([ctx.ll(a[0], a[1]), ctx.ll(b[0], b[1])]);
    }
    layers.blocked.setLatLngs(blocked);
    layers.far.setLatLngs(far);
    if (open) refresh();
  }

  // ------------------------------------------------------------------ picking
  function segDistPx(p, a, b) {
    const dx = b.x - a.x, dy = b.y - a.y, L2 = dx * dx + dy * dy;
    const t = L2 ? Math.max(0, Math.min(1, ((p.x - a.x) * dx + (p.y - a.y) * dy) / L2)) : 0;
    return Math.hypot(p.x - a.x - t * dx, p.y - a.y - t * dy);
  }
  function onClick(ev) {
    if (!frame || !frame.links.vv_status) return;
    const map = ctx.map, p = map.latLngToLayerPoint(ev.latlng), V = frame.v;
    const px = (n, e) => map.latLngToLayerPoint(ctx.ll(n, e));
    // a vehicle under the click?
    let vi = -1, best = 9;
    for (let i = 0; i < V.id.length; i++) {
      if (V.n[i] === null || V.amsl[i] === null) continue;
      const d = p.distanceTo(px(V.n[i], V.e[i]));
      if (d < best) { best = d; vi = i; }
    }
    if (vi >= 0) {
      if (!ev.originalEvent || !ev.originalEvent.shiftKey) return;  // a plain click selects it (app.js)
      if (pick === null || pick === V.id[vi]) { pick = V.id[vi]; mark(vi); return; }
      const i0 = V.id.indexOf(pick);
      pick = null; layers.pick.clearLayers();
      if (i0 >= 0) show({kind: "vehicles", ids: [V.id[i0], V.id[vi]]});
      return;
    }
    let hit = null; best = 7;
    for (const x of ends(frame)) {
      const d = segDistPx(p, px(x[3][0], x[3][1]), px(x[4][0], x[4][1]));
      if (d < best) { best = d; hit = x; }
    }
    if (hit) show({kind: hit[0], pair: hit[5]});
  }
  function mark(i) {
    layers.pick.clearLayers();
    L.circleMarker(ctx.ll(frame.v.n[i], frame.v.e[i]), {radius: 11, color: "#ff00aa", weight: 3, fill: false, interactive: false}).addTo(layers.pick);
  }

  // ------------------------------------------------------------------ the profile
  function endsOf(sel) {  // the link's two ends in the current frame, with names
    const V = frame.v, C = frame.crews, crewName = (c) => (meta.crews[c] || `crew ${c + 1}`);
    const veh = (i) => (i < 0 || V.n[i] === null || V.amsl[i] === null ? null : {name: `vehicle ${V.label[i]}`, p: [V.n[i], V.e[i], V.amsl[i]]});
    if (sel.kind === "vehicles") return [veh(V.id.indexOf(sel.ids[0])), veh(V.id.indexOf(sel.ids[1]))];
    const [i, j] = sel.pair;
    const a = veh(V.id.indexOf(sel.vid0 || (sel.vid0 = V.id[i])));
    if (sel.kind === "vv") return [a, veh(V.id.indexOf(sel.vid1 || (sel.vid1 = V.id[j])))];
    if (sel.kind === "vc") return [a, C.n[j] === null ? null : {name: crewName(j), p: [C.n[j], C.e[j], C.amsl[j]]}];
    return [a, {name: "base", p: [0, 0, frame.links.base_amsl]}];
  }
  function show(sel) { open = sel; refresh(); }
  let busy = false;
  async function refresh() {
    if (busy || !open) return;
    const ab = endsOf(open), box = document.getElementById("terrain-profile");
    if (!ab[0] || !ab[1]) { box.innerHTML = "<i>the link's ends are no longer in view</i>"; return; }
    busy = true;
    try {
      const q = (x) => x.p.map((v) => v.toFixed(1)).join(",");
      const r = await fetch(`/api/profile?a=${q(ab[0])}&b=${q(ab[1])}`);
      const P = await r.json();
      box.innerHTML = draw(P, ab[0].name, ab[1].name);
      box.hidden = false;
      box.dataset.status = P.status_name;
      box.querySelector("button").onclick = () => { open = null; box.hidden = true; };
      window.phiremanProfile = P;  // for tests and the curious
    } finally { busy = false; }
  }
  function draw(P, na, nb) {
    const W = 460, H = 190, pad = {l: 46, r: 10, t: 8, b: 26};
    const d = P.d, g = d.map((_, k) => P.ground[k] + P.bulge[k]);
    const lo = Math.min(...g) - 10, hi = Math.max(...P.los.map((v, k) => v + P.r1[k]), ...g) + 10;
    const X = (v) => pad.l + (W - pad.l - pad.r) * v / Math.max(d[d.length - 1], 1);
    const Y = (v) => H - pad.b - (H - pad.t - pad.b) * (v - lo) / Math.max(hi - lo, 1);
    const path = (xs, ys) => xs.map((x, k) => `${k ? "L" : "M"}${X(x).toFixed(1)},${Y(ys[k]).toFixed(1)}`).join("");
    const upper = P.los.map((v, k) => v + P.r1[k]), lower = P.los.map((v, k) => v - P.r1[k]);
    const must = P.los.map((v, k) => v - P.clear_fraction * P.r1[k]);
    const zone = path(d, upper) + path(d.slice().reverse(), lower.slice().reverse()).replace(/^M/, "L") + "Z";
    const ground = path(d, g) + `L${X(d[d.length - 1])},${Y(lo)}L${X(0)},${Y(lo)}Z`;
    const w = P.worst;
    const worst = w >= 0 ? `<circle cx="${X(d[w])}" cy="${Y(g[w])}" r="4" fill="${P.margin[w] < 0 ? "#d62728" : "#2ca02c"}"/>` : "";
    const ticks = [lo, (lo + hi) / 2, hi].map((v) => `<text x="${pad.l - 4}" y="${Y(v) + 3}" text-anchor="end">${Math.round(v)}</text>`).join("");
    const ok = P.status === OK;
    const ratio = P.clearance_ratio === null ? "-" : P.clearance_ratio.toFixed(2);
    return `<div class="head"><b>${esc(na)} &harr; ${esc(nb)}</b><button title="close">&times;</button></div>` +
      `<div class="verdict ${ok ? "ok" : "no"}" id="terrain-verdict"><b>${esc(P.status_name.toUpperCase())}</b>: slant ${Math.round(P.slant_m)} m of ${Math.round(P.max_range_m)} m; ` +
      `least clearance ${ratio} of the first Fresnel radius (needs ${P.clear_fraction})` +
      (P.worst_margin_m === null ? "" : `, margin ${P.worst_margin_m >= 0 ? "+" : ""}${P.worst_margin_m.toFixed(1)} m at ${Math.round(d[w])} m`) + `</div>` +
      `<svg id="terrain-svg" width="${W}" height="${H}" viewBox="0 0 ${W} ${H}" font-size="10">` +
      `<path d="${ground}" fill="#8c6d46" fill-opacity="0.8"/>` +
      `<path d="${zone}" fill="#7fb0e8" fill-opacity="0.3"/>` +
      `<path d="${path(d, must)}" stroke="#1f6fd1" stroke-dasharray="5 3" fill="none"/>` +
      `<path d="${path(d, P.los)}" stroke="#111" stroke-width="1.5" fill="none"/>${worst}` +
      `<line x1="${pad.l}" y1="${H - pad.b}" x2="${W - pad.r}" y2="${H - pad.b}" stroke="#999"/>${ticks}` +
      `<text x="${(W + pad.l) / 2}" y="${H - 8}" text-anchor="middle">0 - ${Math.round(d[d.length - 1])} m along the link; height AMSL (m)</text></svg>` +
      `<div class="muted">brown: ground (+ earth bulge); black: line of sight; blue: first Fresnel zone, dashed: ${Math.round(100 * P.clear_fraction)} % of it, which must stay clear</div>`;
  }

  window.phiremanTerrain = {setup, render, show};
})();

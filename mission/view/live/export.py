"""GIS export of a recorded run: GeoJSON (RFC 7946, WGS 84 lon/lat) or KML 2.2.

Contents: the base, the geofence, the hazard zones (circles as 64-gons), every vehicle's track
and every crew's track over the whole run (station's belief), and, at each chosen mission time:
vehicles (state, mode, altitude), crews (name, connected), radio links (vehicle-vehicle,
vehicle-crew, vehicle-base) and the task tree.

Heights (docs/live_view.md, "GIS export"): GeoJSON positions are 2-D. RFC 7946's optional third
coordinate is the height above the WGS 84 *ellipsoid*; the station knows heights above mean sea
level (GLOBAL_POSITION_INT ``alt``) and above the mission origin, and the geoid between the two
is tens of metres, so a vehicle's height goes in its properties instead: ``alt_m`` above the
mission origin (the base), ``alt_amsl_m`` above mean sea level. KML writes vehicles at
``alt_amsl_m`` with ``altitudeMode`` ``absolute`` (KML's absolute is above sea level), extruded
to the ground; every other geometry is ``clampToGround``. Polygon exterior rings are
counter-clockwise (RFC 7946 §3.1.6).
"""

from __future__ import annotations

import math
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from planner.geometry import ned_to_geodetic

__all__ = ["export_run", "features"]


def _lonlat(src, ne) -> list:
    ne = np.asarray(ne, dtype=float).reshape(-1, 2)
    o = src.origin
    lat, lon, _ = ned_to_geodetic(
        np.column_stack([ne, np.zeros(len(ne))]), o.lat_deg, o.lon_deg, o.alt_amsl_m
    )
    return [
        [round(float(a), 7), round(float(b), 7)]
        for a, b in zip(np.atleast_1d(lon), np.atleast_1d(lat))
    ]


def _ccw(ring: list) -> list:
    """A closed lon/lat ring counter-clockwise (positive shoelace area), as RFC 7946 §3.1.6
    wants exterior rings (reversed if it was clockwise)."""
    x = np.array([p[0] for p in ring], dtype=float)
    y = np.array([p[1] for p in ring], dtype=float)
    area2 = float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))
    return ring if area2 >= 0 else ring[::-1]


def _feature(geom_type: str, coords, **props) -> dict:
    return {
        "type": "Feature",
        "geometry": {"type": geom_type, "coordinates": coords},
        "properties": props,
    }


def features(src, at_mission_s: list[float]) -> list[dict]:
    """GeoJSON features of ``src`` (a :class:`mission.view.live.replay.ReplaySource`)."""
    m = src.meta()
    out = [_feature("Point", _lonlat(src, [0, 0])[0], kind="base", name="Base (command post)")]
    f = m["geofence"]
    if f and f["n_min"] is not None:
        ring = _lonlat(
            src,
            [
                [f["n_min"], f["e_min"]],
                [f["n_min"], f["e_max"]],
                [f["n_max"], f["e_max"]],
                [f["n_max"], f["e_min"]],
                [f["n_min"], f["e_min"]],
            ],
        )
        out.append(_feature("Polygon", [_ccw(ring)], kind="geofence", max_alt_m=f["max_alt_m"]))
    for z in m["hazard_zones"]:
        if z["kind"] == "circle":
            a = np.linspace(0, 2 * math.pi, 65)
            pts = np.column_stack([z["n"] + z["r"] * np.cos(a), z["e"] + z["r"] * np.sin(a)])
        else:
            pts = np.array(z["pts"] + z["pts"][:1], dtype=float)
        out.append(
            _feature(
                "Polygon",
                [_ccw(_lonlat(src, pts))],
                kind="hazard_zone",
                name=z["label"],
                rate_per_s=z["rate_per_s"],
                start_s=z["start_s"],
                end_s=z["end_s"],
            )
        )
    # whole-run tracks, station's belief
    tracks: dict[str, list] = {}
    for fr in src.frames:
        s = fr.snap
        for i in np.flatnonzero(s.has_position & ~s.lost).tolist():
            tracks.setdefault(f"{s.link_id[i]}:{s.sysid_of_index[i]}", []).append(
                s.pos_ned_m[i, :2]
            )
    for vid, track in tracks.items():
        if len(track) > 1:
            out.append(
                _feature("LineString", _lonlat(src, track), kind="vehicle_track", vehicle=vid)
            )
    t_end = max(0.0, src.t_mission(src.times_s[-1]) or 0.0)
    ts = np.arange(0.0, t_end + 1e-9, 2.0)
    if len(ts) > 1:
        crews = np.array([src.scenario.task_pos_m(t) for t in ts])
        for k, name in enumerate(m["crews"]):
            pts = crews[:, k]
            pts = pts[np.isfinite(pts).all(axis=1)]
            if len(pts) > 1:
                out.append(_feature("LineString", _lonlat(src, pts), kind="crew_track", name=name))
    alt0_amsl_m = float(src.origin.alt_amsl_m)
    for t in at_mission_s:
        fr = src.frame(src.index_at(t))
        tm = fr["t_mission_s"]
        v = fr["v"]
        ne = {}
        for i, vid in enumerate(v["id"]):
            if v["n"][i] is None:
                continue
            ne[i] = [v["n"][i], v["e"][i]]
            alt = v["alt"][i]  # above the mission origin (FleetView's NED frame)
            out.append(
                _feature(
                    "Point",
                    _lonlat(src, ne[i])[0],
                    kind="vehicle",
                    t_mission_s=tm,
                    vehicle=vid,
                    state=v["state"][i],
                    mode=v["mode"][i],
                    alt_m=alt,
                    alt_amsl_m=None if alt is None else round(alt + alt0_amsl_m, 1),
                    heading_deg=v["hdg"][i],
                )
            )
        cne = {}
        for k, name in enumerate(m["crews"]):
            if fr["crews"]["n"][k] is None:
                continue
            cne[k] = [fr["crews"]["n"][k], fr["crews"]["e"][k]]
            out.append(
                _feature(
                    "Point",
                    _lonlat(src, cne[k])[0],
                    kind="crew",
                    name=name,
                    t_mission_s=tm,
                    connected=fr["crews"]["connected"][k],
                )
            )
        L = fr["links"]
        for a, b in zip(L["vv"][::2], L["vv"][1::2]):
            out.append(
                _feature(
                    "LineString",
                    _lonlat(src, [ne[a], ne[b]]),
                    kind="link",
                    link="vehicle-vehicle",
                    t_mission_s=tm,
                )
            )
        for a, k in zip(L["vc"][::2], L["vc"][1::2]):
            out.append(
                _feature(
                    "LineString",
                    _lonlat(src, [ne[a], cne[k]]),
                    kind="link",
                    link="vehicle-crew",
                    crew=m["crews"][k],
                    t_mission_s=tm,
                )
            )
        for a in L["vb"]:
            out.append(
                _feature(
                    "LineString",
                    _lonlat(src, [ne[a], [0, 0]]),
                    kind="link",
                    link="vehicle-base",
                    t_mission_s=tm,
                )
            )
        tree = fr["tree"]
        if tree:
            for j in range(1, len(tree["nodes"])):
                p = tree["parent"][j]
                if p >= 0:
                    out.append(
                        _feature(
                            "LineString",
                            _lonlat(src, [tree["nodes"][p], tree["nodes"][j]]),
                            kind="task_tree",
                            t_mission_s=tm,
                            source=tree["source"],
                        )
                    )
    return out


def _kml(feats: list[dict], name: str) -> str:
    styles = {
        "hazard_zone": "<PolyStyle><color>55281ed6</color></PolyStyle>"
        "<LineStyle><color>ff281ed6</color><width>2</width></LineStyle>",
        "geofence": "<PolyStyle><fill>0</fill></PolyStyle>"
        "<LineStyle><color>ff007ee6</color><width>2</width></LineStyle>",
        "link": "<LineStyle><color>99e8b07f</color><width>1</width></LineStyle>",
        "task_tree": "<LineStyle><color>ff5b18c2</color><width>3</width></LineStyle>",
        "vehicle_track": "<LineStyle><color>88d16f1f</color><width>1</width></LineStyle>",
        "crew_track": "<LineStyle><color>cc2ca02c</color><width>2</width></LineStyle>",
    }
    folders: dict[str, list[str]] = {}
    for f in feats:
        p = f["properties"]
        kind = p["kind"]
        tm = p.get("t_mission_s")
        folder = kind if tm is None else f"t+{tm:.0f} s"
        g = f["geometry"]
        c = g["coordinates"]
        ground = "<altitudeMode>clampToGround</altitudeMode>"
        if g["type"] == "Point" and p.get("alt_amsl_m") is not None:
            # A vehicle: its height above sea level (KML absolute), a line down to the ground.
            geom = (
                "<Point><extrude>1</extrude><altitudeMode>absolute</altitudeMode><coordinates>"
                f"{c[0]},{c[1]},{p['alt_amsl_m']}</coordinates></Point>"
            )
        elif g["type"] == "Point":
            geom = f"<Point>{ground}<coordinates>{c[0]},{c[1]}</coordinates></Point>"
        elif g["type"] == "LineString":
            geom = (
                f"<LineString><tessellate>1</tessellate>{ground}<coordinates>"
                + " ".join(f"{a},{b}" for a, b in c)
                + "</coordinates></LineString>"
            )
        else:
            geom = (
                f"<Polygon><tessellate>1</tessellate>{ground}<outerBoundaryIs><LinearRing>"
                "<coordinates>"
                + " ".join(f"{a},{b}" for a, b in c[0])
                + "</coordinates></LinearRing></outerBoundaryIs></Polygon>"
            )
        title = p.get("name") or p.get("vehicle") or kind
        if kind == "vehicle":
            title = f"vehicle {p['vehicle']} ({p['state']})"
        elif kind == "crew":
            title = f"{p['name']} ({'connected' if p['connected'] else 'NOT connected'})"
        data = "".join(
            f'<Data name="{escape(str(k))}"><value>{escape(str(v))}</value></Data>'
            for k, v in p.items()
        )
        style = f"<styleUrl>#{kind}</styleUrl>" if kind in styles else ""
        folders.setdefault(folder, []).append(
            f"<Placemark><name>{escape(str(title))}</name>{style}"
            f"<ExtendedData>{data}</ExtendedData>{geom}</Placemark>"
        )
    body = "".join(f'<Style id="{k}">{v}</Style>' for k, v in styles.items())
    body += "".join(
        f"<Folder><name>{escape(k)}</name>{''.join(v)}</Folder>" for k, v in folders.items()
    )
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="http://www.opengis.net/kml/2.2">'
        f"<Document><name>{escape(name)}</name>{body}</Document></kml>\n"
    )


def export_run(src, fmt: str, at_mission_s: list[float] | None, out: Path | None = None) -> Path:
    """Write ``export.geojson`` / ``export.kml`` (or ``out``); returns the path.
    ``at_mission_s`` default: the start, the middle and the end of the mission."""
    import json

    if not at_mission_s:
        end = max(0.0, src.t_mission(src.times_s[-1]) or 0.0)
        dur = min(src.duration_s, end)
        at_mission_s = [0.0, dur / 2, dur]
    feats = features(src, list(at_mission_s))
    out = Path(out) if out else src.run_dir / f"export.{fmt}"
    if fmt == "geojson":
        out.write_text(
            json.dumps(
                {"type": "FeatureCollection", "name": src.mission.name, "features": feats},
                allow_nan=False,
            )
            + "\n"
        )
    elif fmt == "kml":
        out.write_text(_kml(feats, f"{src.mission.name} ({src.run_dir.name})"))
    else:
        raise ValueError(f"unknown export format {fmt!r}: geojson or kml")
    return out

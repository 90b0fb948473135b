"""The live web view in a real headless browser (Debian chromium + chromedriver, selenium) during
an emulated flight, its replay driven by the slider, and the GIS export of the same run.

Skipped, loudly, when chromium or chromedriver is missing (``apt-get install -y chromium
chromium-driver``). Loopback only, port 0; waits have generous timeouts, nothing is timed."""

from __future__ import annotations

import asyncio
import csv
import json
import shutil
import threading
from pathlib import Path

import pytest
from browser import (
    _wait,
    get_json,
    live_flight,
    post_json,
)  # the ``browser`` fixture: tests/conftest.py

pytestmark = pytest.mark.udp

CREWS = ("Engine 7", "Hand crew Alpha")


def _mission():
    from mission.format.schema import RunSpec
    from small_mission import crew, small_mission

    return small_mission(
        "browser",
        RunSpec(duration_s=900.0, seed=4, speedup=3.0),
        count=6,
        tasks=(crew(60.0, 40.0, CREWS[0]), crew(-50.0, -60.0, CREWS[1])),
        latency_s=0.01,
    )


def _count(drv, state: str) -> int:
    return int(drv.find_element("id", f"count-{state}").text)


@pytest.fixture(scope="module")
def live_run(browser, tmp_path_factory):
    """Fly, watch and act through the page; returns the run directory (for the replay tests)."""
    box = {}
    kill = threading.Event()

    def hook(op, world):
        if kill.is_set() and "killed" not in box:
            box["killed"] = world.swarm.sysid_of_index[0]
            world.kill(0)

    with live_flight(_mission(), tmp_path_factory.mktemp("live"), hook, box=box) as (info, _):
        drv = browser
        drv.get(f"{info['url']}#key={info['key']}")
        # Every vehicle networked, crews by name.
        _wait(lambda: _count(drv, "networked") == 6, 120, "6 networked vehicles on the page")
        # The crew list is redrawn with every frame: read it in one script (no stale elements).
        names = drv.execute_script(
            "return Array.from(document.querySelectorAll('#crew-list li'),"
            " li => li.getAttribute('data-name'))"
        )
        assert names == list(CREWS)
        assert drv.execute_script("return window.phiremanFrame.v.id.length") == 6
        # A vehicle dies: the page shows it lost.
        kill.set()
        _wait(
            lambda: _count(drv, "lost") == 1 and _count(drv, "networked") == 5,
            60,
            "1 lost, 5 networked after the kill",
        )
        _wait(
            lambda: f"vehicle {box['killed']} lost" in drv.find_element("id", "events").text,
            60,
            "the loss in the events feed",
        )
        # An action without the key is refused.
        code, _ = post_json(info["url"] + "api/action", {"action": "rtl", "vehicle": "all"})
        assert code == 403
        # RTL one vehicle from the page, behind the confirmation.
        target = 3 if box["killed"] != 3 else 4
        # The table and the vehicle card are redrawn with every frame: find and click at once.
        # Found and clicked in one script: between a WebDriver find and its click the redraw can
        # replace the element (StaleElementReference on a loaded machine).
        click_js = (
            "const e = document.querySelector(arguments[0]);"
            "if (!e || e.disabled) return false; e.click(); return true;"
        )
        _wait(
            lambda: drv.execute_script(click_js, f'#vtable tr[data-vid="0:{target}"]'),
            30,
            "a click on the vehicle's row",
        )

        def click_rtl():
            return drv.execute_script(click_js, 'button[data-act="rtl"]')

        _wait(click_rtl, 30, "a click on the enabled RTL button (key given)")
        assert drv.find_element("id", "modal").is_displayed()
        drv.find_element("id", "confirm").click()
        _wait(
            lambda: (
                drv.find_element("id", "selected-state").get_attribute("data-state") == "returning"
            ),
            60,
            "the vehicle shown returning",
        )
        box["rtl_sysid"] = target
        # The emulator's vehicle itself is in RTL (ArduCopter custom_mode 6).
        from mission.flight import runners  # noqa: F401  (the swarm comes back with the result)

        box["rtl_seen_page"] = True
    res = box["result"]
    idx = list(res.swarm.sysid_of_index).index(box["rtl_sysid"])
    core = res.swarm.cores[idx]
    assert core.custom_mode == 6, f"vehicle {box['rtl_sysid']} mode {core.custom_mode}, not RTL"
    events = [json.loads(x) for x in (res.run_dir / "events.jsonl").read_text().splitlines()]
    acts = [e for e in events if e["type"] == "OperatorAction"]
    assert [(a["action"], a["sysid"], a["source"]) for a in acts] == [
        ("rtl", box["rtl_sysid"], "web 127.0.0.1")
    ]
    return res.run_dir


def test_live_page_counts_kill_and_rtl(live_run):
    assert (Path(live_run) / "flight.tlog").stat().st_size > 0


def _metrics(run_dir):
    with open(run_dir / "metrics.csv", newline="") as f:
        return [
            {k: float(v) for k, v in r.items() if v not in ("", None)} for r in csv.DictReader(f)
        ]


@pytest.fixture(scope="module")
def replay_server(live_run):
    from mission.view.live.replay import ReplaySource
    from mission.view.live.server import serve_in_thread

    src = ReplaySource(live_run)
    with serve_in_thread(src) as url:
        yield src, url


_PAGE_JS = """const f = window.phiremanFrame, c = {};
for (const s of ["networked", "reclaimed", "held", "returning", "landed", "lost"])
  c[s] = document.getElementById("count-" + s).textContent;
return {t: f.t_mission_s, id: f.v.id, state: f.v.state, counts: c};"""


def _out_of_plan(run_dir, t_s: float) -> set[str]:
    """Vehicle ids ("link:sysid") an operator action recorded in events.jsonl had taken out of
    the plan at core time ``t_s`` (hold, rtl, land, release; until a rejoin)."""
    out: set[str] = set()
    for line in (run_dir / "events.jsonl").read_text().splitlines():
        e = json.loads(line)
        if e["type"] != "OperatorAction" or e["t_s"] > t_s:
            continue
        vid = f"{e['link_id']}:{e['sysid']}"
        if e["action"] == "rejoin":
            out.discard(vid)
        else:
            out.add(vid)
    return out


def test_replay_slider_matches_the_records(browser, replay_server):
    src, url = replay_server
    rows = _metrics(src.run_dir)
    drv = browser
    drv.get(url)
    slider = _wait(lambda: drv.find_element("id", "slider"), 30, "the slider")
    assert _wait(lambda: drv.find_element("id", "badge").text == "REPLAY", 30, "replay badge")
    checked = 0
    for frac in (0.2, 0.5, 0.8):
        k = int(frac * (len(rows) - 1))
        # The frame taken at the very instant of the tick (the replay puts one at every tick):
        # the page must show what the station believed when it wrote this row.
        i = src.index_at(rows[k]["t_mission_s"])
        assert src.times_s[i] == rows[k]["t_s"] and src.tick_index(k) == i
        drv.execute_script(
            "const s = document.getElementById('slider'); s.value = arguments[0];"
            "s.dispatchEvent(new Event('input'));",
            i,
        )
        want_t = src.frame(i)["t_mission_s"]
        # The frame and the counts drawn from it, read in one script (one rendered frame).
        page = _wait(
            lambda: (lambda p: p if p["t"] == want_t else None)(  # noqa: B023
                drv.execute_script(_PAGE_JS)
            ),
            30,
            f"the page at the slider's time t+{want_t} s",
        )
        states = dict(zip(page["id"], page["state"]))
        counts = {
            s: int(page["counts"][s])
            for s in ("networked", "reclaimed", "held", "returning", "landed", "lost")
        }
        # metrics.csv's networked counts every vehicle heard and not back from a loss in a
        # failsafe (D'(t)), also one an operator took out of the plan (an RTL, a hold); the page
        # shows those as held / returning / landed.
        out = {
            vid
            for vid in _out_of_plan(src.run_dir, rows[k]["t_s"])
            if states.get(vid) not in (None, "lost")
        }
        assert all(states[vid] in ("held", "returning", "landed") for vid in out), (out, states)
        want = {
            "net": int(rows[k]["networked"]) - len(out),
            "lost": int(rows[k]["lost"]),
            "heard": int(rows[k]["networked"] + rows[k]["returning"]),
        }
        got = {
            "net": counts["networked"] + counts["reclaimed"],
            "lost": counts["lost"],
            "heard": sum(counts.values()) - counts["lost"],
        }
        assert got == want, (
            f"t+{rows[k]['t_mission_s']:.1f} s: page {counts} vs metrics.csv "
            f"row {rows[k]} (out of the plan: {sorted(out)})"
        )
        assert int(slider.get_attribute("value")) == i
        checked += 1
    assert checked == 3
    # Play: the slider moves on by itself.
    before = int(slider.get_attribute("value"))
    drv.find_element("id", "play").click()
    _wait(lambda: int(slider.get_attribute("value")) > before, 30, "play to advance the slider")
    drv.find_element("id", "play").click()


def test_geojson_and_kml_export(live_run, tmp_path):
    from mission.view.live.export import export_run
    from mission.view.live.replay import ReplaySource

    src = ReplaySource(live_run)
    path = export_run(src, "geojson", [10.0], tmp_path / "x.geojson")
    feats = json.loads(path.read_text())["features"]
    kinds = {f["properties"]["kind"] for f in feats}
    assert {"base", "geofence", "vehicle_track", "crew_track", "vehicle", "crew", "link"} <= kinds
    assert {f["properties"]["name"] for f in feats if f["properties"]["kind"] == "crew"} == set(
        CREWS
    )
    assert len([f for f in feats if f["properties"]["kind"] == "vehicle_track"]) == 6
    lon, lat = feats[0]["geometry"]["coordinates"][:2]
    assert (
        abs(lat - src.mission.origin.lat_deg) < 1e-6
        and abs(lon - src.mission.origin.lon_deg) < 1e-6
    )
    kml = export_run(src, "kml", [10.0], tmp_path / "x.kml").read_text()
    assert kml.count("<Placemark>") == len(feats) and CREWS[1] in kml


# -- issue 28: what a new user met on the live page (a short flight that reaches its end) --------

END_DURATION_S = 45.0


@pytest.fixture(scope="module")
def ending_flight(tmp_path_factory):
    """A short emulated flight served on port 0 that reaches its mission end by itself (RTL,
    landing, done); the tests read it while it runs. Yields (info, box); box["result"] after."""
    from mission.format.schema import RunSpec
    from small_mission import crew, small_mission

    from mission.format.schema import Attrition, Circle, HazardZone, LocalPoint

    zones = (  # harmless (rate 0), for the export: a disc and a polygon given clockwise
        HazardZone(
            circle=Circle(center=LocalPoint(north_m=-40.0, east_m=50.0), radius_m=30.0),
            rate_per_s=0.0,
            start_s=10.0,
            end_s=30.0,
        ),
        HazardZone(
            polygon=tuple(
                LocalPoint(north_m=n, east_m=e)
                for n, e in ((-80.0, -80.0), (-40.0, -40.0), (-80.0, -20.0))
            ),
            rate_per_s=0.0,
        ),
    )
    mission = small_mission(
        "ending",
        RunSpec(duration_s=END_DURATION_S, seed=5, speedup=3.0),
        count=4,
        tasks=(crew(60.0, 40.0, CREWS[0]),),
        latency_s=0.01,
        attrition=Attrition(hazard_zones=zones),
    )
    box = {}

    def hook(op, world):
        box["phase"] = str(op.phase)

    with live_flight(mission, tmp_path_factory.mktemp("ending"), hook, box=box) as (info, _):
        yield info, box


def test_live_api_truth_and_a_non_utf8_key(ending_flight):
    import http.client
    import urllib.parse

    info, box = ending_flight
    url = info["url"]
    _wait(lambda: get_json(url + "api/frame")[1]["phase"] == "run", 120, "the run phase")
    # The live station has no emulator truth: a clear 404 with a JSON error, not a 500.
    code, body = get_json(url + "api/frame?truth=1")
    assert code == 404 and "truth" in body["error"], (code, body)
    code, body = get_json(url + "api/frame")
    assert code == 200 and "truth" not in body and body["v"]["id"]
    code, body = get_json(url + "api/frame?i=x")
    assert code == 400 and "frame number" in body["error"]
    # An operator key that is not UTF-8 is a wrong key: 403, not 500.
    u = urllib.parse.urlsplit(url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    try:
        conn.putrequest("POST", "/api/action")
        conn.putheader("Content-Type", "application/json")
        conn.putheader("X-Operator-Key", b"\xff\xfe\x80key")
        payload = b'{"action": "rtl", "vehicle": "all"}'
        conn.putheader("Content-Length", str(len(payload)))
        conn.endheaders(payload)
        resp = conn.getresponse()
        assert resp.status == 403, (resp.status, resp.read())
    finally:
        conn.close()


_PANEL_JS = """const cb = Array.from(document.querySelectorAll('.leaflet-control-layers-overlays label'))
  .find(l => l.textContent.includes('links to crews / base'));
const f = window.phiremanFrame, M = window.phiremanMap;
return {checked: cb ? cb.querySelector('input').checked : null,
        drawn: M ? M.map.hasLayer(M.layers.vc) && M.map.hasLayer(M.layers.vb) : null,
        vc: f ? f.links.vc.length : null,
        badge: document.getElementById('badge').textContent,
        clock: document.getElementById('clock').textContent,
        phase: document.getElementById('phase').textContent,
        fphase: f ? f.phase : null, t: f ? f.t_mission_s : null};"""


def test_live_page_layer_toggle_and_the_mission_end(browser, ending_flight):
    info, box = ending_flight
    drv = browser
    drv.get(info["url"])
    problems = []  # both defects reported on one flight (the end cannot be replayed)
    # Crew links drawn (a vehicle within range of the crew): their toggle must be checked.
    page = _wait(
        lambda: (lambda p: p if p["vc"] and p["fphase"] == "run" else None)(
            drv.execute_script(_PANEL_JS)
        ),
        120,
        "a crew link drawn during the run",
    )
    if not (page["checked"] is True and page["drawn"] is True):
        problems.append(f"links drawn but their toggle unchecked: {page}")
    if not (page["badge"] == "LIVE" and f"of {END_DURATION_S:.0f} s" in page["clock"]):
        problems.append(f"during the run: {page}")
    # Unchecking hides them, checking shows them again: the box drives what is drawn.
    for want in (False, True):
        drv.execute_script(
            "Array.from(document.querySelectorAll('.leaflet-control-layers-overlays label'))"
            ".find(l => l.textContent.includes('links to crews / base'))"
            ".querySelector('input').click();"
        )
        page = drv.execute_script(_PANEL_JS)
        if not (page["checked"] is want and page["drawn"] is want):
            problems.append(f"after a click, box and links disagree (want {want}): {page}")
    # After the mission time: the end phase (RTL) is named, the badge no longer says LIVE.
    page = _wait(
        lambda: (lambda p: p if p["fphase"] == "end" and p["t"] > END_DURATION_S else None)(
            drv.execute_script(_PANEL_JS)
        ),
        120,
        "the page in the end phase",
    )
    if not (
        page["badge"] == "RTL"
        and f"mission over at t+{END_DURATION_S:.0f} s" in page["clock"]
        and " of " not in page["clock"]
        and "returning to launch" in page["phase"]
    ):
        problems.append(f"after the mission end: {page}")
    assert not problems, "\n".join(problems)


def test_forward_udpout_announces_its_destination(capsys):
    """``--forward udpout:H:P`` names H:P (where QGC listens), not our ephemeral source port."""
    import socket
    from types import SimpleNamespace

    from mission.commands.live_view import _announce
    from mission.view.live import attach

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        port = rx.getsockname()[1]
        opts = SimpleNamespace(
            forward=(f"udpout:127.0.0.1:{port}", "udpin:127.0.0.1:0"),
            forward_readonly=False,
            serve=None,
            on_live=_announce,
        )

        async def main():
            closers = await attach(
                SimpleNamespace(gcs_sysid=255), [], mission=None, opts=opts, clock=lambda: 0.0
            )
            for c in closers:
                await c.aclose()

        asyncio.run(main())
    lines = [l for l in capsys.readouterr().err.splitlines() if "forwarding" in l]
    assert len(lines) == 2, lines
    assert lines[0].startswith(f"forwarding MAVLink to 127.0.0.1:{port} "), lines
    assert "listening on UDP 127.0.0.1:" in lines[1] and ":0 " not in lines[1], lines


def test_replay_truth_answers_like_live(ending_flight, tmp_path):
    """``/api/frame?truth=1`` on a replay: the truth layer with truth.npz; without it the same
    404 + JSON error as the live view (never a frame silently without the layer asked for)."""

    from mission.view.live.replay import ReplaySource
    from mission.view.live.server import serve_in_thread

    info, box = ending_flight
    _wait(lambda: "result" in box or "error" in box, 240, "the short flight to end")
    assert "error" not in box, box.get("error")
    run_dir = Path(box["result"].run_dir)
    bare = tmp_path / "no-truth"
    shutil.copytree(run_dir, bare)
    (bare / "truth.npz").unlink()
    answers = {}
    for name, d in (("truth", run_dir), ("bare", bare)):
        with serve_in_thread(ReplaySource(d)) as url:
            answers[name] = get_json(url + "api/frame?i=5&truth=1")
    code, body = answers["truth"]
    assert code == 200 and len(body["truth"]["alive"]) == 4, (code, list(body))
    code, body = answers["bare"]
    assert code == 404 and "truth.npz" in body["error"], (code, body)


def _ring_area2(ring) -> float:
    """Twice the signed area of a closed lon/lat ring (> 0: counter-clockwise)."""
    return sum(a[0] * b[1] - b[0] * a[1] for a, b in zip(ring, ring[1:]))


def test_export_rings_heights_and_kml_altitude_mode(ending_flight, tmp_path):
    """RFC 7946: exterior rings counter-clockwise, no third coordinate that is not an ellipsoidal
    height; KML: vehicles above sea level with altitudeMode absolute."""
    import xml.etree.ElementTree as ET

    from mission.view.live.export import export_run
    from mission.view.live.replay import ReplaySource

    info, box = ending_flight
    _wait(lambda: "result" in box or "error" in box, 240, "the short flight to end")
    assert "error" not in box, box.get("error")
    src = ReplaySource(box["result"].run_dir)
    alt0 = src.mission.origin.alt_amsl_m
    feats = json.loads(export_run(src, "geojson", [20.0], tmp_path / "x.geojson").read_text())[
        "features"
    ]
    polys = [f for f in feats if f["geometry"]["type"] == "Polygon"]
    assert {f["properties"]["kind"] for f in polys} == {"geofence", "hazard_zone"}
    assert len(polys) == 3
    for f in polys:
        ring = f["geometry"]["coordinates"][0]
        assert ring[0] == ring[-1] and _ring_area2(ring) > 0, f["properties"]
    vehicles = [f for f in feats if f["properties"]["kind"] == "vehicle"]
    assert len(vehicles) == 4
    for f in vehicles:
        p = f["properties"]
        assert len(f["geometry"]["coordinates"]) == 2, f
        assert 5.0 < p["alt_m"] < 60.0, p  # flying, above the base
        assert p["alt_amsl_m"] == pytest.approx(alt0 + p["alt_m"], abs=0.11), p
    kml = export_run(src, "kml", [20.0], tmp_path / "x.kml").read_text()
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    root = ET.fromstring(kml)
    marks = root.findall(".//k:Placemark", ns)
    seen = 0
    for pm in marks:
        data = {
            d.get("name"): d.findtext("k:value", namespaces=ns)
            for d in pm.iter(f"{{{ns['k']}}}Data")
        }
        geom = next(g for g in pm if g.tag.split("}")[1] in ("Point", "LineString", "Polygon"))
        mode = geom.findtext("k:altitudeMode", namespaces=ns)
        if data.get("kind") == "vehicle":
            lon, lat, alt = (
                float(x) for x in geom.findtext("k:coordinates", namespaces=ns).split(",")
            )
            assert mode == "absolute" and alt == pytest.approx(float(data["alt_amsl_m"]))
            assert alt > alt0 + 5.0
            seen += 1
        else:
            assert mode == "clampToGround", data
    assert seen == 4


def test_event_list_kinds_good_news_and_rally_failures():
    """The live view's event list: a failsafe that ended is shown as good news whatever its
    severity (ArduCopter sends "GCS Failsafe Cleared" at WARNING), a rally set a vehicle does
    not hold as a failure."""
    from gcs.events import StatusText
    from gcs.rally import RallyUploadFailed
    from mission.view.live.station import event_entry

    assert event_entry(StatusText(0, 1, 1.0, 4, "GCS Failsafe Cleared")) == (
        "recovered",
        "says: GCS Failsafe Cleared",
    )
    assert event_entry(StatusText(0, 1, 1.0, 6, "GCS connection regained"))[0] == "recovered"
    assert event_entry(StatusText(0, 1, 1.0, 4, "GCS Failsafe"))[0] == "failsafe"
    assert event_entry(StatusText(0, 1, 1.0, 6, "Takeoff detected"))[0] == "status"
    failed = RallyUploadFailed(0, 1, 2.0, version=3, reason="rally upload failed: x", refused=True)
    assert event_entry(failed) == ("failsafe", "rally upload failed: x")

"""What a pilot watches, on the live page, in a real headless browser during an emulated flight:
the health fields show the emulator's own values, alerts appear, beep and are acknowledged
(logged to events.jsonl), a lost vehicle fades and hides; the page's coordinate formats agree
with the `mgrs` package; the replay shows the same fields from the records.

Skipped, loudly, without chromium / chromedriver (as tests/mission/test_live_view.py). Loopback
only, port 0; generous waits, nothing timed."""

from __future__ import annotations

import json
import threading

import pytest

from browser import _wait, live_flight, post_json  # the ``browser`` fixture: tests/conftest.py

pytestmark = pytest.mark.udp

CREWS = ("Engine 7", "Far crew")
CLICK_JS = (
    "const e = document.querySelector(arguments[0]);"
    "if (!e || e.disabled) return false; e.click(); return true;"
)


def _mission():
    from mission.format.schema import RunSpec
    from small_mission import crew, small_mission

    # "Far crew" stands 3 km out: never connected, so it is cut off from the start.
    return small_mission(
        "health",
        RunSpec(duration_s=900.0, seed=5, speedup=3.0),
        count=6,
        tasks=(crew(60.0, 40.0, CREWS[0]), crew(3000.0, 0.0, CREWS[1])),
        latency_s=0.01,
    )


def _emulator_view(world, sysid):
    """What the emulator itself reports for ``sysid``: its GPS_RAW_INT and SYS_STATUS."""
    from vehicle_emu import telemetry as tm

    sw = world.swarm
    core = sw.cores[list(sw.sysid_of_index).index(sysid)]
    gps = tm.gps_raw_int(core, sw.now_s)
    st = tm.sys_status(core, sw.now_s)
    return {"sats": gps.satellites_visible, "fix": gps.fix_type, "bat": st.battery_remaining}


@pytest.fixture(scope="module")
def health_run(browser, tmp_path_factory):  # noqa: F811
    box = {"world": None}
    kill, failsafe = threading.Event(), threading.Event()

    def hook(op, world):
        box["world"] = world
        sw = world.swarm
        if kill.is_set() and "killed" not in box:
            box["killed"] = int(sw.sysid_of_index[0])
            world.kill(0)
        if failsafe.is_set() and "failsafe" not in box:
            core = sw.cores[1]
            core._set_mode(core.pers.rtl_mode, sw.now_s, "test: failsafe")
            box["failsafe"] = int(sw.sysid_of_index[1])

    drv = browser
    out = tmp_path_factory.mktemp("health")
    with live_flight(_mission(), out, hook, box=box, alert_crew_after_s=5.0) as (info, _):
        drv.get(f"{info['url']}#key={info['key']}")
        _wait(
            lambda: drv.execute_script(
                "const f = window.phiremanFrame; return f && f.v.id.length === 6 &&"
                " f.v.sats.every(x => x !== null) && f.v.bat.every(x => x !== null) &&"
                " f.v.state.every(s => s === 'networked');"
            ),
            120,
            "6 networked vehicles with GPS and battery on the page",
        )
        # --- the fields show the emulator's values, for chosen vehicles
        for sysid in (2, 5):
            want = _emulator_view(box["world"], sysid)
            drv.execute_script(CLICK_JS, f'#vtable tr[data-vid="0:{sysid}"]')
            got = _wait(
                lambda s=sysid: drv.execute_script(
                    "const t = document.getElementById('health');"
                    "if (!t || t.dataset.vid !== arguments[0]) return null;"
                    "const g = (id) => document.getElementById(id).textContent;"
                    "const row = document.querySelector(`#vtable tr[data-vid='${arguments[0]}']`);"
                    "return {sats: g('h-sats'), fix: g('h-fix'), bat: g('h-bat'),"
                    " cell: row.querySelector('td.gpscell').dataset.sats,"
                    " tbat: row.querySelector('td.bat').dataset.bat};",
                    f"0:{s}",
                ),
                30,
                f"vehicle {sysid}'s health panel",
            )
            assert int(got["sats"]) == want["sats"] == int(got["cell"]), (sysid, got, want)
            assert got["fix"] == "3D" and want["fix"] == 3
            # Battery %: what the emulator's SYS_STATUS says now, within the 1 % of a report
            # that may be up to a second old.
            assert abs(int(got["bat"]) - want["bat"]) <= 1, (got, want)
            assert abs(int(got["tbat"]) - want["bat"]) <= 1
        box["sats"] = {s: _emulator_view(box["world"], s)["sats"] for s in (2, 5)}
        # Every vehicle: a position, altitudes, speed, a healthy EKF, no bad sensor.
        f = drv.execute_script("return window.phiremanFrame.v")
        assert all(x is not None for x in f["lat"] + f["lon"] + f["amsl"] + f["ahome"])
        assert set(f["ekf"]) == {"ok"} and set(f["sensors_bad"]) == {""}
        assert all(x is not None and x >= 0 for x in f["since"])
        # --- coordinates in the format the operator picks
        drv.execute_script(
            "const s = document.getElementById('coordfmt'); s.value = 'mgrs';"
            "s.dispatchEvent(new Event('change'));"
        )
        import mgrs

        def mgrs_matches():
            p = drv.execute_script(
                "const V = window.phiremanFrame.v, i = V.id.indexOf('0:5');"
                "return {lat: V.lat[i], lon: V.lon[i],"
                " text: document.getElementById('h-coord').textContent};"
            )
            return p["text"] == mgrs.MGRS().toMGRS(p["lat"], p["lon"]) and p

        _wait(mgrs_matches, 30, "the MGRS position of vehicle 5")
        # --- alerts: a crew cut off (5 s here), a failsafe RTL, a vehicle lost
        _wait(
            lambda: drv.execute_script(
                "return !!document.querySelector(\"#alert-list li[data-kind='crew']"
                "[data-subject='Far crew']\")"
            ),
            120,
            "the crew cut-off alert",
        )
        assert drv.find_element("id", "alertbar").is_displayed()
        assert drv.execute_script("return window.phiremanHealth.beeps") >= 1
        failsafe.set()
        _wait(lambda: "failsafe" in box, 30, "the emulated failsafe")
        _wait(
            lambda: drv.execute_script(
                "return !!document.querySelector(arguments[0])",
                f"#alert-list li[data-kind='failsafe'][data-subject='0:{box['failsafe']}']",
            ),
            60,
            "the failsafe alert",
        )
        kill.set()
        _wait(lambda: "killed" in box, 30, "the kill")
        lost_sel = f"#alert-list li[data-kind='lost'][data-subject='0:{box['killed']}']"
        _wait(
            lambda: drv.execute_script("return !!document.querySelector(arguments[0])", lost_sel),
            60,
            "the lost alert",
        )
        box["alerts_seen"] = drv.execute_script(
            "return Array.from(document.querySelectorAll('#alert-list li'),"
            " li => [li.dataset.kind, li.dataset.subject])"
        )
        if box.get("screenshot"):
            drv.save_screenshot(box["screenshot"])
        # Acknowledging without the key is refused.
        assert post_json(info["url"] + "api/ack", {"alert": "all"})[0] == 403
        # The lost alert acknowledged from the page: gone from the banner, others stay.
        lost_id = drv.execute_script(
            "return document.querySelector(arguments[0]).dataset.id", lost_sel
        )
        _wait(
            lambda: drv.execute_script(CLICK_JS, f"{lost_sel} button[data-ack]"),
            30,
            "a click on Acknowledge",
        )
        _wait(
            lambda: (
                not drv.execute_script("return !!document.querySelector(arguments[0])", lost_sel)
            ),
            30,
            "the acknowledged alert leaves the banner",
        )
        box["lost_id"] = int(lost_id)
        # --- the lost vehicle fades with time, and the toggle hides it
        vid = f"0:{box['killed']}"
        fade = _wait(
            lambda: (lambda o: o if o is not None and o < 0.9 else None)(
                drv.execute_script(
                    "const m = window.phiremanMap.vmark.get(arguments[0]);"
                    "return m ? m.options.fade : null;",
                    vid,
                )
            ),
            60,
            "the lost vehicle's marker to fade",
        )
        assert 0 < fade < 0.9
        drv.execute_script(
            "const c = document.getElementById('hidelost'); c.checked = true;"
            "c.dispatchEvent(new Event('change'));"
        )
        _wait(
            lambda: drv.execute_script(
                "const pm = window.phiremanMap, m = pm.vmark.get(arguments[0]);"
                "const tr = document.querySelector(`#vtable tr[data-vid='${arguments[0]}']`);"
                "return m && !pm.layers.vehicles.hasLayer(m) && (!tr || tr.hidden);",
                vid,
            ),
            30,
            "the lost vehicle hidden",
        )
        # Other vehicles stay on the map.
        assert (
            drv.execute_script(
                "const pm = window.phiremanMap; return pm.layers.vehicles.getLayers().length"
            )
            == 5
        )
        drv.execute_script(
            "const c = document.getElementById('hidelost'); c.checked = false;"
            "c.dispatchEvent(new Event('change'));"
        )
        # The replay test reads packet loss, known once a loss window has closed: the flight
        # lasts at least two windows whatever the browser's speed.
        from mission.view.live.health import LOSS_WINDOW_S

        _wait(
            lambda: box["world"].swarm.now_s >= 2 * LOSS_WINDOW_S + 5.0,
            120,
            "two packet-loss windows of flight",
        )
    res = box["result"]
    box["run_dir"] = res.run_dir
    return box


def test_alerts_are_logged_with_their_acknowledgement(health_run):
    events = [
        json.loads(x) for x in (health_run["run_dir"] / "events.jsonl").read_text().splitlines()
    ]
    raised = [e for e in events if e["type"] == "AlertRaised"]
    kinds = {(e["kind"], e["subject"]) for e in raised}
    assert ("crew", "Far crew") in kinds
    assert ("failsafe", f"0:{health_run['failsafe']}") in kinds
    assert ("lost", f"0:{health_run['killed']}") in kinds
    acks = [e for e in events if e["type"] == "AlertAcknowledged"]
    assert [(a["alert_id"], a["kind"], a["source"]) for a in acks] == [
        (health_run["lost_id"], "lost", "web 127.0.0.1")
    ]
    # The health reports themselves are not in events.jsonl (the .tlog has their frames).
    assert not any(e["type"] in ("GpsReceived", "SensorsReceived") for e in events)


def test_replay_shows_the_recorded_health_and_alerts(health_run):
    from mission.view.live.replay import ReplaySource

    from mission.view.live.health import LOSS_WINDOW_S

    src = ReplaySource(health_run["run_dir"])
    # A frame after vehicle 2's first packet-loss window has closed (the loss column is None
    # before it): the middle one of those. Not simply the middle frame: how long the flight
    # lasts depends on how fast the browser went, and a short one has no closed window there.
    heard = [f.t_s for f in src.frames if 2 in f.snap.sysid_of_index.tolist()]
    later = [i for i, f in enumerate(src.frames) if f.t_s >= heard[0] + LOSS_WINDOW_S + 1.0]
    assert later, (heard[0], src.frames[-1].t_s)
    i = later[len(later) // 2]
    k = src.frames[i].snap.sysid_of_index.tolist().index(2)
    fr = src.frame(i)
    v = fr["v"]
    assert v["sats"][k] == health_run["sats"][2]
    assert v["gps"][k] == 3 and v["ekf"][k] == "ok" and v["bat"][k] is not None
    assert v["loss"][k] is not None and 0.0 <= v["loss"][k] <= 100.0
    last = src.frame(len(src.frames) - 1)
    recorded = {(a["kind"], a["subject"]) for a in last["alerts"]["recent"]}
    assert ("lost", f"0:{health_run['killed']}") in recorded
    # The acknowledged one is no longer open at the end.
    assert all(a["id"] != health_run["lost_id"] for a in last["alerts"]["open"])


_COORDS_JS = """
const out = [];
for (const [lat, lon] of arguments[0]) out.push([PhiremanCoords.mgrs(lat, lon),
  PhiremanCoords.usng(lat, lon), PhiremanCoords.dm(lat, lon), PhiremanCoords.dd(lat, lon)]);
return out;"""


def _dm(v: float, pos: str, neg: str, width: int) -> str:
    a = abs(v)
    d = int(a)
    m = round((a - d) * 60, 3)
    if m >= 60:
        d, m = d + 1, 0.0
    return f"{d:0{width}d}°{m:06.3f}′{neg if v < 0 else pos}"


def test_coordinate_formats_match_the_mgrs_package(browser):  # noqa: F811
    """PhiremanCoords (health.js) against the `mgrs` package (GeoTrans) and a Python
    degrees-minutes, at points over the world: zone edges, both hemispheres, the Norway and
    Svalbard exceptions, the equator, the 80 S / 84 N limits of MGRS over UTM."""
    import mgrs

    from mission.view.live.server import STATIC_DIR

    drv = browser
    drv.get("about:blank")  # the flight is over; the script runs on any page
    drv.execute_script((STATIC_DIR / "health.js").read_text(encoding="utf-8"))
    assert drv.execute_script("return !!window.PhiremanCoords")
    pts = [
        (39.7392, -104.9903),
        (-33.8688, 151.2093),
        (60.5, 5.3),
        (78.2, 15.6),
        (0.0001, 0.0001),
        (-0.5, -78.5),
        (51.4779, -0.0015),
        (64.1466, -21.9426),
        (-79.9, 170.0),
        (83.9, -40.0),
        (37.4219999, -122.0840575),
        (35.0, 6.0),
        (-45.0, -179.9),
    ]
    rng = __import__("random").Random(7)
    pts += [(rng.uniform(-79.9, 83.9), rng.uniform(-180, 179.999)) for _ in range(200)]
    got = drv.execute_script(_COORDS_JS, pts)
    m = mgrs.MGRS()
    bad = []
    for (lat, lon), (g_mgrs, g_usng, g_dm, g_dd) in zip(pts, got):
        want = m.toMGRS(lat, lon, MGRSPrecision=5)
        # Same grid zone and 100 km square; easting / northing within 1 m (rounding of the
        # last digit differs between truncating implementations at exact metre boundaries).
        same = g_mgrs[:-10] == want[:-10] and all(
            abs(
                int(g_mgrs[-10 + 5 * j : len(g_mgrs) - 5 + 5 * j or None])
                - int(want[-10 + 5 * j : len(want) - 5 + 5 * j or None])
            )
            <= 1
            for j in range(2)
        )
        if not same:
            bad.append((lat, lon, g_mgrs, want))
        assert g_usng.replace(" ", "") == g_mgrs.removeprefix("0")  # USNG: no leading zero
        assert g_dm == f"{_dm(lat, 'N', 'S', 2)} {_dm(lon, 'E', 'W', 3)}", (lat, lon, g_dm)
        assert g_dd == f"{lat:.6f}, {lon:.6f}"
    assert not bad, bad[:5]

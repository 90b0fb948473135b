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
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

pytestmark = pytest.mark.udp

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
CREWS = ("Engine 7", "Hand crew Alpha")


def _mission():
    from mission.schema import RunSpec
    from small_mission import crew, small_mission

    return small_mission(
        "browser",
        RunSpec(duration_s=900.0, seed=4, speedup=3.0),
        count=6,
        tasks=(crew(60.0, 40.0, CREWS[0]), crew(-50.0, -60.0, CREWS[1])),
        latency_s=0.01,
    )


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    if not (CHROMIUM and CHROMEDRIVER):
        pytest.skip(
            "BROWSER TEST SKIPPED: chromium / chromedriver not installed "
            "(apt-get install -y chromium chromium-driver)"
        )
    webdriver = pytest.importorskip(
        "selenium.webdriver", reason="BROWSER TEST SKIPPED: no selenium"
    )
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    for a in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--window-size=1400,900",
        f"--user-data-dir={tmp_path_factory.mktemp('chrome-profile')}",
    ):
        opts.add_argument(a)
    opts.binary_location = CHROMIUM
    drv = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    yield drv
    drv.quit()


def _wait(cond, timeout_s: float, what: str):
    end = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < end:
        try:
            last = cond()
            if last:
                return last
        except Exception as exc:  # noqa: BLE001 - page still loading
            last = exc
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what} (last: {last!r})")


def _count(drv, state: str) -> int:
    return int(drv.find_element("id", f"count-{state}").text)


@pytest.fixture(scope="module")
def live_run(browser, tmp_path_factory):
    """Fly, watch and act through the page; returns the run directory (for the replay tests)."""
    from mission.runners import FlyOptions, fly_emulated_async

    tmp = tmp_path_factory.mktemp("live")
    info, box = {}, {}
    kill, stop = threading.Event(), threading.Event()

    def hook(op, world):
        if kill.is_set() and "killed" not in box:
            box["killed"] = world.swarm.sysid_of_index[0]
            world.kill(0)
        if stop.is_set():
            op.phase = "done"

    opts = FlyOptions(
        emulator_in_process=True,
        out_dir=str(tmp),
        serve="127.0.0.1:0",
        on_live=info.update,
        on_operator=hook,
    )

    def run():
        try:
            box["result"] = asyncio.run(fly_emulated_async(_mission(), opts))
        except BaseException as exc:  # noqa: BLE001
            box["error"] = exc

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        _wait(lambda: info.get("url"), 60, "the live view to start")
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
        req = urllib.request.Request(
            info["url"] + "api/action",
            method="POST",
            data=b'{"action": "rtl", "vehicle": "all"}',
            headers={"Content-Type": "application/json"},
        )
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(req, timeout=10)
        assert err.value.code == 403
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
        from mission import runners  # noqa: F401  (the swarm comes back with the result)

        box["rtl_seen_page"] = True
    finally:
        stop.set()
        th.join(180)
    assert "error" not in box, box.get("error")
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
    from mission.live.replay import ReplaySource
    from mission.live.server import LiveServer

    src = ReplaySource(live_run)
    box, ready = {}, threading.Event()

    def run():
        async def main():
            server = await LiveServer(src, "127.0.0.1", 0).start()
            box["url"], box["stop"] = server.url, asyncio.Event()
            box["loop"] = asyncio.get_running_loop()
            ready.set()
            await box["stop"].wait()
            await server.aclose()

        asyncio.run(main())

    th = threading.Thread(target=run, daemon=True)
    th.start()
    assert ready.wait(60)
    yield src, box["url"]
    box["loop"].call_soon_threadsafe(box["stop"].set)
    th.join(30)


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
    from mission.live.export import export_run
    from mission.live.replay import ReplaySource

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


def test_event_list_kinds_good_news_and_rally_failures():
    """The live view's event list: a failsafe that ended is shown as good news whatever its
    severity (ArduCopter sends "GCS Failsafe Cleared" at WARNING), a rally set a vehicle does
    not hold as a failure."""
    from gcs.events import StatusText
    from gcs.rally import RallyUploadFailed
    from mission.live.station import event_entry

    assert event_entry(StatusText(0, 1, 1.0, 4, "GCS Failsafe Cleared")) == (
        "recovered",
        "says: GCS Failsafe Cleared",
    )
    assert event_entry(StatusText(0, 1, 1.0, 6, "GCS connection regained"))[0] == "recovered"
    assert event_entry(StatusText(0, 1, 1.0, 4, "GCS Failsafe"))[0] == "failsafe"
    assert event_entry(StatusText(0, 1, 1.0, 6, "Takeoff detected"))[0] == "status"
    failed = RallyUploadFailed(0, 1, 2.0, version=3, reason="rally upload failed: x", refused=True)
    assert event_entry(failed) == ("failsafe", "rally upload failed: x")

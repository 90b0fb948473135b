"""Make the live-view screenshots of the README and docs/live_view.md (headless chromium).

    nice .venv/bin/python docs/images/make_screenshots.py            # all of them
    nice .venv/bin/python docs/images/make_screenshots.py rotation   # some: live, replay, rotation,
                                                                     # health, terrain

1. live_wildfire.png: ``phireman fly wildfire`` (50 emulated ArduPilot drones, emulator process,
   10x) served with --serve; one vehicle sent home (RTL) and one held through the page's own
   API with the operator key, a vehicle selected; shot at mission time ~90 s.
2. replay_hazard.png: the ``hazard_zone`` mission flown, then ``phireman replay --serve`` of
   its run directory, the slider at ~t+120 s (zone 1 active), the emulator-truth layer off.
3. rotation_panel.png: ``phireman fly wildfire_2h --swap-confirm manual`` (50 emulated drones on
   25-minute batteries, emulator process, 50x) served with --serve; the Relay rotation panel
   (docs/live_view.md) shot when a second vehicle stands on a pad waiting for the crew's Confirm
   (the first one confirmed through the page's own API with the operator key).
4. live_health.png: ``wildfire`` again (50 emulated ArduPilot drones, in-process emulator, 10x),
   the alerts of the hazard's losses acknowledged at ~45 s, at ~50 s one vehicle killed and
   another put in RTL by its own autopilot (a failsafe the station did not command); shot at
   ~58 s with the alert banner up, a networked vehicle selected (battery, link, GPS, health,
   altitudes, MGRS position). Prints the frame's JSON size at 50
   vehicles with and without the health columns.
5. terrain_canyon.png: ``phireman sim --mission canyon_deep --out DIR`` (in process, seed 1), then
   ``phireman replay DIR --serve`` at t+150 s: the relief and contours under the map, links blocked
   by terrain drawn apart, and the profile of the shortest blocked link opened (as a click does).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

HERE = Path(__file__).resolve().parent


@contextlib.contextmanager
def chromium(height: int = 1000):
    """A headless Chromium 1600 px wide, quit on leaving."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    o = webdriver.ChromeOptions()
    for a in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        f"--window-size=1600,{height}",
        "--hide-scrollbars",
        f"--user-data-dir={tempfile.mkdtemp(prefix='phireman-shot-')}",
    ):
        o.add_argument(a)
    o.binary_location = shutil.which("chromium")
    drv = webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=o)
    try:
        yield drv
    finally:
        drv.quit()


#: Move the replay's slider to frame ``arguments[0]`` as a user's drag does.
SLIDE_JS = (
    "const s = document.getElementById('slider'); s.value = arguments[0];"
    "s.dispatchEvent(new Event('input'));"
)


def _api(info, path: str, body: dict):
    """POST ``body`` to the live page's ``api/PATH`` with the operator key: its JSON answer."""
    req = urllib.request.Request(
        info["url"] + "api/" + path,
        method="POST",
        data=json.dumps(body).encode(),
        headers={"Content-Type": "application/json", "X-Operator-Key": info["key"]},
    )
    return json.loads(urllib.request.urlopen(req, timeout=10).read())


def post(info, action, vehicle):
    return _api(info, "action", {"action": action, "vehicle": vehicle})


def ack(info, alert):
    return _api(info, "ack", {"alert": alert})


def until(cond, period_s: float = 0.5, tries: int | None = None) -> None:
    """Poll ``cond`` every ``period_s`` until it holds (or ``tries`` polls have passed)."""
    n = 0
    while not cond() and (tries is None or n < tries):
        time.sleep(period_s)
        n += 1


def t_mission(drv) -> float:
    """The mission time of the frame the page shows (0 before the first)."""
    return (
        drv.execute_script("return window.phiremanFrame && window.phiremanFrame.t_mission_s") or 0
    )


@contextlib.contextmanager
def flying(mission, out_dir: Path, hook=None, **options):
    """Fly ``mission`` emulated from a thread with the live page served on loopback port 0
    (``options``: more FlyOptions); yields what the flight announced (``url``, ``key``) once the
    page is up, and ends the flight (phase done) on leaving."""
    from mission.flight.runners import FlyOptions, fly_emulated_async
    from mission.view.live import attach

    info, state = {}, {"stop": False}

    def on_operator(op, world):
        if hook is not None:
            hook(op, world)
        if state["stop"]:
            op.phase = "done"

    def run():
        asyncio.run(
            fly_emulated_async(
                mission,
                FlyOptions(
                    **options,
                    out_dir=str(out_dir),
                    serve="127.0.0.1:0",
                    attach_view=attach,
                    on_live=info.update,
                    on_operator=on_operator,
                ),
            )
        )

    th = threading.Thread(target=run, daemon=True)
    th.start()
    until(lambda: "url" in info, 0.2)
    try:
        yield info
    finally:
        state["stop"] = True
        th.join(120)


def live_shot(out_dir: Path) -> Path:
    from mission.format.examples import example_path
    from mission.format.load import load_mission

    mission = load_mission(example_path("wildfire"))
    with flying(mission, out_dir, speedup=10.0) as info, chromium() as drv:
        drv.get(f"{info['url']}#key={info['key']}")
        until(lambda: t_mission(drv) >= 50)
        post(info, "rtl", "0:12")
        post(info, "hold", "0:31")
        until(lambda: t_mission(drv) >= 90)
        drv.execute_script("document.querySelector('#vtable tr[data-vid=\"0:31\"]').click()")
        time.sleep(1.0)
        path = HERE / "live_wildfire.png"
        drv.save_screenshot(str(path))
    return path


def replay_shot(out_dir: Path) -> Path:
    from mission.format.examples import example_path
    from mission.view.live.replay import ReplaySource
    from mission.view.live.server import serve_in_thread
    from mission.format.load import load_mission
    from mission.flight.runners import FlyOptions, fly_emulated

    res = fly_emulated(
        load_mission(example_path("hazard_zone")),
        FlyOptions(speedup=20.0, out_dir=str(out_dir), end_wait=False),
    )
    src = ReplaySource(res.run_dir)
    with serve_in_thread(src) as url, chromium() as drv:
        drv.get(url)
        time.sleep(3)
        drv.execute_script(SLIDE_JS, src.index_at(120.0))
        time.sleep(2)
        path = HERE / "replay_hazard.png"
        drv.save_screenshot(str(path))
    return path


def terrain_shot(out_dir: Path) -> Path:
    from mission.experiments.playback import run_inprocess, write_run_dir
    from mission.format.examples import example_path
    from mission.format.load import load_mission
    from mission.view.live.replay_sim import SimReplaySource
    from mission.view.live.server import serve_in_thread

    mission = load_mission(example_path("canyon_deep"))  # its walls block drone-drone links
    run_dir = out_dir / "canyon_deep"
    write_run_dir(mission, run_inprocess(mission, mission.run.seed), run_dir)
    src = SimReplaySource(run_dir)
    with serve_in_thread(src) as url, chromium() as drv:
        drv.get(url)
        until(  # the page up, with its replay controls
            lambda: drv.execute_script("return !!(window.phiremanReplay && window.phiremanFrame)"),
            tries=120,
        )
        drv.execute_script(
            "window.phiremanMap.map.setView(L.latLng(-60, 330),"
            " window.phiremanMap.map.getZoom() + 0.5);" + SLIDE_JS,
            150,
        )
        until(lambda: t_mission(drv) == 150, tries=120)
        time.sleep(1)
        # The shortest vehicle-vehicle link the terrain blocks: its profile, as a click opens.
        drv.execute_script(
            """const f = window.phiremanFrame, L = f.links, V = f.v; let best = -1, d = 1e9;
            for (let k = 0; k < L.vv_status.length; k++) { if (L.vv_status[k] !== 1) continue;
              const i = L.vv[2 * k], j = L.vv[2 * k + 1], x = Math.hypot(V.n[i] - V.n[j], V.e[i] - V.e[j]);
              if (x < d) { d = x; best = k; } }
            if (best >= 0) window.phiremanTerrain.show({kind: "vv", pair: [L.vv[2 * best], L.vv[2 * best + 1]]});"""
        )
        time.sleep(3)
        path = HERE / "terrain_canyon.png"
        drv.save_screenshot(str(path))
    return path


def health_shot(out_dir: Path) -> Path:
    from mission.format.examples import example_path
    from mission.format.load import load_mission

    mission = load_mission(example_path("wildfire"))
    state = {"done": False}

    def hook(op, world):
        t = op.records[-1].t_mission_s if op.records else None
        if t is not None and t > 50 and not state["done"]:
            sw = world.swarm
            world.kill(3)
            core = sw.cores[7]
            core._set_mode(core.pers.rtl_mode, sw.now_s, "screenshot: failsafe")
            state["done"] = True

    with (
        flying(mission, out_dir, hook, speedup=10.0, emulator_in_process=True) as info,
        chromium() as drv,
    ):
        drv.get(f"{info['url']}#key={info['key']}")
        until(lambda: t_mission(drv) >= 45)
        ack(info, "all")  # the hazard's earlier losses: acknowledged, off the banner
        until(lambda: t_mission(drv) >= 58)
        _health_panel(drv)
        path = HERE / "live_health.png"
        drv.save_screenshot(str(path))
    return path


def _health_panel(drv) -> None:
    """MGRS coordinates, a networked vehicle selected and its panel in view; prints the frame's
    JSON size with and without the health columns."""
    drv.execute_script(
        "const s = document.getElementById('coordfmt'); s.value = 'mgrs';"
        "s.dispatchEvent(new Event('change'));"
        "const V = window.phiremanFrame.v, i = V.state.indexOf('networked');"
        "document.querySelector(`#vtable tr[data-vid='${V.id[i]}']`).click();"
    )
    time.sleep(1.0)
    drv.execute_script("document.getElementById('sel-title').scrollIntoView()")
    time.sleep(0.5)
    frame = drv.execute_script("return window.phiremanFrame")
    health_keys = set(frame["v"]) - {
        "id",
        "label",
        "state",
        "mode",
        "n",
        "e",
        "alt",
        "layer",
        "layer_alt",
        "hdg",
        "tn",
        "te",
        "talt",
        "released",
    }
    full = len(json.dumps(frame, separators=(",", ":")))
    frame["v"] = {k: v for k, v in frame["v"].items() if k not in health_keys}
    frame.pop("alerts", None)
    before = len(json.dumps(frame, separators=(",", ":")))
    n = len(frame["v"]["id"])
    print(
        f"frame JSON at {n} vehicles: {before} B without the health columns and alerts, "
        f"{full} B with them ({before / n:.0f} -> {full / n:.0f} B per vehicle)"
    )


def rotation_shot(out_dir: Path) -> Path:
    from mission.format.examples import example_path
    from mission.format.load import load_mission

    mission = load_mission(example_path("wildfire_2h"))
    with (
        flying(
            mission,
            out_dir,
            speedup=50.0,
            apply_failsafes=True,
            swap_confirm="manual",
            end_wait=False,
        ) as info,
        chromium(height=1900) as drv,  # the whole panel in view: an element is shot as it shows
    ):
        drv.get(f"{info['url']}#key={info['key']}")

        def on_pads():
            rot = drv.execute_script("return window.phiremanFrame && window.phiremanFrame.rotation")
            return [] if not rot else [p["vehicle"] for p in rot["pads"] if p["vehicle"]]

        until(lambda: len(on_pads()) >= 1)
        post(info, "confirm_swap", on_pads()[0])
        end = time.monotonic() + 120.0  # a second vehicle on a pad, if one comes soon
        until(lambda: len(on_pads()) >= 2 or time.monotonic() >= end)
        time.sleep(1.0)
        path = HERE / "rotation_panel.png"
        panel = drv.find_element("id", "rotation")
        drv.execute_script("arguments[0].scrollIntoView()", panel)
        drv.save_screenshot(str(out_dir / "rotation_page.png"))
        panel.screenshot(str(path))
    return path


SHOTS = {
    "live": live_shot,
    "replay": replay_shot,
    "health": health_shot,
    "rotation": rotation_shot,
    "terrain": terrain_shot,
}

if __name__ == "__main__":
    import sys

    with tempfile.TemporaryDirectory() as tmp:
        for name in sys.argv[1:] or SHOTS:
            print(SHOTS[name](Path(tmp)))

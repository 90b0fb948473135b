"""Make the live-view screenshots of the README and docs/live_view.md (headless chromium).

    nice .venv/bin/python docs/images/make_screenshots.py

1. live_wildfire.png: ``phireman fly wildfire`` (50 emulated ArduPilot drones, emulator process,
   10x) served with --serve; one vehicle sent home (RTL) and one held through the page's own
   API with the operator key, a vehicle selected; shot at mission time ~90 s.
2. replay_hazard.png: the ``hazard_zone`` mission flown, then ``phireman replay --serve`` of
   its run directory, the slider at ~t+120 s (zone 1 active), the emulator-truth layer off.
3. live_health.png: ``wildfire`` again (50 emulated ArduPilot drones, in-process emulator, 10x),
   the alerts of the hazard's losses acknowledged at ~45 s, at ~50 s one vehicle killed and
   another put in RTL by its own autopilot (a failsafe the station did not command); shot at
   ~58 s with the alert banner up, a networked vehicle selected (battery, link, GPS, health,
   altitudes, MGRS position). Prints the frame's JSON size at 50
   vehicles with and without the health columns.
4. terrain_canyon.png: ``phireman sim --mission canyon --out DIR`` (in process, seed 1), then
   ``phireman replay DIR --serve`` at t+150 s: the relief and contours under the map, links blocked
   by terrain drawn apart, and the profile of the shortest blocked link opened (as a click does).

    nice .venv/bin/python docs/images/make_screenshots.py health    # only the third
    nice .venv/bin/python docs/images/make_screenshots.py terrain   # only the fourth
"""

from __future__ import annotations

import asyncio
import json
import shutil
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

HERE = Path(__file__).resolve().parent


def browser():
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
        "--window-size=1600,1000",
        "--hide-scrollbars",
        f"--user-data-dir={tempfile.mkdtemp(prefix='phireman-shot-')}",
    ):
        o.add_argument(a)
    o.binary_location = shutil.which("chromium")
    return webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=o)


def post(info, action, vehicle):
    req = urllib.request.Request(
        info["url"] + "api/action",
        method="POST",
        data=json.dumps({"action": action, "vehicle": vehicle}).encode(),
        headers={"Content-Type": "application/json", "X-Operator-Key": info["key"]},
    )
    return json.loads(urllib.request.urlopen(req, timeout=10).read())


def ack(info, alert):
    req = urllib.request.Request(
        info["url"] + "api/ack",
        method="POST",
        data=json.dumps({"alert": alert}).encode(),
        headers={"Content-Type": "application/json", "X-Operator-Key": info["key"]},
    )
    return json.loads(urllib.request.urlopen(req, timeout=10).read())


def live_shot(out_dir: Path) -> Path:
    from mission.format.examples import example_path
    from mission.format.load import load_mission
    from mission.flight.runners import FlyOptions, fly_emulated_async

    mission = load_mission(example_path("wildfire"))
    info, state = {}, {"t": None, "stop": False}

    def hook(op, world):
        state["t"] = op.t_mission_s(op.fleet.snapshot(0).t_s) if op.mission_t0_s else None
        if state["stop"]:
            op.phase = "done"

    def run():
        asyncio.run(
            fly_emulated_async(
                mission,
                FlyOptions(
                    speedup=10.0,
                    out_dir=str(out_dir),
                    serve="127.0.0.1:0",
                    on_live=info.update,
                    on_operator=hook,
                ),
            )
        )

    th = threading.Thread(target=run, daemon=True)
    th.start()
    while "url" not in info:
        time.sleep(0.2)
    drv = browser()
    try:
        drv.get(f"{info['url']}#key={info['key']}")

        def t_mission():
            return drv.execute_script(
                "return window.phiremanFrame && window.phiremanFrame.t_mission_s"
            )

        while (t_mission() or 0) < 50:
            time.sleep(0.5)
        post(info, "rtl", "0:12")
        post(info, "hold", "0:31")
        while (t_mission() or 0) < 90:
            time.sleep(0.5)
        drv.execute_script("document.querySelector('#vtable tr[data-vid=\"0:31\"]').click()")
        time.sleep(1.0)
        path = HERE / "live_wildfire.png"
        drv.save_screenshot(str(path))
    finally:
        drv.quit()
        state["stop"] = True
        th.join(120)
    return path


def replay_shot(out_dir: Path) -> Path:
    from mission.format.examples import example_path
    from mission.view.live.replay import ReplaySource
    from mission.view.live.server import LiveServer
    from mission.format.load import load_mission
    from mission.flight.runners import FlyOptions, fly_emulated

    res = fly_emulated(
        load_mission(example_path("hazard_zone")),
        FlyOptions(speedup=20.0, out_dir=str(out_dir), end_wait=False),
    )
    src = ReplaySource(res.run_dir)
    box, ready = {}, threading.Event()

    def serve():
        async def main():
            server = await LiveServer(src, "127.0.0.1", 0).start()
            box.update(url=server.url, stop=asyncio.Event(), loop=asyncio.get_running_loop())
            ready.set()
            await box["stop"].wait()
            await server.aclose()

        asyncio.run(main())

    threading.Thread(target=serve, daemon=True).start()
    ready.wait(60)
    drv = browser()
    try:
        drv.get(box["url"])
        time.sleep(3)
        i = src.index_at(120.0)
        drv.execute_script(
            "const s = document.getElementById('slider'); s.value = arguments[0];"
            "s.dispatchEvent(new Event('input'));",
            i,
        )
        time.sleep(2)
        path = HERE / "replay_hazard.png"
        drv.save_screenshot(str(path))
    finally:
        drv.quit()
        box["loop"].call_soon_threadsafe(box["stop"].set)
    return path


def terrain_shot(out_dir: Path) -> Path:
    from mission.experiments.playback import run_inprocess, write_run_dir
    from mission.format.examples import example_path
    from mission.format.load import load_mission
    from mission.view.live.replay_sim import SimReplaySource
    from mission.view.live.server import LiveServer

    mission = load_mission(example_path("canyon"))
    run_dir = out_dir / "canyon"
    write_run_dir(mission, run_inprocess(mission, mission.run.seed), run_dir)
    src = SimReplaySource(run_dir)
    box, ready = {}, threading.Event()

    def serve():
        async def main():
            server = await LiveServer(src, "127.0.0.1", 0).start()
            box.update(url=server.url, stop=asyncio.Event(), loop=asyncio.get_running_loop())
            ready.set()
            await box["stop"].wait()
            await server.aclose()

        asyncio.run(main())

    threading.Thread(target=serve, daemon=True).start()
    ready.wait(60)
    drv = browser()
    try:
        drv.get(box["url"])
        for _ in range(120):  # the page up, with its replay controls
            if drv.execute_script("return !!(window.phiremanReplay && window.phiremanFrame)"):
                break
            time.sleep(0.5)
        drv.execute_script(
            "window.phiremanMap.map.setView(L.latLng(-60, 330), window.phiremanMap.map.getZoom() + 0.5);"
            "const s = document.getElementById('slider'); s.value = arguments[0];"
            "s.dispatchEvent(new Event('input'));",
            150,
        )
        for _ in range(120):
            if drv.execute_script("return window.phiremanFrame.t_mission_s") == 150:
                break
            time.sleep(0.5)
        time.sleep(1)
        # The shortest vehicle-vehicle link the terrain blocks: its profile, as a click opens it.
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
    finally:
        drv.quit()
        box["loop"].call_soon_threadsafe(box["stop"].set)
    return path


def health_shot(out_dir: Path) -> Path:
    from mission.format.examples import example_path
    from mission.format.load import load_mission
    from mission.flight.runners import FlyOptions, fly_emulated_async
    from mission.view.live import attach

    mission = load_mission(example_path("wildfire"))
    info, state = {}, {"stop": False, "done": False}

    def hook(op, world):
        t = op.records[-1].t_mission_s if op.records else None
        if t is not None and t > 50 and not state["done"]:
            sw = world.swarm
            world.kill(3)
            core = sw.cores[7]
            core._set_mode(core.pers.rtl_mode, sw.now_s, "screenshot: failsafe")
            state["done"] = True
        if state["stop"]:
            op.phase = "done"

    def run():
        asyncio.run(
            fly_emulated_async(
                mission,
                FlyOptions(
                    speedup=10.0,
                    emulator_in_process=True,
                    out_dir=str(out_dir),
                    serve="127.0.0.1:0",
                    attach_view=attach,
                    on_live=info.update,
                    on_operator=hook,
                ),
            )
        )

    th = threading.Thread(target=run, daemon=True)
    th.start()
    while "url" not in info:
        time.sleep(0.2)
    drv = browser()
    try:
        drv.get(f"{info['url']}#key={info['key']}")

        def t_mission():
            return drv.execute_script(
                "return window.phiremanFrame && window.phiremanFrame.t_mission_s"
            )

        while (t_mission() or 0) < 45:
            time.sleep(0.5)
        ack(info, "all")  # the hazard's earlier losses: acknowledged, off the banner
        while (t_mission() or 0) < 58:
            time.sleep(0.5)
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
        path = HERE / "live_health.png"
        drv.save_screenshot(str(path))
    finally:
        drv.quit()
        state["stop"] = True
        th.join(120)
    return path


if __name__ == "__main__":
    import sys

    with tempfile.TemporaryDirectory() as tmp:
        if sys.argv[1:] == ["health"]:
            print(health_shot(Path(tmp)))
        elif sys.argv[1:] == ["terrain"]:
            print(terrain_shot(Path(tmp)))
        else:
            print(live_shot(Path(tmp)))
            print(replay_shot(Path(tmp)))
            print(health_shot(Path(tmp)))
            print(terrain_shot(Path(tmp)))

"""Make the live-view screenshots of the README and docs/live_view.md (headless chromium).

    nice .venv/bin/python docs/images/make_screenshots.py            # all of them
    nice .venv/bin/python docs/images/make_screenshots.py rotation   # some: live, replay, rotation

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


def browser(height: int = 1000):
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
    from mission.view.live import attach

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


def rotation_shot(out_dir: Path) -> Path:
    from mission.format.examples import example_path
    from mission.format.load import load_mission
    from mission.flight.runners import FlyOptions, fly_emulated_async
    from mission.view.live import attach

    mission = load_mission(example_path("wildfire_2h"))
    info, state = {}, {"stop": False}

    def hook(op, world):
        if state["stop"]:
            op.phase = "done"

    def run():
        asyncio.run(
            fly_emulated_async(
                mission,
                FlyOptions(
                    speedup=50.0,
                    out_dir=str(out_dir),
                    serve="127.0.0.1:0",
                    attach_view=attach,
                    on_live=info.update,
                    on_operator=hook,
                    apply_failsafes=True,
                    swap_confirm="manual",
                    end_wait=False,
                ),
            )
        )

    th = threading.Thread(target=run, daemon=True)
    th.start()
    while "url" not in info:
        time.sleep(0.2)
    drv = browser(height=1900)  # the whole panel in view: an element is shot as far as it shows
    try:
        drv.get(f"{info['url']}#key={info['key']}")

        def on_pads():
            rot = drv.execute_script("return window.phiremanFrame && window.phiremanFrame.rotation")
            return [] if not rot else [p["vehicle"] for p in rot["pads"] if p["vehicle"]]

        while len(on_pads()) < 1:
            time.sleep(0.5)
        post(info, "confirm_swap", on_pads()[0])
        end = time.monotonic() + 120.0  # a second vehicle on a pad, if one comes soon
        while len(on_pads()) < 2 and time.monotonic() < end:
            time.sleep(0.5)
        time.sleep(1.0)
        path = HERE / "rotation_panel.png"
        panel = drv.find_element("id", "rotation")
        drv.execute_script("arguments[0].scrollIntoView()", panel)
        drv.save_screenshot(str(out_dir / "rotation_page.png"))
        panel.screenshot(str(path))
    finally:
        drv.quit()
        state["stop"] = True
        th.join(120)
    return path


SHOTS = {
    "live": live_shot,
    "replay": replay_shot,
    "health": health_shot,
    "rotation": rotation_shot,
}

if __name__ == "__main__":
    import sys

    with tempfile.TemporaryDirectory() as tmp:
        for name in sys.argv[1:] or SHOTS:
            print(SHOTS[name](Path(tmp)))

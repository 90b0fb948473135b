"""The relay rotation panel in a real headless browser (Debian chromium + chromedriver, selenium):
a short flight like ``wildfire_2h`` (four emulated drones, one flying, a 4-minute battery, one pad,
20-s swaps), flown with ``swap_confirm='manual'``; the page shows the pad occupied and the swap
requested, the Confirm button is clicked, and the page shows the swap confirmed and done. The
run directory then records the confirmation (events.jsonl, summary.json) and replays it
(rotation.jsonl).

Skipped, loudly, when chromium or chromedriver is missing. Loopback only, port 0; waits have
generous timeouts, nothing is timed."""

from __future__ import annotations

import json

import pytest
from browser import _wait, live_flight  # the ``browser`` fixture: tests/conftest.py

pytestmark = pytest.mark.udp


def rotation_mission(speedup: float = 10.0):
    """Four drones, one crew 72 m out, 4-minute batteries, one pad with 20-s swaps: the plan
    flies one drone and relieves it about every two minutes of mission time."""
    from mission.format.schema import BaseSpec, BatterySpec, EnduranceSpec, RunSpec
    from small_mission import crew, small_mission

    return small_mission(
        "rotation",
        RunSpec(duration_s=900.0, seed=2, speedup=speedup),
        count=4,
        tasks=(crew(60.0, 40.0, "Engine 7"),),
        latency_s=0.01,
        endurance=EnduranceSpec(
            battery=BatterySpec(endurance_s=240.0, low_frac=0.2, critical_frac=0.1),
            base=BaseSpec(
                pads=1, swap_time_s=20.0, spare_batteries=4, chargers=2, charge_time_s=300.0
            ),
        ),
    )


def _rotation(drv) -> dict | None:
    return drv.execute_script("return window.phiremanFrame && window.phiremanFrame.rotation")


def test_the_crew_confirms_a_swap_on_the_page_and_the_replay_shows_it(browser, tmp_path):  # noqa: F811
    from mission.view.live.replay import ReplaySource
    from mission.view.live.server import serve_in_thread

    drv = browser
    with live_flight(
        rotation_mission(), tmp_path, join_s=240.0, apply_failsafes=True, swap_confirm="manual"
    ) as (info, box):
        drv.get(f"{info['url']}#key={info['key']}")
        _wait(lambda: drv.find_element("id", "rotation").is_displayed(), 120, "the panel")
        assert drv.find_element("id", "rotation-mode").text.endswith("by the ground crew")
        # The relay comes home and lands on the pad: the swap is requested.
        vid = _wait(
            lambda: drv.execute_script(
                "const r = document.querySelector('#rotation-pads tr[data-pad=\"1\"]');"
                "return r && r.getAttribute('data-vehicle')"
            ),
            400,
            "a vehicle on pad 1",
        )
        text = drv.find_element("id", "rotation-pads-box").text
        assert f"swap requested: vehicle {vid.split(':')[1]} on pad 1" in text
        rot = _rotation(drv)
        assert rot["phase"][rot_row(drv, vid)] == "swapping"
        assert rot["counters"]["swaps"] == 0  # manual: the power cycle alone does not end it
        # The crew confirms on the page (found and clicked in one script: the panel is redrawn
        # with every frame).
        _wait(
            lambda: drv.execute_script(
                'const b = document.querySelector(`button[data-confirm="${arguments[0]}"]`);'
                "if (!b || b.disabled) return false; b.click(); return true;",
                vid,
            ),
            30,
            "a click on Confirm",
        )
        _wait(
            lambda: drv.find_elements("css selector", "#rotation-events li.crew_confirmed"),
            60,
            "the confirmation among the rotation events",
        )
        # The emulator's crew powers it up with a full pack: a charged spare again, pad free.
        _wait(
            lambda: (
                drv.find_elements("css selector", "#rotation-events li.swap_done")
                and _rotation(drv)["counters"]["swaps_confirmed_by_crew"] == 1
            ),
            300,
            "the swap done",
        )
        _wait(
            lambda: _rotation(drv)["phase"][rot_row(drv, vid)] in ("ready", "inbound", "air"),
            60,
            "the vehicle a spare again",
        )
        assert "1 by the crew" in drv.find_element("id", "rotation-counters").text
    res = box["result"]
    events = [json.loads(x) for x in (res.run_dir / "events.jsonl").read_text().splitlines()]
    (act,) = [e for e in events if e.get("type") == "OperatorAction"]
    assert act["action"] == "confirm_swap" and act["source"].startswith("web 127.0.0.1")
    assert f"{act['link_id']}:{act['sysid']}" == vid and act["result"].startswith("swap confirmed")
    summary = json.loads((res.run_dir / "summary.json").read_text())
    end = summary["endurance"]
    assert end["swap_confirm"] == "manual" and end["swaps_confirmed_by_crew"] >= 1
    assert end["rotations"] >= 1 and end["landed_away"] == 0
    # The replay draws the same panel from rotation.jsonl: the pad occupied, then confirmed.
    src = ReplaySource(res.run_dir)
    # every frame: the pad is occupied from the landing until the crew's click, a few frames
    # at most when the machine is loaded
    index = list(range(len(src.frames)))
    frames = [src.frame(i) for i in index]
    on_pad = [
        (i, f)
        for i, f in zip(index, frames)
        if f.get("rotation") and f["rotation"]["pads"][0]["vehicle"]
    ]
    assert on_pad and on_pad[0][1]["rotation"]["pads"][0]["vehicle"] == vid
    last = frames[-1]["rotation"]
    kinds = [e["kind"] for e in last["events"]]
    assert last["counters"]["swaps_confirmed_by_crew"] >= 1 or "crew_confirmed" in kinds
    assert all(r is None for f in frames for r in f["v"]["released"])  # not an operator hold
    # ... and the page draws it: the slider on a frame with the pad occupied, no Confirm button.
    # (the frame's own index: its t_mission_s is rounded, and index_at of a rounded time may
    # name the frame before it, with the pad still free)
    k = on_pad[0][0]
    with serve_in_thread(src) as url:
        drv.get(url)
        _wait(lambda: drv.execute_script("return !!window.phiremanReplay"), 60, "the replay")
        drv.execute_script("window.phiremanReplay.load(arguments[0])", k)
        _wait(
            lambda: drv.execute_script(
                "const r = document.querySelector('#rotation-pads tr[data-pad=\"1\"]');"
                "return r && r.getAttribute('data-vehicle') === arguments[0]",
                vid,
            ),
            60,
            "the replayed pad occupied",
        )
        assert "swap requested" in drv.find_element("id", "rotation-pads-box").text
        assert not drv.find_elements("css selector", "button[data-confirm]")  # read-only


def rot_row(drv, vid: str) -> int:
    return drv.execute_script("return window.phiremanFrame.v.id.indexOf(arguments[0])", vid)

"""`phireman fly` of a terrain mission with batteries (docs/terrain.md §6, docs/design/endurance.md):
the rotation's spares fly out and its tired relays fly home over the ground, not through it.

A hill 70 m high stands between the base and a crew 480 m east. The drones hold 60 m above the
ground, so a relay behind the hill is below its crest: a spare sent at its layer above home, or a
relay sent home by RTL at its altitude, flies into the hill. Before the rotation's targets went
through the station's terrain targets (gcs/operations/launch.py ``_send_layer_targets``), this
flight lost two drones to the hill."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hill_mission import hill_mission

pytestmark = pytest.mark.udp

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]


def _mission(tmp_path: Path, endurance_s: float) -> Path:
    return hill_mission(
        tmp_path,
        "hill_batteries",
        count=8,
        cruise_agl_m=60.0,
        ceiling_agl_m=120.0,
        tasks=({"name": "North", "track": [{"t_s": 0, "north_m": 300, "east_m": 0}]},),
        run={"speedup": 40.0},
        endurance={
            "battery": {"endurance_s": endurance_s, "low_frac": 0.25, "critical_frac": 0.10},
            "base": {
                "pads": 2,
                "swap_time_s": 10,
                "spare_batteries": 20,
                "chargers": 4,
                "charge_time_s": 100,
            },
            "rotation": True,
        },
    )


def _fly(tmp_path: Path, mission: Path, *flags: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*PHIREMAN, "fly", str(mission), "--out", str(tmp_path / "runs"), *flags],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )


def test_rotation_over_a_hill_keeps_every_drone_clear_of_the_ground(tmp_path):
    out = _fly(tmp_path, _mission(tmp_path, 400.0), "--apply-failsafes")
    assert out.returncode == 0, out.stderr[-2000:]
    run = next((tmp_path / "runs").iterdir())
    s = json.loads((run / "summary.json").read_text())
    emu, end = s["emulator"], s["endurance"]
    assert end["rotations"] >= 5 and end["swaps"] >= 3  # relays did come home and go again
    assert emu["terrain_crashes"] == 0
    # every flight of the station's targets, relaunches after a swap included (a take-off and a
    # landing are not counted), kept the mission's clearance
    assert emu["least_agl_m"] is not None and emu["least_agl_m"] >= 15.0 - 1.0
    assert end["battery_failsafes_in_air"] == 0 and end["landed_away"] == 0
    assert s["truth"]["tu1"] > 0.8  # the crew behind the hill is relayed through the rotation
    assert "over the terrain: 0 crashes into the ground" in out.stdout


def test_a_battery_too_small_for_the_posts_is_a_one_line_error(tmp_path):
    out = _fly(tmp_path, _mission(tmp_path, 60.0))
    assert out.returncode == 2, out.stderr[-2000:]
    assert "Traceback" not in out.stderr
    err = out.stderr.strip().splitlines()[-1]
    assert err.startswith("phireman fly: error: mission hill_batteries: a battery of 60 s")
    assert "--rotation off" in err

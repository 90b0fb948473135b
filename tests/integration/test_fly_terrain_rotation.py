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

pytestmark = pytest.mark.udp

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]

HILL_WITH_BATTERIES = """\
name: hill_batteries
description: Relays rotate through battery swaps over a hill that hides one crew from the base.
origin: {lat_deg: 39.76, lon_deg: -121.62, alt_amsl_m: 500.0}
terrain:
  synthetic:
    half_width_m: 800.0
    spacing_m: 10.0
    hills:
      - {center: {north_m: 0, east_m: 250}, height_m: 70.0, radius_m: 90.0}
  cruise_agl_m: 60.0
  ceiling_agl_m: 120.0
  clearance_m: 15.0
vehicles:
  emulated:
    count: 8
    spawn: {ring: {radius_m: 20.0, noise_m: 0.0}}
    max_speed_m_s: 10.0
    climb_rate_m_s: 5.0
    descent_rate_m_s: 3.0
    cruise_alt_m: 40.0
    n_layers: 1
tasks:
  - name: Behind the hill
    track: [{t_s: 0, north_m: 0, east_m: 480}]
  - name: North
    track: [{t_s: 0, north_m: 300, east_m: 0}]
radio:
  model: terrain
  range_m: 250.0
  base_range_m: 250.0
  link: {fade_margin_db: 20.0}
endurance:
  battery: {endurance_s: ENDURANCE, low_frac: 0.25, critical_frac: 0.10}
  base: {pads: 2, swap_time_s: 10, spare_batteries: 20, chargers: 4, charge_time_s: 100}
  rotation: true
geofence: {half_width_m: 700.0, max_alt_m: 120.0}
planner: {method: phireman, info: central}
run: {duration_s: 400.0, control_period_s: 1.0, seed: 1, speedup: 40.0}
"""


def _mission(tmp_path: Path, endurance_s: float) -> Path:
    path = tmp_path / "hill_batteries.yaml"
    path.write_text(HILL_WITH_BATTERIES.replace("ENDURANCE", f"{endurance_s:g}"))
    return path


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

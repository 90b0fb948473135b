"""The station lost over terrain: every vehicle flies the firmware's own RTL, and that return must
clear the ground (gcs/audit.py ``audit_rtl_altitude``, docs/terrain.md §6). In memory: the
operator and station against the emulated swarm over the lock-step ether, virtual clock.

A 70 m hill stands between the base and a crew 480 m east; under a 50 m ceiling, relays hold at most 50 m above the ground, so
the ones behind the hill are below its crest. When the station goes silent, ArduCopter's GCS
failsafe flies RTL: climb to RTL_ALT above home (or stay higher), then straight home. With the
default RTL_ALT (15 m) the straight line runs into the hill; with the return altitude the audit
requires (written by ``--apply-failsafes``), every vehicle comes home."""

from __future__ import annotations

from pathlib import Path

import pytest

from inmemory_flight import InMemoryFlight
from mission.format.load import load_mission

HILL = """\
name: hill_failsafe
origin: {lat_deg: 39.76, lon_deg: -121.62, alt_amsl_m: 500.0}
terrain:
  synthetic:
    half_width_m: 800.0
    spacing_m: 10.0
    hills:
      - {center: {north_m: 0, east_m: 250}, height_m: 70.0, radius_m: 90.0}
  cruise_agl_m: 45.0
  ceiling_agl_m: 50.0         # a low ceiling: relays behind the hill fly below its crest
  clearance_m: 15.0
vehicles:
  emulated:
    count: 5
    personality: PERSONALITY
    spawn: {ring: {radius_m: 20.0, noise_m: 0.0}}
    max_speed_m_s: 10.0
    climb_rate_m_s: 5.0
    descent_rate_m_s: 3.0
    cruise_alt_m: 40.0
    n_layers: 1
tasks:
  - name: Behind the hill
    track: [{t_s: 0, north_m: 0, east_m: 480}]
radio:
  model: terrain
  range_m: 250.0
  base_range_m: 250.0
  link: {fade_margin_db: 20.0}
geofence: {half_width_m: 700.0, max_alt_m: 120.0}
planner: {method: phireman, info: central}
run: {duration_s: 400.0, control_period_s: 1.0, seed: 1}
"""


def _flight(tmp_path: Path, personality: str, **opts) -> InMemoryFlight:
    path = tmp_path / "hill.yaml"
    path.write_text(HILL.replace("PERSONALITY", personality))
    return InMemoryFlight(load_mission(path), **opts)


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
@pytest.mark.parametrize("fixed", [True, False], ids=["apply-failsafes", "firmware-default"])
def test_station_lost_behind_a_hill(tmp_path, personality, fixed):
    opts = {"apply_failsafes": True} if fixed else {"override_audit": True}
    f = _flight(tmp_path, personality, **opts)
    f.run_until_phase("run", limit_s=200.0)
    f.run_until(f.ether.now_s + 120.0)  # the relays reach the crew behind the hill
    pos = f.swarm.physics.pos_ned_m
    behind = (pos[:, 1] > 300.0) & (-pos[:, 2] < 70.0) & f.swarm.physics.alive
    assert behind.sum() >= 1, pos  # someone is below the crest on the far side
    f.ether.cut_links.add(0)  # the station goes deaf and mute: the firmware's own failsafe
    f.run_until(f.ether.now_s + 150.0)
    crashes = f.swarm.stats["terrain_crashes"]
    if fixed:
        assert crashes == 0
        assert not f.swarm.physics.armed.any()  # all home and disarmed
    else:
        # the firmware default flies straight into the hill: the audit's rule is the truth's
        assert crashes >= 1

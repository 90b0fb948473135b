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

from hill_mission import HILL_HEIGHT_M, hill_mission
from inmemory_flight import InMemoryFlight
from mission.format.load import load_mission


def _flight(tmp_path: Path, personality: str, **opts) -> InMemoryFlight:
    # a low ceiling: relays behind the hill fly below its crest
    path = hill_mission(
        tmp_path,
        "hill_failsafe",
        count=5,
        cruise_agl_m=45.0,
        ceiling_agl_m=50.0,
        personality=personality,
    )
    return InMemoryFlight(load_mission(path), **opts)


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
@pytest.mark.parametrize("fixed", [True, False], ids=["apply-failsafes", "firmware-default"])
def test_station_lost_behind_a_hill(tmp_path, personality, fixed):
    opts = {"apply_failsafes": True} if fixed else {"override_audit": True}
    f = _flight(tmp_path, personality, **opts)
    f.run_until_phase("run", limit_s=200.0)
    f.run_until(f.ether.now_s + 120.0)  # the relays reach the crew behind the hill
    pos = f.swarm.physics.pos_ned_m
    behind = (pos[:, 1] > 300.0) & (-pos[:, 2] < HILL_HEIGHT_M) & f.swarm.physics.alive
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

"""Batteries and relay rotation in the paper's world (mission/experiments/endurance.py): a short,
small-battery version of the shipped wildfire_2h, in process and through ``phireman sim``."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from mission.experiments.playback import run_inprocess
from mission.format.examples import example_path
from mission.format.load import dump_mission, load_mission


def _short(rotation: bool = True):
    """wildfire_2h on 8-minute batteries for 25 minutes: three battery lives."""
    m = load_mission(example_path("wildfire_2h"))
    end = m.endurance
    assert end.battery is not None
    battery = dataclasses.replace(end.battery, endurance_s=480.0)
    return dataclasses.replace(
        m,
        run=dataclasses.replace(m.run, duration_s=1500.0),
        endurance=dataclasses.replace(end, battery=battery, rotation=rotation),
    )


@pytest.fixture(scope="module")
def runs():
    m = _short()
    return {
        mode: run_inprocess(m, 3, battery=b, rotation=r)
        for mode, b, r in (
            ("rotation", "mission", "mission"),
            ("unlimited", "unlimited", "mission"),
            ("off", "mission", "off"),
        )
    }


def test_rotation_keeps_the_crews_connected_where_the_firmware_failsafes_do_not(runs):
    rot, off, unl = runs["rotation"], runs["off"], runs["unlimited"]
    e = rot.endurance
    assert e is not None and unl.endurance is None and unl.battery_frac is None
    # Rotation: relays relieved several times over, nobody at the critical level or landed away,
    # no relay left without a spare.
    assert e["rotations"] >= e["planned_at_start"]
    assert e["critical_in_air"] == 0 and e["landed_away"] == 0
    assert e["battery_failsafes_in_air"] == 0 and e["no_spare"] == 0
    assert e["min_battery_in_air"] > 0.2  # above the firmware's low level (low_frac)
    # Without rotation the firmware's failsafe is what brings drones home.
    assert off.endurance is not None and off.endurance["battery_failsafes_in_air"] > 0
    assert rot.tu1 > off.tu1 + 0.1
    # Only 14 of the 50 fly with 8-minute batteries and 4 pads (the pads bound the plan): below
    # endless batteries, as it must be (wildfire_2h's 25-minute batteries get within points).
    assert unl.tu1 > rot.tu1


def test_batteries_drain_in_the_air_only_and_swaps_refill_them(runs):
    rot = runs["rotation"]
    b = rot.battery_frac
    assert b is not None and b.shape == (rot.record.alive.shape[0] - 1, 50)
    # Some drone's battery went down and came back up to full (a swap).
    rises = np.diff(b, axis=0) > 0.5
    assert rises.any()
    assert np.all(b[rises.nonzero()[0] + 1, rises.nonzero()[1]] == 1.0)
    # Spares waiting on the ground keep their charge: the initial spares are full until launched.
    assert (b[:100] == 1.0).sum(axis=0).max() == 100


def test_missions_without_batteries_are_untouched():
    m = load_mission(example_path("wildfire"))
    r = run_inprocess(dataclasses.replace(m, run=dataclasses.replace(m.run, duration_s=30.0)), 1)
    assert r.endurance is None and r.battery_frac is None
    assert all(ev["event"] == "vehicle_lost" for ev in r.losses)


def test_sim_command_reports_rotations_and_the_references(tmp_path):
    path = tmp_path / "short.yaml"
    path.write_text(dump_mission(_short()))
    base = [sys.executable, "-m", "mission.cli", "sim", "--mission", str(path)]
    out = subprocess.run(base, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "rotations" in out.stdout and "0 landed away from the base" in out.stdout
    off = subprocess.run(base + ["--rotation", "off"], capture_output=True, text=True, timeout=300)
    assert off.returncode == 0, off.stderr
    assert "0 rotations" in off.stdout
    unl = subprocess.run(
        base + ["--battery", "unlimited"], capture_output=True, text=True, timeout=300
    )
    assert unl.returncode == 0, unl.stderr
    assert "rotations" not in unl.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "mission.cli", "sim", "--seeds", "1", "--rotation", "off"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode != 0 and "--battery and --rotation apply to a mission" in bad.stderr
    assert "Traceback" not in bad.stderr

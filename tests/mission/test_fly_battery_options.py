"""``phireman fly --battery / --rotation / --swap-confirm`` (FlyOptions) and the station's rotation built from a
mission with batteries (mission/flight/station_loop.py rotation_setup)."""

from __future__ import annotations

import pytest

from mission.flight.fly_options import FlyOptions, RunnerError
from mission.flight.mission_world import mission_scenario
from mission.flight.runners import with_battery_options
from mission.flight.station_loop import (
    _operations_config,
    _station_config,
    rotation_fleet_size,
    rotation_setup,
)
from mission.format.examples import example_path
from mission.format.load import load_mission


@pytest.fixture(scope="module")
def wildfire():
    return load_mission(example_path("wildfire_2h"))


def test_battery_unlimited_drops_the_batteries(wildfire):
    m = with_battery_options(wildfire, FlyOptions(battery="unlimited"))
    assert m.endurance.battery is None and wildfire.endurance.battery is not None
    assert rotation_setup(m, mission_scenario(m)) is None
    assert not _station_config(m).battery_telemetry


def test_rotation_off_flies_everything(wildfire):
    m = with_battery_options(wildfire, FlyOptions(rotation="off"))
    rot = rotation_setup(m, mission_scenario(m))
    assert rot is not None and not rot.policy.rotate
    assert rot.policy.flying == rot.policy.n_drones


def test_mission_rotation_plans_k_and_reads_batteries(wildfire):
    m = with_battery_options(wildfire, FlyOptions())
    scn = mission_scenario(m)
    rot = rotation_setup(m, scn)
    assert rot is not None and rot.policy.rotate
    assert 1 <= rot.policy.flying < rot.policy.n_drones == len(scn.spawn_ne_m)
    spec = m.endurance.battery
    assert rot.hover_drain_per_s == pytest.approx(1.0 / spec.endurance_s)
    assert rot.policy.params.critical_frac == spec.low_frac
    assert _station_config(m).battery_telemetry
    ops = _operations_config(m, FlyOptions(), None)
    assert ops.battery_audit == "require" and ops.battery_low_frac == spec.low_frac


def test_battery_options_refused_without_batteries():
    m = load_mission(example_path("wildfire_2h"))
    bare = with_battery_options(m, FlyOptions(battery="unlimited"))
    with pytest.raises(RunnerError):
        with_battery_options(bare, FlyOptions(rotation="off"))
    assert _operations_config(bare, FlyOptions(), None).battery_audit == "off"
    assert (
        _operations_config(bare, FlyOptions(connections=("udpin:0.0.0.0:0",)), None).battery_audit
        == "warn"
    )


def test_rotation_is_sized_by_the_vehicles_not_the_links(tmp_path):
    """One link may carry several vehicles (every PX4 SITL instance on UDP 14550): the rotation
    shares the posts among the mission's sysids (or --vehicles), not among its links."""
    import yaml

    m = yaml.safe_load(example_path("sitl_px4").read_text())
    m["endurance"] = {"battery": {"endurance_s": 300.0}, "base": {"swap_time_s": 20}}
    path = tmp_path / "px4_batteries.yaml"
    path.write_text(yaml.safe_dump(m))
    mission = load_mission(path)
    assert len(mission.vehicles.real.connections) == 1
    assert rotation_fleet_size(mission, mission_scenario(mission)) == 3
    rot = rotation_setup(mission, mission_scenario(mission))
    assert rot is not None and rot.policy.n_drones == 3
    del m["vehicles"]["real"]["sysids"]
    path.write_text(yaml.safe_dump(m))
    bare = load_mission(path)
    assert rotation_fleet_size(bare, mission_scenario(bare), expected=4) == 4
    assert rotation_fleet_size(bare, mission_scenario(bare)) == 1  # the links: all it knows


def test_swap_confirm_goes_to_the_station_and_needs_batteries(wildfire):
    m = with_battery_options(wildfire, FlyOptions(swap_confirm="manual"))
    scn = mission_scenario(m)
    assert rotation_setup(m, scn, "manual").swap_confirm == "manual"
    assert rotation_setup(m, scn).swap_confirm == "auto"
    with pytest.raises(RunnerError, match="swap_confirm must be one of auto, manual"):
        with_battery_options(wildfire, FlyOptions(swap_confirm="crew"))
    bare = with_battery_options(wildfire, FlyOptions(battery="unlimited"))
    with pytest.raises(RunnerError, match="--swap-confirm applies to a mission with batteries"):
        with_battery_options(bare, FlyOptions(swap_confirm="manual"))


def test_the_station_plans_the_climb_and_the_landing_the_paper_world_does_not(wildfire):
    """rotation_setup: launch_s gains the climb to the top layer at the mission's climb rate,
    land_s is the firmware's two-stage descent from it; the mission's own params win; fewer fly
    than in process (a longer cycle), and the in-process policy is left as it was."""
    import dataclasses

    from mission.flight.station_loop import landing_descent_s
    from planner.endurance import EnduranceParams

    m = with_battery_options(wildfire, FlyOptions())
    scn = mission_scenario(m)
    rot = rotation_setup(m, scn)
    lim = m.vehicles.limits
    top = lim.cruise_alt_m + (lim.n_layers - 1) * lim.layer_spacing_m
    p = rot.policy.params
    assert p.launch_s == pytest.approx(EnduranceParams().launch_s + top / lim.climb_rate_m_s)
    assert p.land_s == pytest.approx(landing_descent_s(top))
    assert landing_descent_s(50.0) == pytest.approx(40.0 / 1.5 + 10.0 / 0.5)
    assert landing_descent_s(6.0) == pytest.approx(6.0 / 0.5)
    in_process = m.endurance.policy(rot.policy.n_drones, m.run.duration_s, lim.max_speed_m_s, 100.0)
    assert in_process.params.land_s == 0.0
    assert rot.policy.flying < in_process.flying
    own = dataclasses.replace(m.endurance, params={"land_s": 5.0})
    rot_own = rotation_setup(dataclasses.replace(m, endurance=own), scn)
    assert rot_own.policy.params.land_s == 5.0
    # After the audit the plan counts the vehicles' own landing (gcs/landing.py) from the top
    # layer, the slowest of the fleet: a slower LAND_SPEED lands later and fewer fly at once.
    from gcs.autopilot import ARDUPILOT, PX4
    from gcs.landing import landing_descent

    assert rot.land_from_m == top and rot.replan is not None
    slow = landing_descent(ARDUPILOT, {"LAND_SPEED": 30.0})
    k_before = rot.policy.flying
    assert rot.use_landing([landing_descent(PX4), slow]) == pytest.approx(slow.time_s(top))
    assert rot.policy.params.land_s == pytest.approx(slow.time_s(top))
    assert slow.time_s(top) > landing_descent_s(top)
    assert rot.policy.flying <= k_before
    assert rot_own.replan is None  # the mission's own land_s is kept
    assert rot_own.use_landing([slow]) is None and rot_own.policy.params.land_s == 5.0

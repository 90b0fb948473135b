"""``phireman fly --battery / --rotation`` (FlyOptions) and the station's rotation built from a
mission with batteries (mission/flight/station_loop.py rotation_setup)."""

from __future__ import annotations

import pytest

from mission.flight.fly_options import FlyOptions, RunnerError
from mission.flight.mission_world import mission_scenario
from mission.flight.runners import with_battery_options
from mission.flight.station_loop import _operations_config, _station_config, rotation_setup
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

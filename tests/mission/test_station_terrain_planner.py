"""The station plans a terrain mission with the same terrain-aware planner as the in-process world
(docs/terrain.md §6.2): built in one place (mission.format.terrain.terrain_aware_planner)."""

from __future__ import annotations

import numpy as np

from mission.experiments.playback import terrain_flight, terrain_planner
from mission.flight.station_loop import station_planner
from mission.format.examples import example_path
from mission.format.load import load_mission
from mission.format.scenario import control_config
from planner.methods import TickInput, make_planner
from planner.terrain_aware import TerrainAwarePlanner


def test_the_station_plans_a_terrain_mission_as_the_world_does():
    m = load_mission(example_path("canyon"))
    problem = m.problem_config()
    params = m.planner.run_params()
    control = control_config(m, over_terrain=True)
    assert control.terrain is not None and control.terrain.radio is not None
    station = station_planner(
        m, m.planner.method, problem, params, np.random.default_rng(1), control.terrain.radio
    )
    flight = terrain_flight(m, "on")
    assert flight is not None
    inner = make_planner(m.planner.method, problem, params, np.random.default_rng(1))
    world = terrain_planner(inner, m, flight, "on", problem.max_speed_m_s * problem.dt_s)
    assert isinstance(station, TerrainAwarePlanner) and isinstance(world, TerrainAwarePlanner)
    assert station.heights == world.heights
    assert station.heights is not None and station.heights.ceiling_agl_m == 120.0
    # One descent limit: the station's descent steps, the planner's and the world's
    # (vehicles.descent_rate_m_s, 4 m/s on the canyon).
    assert station.heights.max_descent_m == control.terrain.descent_step_m == flight.descent_m
    assert flight.descent_m == 4.0 * m.run.control_period_s
    assert station.heights.max_climb_m == flight.max_climb_m == 5.0
    assert (station.alt_agl_m, station.crew_antenna_agl_m, station.base_antenna_agl_m) == (
        world.alt_agl_m,
        world.crew_antenna_agl_m,
        world.base_antenna_agl_m,
    )
    # the same answer for the same tick: altitudes per drone under the ceiling
    rng = np.random.default_rng(3)
    n = 12
    pos = rng.uniform(-80.0, 80.0, size=(n, 2))
    ground = control.terrain.terrain.height_m(pos)
    tick = TickInput(
        0,
        pos,
        np.ones(n, bool),
        np.ones(n, bool),
        np.array([[-150.0, 375.0], [250.0, 680.0]]),
        alt_amsl_m=ground + 100.0,
    )
    a, b = station.plan(tick), world.plan(tick)
    np.testing.assert_allclose(a.disp_m, b.disp_m)
    assert a.alt_agl_m is not None and b.alt_agl_m is not None
    np.testing.assert_allclose(a.alt_agl_m, b.alt_agl_m)
    assert (a.alt_agl_m <= 120.0).all() and (a.alt_agl_m >= 15.0).all()


def test_a_disc_mission_keeps_its_plain_planner():
    m = load_mission(example_path("wildfire"))
    control = control_config(m, over_terrain=True)
    assert control.terrain is None  # the disc radio: a flat earth
    problem = m.problem_config()
    plain = station_planner(
        m, m.planner.method, problem, m.planner.run_params(), np.random.default_rng(1), None
    )
    assert not isinstance(plain, TerrainAwarePlanner)

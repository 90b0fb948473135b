"""vehicle_emu.world over terrain: terrain following keeps its clearance, flat flight crashes."""

from __future__ import annotations

import dataclasses

import numpy as np

from planner.problem import ProblemConfig
from planner.terrain import (
    Canyon,
    LinkBudget,
    Ridge,
    TerrainRadio,
    path_agl_m,
    path_clearance_m,
    synthetic_terrain,
)
from vehicle_emu.world import TerrainFlight, World


def _world(mode: str, n: int = 30, seed: int = 0) -> World:
    ground = synthetic_terrain([Ridge([(0.0, -900.0), (0.0, 900.0)], 120.0, 60.0)], 900.0, 10.0)
    rng = np.random.default_rng(seed)
    pos = np.column_stack([rng.uniform(-300.0, -100.0, n), rng.uniform(-200.0, 200.0, n)])
    track = np.zeros((2, 1, 2))
    problem = ProblemConfig(n_drones=n, n_tasks=1, max_speed_m_s=10.0)
    w = World(problem, pos, np.ones(n, bool), track)
    flight = TerrainFlight(
        TerrainRadio(ground, LinkBudget()),
        mode=mode,
        alt_agl_m=40.0,
        flat_alt_amsl_m=60.0,
        clearance_m=15.0,
        max_climb_m=3.0,
        ceiling_agl_m=120.0,
    )
    return w.with_terrain(flight)


def _fly_north(w: World, steps: int) -> float:
    """Every drone heads north over the ridge at full speed; the least clearance seen."""
    least = np.inf
    n = len(w.pos_m)
    for _ in range(steps):  # loop over time
        before, alt0 = w.pos_m, w.alt_amsl_m
        assert alt0 is not None
        disp = np.tile([10.0, 0.0], (n, 1))
        w.step(disp, np.ones(n, bool), 0.0, np.ones(n))
        w.fly_terrain(before)
        assert w.alt_amsl_m is not None
        live = w.alive
        if live.any():
            c = path_clearance_m(
                w.terrain.radio.terrain,  # type: ignore[union-attr]
                before[live],
                w.pos_m[live],
                alt0[live],
                w.alt_amsl_m[live],
                n_samples=128,
            )
            least = min(least, float(c.min()))
    return least


def test_terrain_following_never_goes_below_its_clearance():
    w = _world("follow")
    least = _fly_north(w, 60)
    assert w.terrain_crashes == 0 and w.alive.all()
    assert least >= 15.0
    assert (w.pos_m[:, 0] > 0).all()  # they did cross the ridge, slowed by the climb


def test_flat_flight_into_a_ridge_is_a_crash():
    w = _world("flat")
    _fly_north(w, 60)
    assert w.terrain_crashes == len(w.pos_m)  # 60 m AMSL into a 120 m ridge: every drone
    assert not w.alive.any()


def test_terrain_following_holds_each_drones_own_height():
    """A planner's per-drone heights above the ground (PlanOutput.alt_agl_m) are flown, kept
    within [clearance + margin, ceiling], one climb step at a time."""
    w = _world("follow", n=4)
    ground = w.terrain.radio.terrain  # type: ignore[union-attr]
    want = np.array([20.0, 60.0, 500.0, 0.0])  # the last two outside the band: clipped
    for _ in range(40):  # loop over time: long enough to reach every height at 3 m per step
        before = w.pos_m
        w.step(np.zeros((4, 2)), np.ones(4, bool), 0.0, np.ones(4))
        w.fly_terrain(before, alt_agl_m=want)
    assert w.alt_amsl_m is not None
    agl = w.alt_amsl_m - ground.height_m(w.pos_m)
    np.testing.assert_allclose(agl, [20.0, 60.0, 119.0, 16.0], atol=1e-9)  # the margins: 1 m


def test_terrain_following_descends_at_the_descent_rate_and_climbs_at_the_climb_rate():
    """``max_descent_m`` limits each step down, ``max_climb_m`` each step up (the station limits
    descents to the vehicles' descent speed, docs/terrain.md §6.2); without it, descents are
    limited by the climb."""
    w = _world("follow", n=2)
    w.terrain = dataclasses.replace(w.terrain, max_descent_m=1.5)  # type: ignore[arg-type]
    ground = w.terrain.radio.terrain
    alt0 = w.alt_amsl_m.copy()  # type: ignore[union-attr]
    before = w.pos_m
    w.step(np.zeros((2, 2)), np.ones(2, bool), 0.0, np.ones(2))
    w.fly_terrain(before, alt_agl_m=np.array([20.0, 100.0]))  # from 40 m: down 20, up 60
    np.testing.assert_allclose(w.alt_amsl_m - alt0, [-1.5, 3.0])  # type: ignore[operator]
    assert w.terrain.descent_m == 1.5
    assert dataclasses.replace(w.terrain, max_descent_m=None).descent_m == 3.0
    assert (w.alt_amsl_m - ground.height_m(w.pos_m) > 15.0).all()  # type: ignore[operator]


def test_terrain_following_never_passes_over_the_ceiling_along_a_step():
    """A step that starts and ends over the rims of a narrow slot 80 m deep but passes over its
    floor would fly 180 m above the floor: it is shortened, although both its ends are under the
    ceiling (the ceiling holds along the whole flight, not only at its end)."""
    ground = synthetic_terrain([Canyon([(-900.0, 0.0), (900.0, 0.0)], 80.0, 10.0, 12.0)], 300, 2)
    problem = ProblemConfig(n_drones=1, n_tasks=1, max_speed_m_s=40.0)
    w = World(problem, np.array([[0.0, -20.0]]), np.ones(1, bool), np.zeros((2, 1, 2)))
    flight = TerrainFlight(
        TerrainRadio(ground, LinkBudget()),
        alt_agl_m=100.0,
        clearance_m=15.0,
        max_climb_m=5.0,
        max_descent_m=4.0,
        ceiling_agl_m=120.0,
    )
    w.with_terrain(flight)
    before, alt0 = w.pos_m.copy(), w.alt_amsl_m.copy()  # type: ignore[union-attr]
    w.step(np.array([[0.0, 40.0]]), np.ones(1, bool), 0.0, np.ones(1))  # over the slot, 40 m
    w.fly_terrain(before)
    assert w.pos_m[0, 1] < -12.0  # stopped before the west rim
    agl = path_agl_m(ground, before, w.pos_m, alt0, w.alt_amsl_m, 256)  # type: ignore[arg-type]
    assert agl.max() <= 120.0
    straight = path_agl_m(ground, before, before + [[0.0, 40.0]], alt0, alt0, 256)
    assert straight.max() > 170.0 and straight[0, -1] <= 120.0  # what it was kept from

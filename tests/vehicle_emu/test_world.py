"""The paper's world model: streams, attrition, motion rules."""

import numpy as np
import pytest

from planner.problem import problem_preset
from vehicle_emu.world import World, draw_scenario, spawn_streams, walk_tasks


def test_common_random_numbers_do_not_depend_on_the_algorithm_stream():
    p = problem_preset("S", 0.01)
    a, b = spawn_streams(7), spawn_streams(7)
    b.algorithm.random(1000)  # a method that draws a lot must not shift scenario or attrition
    sa, sb = draw_scenario(p, a), draw_scenario(p, b)
    assert np.array_equal(sa.task_track_m, sb.task_track_m)
    assert np.array_equal(sa.attrition_u, sb.attrition_u)
    assert not np.array_equal(draw_scenario(p, spawn_streams(8)).task_track_m, sa.task_track_m)


def test_ring_start_and_task_field():
    p = problem_preset("M", 0.0)  # scaled: ring radius 2, noise 0.4
    s = draw_scenario(p, spawn_streams(1))
    r = np.linalg.norm(s.drone_pos0_m, axis=1)
    assert abs(np.median(r) - 2.0) < 0.3
    assert np.abs(s.task_track_m[0]).max() <= 10.0
    assert s.task_track_m.shape == (201, 20, 2) and s.attrition_u.shape == (200, 100)


@pytest.mark.parametrize("border", ["clip", "reflect"])
def test_border_policies_keep_tasks_in_the_field(rng, border):
    start = rng.uniform(-5, 5, (20, 2))
    track = walk_tasks(start, rng.normal(0, 1.0, (300, 20, 2)), 5.0, border)
    assert np.abs(track).max() <= 5.0 + 1e-12


def test_step_rules_speed_home_and_attrition():
    p = problem_preset("S", 0.5).replace(n_drones=3)
    w = World(
        p, np.array([[1.0, 0.0], [5.0, 0.0], [0.05, 0.0]]), np.ones(3, bool), np.zeros((2, 1, 2))
    )
    active = np.array([True, False, False])
    disp = np.array([[3.0, 0.0], [0.0, 3.0], [0.0, 0.0]])  # too fast; inactive row ignored
    lost = w.step(disp, active, 0.5, attrition_u=np.array([0.9, 0.9, 0.1]))
    assert lost.tolist() == [False, False, True]
    assert np.allclose(w.pos_m[0], [1.15, 0.0])  # clipped to v = 0.15
    assert np.allclose(w.pos_m[1], [4.85, 0.0])  # disconnected: straight home at v
    assert np.allclose(w.pos_m[2], [0.05, 0.0])  # lost this step: does not move
    w.step(np.zeros((3, 2)), np.zeros(3, bool), 0.0, np.ones(3))
    assert not w.alive[2]  # irreversible
    assert np.allclose(w.pos_m[2], [0.05, 0.0])


def test_home_flight_never_overshoots_the_base():
    p = problem_preset("S", 0.0).replace(n_drones=1)
    w = World(p, np.array([[0.1, 0.0]]), np.ones(1, bool), np.zeros((2, 1, 2)))
    w.step(np.zeros((1, 2)), np.zeros(1, bool), 0.0, np.ones(1))
    assert np.allclose(w.pos_m, 0.0)

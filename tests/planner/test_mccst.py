"""MCCST baseline: parameters, speed limit, assignment, spanning tree, CBF-QP, closed loop."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from planner.geometry import active_mask, neighbour_pairs, tasks_connected
from planner.mccst import (
    MccstParams,
    MccstPlanner,
    _mst_reference,
    assign_tasks,
    candidate_edges,
    collision_candidates,
    edge_slack,
    make_mccst,
    nominal_controls,
    spanning_tree_edges,
)
from planner.methods import TickInput, make_planner
from planner.problem import ProblemConfig

R = 2.0
V = 0.15
PROBLEM = ProblemConfig(n_drones=20, n_tasks=5, field_half_width_m=6.0, radio_range_m=R,
                        base_range_m=R, max_speed_m_s=V, attrition_per_step=0.0)


def _tick(pos, tasks, alive=None, problem=PROBLEM, t_step=0):
    pos = np.asarray(pos, dtype=float)
    alive = np.ones(len(pos), dtype=bool) if alive is None else np.asarray(alive, dtype=bool)
    net = active_mask(pos, alive, problem.radio_range_m, problem.base_range_m)
    return TickInput(t_step, pos, alive, net, np.asarray(tasks, dtype=float))


def _random_connected_tick(rng, n=20, m=5, spread=3.0, problem=PROBLEM):
    """A random layout whose networked set is non-trivial (grown from the base)."""
    unit = problem.length_unit_m
    pos = np.zeros((n, 2))
    for k in range(n):  # each drone within reach of an earlier one or of the base
        anchor = pos[rng.integers(k)] if k else np.zeros(2)
        pos[k] = anchor + rng.uniform(-1, 1, 2) * 0.7 * problem.radio_range_m
    pos[rng.random(n) < 0.2] += rng.uniform(-spread, spread, 2) * 3 * unit  # some strays
    tasks = rng.uniform(-spread * 2, spread * 2, (m, 2)) * unit
    return _tick(pos, tasks, problem=problem)


# ----------------------------------------------------------------------------------------------
# Parameters and factory
# ----------------------------------------------------------------------------------------------

def test_unknown_param_raises_and_lists_valid_params():
    with pytest.raises(ValueError) as err:
        make_mccst(PROBLEM, {"gama": 1.0}, np.random.default_rng(0))
    message = str(err.value)
    assert "gama" in message
    for field in dataclasses.fields(MccstParams):
        assert field.name in message


@pytest.mark.parametrize("bad", [{"assignment": "greedy"}, {"speed_bound": "cone"},
                                 {"kappa": 1.5}, {"gamma": 0.0}, {"alpha": 2.0},
                                 {"collision_neighbours": -1}])
def test_invalid_param_values_raise(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        make_mccst(PROBLEM, bad, np.random.default_rng(0))


def test_registry_builds_mccst_with_overrides():
    planner = make_planner("mccst", PROBLEM, {"gamma": 0.5, "assignment": "nearest"})
    assert isinstance(planner, MccstPlanner)
    assert planner.params == MccstParams(gamma=0.5, assignment="nearest")


# ----------------------------------------------------------------------------------------------
# Speed limit, fallback, determinism, scale
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("params", [{}, {"speed_bound": "clip"}, {"discrete_time": True},
                                    {"gamma": 50.0, "safety_radius": 1.0}])
@pytest.mark.parametrize("unit", [1.0, 10.0])
def test_speed_limit_always_respected(rng, params, unit):
    problem = PROBLEM.replace(radio_range_m=R * unit, base_range_m=R * unit,
                              max_speed_m_s=V * unit, length_unit_m=unit, dt_s=1.0)
    planner = make_mccst(problem, params, rng)
    limit = problem.max_speed_m_s * problem.dt_s
    for _ in range(15):
        tick = _random_connected_tick(rng, problem=problem)
        out = planner.plan(tick)
        speed = np.linalg.norm(out.disp_m, axis=1)
        assert np.all(speed <= limit), speed.max() - limit
        assert np.all(out.disp_m[~tick.networked] == 0.0)
        assert np.all(np.isfinite(out.disp_m))
        if tick.networked.sum() > 2:
            assert speed[tick.networked].max() > 0.5 * limit  # it does move


def test_solver_failure_falls_back_to_clipped_nominal(rng):
    tick = _random_connected_tick(rng)
    planner = make_mccst(PROBLEM, {"solver_max_iter": 1}, rng)
    out = planner.plan(tick)
    assert out.info["fallback"] is True
    assert out.info["status"] not in ("solved", "solved inaccurate")
    members = np.flatnonzero(tick.networked)
    goal = tick.task_pos_m[out.info["task_of"][members]]
    nominal = np.clip(nominal_controls(tick.pos_m[members], goal, 1.0, V), -V / np.sqrt(2),
                      V / np.sqrt(2))
    np.testing.assert_allclose(out.disp_m[members], nominal, atol=1e-12)


def test_deterministic(rng):
    tick = _random_connected_tick(rng)
    first = make_mccst(PROBLEM, {}, np.random.default_rng(1)).plan(tick)
    planner = make_mccst(PROBLEM, {}, np.random.default_rng(2))
    for _ in range(2):
        again = planner.plan(tick)
        np.testing.assert_array_equal(first.disp_m, again.disp_m)
        np.testing.assert_array_equal(first.info["tree_edges"], again.info["tree_edges"])


def test_scale_free_defaults(rng):
    """Scaling every length by 10 (the scaled reading) scales the output by 10."""
    tick = _random_connected_tick(rng)
    big = PROBLEM.replace(radio_range_m=10 * R, base_range_m=10 * R, max_speed_m_s=10 * V,
                          length_unit_m=10.0)
    small_out = make_mccst(PROBLEM, {}, rng).plan(tick)
    big_tick = dataclasses.replace(tick, pos_m=10 * tick.pos_m, task_pos_m=10 * tick.task_pos_m)
    big_out = make_mccst(big, {}, rng).plan(big_tick)
    np.testing.assert_allclose(big_out.disp_m, 10 * small_out.disp_m, atol=1e-5)


def test_empty_network_returns_zeros():
    tick = _tick([[10.0, 10.0], [12.0, 10.0]], [[5.0, 5.0]])
    out = make_mccst(PROBLEM, {}, np.random.default_rng(0)).plan(tick)
    assert not tick.networked.any()
    assert np.all(out.disp_m == 0.0) and out.info["status"] == "empty"


# ----------------------------------------------------------------------------------------------
# Assignment
# ----------------------------------------------------------------------------------------------

def _assignment_brute_force(pos, tasks):
    n, m = len(pos), len(tasks)
    capacity = -(-n // m)
    dist = np.linalg.norm(pos[:, None] - tasks[None], axis=2)
    best = np.inf
    for combo in itertools.product(range(m), repeat=n):
        if np.bincount(combo, minlength=m).max() <= capacity:
            best = min(best, dist[np.arange(n), combo].sum())
    return best


@pytest.mark.parametrize("n, m", [(5, 2), (6, 3), (7, 3), (4, 4), (3, 5)])
def test_balanced_assignment_matches_brute_force(rng, n, m):
    for _ in range(5):
        pos, tasks = rng.normal(size=(n, 2)), rng.normal(size=(m, 2)) * 2
        task_of = assign_tasks(pos, tasks, "balanced")
        cost = np.linalg.norm(pos - tasks[task_of], axis=1).sum()
        assert cost == pytest.approx(_assignment_brute_force(pos, tasks), rel=1e-12)
        assert np.bincount(task_of, minlength=m).max() <= -(-n // m)


def test_balanced_assignment_capacity_and_nearest(rng):
    for n, m in [(50, 10), (47, 10), (500, 100), (9, 10)]:
        pos, tasks = rng.uniform(-5, 5, (n, 2)), rng.uniform(-5, 5, (m, 2))
        task_of = assign_tasks(pos, tasks, "balanced")
        assert task_of.shape == (n,) and task_of.min() >= 0 and task_of.max() < m
        assert np.bincount(task_of, minlength=m).max() <= -(-n // m)
        nearest = assign_tasks(pos, tasks, "nearest")
        np.testing.assert_array_equal(
            nearest, np.argmin(np.linalg.norm(pos[:, None] - tasks[None], axis=2), axis=1))


def test_nominal_controls_saturate_and_hold():
    pos = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    goal = np.array([[3.0, 4.0], [0.05, 0.0], [0.3, 0.4]])
    u = nominal_controls(pos, goal, 1.0, V)
    np.testing.assert_allclose(u, [[0.09, 0.12], [0.05, 0.0], [0.09, 0.12]])
    held = nominal_controls(pos, goal, 1.0, V, hold=0.5)
    np.testing.assert_allclose(held, [[0.09, 0.12], [0.0, 0.0], [0.0, 0.0]])


# ----------------------------------------------------------------------------------------------
# Spanning tree
# ----------------------------------------------------------------------------------------------

def test_spanning_tree_matches_networkx(rng):
    for trial in range(40):
        n_nodes = int(rng.integers(2, 25))
        pts = rng.uniform(0, 4, (n_nodes, 2))
        edges = neighbour_pairs(pts, float(rng.uniform(1.0, 3.0)))
        weights = rng.normal(size=len(edges)) * 10.0 ** rng.integers(-3, 4)
        if trial % 4 == 0:
            weights -= weights.max() + 1.0  # all negative, as MCCST weights usually are
        got = spanning_tree_edges(n_nodes, edges, weights)
        assert {frozenset(e) for e in edges[got].tolist()} == _mst_reference(n_nodes, edges, weights)


def test_planner_tree_is_mccst_of_candidate_graph(rng):
    tick = _random_connected_tick(rng)
    params = MccstParams()
    out = make_mccst(PROBLEM, {}, rng).plan(tick)
    members = np.flatnonzero(tick.networked)
    n = len(members)
    x = np.vstack([tick.pos_m[members], np.zeros(2)])
    edges = candidate_edges(tick.pos_m[members], np.zeros(2), R, R)
    r_c = params.kappa * np.full(len(edges), R)
    task_local = out.info["task_of"][members]
    u_hat = np.vstack([nominal_controls(x[:n], tick.task_pos_m[task_local], 1.0, V), np.zeros(2)])
    delta = edge_slack(x, u_hat, edges, r_c, np.append(task_local, -1), params)
    expected = {frozenset(e) for e in _mst_reference(n + 1, edges, -delta)}
    to_local = {g: k for k, g in enumerate(members)} | {-1: n}
    got = {frozenset((to_local[a], to_local[b])) for a, b in out.info["tree_edges"].tolist()}
    assert got == expected
    assert len(got) == n and out.info["n_components"] == 1  # a spanning tree of D' + base


# ----------------------------------------------------------------------------------------------
# CBF-QP: connectivity and feasibility
# ----------------------------------------------------------------------------------------------

def _tree_lengths(pos, tree_edges):
    ends = np.where(tree_edges[:, :, None] < 0, 0.0, pos[np.maximum(tree_edges, 0)])
    return np.linalg.norm(ends[:, 0] - ends[:, 1], axis=1)


@pytest.mark.parametrize("params", [{}, {"discrete_time": True}, {"speed_bound": "clip"}])
def test_chain_kept_connected_when_nominal_pulls_away(params):
    # base -- d1 -- d2; d1's task is where d1 stands, d2's task is far to the east.
    pos = np.array([[1.5, 0.0], [3.2, 0.0]])
    tasks = np.array([[1.5, 0.0], [10.0, 0.0]])
    planner = make_mccst(PROBLEM, params, np.random.default_rng(0))
    start_d2 = pos[1].copy()
    for t_step in range(100):
        tick = _tick(pos, tasks, t_step=t_step)
        assert tick.networked.all()
        out = planner.plan(tick)
        assert not out.info["fallback"]
        pos = pos + out.disp_m
        lengths = _tree_lengths(pos, out.info["tree_edges"])
        assert len(lengths) == 2 and np.all(lengths <= R), lengths
    np.testing.assert_array_equal(out.info["task_of"], [0, 1])
    assert active_mask(pos, np.ones(2, bool), R, R).all()
    assert pos[1, 0] > start_d2[0] + 0.2                    # d2 moved towards its task...
    assert np.linalg.norm(pos[1]) <= 2 * R                   # ...but was held by the tree,
    assert np.linalg.norm(pos[1] - pos[0]) > 0.85 * R        # which is taut at r_c = 0.9 r
    assert np.linalg.norm(pos[0]) > 1.5                      # and d1 was dragged along


def test_qp_feasible_right_after_relay_loss():
    # A chain along the east axis whose links become 1.99 long (> r_c = 1.8) once the relays die.
    # Holding all three barriers would need d3 to close at 3 * 0.094 per tick > v / sqrt(2):
    # infeasible without slacks.
    chain = np.array([[1.99, 0.0], [3.98, 0.0], [5.97, 0.0]])
    relays = np.array([[1.0, 0.3], [3.0, 0.3], [5.0, 0.3]])
    pos = np.vstack([chain, relays])
    tasks = np.array([[8.0, 0.0]])
    planner = make_mccst(PROBLEM, {}, np.random.default_rng(0))
    before = planner.plan(_tick(pos, tasks))
    assert not before.info["fallback"] and before.info["max_tree_slack"] < 1e-3
    alive = np.array([True, True, True, False, False, False])
    tick = _tick(pos, tasks, alive=alive)
    np.testing.assert_array_equal(tick.networked, alive)
    out = planner.plan(tick)
    assert out.info["status"] == "solved" and not out.info["fallback"]
    assert out.info["max_tree_slack"] > 1e-3                  # some barrier had to give
    assert np.all(np.linalg.norm(out.disp_m, axis=1) <= V)
    assert np.all(out.disp_m[:3, 0] < 0)                      # everyone pulls back to the base
    assert np.all(out.disp_m[3:] == 0.0)


def test_collision_candidates_cap(rng):
    x = rng.uniform(0, 1.5, (60, 2))
    reach = 0.8
    every = collision_candidates(x, reach, 0)
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    i, j = np.nonzero(np.triu(d < reach, k=1))
    np.testing.assert_array_equal(every, np.column_stack([i, j]))
    capped = collision_candidates(x, reach, 4)
    assert len(capped) <= 4 * len(x)
    assert {tuple(p) for p in capped.tolist()} <= {tuple(p) for p in every.tolist()}
    nearest = np.argsort(d + np.eye(len(x)) * 1e9, axis=1)[:, 0]  # each drone's nearest is kept
    kept = {tuple(sorted(p)) for p in zip(range(len(x)), nearest.tolist())}
    assert kept <= {tuple(p) for p in capped.tolist()}


# ----------------------------------------------------------------------------------------------
# Closed loop without attrition
# ----------------------------------------------------------------------------------------------

def test_closed_loop_keeps_network_and_reaches_a_task():
    rng = np.random.default_rng(7)
    n, m = PROBLEM.n_drones, PROBLEM.n_tasks
    angles = 2 * np.pi * np.arange(n) / n
    pos = np.column_stack([np.cos(angles), np.sin(angles)]) + rng.normal(0, 0.2, (n, 2))
    task_angles = rng.uniform(0, 2 * np.pi, m)
    tasks = 6.0 * np.column_stack([np.cos(task_angles), np.sin(task_angles)])
    alive = np.ones(n, dtype=bool)
    planner = make_mccst(PROBLEM, {}, rng)
    networked = active_mask(pos, alive, R, R)
    assert networked.all()
    for t_step in range(200):
        tick = TickInput(t_step, pos, alive, networked, tasks)
        out = planner.plan(tick)
        assert not out.info["fallback"]
        disp = out.disp_m.copy()
        home = ~networked  # RTNUA default: straight to the base at v
        dist = np.linalg.norm(pos[home], axis=1, keepdims=True)
        disp[home] = -pos[home] / np.maximum(dist, 1e-12) * np.minimum(V, dist)
        pos = pos + disp
        now = active_mask(pos, alive, R, R)
        assert np.all(now[networked]), f"step {t_step}: lost {np.flatnonzero(networked & ~now)}"
        networked = now
    assert tasks_connected(tasks, pos, networked, R).sum() >= 1

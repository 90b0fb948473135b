"""MCCST baseline: parameters, speed limit, assignment, spanning tree, CBF-QP, closed loop."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from planner import _graph_kernels, _kernels
from planner.geometry import active_mask, neighbour_candidates, neighbour_pairs, tasks_connected
from planner.mccst import (
    BALANCED_PARAMS,
    STRONG_PARAMS,
    MccstParams,
    MccstPlanner,
    _argsort_stable,
    _barrier_rows,
    _capped_class_k,
    _class_k,
    _clip_norm,
    _clip_norm_reference,
    _constraint_matrix,
    _constraint_matrix_reference,
    _csc,
    _mst_reference,
    _qp_objective,
    assign_tasks,
    candidate_edges,
    collision_candidates,
    edge_slack,
    make_mccst,
    nominal_controls,
    solve_cbf_qp,
    spanning_tree_edges,
)
from planner.methods import TickInput, make_planner
from planner.problem import ProblemConfig

R = 2.0
V = 0.15
PROBLEM = ProblemConfig(
    n_drones=20,
    n_tasks=5,
    field_half_width_m=6.0,
    radio_range_m=R,
    base_range_m=R,
    max_speed_m_s=V,
    attrition_per_step=0.0,
)


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


def _expected_nominal(tick, task_of, params):
    """u_hat of the networked drones from the planner's reported tasks (-1: hold position)."""
    members = np.flatnonzero(tick.networked)
    task_local = task_of[members]
    goal = np.where(
        task_local[:, None] >= 0, tick.task_pos_m[np.maximum(task_local, 0)], tick.pos_m[members]
    )
    speed = V if params.saturate_nominal else np.inf
    return nominal_controls(tick.pos_m[members], goal, params.k_p, speed, params.hold_distance)


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


@pytest.mark.parametrize(
    "bad",
    [
        {"assignment": "greedy"},
        {"speed_bound": "cone"},
        {"kappa": 1.5},
        {"gamma": 0.0},
        {"alpha": 2.0},
        {"collision_neighbours": -1},
        {"task_capacity": -1},
        {"reassign_period": -1},
        {"reassign_period": 0.5},
    ],
)
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


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"speed_bound": "clip"},
        {"discrete_time": True},
        {"gamma": 50.0, "safety_radius": 1.0},
        BALANCED_PARAMS,
        STRONG_PARAMS,
        {"speed_bound": "none", "saturate_nominal": False},
    ],
)
@pytest.mark.parametrize("unit", [1.0, 10.0])
def test_speed_limit_always_respected(rng, params, unit):
    problem = PROBLEM.replace(
        radio_range_m=R * unit,
        base_range_m=R * unit,
        max_speed_m_s=V * unit,
        length_unit_m=unit,
        dt_s=1.0,
    )
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


@pytest.mark.parametrize("solver", ["piqp", "osqp"])
def test_solver_failure_falls_back_to_clipped_nominal(rng, solver):
    tick = _random_connected_tick(rng)
    planner = make_mccst(PROBLEM, {"solver_max_iter": 1, "solver": solver}, rng)
    out = planner.plan(tick)
    assert out.info["fallback"] is True
    assert out.info["status"] not in ("solved", "solved inaccurate")
    members = np.flatnonzero(tick.networked)
    nominal = np.clip(
        _expected_nominal(tick, out.info["task_of"], planner.params),
        -V / np.sqrt(2),
        V / np.sqrt(2),
    )
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
    big = PROBLEM.replace(
        radio_range_m=10 * R, base_range_m=10 * R, max_speed_m_s=10 * V, length_unit_m=10.0
    )
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
            nearest, np.argmin(np.linalg.norm(pos[:, None] - tasks[None], axis=2), axis=1)
        )


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
        assert {frozenset(e) for e in edges[got].tolist()} == _mst_reference(
            n_nodes, edges, weights
        )


@pytest.mark.parametrize("overrides", [{}, BALANCED_PARAMS, STRONG_PARAMS])
def test_planner_tree_is_mccst_of_candidate_graph(rng, overrides):
    tick = _random_connected_tick(rng)
    params = MccstParams(**overrides)
    out = make_mccst(PROBLEM, overrides, rng).plan(tick)
    members = np.flatnonzero(tick.networked)
    n = len(members)
    x = np.vstack([tick.pos_m[members], np.zeros(2)])
    edges = candidate_edges(tick.pos_m[members], np.zeros(2), R, R)
    r_c = params.kappa * np.full(len(edges), R)
    task_local = out.info["task_of"][members]
    u_hat = np.vstack([_expected_nominal(tick, out.info["task_of"], params), np.zeros(2)])
    subgroup = np.append(np.where(task_local >= 0, task_local, -2), -1)
    delta = edge_slack(x, u_hat, edges, r_c, subgroup, params)
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


@pytest.mark.parametrize(
    "params", [{}, {"discrete_time": True}, {"speed_bound": "clip"}, {"reassign_period": 0}]
)
def test_chain_kept_connected_when_nominal_pulls_away(params):
    # base -- d1 -- d2; d1's task is where d1 stands, d2's task is far to the east. The tree
    # guarantee of the module docstring needs gamma <= 1 and kappa = 0.9 (BALANCED_PARAMS); the
    # calibrated default (gamma = 1e4, kappa = 0.95) trades it away on purpose.
    pos = np.array([[1.5, 0.0], [3.2, 0.0]])
    tasks = np.array([[1.5, 0.0], [10.0, 0.0]])
    planner = make_mccst(PROBLEM, {**BALANCED_PARAMS, **params}, np.random.default_rng(0))
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
    assert pos[1, 0] > start_d2[0] + 0.2  # d2 moved towards its task...
    assert np.linalg.norm(pos[1]) <= 2 * R  # ...but was held by the tree,
    assert np.linalg.norm(pos[1] - pos[0]) > 0.85 * R  # which is taut at r_c = 0.9 r
    assert np.linalg.norm(pos[0]) > 1.5  # and d1 was dragged along


def test_qp_feasible_right_after_relay_loss():
    # A chain along the east axis whose links become 1.99 long (> r_c = 1.8) once the relays die.
    # Holding all three barriers would need d3 to close at 3 * 0.094 per tick > v / sqrt(2):
    # infeasible without slacks.
    chain = np.array([[1.99, 0.0], [3.98, 0.0], [5.97, 0.0]])
    relays = np.array([[1.0, 0.3], [3.0, 0.3], [5.0, 0.3]])
    pos = np.vstack([chain, relays])
    tasks = np.array([[8.0, 0.0]])
    planner = make_mccst(PROBLEM, BALANCED_PARAMS, np.random.default_rng(0))
    before = planner.plan(_tick(pos, tasks))
    assert not before.info["fallback"] and before.info["max_tree_slack"] < 1e-3
    alive = np.array([True, True, True, False, False, False])
    tick = _tick(pos, tasks, alive=alive)
    np.testing.assert_array_equal(tick.networked, alive)
    out = planner.plan(tick)
    assert out.info["status"] == "solved" and not out.info["fallback"]
    assert out.info["max_tree_slack"] > 1e-3  # some barrier had to give
    assert np.all(np.linalg.norm(out.disp_m, axis=1) <= V)
    assert np.all(out.disp_m[:3, 0] < 0)  # everyone pulls back to the base
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


@pytest.mark.parametrize("params", [BALANCED_PARAMS, STRONG_PARAMS])
def test_closed_loop_keeps_network_and_reaches_a_task(params):
    rng = np.random.default_rng(7)
    n, m = PROBLEM.n_drones, PROBLEM.n_tasks
    angles = 2 * np.pi * np.arange(n) / n
    pos = np.column_stack([np.cos(angles), np.sin(angles)]) + rng.normal(0, 0.2, (n, 2))
    task_angles = rng.uniform(0, 2 * np.pi, m)
    tasks = 6.0 * np.column_stack([np.cos(task_angles), np.sin(task_angles)])
    alive = np.ones(n, dtype=bool)
    planner = make_mccst(PROBLEM, params, rng)
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


# ----------------------------------------------------------------------------------------------
# Pre-tasking: capacity, static assignment, tasks lost on disconnection (calibration knobs)
# ----------------------------------------------------------------------------------------------


def _capacity_brute_force(pos, tasks, k):
    n, m = len(pos), len(tasks)
    dist = np.linalg.norm(pos[:, None] - tasks[None], axis=2)
    best = np.inf
    for combo in itertools.product(range(-1, m), repeat=n):
        combo = np.array(combo)
        counts = np.bincount(combo[combo >= 0], minlength=m)
        if counts.max() <= k and counts.sum() == min(n, k * m):
            best = min(best, dist[np.flatnonzero(combo >= 0), combo[combo >= 0]].sum())
    return best


@pytest.mark.parametrize("n, m, k", [(5, 2, 1), (5, 2, 2), (6, 3, 1), (4, 3, 2)])
def test_capacity_assignment_matches_brute_force(rng, n, m, k):
    for _ in range(3):
        pos, tasks = rng.normal(size=(n, 2)), rng.normal(size=(m, 2)) * 2
        task_of = assign_tasks(pos, tasks, "balanced", k)
        tasked = task_of >= 0
        assert tasked.sum() == min(n, k * m)
        assert np.bincount(task_of[tasked], minlength=m).max() <= k
        cost = np.linalg.norm(pos[tasked] - tasks[task_of[tasked]], axis=1).sum()
        assert cost == pytest.approx(_capacity_brute_force(pos, tasks, k), rel=1e-12)


def test_untasked_drones_hold_position():
    # One task, capacity 1: the drone nearest to it goes, the other two hold (no barrier binds).
    pos = np.array([[0.5, 0.0], [0.0, 0.5], [-0.5, 0.0]])
    tasks = np.array([[5.0, 0.0]])
    for period in (0, 1):
        planner = make_mccst(
            PROBLEM, {"task_capacity": 1, "reassign_period": period}, np.random.default_rng(0)
        )
        out = planner.plan(_tick(pos, tasks))
        np.testing.assert_array_equal(out.info["task_of"], [0, -1, -1])
        assert out.disp_m[0, 0] > 0.5 * V / np.sqrt(2)
        assert np.abs(out.disp_m[1:]).max() < 1e-3


def _reversed_tasks(tick, t_step):
    return dataclasses.replace(tick, t_step=t_step, task_pos_m=tick.task_pos_m[::-1].copy())


def test_static_assignment_is_kept_until_a_new_run(rng):
    tick = _random_connected_tick(rng)
    members = np.flatnonzero(tick.networked)
    planner = make_mccst(PROBLEM, {"reassign_period": 0, "task_capacity": 0}, rng)
    first = planner.plan(tick).info["task_of"]
    per_tick = make_mccst(PROBLEM, {"reassign_period": 1, "task_capacity": 0}, rng)
    moved = _reversed_tasks(tick, 1)
    resolved = per_tick.plan(moved).info["task_of"]
    assert np.any(resolved[members] != first[members])  # a per-tick solve would change it
    for t_step in (1, 2, 5):
        np.testing.assert_array_equal(
            planner.plan(_reversed_tasks(tick, t_step)).info["task_of"], first
        )
    # A lost drone gives up its task; the others keep theirs.
    alive = tick.alive.copy()
    alive[members[0]] = False
    lost = dataclasses.replace(
        _reversed_tasks(tick, 6), alive=alive, networked=active_mask(tick.pos_m, alive, R, R)
    )
    task_of = planner.plan(lost).info["task_of"]
    keep = np.flatnonzero(lost.networked)
    assert task_of[members[0]] == -1
    np.testing.assert_array_equal(task_of[keep], first[keep])
    # t_step 0 starts a new run: solved again over every alive drone, on the reversed tasks.
    again = planner.plan(_reversed_tasks(tick, 0)).info["task_of"]
    expected = assign_tasks(tick.pos_m, tick.task_pos_m[::-1], "balanced")
    np.testing.assert_array_equal(again[members], expected[members])


def test_reassign_period_resolves_every_k_ticks(rng):
    tick = _random_connected_tick(rng)
    planner = make_mccst(PROBLEM, {"reassign_period": 3, "task_capacity": 0}, rng)
    per_tick = make_mccst(PROBLEM, {"reassign_period": 1, "task_capacity": 0}, rng)
    first = planner.plan(tick).info["task_of"]
    for t_step in (1, 2):
        np.testing.assert_array_equal(
            planner.plan(_reversed_tasks(tick, t_step)).info["task_of"], first
        )
    np.testing.assert_array_equal(
        planner.plan(_reversed_tasks(tick, 3)).info["task_of"],
        per_tick.plan(_reversed_tasks(tick, 3)).info["task_of"],
    )


@pytest.mark.parametrize("keep", [True, False])
def test_task_after_leaving_and_rejoining_the_network(keep):
    tasks = np.array([[6.0, 0.0], [0.0, 6.0]])
    pos = np.array([[1.0, 0.0], [2.5, 0.0], [0.0, 1.0]])
    planner = make_mccst(
        PROBLEM,
        {"reassign_period": 0, "task_capacity": 0, "keep_task_when_disconnected": keep},
        np.random.default_rng(0),
    )
    task = planner.plan(_tick(pos, tasks, t_step=0)).info["task_of"][1]
    assert task >= 0
    away = pos.copy()
    away[1] = [9.0, 9.0]
    gone = planner.plan(_tick(away, tasks, t_step=1))
    assert gone.info["task_of"][1] == -1 and np.all(gone.disp_m[1] == 0.0)
    back = planner.plan(_tick(pos, tasks, t_step=2))
    assert back.info["task_of"][1] == (task if keep else -1)
    if not keep:
        assert np.abs(back.disp_m[1]).max() < 1e-3  # an untasked relay holds position


def test_named_variants_are_valid_and_differ_from_the_default():
    default = MccstParams()
    for overrides in (BALANCED_PARAMS, STRONG_PARAMS):
        variant = MccstParams.from_dict(overrides)
        assert variant != default
        assert variant.reassign_period == 1 and variant.gamma == 1.0 and variant.kappa == 0.9


def test_carried_rho_starts_cold_at_a_run_start_and_solves(rng):
    """carry_rho starts tick t's ADMM at tick t-1's adapted rho. A run's first tick (and a repeated
    t_step, i.e. a new run) starts at OSQP's default exactly like ``carry_rho=False``; later ticks
    are solved to the same tolerance from another starting step size (so they may return another
    point of the tolerance set: eps = 1e-4 residuals leave this QP's controls ~0.05 from the exact
    optimum whichever rho is used)."""
    tick0 = _random_connected_tick(rng)
    carry = make_mccst(PROBLEM, {"solver": "osqp"}, rng)
    cold = make_mccst(PROBLEM, {"solver": "osqp", "carry_rho": False}, rng)
    first_c, first_k = carry.plan(tick0), cold.plan(tick0)
    np.testing.assert_array_equal(first_c.disp_m, first_k.disp_m)  # t_step 0: no carried rho
    assert carry._rho is not None and carry._rho != 0.1
    tick1 = _tick(tick0.pos_m + first_c.disp_m, tick0.task_pos_m, t_step=1)
    out_c, out_k = carry.plan(tick1), cold.plan(tick1)
    assert out_c.info["status"] == out_k.info["status"] == "solved"
    assert np.all(np.abs(out_c.disp_m) <= V / np.sqrt(2) + 1e-12)
    again = carry.plan(tick1)  # same t_step: a new run
    np.testing.assert_array_equal(again.disp_m, out_k.disp_m)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_direct_csc_constraint_matrix_equals_coo_reference(seed):
    """The QP's constraint matrix is assembled straight into CSC; it must equal, entry for entry
    (same indptr, sorted row indices and values), the COO-built reference, with and without base
    ends, slacks and empty barrier sets."""
    rng = np.random.default_rng(seed)
    n = 30
    for n_rows in (0, 1, 40, 200):
        i = rng.integers(0, n, n_rows)
        j = (i + 1 + rng.integers(0, n, n_rows)) % (n + 1)  # may be the base (== n)
        j = np.where(j == i, n, j)
        coef = rng.normal(size=(n_rows, 2))
        slack_rows = np.flatnonzero(rng.random(n_rows) < 0.3)
        fast = _constraint_matrix(i, j, coef, slack_rows, n)
        ref = _constraint_matrix_reference(i, j, coef, slack_rows, n)
        ref.sort_indices()
        assert fast.shape == ref.shape
        assert fast.has_sorted_indices
        np.testing.assert_array_equal(fast.indptr, ref.indptr)
        np.testing.assert_array_equal(fast.indices, ref.indices)
        np.testing.assert_array_equal(fast.data, ref.data)
        # PIQP's form: the barrier rows only, the same entries as the full matrix's first rows
        barrier = _constraint_matrix(i, j, coef, slack_rows, n, bound_rows=False)
        top = ref[:n_rows]
        top.sort_indices()
        assert barrier.shape == top.shape
        np.testing.assert_array_equal(barrier.indptr, top.indptr)
        np.testing.assert_array_equal(barrier.indices, top.indices)
        np.testing.assert_array_equal(barrier.data, top.data)


def test_unchecked_csc_is_the_checked_one():
    """``_csc`` (no constructor checks) gives scipy's checked matrix: same arrays, shape, type,
    products; arrays that are not of the expected dtypes go through the checked constructor."""
    from scipy.sparse import csc_matrix

    rng = np.random.default_rng(0)
    dense = np.where(rng.random((7, 5)) < 0.4, rng.normal(size=(7, 5)), 0.0)
    ref = csc_matrix(dense)
    ref.sort_indices()
    data, indices, indptr = ref.data, ref.indices.astype(np.int32), ref.indptr.astype(np.int32)
    fast = _csc(data, indices, indptr, (7, 5))
    assert type(fast) is csc_matrix and fast.shape == (7, 5) and fast.nnz == ref.nnz
    np.testing.assert_array_equal(fast.toarray(), dense)
    np.testing.assert_array_equal((fast.T @ fast).toarray(), (ref.T @ ref).toarray())
    checked = csc_matrix((data, indices, indptr), shape=(7, 5))
    for name in ("data", "indices", "indptr"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(checked, name))
        assert getattr(fast, name).dtype == getattr(checked, name).dtype
    wide = _csc(data, indices.astype(np.int64), indptr.astype(np.int64), (7, 5))
    np.testing.assert_array_equal(wide.toarray(), dense)


@pytest.mark.parametrize("discrete_time", [False, True])
def test_capped_class_k_is_the_plain_minimum(discrete_time):
    """The QP's right sides: the class-K function evaluated only where it may be below the cap
    equals, bit for bit, the minimum of the function over every row (negative, tiny, huge and
    non-finite h; caps of every size)."""
    rng = np.random.default_rng(1)
    params = MccstParams(discrete_time=discrete_time)
    for trial in range(200):
        n = int(rng.integers(0, 400))
        h = rng.normal(size=n) * 10.0 ** rng.integers(-4, 3)
        if trial % 10 == 0 and n > 3:
            h[:3] = [np.inf, -np.inf, np.nan]
        cap = rng.uniform(0, 2, n) * 10.0 ** rng.integers(-3, 3) + 1e-3
        with np.errstate(over="ignore", invalid="ignore"):
            want = np.minimum(_class_k(h, params), cap)
            got = _capped_class_k(h, cap, params)
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", [0, 1])
def test_fast_argsort_equals_stable_argsort(seed):
    """The MST's rank sort takes numpy's default sort when no ties exist and the stable one
    otherwise: the permutation must equal ``kind='stable'`` in both cases."""
    rng = np.random.default_rng(seed)
    distinct = rng.normal(size=5000)
    tied = np.round(rng.normal(size=5000), 1)  # many equal values
    for values in (distinct, tied, np.zeros(0), np.ones(1), np.array([2.0, 1.0, 2.0, 1.0])):
        np.testing.assert_array_equal(_argsort_stable(values), np.argsort(values, kind="stable"))


def _random_qp(rng, n=12, n_tree=10, n_col=8):
    """A CBF-QP instance like the planner's: tree edges (some to the base, node n), near pairs,
    some barriers violated (slacked), some capped (never active)."""
    x = np.vstack([rng.uniform(-1.5, 1.5, (n, 2)), np.zeros((1, 2))])
    u_hat = rng.uniform(-0.2, 0.2, (n, 2))
    tree = np.column_stack([rng.integers(0, n, n_tree), rng.integers(0, n + 1, n_tree)])
    tree = tree[tree[:, 0] != tree[:, 1]]
    d = np.linalg.norm(x[tree[:, 0]] - x[tree[:, 1]], axis=1)
    r_c = d * rng.uniform(0.97, 1.3, len(d))  # some violated, some with margin
    col = np.column_stack([rng.integers(0, n, n_col), rng.integers(0, n, n_col)])
    col = col[col[:, 0] < col[:, 1]]
    return x, u_hat, tree, r_c, col


def _qp_reference(x, u_hat, tree, r_c, col, box, params):
    """The same CBF-QP written out row by row and solved by scipy's SLSQP over every row (no
    pruning), slow and independent of both solver paths."""
    from scipy.optimize import minimize

    n = len(u_hat)
    rows = [
        (int(a), int(b), 1.0, params.gamma * (rc**2 - np.sum((x[a] - x[b]) ** 2)) ** 3, True)
        for (a, b), rc in zip(tree, r_c)
    ]
    rows += [
        (
            int(a),
            int(b),
            -1.0,
            params.gamma * (np.sum((x[a] - x[b]) ** 2) - params.safety_radius**2) ** 3,
            False,
        )
        for a, b in col
    ]
    slacked = [k for k, row in enumerate(rows) if row[3] < 0]
    pen = np.array(
        [params.slack_penalty if rows[k][4] else params.collision_slack_penalty for k in slacked]
    )

    def lhs(z, k):
        a, b, sign, _, _ = rows[k]
        u = z[: 2 * n].reshape(n, 2)
        ub = u[b] if b < n else np.zeros(2)
        return 2 * sign * (x[a] - x[b]) @ (u[a] - ub)

    def cons(z):
        s = np.zeros(len(rows))
        s[slacked] = z[2 * n :]
        return np.array([rows[k][3] + s[k] - lhs(z, k) for k in range(len(rows))])

    def cost(z):
        return np.sum((z[: 2 * n] - u_hat.ravel()) ** 2) + np.sum(pen * z[2 * n :] ** 2)

    z0 = np.concatenate([np.zeros(2 * n), [-rows[k][3] for k in slacked]])  # feasible start
    bounds = [(-box, box)] * (2 * n) + [(0, None)] * len(slacked)
    res = minimize(
        cost,
        z0,
        method="SLSQP",
        bounds=bounds,
        constraints=[{"type": "ineq", "fun": cons}],
        options={"ftol": 1e-14, "maxiter": 2000},
    )
    assert res.success, res.message
    return res.x[: 2 * n].reshape(n, 2)


@pytest.mark.parametrize("seed", range(6))
def test_piqp_optimum_equals_a_slow_reference_solve(seed):
    """PIQP drops the rows that cannot bind inside the box; the reference keeps every row. Both
    must land on the same optimum (unique: the objective is strictly convex). OSQP at its default
    tolerance is only near it (the reason PIQP is the default)."""
    rng = np.random.default_rng(seed)
    x, u_hat, tree, r_c, col = _random_qp(rng)
    params = MccstParams(gamma=1.0, solver_eps=1e-9)
    box = V / np.sqrt(2)
    got = solve_cbf_qp(x, u_hat, tree, r_c, col, box, params)
    assert got.used_solution and got.status == "solved"
    assert np.all(np.abs(got.u) <= box)
    ref = _qp_reference(x, u_hat, tree, r_c, col, box, params)
    np.testing.assert_allclose(got.u, ref, atol=1e-5)
    osqp_u = solve_cbf_qp(
        x, u_hat, tree, r_c, col, box, dataclasses.replace(params, solver="osqp", solver_eps=1e-4)
    ).u
    assert np.abs(osqp_u - ref).max() < 0.05


def test_piqp_optimum_satisfies_kkt_by_brute_force():
    """Against an obviously-correct reference: for a 2-drone QP, the optimum over a fine grid of
    controls (slacks solved in closed form) is within the grid step of PIQP's."""
    x = np.array([[1.0, 0.0], [2.6, 0.0], [0.0, 0.0]])  # base at the origin
    u_hat = np.array([[0.1, 0.05], [0.1, -0.05]])  # both pulled away east
    tree = np.array([[0, 2], [1, 0]])
    r_c = np.array([1.05, 1.5])  # 1-0 violated, 0-base tight
    params = MccstParams(gamma=1.0, solver_eps=1e-9)
    box = V / np.sqrt(2)
    got = solve_cbf_qp(x, u_hat, tree, r_c, np.zeros((0, 2), dtype=int), box, params)
    grid = np.linspace(-box, box, 41)
    u0x, u0y, u1x, u1y = np.meshgrid(grid, grid, grid, grid, indexing="ij")
    u = np.stack([u0x, u0y, u1x, u1y], axis=-1).reshape(-1, 2, 2)
    diff = x[tree[:, 0]] - x[tree[:, 1]]
    rhs = params.gamma * (r_c**2 - (diff**2).sum(1)) ** 3
    lhs0 = 2 * (diff[0] * u[:, 0]).sum(-1)  # base end: u_0 only
    lhs1 = 2 * (diff[1] * (u[:, 1] - u[:, 0])).sum(-1)
    slack0 = np.maximum(lhs0 - rhs[0], 0.0) if rhs[0] < 0 else np.where(lhs0 <= rhs[0], 0.0, np.inf)
    slack1 = np.maximum(lhs1 - rhs[1], 0.0) if rhs[1] < 0 else np.where(lhs1 <= rhs[1], 0.0, np.inf)
    cost = ((u - u_hat) ** 2).sum((1, 2)) + params.slack_penalty * (slack0**2 + slack1**2)
    best = u[np.argmin(cost)]
    assert np.isfinite(cost.min())
    np.testing.assert_allclose(got.u, best, atol=grid[1] - grid[0])


@pytest.mark.skipif(not _kernels.NUMBA, reason="Numba missing")
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_qp_rows_and_barrier_matrix_are_the_numpy_ones(seed):
    """The compiled QP assembly (rows, capped right sides, pruned PIQP matrix) equals, array for
    array and bit for bit, the NumPy reference (:func:`_barrier_rows`, :func:`_capped_class_k`,
    :func:`_constraint_matrix` on the kept rows), on random QPs with base edges, violated and
    capped rows, and on the empty QP."""
    rng = np.random.default_rng(seed)
    params = MccstParams()
    box = 0.106
    for trial in range(60):
        n = int(rng.integers(2, 40))
        x, _, tree, r_c, col = _random_qp(
            rng, n, int(rng.integers(0, 3 * n)), int(rng.integers(0, 2 * n))
        )
        if trial == 0:
            tree, r_c, col = tree[:0], r_c[:0], col[:0]
        i, j, coef, h, reach = _barrier_rows(x, tree, r_c, col, box, params)
        rhs = _capped_class_k(h, reach + 1e-3, params)
        fast = _graph_kernels.qp_rows(x, tree, r_c, col, params.safety_radius, box, params.gamma)
        assert fast is not None
        fi, fj, fcoef, fh, freach, fcap, need = fast
        for got, want in ((fi, i), (fj, j), (fcoef, coef), (fh, h), (freach, reach)):
            np.testing.assert_array_equal(got, want)
            assert got.shape == want.shape
        frhs = fcap.copy()
        frhs[need] = np.minimum(_class_k(fh[need], params), fcap[need])
        np.testing.assert_array_equal(frhs, rhs)
        # The pruned matrix: kept rows, violated rows, and the CSC entries.
        slack_rows = np.flatnonzero(rhs < 0)
        keep = rhs <= reach
        keep[slack_rows] = True
        rows = np.flatnonzero(keep)
        new_row = np.cumsum(keep) - 1
        ref = _constraint_matrix(i[rows], j[rows], coef[rows], new_row[slack_rows], n, False)
        mat = _graph_kernels.barrier_matrix(i, j, coef, rhs, reach, n)
        assert mat is not None
        data, indices, indptr, got_rows, got_slack = mat
        np.testing.assert_array_equal(got_rows, rows)
        np.testing.assert_array_equal(got_slack, slack_rows)
        np.testing.assert_array_equal(data, ref.data)
        np.testing.assert_array_equal(indices, ref.indices)
        np.testing.assert_array_equal(indptr, ref.indptr)
        assert indices.dtype == indptr.dtype == np.int32


@pytest.mark.skipif(not _kernels.NUMBA, reason="Numba missing")
def test_candidate_edges_compiled_is_the_reference():
    """:func:`candidate_edges` with the compiled re-check (:func:`_graph_kernels.link_edges`) gives
    the reference's array, pair for pair in the KD-tree's order, on swarms with pairs and base
    links at exactly the range (grid positions), at the base, and of one or two drones."""
    rng = np.random.default_rng(3)
    cases = []
    for _ in range(40):
        n = int(rng.integers(1, 120))
        cases.append(rng.uniform(-60, 60, (n, 2)))
        cases.append(rng.integers(-6, 7, (n, 2)) * 10.0)  # distances exactly 10, 20, ...
    for pos_m in cases:
        base_m = np.array([0.0, 0.0]) if rng.random() < 0.5 else rng.uniform(-5, 5, 2)
        r, big_r = 20.0, float(rng.choice([10.0, 20.0, 30.0]))
        got = candidate_edges(pos_m, base_m, r, big_r)
        try:
            _kernels.ENABLED = False
            want = candidate_edges(pos_m, base_m, r, big_r)
        finally:
            _kernels.ENABLED = True
        np.testing.assert_array_equal(got, want)
        assert got.dtype == want.dtype and got.shape == want.shape


@pytest.mark.skipif(not _kernels.NUMBA, reason="Numba missing")
def test_clip_norm_compiled_is_the_reference():
    """The compiled norm clip equals the NumPy one bit for bit: rows below, at, just above and far
    above the limit, zero, NaN and infinite rows, and an empty array."""
    rng = np.random.default_rng(4)
    for trial in range(200):
        n = int(rng.integers(0, 300))
        vec = rng.normal(size=(n, 2)) * 10.0 ** rng.integers(-3, 3)
        limit = float(rng.uniform(0.01, 2.0))
        if n > 6:
            vec[0] = [limit, 0.0]
            vec[1] = [0.0, -limit * (1 + 1e-16)]
            vec[2] = np.array([3.0, 4.0]) * limit / 5.0
            vec[3] = 0.0
            if trial % 5 == 0:
                vec[4] = [np.nan, 1.0]
                vec[5] = [np.inf, 0.0]
        got = _clip_norm(vec, limit)
        with np.errstate(invalid="ignore"):  # inf rows: inf * 0
            want = _clip_norm_reference(vec, limit)
        np.testing.assert_array_equal(got, want)
        assert got.shape == want.shape and got is not vec


@pytest.mark.skipif(not _kernels.NUMBA, reason="Numba missing")
def test_qp_vectors_compiled_are_the_numpy_ones():
    """P's diagonal, q and the variable bounds built in one compiled pass equal the NumPy ones
    (:func:`_qp_objective` and the bounds of ``_solve_piqp``), with and without slacks."""
    rng = np.random.default_rng(5)
    params = MccstParams()
    box = 0.106
    for _ in range(50):
        n = int(rng.integers(1, 60))
        u_hat = rng.normal(size=(n, 2)) * 0.1
        slack_tree = rng.random(int(rng.integers(0, 20))) < 0.5
        p_mat, q_vec = _qp_objective(u_hat, slack_tree, params)
        x_lo = np.concatenate([np.full(2 * n, -box), np.zeros(len(slack_tree))])
        x_hi = np.concatenate([np.full(2 * n, box), np.full(len(slack_tree), np.inf)])
        got = _graph_kernels.qp_vectors(
            u_hat, slack_tree, params.slack_penalty, params.collision_slack_penalty, box
        )
        assert got is not None
        for a, b in zip(got, (p_mat.diagonal(), q_vec, x_lo, x_hi)):
            np.testing.assert_array_equal(a, b)
            assert a.dtype == b.dtype


@pytest.mark.skipif(not _kernels.NUMBA, reason="Numba missing")
def test_link_edges_near_the_range_is_the_sqrt_test():
    """Pairs a hair inside, at and a hair outside the range (the square root decides there, the
    squared-distance shortcut only far inside) are kept exactly as the NumPy re-check keeps them."""
    rng = np.random.default_rng(6)
    r = 20.0
    for _ in range(20):
        n = 60
        ang = rng.uniform(0, 2 * np.pi, n // 2)
        rad = r * (1 + rng.choice([-1e-9, -3e-16, 0.0, 2e-16, 1e-9, -2e-9], n // 2))
        a = rng.uniform(-5, 5, (n // 2, 2))
        b = a + np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])
        pos_m = np.vstack([a, b])
        pairs = neighbour_candidates(pos_m, r)
        got = _graph_kernels.link_edges(pos_m, pairs, r, np.zeros(2), 0.0)
        d = np.linalg.norm(pos_m[pairs[:, 0]] - pos_m[pairs[:, 1]], axis=1)
        want = pairs[d <= r]
        np.testing.assert_array_equal(got, want)


@pytest.mark.skipif(not _kernels.NUMBA, reason="Numba missing")
def test_toward_tasks_compiled_is_the_numpy_nominal_control():
    """The goal (the task in paper units, or the drone itself without one) and the saturated
    nominal control in one compiled pass equal the NumPy lines of ``plan`` bit for bit."""
    rng = np.random.default_rng(7)
    for _ in range(100):
        n, m = int(rng.integers(1, 80)), int(rng.integers(1, 10))
        unit = float(rng.choice([1.0, 10.0, 37.5]))
        x = rng.uniform(-5, 5, (n, 2))
        task_m = rng.uniform(-50, 50, (m, 2))
        task_local = rng.integers(-1, m, n)
        speed = float(rng.choice([0.15, 0.5, np.inf]))
        k_p = float(rng.choice([1.0, 0.3]))
        goal = np.where((task_local >= 0)[:, None], task_m[np.maximum(task_local, 0)] / unit, x)
        want = nominal_controls(x, goal, k_p, speed, 0.0)
        got = _graph_kernels.toward_tasks(x, task_m, task_local, unit, k_p, speed)
        assert got is not None
        np.testing.assert_array_equal(got, want)


@pytest.mark.skipif(not _kernels.NUMBA, reason="Numba missing")
@pytest.mark.parametrize("discrete_time", [False, True])
def test_edge_slack_compiled_is_the_numpy_one(discrete_time):
    """The edge slacks with the compiled edge terms and combination equal the NumPy reference
    path bit for bit (edges to the base, across and within subgroups, longer than r_c)."""
    rng = np.random.default_rng(8)
    params = MccstParams(discrete_time=discrete_time)
    for _ in range(40):
        n = int(rng.integers(2, 60))
        x = np.vstack([rng.uniform(-3, 3, (n, 2)), np.zeros((1, 2))])
        u = np.vstack([rng.uniform(-0.2, 0.2, (n, 2)), np.zeros((1, 2))])
        edges = candidate_edges(x[:n], x[n], 2.0, 2.0)
        r_c = 0.95 * np.where(edges[:, 1] == n, 2.0, 2.0 * rng.uniform(0.8, 1.1))
        subgroup = np.append(rng.integers(-2, 4, n), -1)
        got = edge_slack(x, u, edges, r_c, subgroup, params)
        try:
            _kernels.ENABLED = False
            want = edge_slack(x, u, edges, r_c, subgroup, params)
        finally:
            _kernels.ENABLED = True
        np.testing.assert_array_equal(got, want)

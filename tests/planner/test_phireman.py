"""PhiIREMAN kernels against their references, descent properties, and the planner contract."""

import numpy as np
import pytest

from planner.methods import TickInput, UnknownMethod, make_planner
from planner.phireman import (
    PhiremanParams,
    descend,
    descend_reference,
    energy,
    pair_gradient,
    pair_gradient_reference,
    task_gradient,
)
from planner.problem import problem_preset
from planner.steiner import build_task_tree

KW = dict(attraction=0.05, floor=0.5, repulsion=0.3, reach=2.0, pair_factor=2.0)


def test_pair_gradient_matches_reference_shared_and_per_drone_views(rng):
    for _ in range(10):
        n = int(rng.integers(1, 25))
        x = rng.uniform(-3, 3, (n, 2))
        mask = ~np.eye(n, dtype=bool) & (rng.random((n, n)) < 0.8)
        shared = pair_gradient(x, x, mask, **KW)
        assert np.allclose(shared, pair_gradient_reference(x, x, mask, **KW), atol=1e-9)
        beliefs = x[None] + rng.normal(0, 0.1, (n, n, 2))  # each drone's own view of the others
        assert np.allclose(
            pair_gradient(x, beliefs, mask, **KW),
            pair_gradient_reference(x, beliefs, mask, **KW),
            atol=1e-9,
        )


def test_pair_gradient_is_the_gradient_of_the_energy(rng):
    # Central view, total energy (c = 2): compare with central finite differences.
    p = PhiremanParams(thorn=0.0)
    x = rng.uniform(-2, 2, (6, 2))
    mask = ~np.eye(6, dtype=bool)
    g = pair_gradient(x, x, mask, p.attraction, p.attraction_floor, p.repulsion, 2.0, 2.0)
    eps = 1e-6
    for i in range(6):
        for c in range(2):
            xp, xm = x.copy(), x.copy()
            xp[i, c] += eps
            xm[i, c] -= eps
            fd = (energy(xp, None, p, 2.0) - energy(xm, None, p, 2.0)) / (2 * eps)
            assert g[i, c] == pytest.approx(fd, rel=1e-4, abs=1e-7)


def test_task_gradient_points_away_from_the_tree_with_norm_thorn():
    tree = build_task_tree(np.zeros(2), np.array([[4.0, 0.0]]))
    x = np.array([[2.0, 1.0], [2.0, -3.0], [2.0, 0.0]])
    g = task_gradient(x, tree, 0.05)
    assert np.allclose(g[0], [0, 0.05]) and np.allclose(g[1], [0, -0.05])
    assert np.allclose(g[2], 0.0)  # on the tree: no force


@pytest.mark.parametrize("rule", ["uniform", "per_drone", "clip"])
def test_descend_matches_reference_and_respects_the_speed_limit(rng, rule):
    p = PhiremanParams(speed_rule=rule, step_size=0.5, max_descent_steps=12)
    tree = build_task_tree(np.zeros(2), rng.uniform(-5, 5, (4, 2)))
    for _ in range(5):
        x = rng.uniform(-3, 3, (int(rng.integers(2, 15)), 2))
        mask = ~np.eye(len(x), dtype=bool)

        def grad(y, rows, mask=mask):
            return task_gradient(y, tree, p.thorn) + pair_gradient(
                y,
                y,
                mask,
                p.attraction,
                p.attraction_floor,
                p.repulsion,
                2.0,
                2.0,
            )

        res = descend(x, grad, 0.15, p)
        assert np.allclose(res.disp_u, descend_reference(x, grad, 0.15, p), atol=1e-7)
        assert np.linalg.norm(res.disp_u, axis=1).max() <= 0.15 + 1e-9


def test_converged_only_when_equilibrium_holds():
    p = PhiremanParams(tolerance=1e-3)
    res = descend(np.zeros((3, 2)), lambda y, rows: np.zeros_like(y), 0.15, p)
    assert res.converged and res.iterations == 1 and np.allclose(res.disp_u, 0)
    res = descend(np.zeros((3, 2)), lambda y, rows: np.ones_like(y), 0.15, p)
    assert not res.converged and res.hit_speed_limit


def test_uniform_rule_moves_the_fastest_drone_exactly_v():
    p = PhiremanParams(speed_rule="uniform", step_size=1.0)
    g = np.array([[-1.0, 0.0], [-0.1, 0.0]])
    res = descend(np.zeros((2, 2)), lambda y, rows: g, 0.15, p)
    assert np.linalg.norm(res.disp_u[0]) == pytest.approx(0.15)
    assert res.disp_u[1, 0] == pytest.approx(0.015)  # same scale for every drone


def test_descent_does_not_increase_energy_for_small_steps(rng):
    p = PhiremanParams(step_size=0.05, max_descent_steps=5, speed_rule="clip")
    x = rng.uniform(-2, 2, (10, 2))
    tree = build_task_tree(np.zeros(2), np.array([[4.0, 1.0], [-3.0, 2.0]]))
    mask = ~np.eye(10, dtype=bool)

    def grad(y, rows):
        return task_gradient(y, tree, p.thorn) + pair_gradient(
            y, y, mask, p.attraction, p.attraction_floor, p.repulsion, 2.0, 2.0
        )

    res = descend(x, grad, 10.0, p)
    assert energy(x + res.disp_u, tree, p, 2.0) <= energy(x, tree, p, 2.0)


@pytest.mark.parametrize(
    "method", ["phireman", "phireman-central", "phireman-no-task", "phireman-nodes-only"]
)
def test_planner_contract_speed_limit_and_determinism(method):
    prob = problem_preset("S", 0.01)
    rng = np.random.default_rng(3)
    pos = rng.normal(0, 1, (50, 2))
    alive = rng.random(50) < 0.9
    tick = TickInput(
        0, pos, alive, alive & (np.linalg.norm(pos, axis=1) < 2), rng.uniform(-5, 5, (10, 2))
    )
    a = make_planner(method, prob, {}).plan(tick)
    b = make_planner(method, prob, {}).plan(tick)
    assert np.array_equal(a.disp_m, b.disp_m)
    assert np.linalg.norm(a.disp_m, axis=1).max() <= prob.max_speed_m_s + 1e-9


def test_scale_invariance_of_the_scaled_reading():
    """The scaled M problem is the S geometry in a different unit: plans scale with the unit."""
    s = problem_preset("S", 0.0).replace(n_drones=30)
    m = problem_preset("S", 0.0, length_unit_m=2.0).replace(
        n_drones=30, radio_range_m=4.0, base_range_m=4.0, max_speed_m_s=0.3
    )
    rng = np.random.default_rng(5)
    pos = rng.normal(0, 1, (30, 2))
    tasks = rng.uniform(-5, 5, (6, 2))
    net = np.linalg.norm(pos, axis=1) < 2
    for info in ("central", "async"):
        a = make_planner("phireman", s, {"info": info}).plan(
            TickInput(0, pos, np.ones(30, bool), net, tasks)
        )
        b = make_planner("phireman", m, {"info": info}).plan(
            TickInput(0, 2 * pos, np.ones(30, bool), net, 2 * tasks)
        )
        assert np.allclose(2 * a.disp_m, b.disp_m, atol=1e-9)


def test_unknown_method_and_parameter_are_reported_with_the_valid_names():
    prob = problem_preset("S", 0.01)
    with pytest.raises(UnknownMethod, match="valid methods: .*phireman"):
        make_planner("phiremann", prob)
    with pytest.raises(ValueError, match="valid: .*step_size"):
        make_planner("phireman", prob, {"stepsize": 1})


def test_batched_task_gradient_matches_one_tree_at_a_time(rng):
    from planner.phireman import padded_segments, task_gradient_batched

    trees = [
        build_task_tree(np.zeros(2), rng.uniform(-5, 5, (int(rng.integers(1, 8)), 2)))
        for _ in range(4)
    ]
    x = rng.uniform(-6, 6, (40, 2))
    version = rng.integers(0, 4, 40)
    for nodes_only in (False, True):
        seg = padded_segments(trees, nodes_only)
        got = task_gradient_batched(x, *seg, version, 0.05)
        for v, tree in enumerate(trees):
            sel = version == v
            assert np.allclose(got[sel], task_gradient(x[sel], tree, 0.05, nodes_only), atol=1e-12)


def test_separable_descent_equals_full_evaluation(rng):
    """Skipping stopped drones is exact when each drone's gradient depends on itself only."""
    p = PhiremanParams(speed_rule="per_drone", step_size=0.5)
    anchors = rng.uniform(-3, 3, (12, 2))
    x = rng.uniform(-3, 3, (12, 2))

    def grad(y, rows):
        return 0.3 * (y[rows] - anchors[rows]) * (1 + np.arange(12)[rows, None] / 4)

    a = descend(x, grad, 0.15, p, separable=True).disp_u
    b = descend(x, lambda y, rows: grad(y, np.arange(12)), 0.15, p).disp_u
    assert np.allclose(a, b)

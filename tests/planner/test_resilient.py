"""ΦIREMAN-resilient: each mechanism against a slow reference or a hand-built scenario, the world's
rally rule, and the contract that every mechanism off is PhiIREMAN."""

import numpy as np
import pytest

from mission.experiments.sim import run_episode
from planner.methods import TickInput, make_planner
from planner.problem import problem_preset
from planner.resilient import (
    ResilientParams,
    claim_gradient,
    claim_targets,
    claim_targets_reference,
    nearest_rally,
    prune_tree,
    rally_points,
    rally_points_reference,
    select_tasks,
    select_tasks_reference,
    task_paths,
)
from planner.steiner import TaskTree, build_task_tree
from vehicle_emu.world import World

OFF = dict(
    triage_length_per_drone=0.0,
    rally=False,
    claim_gain=0.0,
    predict_steps=0.0,
    redundancy_gain=0.0,
    hazard_avoid=False,
    hazard_push_gain=0.0,
)


def _random_tree(rng, m):
    return build_task_tree(np.zeros(2), rng.uniform(-5, 5, (m, 2)))


# -- triage ----------------------------------------------------------------------------------


def test_task_paths_follow_parent_pointers(rng):
    for _ in range(10):
        tree = _random_tree(rng, int(rng.integers(1, 12)))
        paths = task_paths(tree)
        for k in range(tree.n_tasks):
            v, expect = k + 1, set()
            while v != 0:
                expect.add(v)
                v = int(tree.parent[v])
            assert set(np.flatnonzero(paths[k])) == expect


def test_select_tasks_matches_reference(rng):
    for _ in range(30):
        tree = _random_tree(rng, int(rng.integers(1, 15)))
        budget = float(rng.uniform(0, 40))
        kept = rng.random(tree.n_tasks) < 0.5
        for prev, bonus in ((None, 0.0), (kept, 0.3)):
            assert np.array_equal(
                select_tasks(tree, budget, prev, bonus),
                select_tasks_reference(tree, budget, prev, bonus),
            )


def test_select_tasks_by_hand_keeps_the_cheap_cluster():
    # Base at 0; task 1 at (1, 0); tasks 2, 3 share a Steiner-free path through task 1 further out;
    # task 4 alone far away. Budget 3: tasks 1 (1.0), 2 (+1.0), 3 (+1.0), not 4 (+8).
    nodes = np.array([[0, 0], [1, 0], [2, 0], [3, 0], [-8, 0]], float)
    tree = TaskTree(nodes, np.array([-1, 0, 1, 2, 0]), 4)
    assert select_tasks(tree, 3.0).tolist() == [True, True, True, False]
    assert select_tasks(tree, 2.5).tolist() == [True, True, False, False]
    assert select_tasks(tree, 0.1).tolist() == [True, False, False, False]  # the nearest, always
    assert select_tasks(tree, 100.0).all()


def test_prune_tree_keeps_paths_and_splices_lone_steiner_nodes():
    # base 0; tasks 1 (2, 1), 2 (2, -1); Steiner 3 at (1, 0) joins them; task 3 (-3, 0) direct.
    nodes = np.array([[0, 0], [2, 1], [2, -1], [-3, 0], [1, 0]], float)
    tree = TaskTree(nodes, np.array([-1, 4, 4, 0, 0]), 3)
    assert prune_tree(tree, np.ones(3, bool)) is tree
    pruned = prune_tree(tree, np.array([True, False, True]))
    # Steiner node 4 now has one child: spliced out, task 1 hangs from the base.
    assert pruned.n_tasks == 2 and pruned.n_nodes == 3
    assert np.allclose(pruned.nodes_m, [[0, 0], [2, 1], [-3, 0]])
    assert pruned.parent.tolist() == [-1, 0, 0]
    both = prune_tree(tree, np.array([True, True, False]))
    assert both.n_tasks == 2 and both.n_steiner == 1 and both.parent.tolist() == [-1, 3, 3, 0]


# -- rally points ----------------------------------------------------------------------------


def test_rally_points_match_reference(rng):
    for _ in range(30):
        tree = _random_tree(rng, int(rng.integers(1, 12)))
        for dist in (0.5, 2.0, 6.0, 50.0):
            assert np.allclose(rally_points(tree, dist), rally_points_reference(tree, dist))


def test_rally_points_by_hand():
    # One branch bending at (1, 0) toward (1, 3): at distance 2 the point is (1, 1).
    nodes = np.array([[0, 0], [1, 3], [1, 0]], float)
    tree = TaskTree(nodes, np.array([-1, 2, 0]), 1)
    assert np.allclose(rally_points(tree, 2.0), [[1, 1]])
    assert np.allclose(rally_points(tree, 0.5), [[0.5, 0]])
    assert np.allclose(rally_points(tree, 9.0), [[1, 3]])  # past the end: the task
    assert np.allclose(
        nearest_rally(np.array([[5.0, 5.0]]), np.array([[0, 1.0], [4, 4]])), [[4, 4]]
    )
    assert np.isnan(nearest_rally(np.zeros((1, 2)), np.zeros((0, 2)))).all()


def test_world_rally_rule_only_when_targets_are_given():
    p = problem_preset("S", 0.0).replace(n_drones=2)
    start = np.array([[6.0, 0.0], [0.0, 6.0]])
    target = np.array([[6.0, 3.0], [np.nan, np.nan]])
    w = World(p, start.copy(), np.ones(2, bool), np.zeros((2, 1, 2)))
    w.step(np.zeros((2, 2)), np.zeros(2, bool), 0.0, np.ones(2), target)
    assert np.allclose(w.pos_m, [[6.0, 0.15], [0.0, 5.85]])  # rally point; NaN row: home
    w2 = World(p, start.copy(), np.ones(2, bool), np.zeros((2, 1, 2)))
    w2.step(np.zeros((2, 2)), np.zeros(2, bool), 0.0, np.ones(2))
    assert np.allclose(w2.pos_m, [[5.85, 0.0], [0.0, 5.85]])  # the paper's rule


def test_cut_branch_reaches_its_rally_point_and_reconnects():
    # S geometry (r = 2, base reach 2). One task far east; the tree is the segment base -> (8, 0),
    # rally point at distance 2 from the base: (2, 0). Drones at 0.9, 2.6 (links to base chain)
    # and a cut-off pair at (7, 1), (8, 1): no alive drone links them to the base chain.
    p = problem_preset("S", 0.0).replace(n_drones=4, n_tasks=1)
    planner = make_planner(
        "phireman-resilient", p, {**OFF, "rally": True, "rally_dist": 2.0, "info": "central"}
    )
    pos = np.array([[0.9, 0.0], [2.6, 0.0], [7.0, 1.0], [8.0, 1.0]])
    alive = np.ones(4, bool)
    w = World(p, pos.copy(), alive.copy(), np.tile([[8.0, 0.0]], (60, 1, 1)))
    # Tick 0: every drone still connected (a relay between 2.6 and 7 has just been lost), so every
    # drone holds the tree and its rally point.
    planner.plan(TickInput(0, w.pos_m, w.alive, np.ones(4, bool), w.task_pos_m))
    first_connected = {}
    for t in range(1, 41):
        active = w.active()
        assert t > 1 or not active[2:].any()
        for i in (2, 3):
            if active[i] and i not in first_connected:
                first_connected[i] = t - 1  # steps flown since cut off
        planner.plan(TickInput(t, w.pos_m, w.alive, active, w.task_pos_m))
        target = planner.recovery_target_m
        if t == 1:
            assert np.allclose(target[2:], [[2.0, 0.0], [2.0, 0.0]])  # nearest (only) rally point
        # Freeze the connected drones so that only the rule under test moves anything.
        w.step(np.zeros((4, 2)), active, 0.0, np.ones(4), target)

    # Drone 2 flies from (7, 1) straight at (2, 0) at 0.15 per step and reconnects at the first
    # step that brings it within r = 2 of drone 1 at (2.6, 0) (counted on the straight line).
    def steps_to_link(start, goal, anchor):
        x, k = np.array(start, float), 0
        while np.linalg.norm(x - anchor) > 2.0:
            d = goal - x
            x = x + d * min(1.0, 0.15 / np.linalg.norm(d))
            k += 1
        return k

    assert first_connected[2] == steps_to_link([7, 1], np.array([2.0, 0.0]), np.array([2.6, 0.0]))
    # Drone 3 reconnects through drone 2 (one hop behind it on the same line) no later than it
    # would through drone 1 alone.
    assert first_connected[3] <= steps_to_link([8, 1], np.array([2.0, 0.0]), np.array([2.6, 0.0]))
    assert np.isnan(planner.recovery_target_m[2:]).all()  # reclaimed: no target


def test_rally_wait_then_home():
    # A lone drone whose rally point is itself cut off: waits rally_wait_steps, then flies home.
    p = problem_preset("S", 0.0).replace(n_drones=1, n_tasks=1)
    planner = make_planner(
        "phireman-resilient",
        p,
        {**OFF, "rally": True, "rally_dist": 6.0, "rally_wait_steps": 3, "info": "central"},
    )
    w = World(p, np.array([[6.3, 0.0]]), np.ones(1, bool), np.tile([[9.0, 0.0]], (40, 1, 1)))
    # tick 0: connected by hand so the drone holds the tree; then it is cut off.
    planner.plan(TickInput(0, w.pos_m, w.alive, np.ones(1, bool), w.task_pos_m))
    seen = []
    for t in range(1, 12):
        planner.plan(TickInput(t, w.pos_m, w.alive, np.zeros(1, bool), w.task_pos_m))
        seen.append(planner.recovery_target_m[0].copy())
        w.step(np.zeros((1, 2)), np.zeros(1, bool), 0.0, np.ones(1), planner.recovery_target_m)
    assert np.allclose(seen[0], [6.0, 0.0])
    # arrives after 2 steps (0.3 at 0.15/step), waits 3 steps there, then the target is the base
    home = [k for k, s in enumerate(seen) if np.allclose(s, 0.0)]
    assert home and home[0] == 2 + 3
    assert np.allclose(w.pos_m[0], [6.0 - 0.15 * (len(seen) - home[0]), 0.0])


# -- coverage claims -------------------------------------------------------------------------


def test_claim_targets_match_reference(rng):
    for _ in range(20):
        n = int(rng.integers(1, 12))
        pos = rng.uniform(-4, 4, (n, 2))
        ent_r = np.sort(rng.integers(0, n, int(rng.integers(0, 3 * n))))
        ent_y = rng.uniform(-4, 4, (len(ent_r), 2))
        stamps = rng.integers(0, 3, n)
        open_by = {
            0: rng.uniform(-4, 4, (3, 2)),
            1: np.zeros((0, 2)),
            2: rng.uniform(-4, 4, (1, 2)),
        }
        a = claim_targets(pos, ent_r, ent_y, stamps, open_by, 3.0)
        b = claim_targets_reference(pos, ent_r, ent_y, stamps, open_by, 3.0)
        assert np.array_equal(np.isnan(a), np.isnan(b)) and np.allclose(
            a[~np.isnan(a)], b[~np.isnan(b)]
        )


def test_claim_by_hand_nearest_known_drone_claims():
    pos = np.array([[0.0, 0.0], [2.0, 0.0]])
    # each knows the other where it is
    ent_r, ent_y = np.array([0, 1]), np.array([[2.0, 0.0], [0.0, 0.0]])
    task = {0: np.array([[3.0, 0.0]])}
    out = claim_targets(pos, ent_r, ent_y, np.zeros(2, int), task, 5.0)
    assert np.isnan(out[0]).all() and np.allclose(out[1], [3.0, 0.0])
    g = claim_gradient(pos, out, 0.1)
    assert np.allclose(g, [[0, 0], [-0.1, 0]])  # descent moves it east
    assert np.isnan(
        claim_targets(pos, ent_r, ent_y, np.zeros(2, int), task, 0.5)
    ).all()  # out of reach


# -- the planner contract --------------------------------------------------------------------


@pytest.mark.parametrize("base_view", ["heard", "oracle"])
def test_every_mechanism_off_is_phireman_bit_for_bit(base_view):
    p = problem_preset("S", 0.01).replace(n_steps=60)
    for seed in (3, 11):
        a = run_episode(p, "phireman", {}, seed)
        b = run_episode(p, "phireman-resilient", {**OFF, "base_view": base_view}, seed)
        assert a.tu1 == b.tu1 and a.tu2 == b.tu2
        assert np.array_equal(a.series.tu1_step, b.series.tu1_step)


def test_default_planner_runs_and_publishes_targets():
    p = problem_preset("XS", 0.05).replace(n_steps=40)
    r = run_episode(p, "phireman-resilient", {}, 1)
    assert 0.0 <= r.tu1 <= 1.0 and 0.0 <= r.tu2 <= 1.0


def test_params_are_validated():
    with pytest.raises(ValueError):
        ResilientParams(triage_keep_bonus=1.0)
    with pytest.raises(ValueError):
        ResilientParams(claim_reach=-1.0)
    with pytest.raises(ValueError):
        make_planner("phireman-resilient", problem_preset("S"), {"no_such_key": 1})


def test_tether_by_hand():
    from planner.resilient import tether, tether_anchors

    pos = np.array([[0.5, 0.0], [3.0, 0.0], [9.0, 9.0]])
    # drone 1 knows drones at (1.5, 0) and (4, 0) (both within r = 2); drone 2 knows nobody near
    ent_r = np.array([1, 1, 2])
    ent_y = np.array([[1.5, 0.0], [4.0, 0.0], [0.0, 0.0]])
    anchor = tether_anchors(pos, ent_r, ent_y, np.zeros(2), 2.0, 2.0)
    assert np.allclose(anchor[0], 0.0)  # within the base's reach: the base
    assert np.allclose(anchor[1], [1.5, 0.0])  # the known neighbour nearest the base
    assert np.isnan(anchor[2]).all()  # no anchor
    out = tether(np.array([[0.0, 3.0], [2.5, 1.0], [9.5, 9.0]]), anchor, 1.8)
    assert (
        np.allclose(out[0], [0.0, 1.8])
        and np.allclose(out[1], [2.5, 1.0])
        and np.allclose(out[2], [9.5, 9.0])
    )


def test_prediction_builds_the_tree_on_extrapolated_tasks():
    p = problem_preset("S", 0.0).replace(n_drones=3, n_tasks=2)
    planner = make_planner(
        "phireman-resilient",
        p,
        {**OFF, "predict_steps": 5.0, "predict_smoothing": 1.0, "info": "central"},
    )
    pos = np.array([[0.5, 0.0], [0.0, 0.5], [-0.5, 0.0]])
    vel = np.array([[0.1, 0.0], [0.0, -0.2]])
    y0 = np.array([[3.0, 1.0], [-2.0, 3.0]])
    for t in range(3):
        planner.plan(TickInput(t, pos, np.ones(3, bool), np.ones(3, bool), y0 + t * vel))
    # smoothing 1: the velocity is the last displacement, so the tree's tasks are 5 steps ahead
    assert np.allclose(planner.full_tree.nodes_m[1:3], y0 + 2 * vel + 5 * vel)
    off = make_planner("phireman-resilient", p, {**OFF, "info": "central"})
    for t in range(3):
        off.plan(TickInput(t, pos, np.ones(3, bool), np.ones(3, bool), y0 + t * vel))
    assert np.allclose(off.full_tree.nodes_m[1:3], y0 + 2 * vel)


def test_planner_runs_with_every_mechanism_on():
    p = problem_preset("XS", 0.02).replace(n_steps=40)
    r = run_episode(
        p,
        "phireman-resilient",
        {"claim_tether": 0.9, "rally": True, "triage_length_per_drone": 3.0, "predict_steps": 5.0},
        2,
    )
    assert 0.0 <= r.tu1 <= 1.0


@pytest.mark.parametrize("info", ["central", "async"])
def test_rally_planner_plans_for_the_fleet_it_is_given(info):
    # A station plans for the vehicles it has: 6 of the mission's 10 on real links, then more
    # rows as vehicles are discovered. The rally bookkeeping must follow the tick's size.
    p = problem_preset("XS", 0.0).replace(n_drones=10)
    planner = make_planner(
        "phireman-resilient", p, {"rally": True, "info": info}, np.random.default_rng(0)
    )
    rng = np.random.default_rng(1)
    tasks = rng.uniform(-200, 200, (p.n_tasks, 2))
    # (The message layer is sized at its first tick: with async information the fleet may be
    # smaller than the problem's but must not grow.)
    sizes = ((6, 0), (6, 1), (12, 2), (12, 3)) if info == "central" else ((6, 0), (6, 1), (6, 2))
    for n, t in sizes:
        pos = rng.uniform(-50, 50, (n, 2))
        out = planner.plan(TickInput(t, pos, np.ones(n, bool), np.ones(n, bool), tasks))
        assert out.disp_m.shape == (n, 2)
        assert planner.recovery_target_m.shape == (n, 2)

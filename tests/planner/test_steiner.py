"""Tests of planner.steiner: Fermat points, the greedy semi-Steiner tree, maintenance and h^T."""

import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from planner.steiner import (
    TaskTree,
    build_task_tree,
    distance_to_tree,
    distance_to_tree_reference,
    fermat_point,
    fermat_point_reference,
    fermat_points,
    maintain_task_tree,
    tree_cost,
    update_task_positions,
)

SQRT3 = math.sqrt(3.0)
BASE_WEIGHTS = [0.0, 0.3, 1.0, 3.0]

coord = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
point = st.tuples(coord, coord)


def _star_cost(base, tasks, cb):
    return (1.0 + cb) * float(np.linalg.norm(np.asarray(tasks) - base, axis=1).sum())


def _objective(x, pts):
    return float(np.linalg.norm(np.asarray(pts) - x, axis=1).sum())


def _assert_spanning_tree(tree: TaskTree, base, tasks):
    """Rooted at 0, K-1 edges, every node reaches the root, tasks in place, Steiner degree >= 3."""
    k = tree.n_nodes
    assert tree.nodes_m.shape == (k, 2) and tree.nodes_m.dtype == np.float64
    assert tree.parent.shape == (k,) and tree.parent.dtype == np.int64
    assert tree.parent[0] == -1
    assert tree.edges.shape == (k - 1, 2)
    assert tree.n_tasks == len(tasks)
    np.testing.assert_array_equal(tree.nodes_m[0], base)
    np.testing.assert_array_equal(tree.nodes_m[1 : 1 + len(tasks)], tasks)
    for v in range(k):
        seen, u = set(), v
        while u != 0:
            assert u not in seen, "cycle"
            seen.add(u)
            u = int(tree.parent[u])
            assert 0 <= u < k
    degree = np.bincount(tree.edges.ravel(), minlength=k)
    assert np.all(degree[tree.is_steiner] >= 3)


# ----------------------------------------------------------------------------------------------
# Fermat points
# ----------------------------------------------------------------------------------------------


def test_fermat_equilateral_is_centroid():
    a, b, c = np.array([0.0, 0.0]), np.array([2.0, 0.0]), np.array([1.0, SQRT3])
    np.testing.assert_allclose(fermat_point(a, b, c), (a + b + c) / 3, atol=1e-14)
    np.testing.assert_allclose(
        fermat_points(a[None], b[None], c[None])[0], (a + b + c) / 3, atol=1e-14
    )


def test_fermat_isosceles_by_hand():
    # Apex at the origin, base (4, ±1): the point on the axis seeing the base under 120° is at
    # x = 4 - 1/tan(60°) = 4 - 1/√3, and the three edges sum to 4 + √3.
    a, b, c = np.zeros(2), np.array([4.0, 1.0]), np.array([4.0, -1.0])
    s = fermat_point(a, b, c)
    np.testing.assert_allclose(s, [4.0 - 1.0 / SQRT3, 0.0], atol=1e-14)
    assert _objective(s, [a, b, c]) == pytest.approx(4.0 + SQRT3, abs=1e-13)


@pytest.mark.parametrize("angle_deg", [120.5, 135.0, 170.0, 180.0])
@pytest.mark.parametrize("which", [0, 1, 2])
def test_fermat_obtuse_returns_that_vertex(angle_deg, which):
    apex = np.array([0.3, -0.7])
    half = math.radians(angle_deg) / 2
    p = apex + 2.0 * np.array([math.cos(half), math.sin(half)])
    q = apex + 3.0 * np.array([math.cos(-half), math.sin(-half)])
    pts = [p, q]
    pts.insert(which, apex)
    np.testing.assert_array_equal(fermat_point(*pts), apex)
    np.testing.assert_array_equal(fermat_points(*[x[None] for x in pts])[0], apex)


def test_fermat_just_below_120_is_interior_and_close():
    apex = np.zeros(2)
    half = math.radians(119.5) / 2
    p = 2.0 * np.array([math.cos(half), math.sin(half)])
    q = 3.0 * np.array([math.cos(half), -math.sin(half)])
    s = fermat_point(apex, p, q)
    assert 0.0 < np.linalg.norm(s - apex) < 0.05
    units = [(x - s) / np.linalg.norm(x - s) for x in (apex, p, q)]
    np.testing.assert_allclose(np.sum(units, axis=0), 0.0, atol=1e-9)


def test_fermat_coincident_and_collinear():
    a, c = np.array([1.0, 2.0]), np.array([-3.0, 5.0])
    np.testing.assert_array_equal(fermat_point(a, a, c), a)
    np.testing.assert_array_equal(fermat_point(c, a, a), a)
    np.testing.assert_array_equal(fermat_point(a, a, a), a)
    np.testing.assert_array_equal(fermat_point([0.0, 0.0], [3.0, 0.0], [1.0, 0.0]), [1.0, 0.0])


def test_fermat_matches_reference_on_random_triangles(rng):
    tri = rng.uniform(-5.0, 5.0, size=(60, 3, 2))
    fast = fermat_points(tri[:, 0], tri[:, 1], tri[:, 2])
    n_vertex = 0
    for (a, b, c), s in zip(tri, fast):
        ref = fermat_point_reference(a, b, c)
        np.testing.assert_allclose(s, ref, atol=1e-6)
        assert _objective(s, [a, b, c]) <= _objective(ref, [a, b, c]) + 1e-12
        np.testing.assert_allclose(fermat_point(a, b, c), s, rtol=0, atol=1e-12)
        n_vertex += any(np.array_equal(s, v) for v in (a, b, c))
    assert 0 < n_vertex < len(tri), "the sample should contain both cases"


@given(point, point, point)
def test_fermat_optimality_conditions(a, b, c):
    a, b, c = np.array(a), np.array(b), np.array(c)
    s = fermat_point(a, b, c)
    scale = 1.0 + max(np.linalg.norm(b - a), np.linalg.norm(c - a))
    np.testing.assert_allclose(
        fermat_points(a[None], b[None], c[None])[0], s, rtol=0, atol=1e-12 * scale
    )
    # Never worse than the reference minimiser (and than every vertex).
    ref = fermat_point_reference(a, b, c)
    assert _objective(s, [a, b, c]) <= _objective(ref, [a, b, c]) + 1e-9 * scale
    # First-order conditions, where the directions are well conditioned (no vertex within 1e-6 of
    # s or of another vertex, relative to the triangle; the objective check above covers the rest).
    gaps = [np.linalg.norm(v - s) for v in (a, b, c)]
    sides = [np.linalg.norm(b - a), np.linalg.norm(c - a), np.linalg.norm(c - b)]
    tol = 1e-6 * (scale - 1.0)
    if min(sides) <= tol:
        return
    if min(gaps) == 0.0:
        # A vertex is optimal iff the unit vectors to the other two points sum to <= 1.
        pull = sum(((v - s) / g for v, g in zip((a, b, c), gaps) if g > 0.0), np.zeros(2))
        assert np.linalg.norm(pull) <= 1.0 + 1e-9
    elif min(gaps) > tol:
        units = [(v - s) / g for v, g in zip((a, b, c), gaps)]
        assert np.linalg.norm(np.sum(units, axis=0)) <= 1e-6


# ----------------------------------------------------------------------------------------------
# Building the tree
# ----------------------------------------------------------------------------------------------


def test_acute_pair_gets_a_steiner_node_by_hand():
    # Tasks at (4, ±1) see the base under ~28°, every angle < 120°: greedy attaches task 0 to the
    # base (tie broken to the first task), then splits that edge for task 1 at the Fermat point
    # (4 - 1/√3, 0). Total edge length 4 + √3 < the star's 2√17.
    base, tasks = np.zeros(2), np.array([[4.0, 1.0], [4.0, -1.0]])
    for cb in (0.0, 0.3, 1.0):
        tree = build_task_tree(base, tasks, cb)
        assert tree.n_nodes == 4 and tree.n_steiner == 1
        np.testing.assert_array_equal(tree.parent, [-1, 3, 3, 0])
        np.testing.assert_allclose(tree.nodes_m[3], [4.0 - 1.0 / SQRT3, 0.0], atol=1e-12)
        l_total, l_edges, l_base = tree_cost(tree, cb)
        assert l_edges == pytest.approx(4.0 + SQRT3, abs=1e-12)
        assert l_base == pytest.approx(2 * (4.0 - 1.0 / SQRT3 + 2.0 / SQRT3), abs=1e-12)
        assert l_total == pytest.approx(l_edges + cb * l_base, abs=1e-12)


def test_heavy_base_weight_prefers_direct_routes_by_hand():
    # Same tasks with c_b = 3: the split costs 1.609 + 3·(0.454 + 4.577) = 16.70 against
    # 4·√17 = 16.49 for a direct edge, so the tree is the star.
    base, tasks = np.zeros(2), np.array([[4.0, 1.0], [4.0, -1.0]])
    tree = build_task_tree(base, tasks, 3.0)
    np.testing.assert_array_equal(tree.parent, [-1, 0, 0])
    assert tree_cost(tree, 3.0)[0] == pytest.approx(_star_cost(base, tasks, 3.0), abs=1e-12)


def test_obtuse_pair_stays_a_star_by_hand():
    # Tasks at (1, ±2) subtend 2·atan(2) ≈ 126.9° ≥ 120° at the base: the Fermat point of
    # (base, t0, t1) is the base itself, so no Steiner node; attaching t1 to t0 (length 4) loses
    # to the base (√5).
    base, tasks = np.zeros(2), np.array([[1.0, 2.0], [1.0, -2.0]])
    for cb in BASE_WEIGHTS:
        tree = build_task_tree(base, tasks, cb)
        np.testing.assert_array_equal(tree.parent, [-1, 0, 0])
        assert tree.n_steiner == 0


def test_task_in_line_relays_through_the_nearer_task():
    # c_b = 0: the far task hangs off the near one (edge 1 < 3), giving a path, not a star.
    tree = build_task_tree(np.zeros(2), np.array([[3.0, 0.0], [2.0, 0.0]]), 0.0)
    np.testing.assert_array_equal(tree.parent, [-1, 2, 0])
    assert tree_cost(tree, 0.0)[1] == pytest.approx(3.0)


def test_empty_and_single_task():
    base = np.array([1.0, -1.0])
    empty = build_task_tree(base, np.empty((0, 2)))
    assert empty.n_nodes == 1 and empty.n_tasks == 0 and empty.edges.shape == (0, 2)
    assert tree_cost(empty) == (0.0, 0.0, 0.0)
    one = build_task_tree(base, np.array([[4.0, 3.0]]), 1.0)
    np.testing.assert_array_equal(one.parent, [-1, 0])
    assert tree_cost(one, 1.0) == pytest.approx(
        (2 * math.hypot(3.0, 4.0), math.hypot(3.0, 4.0), math.hypot(3.0, 4.0))
    )


@given(point, st.lists(point, min_size=0, max_size=20), st.sampled_from(BASE_WEIGHTS))
def test_tree_spans_and_never_costs_more_than_the_star(base, tasks, cb):
    base = np.array(base)
    tasks = np.array(tasks, dtype=float).reshape(-1, 2)
    tree = build_task_tree(base, tasks, cb)
    _assert_spanning_tree(tree, base, tasks)
    star = _star_cost(base, tasks, cb)
    assert tree_cost(tree, cb)[0] <= star * (1 + 1e-12) + 1e-9


@pytest.mark.parametrize("cb", BASE_WEIGHTS)
@pytest.mark.parametrize("m", [10, 50, 100])
def test_random_fields_beat_the_star(rng, m, cb):
    tasks = rng.uniform(-5.0, 5.0, size=(m, 2))
    tree = build_task_tree(np.zeros(2), tasks, cb)
    _assert_spanning_tree(tree, np.zeros(2), tasks)
    l_total, l_edges, _ = tree_cost(tree, cb)
    star = _star_cost(np.zeros(2), tasks, cb)
    assert l_total < star
    if cb == 0.0:
        # Steiner-like: far shorter than the star on a uniform field.
        assert l_edges < 0.6 * star


def test_tree_cost_by_hand():
    # base -> S(0, 1) -> tasks (-1, 2) and (1, 2); edges 1 + √2 + √2; paths 1 + √2 each.
    tree = TaskTree(
        np.array([[0.0, 0.0], [-1.0, 2.0], [1.0, 2.0], [0.0, 1.0]]), np.array([-1, 3, 3, 0]), 2
    )
    l_total, l_edges, l_base = tree_cost(tree, 0.5)
    r2 = math.sqrt(2.0)
    assert l_edges == pytest.approx(1 + 2 * r2)
    assert l_base == pytest.approx(2 * (1 + r2))
    assert l_total == pytest.approx(1 + 2 * r2 + 0.5 * 2 * (1 + r2))
    assert tree.is_steiner.tolist() == [False, False, False, True]
    np.testing.assert_array_equal(tree.edges, [[1, 3], [2, 3], [3, 0]])
    a_m, b_m = tree.segments()
    np.testing.assert_array_equal(a_m, tree.nodes_m[1:])
    np.testing.assert_array_equal(b_m, tree.nodes_m[[3, 3, 0]])


@pytest.mark.parametrize("cb", [0.0, 1.0])
def test_frame_agnostic_translation_and_rotation(rng, cb):
    base = rng.uniform(-1.0, 1.0, size=2)
    tasks = rng.uniform(-5.0, 5.0, size=(15, 2))
    tree = build_task_tree(base, tasks, cb)
    shift = np.array([3.25, -7.5])
    moved = build_task_tree(base + shift, tasks + shift, cb)
    np.testing.assert_array_equal(moved.parent, tree.parent)
    np.testing.assert_allclose(moved.nodes_m, tree.nodes_m + shift, atol=1e-9)
    rot = np.array([[0.0, -1.0], [1.0, 0.0]])  # 90°
    turned = build_task_tree(base @ rot.T, tasks @ rot.T, cb)
    np.testing.assert_array_equal(turned.parent, tree.parent)
    np.testing.assert_allclose(turned.nodes_m, tree.nodes_m @ rot.T, atol=1e-9)
    # Task order does not matter for the cost.
    perm = rng.permutation(len(tasks))
    assert tree_cost(build_task_tree(base, tasks[perm], cb), cb)[0] == pytest.approx(
        tree_cost(tree, cb)[0], rel=1e-9
    )


def test_invalid_inputs_raise():
    with pytest.raises(ValueError, match="task_pos_m"):
        build_task_tree(np.zeros(2), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="base_m"):
        build_task_tree(np.zeros(3), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="base_weight"):
        build_task_tree(np.zeros(2), np.zeros((3, 2)), -1.0)
    with pytest.raises(ValueError, match="cycle"):
        TaskTree(np.zeros((3, 2)), np.array([-1, 2, 1]), 2)
    with pytest.raises(ValueError, match="parent"):
        TaskTree(np.zeros((2, 2)), np.array([0, 0]), 1)


# ----------------------------------------------------------------------------------------------
# Maintenance
# ----------------------------------------------------------------------------------------------


def test_update_keeps_topology_and_relaxes_to_fermat_points(rng):
    tasks = rng.uniform(-5.0, 5.0, size=(20, 2))
    # Relax fully first (the build does only a few sweeps, and may splice on the way).
    tree = update_task_positions(build_task_tree(np.zeros(2), tasks, 0.3), tasks, sweeps=200)
    assert tree.n_steiner > 0
    # Small moves: no Steiner node becomes degenerate, so the topology is unchanged.
    moved = tasks + 1e-4 * rng.standard_normal(tasks.shape)
    new = update_task_positions(tree, moved, sweeps=200)
    np.testing.assert_array_equal(new.parent, tree.parent)
    np.testing.assert_array_equal(new.nodes_m[0], tree.nodes_m[0])
    np.testing.assert_array_equal(new.nodes_m[1:21], moved)
    # After many sweeps each Steiner node sits at the Fermat point of its neighbours.
    edges = new.edges
    for s in np.flatnonzero(new.is_steiner):
        nbrs = np.concatenate([edges[edges[:, 1] == s, 0], [new.parent[s]]])
        units = new.nodes_m[nbrs] - new.nodes_m[s]
        units /= np.linalg.norm(units, axis=1, keepdims=True)
        assert np.linalg.norm(units.sum(axis=0)) <= 1e-6


@given(st.lists(point, min_size=1, max_size=15), st.sampled_from(BASE_WEIGHTS), st.integers(0, 5))
def test_update_never_lengthens_edges_at_fixed_tasks(tasks, cb, sweeps):
    tasks = np.array(tasks)
    tree = build_task_tree(np.zeros(2), tasks, cb, refine_sweeps=0)
    new = update_task_positions(tree, tasks, sweeps=sweeps)
    _assert_spanning_tree(new, np.zeros(2), tasks)
    assert tree_cost(new, cb)[1] <= tree_cost(tree, cb)[1] + 1e-9


def test_update_splices_steiner_node_onto_base_when_angle_opens():
    tree = build_task_tree(np.zeros(2), np.array([[4.0, 1.0], [4.0, -1.0]]), 0.0)
    assert tree.n_steiner == 1
    # Now the tasks subtend ≈ 126.9° at the base: the Fermat point is the base.
    new = update_task_positions(tree, np.array([[1.0, 2.0], [1.0, -2.0]]))
    assert new.n_nodes == 3
    np.testing.assert_array_equal(new.parent, [-1, 0, 0])


def test_update_splices_steiner_node_onto_a_task():
    tree = build_task_tree(np.zeros(2), np.array([[4.0, 1.0], [4.0, -1.0]]), 0.0)
    # Task 0 at (4, 0) between the base and task 1 at (5, 0.5): angle ≈ 153° at task 0, so the
    # Steiner node collapses onto it and task 1 hangs off task 0.
    new = update_task_positions(tree, np.array([[4.0, 0.0], [5.0, 0.5]]))
    np.testing.assert_array_equal(new.parent, [-1, 0, 1])


def test_update_removes_steiner_nodes_with_fewer_than_three_neighbours():
    # Node 2 is a Steiner node with one child (degree 2), node 3 a Steiner leaf.
    tree = TaskTree(
        np.array([[0.0, 0.0], [2.0, 2.0], [1.0, 0.0], [5.0, 5.0]]), np.array([-1, 2, 0, 1]), 1
    )
    new = update_task_positions(tree, np.array([[2.0, 2.0]]), sweeps=1)
    np.testing.assert_array_equal(new.parent, [-1, 0])
    assert tree_cost(new, 0.0)[1] == pytest.approx(math.hypot(2.0, 2.0))


def test_update_moves_degree_four_steiner_node_to_geometric_median():
    # Steiner node 4 joins the base (0,0) and tasks (2,±1), (3,0). Their geometric median is (2,0):
    # the unit vectors from there, (-1,0), (0,1), (0,-1) and (1,0), cancel.
    nodes = np.array([[0.0, 0.0], [2.0, 1.0], [2.0, -1.0], [3.0, 0.0], [0.5, 0.3]])
    tree = TaskTree(nodes, np.array([-1, 4, 4, 4, 0]), 3)
    new = update_task_positions(tree, nodes[1:4], sweeps=1)
    np.testing.assert_array_equal(new.parent, tree.parent)
    np.testing.assert_allclose(new.nodes_m[4], [2.0, 0.0], atol=1e-9)
    assert tree_cost(new, 0.0)[1] == pytest.approx(2.0 + 1.0 + 1.0 + 1.0, abs=1e-9)


def test_update_splices_degree_four_steiner_node_onto_a_vertex_median():
    # Neighbours (0,0), (1,0), (2,±1): at (1,0) the other three unit vectors sum to (√2 - 1, 0),
    # of norm < 1, so task 0 at (1,0) is the median; it takes the Steiner node's place.
    nodes = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [2.0, -1.0], [1.2, 0.1]])
    tree = TaskTree(nodes, np.array([-1, 4, 4, 4, 0]), 3)
    new = update_task_positions(tree, nodes[1:4], sweeps=1)
    np.testing.assert_array_equal(new.parent, [-1, 0, 1, 1])


def test_update_rejects_wrong_shape():
    tree = build_task_tree(np.zeros(2), np.ones((3, 2)))
    with pytest.raises(ValueError, match="task_pos_m"):
        update_task_positions(tree, np.ones((4, 2)))


def test_maintain_builds_when_missing_and_applies_the_nu_rule():
    base, tasks, cb = np.zeros(2), np.array([[10.0, 1.0], [10.0, -1.0]]), 0.0
    fresh = build_task_tree(base, tasks, cb)
    first = maintain_task_tree(None, base, tasks, t_step=7, base_weight=cb)
    np.testing.assert_array_equal(first.parent, fresh.parent)

    star = TaskTree(np.vstack([base, tasks]), np.array([-1, 0, 0]), 2)
    ratio = tree_cost(fresh, cb)[0] / tree_cost(star, cb)[0]  # ≈ 0.55: the rebuild is better
    assert ratio < 0.99

    def run(t_step, nu):
        return maintain_task_tree(
            star, base, tasks, t_step, base_weight=cb, accept_ratio=nu, rebuild_period=10
        )

    # Not a rebuild tick: the current topology is kept however good the alternative.
    np.testing.assert_array_equal(run(3, 0.99).parent, [-1, 0, 0])
    # Rebuild ticks: accepted iff l_new < ν · l_curr.
    np.testing.assert_array_equal(run(10, 0.99).parent, fresh.parent)
    np.testing.assert_array_equal(run(0, ratio * 1.001).parent, fresh.parent)
    np.testing.assert_array_equal(run(20, ratio * 0.999).parent, [-1, 0, 0])
    # rebuild_period = 0 disables rebuilds.
    kept = maintain_task_tree(star, base, tasks, 10, base_weight=cb, rebuild_period=0)
    np.testing.assert_array_equal(kept.parent, [-1, 0, 0])


def test_maintain_moves_tasks_and_base(rng):
    tasks = rng.uniform(-5.0, 5.0, size=(10, 2))
    tree = maintain_task_tree(None, np.zeros(2), tasks, 0)
    moved = tasks + 0.1 * rng.standard_normal(tasks.shape)
    new_base = np.array([0.5, 0.0])
    out = maintain_task_tree(tree, new_base, moved, 1)
    np.testing.assert_array_equal(out.nodes_m[0], new_base)
    np.testing.assert_array_equal(out.nodes_m[1:11], moved)
    # A changed task count forces a rebuild.
    fewer = maintain_task_tree(tree, np.zeros(2), tasks[:4], 1)
    assert fewer.n_tasks == 4


# ----------------------------------------------------------------------------------------------
# Distance to the tree
# ----------------------------------------------------------------------------------------------


def test_distance_by_hand():
    tree = TaskTree(np.array([[0.0, 0.0], [2.0, 0.0]]), np.array([-1, 0]), 1)
    pts = np.array([[1.0, 1.0], [3.0, 1.0], [-1.0, 0.0], [0.5, 0.0]])
    d, near = distance_to_tree(pts, tree)
    np.testing.assert_allclose(d, [1.0, math.sqrt(2.0), 1.0, 0.0])
    np.testing.assert_allclose(near, [[1.0, 0.0], [2.0, 0.0], [0.0, 0.0], [0.5, 0.0]])
    d, near = distance_to_tree(pts, tree, nodes_only=True)
    np.testing.assert_allclose(d, [math.sqrt(2.0), math.sqrt(2.0), 1.0, 0.5])
    np.testing.assert_allclose(near, [[0.0, 0.0], [2.0, 0.0], [0.0, 0.0], [0.0, 0.0]])


def test_distance_to_single_node_tree():
    tree = build_task_tree(np.array([1.0, 1.0]), np.empty((0, 2)))
    for nodes_only in (False, True):
        d, near = distance_to_tree(np.array([[4.0, 5.0]]), tree, nodes_only)
        np.testing.assert_allclose(d, [5.0])
        np.testing.assert_allclose(near, [[1.0, 1.0]])
    d, near = distance_to_tree(np.empty((0, 2)), tree)
    assert d.shape == (0,) and near.shape == (0, 2)


@pytest.mark.parametrize("nodes_only", [False, True])
def test_distance_matches_reference_on_random_trees(rng, nodes_only):
    for m in (1, 5, 30):
        tree = build_task_tree(np.zeros(2), rng.uniform(-5.0, 5.0, size=(m, 2)), 1.0)
        pts = rng.uniform(-7.0, 7.0, size=(200, 2))
        d, near = distance_to_tree(pts, tree, nodes_only)
        d_ref, near_ref = distance_to_tree_reference(pts, tree, nodes_only)
        np.testing.assert_allclose(d, d_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(near, near_ref, rtol=0, atol=1e-12)


@given(
    st.lists(point, min_size=0, max_size=8), st.lists(point, min_size=1, max_size=10), st.booleans()
)
def test_distance_matches_reference_property(tasks, pts, nodes_only):
    tree = build_task_tree(np.zeros(2), np.array(tasks, dtype=float).reshape(-1, 2), 0.3)
    pts = np.array(pts)
    d, near = distance_to_tree(pts, tree, nodes_only)
    d_ref, _ = distance_to_tree_reference(pts, tree, nodes_only)
    np.testing.assert_allclose(d, d_ref, rtol=0, atol=1e-9)
    # The returned point is at that distance and lies on the tree (ties may pick another one).
    np.testing.assert_allclose(np.linalg.norm(pts - near, axis=1), d_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(
        distance_to_tree_reference(near, tree, nodes_only)[0], 0.0, atol=1e-9
    )


def test_nearest_point_gives_the_gradient_of_h(rng):
    tree = build_task_tree(np.zeros(2), rng.uniform(-5.0, 5.0, size=(12, 2)), 1.0)
    pts = rng.uniform(-6.0, 6.0, size=(50, 2))
    d, near = distance_to_tree(pts, tree)
    grad = (pts - near) / d[:, None]
    h = 1e-6
    for axis in (0, 1):
        step = np.zeros(2)
        step[axis] = h
        numeric = (
            distance_to_tree(pts + step, tree)[0] - distance_to_tree(pts - step, tree)[0]
        ) / (2 * h)
        np.testing.assert_allclose(numeric, grad[:, axis], atol=1e-5)


@pytest.mark.parametrize("sweeps", [1, 3, 6])
def test_relaxation_shortcuts_give_the_same_bits(rng, monkeypatch, sweeps):
    """Stopping after a sweep that changed nothing, and returning a fixed-point tree as it is when
    its tasks are unchanged, give exactly the trees of running every sweep every tick."""
    from planner import steiner

    base = np.zeros(2)
    shortcuts = 0
    for trial in range(25):
        m = int(rng.integers(2, 14))
        tasks = rng.uniform(-10, 10, (m, 2))
        tree = ref = build_task_tree(base, tasks)
        for t in range(12):
            if t % 4 == 3:  # the tasks move now and then; otherwise they stay put
                tasks = tasks + rng.normal(0, 0.5, tasks.shape)
            new = update_task_positions(tree, tasks, sweeps)
            shortcuts += new is tree
            monkeypatch.setattr(steiner, "RELAX_SHORTCUTS", False)
            ref = update_task_positions(ref, tasks, sweeps)
            monkeypatch.setattr(steiner, "RELAX_SHORTCUTS", True)
            assert np.array_equal(new.nodes_m.view(np.int64), ref.nodes_m.view(np.int64)), trial
            assert np.array_equal(new.parent, ref.parent), trial
            tree = new
    assert shortcuts > 0


def test_scaled_tree_is_the_replaced_one(rng):
    """TaskTree.scaled (what PhiIREMAN returns each tick, in metres) against the checked
    construction of planner.units.PaperUnits.tree_to_m: the same arrays, read-only; a scale that
    overflows is refused."""
    import dataclasses

    for m in (0, 1, 7, 30):
        tree = build_task_tree(np.zeros(2), rng.uniform(-8, 8, (m, 2)))
        for factor in (1.0, 0.37, 250.0):
            got = tree.scaled(factor)
            want = dataclasses.replace(tree, nodes_m=tree.nodes_m * factor)
            assert type(got) is TaskTree and got.n_tasks == want.n_tasks
            assert got.nodes_m.tobytes() == want.nodes_m.tobytes()
            assert (
                got.nodes_m.dtype == want.nodes_m.dtype and got.nodes_m.shape == want.nodes_m.shape
            )
            assert np.array_equal(got.parent, want.parent) and got.parent.dtype == np.int64
            assert not got.nodes_m.flags.writeable and not got.parent.flags.writeable
            assert got.path_to_base_m().tobytes() == want.path_to_base_m().tobytes()
    far = TaskTree(np.array([[0.0, 0.0], [5.0, 0.0]]), np.array([-1, 0]), 1)
    with pytest.raises(ValueError, match="finite"), np.errstate(over="ignore"):
        far.scaled(1e308)  # 5e308 overflows

"""The compiled graph kernels (planner._graph_kernels) against their references.

Each kernel returns a set (a tree's edges, a mask, sorted pairs, entries): it must equal the
reference's exactly, including on ties (equal weights, equal distances), where it either breaks
them the reference's way (the spanning tree: weight, then index) or declines (the collision pairs:
None, the caller runs the KD-tree).
"""

import numpy as np
import pytest

from planner import _graph_kernels, _kernels, knowledge, mccst
from planner.geometry import active_mask, active_mask_reference, radio_pairs
from planner.knowledge import StampTable

pytestmark = pytest.mark.skipif(not _kernels.NUMBA, reason="numba not installed")


@pytest.fixture
def reference_paths():
    """Run the reference paths inside the block."""

    def switch(on: bool) -> None:
        _kernels.ENABLED = not on

    yield switch
    _kernels.ENABLED = True


def _swarm(rng, n, rounded=False):
    x = rng.uniform(0, rng.uniform(1, 20), (n, 2))
    return np.round(x, 1) if rounded else x


def test_prim_spanning_tree_is_the_reference_tree(rng):
    ties = 0
    for trial in range(150):
        n = int(rng.integers(2, 250))
        x = _swarm(rng, n, rounded=trial % 5 == 0)
        edges = mccst.candidate_edges(x[:-1], x[-1], 2.0, 3.0)
        w = rng.normal(size=len(edges))
        if trial % 3 == 0:
            w = np.round(w, 1)  # many equal weights: ties broken by index
            ties += len(np.unique(w)) < len(w)
        if trial % 7 == 0:
            w[: len(w) // 2] = -0.0  # -0 and +0 tie as well
            w[len(w) // 2 :] = 0.0
        got = _graph_kernels.mst_prim(n, edges, w)
        assert got is not None
        assert np.array_equal(got, mccst._spanning_tree_reference(n, edges, w)), trial
        assert np.array_equal(mccst.spanning_tree_edges(n, edges, w), got)
    assert ties > 10


def test_prim_declines_nan_and_the_planner_falls_back(rng):
    x = _swarm(rng, 30)
    edges = mccst.candidate_edges(x[:-1], x[-1], 3.0, 3.0)
    w = rng.normal(size=len(edges))
    w[3] = np.nan
    assert _graph_kernels.mst_prim(30, edges, w) is None
    assert np.array_equal(
        mccst.spanning_tree_edges(30, edges, w), mccst._spanning_tree_reference(30, edges, w)
    )


def test_reach_from_is_the_active_mask(rng, reference_paths):
    for trial in range(150):
        n = int(rng.integers(1, 400))
        x = _swarm(rng, n, rounded=trial % 4 == 0)
        alive = rng.random(n) > 0.1
        base = x[0] if trial % 2 else np.zeros(2)
        got = active_mask(x, alive, 2.0, 3.0, base)
        reference_paths(True)
        want = active_mask(x, alive, 2.0, 3.0, base)
        reference_paths(False)
        assert np.array_equal(got, want), trial
        if n <= 40:
            assert np.array_equal(got, active_mask_reference(x, alive, 2.0, 3.0, base))


def test_reach_from_exact_at_the_link_radius():
    """A link at exactly r counts (the paper's inclusive inequality), one a hair longer does not."""
    x = np.array([[0.0, 0.0], [2.0, 0.0], [4.0, 0.0], [6.0 + 1e-12, 0.0]])
    got = _graph_kernels.reach_from(x, np.array([True, False, False, False]), 2.0)
    assert got is not None and got.tolist() == [True, True, True, False]


def test_knn_pairs_are_the_kd_tree_pairs_or_decline(rng):
    declined = 0
    for trial in range(150):
        n = int(rng.integers(2, 300))
        x = _swarm(rng, n, rounded=trial % 5 == 0)
        for k in (1, 3, 8):
            got = _graph_kernels.knn_pairs(x, 0.8, k)
            want = mccst._collision_candidates_reference(x, 0.8, k)
            if got is None:
                declined += 1
            else:
                assert np.array_equal(got, want), (trial, k)
            assert np.array_equal(mccst.collision_candidates(x, 0.8, k), want)
    assert declined > 0  # the rounded swarms have ties at the k-th distance


def test_hop_bitsets_is_the_numpy_bitset_hop(rng):
    for trial in range(60):
        n = int(rng.integers(2, 300))
        t_sent, age_max = int(rng.integers(0, 12)), int(rng.integers(0, 5))
        x = rng.uniform(0, rng.uniform(1, 10), (n, 2))
        pairs = radio_pairs(x, 1.5)
        lo = max(t_sent - age_max, 0)
        stamp = np.where(
            rng.random((n, n + 3)) < rng.uniform(0.02, 0.9),
            rng.integers(lo, t_sent + 1, (n, n + 3)),
            -1,
        )
        r, c = np.nonzero(stamp >= 0)
        if len(r) == 0:
            continue
        loops = np.arange(n)
        src = np.concatenate([pairs[:, 1], pairs[:, 0], loops])
        dst = np.concatenate([pairs[:, 0], pairs[:, 1], loops])
        order = np.argsort(dst, kind="stable")
        start = np.searchsorted(dst[order], np.arange(n + 1))
        got = _graph_kernels.hop_bitsets(
            r, c, stamp[r, c], n, n + 3, start, src[order], t_sent, age_max
        )
        want = knowledge._propagate_bitsets(r, c, stamp[r, c], n, n + 3, src, dst, t_sent, age_max)
        for a, b in zip(got, want):
            assert np.array_equal(a, b), trial


@pytest.mark.parametrize("max_per_bit", [1e-9, 1e9])
@pytest.mark.parametrize("compiled_from", [0, 10_000])
def test_propagate_entries_same_whichever_compiled_hop(
    rng, monkeypatch, max_per_bit, compiled_from
):
    """The cost model picks the per-entry maximum, the compiled or NumPy's bit sets: same entries."""
    monkeypatch.setattr(knowledge, "_MAX_PER_BIT_WORD", max_per_bit)
    monkeypatch.setattr(knowledge, "_COMPILED_BITSET_MIN_HOLDERS", compiled_from)
    for _ in range(30):
        n = int(rng.integers(2, 200))
        x = rng.uniform(0, 6, (n, 2))
        stamp = np.where(rng.random((n, n)) < 0.3, rng.integers(4, 10, (n, n)), -1)
        r, c = np.nonzero(stamp >= 0)
        pairs = radio_pairs(x, 1.5)
        got = knowledge.propagate_entries(r, c, stamp[r, c], n, n, pairs, 9, 3)
        fresh = np.where(stamp >= 6, stamp, -1)
        table = np.full((n, n), -1)
        table[got[0], got[1]] = got[2]
        assert np.array_equal(table, knowledge.propagate_stamps_reference(fresh, pairs))


def test_stamp_table_lookup_is_the_dense_table(rng):
    n = 40
    dense = np.where(rng.random((n, n)) < 0.2, rng.integers(0, 9, (n, n)), -1)
    r, c = np.nonzero(dense >= 0)
    table = StampTable(n, r, c, dense[r, c])
    assert np.array_equal(np.asarray(table), dense)
    qr, qc = rng.integers(0, n, 500), rng.integers(0, n, 500)
    assert np.array_equal(table[qr, qc], dense[qr, qc])
    assert table[3, 5] == dense[3, 5] and table[-1, -2] == dense[-1, -2]
    assert np.array_equal(table[np.ix_([1, 4], [2, 3, 7])], dense[np.ix_([1, 4], [2, 3, 7])])
    assert np.array_equal(table[2], dense[2]) and np.array_equal(table == -1, dense == -1)
    empty = StampTable(n, r[:0], c[:0], r[:0])
    assert (empty[qr, qc] == -1).all()
    with pytest.raises(IndexError):
        table[np.array([n]), np.array([0])]


def test_any_within_is_the_kd_tree_coverage(rng, reference_paths):
    from planner.geometry import tasks_connected

    for trial in range(300):
        n, m, w = int(rng.integers(1, 200)), int(rng.integers(1, 40)), rng.uniform(1, 20)
        x, tasks = rng.uniform(-w, w, (n, 2)), rng.uniform(-w, w, (m, 2))
        active = rng.random(n) > 0.2
        if trial % 5 == 0:
            x, tasks = np.round(x, 1), np.round(tasks, 1)
        if trial % 7 == 0:
            tasks[0] = x[0] + [2.0, 0.0]  # exactly at r: not covered (strict)
            active[0] = True
        got = tasks_connected(tasks, x, active, 2.0)
        reference_paths(True)
        want = tasks_connected(tasks, x, active, 2.0)
        reference_paths(False)
        assert np.array_equal(got, want), trial


def test_world_step_compiled_is_the_numpy_step(rng, reference_paths):
    """Whole episodes of the world with random instructions: same positions bit for bit, same losses."""
    from dataclasses import replace

    from mission.experiments.sim import draw_scenario, spawn_streams
    from planner.problem import problem_preset
    from vehicle_emu.world import World

    for size, seed in (("XS", 0), ("S", 1), ("M", 2)):
        problem = replace(problem_preset(size, 0.02))
        scenario = draw_scenario(problem, spawn_streams(seed))
        worlds = [World.from_scenario(problem, scenario) for _ in range(2)]
        vmax = problem.max_speed_m_s * problem.dt_s
        for t in range(60):
            active = worlds[0].active()
            disp = rng.normal(0, vmax, (problem.n_drones, 2)) * rng.choice(
                [0.0, 0.5, 3.0], (problem.n_drones, 1)
            )
            for k, world in enumerate(worlds):
                reference_paths(k == 1)
                lost = world.step(disp, active, problem.attrition_per_step, scenario.attrition_u[t])
            reference_paths(False)
            assert np.array_equal(worlds[0].pos_m, worlds[1].pos_m) and np.array_equal(
                worlds[0].alive, worlds[1].alive
            )
            assert lost.dtype == bool


def test_reaches_root_is_the_pointer_jumping_check(rng):
    from planner.steiner import _edge_lengths, _root_path_lengths

    for _ in range(500):
        k = int(rng.integers(1, 30))
        parent = rng.integers(0, k, k)  # TaskTree checks the range before the cycles
        parent[0] = -1
        if rng.random() < 0.5:  # a proper tree: parents earlier in a shuffle
            order = rng.permutation(np.arange(1, k))
            chain = np.concatenate([[0], order])
            for pos in range(1, k):
                parent[chain[pos]] = chain[rng.integers(0, pos)]
        try:
            _root_path_lengths(parent, _edge_lengths(np.zeros((k, 2)), parent))
            want = True
        except ValueError:
            want = False
        assert _graph_kernels.reaches_root(parent) is want


def test_pairs_within_is_the_numpy_recheck(rng):
    """neighbour_pairs' compiled re-check keeps exactly NumPy's pairs, in the KD-tree's order,
    also on distances at the range (rounded coordinates, pairs placed exactly at r) and on
    distances that differ from r by one ulp."""
    from scipy.spatial import cKDTree

    from planner.geometry import _recheck_pairs

    boundary = 0
    for trial in range(300):
        n, w, r = int(rng.integers(2, 300)), rng.uniform(1, 30), rng.uniform(0.5, 5)
        x = rng.uniform(-w, w, (n, 2))
        if trial % 3 == 0:
            x, r = np.round(x, 1), round(r, 1)
        if trial % 4 == 0:
            x[1] = x[0] + [r, 0.0]  # exactly at r: kept (inclusive)
            x[2] = x[0] + [0.0, np.nextafter(r, np.inf)]
        pairs = cKDTree(x).query_pairs(r * 1.01, output_type="ndarray")
        if len(pairs) == 0:
            continue
        got = _graph_kernels.pairs_within(x, pairs, r)
        want = _recheck_pairs(x, pairs, r)
        assert got is not None and np.array_equal(got, want), trial
        d = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1)
        boundary += int(np.sum(d == r))
    assert boundary > 0
    # The distance itself, on many random pairs: the kept set at r = each pair's own distance
    # (kept) and at the next float below it (dropped) is NumPy's.
    x = rng.normal(0, 1e3, (2000, 2)) * rng.uniform(1e-6, 1, (2000, 1))
    pairs = np.column_stack([np.arange(0, 2000, 2), np.arange(1, 2000, 2)])
    d = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1)
    for k in range(0, len(pairs), 50):
        for r in (d[k], np.nextafter(d[k], -np.inf)):
            got = _graph_kernels.pairs_within(x, pairs, r)
            assert np.array_equal(got, _recheck_pairs(x, pairs, r)), k


def test_knn_pairs_ring_search_dense_and_sparse(rng):
    """The ring search stops once the k-th best distance is inside the rings seen: dense clusters
    (many drones within reach, the k nearest a fraction of it), sparse spreads (whole-reach cells)
    and clusters plus outliers give the KD-tree reference's pairs, or decline."""
    answered = 0
    for trial in range(120):
        n = int(rng.integers(2, 400))
        side = float(rng.choice([0.3, 1.0, 3.0, 10.0, 200.0]))
        x = rng.uniform(0, side, (n, 2))
        if trial % 3 == 0:
            x[: n // 4] += rng.uniform(-50, 50, 2)  # a second cluster far away
        if trial % 7 == 0:
            x = np.round(x, 1)  # exact ties
        for k in (1, 3, 8):
            got = _graph_kernels.knn_pairs(x, 0.8, k)
            want = mccst._collision_candidates_reference(x, 0.8, k)
            if got is not None:
                answered += 1
                assert np.array_equal(got, want), (trial, k)
                assert got.dtype == want.dtype
    assert answered > 200


def test_finite_bbox_is_numpy_min_max(rng):
    """The one-pass bounding box equals ``min`` / ``max`` over axis 0, and is None exactly when
    some entry is NaN or infinite."""
    for trial in range(50):
        x = rng.normal(size=(int(rng.integers(1, 200)), 2)) * 10.0 ** rng.integers(-3, 4)
        if trial % 4 == 1:
            x[rng.integers(len(x)), rng.integers(2)] = [np.nan, np.inf, -np.inf][trial % 3]
        got = _graph_kernels._finite_bbox(np.ascontiguousarray(x))
        if not np.isfinite(x).all():
            assert got is None
            continue
        assert got == (*x.min(axis=0).tolist(), *x.max(axis=0).tolist())


def test_bounded_moves_declines_non_finite_input():
    """A NaN or infinite position, displacement or home declines (the world then runs NumPy)."""
    pos = np.zeros((3, 2))
    disp = np.full((3, 2), 0.1)
    act, alive = np.ones(3, bool), np.ones(3, bool)
    assert _graph_kernels.bounded_moves(pos, disp, act, alive, np.zeros(2), 1.0) is not None
    for bad in (np.nan, np.inf, -np.inf):
        for which in range(3):
            p, d, h = pos.copy(), disp.copy(), np.zeros(2)
            [p, d, h][which].flat[1] = bad
            assert _graph_kernels.bounded_moves(p, d, act, alive, h, 1.0) is None

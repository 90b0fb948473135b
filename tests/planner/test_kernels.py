"""The compiled kernels (planner._kernels) against their NumPy references.

Where the kernel repeats the NumPy arithmetic in the same order, the results must be identical bit
for bit (that is what keeps per-seed results unchanged); the all-pairs central kernel sums in
another order and must agree to rounding.
"""

import numpy as np
import pytest

from planner import _kernels
from planner.phireman import (
    PhiremanParams,
    PhiremanPlanner,
    TreeSegments,
    _pair_gradient_xy,
    _pair_gradient_xy_numpy,
    pair_gradient,
    pair_gradient_reference,
    task_gradient,
)
from planner.methods import TickInput
from planner.problem import problem_preset
from planner.steiner import TaskTree, build_task_tree

pytestmark = pytest.mark.skipif(not _kernels.NUMBA, reason="numba not installed")

KW = dict(attraction=0.05, floor=0.5, repulsion=0.3, reach=2.0, pair_factor=2.0)


@pytest.fixture
def numpy_only():
    """Run the NumPy reference paths inside the block."""

    def switch(on: bool):
        _kernels.ENABLED = not on

    yield switch
    _kernels.ENABLED = True


@pytest.mark.parametrize("n", [1, 2, 7, 150, 1600])
def test_central_pair_gradient_matches_dense_and_loops(rng, n):
    x = rng.uniform(-8, 8, (n, 2))
    mask = ~np.eye(n, dtype=bool)
    dense = pair_gradient(x, x, mask, **KW)
    scale = max(np.abs(dense).max(initial=0.0), 1e-300)
    assert np.allclose(
        _kernels.central_pair_gradient(x, **KW), dense, rtol=1e-10, atol=1e-10 * scale
    )
    if n <= 150:
        if n > 2:
            # coincident drones contribute nothing to each other (the dense kernel's d^2 expansion
            # cancels badly there, so only the loops are the reference for these)
            x[1] = x[0]
            x[2] = x[0] + [0.3, 0.0]  # inside the attraction floor and the repulsion reach
        ref = pair_gradient_reference(x, x, mask, **KW)
        assert np.allclose(
            _kernels.central_pair_gradient(x, **KW),
            ref,
            rtol=1e-12,
            atol=1e-12 * max(np.abs(ref).max(initial=0.0), 1e-300),
        )


@pytest.mark.parametrize(
    "n_tasks,nodes_only", [(0, False), (1, False), (9, False), (60, False), (9, True)]
)
def test_segment_gradient_bit_identical_to_task_gradient(rng, n_tasks, nodes_only):
    tree = build_task_tree(np.zeros(2), rng.uniform(-8, 8, (n_tasks, 2)))
    x = rng.uniform(-9, 9, (400, 2))
    x[:3] = tree.nodes_m[:3] if tree.n_nodes >= 3 else x[:3]  # on the tree: gradient 0
    if nodes_only or tree.n_nodes == 1:
        a = b = tree.nodes_m
    else:
        a, b = tree.segments()
    assert np.array_equal(
        _kernels.segment_gradient(x, a, b, 0.05), task_gradient(x, tree, 0.05, nodes_only)
    )


def test_segment_gradient_zero_length_edge(rng):
    nodes = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0], [-2.0, 3.0]])
    tree = TaskTree(nodes, np.array([-1, 0, 1, 0]), 3)
    x = rng.uniform(-4, 4, (100, 2))
    a, b = tree.segments()
    assert np.array_equal(_kernels.segment_gradient(x, a, b, 0.05), task_gradient(x, tree, 0.05))


@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize(
    "n,k,density", [(1, 1, 1.0), (40, 60, 0.3), (300, 300, 0.2), (20, 20, 0.0)]
)
def test_entries_pair_gradient_bit_identical(rng, n, k, density, weighted):
    x = rng.uniform(-6, 6, (n, 2))
    beliefs = rng.uniform(-6, 6, (n, k, 2))
    if k >= n:
        beliefs[np.arange(n), np.arange(n)] = x  # d = 0 entries
    beliefs[:, :2] = x[:, None, :] + [0.2, -0.1]  # inside floor and reach
    mask = rng.random((n, k)) < density
    r, c = np.nonzero(mask)
    w = rng.uniform(0.5, 2.0, n) if weighted else None
    args = (
        x,
        r,
        beliefs[r, c, 0].copy(),
        beliefs[r, c, 1].copy(),
        KW["attraction"],
        KW["floor"],
        KW["repulsion"],
        KW["reach"],
        KW["pair_factor"],
    )
    got = _pair_gradient_xy(*args, weight=w)
    want = _pair_gradient_xy_numpy(*args, weight=w)
    assert np.array_equal(got, want)
    if not weighted and n * k <= 20_000:
        ref = pair_gradient_reference(x, beliefs, mask, **KW)
        assert np.allclose(
            got, ref, rtol=1e-12, atol=1e-12 * max(np.abs(ref).max(initial=0.0), 1e-300)
        )


def test_tree_segments_entries_kernel_bit_identical(rng, numpy_only):
    trees = [
        build_task_tree(np.zeros(2), rng.uniform(-8, 8, (int(rng.integers(1, 30)), 2)))
        for _ in range(4)
    ]
    n = 400
    x0 = rng.uniform(-9, 9, (n, 2))
    version = rng.integers(0, 4, n)
    for nodes_only in (False, True):
        seg = TreeSegments(trees, version, nodes_only, x0, 0.15)
        for _ in range(3):
            x = x0 + rng.uniform(-0.1, 0.1, (n, 2))
            rows = np.flatnonzero(rng.random(n) < 0.4)
            for r in (np.arange(n), rows):
                got = seg.gradient(x[r], r, 0.05)
                numpy_only(True)
                want = seg.gradient(x[r], r, 0.05)
                numpy_only(False)
                assert np.array_equal(got, want)


@pytest.mark.parametrize("info", ["async", "central"])
def test_planner_with_and_without_kernels(rng, info, numpy_only):
    """Whole ticks: async bit for bit; central to rounding (its pair sum is reordered)."""
    prob = problem_preset("M", 0.01)
    outs = []
    for numpy_path in (False, True):
        numpy_only(numpy_path)
        planner = PhiremanPlanner(prob, PhiremanParams(info=info), np.random.default_rng(0))
        r = np.random.default_rng(5)
        pos = r.uniform(
            -prob.field_half_width_m / 3, prob.field_half_width_m / 3, (prob.n_drones, 2)
        )
        tasks = r.uniform(-prob.field_half_width_m, prob.field_half_width_m, (prob.n_tasks, 2))
        alive = np.ones(prob.n_drones, bool)
        disp = []
        for t in range(12):
            out = planner.plan(TickInput(t, pos, alive, alive, tasks))
            disp.append(out.disp_m)
            pos = pos + out.disp_m
        outs.append(np.array(disp))
    if info == "async":
        assert np.array_equal(outs[0], outs[1])
    else:
        assert np.allclose(outs[0], outs[1], rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    "thorn,max_steps,density",
    [(0.05, 10, 0.08), (0.0, 10, 0.08), (0.05, 2, 0.08), (0.5, 10, 0.08), (0.05, 10, 0.4)],
)
def test_compiled_async_descent_bit_identical(rng, thorn, max_steps, density):
    """descend_separable against descend(separable=True, per_drone) on the same entries, including
    the iterations / converged / hit_speed_limit diagnostics. density 0.4: ~120 entries a drone,
    several of the kernel's blocks (_kernels._PAIR_BLOCK) and a partial one; some believed
    positions on the drone (d = 0), within the attraction floor and at the reach exactly."""
    from planner.phireman import _descend_separable_compiled, _EntriesByDrone, descend

    n = 300
    trees = [
        build_task_tree(np.zeros(2), rng.uniform(-8, 8, (int(rng.integers(1, 20)), 2)))
        for _ in range(3)
    ]
    x0 = rng.uniform(-9, 9, (n, 2))
    version = rng.integers(0, 3, n)
    p = PhiremanParams(thorn=thorn, max_descent_steps=max_steps, speed_rule="per_drone")
    vmax, reach = 0.3, 2.0
    mask = rng.random((n, n)) < density
    mask[np.arange(n), np.arange(n)] = False
    r, c = np.nonzero(mask)
    y = x0[c] + rng.normal(0, 0.05, (len(r), 2))
    if density > 0.2:
        special = rng.choice(len(r), 60, replace=False)
        y[special[:20]] = x0[r[special[:20]]]  # on the drone: d = 0 at the first step
        y[special[20:40]] = x0[r[special[20:40]]] + [0.3, 0.0]  # within the floor
        y[special[40:]] = x0[r[special[40:]]] + [0.0, reach]  # at the reach exactly
    segs = TreeSegments(trees, version, False, x0, vmax)
    ent = _EntriesByDrone(r, y, n)

    def grad(x, rows):
        er, ox, oy = ent.of(rows)
        return (
            _pair_gradient_xy_numpy(
                x[rows],
                er,
                ox,
                oy,
                p.attraction,
                p.attraction_floor,
                p.repulsion,
                reach,
                p.pair_factor,
            )
            + segs._gradient_entries_numpy(x[rows], *_sub_entries(segs, rows), p.thorn)
            if p.thorn
            else _pair_gradient_xy_numpy(
                x[rows],
                er,
                ox,
                oy,
                p.attraction,
                p.attraction_floor,
                p.repulsion,
                reach,
                p.pair_factor,
            )
            + np.zeros((len(rows), 2))
        )

    want = descend(x0, grad, vmax, p, separable=True)
    got = _descend_separable_compiled(x0, ent, segs, p, reach, vmax)
    assert np.array_equal(got.disp_u, want.disp_u)
    assert (got.iterations, got.converged, got.hit_speed_limit) == (
        want.iterations,
        want.converged,
        want.hit_speed_limit,
    )


def _sub_entries(segs, rows):
    er, a, ab, ab2 = segs.entries
    chosen = np.zeros(segs.n, dtype=bool)
    chosen[rows] = True
    take = chosen[er]
    return (np.cumsum(chosen) - 1)[er[take]], a[take], ab[take], ab2[take]


@pytest.mark.parametrize("nodes_only", [False, True])
def test_tree_segments_compiled_pruning_identical(rng, numpy_only, nodes_only):
    trees = [
        build_task_tree(np.zeros(2), rng.uniform(-8, 8, (int(rng.integers(0, 40)), 2)))
        for _ in range(5)
    ]
    n = 500
    x0 = rng.uniform(-9, 9, (n, 2))
    x0[:5] = trees[0].nodes_m[0]  # on a node: distance 0
    version = rng.integers(0, 5, n)
    for radius in (0.0, 0.15, 3.0):
        fast = TreeSegments(trees, version, nodes_only, x0, radius)
        numpy_only(True)
        slow = TreeSegments(trees, version, nodes_only, x0, radius)
        numpy_only(False)
        for got, want in zip(fast.entries, slow.entries):
            assert got.dtype == want.dtype and np.array_equal(got, want)
        for name in ("a", "ab", "ab2", "valid"):  # the dense arrays, on request
            assert np.array_equal(getattr(fast, name), getattr(slow, name))


@pytest.mark.parametrize(
    "n,radius,age_max", [(60, 100.0, 3), (300, 4.0, 3), (520, 2.5, 3), (200, 5.0, 20), (50, 5.0, 0)]
)
def test_propagate_entries_compiled_identical(rng, numpy_only, n, radius, age_max):
    from planner.knowledge import propagate_entries, propagate_stamps_reference

    t_sent = 30
    stamp = np.where(
        rng.random((n, n)) < 0.3, rng.integers(t_sent - age_max - 2, t_sent + 1, (n, n)), -1
    )
    pos = rng.uniform(0, 40, (n, 2))
    d = np.linalg.norm(pos[:, None] - pos[None], axis=2)
    i, j = np.nonzero(np.triu(d <= radius, 1))
    pairs = np.column_stack([i, j])
    r, c = np.nonzero(stamp >= 0)
    got = propagate_entries(r, c, stamp[r, c], n, n, pairs, t_sent, age_max)
    numpy_only(True)
    want = propagate_entries(r, c, stamp[r, c], n, n, pairs, t_sent, age_max)
    numpy_only(False)
    for g, w in zip(got, want):
        assert np.array_equal(g, w)
    fresh = np.where(t_sent - stamp <= age_max, stamp, -1)
    table = np.full((n, n), -1)
    table[got[0], got[1]] = got[2]
    assert np.array_equal(table, propagate_stamps_reference(fresh, pairs))


def test_propagate_max_kernel_directly(rng):
    """The kernel itself (whatever the cost rule in propagate_entries picks) on a small case."""
    from planner.knowledge import propagate_stamps_reference

    n = 40
    stamp = np.where(rng.random((n, n)) < 0.4, rng.integers(0, 9, (n, n)), -1)
    pos = rng.uniform(0, 10, (n, 2))
    d = np.linalg.norm(pos[:, None] - pos[None], axis=2)
    i, j = np.nonzero(np.triu(d <= 3.0, 1))
    src = np.concatenate([j, i, np.arange(n)])
    dst = np.concatenate([i, j, np.arange(n)])
    order = np.argsort(dst, kind="stable")
    r, c = np.nonzero(stamp >= 0)
    start = np.searchsorted(r, np.arange(n + 1))
    nr, nc, ns = _kernels.propagate_max(
        start,
        c.astype(np.int64),
        stamp[r, c].astype(np.int64),
        np.searchsorted(dst[order], np.arange(n + 1)),
        src[order].astype(np.int64),
        n,
    )
    assert np.all(np.diff(nr * n + nc) > 0)  # row-major, no duplicates
    table = np.full((n, n), -1)
    table[nr, nc] = ns
    assert np.array_equal(table, propagate_stamps_reference(stamp, np.column_stack([i, j])))


@pytest.mark.parametrize(
    "n,spread,r",
    [
        (2, 1.0, 2.0),
        (50, 5.0, 2.0),
        (500, 50.0, 2.0),
        (3000, 150.0, 2.0),
        (400, 1000.0, 2.0),
        (300, 3.0, 0.7),
    ],
)
def test_radio_pairs_same_set_as_neighbour_pairs(rng, n, spread, r):
    from planner.geometry import neighbour_pairs, radio_pairs

    x = rng.uniform(-spread, spread, (n, 2))
    x[: n // 4] = np.round(x[: n // 4] / r) * r  # lattice points: pairs at exactly r
    x[-1] = x[0]  # coincident
    got = radio_pairs(x, r)
    want = neighbour_pairs(x, r)
    assert np.array_equal(got, want[np.lexsort((want[:, 1], want[:, 0]))])
    assert got.dtype == want.dtype
    loose = radio_pairs(x, r, ordered=False)
    assert np.array_equal(loose[np.lexsort((loose[:, 1], loose[:, 0]))], got)
    assert (loose[:, 0] < loose[:, 1]).all()


def test_radio_pairs_falls_back_outside_two_dimensions(rng):
    from planner.geometry import neighbour_pairs, radio_pairs

    x = rng.uniform(-3, 3, (60, 3))
    assert np.array_equal(radio_pairs(x, 1.0), neighbour_pairs(x, 1.0))


@pytest.mark.parametrize("after_move,forget", [(True, True), (False, False), (True, False)])
def test_knowledge_update_compiled_identical(rng, numpy_only, after_move, forget):
    """A run of the message layer with the compiled end of update and without: same tables, same
    entries, same views, every step (with losses, so dead holders and missing own entries occur)."""
    from planner.knowledge import MessageLayer

    n, steps = 120, 25
    layers = [
        MessageLayer(n, steps, 2.0, 2.0, 3, 6.0, 15, after_move=after_move, forget_unheard=forget)
        for _ in range(2)
    ]
    pos = rng.uniform(-3, 3, (n, 2))
    alive = np.ones(n, bool)
    for t in range(steps):
        for layer, numpy_path in zip(layers, (False, True)):
            numpy_only(numpy_path)
            layer.step(t, pos.copy(), alive.copy(), np.zeros(2), object())
        numpy_only(False)
        a, b = layers[0].knowledge, layers[1].knowledge
        assert np.array_equal(a.stamp, b.stamp) and np.array_equal(a.tree_stamp, b.tree_stamp)
        for name in (
            "held_rows",
            "held_cols",
            "held_stamps",
            "rows",
            "cols",
            "entry_rows",
            "entry_cols",
            "entry_believed_m",
        ):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
            assert getattr(a, name).dtype == getattr(b, name).dtype, name
        assert a.entry_believed_m.shape == b.entry_believed_m.shape
        pos = pos + rng.normal(0, 0.4, (n, 2))
        alive &= rng.random(n) > 0.03


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"leader_exponent": 2.0},
        {"leader_cap": 2},
        {"max_descent_steps": 2},
        {"leader_exponent": -1.0},
    ],
)
def test_dccrs_compiled_descent_identical(numpy_only, params):
    """DCCRS ticks with the compiled descent and with the NumPy one: same instructions and info."""
    from planner.methods import make_planner

    prob = problem_preset("M", 0.01)
    outs = []
    for numpy_path in (False, True):
        numpy_only(numpy_path)
        planner = make_planner("dccrs", prob, dict(params), np.random.default_rng(0))
        r = np.random.default_rng(7)
        pos = r.uniform(
            -prob.field_half_width_m / 3, prob.field_half_width_m / 3, (prob.n_drones, 2)
        )
        tasks = r.uniform(-prob.field_half_width_m, prob.field_half_width_m, (prob.n_tasks, 2))
        alive = np.ones(prob.n_drones, bool)
        run = []
        for t in range(15):
            out = planner.plan(TickInput(t, pos, alive, alive, tasks))
            run.append((out.disp_m, out.info.get("iterations"), out.info.get("converged")))
            pos = pos + out.disp_m
            alive &= r.random(prob.n_drones) > 0.01
        outs.append(run)
    for (d0, i0, c0), (d1, i1, c1) in zip(*outs):
        assert np.array_equal(d0, d1) and (i0, c0) == (i1, c1)


@pytest.mark.parametrize("m,cb", [(1, 1.0), (5, 1.0), (40, 1.0), (40, 0.0), (120, 0.5)])
def test_greedy_tree_compiled_pick_identical(rng, numpy_only, m, cb):
    tasks = rng.uniform(-20, 20, (m, 2))
    if m >= 5:
        tasks[1] = tasks[0]  # duplicate tasks: exact ties
        tasks[2:5] = [[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]  # collinear
    fast = build_task_tree(np.array([0.5, -0.5]), tasks, cb)
    numpy_only(True)
    slow = build_task_tree(np.array([0.5, -0.5]), tasks, cb)
    numpy_only(False)
    assert np.array_equal(fast.nodes_m, slow.nodes_m) and np.array_equal(fast.parent, slow.parent)


def test_believed_displacement_compiled_identical(rng, numpy_only):
    """DCCRS's believed displacements per entry: the compiled lookup + difference against the
    StampTable lookup and NumPy's difference, bit for bit (unknown entries and stamp 0 give 0)."""
    from planner import _message_kernels
    from planner.knowledge import MessageLayer

    n, steps = 90, 12
    layer = MessageLayer(n, steps, 2.0, 2.0, 3, 6.0, 15, after_move=True, forget_unheard=True)
    pos = rng.uniform(-3, 3, (n, 2))
    alive = np.ones(n, bool)
    seen: set[bool] = set()  # both known (stamp >= 1) and unknown entries were looked up
    for t in range(steps):
        layer.step(t, pos.copy(), alive.copy(), np.zeros(2), object())
        kn = layer.knowledge
        holders = rng.integers(0, n, 400)
        cols = rng.integers(0, n, 400)
        by_key = np.lexsort((cols, holders))
        some = np.sort(rng.choice(len(kn.held_rows), min(300, len(kn.held_rows)), replace=False))
        queries = [
            (holders, cols),  # any order
            (holders[by_key], cols[by_key]),  # row-major, as DCCRS asks (the search gallops on)
            (kn.held_rows[some], kn.held_cols[some]),  # held entries, row-major
            (np.r_[holders[by_key], holders[by_key]], np.r_[cols[by_key], cols[by_key]]),
        ]
        for holders, cols in queries:
            got = _message_kernels.believed_displacement(
                kn.held_rows, kn.held_cols, kn.held_stamps, n, holders, cols, kn.pos_hist_m
            )
            stamp = kn.stamp[holders, cols]
            s = np.where(stamp >= 1, stamp, 1)
            want = np.where(
                (stamp >= 1)[:, None], kn.pos_hist_m[s, cols] - kn.pos_hist_m[s - 1, cols], 0.0
            )
            assert got is not None and got.dtype == want.dtype
            assert np.array_equal(got.view(np.int64), want.view(np.int64))  # bits, -0.0 included
            seen |= {bool(v) for v in stamp >= 1}
        pos = pos + rng.normal(0, 0.4, (n, 2))
        alive &= rng.random(n) > 0.03
    numpy_only(True)
    assert (
        _message_kernels.believed_displacement(
            kn.held_rows, kn.held_cols, kn.held_stamps, n, holders, cols, kn.pos_hist_m
        )
        is None
    )


def test_near_counts_is_einsum_and_bincount(rng, numpy_only):
    """DCCRS's neighbour test over entries: the compiled pass against einsum + bincount, both signs."""
    from planner import _message_kernels

    for scale in (0.01, 1.0, 300.0):
        n, e = 60, 900
        holder = rng.normal(0, scale, (n, 2))
        er = np.sort(rng.integers(0, n, e))
        y_e = holder[er] + rng.normal(0, scale, (e, 2))
        r2 = float(np.median(np.einsum("ec,ec->e", holder[er] - y_e, holder[er] - y_e)))
        y_e[::7] = holder[er[::7]] + np.sqrt(r2) * np.array([0.6, 0.8])  # on the boundary
        for holder_first in (True, False):
            d = holder[er] - y_e if holder_first else y_e - holder[er]
            near = np.einsum("ec,ec->e", d, d) <= r2
            wide = np.zeros((n, 4))
            wide[:, ::2] = holder  # strided input, read in place
            for h in (holder, wide[:, ::2]):
                got = _message_kernels.near_counts(h, y_e, er, holder_first, r2)
                assert got is not None
                assert np.array_equal(got[0], near)
                assert np.array_equal(got[1], np.bincount(er[near], minlength=n))
                assert got[1].dtype == np.bincount(er[near], minlength=n).dtype
            assert 0 < near.sum() < e
    numpy_only(True)
    assert _message_kernels.near_counts(holder, y_e, er, True, r2) is None


def _grid_scan_reference(x, y, r, cell, x0, y0, nx, ny):
    """The pairs of grid_pairs(ordered=False) in its documented order, by plain loops: i ascending,
    the 3 x 3 cells around i's in (x, y) order, the drones of a cell ascending, j > i kept."""
    cx = [min(max(int((x[i] - x0) / cell), 0), nx - 1) for i in range(len(x))]
    cy = [min(max(int((y[i] - y0) / cell), 0), ny - 1) for i in range(len(x))]
    out = []
    for i in range(len(x)):
        for ax in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
            for ay in range(max(cy[i] - 1, 0), min(cy[i] + 2, ny)):
                for j in range(len(x)):
                    if (cx[j], cy[j]) == (ax, ay) and j > i:
                        if np.linalg.norm([x[i] - x[j], y[i] - y[j]]) <= r:
                            out.append((i, j))
    return np.array(out, dtype=np.int64).reshape(-1, 2)


@pytest.mark.parametrize("n,spread,r", [(1, 1.0, 2.0), (60, 5.0, 2.0), (300, 3.0, 0.7)])
def test_grid_pairs_unordered_in_scan_order(rng, n, spread, r):
    """grid_pairs' unordered pairs in the order of the plain scan (cells counting-sorted, coincident
    and on-the-range pairs included, the output grown past its first capacity at (300, 3, 0.7))."""
    x = rng.uniform(-spread, spread, (n, 2))
    x[: n // 4] = np.round(x[: n // 4] / r) * r
    x[-1] = x[0]
    lo = x.min(axis=0)
    cell = r * (1 + 1e-6)
    nx, ny = (int(v) for v in (x.max(axis=0) - lo) // cell + 1)
    args = (x[:, 0].copy(), x[:, 1].copy(), r, cell, float(lo[0]), float(lo[1]), nx, ny)
    want = _grid_scan_reference(*args)
    got = _kernels.grid_pairs(*args, False)
    assert got.dtype == np.int64 and np.array_equal(got, want)
    ordered = _kernels.grid_pairs(*args, True)
    assert np.array_equal(ordered, want[np.lexsort((want[:, 1], want[:, 0]))])


@pytest.mark.parametrize("exponent", [1.0, 2.0, 0.5])
def test_leader_descent_step_nearest_leader_rule(rng, exponent):
    """descend_separable_leader's leader term (one step, no pair entries) against
    dccrs.leader_gradient: 37 leaders a drone (a partial SIMD block), exact ties (the first wins),
    a leader on the drone (no pull), and NaN leaders, which the kernel skips (compared with the
    gradient of the same leaders without them)."""
    from planner.dccrs import leader_gradient

    n, n_lead, eta, r, lfloor = 60, 37, 0.2, 2.0, 0.5
    pos = np.round(rng.uniform(-9, 9, (n, 2)) * 64) / 64  # dyadic: the ties below are exact
    lead = rng.uniform(-9, 9, (n, n_lead, 2))
    lead[:10, 4] = pos[:10] + [1 / 64, 0.0]  # ties at the same distance: the first (column 4) wins
    lead[:10, 20] = pos[:10] - [1 / 64, 0.0]
    lead[10:15, 7] = pos[10:15]  # on the drone: d = 0
    lead[20:30, 3:11:2, 0] = np.nan  # every other one of a SIMD block
    gain = rng.uniform(0.5, 2.0, n)
    delta, _, _ = _kernels.descend_separable_leader(
        *(np.ascontiguousarray(pos[:, c]) for c in (0, 1)),
        np.zeros(n + 1, np.int64),
        np.empty(0),
        np.empty(0),
        np.ones(n),
        *(np.ascontiguousarray(lead[..., c]) for c in (0, 1)),
        gain,
        exponent,
        r,
        lfloor,
        0.5,
        0.3,
        2.0,
        2.0,
        eta,
        0.0,  # tolerance
        1e9,  # vmax: never at the limit
        1,
    )
    clean = np.delete(lead, [3, 5, 7, 9], axis=1)
    want = np.where(
        (np.arange(n) >= 20)[:, None] & (np.arange(n) < 30)[:, None],
        leader_gradient(pos, clean, gain, exponent, r, lfloor),
        leader_gradient(pos, np.where(np.isnan(lead), 0.0, lead), gain, exponent, r, lfloor),
    )
    assert np.array_equal(delta, -eta * want)  # == on floats: 0.0 and -0.0 are equal
    assert np.all(delta[10:15] == 0) and np.all(delta[:10, 0] > 0)  # ties: toward column 4

"""The entry-list (sparse) kernels of the async model against their dense versions and the loops.

The gradient kernels must agree with the dense kernels and the loops to rounding (~1e-12 relative;
the summation order may differ, so the last bits may too). The message layer works on integer
stamps: there the entry version must give *identical* tables to the dense one.
"""

import numpy as np
import pytest

from planner.dccrs import (
    velocity_match,
    velocity_match_entries,
    velocity_match_reference,
    weighted_pair_gradient,
    weighted_pair_gradient_entries,
)
from planner.knowledge import MessageLayer, propagate_stamps, propagate_stamps_reference
from planner.phireman import (
    TreeSegments,
    padded_segments,
    pair_gradient,
    pair_gradient_entries,
    pair_gradient_reference,
    task_gradient_batched,
)
from planner.steiner import build_task_tree

KW = dict(attraction=0.05, floor=0.5, repulsion=0.3, reach=2.0, pair_factor=2.0)


def _view(rng, n, k, density, spread=8.0):
    x = rng.uniform(-spread, spread, (n, 2))
    beliefs = rng.uniform(-spread, spread, (n, k, 2))
    mask = rng.random((n, k)) < density
    if k >= n:  # some beliefs coincide with the holder (d = 0 must be skipped)
        beliefs[np.arange(n), np.arange(n)] = x
    return x, beliefs, mask


def _close(got, want, tol=1e-12):
    """Agreement to ``tol`` relative to the largest component (sums of many terms may cancel)."""
    scale = max(np.abs(want).max(initial=0.0), 1e-300)
    return np.allclose(got, want, rtol=tol, atol=tol * scale)


@pytest.mark.parametrize(
    "n,k,density",
    [
        (1, 1, 1.0),
        (3, 5, 0.5),
        (40, 60, 0.3),
        (200, 500, 0.12),
        (500, 500, 0.85),
        (7, 300, 0.02),
        (20, 20, 0.0),
    ],
)
def test_pair_gradient_entries_match_dense_and_reference(rng, n, k, density):
    x, beliefs, mask = _view(rng, n, k, density)
    sq = np.einsum("nkc,nkc->nk", beliefs, beliefs)
    dense = pair_gradient(x, beliefs, mask, others_sq=sq, **KW)
    r, c = np.nonzero(mask)
    got = pair_gradient_entries(
        x,
        r,
        beliefs[r, c],
        KW["attraction"],
        KW["floor"],
        KW["repulsion"],
        KW["reach"],
        KW["pair_factor"],
    )
    # the dense kernel expands d^2 = |x|^2 + |y|^2 - 2 x.y (about |x|^2 eps lost): close, not exact
    assert _close(got, dense, 1e-10)
    if n * k <= 100_000:
        assert _close(got, pair_gradient_reference(x, beliefs, mask, **KW))
    # the entries may come in any order (the sum per drone is the same to rounding)
    perm = rng.permutation(len(r))
    assert _close(
        pair_gradient_entries(
            x,
            r[perm],
            beliefs[r[perm], c[perm]],
            KW["attraction"],
            KW["floor"],
            KW["repulsion"],
            KW["reach"],
            KW["pair_factor"],
        ),
        got,
    )


def _weighted_reference(x, beliefs, mask, w):
    out = np.zeros((len(x), 2))
    for i in range(len(x)):
        for k in range(beliefs.shape[1]):
            if not mask[i, k]:
                continue
            dx = x[i] - beliefs[i, k]
            d = float(np.hypot(*dx))
            if d > KW["floor"]:
                out[i] += KW["pair_factor"] * w[i] * KW["attraction"] * dx / d**3
            if 0 < d < KW["reach"]:
                out[i] -= KW["pair_factor"] * KW["repulsion"] * (KW["reach"] - d) * dx / d
    return out


@pytest.mark.parametrize(
    "n,k,density", [(1, 1, 1.0), (40, 60, 0.3), (200, 500, 0.12), (500, 500, 0.85)]
)
def test_weighted_pair_gradient_entries_match_dense_and_reference(rng, n, k, density):
    x, beliefs, mask = _view(rng, n, k, density)
    w = rng.uniform(0.5, 2.0, n)
    dense = weighted_pair_gradient(
        x,
        beliefs,
        mask,
        w,
        KW["attraction"],
        KW["floor"],
        KW["repulsion"],
        KW["reach"],
        KW["pair_factor"],
    )
    r, c = np.nonzero(mask)
    got = weighted_pair_gradient_entries(
        x,
        r,
        beliefs[r, c],
        w,
        KW["attraction"],
        KW["floor"],
        KW["repulsion"],
        KW["reach"],
        KW["pair_factor"],
    )
    assert _close(got, dense)
    if n * k <= 100_000:
        assert _close(got, _weighted_reference(x, beliefs, mask, w))


@pytest.mark.parametrize("n,k,density", [(1, 1, 1.0), (40, 60, 0.3), (300, 500, 0.12)])
def test_velocity_match_entries_bit_identical_to_dense(rng, n, k, density):
    disp = rng.normal(0, 0.2, (n, 2))
    vel = rng.normal(0, 0.1, (n, k, 2))
    near = rng.random((n, k)) < density
    dense = velocity_match(disp, near, vel, 0.3, 0.15)
    r, c = np.nonzero(near)
    got = velocity_match_entries(disp, r, vel[r, c], 0.3, 0.15)
    assert np.array_equal(got, dense)
    if n * k <= 3000:
        assert np.allclose(got, velocity_match_reference(disp, near, vel, 0.3, 0.15), atol=1e-12)


def test_tree_segments_bit_identical_to_batched(rng):
    trees = [
        build_task_tree(np.zeros(2), rng.uniform(-5, 5, (int(rng.integers(1, 12)), 2)))
        for _ in range(5)
    ]
    x = rng.uniform(-6, 6, (300, 2))
    version = rng.integers(0, 5, 300)
    for nodes_only in (False, True):
        seg = TreeSegments(trees, version, nodes_only)
        full = task_gradient_batched(x, *padded_segments(trees, nodes_only), version, 0.05)
        assert np.array_equal(seg.gradient(x, np.arange(300), 0.05), full)
        rows = np.flatnonzero(rng.random(300) < 0.3)
        assert np.array_equal(
            seg.gradient(x[rows], rows, 0.05),
            task_gradient_batched(
                x[rows], *padded_segments(trees, nodes_only), version[rows], 0.05
            ),
        )


def test_sparse_propagation_matches_reference(rng):
    """Above the sparse threshold the one-hop product uses a sparse adjacency matrix."""
    for n in (300, 520):
        stamp = rng.integers(-1, 12, (n, n))
        pos = rng.uniform(0, 40, (n, 2))
        d = np.linalg.norm(pos[:, None] - pos[None], axis=2)
        i, j = np.nonzero(np.triu(d <= 3.0, 1))
        pairs = np.column_stack([i, j])
        assert (propagate_stamps(stamp, pairs) == propagate_stamps_reference(stamp, pairs)).all()
        t_sent, age_max = 11, 3
        fresh = np.where(t_sent - stamp <= age_max, stamp, -1)
        expected = np.maximum(propagate_stamps_reference(fresh, pairs), stamp)
        assert (propagate_stamps(stamp, pairs, t_sent, age_max) == expected).all()


def test_view_entries_are_the_known_entries_of_the_dense_view(rng):
    n = 60
    layer = MessageLayer(n, 20, 2.0, 2.0, 3, 6.0, 15, after_move=True, forget_unheard=True)
    pos = rng.uniform(-4, 4, (n, 2))
    alive = np.ones(n, bool)
    for t in range(6):
        alive &= rng.random(n) > 0.05
        pos = pos + rng.normal(0, 0.3, pos.shape)
        layer.step(t, pos, alive, np.zeros(2), t)
    kn = layer.knowledge
    holders = kn.rows[rng.random(len(kn.rows)) < 0.7]
    er, ek, believed, stamps = layer.view_entries(holders)
    dense, known, stamps2 = layer.view(holders)
    r, c = np.nonzero(known)
    assert np.array_equal(er, r) and np.array_equal(ek, c)
    assert np.array_equal(believed, dense[r, c]) and np.array_equal(stamps, stamps2)
    # each entry is the true position of drone cols[k] at its stamp, and never the holder itself
    s = kn.stamp[holders[er], kn.cols[ek]]
    assert (s >= 0).all() and (holders[er] != kn.cols[ek]).all()
    assert np.array_equal(believed, kn.pos_hist_m[s, kn.cols[ek]])
    # the known mask is exactly: valid stamp, not self, within dist_max of the holder
    sub = kn.stamp[np.ix_(holders, kn.cols)]
    expect = (sub >= 0) & (holders[:, None] != kn.cols[None, :])
    assert np.array_equal(known, expect)


def test_tree_segments_pruned_to_candidates_bit_identical(rng):
    """Keeping only the segments that can be nearest within ``radius`` of the tick's start."""
    trees = [
        build_task_tree(np.zeros(2), rng.uniform(-8, 8, (int(rng.integers(1, 30)), 2)))
        for _ in range(4)
    ]
    n = 400
    x0 = rng.uniform(-9, 9, (n, 2))
    version = rng.integers(0, 4, n)
    for nodes_only in (False, True):
        seg = TreeSegments(trees, version, nodes_only, x0, 0.15)
        padded = padded_segments(trees, nodes_only)
        assert len(seg.entries[0]) < n * padded[0].shape[1] / 3  # the pruning does prune
        for _ in range(5):
            step = rng.normal(size=(n, 2))
            step *= (0.15 * rng.random(n) / np.linalg.norm(step, axis=1))[:, None]
            x = x0 + step
            assert np.array_equal(
                seg.gradient(x, np.arange(n), 0.05),
                task_gradient_batched(x, *padded, version, 0.05),
            )
            rows = np.flatnonzero(rng.random(n) < 0.4)
            assert np.array_equal(
                seg.gradient(x[rows], rows, 0.05),
                task_gradient_batched(x[rows], *padded, version[rows], 0.05),
            )

"""Compiled graph and geometry kernels (Numba): the MCCST's spanning tree, collision pairs and edge
terms, the radio graph's reach from the base, the tasks' coverage, the world's bounded moves, the
message layer's bit-set hop.

Kept apart from :mod:`planner._kernels` (the planners' descent and message kernels) so that each
module stays readable; the same rules hold (docs in :mod:`planner._kernels`): every kernel has a
NumPy / SciPy reference in the module that calls it, ``tests/planner/test_graph_kernels.py``
compares the two, nothing here uses ``fastmath``, and when Numba is missing (``_kernels.NUMBA``
False) or switched off (``_kernels.ENABLED`` False) the callers run the references.

Every kernel here returns a *set* (a tree's edges, a mask, sorted pairs) that does not depend on
the order in which it was found, so the callers get exactly the reference's result, not merely
the same result up to rounding.

Length (over the ~600 lines this code base aims for): the compiled graph kernels (spanning
tree, grid neighbours, connectivity, edge terms) share their grid and CSR helpers, and each sits
beside the NumPy/SciPy reference it is tested against (tests/planner/test_graph_kernels.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numpy as np

from planner import _kernels

__all__ = [
    "mst_prim",
    "reach_from",
    "knn_pairs",
    "hop_bitsets",
    "edge_terms",
    "pairs_within",
    "any_within",
    "bounded_moves",
    "reaches_root",
]

_F = TypeVar("_F", bound=Callable[..., Any])


def _jit(func: _F) -> _F:
    """``numba.njit(cache=True)`` with the function's own signature for the type checker (Numba's
    decorator is untyped); the plain function when Numba is missing."""
    if not _kernels.NUMBA:  # pragma: no cover
        return func
    from numba import njit

    return cast(_F, njit(cache=True)(func))


def _mst_prim(n_nodes: int, edges: np.ndarray, w: np.ndarray) -> tuple[bool, np.ndarray]:
    n_edges = edges.shape[0]
    # CSR adjacency: each undirected edge listed at both ends (edge id, other end, weight), int32
    # ids and the weight stored inline: the relaxation reads it sequentially.
    deg = np.zeros(n_nodes + 1, dtype=np.int64)
    for e in range(n_edges):
        if math.isnan(w[e]):
            return False, np.zeros(0, dtype=np.int64)
        deg[edges[e, 0] + 1] += 1
        deg[edges[e, 1] + 1] += 1
    for v in range(n_nodes):
        deg[v + 1] += deg[v]
    fill = deg[:-1].copy()
    adj_e = np.empty(2 * n_edges, dtype=np.int32)
    adj_v = np.empty(2 * n_edges, dtype=np.int32)
    adj_w = np.empty(2 * n_edges)
    for e in range(n_edges):
        a, b = edges[e, 0], edges[e, 1]
        we = w[e]
        fa = fill[a]
        adj_e[fa] = e
        adj_v[fa] = b
        adj_w[fa] = we
        fill[a] = fa + 1
        fb = fill[b]
        adj_e[fb] = e
        adj_v[fb] = a
        adj_w[fb] = we
        fill[b] = fb + 1
    in_tree = np.zeros(n_nodes, dtype=np.bool_)
    key_w = np.full(n_nodes, np.inf)
    key_e = np.full(n_nodes, -1, dtype=np.int64)
    # The frontier: vertices outside the tree with an edge into it (key_e >= 0), unordered, and
    # each one's slot in it; the next vertex is searched there only, not among all n.
    front = np.empty(n_nodes, dtype=np.int64)
    slot = np.full(n_nodes, -1, dtype=np.int64)
    n_front = 0
    out = np.empty(max(n_nodes - 1, 0), dtype=np.int64)
    m = 0
    for root in range(n_nodes):
        if in_tree[root]:
            continue
        v = root
        while v >= 0:
            in_tree[v] = True
            if key_e[v] >= 0:
                out[m] = key_e[v]
                m += 1
                last = front[n_front - 1]  # swap-remove v from the frontier
                front[slot[v]] = last
                slot[last] = slot[v]
                n_front -= 1
            for q in range(deg[v], deg[v + 1]):
                u = adj_v[q]
                if in_tree[u]:
                    continue
                eq = adj_e[q]
                we = adj_w[q]
                if key_e[u] < 0:
                    front[n_front] = u
                    slot[u] = n_front
                    n_front += 1
                if we < key_w[u] or (we == key_w[u] and (key_e[u] < 0 or eq < key_e[u])):
                    key_w[u] = we
                    key_e[u] = eq
            # the next vertex: the lightest edge (weight, then index) into the tree; the keys of
            # distinct frontier vertices are distinct edges, so the scan order does not matter
            v = -1
            bw = np.inf
            be = -1
            for f in range(n_front):
                u = front[f]
                if key_w[u] < bw or (key_w[u] == bw and key_e[u] < be) or be < 0:
                    bw = key_w[u]
                    be = key_e[u]
                    v = u
    return True, np.sort(out[:m])


_mst_prim_jit = _jit(_mst_prim)

#: Above this many nodes the O(n^2) vertex scan of :func:`mst_prim` loses to the sort-based
#: reference (MCCST's swarms have at most 501 nodes in the paper's sizes).
MST_PRIM_MAX_NODES = 4000


def mst_prim(n_nodes: int, edges: np.ndarray, weights: np.ndarray) -> np.ndarray | None:
    """The minimum spanning forest of ``edges`` (unique unordered pairs) under the strict order
    (weight, edge index), as sorted edge indices; None when the kernel does not apply (no Numba,
    switched off, NaN weights, more than ``MST_PRIM_MAX_NODES`` nodes).

    Under a strict total order the minimum spanning forest is unique, so this is exactly the edge
    set of :func:`planner.mccst.spanning_tree_edges`'s reference path (weights replaced by their
    ranks, ties by index, then scipy's ``minimum_spanning_tree``). Prim's algorithm on a CSR
    adjacency with a scan of the frontier (the vertices with an edge into the tree) for the next
    vertex: O(n^2 + E) at worst, no sort of the E weights. (A binary heap in place of the scan was
    ~1.6x slower on the XL ticks: keys improve often, so it pushes ~E entries.)
    """
    if not (_kernels.NUMBA and _kernels.ENABLED) or n_nodes > MST_PRIM_MAX_NODES:
        return None
    ok, tree = _mst_prim_jit(
        int(n_nodes),
        np.ascontiguousarray(edges, dtype=np.int64),
        np.ascontiguousarray(weights, dtype=np.float64),
    )
    return tree.astype(np.intp) if ok else None


def _grid_buckets(
    x: np.ndarray, y: np.ndarray, cell: float, x0: float, y0: float, nx: int, ny: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each point's cell (cx, cy) in an ``nx`` x ``ny`` grid of ``cell``-sized cells from (x0, y0),
    clamped to the grid, and the points by cell: ``members[head[c]:head[c + 1]]`` are the points of
    cell ``c = cx * ny + cy`` in ascending index (a counting sort)."""
    n = len(x)
    cx = np.empty(n, dtype=np.int64)
    cy = np.empty(n, dtype=np.int64)
    for i in range(n):
        cx[i] = min(max(int((x[i] - x0) / cell), 0), nx - 1)
        cy[i] = min(max(int((y[i] - y0) / cell), 0), ny - 1)
    head = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(n):
        head[cx[i] * ny + cy[i] + 1] += 1
    for c in range(nx * ny):
        head[c + 1] += head[c]
    fill = head[:-1].copy()
    members = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = cx[i] * ny + cy[i]
        members[fill[c]] = i
        fill[c] += 1
    return cx, cy, head, members


if _kernels.NUMBA:
    from numba import njit as _njit_inline

    _grid_buckets = _njit_inline(cache=True, inline="always")(_grid_buckets)


def _bbox(pos: np.ndarray) -> tuple[bool, float, float, float, float]:
    lo_x = np.inf
    lo_y = np.inf
    hi_x = -np.inf
    hi_y = -np.inf
    for i in range(pos.shape[0]):
        a = pos[i, 0]
        b = pos[i, 1]
        if not (math.isfinite(a) and math.isfinite(b)):
            return False, 0.0, 0.0, 0.0, 0.0
        lo_x = min(lo_x, a)
        lo_y = min(lo_y, b)
        hi_x = max(hi_x, a)
        hi_y = max(hi_y, b)
    return True, lo_x, lo_y, hi_x, hi_y


_bbox_jit = _jit(_bbox)


def _finite_bbox(pos: np.ndarray) -> tuple[float, float, float, float] | None:
    """(min x, min y, max x, max y) of an (n >= 1, 2) float64 array in one pass (the values of
    ``pos.min(axis=0)`` / ``pos.max(axis=0)``: a minimum is exact), or None if some entry is not
    finite (``not np.isfinite(pos).all()``)."""
    ok, lo_x, lo_y, hi_x, hi_y = _bbox_jit(pos)
    return (lo_x, lo_y, hi_x, hi_y) if ok else None


def _reach_from(
    x: np.ndarray,
    y: np.ndarray,
    reached: np.ndarray,
    range_m: float,
    cell: float,
    x0: float,
    y0: float,
    nx: int,
    ny: int,
) -> np.ndarray:
    n = len(x)
    cx, cy, head, members = _grid_buckets(x, y, cell, x0, y0, nx, ny)
    out = reached.copy()
    queue = np.empty(n, dtype=np.int64)
    tail = 0
    for i in range(n):
        if out[i]:
            queue[tail] = i
            tail += 1
    front = 0
    while front < tail:
        i = queue[front]
        front += 1
        for ax in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
            for ay in range(max(cy[i] - 1, 0), min(cy[i] + 2, ny)):
                c = ax * ny + ay
                for q in range(head[c], head[c + 1]):
                    j = members[q]
                    if out[j]:
                        continue
                    dx = x[i] - x[j]
                    dy = y[i] - y[j]
                    if math.sqrt(dx * dx + dy * dy) <= range_m:
                        out[j] = True
                        queue[tail] = j
                        tail += 1
    return out


_reach_from_jit = _jit(_reach_from)


def reach_from(pos_m: np.ndarray, reached: np.ndarray, range_m: float) -> np.ndarray | None:
    """Every drone joined to a ``reached`` one by a chain of links |x_i - x_j| <= ``range_m``
    (the distance computed as :func:`planner.geometry.neighbour_pairs` computes it), as an (n,)
    bool mask: a breadth-first search over a uniform grid, no pair list. None when the kernel
    does not apply (no Numba, switched off, non-finite input, or a spread too sparse for a grid:
    the caller then uses the pair list)."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or not np.isfinite(range_m) or range_m <= 0:
        return None
    n = len(pos_m)
    if n == 0 or pos_m.ndim != 2 or pos_m.shape[1] != 2:
        return None
    pos_m = np.ascontiguousarray(pos_m, dtype=np.float64)
    box = _finite_bbox(pos_m)
    if box is None:
        return None
    lo_x, lo_y, hi_x, hi_y = box
    cell = float(range_m) * (1 + 1e-6)  # > range: a link lies in the same or adjacent cells
    nx = int((hi_x - lo_x) // cell) + 1
    ny = int((hi_y - lo_y) // cell) + 1
    if nx * ny > 8 * n + 4096:
        return None
    return _reach_from_jit(
        np.ascontiguousarray(pos_m[:, 0]),
        np.ascontiguousarray(pos_m[:, 1]),
        np.asarray(reached, dtype=np.bool_),
        float(range_m),
        cell,
        lo_x,
        lo_y,
        nx,
        ny,
    )


def _knn_pairs(
    pos: np.ndarray,
    reach: float,
    k: int,
    cell: float,
    x0: float,
    y0: float,
    nx: int,
    ny: int,
) -> tuple[bool, np.ndarray]:
    n = pos.shape[0]
    x = pos[:, 0]
    y = pos[:, 1]
    cx, cy, head, members = _grid_buckets(x, y, cell, x0, y0, nx, ny)
    best_d = np.empty(k)
    best_j = np.empty(k, dtype=np.int64)
    near_d = np.empty(n)  # every drone strictly within reach of i seen, for the tie check
    near_j = np.empty(n, dtype=np.int64)
    lo_end = np.empty(n * k, dtype=np.int64)
    hi_end = np.empty(n * k, dtype=np.int64)
    m = 0
    for i in range(n):
        nb = 0
        n_near = 0
        # Square rings of cells around i's cell, nearest first. A drone outside the rings
        # 0..ring lies farther than ring * cell (less a rounding margin) from i: once the k-th
        # best distance is below that, no unseen drone can enter (or tie) the k best; once it
        # exceeds reach (plus the near-reach band), every drone within reach has been seen.
        ring = 0
        while True:
            for ax in range(max(cx[i] - ring, 0), min(cx[i] + ring + 1, nx)):
                edge_x = ax == cx[i] - ring or ax == cx[i] + ring
                ay = max(cy[i] - ring, 0)
                ay_stop = min(cy[i] + ring + 1, ny)
                while ay < ay_stop:
                    if not edge_x and ay != cy[i] - ring and ay != cy[i] + ring:
                        ay = cy[i] + ring  # inner cells were seen in earlier rings
                        continue
                    c = ax * ny + ay
                    ay += 1
                    for q in range(head[c], head[c + 1]):
                        j = members[q]
                        if j == i:
                            continue
                        dx = x[i] - x[j]
                        dy = y[i] - y[j]
                        d = math.sqrt(dx * dx + dy * dy)
                        # A distance within rounding of ``reach``: the KD-tree reference's
                        # squared-distance test decides; report it, the caller falls back.
                        if abs(d - reach) <= 1e-9 * reach:
                            return False, np.zeros((0, 2), dtype=np.int64)
                        if not d < reach:
                            continue
                        near_d[n_near] = d
                        near_j[n_near] = j
                        n_near += 1
                        # insert (d, j) into the sorted list of the k best, order (distance, index)
                        if nb == k and not (
                            d < best_d[k - 1] or (d == best_d[k - 1] and j < best_j[k - 1])
                        ):
                            continue
                        p = nb if nb < k else k - 1
                        while p > 0 and (
                            d < best_d[p - 1] or (d == best_d[p - 1] and j < best_j[p - 1])
                        ):
                            if p < k:
                                best_d[p] = best_d[p - 1]
                                best_j[p] = best_j[p - 1]
                            p -= 1
                        best_d[p] = d
                        best_j[p] = j
                        if nb < k:
                            nb += 1
            seen = (ring * cell) * (1.0 - 1e-6)  # every unseen drone is at least this far
            if nb == k and best_d[k - 1] < seen:
                break
            if seen > reach * (1.0 + 1e-6):
                break
            if cx[i] - ring <= 0 and cx[i] + ring >= nx - 1 and cy[i] - ring <= 0:
                if cy[i] + ring >= ny - 1:
                    break  # the rings cover the whole grid
            ring += 1
        # A tie at the k-th distance is broken by whatever order the KD-tree reference visits
        # points in: report it, the caller falls back. Such a drone is no farther than the k-th
        # distance, so it was seen: the drones recorded above are all there is to check.
        if nb == k:
            kth = best_d[k - 1]
            for q in range(n_near):
                if near_d[q] == kth and not _in(best_j, nb, near_j[q]):
                    return False, np.zeros((0, 2), dtype=np.int64)
        for q in range(nb):
            j = best_j[q]
            lo_end[m] = min(i, j)
            hi_end[m] = max(i, j)
            m += 1
    # The pairs sorted by (lo, hi), duplicates (j among i's k best and i among j's) dropped:
    # a counting sort by lo, then an insertion sort of each lo's few partners.
    start = np.zeros(n + 1, dtype=np.int64)
    for q in range(m):
        start[lo_end[q] + 1] += 1
    for v in range(n):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    partner = np.empty(m, dtype=np.int64)
    for q in range(m):
        partner[fill[lo_end[q]]] = hi_end[q]
        fill[lo_end[q]] += 1
    out = np.empty((m, 2), dtype=np.int64)
    n_out = 0
    for v in range(n):
        a = start[v]
        b = start[v + 1]
        for q in range(a + 1, b):
            val = partner[q]
            p = q
            while p > a and partner[p - 1] > val:
                partner[p] = partner[p - 1]
                p -= 1
            partner[p] = val
        for q in range(a, b):
            if q == a or partner[q] != partner[q - 1]:
                out[n_out, 0] = v
                out[n_out, 1] = partner[q]
                n_out += 1
    return True, out[:n_out].copy()


def _in(values: np.ndarray, count: int, v: int) -> bool:
    for q in range(count):
        if values[q] == v:
            return True
    return False


if _kernels.NUMBA:
    from numba import njit as _njit

    _in = _njit(cache=True, inline="always")(_in)


_knn_pairs_jit = _jit(_knn_pairs)

#: Grid cells per ``reach`` of :func:`knn_pairs` (when the spread allows that many cells).
KNN_CELLS_PER_REACH = 4


def knn_pairs(x: np.ndarray, reach: float, k: int) -> np.ndarray | None:
    """Pairs (i, j), i < j, sorted, unique, such that j is among i's ``k`` nearest drones strictly
    closer than ``reach`` or i among j's (nearest by (distance, index); distance as
    ``np.linalg.norm`` of the difference). The grid twin of :func:`planner.mccst.collision_candidates`
    with a cap; None when the kernel does not apply (the caller uses the KD-tree), and None on a tie
    at some drone's k-th distance or a distance within 1e-9 (relative) of ``reach``: there the
    KD-tree's visiting order, or its squared-distance test, decides, and only the reference
    reproduces it."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or not np.isfinite(reach) or reach <= 0 or k <= 0:
        return None
    n = len(x)
    if n < 2 or x.ndim != 2 or x.shape[1] != 2:
        return None
    x = np.ascontiguousarray(x, dtype=np.float64)
    box = _finite_bbox(x)
    if box is None:
        return None
    lo_x, lo_y, hi_x, hi_y = box
    # Cells of a quarter of reach: the k nearest of a drone in a dense swarm lie much closer
    # than reach, and the ring search stops at them. Whole-reach cells for sparse spreads.
    cell = float(reach) * (1 + 1e-5) / KNN_CELLS_PER_REACH
    nx = int((hi_x - lo_x) // cell) + 1
    ny = int((hi_y - lo_y) // cell) + 1
    if nx * ny > 8 * n + 4096:
        cell = float(reach) * (1 + 1e-5)
        nx = int((hi_x - lo_x) // cell) + 1
        ny = int((hi_y - lo_y) // cell) + 1
        if nx * ny > 8 * n + 4096:
            return None
    ok, pairs = _knn_pairs_jit(
        np.ascontiguousarray(x, dtype=np.float64),
        float(reach),
        int(k),
        cell,
        lo_x,
        lo_y,
        nx,
        ny,
    )
    if not ok:
        return None
    return pairs.astype(np.intp, copy=False)


def _hop_bitsets(
    rows: np.ndarray,
    cols: np.ndarray,
    stamps: np.ndarray,
    n_holders: int,
    n_cols: int,
    link_start: np.ndarray,
    link_src: np.ndarray,
    t_sent: int,
    max_level: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    levels = max_level + 1
    col_of = np.full(n_cols, -1, dtype=np.int64)
    for e in range(len(cols)):
        col_of[cols[e]] = 0
    n_k = 0
    for k in range(n_cols):
        if col_of[k] == 0:
            col_of[k] = n_k
            n_k += 1
    col_ids = np.empty(n_k, dtype=np.int64)
    for k in range(n_cols):
        if col_of[k] >= 0:
            col_ids[col_of[k]] = k
    words = (n_k + 63) // 64
    block = levels * words
    # sets[i, L * words + w]: the columns holder i holds with age <= L, one bit each
    sets = np.zeros((n_holders, block), dtype=np.uint64)
    one = np.uint64(1)
    for e in range(len(rows)):
        kk = col_of[cols[e]]
        bit = one << np.uint64(kk & 63)
        w = kk >> 6
        for level in range(t_sent - stamps[e], levels):
            sets[rows[e], level * words + w] |= bit
    acc = np.zeros(block, dtype=np.uint64)
    cap = len(rows) + n_holders + 16
    out_r = np.empty(cap, dtype=np.int64)
    out_c = np.empty(cap, dtype=np.int64)
    out_s = np.empty(cap, dtype=np.int64)
    m = 0
    top = (levels - 1) * words
    for i in range(n_holders):
        acc[:] = 0
        for li in range(link_start[i], link_start[i + 1]):
            row = sets[link_src[li]]
            for q in range(block):
                acc[q] |= row[q]
        need = 0  # entries of holder i: the bits of its widest set (popcount)
        for w in range(words):
            x = acc[top + w]
            while x:
                x &= x - one
                need += 1
        if m + need > cap:
            while m + need > cap:
                cap *= 2
            out_r = np.concatenate((out_r, np.empty(cap - len(out_r), dtype=np.int64)))
            out_c = np.concatenate((out_c, np.empty(cap - len(out_c), dtype=np.int64)))
            out_s = np.concatenate((out_s, np.empty(cap - len(out_s), dtype=np.int64)))
        for w in range(words):
            word = acc[top + w]
            if word == 0:
                continue
            for b in range(64):
                if (word >> np.uint64(b)) & one:
                    count = 0  # levels whose set holds the column: max_level + 1 - age
                    for level in range(levels):
                        count += int((acc[level * words + w] >> np.uint64(b)) & one)
                    out_r[m] = i
                    out_c[m] = col_ids[w * 64 + b]
                    out_s[m] = t_sent - (levels - count)
                    m += 1
    return out_r[:m], out_c[:m], out_s[:m]


_hop_bitsets_jit = _jit(_hop_bitsets)


def hop_bitsets(
    rows: np.ndarray,
    cols: np.ndarray,
    stamps: np.ndarray,
    n_holders: int,
    n_cols: int,
    link_start: np.ndarray,
    link_src: np.ndarray,
    t_sent: int,
    max_level: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The compiled twin of :func:`planner.knowledge._propagate_bitsets` (one hop of the recency
    rule on bit sets, one set per age level): holder i's sets are the OR of its sources' sets
    (``link_src[link_start[i]:link_start[i + 1]]``, its self-loop included), OR-ed source by source
    in place of the reference's gather of every link's row (which held links x columns / 8 bytes per
    level: ~370 MB at 2,000 packed drones). Integer results, so exactly the reference's entries, in
    the same row-major order. Every stamp must lie in [t_sent - max_level, t_sent].

    The output is sized per holder by a popcount of its widest set and the bits are read word by
    word (no lowest-bit table): 2-5x faster than the NumPy reference from 100 to 500 drones
    (docs/results/benchmarks.md, third pass)."""
    return _hop_bitsets_jit(
        np.asarray(rows, np.int64),
        np.asarray(cols, np.int64),
        np.asarray(stamps, np.int64),
        int(n_holders),
        int(n_cols),
        np.asarray(link_start, np.int64),
        np.asarray(link_src, np.int64),
        int(t_sent),
        int(max_level),
    )


def _edge_terms(
    x: np.ndarray, u: np.ndarray, edges: np.ndarray, r_c: np.ndarray, group: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n_edges = edges.shape[0]
    h = np.empty(n_edges)
    dot = np.empty(n_edges)
    cross = np.empty(n_edges, dtype=np.bool_)
    for e in range(n_edges):
        i = edges[e, 0]
        j = edges[e, 1]
        dx = x[i, 0] - x[j, 0]
        dy = x[i, 1] - x[j, 1]
        h[e] = r_c[e] * r_c[e] - (dx * dx + dy * dy)
        dot[e] = dx * (u[i, 0] - u[j, 0]) + dy * (u[i, 1] - u[j, 1])
        cross[e] = group[i] != group[j]
    return h, dot, cross


_edge_terms_jit = _jit(_edge_terms)


def edge_terms(
    x: np.ndarray, u: np.ndarray, edges: np.ndarray, r_c: np.ndarray, group: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Per edge (i, j): h = r_c^2 - |x_i - x_j|^2, (x_i - x_j) . (u_i - u_j) and whether i and j
    are in different groups, in one pass (:func:`planner.mccst.edge_slack` without its gathers).
    The same operations in the same order as the NumPy expressions there (``np.einsum`` over two
    components sums x then y, checked by tests), so the same bits. None without Numba."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or x.ndim != 2 or x.shape[1] != 2:
        return None
    if np.ndim(r_c) != 1:
        r_c = np.broadcast_to(r_c, (len(edges),))
    return _edge_terms_jit(
        np.ascontiguousarray(x, dtype=np.float64),
        np.ascontiguousarray(u, dtype=np.float64),
        np.ascontiguousarray(edges, dtype=np.int64),
        np.ascontiguousarray(r_c, dtype=np.float64),
        np.ascontiguousarray(group, dtype=np.int64),
    )


def _pairs_within(x: np.ndarray, y: np.ndarray, pairs: np.ndarray, range_m: float) -> np.ndarray:
    n_pairs = pairs.shape[0]
    out = np.empty((n_pairs, 2), dtype=np.int64)
    k = 0
    for p in range(n_pairs):
        i = pairs[p, 0]
        j = pairs[p, 1]
        dx = x[i] - x[j]
        dy = y[i] - y[j]
        if math.sqrt(dx * dx + dy * dy) <= range_m:
            out[k, 0] = i
            out[k, 1] = j
            k += 1
    return out[:k].copy()


_pairs_within_jit = _jit(_pairs_within)


def pairs_within(pos_m: np.ndarray, pairs: np.ndarray, range_m: float) -> np.ndarray | None:
    """The rows (i, j) of ``pairs`` with ``|x_i - x_j| <= range_m``, in their order, as (K, 2)
    int64: :func:`planner.geometry.neighbour_pairs`'s exact re-check of the KD-tree's candidates
    (``np.linalg.norm(pos[i] - pos[j], axis=1) <= range_m``) without its gathers and temporaries.
    ``np.linalg.norm`` over two components is sqrt(x^2 + y^2) (the squares, then one addition:
    two terms have one sum), so the same distance bits (tests/planner/test_graph_kernels.py).
    None without Numba or for other than 2-D positions / (P, 2) pairs: the caller runs NumPy."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or pos_m.ndim != 2 or pos_m.shape[1] != 2:
        return None
    if pairs.ndim != 2 or pairs.shape[1] != 2:
        return None
    return _pairs_within_jit(
        np.ascontiguousarray(pos_m[:, 0], dtype=np.float64),
        np.ascontiguousarray(pos_m[:, 1], dtype=np.float64),
        np.ascontiguousarray(pairs, dtype=np.int64),
        float(range_m),
    )


def _any_within(
    tx: np.ndarray, ty: np.ndarray, x: np.ndarray, y: np.ndarray, range_m: float
) -> np.ndarray:
    out = np.zeros(len(tx), dtype=np.bool_)
    for t in range(len(tx)):
        for j in range(len(x)):
            dx = tx[t] - x[j]
            dy = ty[t] - y[j]
            if math.sqrt(dx * dx + dy * dy) < range_m:
                out[t] = True
                break
    return out


_any_within_jit = _jit(_any_within)

#: Above this many (task, drone) pairs :func:`any_within` leaves the work to the KD-tree.
ANY_WITHIN_MAX_PAIRS = 2_000_000


def any_within(task_pos_m: np.ndarray, pos_m: np.ndarray, range_m: float) -> np.ndarray | None:
    """(M,) bool: some row of ``pos_m`` lies strictly closer than ``range_m`` to each task, the
    distance sqrt(dx^2 + dy^2) as the KD-tree's nearest-neighbour query computes it (squares
    summed x then y, one square root), by brute force with an early exit: for the swarms of one
    mission (M x N below ``ANY_WITHIN_MAX_PAIRS``) cheaper than building a KD-tree every tick.
    None when it does not apply (no Numba, not 2-D, NaN or non-finite drones): the caller queries
    the KD-tree (:func:`planner.geometry.tasks_connected`)."""
    if (
        not (_kernels.NUMBA and _kernels.ENABLED)
        or len(task_pos_m) * len(pos_m) > ANY_WITHIN_MAX_PAIRS
    ):
        return None
    if task_pos_m.ndim != 2 or task_pos_m.shape[1] != 2 or pos_m.ndim != 2 or pos_m.shape[1] != 2:
        return None
    if not np.isfinite(pos_m).all() or np.isnan(task_pos_m).any() or not np.isfinite(range_m):
        return None
    return _any_within_jit(
        np.ascontiguousarray(task_pos_m[:, 0], dtype=np.float64),
        np.ascontiguousarray(task_pos_m[:, 1], dtype=np.float64),
        np.ascontiguousarray(pos_m[:, 0], dtype=np.float64),
        np.ascontiguousarray(pos_m[:, 1], dtype=np.float64),
        float(range_m),
    )


def _bounded_moves(
    px: np.ndarray,
    py: np.ndarray,
    dx_in: np.ndarray,
    dy_in: np.ndarray,
    active: np.ndarray,
    alive: np.ndarray,
    hx: float,
    hy: float,
    vmax: float,
) -> tuple[bool, np.ndarray]:
    n = len(px)
    out = np.empty((n, 2))
    if not (math.isfinite(hx) and math.isfinite(hy)):
        return False, out
    for i in range(n):
        if not (
            math.isfinite(px[i])
            and math.isfinite(py[i])
            and math.isfinite(dx_in[i])
            and math.isfinite(dy_in[i])
        ):
            return False, out
    for i in range(n):
        if active[i]:
            dx = dx_in[i]
            dy = dy_in[i]
        else:  # planner.geometry.step_toward, row by row
            tx = hx - px[i]
            ty = hy - py[i]
            dist = math.sqrt(tx * tx + ty * ty)
            f = min(vmax, dist) / (dist if dist > 0 else 1.0)
            dx = tx * f
            dy = ty * f
        norm = math.sqrt(dx * dx + dy * dy)
        s = min(1.0, vmax / (norm if norm > 0 else 1.0))
        a = 1.0 if alive[i] else 0.0
        out[i, 0] = px[i] + dx * s * a
        out[i, 1] = py[i] + dy * s * a
    return True, out


_bounded_moves_jit = _jit(_bounded_moves)


def bounded_moves(
    pos_m: np.ndarray,
    disp_m: np.ndarray,
    active: np.ndarray,
    alive: np.ndarray,
    home_m: np.ndarray,
    vmax: float,
) -> np.ndarray | None:
    """The motion of :meth:`vehicle_emu.world.World.step` for one home point, in one pass: active
    drones take ``disp_m``, the others head for ``home_m`` (never overshooting it), every
    displacement is scaled down to ``vmax``, and only ``alive`` drones move. The same operations
    in the same order as the NumPy lines there (``np.linalg.norm`` of two components sums x^2 then
    y^2; a bool times a float is a product with 1.0 or 0.0), so the same bits; a new (N, 2) array.
    None when it does not apply (no Numba, not 2-D, non-finite or NaN input, home not one point)."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or pos_m.ndim != 2 or pos_m.shape[1] != 2:
        return None
    if disp_m.shape != pos_m.shape or np.shape(home_m) != (2,) or not np.isfinite(vmax):
        return None
    ok, out = _bounded_moves_jit(
        np.ascontiguousarray(pos_m[:, 0], dtype=np.float64),
        np.ascontiguousarray(pos_m[:, 1], dtype=np.float64),
        np.ascontiguousarray(disp_m[:, 0], dtype=np.float64),
        np.ascontiguousarray(disp_m[:, 1], dtype=np.float64),
        np.asarray(active, dtype=np.bool_),
        np.asarray(alive, dtype=np.bool_),
        float(home_m[0]),
        float(home_m[1]),
        float(vmax),
    )
    return out if ok else None  # a non-finite entry (checked in the kernel): NumPy runs


def _reaches_root(parent: np.ndarray) -> bool:
    k = len(parent)
    state = np.zeros(k, dtype=np.int8)  # 0 unseen, 1 on the current walk, 2 reaches node 0
    state[0] = 2
    path = np.empty(k, dtype=np.int64)
    for v in range(k):
        m = 0
        u = v
        while state[u] == 0:
            state[u] = 1
            path[m] = u
            m += 1
            u = parent[u]
            if u < 0 or u >= k:
                return False
        if state[u] == 1:
            return False
        for q in range(m):
            state[path[q]] = 2
    return True


_reaches_root_jit = _jit(_reaches_root)


def reaches_root(parent: np.ndarray) -> bool | None:
    """Whether every node's parent pointers lead to node 0 (no cycle, indices in range; node 0's
    own parent is not followed), in O(K): the check of :class:`planner.steiner.TaskTree`, whose
    reference is the pointer jumping of ``_root_path_lengths``. None without Numba."""
    if not (_kernels.NUMBA and _kernels.ENABLED):
        return None
    return bool(_reaches_root_jit(np.asarray(parent, dtype=np.int64)))


def _qp_rows(
    x: np.ndarray,
    y: np.ndarray,
    ti: np.ndarray,
    tj: np.ndarray,
    ci: np.ndarray,
    cj: np.ndarray,
    r_c: np.ndarray,
    safety_sq: float,
    box: float,
    n: int,
    gamma: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    n_tree = len(ti)
    n_rows = n_tree + len(ci)
    i_out = np.empty(n_rows, dtype=np.int64)
    j_out = np.empty(n_rows, dtype=np.int64)
    coef = np.empty((n_rows, 2))
    h = np.empty(n_rows)
    reach = np.empty(n_rows)
    cap = np.empty(n_rows)
    need = np.empty(n_rows, dtype=np.int64)
    n_need = 0
    for r in range(n_rows):
        if r < n_tree:
            i = ti[r]
            j = tj[r]
        else:
            i = ci[r - n_tree]
            j = cj[r - n_tree]
        dx = x[i] - x[j]
        dy = y[i] - y[j]
        d2 = dx * dx + dy * dy
        if r < n_tree:
            c0 = 2.0 * dx
            c1 = 2.0 * dy
            hr = r_c[r] * r_c[r] - d2
        else:
            c0 = -2.0 * dx
            c1 = -2.0 * dy
            hr = d2 - safety_sq
        reach_r = box * (abs(c0) + abs(c1)) * (2.0 if j < n else 1.0)
        cap_r = reach_r + 1e-3
        i_out[r] = i
        j_out[r] = j
        coef[r, 0] = c0
        coef[r, 1] = c1
        h[r] = hr
        reach[r] = reach_r
        cap[r] = cap_r
        if not gamma * (hr * hr * hr) > cap_r * (1.0 + 1e-9):  # NaN: not surely capped
            need[n_need] = r
            n_need += 1
    return i_out, j_out, coef, h, reach, cap, need[:n_need].copy()


_qp_rows_jit = _jit(_qp_rows)


def qp_rows(
    x: np.ndarray,
    tree: np.ndarray,
    r_c: np.ndarray,
    collision_pairs: np.ndarray,
    safety_radius: float,
    box: float,
    gamma: float,
) -> (
    tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None
):
    """The barrier rows of :func:`planner.mccst.solve_cbf_qp` in one pass: per row (the tree
    edges, then the collision pairs) i, j, coef (R, 2), h, reach, cap = reach + 1e-3 and the rows
    ``need`` whose cubic class-K value gamma h^3 may be below cap (the others are surely capped,
    :func:`planner.mccst._capped_class_k`). The same operations in the same order as the NumPy
    reference :func:`planner.mccst._barrier_rows` (2 sign diff is exact; |c0| + |c1| is the sum of
    two terms; squares summed x then y), so the same bits (tests/planner/test_mccst.py). ``x``
    is (n + 1, 2) with the base in row n. None without Numba."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or x.ndim != 2 or x.shape[1] != 2:
        return None
    return _qp_rows_jit(
        np.ascontiguousarray(x[:, 0], dtype=np.float64),
        np.ascontiguousarray(x[:, 1], dtype=np.float64),
        np.ascontiguousarray(tree[:, 0], dtype=np.int64),
        np.ascontiguousarray(tree[:, 1], dtype=np.int64),
        np.ascontiguousarray(collision_pairs[:, 0], dtype=np.int64),
        np.ascontiguousarray(collision_pairs[:, 1], dtype=np.int64),
        np.ascontiguousarray(r_c, dtype=np.float64),
        float(safety_radius) ** 2,
        float(box),
        len(x) - 1,
        float(gamma),
    )


def _barrier_matrix(
    i: np.ndarray, j: np.ndarray, coef: np.ndarray, rhs: np.ndarray, reach: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    n_rows = len(i)
    new_row = np.empty(n_rows, dtype=np.int64)
    rows = np.empty(n_rows, dtype=np.int64)
    slack_rows = np.empty(n_rows, dtype=np.int64)
    per_drone = np.zeros(n, dtype=np.int64)
    n_kept = 0
    n_slack = 0
    for r in range(n_rows):
        if rhs[r] <= reach[r] or rhs[r] < 0:
            new_row[r] = n_kept
            rows[n_kept] = r
            n_kept += 1
            per_drone[i[r]] += 1
            if j[r] < n:
                per_drone[j[r]] += 1
            if rhs[r] < 0:
                slack_rows[n_slack] = r
                n_slack += 1
    n_u = 2 * n
    indptr = np.empty(n_u + n_slack + 1, dtype=np.int32)
    indptr[0] = 0
    for d in range(n):
        indptr[2 * d + 1] = indptr[2 * d] + per_drone[d]
        indptr[2 * d + 2] = indptr[2 * d + 1] + per_drone[d]
    for s in range(n_slack):
        indptr[n_u + s + 1] = indptr[n_u + s] + 1
    nnz = indptr[n_u + n_slack]
    indices = np.empty(nnz, dtype=np.int32)
    data = np.empty(nnz)
    fill = np.empty(n, dtype=np.int64)
    for d in range(n):
        fill[d] = 0
    for q in range(n_kept):  # kept rows ascending: each drone's column fills in row order
        r = rows[q]
        a = i[r]
        at = indptr[2 * a] + fill[a]
        indices[at] = q
        data[at] = coef[r, 0]
        indices[at + per_drone[a]] = q
        data[at + per_drone[a]] = coef[r, 1]
        fill[a] += 1
        b = j[r]
        if b < n:
            at = indptr[2 * b] + fill[b]
            indices[at] = q
            data[at] = -coef[r, 0]
            indices[at + per_drone[b]] = q
            data[at + per_drone[b]] = -coef[r, 1]
            fill[b] += 1
    for s in range(n_slack):
        at = indptr[n_u + s]
        indices[at] = new_row[slack_rows[s]]
        data[at] = -1.0
    return data, indices, indptr, rows[:n_kept].copy(), slack_rows[:n_slack].copy()


_barrier_matrix_jit = _jit(_barrier_matrix)


def barrier_matrix(
    i: np.ndarray, j: np.ndarray, coef: np.ndarray, rhs: np.ndarray, reach: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """PIQP's barrier matrix of :func:`planner.mccst._solve_piqp` in one pass: the rows that may
    bind (``rhs <= reach`` or violated, ``rhs < 0``), in order, as CSC arrays (data float64,
    indices and indptr int32; columns u_0x, u_0y, ..., then one slack per violated row), plus
    the kept rows' indices and the violated rows' indices. Entry for entry
    :func:`planner.mccst._constraint_matrix` on the kept rows without bound rows (its reference;
    tests/planner/test_mccst.py). None without Numba."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or coef.ndim != 2 or coef.shape[1] != 2:
        return None
    return _barrier_matrix_jit(
        np.ascontiguousarray(i, dtype=np.int64),
        np.ascontiguousarray(j, dtype=np.int64),
        np.ascontiguousarray(coef, dtype=np.float64),
        np.ascontiguousarray(rhs, dtype=np.float64),
        np.ascontiguousarray(reach, dtype=np.float64),
        int(n),
    )


def _link_edges(
    pos: np.ndarray, pairs: np.ndarray, range_m: float, bx: float, by: float, base_reach: float
) -> np.ndarray:
    n = pos.shape[0]
    n_pairs = pairs.shape[0]
    out = np.empty((n_pairs + n, 2), dtype=np.int64)
    # d^2 this far inside range^2 has sqrt(d^2) < range whatever the rounding (1e-9 relative
    # against a few ulps): the square root is taken only near the boundary.
    inner = range_m * range_m * (1.0 - 1e-9) if range_m > 0 else -1.0
    k = 0
    for p in range(n_pairs):
        i = pairs[p, 0]
        j = pairs[p, 1]
        dx = pos[i, 0] - pos[j, 0]
        dy = pos[i, 1] - pos[j, 1]
        d2 = dx * dx + dy * dy
        if d2 <= inner or math.sqrt(d2) <= range_m:
            out[k, 0] = i
            out[k, 1] = j
            k += 1
    for i in range(n):
        dx = pos[i, 0] - bx
        dy = pos[i, 1] - by
        if math.sqrt(dx * dx + dy * dy) <= base_reach:
            out[k, 0] = i
            out[k, 1] = n
            k += 1
    return out[:k].copy()


_link_edges_jit = _jit(_link_edges)


def link_edges(
    pos_m: np.ndarray, pairs: np.ndarray, range_m: float, base_m: np.ndarray, base_reach_m: float
) -> np.ndarray | None:
    """:func:`planner.mccst.candidate_edges` from the KD-tree's candidate pairs
    (:func:`planner.geometry.neighbour_candidates`) in one pass: the pairs with
    ``|x_i - x_j| <= range_m``, in their order (:func:`pairs_within`), then (i, n) for each drone
    i with ``|x_i - b| <= base_reach_m`` in ascending i, as (E, 2) int64. Distances as
    ``np.linalg.norm`` of two components (the squares summed x then y, one square root), so the
    same set (tests/planner/test_mccst.py). None without Numba or for other than 2-D positions."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or pos_m.ndim != 2 or pos_m.shape[1] != 2:
        return None
    if pairs.ndim != 2 or pairs.shape[1] != 2 or np.shape(base_m) != (2,):
        return None
    return _link_edges_jit(
        np.ascontiguousarray(pos_m, dtype=np.float64),
        np.ascontiguousarray(pairs, dtype=np.int64),
        float(range_m),
        float(base_m[0]),
        float(base_m[1]),
        float(base_reach_m),
    )


def _clip2(a: float, b: float, limit: float, shrink: float) -> tuple[float, float]:
    """One row of :func:`planner.mccst._clip_norm`: (a, b) scaled to norm ``limit`` when longer,
    then by ``shrink`` if rounding left it above."""
    norm = math.sqrt(a * a + b * b)
    if norm > limit:
        f = limit / norm
        a = a * f
        b = b * f
        if math.sqrt(a * a + b * b) > limit:
            a = a * shrink
            b = b * shrink
    return a, b


if _kernels.NUMBA:
    _clip2 = _njit(cache=True, inline="always")(_clip2)


def _clip_norm(vec: np.ndarray, limit: float, shrink: float) -> np.ndarray:
    n = vec.shape[0]
    out = np.empty((n, 2))
    for r in range(n):
        out[r, 0], out[r, 1] = _clip2(vec[r, 0], vec[r, 1], limit, shrink)
    return out


_clip_norm_jit = _jit(_clip_norm)


def clip_norm(vec: np.ndarray, limit: float) -> np.ndarray | None:
    """:func:`planner.mccst._clip_norm` of an (n, 2) array in one pass (its reference): rows with
    ``|row| > limit`` scaled by limit / |row|, then by 1 - 1e-12 if rounding left them above;
    |row| = sqrt(x^2 + y^2) as ``np.linalg.norm`` of two components computes it (the squares,
    one addition), so the same bits. A new float64 array; None without Numba or for other than
    (n, 2) input."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or vec.ndim != 2 or vec.shape[1] != 2:
        return None
    return _clip_norm_jit(np.ascontiguousarray(vec, dtype=np.float64), float(limit), 1.0 - 1e-12)


def _qp_vectors(
    u_hat: np.ndarray, slack_tree: np.ndarray, pen_tree: float, pen_col: float, box: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    n_u = 2 * u_hat.shape[0]
    n_var = n_u + len(slack_tree)
    p_diag = np.empty(n_var)
    q = np.empty(n_var)
    lo = np.empty(n_var)
    hi = np.empty(n_var)
    for d in range(u_hat.shape[0]):
        for k in range(2):
            v = 2 * d + k
            p_diag[v] = 2.0
            q[v] = -2.0 * u_hat[d, k]
            lo[v] = -box
            hi[v] = box
    for s in range(len(slack_tree)):
        v = n_u + s
        p_diag[v] = 2.0 * (pen_tree if slack_tree[s] else pen_col)
        q[v] = 0.0
        lo[v] = 0.0
        hi[v] = np.inf
    return p_diag, q, lo, hi


_qp_vectors_jit = _jit(_qp_vectors)


def qp_vectors(
    u_hat: np.ndarray, slack_tree: np.ndarray, pen_tree: float, pen_col: float, box: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The CBF-QP's vectors over z = (u_0x, u_0y, ..., one slack per violated row): P's diagonal
    (2 per control, 2 x the tree or collision penalty per slack), q (-2 u_hat, 0 per slack) and
    the bounds (+-box per control, [0, inf) per slack), in one pass: the arrays
    :func:`planner.mccst._qp_objective` and :func:`planner.mccst._solve_piqp` build by NumPy
    (doubling is exact, so the same bits). None without Numba or for other than (n, 2) u_hat."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or u_hat.ndim != 2 or u_hat.shape[1] != 2:
        return None
    return _qp_vectors_jit(
        np.ascontiguousarray(u_hat, dtype=np.float64),
        np.ascontiguousarray(slack_tree, dtype=np.bool_),
        float(pen_tree),
        float(pen_col),
        float(box),
    )


def _toward_tasks(
    x: np.ndarray,
    task: np.ndarray,
    task_of: np.ndarray,
    unit: float,
    k_p: float,
    speed: float,
    shrink: float,
) -> np.ndarray:
    n = len(task_of)
    out = np.empty((n, 2))
    for d in range(n):
        t = task_of[d]
        if t >= 0:
            gx = task[t, 0] / unit
            gy = task[t, 1] / unit
        else:  # no task: the goal is where the drone is
            gx = x[d, 0]
            gy = x[d, 1]
        out[d, 0], out[d, 1] = _clip2(k_p * (gx - x[d, 0]), k_p * (gy - x[d, 1]), speed, shrink)
    return out


_toward_tasks_jit = _jit(_toward_tasks)


def toward_tasks(
    x: np.ndarray, task_m: np.ndarray, task_of: np.ndarray, unit: float, k_p: float, speed: float
) -> np.ndarray | None:
    """MCCST's nominal controls toward the assigned tasks in one pass: goal_d = task_m[task_of[d]] /
    unit (x_d when task_of[d] < 0), then :func:`planner.mccst.nominal_controls` with no hold
    distance, sat_speed(k_p (goal - x)); the same operations in the same order as the NumPy lines
    (the reference: ``planner.mccst.MccstPlanner.plan``'s goal and ``nominal_controls``), so the
    same bits. ``x`` (n, 2) paper units, ``task_m`` (M, 2) metres. None without Numba or for
    other than 2-D input."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or x.ndim != 2 or x.shape[1] != 2:
        return None
    if task_m.ndim != 2 or task_m.shape[1] != 2 or len(task_of) != len(x):
        return None
    return _toward_tasks_jit(
        np.ascontiguousarray(x, dtype=np.float64),
        np.ascontiguousarray(task_m, dtype=np.float64),
        np.ascontiguousarray(task_of, dtype=np.int64),
        float(unit),
        float(k_p),
        float(speed),
        1.0 - 1e-12,
    )


def _slack_combine(
    dot: np.ndarray, class_k: np.ndarray, cross: np.ndarray, factor: float
) -> np.ndarray:
    out = np.empty(len(dot))
    for e in range(len(dot)):
        delta = -2.0 * dot[e] + class_k[e]
        out[e] = delta / factor if cross[e] else delta
    return out


_slack_combine_jit = _jit(_slack_combine)


def slack_combine(
    dot: np.ndarray, class_k: np.ndarray, cross: np.ndarray, factor: float
) -> np.ndarray | None:
    """:func:`planner.mccst.edge_slack`'s last two lines in one pass: delta = -2 dot + K, divided
    by ``factor`` where ``cross``; the same operations in the same order, so the same bits. None
    without Numba."""
    if not (_kernels.NUMBA and _kernels.ENABLED):
        return None
    return _slack_combine_jit(
        np.ascontiguousarray(dot, dtype=np.float64),
        np.ascontiguousarray(class_k, dtype=np.float64),
        np.ascontiguousarray(cross, dtype=np.bool_),
        float(factor),
    )

"""Compiled per-tick kernels (Numba), each the fast twin of a NumPy function kept as its reference.

Every kernel here has a slow, obviously-correct NumPy (or loop) version in the module that uses it,
and ``tests/planner/test_kernels.py`` compares the two. When Numba is not importable ``NUMBA`` is
False and the callers use the NumPy versions, so the planners still run (slower).

Kernels are compiled on first use and cached on disk (``cache=True``), so a short run pays the
compilation once per machine, not once per process.

Bit-identity. The kernels use no ``fastmath`` flags (LLVM then neither reorders nor fuses floating
point operations into FMAs), so an element-wise formula written in the same operation order as the
NumPy version gives the same bits, and a sum accumulated in the same order as ``np.bincount`` (entry
order) gives the same bits as well. Where NumPy sums in another order (BLAS products, pairwise
sums), the kernel's docstring says so.

Speed without reordering. Hot loops are written branch-free (``a if c else b`` selects, a kept list
advanced by ``m += test``) and sums are split from the element-wise work (a block of terms computed,
then added in entry order), so LLVM vectorises the element-wise part: SIMD square roots and
divisions are correctly rounded like the scalar ones (the same bits), and no data-dependent branch
is mispredicted. Arrays that may grow (``np.concatenate``) are grown outside the innermost loop: a
reassignment inside it keeps the array's reference counting in the loop (~4x slower).

Size: ~1000 lines, above the ~600 guideline: the planners' compiled kernels in one place (one
import, one Numba cache); the graph and geometry kernels live in :mod:`planner._graph_kernels`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numpy as np

try:  # pragma: no cover - exercised by whichever environment runs the tests
    import numba

    NUMBA = True
    prange: Any = numba.prange
except ImportError:  # pragma: no cover
    NUMBA = False
    prange = range

_F = TypeVar("_F", bound=Callable[..., Any])


def njit(**options: Any) -> Callable[[_F], _F]:
    """``numba.njit(**options)`` that keeps the function's signature for the type checker (Numba's
    decorator is untyped); the plain function when Numba is missing."""

    def wrap(func: _F) -> _F:
        if not NUMBA:  # pragma: no cover
            return func
        return cast(_F, numba.njit(**options)(func))

    return wrap


#: False: the callers run the NumPy reference paths instead (benchmarks and tests compare the two).
ENABLED = True

__all__ = [
    "NUMBA",
    "central_pair_gradient",
    "segment_gradient",
    "entries_pair_gradient",
    "entries_segment_gradient",
]

#: From this many drones the all-pairs kernel runs its rows on Numba's thread pool (the rows are
#: independent and each is summed in a fixed order, so the result does not depend on the threads).
PARALLEL_MIN_DRONES = 1500


#: Flags of the all-pairs kernel only: reassociation lets LLVM vectorise drone i's sum over j
#: (4 pairs per instruction, ~5x); the order is then fixed by the compiled code, so the result is
#: still deterministic, but it is not the order of any NumPy expression.
_PAIR_FASTMATH = {"reassoc", "nsz", "contract"}


def _central_pair_body_py(
    x: np.ndarray,
    y: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
    out: np.ndarray,
    i: int,
) -> None:
    xi, yi = x[i], y[i]
    gx = 0.0
    gy = 0.0
    for j in range(len(x)):
        dx = xi - x[j]
        dy = yi - y[j]
        d2 = dx * dx + dy * dy
        # branch-free (selects), so the loop vectorises; j == i gives d2 = 0, hence coef = 0
        pos = d2 > 0.0
        inv = 1.0 / math.sqrt(d2 if pos else 1.0)
        inv = inv if pos else 0.0
        d = d2 * inv
        att = attraction * inv * inv * inv if d > floor else 0.0
        rep = repulsion * (reach * inv - 1.0) if (d < reach and pos) else 0.0
        coef = att - rep
        gx += coef * dx
        gy += coef * dy
    out[i, 0] = pair_factor * gx
    out[i, 1] = pair_factor * gy


_central_pair_body = njit(cache=True, inline="always", fastmath=_PAIR_FASTMATH)(
    _central_pair_body_py
)


@njit(cache=True, fastmath=_PAIR_FASTMATH)
def _central_pair_serial(
    x: np.ndarray,
    y: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
) -> np.ndarray:
    out = np.empty((len(x), 2))
    for i in range(len(x)):
        _central_pair_body(x, y, attraction, floor, repulsion, reach, pair_factor, out, i)
    return out


@njit(cache=True, parallel=True, fastmath=_PAIR_FASTMATH)
def _central_pair_parallel(
    x: np.ndarray,
    y: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
) -> np.ndarray:
    out = np.empty((len(x), 2))
    for i in prange(len(x)):
        _central_pair_body(x, y, attraction, floor, repulsion, reach, pair_factor, out, i)
    return out


def central_pair_gradient(
    pos_u: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
) -> np.ndarray:
    """All-pairs :func:`planner.phireman.pair_gradient` of the central view (every drone sees every
    other, mask = not self), O(n) memory.

    Parameters
    ----------
    pos_u : (n, 2) positions, paper units
    attraction, floor, repulsion, reach, pair_factor : as :func:`planner.phireman.pair_gradient`

    Returns
    -------
    (n, 2) gradient. The differences are formed directly (the NumPy version expands
    d^2 = |x|^2 + |y|^2 - 2 x.y, losing ~|x|^2 eps) and drone i's sum is vectorised (reassociated),
    while NumPy sums by BLAS: the two agree to rounding (~1e-14 relative here, ~1e-10 for NumPy's
    expansion at 2,000 drones), not bit for bit.
    """
    pos_u = np.asarray(pos_u, dtype=np.float64)
    x = np.ascontiguousarray(pos_u[:, 0])
    y = np.ascontiguousarray(pos_u[:, 1])
    kernel = _central_pair_parallel if len(x) >= PARALLEL_MIN_DRONES else _central_pair_serial
    return kernel(
        x, y, float(attraction), float(floor), float(repulsion), float(reach), float(pair_factor)
    )


@njit(cache=True)
def _segment_gradient(
    px: np.ndarray,
    py: np.ndarray,
    ax: np.ndarray,
    ay: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    e2: np.ndarray,
    thorn: float,
) -> np.ndarray:
    n = len(px)
    m = len(ax)
    out = np.empty((n, 2))
    d2 = np.empty(m)
    for i in range(n):
        xi = px[i]
        yi = py[i]
        # pass 1, element-wise (LLVM vectorises it; no reassociation, so the bits are NumPy's)
        for s in range(m):
            qx = xi - ax[s]
            qy = yi - ay[s]
            t = (qx * ex[s] + qy * ey[s]) / e2[s] if e2[s] > 0.0 else 0.0
            t = min(max(t, 0.0), 1.0)
            ox = xi - (ax[s] + t * ex[s])
            oy = yi - (ay[s] + t * ey[s])
            d2[s] = ox * ox + oy * oy
        # pass 2: the first minimum, as np.argmin
        best = 0
        for s in range(1, m):
            if d2[s] < d2[best]:
                best = s
        t = (
            (((xi - ax[best]) * ex[best] + (yi - ay[best]) * ey[best]) / e2[best])
            if e2[best] > 0.0
            else 0.0
        )
        t = min(max(t, 0.0), 1.0)
        bx = xi - (ax[best] + t * ex[best])
        by = yi - (ay[best] + t * ey[best])
        dist = math.sqrt(bx * bx + by * by)
        if dist > 1e-12:
            out[i, 0] = thorn * bx / dist
            out[i, 1] = thorn * by / dist
        else:
            out[i, 0] = 0.0
            out[i, 1] = 0.0
    return out


def segment_gradient(
    pos_u: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray, thorn: float
) -> np.ndarray:
    """∇ Þ h_T for drones sharing one tree given as segments: the fast twin of
    :func:`planner.phireman.task_gradient` (via :func:`planner.steiner.distance_to_tree`), same
    per-element formula and first-minimum rule, O(n) memory instead of (n, E).

    Parameters
    ----------
    pos_u : (n, 2) positions
    seg_a, seg_b : (E, 2) segment ends (a zero-length segment is a node), E >= 1
    thorn : Þ
    """
    pos_u = np.asarray(pos_u, dtype=np.float64)
    a = np.asarray(seg_a, dtype=np.float64)
    ab = np.asarray(seg_b, dtype=np.float64) - a
    e2 = ab[:, 0] * ab[:, 0] + ab[:, 1] * ab[:, 1]
    return _segment_gradient(
        np.ascontiguousarray(pos_u[:, 0]),
        np.ascontiguousarray(pos_u[:, 1]),
        np.ascontiguousarray(a[:, 0]),
        np.ascontiguousarray(a[:, 1]),
        np.ascontiguousarray(ab[:, 0]),
        np.ascontiguousarray(ab[:, 1]),
        e2,
        float(thorn),
    )


@njit(cache=True, inline="always")
def _pair_coef(
    dx: float, dy: float, attraction: float, floor: float, repulsion: float, reach: float
) -> float:
    """One entry's pair-gradient coefficient (gradient = (dx, dy) * coef):
    :func:`planner.phireman._pair_gradient_xy`'s element-wise operations in the same order."""
    d2 = dx * dx
    d2 += dy * dy
    d = math.sqrt(d2)
    inv = 1.0 / d if d > 0 else 0.0
    coef = inv * inv
    coef *= inv
    coef *= attraction
    coef = 0.0 if d <= floor else coef
    # selects, not branches: LLVM vectorises a loop of these (a branch on d < reach, taken by ~12 %
    # of the entries in no order, mispredicted); the same value either way
    pushed = coef - repulsion * (reach * inv - 1.0)
    return pushed if (d < reach) & (d > 0) else coef


#: Entries per block of :func:`_pair_block`: the block's coefficients are computed vectorised, then
#: summed in entry order; the next block's square roots and divisions overlap that sum's chain.
_PAIR_BLOCK = 32


@njit(cache=True, inline="always")
def _pair_block(
    xi: float,
    yi: float,
    ox: np.ndarray,
    oy: np.ndarray,
    e0: int,
    m: int,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    wx: np.ndarray,
    wy: np.ndarray,
) -> None:
    """wx[q], wy[q] = the pair-gradient terms (dx coef, dy coef) of entries e0 + q, q < m, of a drone
    at (xi, yi): :func:`_pair_coef` element-wise, no reduction, so the loop vectorises (square roots
    and divisions are correctly rounded in SIMD lanes too: the same bits)."""
    for q in range(m):
        ddx = xi - ox[e0 + q]
        ddy = yi - oy[e0 + q]
        coef = _pair_coef(ddx, ddy, attraction, floor, repulsion, reach)
        wx[q] = ddx * coef
        wy[q] = ddy * coef


@njit(cache=True, inline="always")
def _pair_sum(
    xi: float,
    yi: float,
    ox: np.ndarray,
    oy: np.ndarray,
    e0: int,
    e1: int,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    wx: np.ndarray,
    wy: np.ndarray,
) -> tuple[float, float]:
    """The pair-gradient sums (sx, sy) of entries e0:e1 of a drone at (xi, yi), accumulated from 0.0
    in entry order (as ``np.bincount``), blockwise through :func:`_pair_block`; wx, wy : scratch of
    at least :data:`_PAIR_BLOCK`."""
    sx = 0.0
    sy = 0.0
    e = e0
    while e < e1:
        m = min(_PAIR_BLOCK, e1 - e)
        _pair_block(xi, yi, ox, oy, e, m, attraction, floor, repulsion, reach, wx, wy)
        for q in range(m):
            sx += wx[q]
            sy += wy[q]
        e += m
    return sx, sy


@njit(cache=True, inline="always")
def _limit_fraction(dx: float, dy: float, stx: float, sty: float, v2: float) -> float:
    """The fraction of the step (stx, sty) from (dx, dy) that ends on the speed limit |d| = √v2
    (:func:`planner.phireman._scale_to_limit`, same arithmetic), clipped to [0, 1]."""
    a = stx * stx + sty * sty
    b = dx * stx + dy * sty
    c = (dx * dx + dy * dy) - v2
    disc = math.sqrt(max(b * b - a * c, 0.0))
    alpha = (-b + disc) / a if a > 0 else 1.0
    return min(max(alpha, 0.0), 1.0)


@njit(cache=True)
def entries_pair_gradient(
    px: np.ndarray,
    py: np.ndarray,
    rows: np.ndarray,
    ox: np.ndarray,
    oy: np.ndarray,
    n: int,
    attraction: np.ndarray,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
) -> np.ndarray:
    """:func:`planner.phireman._pair_gradient_xy`, bit for bit: the same element-wise operations in
    the same order, summed per holder in entry order as ``np.bincount`` does.

    px, py : (m,) positions of the m drones whose entries are given; rows : (E,) holder of each
    entry (into px); ox, oy : (E,) believed positions; n : rows of the output (>= max(rows) + 1);
    attraction : (m,) ℳ per holder (ℳ w_i for DCCRS's density weighting; ℳ * 1.0 == ℳ exactly).
    """
    sx = np.zeros(n)
    sy = np.zeros(n)
    for e in range(len(rows)):
        r = rows[e]
        dx = px[r] - ox[e]
        dy = py[r] - oy[e]
        coef = _pair_coef(dx, dy, attraction[r], floor, repulsion, reach)
        sx[r] += dx * coef
        sy[r] += dy * coef
    out = np.empty((n, 2))
    for i in range(n):
        out[i, 0] = sx[i] * pair_factor
        out[i, 1] = sy[i] * pair_factor
    return out


@njit(cache=True)
def entries_segment_gradient(
    px: np.ndarray,
    py: np.ndarray,
    er: np.ndarray,
    ax: np.ndarray,
    ay: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    e2: np.ndarray,
    n: int,
    thorn: float,
) -> np.ndarray:
    """:meth:`planner.phireman.TreeSegments._gradient_entries`, bit for bit: per entry (drone er[e],
    segment e) the same clamped projection, the first minimum per drone (entries of a drone are
    consecutive, in segment order). Every drone 0..n-1 has at least one entry."""
    out = np.empty((n, 2))
    e = 0
    m = len(er)
    while e < m:
        i = er[e]
        best = np.inf
        bx = 0.0
        by = 0.0
        while e < m and er[e] == i:
            qx = px[i] - ax[e]
            qy = py[i] - ay[e]
            t = 0.0
            if e2[e] > 0:
                t = (qx * ex[e] + qy * ey[e]) / e2[e]
            t = min(max(t, 0.0), 1.0)
            fx = ax[e] + t * ex[e]
            fy = ay[e] + t * ey[e]
            offx = px[i] - fx
            offy = py[i] - fy
            d2 = offx * offx + offy * offy
            if d2 < best:
                best, bx, by = d2, offx, offy
            e += 1
        dist = math.sqrt(best)
        if dist > 1e-12:
            out[i, 0] = thorn * bx / dist
            out[i, 1] = thorn * by / dist
        else:
            out[i, 0] = 0.0
            out[i, 1] = 0.0
    return out


@njit(cache=True)
def descend_separable(
    px: np.ndarray,
    py: np.ndarray,
    pair_start: np.ndarray,
    ox: np.ndarray,
    oy: np.ndarray,
    seg_start: np.ndarray,
    ax: np.ndarray,
    ay: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    e2: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
    thorn: float,
    step_size: float,
    tolerance: float,
    vmax: float,
    max_steps: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The async PhiIREMAN descent of one tick (:func:`planner.phireman.descend` with
    ``separable=True`` and the 'per_drone' speed rule), every drone in one compiled loop.

    With separable gradients and the per-drone rule each drone's descent is independent of the
    others', so it runs drone by drone: gradient = pair term over the drone's entries
    ``pair_start[i]:pair_start[i + 1]`` (summed in entry order, as ``np.bincount``) + task term
    over its candidate segments ``seg_start[i]:seg_start[i + 1]`` (first minimum), then the same
    step, equilibrium and speed-limit arithmetic as the NumPy descent, bit for bit.

    Returns
    -------
    delta : (n, 2) instructions
    stop : (n,) int, the descent step at which the drone stopped (max_steps + 1: never)
    at_limit : (n,) bool, it stopped at the speed limit (else at its equilibrium)
    """
    n = len(px)
    delta = np.zeros((n, 2))
    stop = np.full(n, max_steps + 1, dtype=np.int64)
    at_limit = np.zeros(n, dtype=np.bool_)
    v2 = vmax * vmax
    neg_eta = -step_size
    wx = np.empty(_PAIR_BLOCK)
    wy = np.empty(_PAIR_BLOCK)
    for i in range(n):
        dx_i = 0.0
        dy_i = 0.0
        for k in range(1, max_steps + 1):
            xi = px[i] + dx_i
            yi = py[i] + dy_i
            # pair term (planner.phireman._pair_gradient_xy)
            sx, sy = _pair_sum(
                xi,
                yi,
                ox,
                oy,
                pair_start[i],
                pair_start[i + 1],
                attraction,
                floor,
                repulsion,
                reach,
                wx,
                wy,
            )
            gx = sx * pair_factor
            gy = sy * pair_factor
            # task term (TreeSegments._gradient_entries)
            if thorn != 0.0:
                best = np.inf
                bx = 0.0
                by = 0.0
                for s in range(seg_start[i], seg_start[i + 1]):
                    qx = xi - ax[s]
                    qy = yi - ay[s]
                    t = 0.0
                    if e2[s] > 0:
                        t = (qx * ex[s] + qy * ey[s]) / e2[s]
                    t = min(max(t, 0.0), 1.0)
                    fx = ax[s] + t * ex[s]
                    fy = ay[s] + t * ey[s]
                    offx = xi - fx
                    offy = yi - fy
                    dd = offx * offx + offy * offy
                    if dd < best:
                        best, bx, by = dd, offx, offy
                dist = math.sqrt(best)
                if dist > 1e-12:
                    gx = gx + thorn * bx / dist
                    gy = gy + thorn * by / dist
                else:
                    gx = gx + 0.0
                    gy = gy + 0.0
            stx = neg_eta * gx
            sty = neg_eta * gy
            if max(abs(stx), abs(sty)) < tolerance:
                stop[i] = k
                break
            nx = dx_i + stx
            ny = dy_i + sty
            if nx * nx + ny * ny > v2:
                alpha = _limit_fraction(dx_i, dy_i, stx, sty, v2)
                dx_i = dx_i + alpha * stx
                dy_i = dy_i + alpha * sty
                stop[i] = k
                at_limit[i] = True
                break
            dx_i = nx
            dy_i = ny
        delta[i, 0] = dx_i
        delta[i, 1] = dy_i
    return delta, stop, at_limit


@njit(cache=True)
def prune_segments(
    px: np.ndarray,
    py: np.ndarray,
    version: np.ndarray,
    ax: np.ndarray,
    ay: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    e2: np.ndarray,
    count: np.ndarray,
    margin: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The candidate segments of :class:`planner.phireman.TreeSegments` (``pos0`` given): for drone
    i holding tree ``version[i]``, the segments s < count[v] with D_s <= min_s D_s + margin +
    1e-9 (1 + min_s D_s), D_s the distance from (px[i], py[i]) computed as ``TreeSegments._d2``
    does. ax, ay, ex, ey, e2 : (V, E) segment starts, directions and squared lengths per version;
    margin = 2 radius (1 + 1e-9), computed by the caller as the NumPy version does.

    Returns (r, s), (C,) int64 each, row-major (by drone, then segment), as ``np.nonzero``.
    """
    n = len(px)
    e_max = ax.shape[1]
    dist = np.empty(e_max)
    keep_r = np.empty(n * 4, dtype=np.int64)
    keep_s = np.empty(n * 4, dtype=np.int64)
    m = 0
    for i in range(n):
        v = version[i]
        xi = px[i]
        yi = py[i]
        for s in range(count[v]):  # branch-free: vectorised
            qx = xi - ax[v, s]
            qy = yi - ay[v, s]
            t = (qx * ex[v, s] + qy * ey[v, s]) / e2[v, s] if e2[v, s] > 0 else 0.0
            t = min(max(t, 0.0), 1.0)
            ox = xi - (ax[v, s] + t * ex[v, s])
            oy = yi - (ay[v, s] + t * ey[v, s])
            dist[s] = math.sqrt(ox * ox + oy * oy)
        low = np.inf
        for s in range(count[v]):
            if dist[s] < low:
                low = dist[s]
        bound = low + margin + 1e-9 * (1.0 + low)
        if m + count[v] > len(keep_r):  # grown here, not in the loop below (that keeps it tight)
            grow = len(keep_r) + count[v]
            keep_r = np.concatenate((keep_r, np.empty(grow, dtype=np.int64)))
            keep_s = np.concatenate((keep_s, np.empty(grow, dtype=np.int64)))
        for s in range(count[v]):  # branch-free: written always, kept by advancing m
            keep_r[m] = i
            keep_s[m] = s
            m += dist[s] <= bound
    return keep_r[:m], keep_s[:m]


@njit(cache=True)
def propagate_max(
    start: np.ndarray,
    cols: np.ndarray,
    stamps: np.ndarray,
    link_start: np.ndarray,
    link_src: np.ndarray,
    n_cols: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One hop of the recency rule on an entry list (:func:`planner.knowledge.propagate_entries`):
    new[i, k] = max over j in {i} U N(i) of sent[j, k], as a per-entry maximum over a CSR
    adjacency. Integer maxima, so exactly the bit-set / max-plus versions' result.

    start : (n + 1,) CSR offsets of the (row-major) entries by holder; cols, stamps : (E,)
    link_start : (n + 1,) CSR offsets of each holder's sources in link_src (its self-loop included)
    Returns rows, cols, stamps (E',) row-major, columns ascending within a row.
    """
    n = len(start) - 1
    best = np.full(n_cols, -1, dtype=np.int64)
    touched = np.empty(n_cols, dtype=np.int64)
    cap = max(len(cols), 16)
    out_r = np.empty(cap, dtype=np.int64)
    out_c = np.empty(cap, dtype=np.int64)
    out_s = np.empty(cap, dtype=np.int64)
    m = 0
    for i in range(n):
        nt = 0
        for li in range(link_start[i], link_start[i + 1]):
            j = link_src[li]
            for e in range(start[j], start[j + 1]):
                k = cols[e]
                if best[k] < 0:
                    touched[nt] = k
                    nt += 1
                if stamps[e] > best[k]:
                    best[k] = stamps[e]
        if nt == 0:
            continue
        ks = np.sort(touched[:nt])
        if m + nt > cap:
            while m + nt > cap:
                cap *= 2
            out_r = np.concatenate((out_r, np.empty(cap - len(out_r), dtype=np.int64)))
            out_c = np.concatenate((out_c, np.empty(cap - len(out_c), dtype=np.int64)))
            out_s = np.concatenate((out_s, np.empty(cap - len(out_s), dtype=np.int64)))
        for q in range(nt):
            k = ks[q]
            out_r[m] = i
            out_c[m] = k
            out_s[m] = best[k]
            best[k] = -1
            m += 1
    return out_r[:m], out_c[:m], out_s[:m]


@njit(cache=True)
def grid_pairs(
    x: np.ndarray,
    y: np.ndarray,
    range_m: float,
    cell: float,
    x0: float,
    y0: float,
    nx: int,
    ny: int,
    ordered: bool = True,
) -> np.ndarray:
    """All pairs i < j with sqrt(dx^2 + dy^2) <= range_m (the distance as ``np.linalg.norm`` of
    the difference computes it), found through a uniform grid of ``cell``-sized cells (cell >=
    range_m, so a pair lies in the same or adjacent cells). Returns (P, 2) int64 sorted by (i, j)
    (``ordered``; else in the order found, i ascending, which saves the sort of P keys).
    """
    n = len(x)
    n_cells = nx * ny
    cid = np.empty(n, dtype=np.int64)
    cx = np.empty(n, dtype=np.int64)
    cy = np.empty(n, dtype=np.int64)
    head = np.zeros(n_cells + 1, dtype=np.int64)
    for i in range(n):
        cx[i] = min(max(int((x[i] - x0) / cell), 0), nx - 1)
        cy[i] = min(max(int((y[i] - y0) / cell), 0), ny - 1)
        cid[i] = cx[i] * ny + cy[i]
        head[cid[i] + 1] += 1
    for c in range(n_cells):
        head[c + 1] += head[c]
    # counting sort by cell, stable (index order within a cell, as a stable argsort), with the
    # coordinates gathered in that order so the scan below reads them contiguously
    fill = head[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    xs = np.empty(n)
    ys = np.empty(n)
    for i in range(n):
        q = fill[cid[i]]
        fill[cid[i]] = q + 1
        order[q] = i
        xs[q] = x[i]
        ys[q] = y[i]
    cap = 4 * n + 16
    pi = np.empty(cap, dtype=np.int64)
    pj = np.empty(cap, dtype=np.int64)
    near = np.empty(n, dtype=np.bool_)
    m = 0
    r2 = range_m
    for i in range(n):
        xi = x[i]
        yi = y[i]
        ay0 = max(cy[i] - 1, 0)
        ay1 = min(cy[i] + 2, ny)
        for ax in range(max(cx[i] - 1, 0), min(cx[i] + 2, nx)):
            # cells (ax, ay0..ay1-1) are consecutive in the sorted order: one range
            q0 = head[ax * ny + ay0]
            q1 = head[ax * ny + ay1]
            for q in range(q0, q1):  # branch-free tests first (vectorised) ...
                dx = xi - xs[q]
                dy = yi - ys[q]
                near[q - q0] = (order[q] > i) & (math.sqrt(dx * dx + dy * dy) <= r2)
            if m + (q1 - q0) > cap:
                cap = 2 * cap + (q1 - q0)
                pi = np.concatenate((pi, np.empty(cap - len(pi), dtype=np.int64)))
                pj = np.concatenate((pj, np.empty(cap - len(pj), dtype=np.int64)))
            for q in range(q0, q1):  # ... then the pairs, in cell order: written, kept by m
                pi[m] = i
                pj[m] = order[q]
                m += near[q - q0]
    out = np.empty((m, 2), dtype=np.int64)
    if not ordered:  # the order in which the cells were scanned
        for q in range(m):
            out[q, 0] = pi[q]
            out[q, 1] = pj[q]
        return out
    key = pi[:m] * n + pj[:m]
    o = np.argsort(key)
    for q in range(m):
        out[q, 0] = pi[o[q]]
        out[q, 1] = pj[o[q]]
    return out


@njit(cache=True)
def finish_knowledge_update(
    r: np.ndarray,
    c: np.ndarray,
    s: np.ndarray,
    alive: np.ndarray,
    t_step: int,
    age_cut: int,
    hist: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    far2: float,
    radio2: float,
    forget: bool,
    t_sent: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The end of :meth:`planner.knowledge.Knowledge.update` after the message hop, in one pass,
    with the NumPy version's integer rules and the same float arithmetic (bit for bit):

    own entries (dead holders' entries dropped, every alive holder's own entry stamped t_step,
    inserted in row-major order if missing), the age cut (stamp >= age_cut), the distance cut
    (d^2 > far2, plus believed within radio range yet not heard, stamp < t_sent, if ``forget``).

    r, c, s : (E,) entries after the hop, row-major, one per (r, c); hist : (T, N, 2) positions.
    Returns rows, cols, stamps (kept entries), col_held (N,) bool (known to somebody before the
    distance cut), believed x and y (E',) of the kept entries.
    """
    n = len(alive)
    m = len(r)
    cap = m + n
    nr = np.empty(cap, dtype=np.int64)
    nc = np.empty(cap, dtype=np.int64)
    ns = np.empty(cap, dtype=np.int64)
    q = 0
    e = 0
    # own entries + age cut, holder by holder (entries are row-major)
    for i in range(n):
        start = e
        while e < m and r[e] == i:
            e += 1
        if not alive[i]:
            continue
        placed = False
        for f in range(start, e):
            k = c[f]
            if not placed and k >= i:
                placed = True
                nr[q] = i
                nc[q] = i
                ns[q] = t_step
                q += 1
                if k == i:
                    continue
            st = s[f]
            if st >= age_cut:
                nr[q] = i
                nc[q] = k
                ns[q] = st
                q += 1
        if not placed:
            nr[q] = i
            nc[q] = i
            ns[q] = t_step
            q += 1
    col_held = np.zeros(n, dtype=np.bool_)
    for f in range(q):
        col_held[nc[f]] = True
    # distance cut
    keep = np.empty(q, dtype=np.bool_)
    bx = np.empty(q)
    by = np.empty(q)
    kept = 0
    for f in range(q):
        x = hist[ns[f], nc[f], 0]
        y = hist[ns[f], nc[f], 1]
        dx = x - px[nr[f]]
        dy = y - py[nr[f]]
        d2 = dx * dx
        d2 += dy * dy
        far = d2 > far2
        if forget and d2 <= radio2 and ns[f] < t_sent:
            far = True
        keep[f] = not far
        bx[f] = x
        by[f] = y
        if not far:
            kept += 1
    rr = np.empty(kept, dtype=np.int64)
    cc = np.empty(kept, dtype=np.int64)
    ss = np.empty(kept, dtype=np.int64)
    xx = np.empty(kept)
    yy = np.empty(kept)
    w = 0
    for f in range(q):
        if keep[f]:
            rr[w] = nr[f]
            cc[w] = nc[f]
            ss[w] = ns[f]
            xx[w] = bx[f]
            yy[w] = by[f]
            w += 1
    return rr, cc, ss, col_held, xx, yy


@njit(cache=True, fastmath={"nnan", "nsz"})
def _min_no_nan(values: np.ndarray, n: int) -> float:
    """min(values[:n], inf), vectorised: nnan / nsz let LLVM reorder the comparisons, which gives
    the same minimum when no value is NaN (the caller's condition; -0 and +0 do not occur: squares)."""
    m = np.inf
    for q in range(n):
        v = values[q]
        m = v if v < m else m
    return m


@njit(cache=True)
def descend_separable_leader(
    px: np.ndarray,
    py: np.ndarray,
    pair_start: np.ndarray,
    ox: np.ndarray,
    oy: np.ndarray,
    aw: np.ndarray,
    lx: np.ndarray,
    ly: np.ndarray,
    gain: np.ndarray,
    exponent: float,
    r: float,
    lfloor: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
    step_size: float,
    tolerance: float,
    vmax: float,
    max_steps: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """DCCRS's async descent (:meth:`planner.dccrs.DccrsPlanner._descend_entries`: ``descend``
    with ``separable=True``, 'per_drone'), every drone in one compiled loop: pair term with
    per-holder attraction aw[i] = ℳ w_i over the drone's entries + leader term
    (:func:`planner.dccrs.leader_gradient`) toward the nearest of its leaders lx[i], ly[i] (first on
    ties). Same arithmetic as the NumPy version, bit for bit (up to the sign of a zero gradient).
    Returns delta (n, 2), stop (n,), at_limit (n,) as :func:`descend_separable`.
    """
    n = len(px)
    n_lead = lx.shape[1]
    delta = np.zeros((n, 2))
    stop = np.full(n, max_steps + 1, dtype=np.int64)
    at_limit = np.zeros(n, dtype=np.bool_)
    v2 = vmax * vmax
    neg_eta = -step_size
    wx = np.empty(_PAIR_BLOCK)
    wy = np.empty(_PAIR_BLOCK)
    one_plus = 1.0 + exponent
    lead_d2 = np.empty(n_lead)
    for i in range(n):
        dx_i = 0.0
        dy_i = 0.0
        a_i = aw[i]
        for k in range(1, max_steps + 1):
            xi = px[i] + dx_i
            yi = py[i] + dy_i
            sx, sy = _pair_sum(
                xi,
                yi,
                ox,
                oy,
                pair_start[i],
                pair_start[i + 1],
                a_i,
                floor,
                repulsion,
                reach,
                wx,
                wy,
            )
            gx = sx * pair_factor
            gy = sy * pair_factor
            if exponent != -1.0:
                # nearest leader, first on ties: the squared distances vectorised, their minimum
                # vectorised (_min_no_nan, if none is NaN), then the first index at it
                nan = False
                for q in range(n_lead):
                    ax = xi - lx[i, q]
                    ay = yi - ly[i, q]
                    dd = ax * ax + ay * ay
                    lead_d2[q] = dd
                    nan |= dd != dd
                best = np.inf
                near = -1
                if nan:  # the scan's rule: NaN is never below
                    for q in range(n_lead):
                        if lead_d2[q] < best:
                            best = lead_d2[q]
                            near = q
                else:
                    best = _min_no_nan(lead_d2, n_lead)
                    if best < np.inf:
                        near = 0
                        while lead_d2[near] != best:
                            near += 1
                bx = xi - lx[i, near] if near >= 0 else 0.0
                by = yi - ly[i, near] if near >= 0 else 0.0
                d = math.sqrt(best)
                ratio = max(d, lfloor) / r
                # ** 1.0 is the ratio itself (NumPy's power takes that fast path too): no pow call
                mag = gain[i] * one_plus * (ratio if exponent == 1.0 else ratio**exponent)
                f = mag / d if d > 0 else 0.0
                gx = gx + bx * f
                gy = gy + by * f
            stx = neg_eta * gx
            sty = neg_eta * gy
            if max(abs(stx), abs(sty)) < tolerance:
                stop[i] = k
                break
            nx = dx_i + stx
            ny = dy_i + sty
            if nx * nx + ny * ny > v2:
                alpha = _limit_fraction(dx_i, dy_i, stx, sty, v2)
                dx_i = dx_i + alpha * stx
                dy_i = dy_i + alpha * sty
                stop[i] = k
                at_limit[i] = True
                break
            dx_i = nx
            dy_i = ny
        delta[i, 0] = dx_i
        delta[i, 1] = dy_i
    return delta, stop, at_limit


@njit(cache=True, fastmath={"nnan", "nsz"})
def _row_min(row: np.ndarray, add: np.ndarray, n: int) -> float:
    # no NaN here; nnan / nsz only let LLVM vectorise the min (the sums are not reordered)
    m = np.inf
    for v in range(n):
        c = row[v] + add[v]
        m = c if c < m else m
    return m


@njit(cache=True)
def _first_at(row: np.ndarray, add: np.ndarray, n: int, value: float) -> int:
    for v in range(n):
        if row[v] + add[v] == value:
            return v
    return 0


@njit(cache=True)
def greedy_pick(
    direct: np.ndarray,
    split: np.ndarray,
    cb_path: np.ndarray,
    parent: np.ndarray,
    n_free: int,
    n: int,
    with_path: bool,
) -> tuple[int, float, int, float]:
    """One step's choice in :func:`planner.steiner._greedy_tree`: the first minimum (row-major, as
    ``np.argmin`` on the flattened array) of cost_a = direct[:n_free, :n] + cb_path[:n] and of
    cost_b = split[:n_free, :n] + cb_path[parent[:n]] (without ``with_path``: direct and split
    themselves), without forming either array: row minima first (vectorised), then the first
    column in the first row that attains the overall minimum. Returns (ia, a_min, ib, b_min)."""
    pa = np.zeros(n)
    pb = np.zeros(n)
    if with_path:
        for v in range(n):
            pa[v] = cb_path[v]
            pb[v] = cb_path[parent[v]]
    # x + 0.0 == x for every x here (costs are >= 0 or inf), so the additions change nothing then
    ra = 0
    rb = 0
    a_min = _row_min(direct[0], pa, n)
    b_min = _row_min(split[0], pb, n)
    for j in range(1, n_free):
        m = _row_min(direct[j], pa, n)
        if m < a_min:
            a_min, ra = m, j
        m = _row_min(split[j], pb, n)
        if m < b_min:
            b_min, rb = m, j
    ia = ra * n + _first_at(direct[ra], pa, n, a_min)
    ib = rb * n + _first_at(split[rb], pb, n, b_min)
    return ia, a_min, ib, b_min

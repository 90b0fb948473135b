"""Compiled task-tree relaxation (Numba): :func:`planner.steiner._relax_steiner`'s Gauss-Seidel
sweeps, its Fermat points and geometric medians, in one compiled call.

The reference is the plain-Python code in :mod:`planner.steiner` (``_relax_steiner``,
``_fermat_scalar``, ``_geometric_median_scalar``); ``tests/planner/test_steiner_kernels.py``
compares the two bit for bit. The same operations run in the same order, so the results are the
same bits:

* distances are CPython's ``math.hypot`` (:func:`py_hypot`: its scaled, error-free squaring and
  compensated sum with one correction step, not libm's ``hypot``), checked against ``math.hypot``
  on random and edge-case inputs;
* Python's ``sum`` over floats (3.11: one double accumulator from 0.0, in order) is a loop from
  0.0; ``min`` / ``max`` keep the first extreme;
* the children lists (whose order is each Steiner node's neighbour order, and so the order of the
  Fermat point's vertices) are sibling linked lists with the same remove / append semantics.

No ``fastmath`` (no contraction into fused multiply-adds). Used only when ``_kernels.NUMBA`` and
``_kernels.ENABLED``.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numpy as np

from planner import _kernels

__all__ = ["py_hypot", "relax_steiner", "APPLIES"]

_F = TypeVar("_F", bound=Callable[..., Any])

#: The kernel reproduces CPython 3.11's ``math.hypot`` and ``sum`` (3.12's ``sum`` of floats is
#: compensated): elsewhere the caller keeps the Python sweeps.
APPLIES = sys.version_info[:2] == (3, 11)

_SQRT3 = math.sqrt(3.0)
_DBL_MIN = 2.2250738585072014e-308
_SPLIT = 134217729.0  # 2**27 + 1, Veltkamp's splitter


def _jit(func: _F) -> _F:
    """``numba.njit(cache=True)`` typed for the checker; the plain function without Numba."""
    if not _kernels.NUMBA:  # pragma: no cover
        return func
    from numba import njit

    return cast(_F, njit(cache=True)(func))


@_jit
def _two_prod(a: float, b: float) -> tuple[float, float]:
    """a * b as hi + lo exactly (Dekker; the same pair as CPython's fma-based ``dl_mul``)."""
    p = a * b
    c = _SPLIT * a
    ah = c - (c - a)
    al = a - ah
    c = _SPLIT * b
    bh = c - (c - b)
    bl = b - bh
    err = ((ah * bh - p) + ah * bl + al * bh) + al * bl
    return p, err


@_jit
def _norm_scaled(x: float, y: float, mx: float) -> float:
    """CPython's ``vector_norm`` for two finite non-negative coordinates, mx = max(x, y) > 0."""
    e = math.frexp(mx)[1]
    if e < -1023:  # subnormal: CPython scales up by 1 / DBL_MIN and multiplies the norm back
        r = _norm_scaled(x / _DBL_MIN, y / _DBL_MIN, mx / _DBL_MIN)
        return _DBL_MIN * r
    scale = math.ldexp(1.0, -e)
    csum = 1.0
    frac1 = 0.0
    frac2 = 0.0
    v = x * scale
    hi, lo = _two_prod(v, v)
    s = csum + hi
    frac2 += (csum - s) + hi
    csum = s
    frac1 += lo
    v = y * scale
    hi, lo = _two_prod(v, v)
    s = csum + hi
    frac2 += (csum - s) + hi
    csum = s
    frac1 += lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    hi, lo = _two_prod(-h, h)
    s = csum + hi
    frac2 += (csum - s) + hi
    csum = s
    frac1 += lo
    r = csum - 1.0 + (frac1 + frac2)
    h += r / (2.0 * h)
    return h / scale


@_jit
def py_hypot(x: float, y: float) -> float:
    """``math.hypot(x, y)`` as CPython 3.11 computes it, bit for bit."""
    x = abs(x)
    y = abs(y)
    mx = 0.0
    if x > mx:
        mx = x
    if y > mx:
        mx = y
    if math.isinf(mx):
        return mx
    if math.isnan(x) or math.isnan(y):
        return math.nan
    if mx == 0.0:
        return mx
    return _norm_scaled(x, y, mx)


@_jit
def _hyp(x: float, y: float, flag: np.ndarray) -> float:
    """:func:`py_hypot`, raising ``flag[0]`` where its result may differ from CPython's (a
    subnormal largest coordinate: CPython's path there is not reproduced bit for bit)."""
    big = max(abs(x), abs(y))
    if 0.0 < big < _DBL_MIN:
        flag[0] = True
    return py_hypot(x, y)


@_jit
def _fermat(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float, flag: np.ndarray
) -> tuple[float, float, int]:
    """:func:`planner.steiner._fermat_scalar`."""
    abx, aby = bx - ax, by - ay
    acx, acy = cx - ax, cy - ay
    bcx, bcy = cx - bx, cy - by
    d1 = _hyp(abx, aby, flag)
    d2 = _hyp(acx, acy, flag)
    scale = d2 if d2 > d1 else d1
    if scale == 0.0:
        return ax, ay, 0
    abx, aby, acx, acy = abx / scale, aby / scale, acx / scale, acy / scale
    bcx, bcy = bcx / scale, bcy / scale
    cross = abs(abx * acy - aby * acx)
    den_a = cross + _SQRT3 * (abx * acx + aby * acy)
    den_b = cross - _SQRT3 * (abx * bcx + aby * bcy)
    den_c = cross + _SQRT3 * (acx * bcx + acy * bcy)
    if den_a <= 0.0:
        return ax, ay, 0
    if den_b <= 0.0:
        return bx, by, 1
    if den_c <= 0.0:
        return cx, cy, 2
    wa, wb, wc = den_b * den_c, den_a * den_c, den_a * den_b
    total = wa + wb + wc
    wb, wc = wb / total, wc / total
    return ax + scale * (wb * abx + wc * acx), ay + scale * (wb * aby + wc * acy), -1


@_jit
def _median(
    xs: np.ndarray,
    ys: np.ndarray,
    n: int,
    x0: float,
    y0: float,
    max_iter: int,
    flag: np.ndarray,
) -> tuple[float, float, int]:
    """:func:`planner.steiner._geometric_median_scalar` on ``xs[:n]``, ``ys[:n]``."""
    for j in range(n):
        rx = 0.0
        ry = 0.0
        mult = 0
        for i in range(n):
            dx, dy = xs[i] - xs[j], ys[i] - ys[j]
            d = _hyp(dx, dy, flag)
            if d == 0.0:
                mult += 1
            else:
                rx += dx / d
                ry += dy / d
        if _hyp(rx, ry, flag) <= mult:
            return xs[j], ys[j], j
    x, y = x0, y0
    on_input = False
    for i in range(n):
        if x == xs[i] and y == ys[i]:
            on_input = True
            break
    if on_input:
        sx = 0.0
        sy = 0.0
        for i in range(n):
            sx += xs[i]
        for i in range(n):
            sy += ys[i]
        x, y = sx / n, sy / n
    scale = _hyp(xs[0] - x, ys[0] - y, flag)
    for i in range(1, n):
        d = _hyp(xs[i] - x, ys[i] - y, flag)
        if d > scale:
            scale = d
    for _ in range(max_iter):
        sw = 0.0
        sx = 0.0
        sy = 0.0
        for i in range(n):
            d = _hyp(xs[i] - x, ys[i] - y, flag)
            if d == 0.0:
                return x, y, -1
            sw += 1.0 / d
            sx += xs[i] / d
            sy += ys[i] / d
        nx, ny = sx / sw, sy / sw
        step = _hyp(nx - x, ny - y, flag)
        x, y = nx, ny
        if step <= 1e-14 * scale:
            break
    return x, y, -1


@_jit
def _unlink(
    v: int, p: int, head: np.ndarray, tail: np.ndarray, nxt: np.ndarray, prv: np.ndarray
) -> None:
    a, b = prv[v], nxt[v]
    if a >= 0:
        nxt[a] = b
    else:
        head[p] = b
    if b >= 0:
        prv[b] = a
    else:
        tail[p] = a
    nxt[v] = -1
    prv[v] = -1


@_jit
def _append(
    v: int, p: int, head: np.ndarray, tail: np.ndarray, nxt: np.ndarray, prv: np.ndarray
) -> None:
    t = tail[p]
    prv[v] = t
    nxt[v] = -1
    if t >= 0:
        nxt[t] = v
    else:
        head[p] = v
    tail[p] = v


@_jit
def _same_bits(a: float, b: float) -> bool:
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


@_jit
def _relax(
    xs: np.ndarray,
    ys: np.ndarray,
    par: np.ndarray,
    n_tasks: int,
    sweeps: int,
    shortcuts: bool,
    coincide_rtol: float,
    max_iter: int,
    flag: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, bool]:
    k = len(xs)
    head = np.full(k, -1, dtype=np.int64)
    tail = np.full(k, -1, dtype=np.int64)
    nxt = np.full(k, -1, dtype=np.int64)
    prv = np.full(k, -1, dtype=np.int64)
    for v in range(1, k):
        _append(v, par[v], head, tail, nxt, prv)
    alive = np.ones(k, dtype=np.bool_)
    nbrs = np.empty(k, dtype=np.int64)
    nx = np.empty(k)
    ny = np.empty(k)
    dists = np.empty(k)
    spliced = False
    changed = True
    for _ in range(sweeps):
        changed = False
        for s in range(n_tasks + 1, k):
            if not alive[s]:
                continue
            nn = 1
            nbrs[0] = par[s]
            c = head[s]
            while c >= 0:
                nbrs[nn] = c
                nn += 1
                c = nxt[c]
            onto = -1
            if nn <= 2:
                onto = par[s]
            else:
                for i in range(nn):
                    nx[i] = xs[nbrs[i]]
                    ny[i] = ys[nbrs[i]]
                if nn == 3:
                    x, y, vert = _fermat(nx[0], ny[0], nx[1], ny[1], nx[2], ny[2], flag)
                else:
                    x, y, vert = _median(nx, ny, nn, xs[s], ys[s], max_iter, flag)
                if vert >= 0:
                    onto = nbrs[vert]
                else:
                    old = 0.0
                    for i in range(nn):
                        old += _hyp(nx[i] - xs[s], ny[i] - ys[s], flag)
                    total = 0.0
                    for i in range(nn):
                        dists[i] = _hyp(nx[i] - x, ny[i] - y, flag)
                        total += dists[i]
                    if total <= old:
                        if not changed and not (_same_bits(x, xs[s]) and _same_bits(y, ys[s])):
                            changed = True
                        xs[s] = x
                        ys[s] = y
                    else:
                        for i in range(nn):
                            dists[i] = _hyp(nx[i] - xs[s], ny[i] - ys[s], flag)
                    j = 0
                    big = dists[0]
                    for i in range(1, nn):
                        if dists[i] < dists[j]:
                            j = i
                        if dists[i] > big:
                            big = dists[i]
                    if dists[j] <= coincide_rtol * (1.0 + big):
                        onto = nbrs[j]
            if onto < 0:
                continue
            # splice(s, onto)
            spliced = True
            changed = True
            p = par[s]
            _unlink(s, p, head, tail, nxt, prv)
            if onto == p:
                c = head[s]
                while c >= 0:
                    after = nxt[c]
                    par[c] = p
                    _append(c, p, head, tail, nxt, prv)
                    c = after
            else:
                par[onto] = p
                _unlink(onto, s, head, tail, nxt, prv)
                _append(onto, p, head, tail, nxt, prv)
                c = head[s]
                while c >= 0:
                    after = nxt[c]
                    par[c] = onto
                    _append(c, onto, head, tail, nxt, prv)
                    c = after
            head[s] = -1
            tail[s] = -1
            alive[s] = False
        if not changed and shortcuts:
            break
    fixed = sweeps > 0 and not changed and not spliced
    n_keep = 0
    new_index = np.full(k, -1, dtype=np.int64)
    for v in range(k):
        if alive[v]:
            new_index[v] = n_keep
            n_keep += 1
    nodes = np.empty((n_keep, 2))
    parent = np.empty(n_keep, dtype=np.int64)
    for v in range(k):
        if alive[v]:
            i = new_index[v]
            nodes[i, 0] = xs[v]
            nodes[i, 1] = ys[v]
            parent[i] = -1 if par[v] < 0 else new_index[par[v]]
    return nodes, parent, fixed


def relax_steiner(
    nodes_m: np.ndarray,
    parent: np.ndarray,
    n_tasks: int,
    sweeps: int,
    shortcuts: bool,
    coincide_rtol: float,
    max_iter: int,
) -> tuple[np.ndarray, np.ndarray, bool] | None:
    """:func:`planner.steiner._relax_steiner` compiled (the same nodes, parents and fixed-point
    flag, bit for bit); None when it does not apply (no Numba, switched off, not CPython 3.11)."""
    if not (_kernels.NUMBA and _kernels.ENABLED and APPLIES):
        return None
    flag = np.zeros(1, dtype=np.bool_)
    out = _relax(
        np.array(nodes_m[:, 0], dtype=np.float64),
        np.array(nodes_m[:, 1], dtype=np.float64),
        np.array(parent, dtype=np.int64),
        int(n_tasks),
        int(sweeps),
        bool(shortcuts),
        float(coincide_rtol),
        int(max_iter),
        flag,
    )
    return None if flag[0] else out

"""Compiled greedy task-tree build (Numba): :func:`planner.steiner._greedy_tree_python` in one call.

The reference is the NumPy code in :mod:`planner.steiner` (``_greedy_tree_python``,
``_split_costs``, ``_direct_costs``, ``_fermat_complex``, ``_fermat_scalar``);
``tests/planner/test_greedy_kernel.py`` compares the two bit for bit. The kernel runs the same
IEEE operations in the same order, element by element, so it returns the same bits, given how
NumPy evaluates the few operations that are not a single correctly rounded IEEE operation:

* ``np.abs`` of a complex128 array (NumPy's SIMD loop, ``simd_cabsolute``): with
  ``L = max(|re|, |im|)``, ``S = min(|re|, |im|)``, ``r = S / L`` (0 if L == 0), the result is
  ``sqrt(fma(r, r, 1)) * L`` (:func:`cabs`);
* a complex128 array product (NumPy's SIMD loop, ``simd_cmul``: a fused multiply-add/subtract):
  real ``fma(ar, br, -(ai*bi))``, imaginary ``fma(ar, bi, ai*br)`` (:func:`cmul_re`,
  :func:`cmul_im`); a float64 operand is cast to complex first (imaginary part +0.0), and
  ``conjugate`` negates the imaginary part;
* ``abs`` of a complex128 scalar (NumPy's scalar math): the C library's ``hypot``, which Numba's
  ``math.hypot`` calls;
* ``math.hypot`` of plain floats in ``_fermat_scalar``: CPython's own algorithm, reproduced by
  :func:`planner._steiner_kernels.py_hypot` (CPython 3.11 only, as there).

(Measured with NumPy 2.4 on an AVX-512 CPU.) NumPy picks its loop by the operands' shapes and
strides: a complex product broadcast without a cast whose result has one element, say, takes its
scalar loop, unfused; the build has no such product (its complex-by-complex products have equal
shapes, the others a float cast to complex). The first two depend on the CPU and the NumPy build
(another build may take the scalar loop, or a CPU without FMA a plain multiply-add), so before its
first use the kernel checks them (:func:`matches_numpy`, ~70 ms once a process): on a fixed probe
set, at every shape of a build up to 17 free tasks and a few larger ones, the compiled element
formulas must give NumPy's bits (``_split_costs``, ``_direct_costs``), libm's ``hypot`` NumPy's
scalar ``abs``, and the compiled Fermat point ``_fermat_scalar``'s. Otherwise the kernel declines
(returns None) for the rest of the process and the NumPy version runs. It also declines on inputs
outside the range it was checked for: non-finite values, coordinates or c_b above 1e100 (no
overflow anywhere), or a subnormal largest side in a scalar Fermat point (as
:func:`planner._steiner_kernels.relax_steiner` does).

No ``fastmath`` (LLVM then neither reorders nor contracts); the fused multiply-adds are explicit
(``llvm.fma.f64``, exact on every target). Used only when ``_kernels.NUMBA`` and
``_kernels.ENABLED``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar, cast

import numpy as np

from planner import _kernels, _steiner_kernels

__all__ = ["cabs", "cmul_re", "cmul_im", "split_costs", "greedy_tree", "matches_numpy"]

_log = logging.getLogger(__name__)

_F = TypeVar("_F", bound=Callable[..., Any])

_SQRT3 = math.sqrt(3.0)
_TINY = float(np.finfo(np.float64).tiny)

#: Largest |coordinate| and c_b the kernel accepts: no sum, product or cost can overflow below it.
MAX_ABS = 1e100


def _jit(func: _F) -> _F:
    """``numba.njit(cache=True)`` typed for the checker; the plain function without Numba."""
    if not _kernels.NUMBA:  # pragma: no cover
        return func
    from numba import njit

    return cast(_F, njit(cache=True)(func))


if _kernels.NUMBA:
    from llvmlite import ir  # type: ignore[import-untyped]
    from numba import types
    from numba.extending import intrinsic

    @intrinsic
    def _fma_intrinsic(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
        """``llvm.fma.f64``: a * b + c with one rounding (a library call where the CPU has none)."""
        if not all(t == types.float64 for t in (a, b, c)):
            return None
        sig = types.float64(types.float64, types.float64, types.float64)

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            fn = builder.module.declare_intrinsic("llvm.fma", [ir.DoubleType()] * 3)
            return builder.call(fn, args)

        return sig, codegen

    _fma_call: Any = _fma_intrinsic  # (the typing context argument is Numba's, not the caller's)

    @_jit
    def fma(a: float, b: float, c: float) -> float:
        """a * b + c rounded once."""
        return _fma_call(a, b, c)

else:  # pragma: no cover

    def fma(a: float, b: float, c: float) -> float:
        """a * b + c rounded once (Python 3.13's ``math.fma``; unused without Numba)."""
        return cast(float, math.fma(a, b, c))  # type: ignore[attr-defined]


@_jit
def cabs(re: float, im: float) -> float:
    """``np.abs`` of one element of a complex128 array (finite input), NumPy's SIMD loop."""
    x = abs(re)
    y = abs(im)
    larger = x if x > y else y
    smaller = y if y < x else x
    ratio = 0.0 if larger == 0.0 else smaller / larger
    return math.sqrt(fma(ratio, ratio, 1.0)) * larger


@_jit
def cmul_re(ar: float, ai: float, br: float, bi: float) -> float:
    """Real part of one element of a complex128 array product a * b (NumPy's ``simd_cmul``)."""
    return fma(ar, br, -(ai * bi))


@_jit
def cmul_im(ar: float, ai: float, br: float, bi: float) -> float:
    """Imaginary part of one element of a complex128 array product a * b."""
    return fma(ar, bi, ai * br)


@_jit
def _split_entry(
    ur: float,
    ui: float,
    wr: float,
    wi: float,
    yr: float,
    yi: float,
    n_below: float,
    cb: float,
) -> tuple[float, float]:
    """One element of :func:`planner.steiner._split_costs`: (split, stretch) of the edge u -> w
    for the task y, i.e. ``_fermat_complex(u, w, y, exact_ab=False)`` and the costs, in NumPy's
    operation order."""
    # _fermat_complex(a=u, b=w, c=y)
    abr, abi = wr - ur, wi - ui
    acr, aci = yr - ur, yi - ui
    sa = cabs(abr, abi)
    sc = cabs(acr, aci)
    scale = sa if sa > sc else sc  # np.maximum (no NaN here)
    scale = scale if scale > _TINY else _TINY
    inv = 1.0 / scale
    # ab, ac, bc = ab * inv_scale, ac * inv_scale, (c - b) * inv_scale: inv_scale cast to complex
    bcr0, bci0 = yr - wr, yi - wi
    abr, abi = cmul_re(abr, abi, inv, 0.0), cmul_im(abr, abi, inv, 0.0)
    acr, aci = cmul_re(acr, aci, inv, 0.0), cmul_im(acr, aci, inv, 0.0)
    bcr, bci = cmul_re(bcr0, bci0, inv, 0.0), cmul_im(bcr0, bci0, inv, 0.0)
    p1 = abr * aci
    p2 = abi * acr
    cross = abs(p1 - p2)
    den_a = cross + _SQRT3 * cmul_re(abr, -abi, acr, aci)
    den_b = cross - _SQRT3 * cmul_re(abr, -abi, bcr, bci)
    den_c = cross + _SQRT3 * cmul_re(acr, -aci, bcr, bci)
    at_a = den_a <= 0.0
    at_b = den_b <= 0.0
    at_c = den_c <= 0.0
    if at_a:
        den_a = 1.0
    if at_b:
        den_b = 1.0
    if at_c:
        den_c = 1.0
    wa = den_b * den_c
    wb = den_a * den_c
    wc = den_a * den_b
    total = wa + wb + wc
    tb = wb / total
    tc = wc / total
    # z = a + scale * ((wb / total) * ab + (wc / total) * ac): floats cast to complex
    qr = cmul_re(tb, 0.0, abr, abi) + cmul_re(tc, 0.0, acr, aci)
    qi = cmul_im(tb, 0.0, abr, abi) + cmul_im(tc, 0.0, acr, aci)
    sr = ur + cmul_re(scale, 0.0, qr, qi)
    si = ui + cmul_im(scale, 0.0, qr, qi)
    if at_c:
        sr, si = yr, yi
    # _split_costs
    us = cabs(sr - ur, si - ui)
    sy = cabs(yr - sr, yi - si)
    detour = us + cabs(wr - sr, wi - si) - cabs(wr - ur, wi - ui)
    cost = (detour + sy) + cb * ((us + sy) + n_below * detour)
    split = np.inf if (at_a or at_b) else cost
    return split, cb * detour


@_jit
def _split_costs_arrays(
    ur: np.ndarray,
    ui: np.ndarray,
    wr: np.ndarray,
    wi: np.ndarray,
    yr: np.ndarray,
    yi: np.ndarray,
    n_below: np.ndarray,
    cb: float,
) -> tuple[np.ndarray, np.ndarray]:
    n_y, n_e = len(yr), len(ur)
    split = np.empty((n_y, n_e))
    stretch = np.empty((n_y, n_e))
    for j in range(n_y):
        for e in range(n_e):
            split[j, e], stretch[j, e] = _split_entry(
                ur[e], ui[e], wr[e], wi[e], yr[j], yi[j], n_below[e], cb
            )
    return split, stretch


def _re_im(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contiguous real and imaginary parts of a complex array (the kernels' inputs)."""
    return np.ascontiguousarray(z.real), np.ascontiguousarray(z.imag)


def split_costs(
    u: np.ndarray, w: np.ndarray, y: np.ndarray, n_below: np.ndarray, cb: float
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`planner.steiner._split_costs` element by element: u, w (n,) complex, y (F, 1)."""
    return _split_costs_arrays(
        *_re_im(u), *_re_im(w), *_re_im(y[:, 0]), np.asarray(n_below, dtype=np.float64), float(cb)
    )


@_jit
def _cabs_array(re: np.ndarray, im: np.ndarray) -> np.ndarray:
    out = np.empty(len(re))
    for i in range(len(re)):
        out[i] = cabs(re[i], im[i])
    return out


@_jit
def _cmul_array(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 2) real / imaginary parts of a * b, a and b (n, 2) real / imaginary parts."""
    out = np.empty_like(a)
    for i in range(len(a)):
        out[i, 0] = cmul_re(a[i, 0], a[i, 1], b[i, 0], b[i, 1])
        out[i, 1] = cmul_im(a[i, 0], a[i, 1], b[i, 0], b[i, 1])
    return out


@_jit
def _hypot_array(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    out = np.empty(len(x))
    for i in range(len(x)):
        out[i] = math.hypot(x[i], y[i])
    return out


def cabs_array(z: np.ndarray) -> np.ndarray:
    """:func:`cabs` of each element of a 1-D complex array (for the tests)."""
    return _cabs_array(np.ascontiguousarray(z.real), np.ascontiguousarray(z.imag))


def cmul_array(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`cmul_re` / :func:`cmul_im` of 1-D complex arrays, as complex (for the tests)."""
    a2 = np.stack([a.real, a.imag], axis=1)
    b2 = np.stack([b.real, b.imag], axis=1)
    out = _cmul_array(a2, b2)
    return _pack(out)


def _pack(re_im: np.ndarray) -> np.ndarray:
    out = np.empty(len(re_im), dtype=np.complex128)
    out.real = re_im[:, 0]
    out.imag = re_im[:, 1]
    return out


def hypot_array(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Numba's ``math.hypot`` (the C library's) of each pair (for the tests)."""
    return _hypot_array(np.ascontiguousarray(x, np.float64), np.ascontiguousarray(y, np.float64))


@_jit
def _direct_entry(yr: float, yi: float, pr: float, pi: float, c1: float) -> float:
    """One element of :func:`planner.steiner._direct_costs`, c1 = 1 + c_b."""
    return c1 * cabs(yr - pr, yi - pi)


@_jit
def _direct_costs_arrays(
    yr: np.ndarray, yi: np.ndarray, pr: np.ndarray, pi: np.ndarray, cb: float
) -> np.ndarray:
    out = np.empty((len(yr), len(pr)))
    c1 = 1.0 + cb
    for j in range(len(yr)):
        for v in range(len(pr)):
            out[j, v] = _direct_entry(yr[j], yi[j], pr[v], pi[v], c1)
    return out


def direct_costs(y: np.ndarray, p: np.ndarray, cb: float) -> np.ndarray:
    """:func:`planner.steiner._direct_costs` element by element: y (F, 1), p (n,) complex."""
    return _direct_costs_arrays(*_re_im(y[:, 0]), *_re_im(p), float(cb))


# --------------------------------------------------------------------------------------------
# The build
# --------------------------------------------------------------------------------------------


@_jit
def _new_node(
    zr: float,
    zi: float,
    final: int,
    under: int,
    v: int,
    pos_r: np.ndarray,
    pos_i: np.ndarray,
    final_index: np.ndarray,
    parent: np.ndarray,
    path: np.ndarray,
    anc: np.ndarray,
) -> None:
    """``new_node``: leaf v at z under ``under``; |z - pos[under]| is NumPy's scalar ``abs`` (the
    C library's ``hypot``), as Numba's ``math.hypot``."""
    pos_r[v] = zr
    pos_i[v] = zi
    final_index[v] = final
    parent[v] = under
    path[v] = path[under] + math.hypot(zr - pos_r[under], zi - pos_i[under])
    anc[v, :] = anc[under, :]
    anc[v, v] = True


@_jit
def _lift_onto(
    v: int,
    w: int,
    n: int,
    pos_r: np.ndarray,
    pos_i: np.ndarray,
    parent: np.ndarray,
    path: np.ndarray,
    n_below: np.ndarray,
    anc: np.ndarray,
) -> None:
    """``lift_onto``: the new leaf v (a child of w's parent u) becomes w's parent, u -> v -> w."""
    u = parent[w]
    parent[w] = v
    extra = (
        math.hypot(pos_r[v] - pos_r[u], pos_i[v] - pos_i[u])
        + math.hypot(pos_r[w] - pos_r[v], pos_i[w] - pos_i[v])
        - math.hypot(pos_r[w] - pos_r[u], pos_i[w] - pos_i[u])
    )
    for b in range(n):  # rows >= n (nodes not created yet) have no ancestor
        if anc[b, w]:
            path[b] += extra
            anc[b, v] = True
    n_below[v] = n_below[w]


@_jit
def _greedy(
    base_x: float,
    base_y: float,
    task_r: np.ndarray,
    task_i: np.ndarray,
    cb: float,
    flag: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`planner.steiner._greedy_tree_python` (same layout, same names); ``flag[0]`` is
    raised where a scalar Fermat point may differ from Python's (then the result is discarded)."""
    m = len(task_r)
    kmax = 2 * m + 1
    row_r = task_r.copy()  # free tasks first
    row_i = task_i.copy()
    row_task = np.arange(m)
    pos_r = np.zeros(kmax)
    pos_i = np.zeros(kmax)
    pos_r[0] = base_x
    pos_i[0] = base_y
    final_index = np.zeros(kmax, dtype=np.int64)
    parent = np.zeros(kmax, dtype=np.int64)
    path = np.zeros(kmax)
    n_below = np.zeros(kmax)
    cb_path = np.zeros(kmax)
    anc = np.zeros((kmax, kmax), dtype=np.bool_)
    anc[0, 0] = True
    direct = np.full((m, kmax), np.inf)
    split = np.full((m, kmax), np.inf)
    stretch = np.zeros((m, kmax))
    c1 = 1.0 + cb
    new_nodes = np.zeros(2, dtype=np.int64)
    new_edges = np.zeros(3, dtype=np.int64)

    for j in range(m):  # add_node_columns([0], m)
        direct[j, 0] = _direct_entry(row_r[j], row_i[j], pos_r[0], pos_i[0], c1)
    n = 1
    n_steiner = 0
    with_path = cb != 0.0
    for n_free in range(m, 0, -1):
        if with_path:
            for v in range(n):
                cb_path[v] = cb * path[v]
        ia, a_min, ib, b_min = _kernels.greedy_pick(
            direct, split, cb_path, parent, n_free, n, with_path
        )
        use_direct = a_min <= b_min
        pick = ia if use_direct else ib
        j = pick // n
        col = pick - j * n
        k = row_task[j]
        yr = task_r[k]
        yi = task_i[k]
        vertex = -1
        sx = 0.0
        sy = 0.0
        c = col
        u = parent[col]
        if not use_direct:
            sx, sy, vertex = _steiner_kernels._fermat(
                pos_r[u], pos_i[u], pos_r[c], pos_i[c], yr, yi, flag
            )
            if vertex == 0 or vertex == 1:  # rounding put s on u or w after all: a direct edge
                use_direct = True
                col = u if vertex == 0 else c
        if use_direct:
            node = n
            _new_node(yr, yi, 1 + k, col, node, pos_r, pos_i, final_index, parent, path, anc)
            n += 1
            n_new_nodes, n_new_edges = 1, 1
            new_nodes[0] = node
            new_edges[0] = node
        elif vertex == 2:  # s = y: the task itself goes on the edge u -> y -> w
            node = n
            _new_node(yr, yi, 1 + k, u, node, pos_r, pos_i, final_index, parent, path, anc)
            n += 1
            _lift_onto(node, c, n, pos_r, pos_i, parent, path, n_below, anc)
            n_new_nodes, n_new_edges = 1, 2
            new_nodes[0] = node
            new_edges[0] = node
            new_edges[1] = c
        else:
            steiner = n
            _new_node(
                sx, sy, m + 1 + n_steiner, u, steiner, pos_r, pos_i, final_index, parent, path, anc
            )
            n += 1
            n_steiner += 1
            _lift_onto(steiner, c, n, pos_r, pos_i, parent, path, n_below, anc)
            node = n
            _new_node(yr, yi, 1 + k, steiner, node, pos_r, pos_i, final_index, parent, path, anc)
            n += 1
            n_new_nodes, n_new_edges = 2, 3
            new_nodes[0] = steiner
            new_nodes[1] = node
            new_edges[0] = steiner
            new_edges[1] = c
            new_edges[2] = node
        # One more task below each ancestor of the new task (rows >= n_free are retired).
        for a in range(n):
            if anc[node, a]:
                n_below[a] += 1.0
                if with_path:
                    for r in range(n_free):
                        split[r, a] += stretch[r, a]
        # Retire row j: swap it with the last free row.
        last = n_free - 1
        if j != last:
            for col2 in range(kmax):
                direct[j, col2], direct[last, col2] = direct[last, col2], direct[j, col2]
                split[j, col2], split[last, col2] = split[last, col2], split[j, col2]
                stretch[j, col2], stretch[last, col2] = stretch[last, col2], stretch[j, col2]
            row_r[j], row_r[last] = row_r[last], row_r[j]
            row_i[j], row_i[last] = row_i[last], row_i[j]
            row_task[j], row_task[last] = row_task[last], row_task[j]
        if last:
            for q in range(n_new_nodes):
                v = new_nodes[q]
                for r in range(last):
                    direct[r, v] = _direct_entry(row_r[r], row_i[r], pos_r[v], pos_i[v], c1)
            for q in range(n_new_edges):
                w = new_edges[q]
                pu = parent[w]
                for r in range(last):
                    split[r, w], stretch[r, w] = _split_entry(
                        pos_r[pu], pos_i[pu], pos_r[w], pos_i[w], row_r[r], row_i[r], n_below[w], cb
                    )

    nodes_out = np.empty((n, 2))
    parent_out = np.full(n, -1, dtype=np.int64)
    for v in range(n):
        nodes_out[final_index[v], 0] = pos_r[v]
        nodes_out[final_index[v], 1] = pos_i[v]
        if v > 0:
            parent_out[final_index[v]] = final_index[parent[v]]
    return nodes_out, parent_out


# --------------------------------------------------------------------------------------------
# Dispatch and the check against NumPy
# --------------------------------------------------------------------------------------------


class Reference(NamedTuple):
    """The NumPy functions of :mod:`planner.steiner` that the kernel reproduces (passed in, since
    :mod:`planner.steiner` imports this module)."""

    as_complex: Callable[[np.ndarray], np.ndarray]
    direct_costs: Callable[[np.ndarray, np.ndarray, float], np.ndarray]
    split_costs: Callable[
        [np.ndarray, np.ndarray, np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray]
    ]
    fermat_scalar: Callable[[float, float, float, float, float, float], tuple[float, float, int]]


#: Outcome of :func:`matches_numpy` in this process (None: not checked yet).
_MATCHES: bool | None = None


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    return a.shape == b.shape and bool(np.array_equal(a.view(np.int64), b.view(np.int64)))


def _probe_points(rng: np.random.Generator, k: int, kind: int) -> np.ndarray:
    """k complex probe points of one kind: 0 spread over many scales, 1 on a coarse grid (zeros,
    ties, axis-aligned and coincident points), 2 a field like the planners' (+-5 or +-50)."""
    if kind == 0:
        scale = 10.0 ** rng.uniform(-4.0, 5.0, (k, 1))
        xy = rng.normal(0.0, 1.0, (k, 2)) * scale
    elif kind == 1:
        xy = rng.integers(-2, 3, (k, 2)).astype(np.float64)
    else:
        xy = rng.uniform(-1.0, 1.0, (k, 2)) * rng.choice([5.0, 50.0])
    xy[rng.random((k, 2)) < 0.05] = -0.0
    return xy[:, 0] + 1j * xy[:, 1]


def _probe(ref: Reference) -> bool:
    """The compiled element formulas against NumPy on a fixed probe set (see the module doc)."""
    rng = np.random.default_rng(20_240_611)
    # Every (F, n) of a build up to F = 17 (NumPy picks its loop, SIMD or scalar, by the shapes
    # and strides: a one-element broadcast result, say, may take the unfused scalar loop), a few
    # larger ones, several draws where there are few elements (so that a formula difference shows).
    shapes = [(f, n) for f in (*range(1, 18), 31, 64, 150) for n in (1, 2, 3)]
    for kind in (0, 1, 2):
        for f, n in shapes:
            for _ in range(max(1, 12 // (f * n))):
                pos = _probe_points(rng, 8, kind)
                pos[rng.random(8) < 0.2] = pos[0]  # coincident nodes
                y_all = _probe_points(rng, f + 2, kind)
                pick = rng.random(f + 2)
                y_all[pick < 0.1] = pos[1]  # tasks on a node
                mid = 0.5 * (pos[0] + pos[1])
                y_all[(pick >= 0.1) & (pick < 0.2)] = mid  # (nearly) collinear
                y = y_all[:f, None]  # the build's (F, 1) view of its row array
                tops, bottoms = rng.integers(0, 8, n), rng.integers(0, 8, n)
                u, w = pos[tops], pos[bottoms]
                n_below = rng.integers(0, 40, n).astype(np.float64)
                cb = float(rng.choice([0.0, 1.0, 0.5, 2.75]))
                want = ref.split_costs(u, w, y, n_below, cb)
                got = split_costs(u, w, y, n_below, cb)
                if not (_same_bits(want[0], got[0]) and _same_bits(want[1], got[1])):
                    return False
                vs = [int(t) for t in tops[: 1 + n % 2]]
                if not _same_bits(ref.direct_costs(y, pos[vs], cb), direct_costs(y, pos[vs], cb)):
                    return False
    # NumPy's scalar abs (new_node, lift_onto) against the compiled hypot
    a = _probe_points(rng, 600, 0)
    b = np.concatenate([_probe_points(rng, 300, 1), _probe_points(rng, 300, 2)])
    want_h = np.array([abs(p - q) for p, q in zip(a, b)])  # numpy.complex128 scalars
    if not _same_bits(want_h, hypot_array((a - b).real, (a - b).imag)):
        return False
    # _fermat_scalar (Python floats and numpy.float64 mixed, as in the build)
    flag = np.zeros(1, dtype=np.bool_)
    for i in range(0, 600, 3):
        ax, ay, bx, by = a[i].real, a[i].imag, b[i].real, b[i].imag
        cx, cy = float(a[i + 1].real), float(b[i + 2].imag)
        x, y2, vert = ref.fermat_scalar(ax, ay, bx, by, cx, cy)
        gx, gy, gv = _steiner_kernels._fermat(
            float(ax), float(ay), float(bx), float(by), cx, cy, flag
        )
        if vert != gv or not _same_bits(np.array([x, y2]), np.array([gx, gy])):
            return False
    return not flag[0]


def matches_numpy(ref: Reference) -> bool:
    """Whether NumPy on this machine evaluates as the kernel emulates (checked once a process)."""
    global _MATCHES
    if _MATCHES is None:
        _MATCHES = _probe(ref)
        if not _MATCHES:
            _log.warning(
                "the compiled greedy task tree does not reproduce NumPy on this machine "
                "(NumPy %s); the NumPy build runs",
                np.__version__,
            )
    return _MATCHES


def greedy_tree(
    base: np.ndarray, tasks: np.ndarray, cb: float, ref: Reference
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`planner.steiner._greedy_tree_python` compiled: the same ``(nodes_m, parent)`` bits,
    or None when it does not apply (no Numba, switched off, not CPython 3.11, NumPy on this machine
    not as emulated, inputs outside the checked range, a subnormal scalar Fermat side)."""
    if not (_kernels.NUMBA and _kernels.ENABLED and _steiner_kernels.APPLIES):
        return None
    cb = float(cb)
    if not (math.isfinite(cb) and 0.0 <= cb <= MAX_ABS):
        return None
    if not (np.all(np.abs(base) <= MAX_ABS) and np.all(np.abs(tasks) <= MAX_ABS)):
        return None  # also NaN
    if not matches_numpy(ref):
        return None
    task_z = ref.as_complex(tasks)
    flag = np.zeros(1, dtype=np.bool_)
    out = _greedy(
        float(base[0]),
        float(base[1]),
        np.ascontiguousarray(task_z.real),
        np.ascontiguousarray(task_z.imag),
        cb,
        flag,
    )
    return None if flag[0] else out

"""Compiled glue of the message layer (Numba): the steps of :func:`planner.knowledge.propagate_entries`
before the hop (forwarded entries, the links' CSR adjacency, the cost model's counts) and the view
of :meth:`planner.knowledge.Knowledge._set_view`, each in one pass instead of a dozen NumPy calls.

At Table II's sizes a tick of the async planners makes thousands of small NumPy calls; these two
replace ~20 of them per tick (selections, concatenations, bincounts, an argsort, a searchsorted,
a column_stack). DCCRS's believed displacements (a stamp lookup and a difference of two
positions per entry) and its neighbour counts over the entries are here too. The same rules as :mod:`planner._graph_kernels` hold: integer and copy results
only (no arithmetic on floats), so the callers get exactly the NumPy path's arrays; the NumPy
path stays the reference (``_kernels.ENABLED = False``) and ``tests/planner/test_knowledge.py``
compares the two.
"""

from __future__ import annotations

import numpy as np

from planner import _kernels
from planner._graph_kernels import _jit

__all__ = ["hop_inputs", "entry_view", "believed_displacement", "near_counts"]


def _hop_inputs(
    rows: np.ndarray,
    cols: np.ndarray,
    stamps: np.ndarray,
    n_holders: int,
    n_cols: int,
    pairs: np.ndarray,
    cutoff: int,
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int, int, bool
]:
    m = 0
    for e in range(len(stamps)):
        if stamps[e] >= cutoff:
            m += 1
    fr = np.empty(m, dtype=np.int64)
    fc = np.empty(m, dtype=np.int64)
    fs = np.empty(m, dtype=np.int64)
    count = np.zeros(n_holders, dtype=np.int64)
    held = np.zeros(n_cols, dtype=np.bool_)
    q = 0
    s_max = -(2**62)
    ordered = True
    for e in range(len(stamps)):
        if stamps[e] >= cutoff:
            fr[q] = rows[e]
            fc[q] = cols[e]
            fs[q] = stamps[e]
            if q > 0 and fr[q] < fr[q - 1]:
                ordered = False
            count[rows[e]] += 1
            held[cols[e]] = True
            if stamps[e] > s_max:
                s_max = stamps[e]
            q += 1
    n_k = 0
    for k in range(n_cols):
        if held[k]:
            n_k += 1
    # CSR of the links by destination: for holder i, its sources (the other end of each pair
    # and itself). The order within a holder does not matter to the hop (maxima / ORs).
    deg = np.ones(n_holders, dtype=np.int64)  # the self-loop
    for p in range(len(pairs)):
        deg[pairs[p, 0]] += 1
        deg[pairs[p, 1]] += 1
    link_start = np.zeros(n_holders + 1, dtype=np.int64)
    for i in range(n_holders):
        link_start[i + 1] = link_start[i] + deg[i]
    fill = link_start[:-1].copy()
    link_src = np.empty(link_start[n_holders], dtype=np.int64)
    for i in range(n_holders):
        link_src[fill[i]] = i
        fill[i] += 1
    for p in range(len(pairs)):
        a = pairs[p, 0]
        b = pairs[p, 1]
        link_src[fill[a]] = b
        fill[a] += 1
        link_src[fill[b]] = a
        fill[b] += 1
    # the per-entry maximum's work: one (link, entry) pair per entry of every link's source
    work = 0
    for i in range(n_holders):
        work += count[i] * deg[i]
    entry_start = np.zeros(n_holders + 1, dtype=np.int64)
    for i in range(n_holders):
        entry_start[i + 1] = entry_start[i] + count[i]
    return fr, fc, fs, entry_start, link_start, link_src, work, n_k, s_max, ordered


_hop_inputs_jit = _jit(_hop_inputs)


def hop_inputs(
    rows: np.ndarray,
    cols: np.ndarray,
    stamps: np.ndarray,
    n_holders: int,
    n_cols: int,
    pairs: np.ndarray,
    cutoff: int,
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int, int, bool
]:
    """The forwarded entries (stamp >= ``cutoff``, in their order), their CSR offsets by holder,
    the links' CSR adjacency by destination (self-loops included), the per-entry maximum's work
    (sum over holders of entries x (degree + 1)), the number of held columns, the largest stamp
    and whether the entries' holders are ascending. Integers only (exactly NumPy's)."""
    fr, fc, fs, entry_start, link_start, link_src, work, n_k, s_max, ordered = _hop_inputs_jit(
        np.asarray(rows, np.int64),
        np.asarray(cols, np.int64),
        np.asarray(stamps, np.int64),
        int(n_holders),
        int(n_cols),
        np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2),
        int(cutoff),
    )
    return (
        fr,
        fc,
        fs,
        entry_start,
        link_start,
        link_src,
        int(work),
        int(n_k),
        int(s_max),
        bool(ordered),
    )


def _entry_view(
    alive: np.ndarray,
    col_held: np.ndarray,
    r: np.ndarray,
    c: np.ndarray,
    bx: np.ndarray,
    by: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    n_rows = 0
    row_of = np.empty(len(alive), dtype=np.int64)
    for i in range(len(alive)):
        if alive[i]:
            n_rows += 1
        row_of[i] = n_rows - 1
    n_cols = 0
    col_of = np.empty(len(col_held), dtype=np.int64)
    for k in range(len(col_held)):
        if col_held[k]:
            n_cols += 1
        col_of[k] = n_cols - 1
    view_rows = np.empty(n_rows, dtype=np.int64)
    q = 0
    for i in range(len(alive)):
        if alive[i]:
            view_rows[q] = i
            q += 1
    view_cols = np.empty(n_cols, dtype=np.int64)
    q = 0
    for k in range(len(col_held)):
        if col_held[k]:
            view_cols[q] = k
            q += 1
    m = 0
    for e in range(len(r)):
        if r[e] != c[e]:
            m += 1
    er = np.empty(m, dtype=np.int64)
    ec = np.empty(m, dtype=np.int64)
    believed = np.empty((m, 2))
    q = 0
    for e in range(len(r)):
        if r[e] != c[e]:
            er[q] = row_of[r[e]]
            ec[q] = col_of[c[e]]
            believed[q, 0] = bx[e]
            believed[q, 1] = by[e]
            q += 1
    return view_rows, view_cols, er, ec, believed


_entry_view_jit = _jit(_entry_view)


def entry_view(
    alive: np.ndarray,
    col_held: np.ndarray,
    r: np.ndarray,
    c: np.ndarray,
    bx: np.ndarray,
    by: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """:meth:`planner.knowledge.Knowledge._set_view` in one pass: the view's rows (alive holders)
    and columns (held drones), each non-self entry's view row and column and its believed position
    (E, 2). Copies and integer counts only, so the NumPy version's arrays exactly. None without
    Numba."""
    if not (_kernels.NUMBA and _kernels.ENABLED):
        return None
    return _entry_view_jit(
        np.asarray(alive, np.bool_),
        np.asarray(col_held, np.bool_),
        np.asarray(r, np.int64),
        np.asarray(c, np.int64),
        np.asarray(bx, np.float64),
        np.asarray(by, np.float64),
    )


def _believed_displacement(
    held_rows: np.ndarray,
    held_cols: np.ndarray,
    held_stamps: np.ndarray,
    n: int,
    holders: np.ndarray,
    col_ids: np.ndarray,
    pos_hist: np.ndarray,
) -> np.ndarray:
    out = np.empty((len(holders), 2))
    m = len(held_rows)
    for e in range(len(holders)):
        want = holders[e] * n + col_ids[e]
        lo = 0
        hi = m
        while lo < hi:  # the first entry whose key is >= want (row-major keys are sorted)
            mid = (lo + hi) >> 1
            if held_rows[mid] * n + held_cols[mid] < want:
                lo = mid + 1
            else:
                hi = mid
        s = -1
        if lo < m and held_rows[lo] * n + held_cols[lo] == want:
            s = held_stamps[lo]
        k = col_ids[e]
        if s >= 1:
            out[e, 0] = pos_hist[s, k, 0] - pos_hist[s - 1, k, 0]
            out[e, 1] = pos_hist[s, k, 1] - pos_hist[s - 1, k, 1]
        else:
            out[e, 0] = 0.0
            out[e, 1] = 0.0
    return out


_believed_displacement_jit = _jit(_believed_displacement)


def believed_displacement(
    held_rows: np.ndarray,
    held_cols: np.ndarray,
    held_stamps: np.ndarray,
    n_drones: int,
    holders: np.ndarray,
    col_ids: np.ndarray,
    pos_hist_m: np.ndarray,
) -> np.ndarray | None:
    """(E, 2): pos_hist[s, k] - pos_hist[s - 1, k] for the stamp s that holder ``holders[e]``
    holds of drone ``col_ids[e]`` (0 where s < 1 or unknown), the stamp found by binary search in
    the row-major entries (:meth:`planner.knowledge.StampTable.lookup`) and the difference taken per
    coordinate as NumPy does (one subtraction: the same bits). Ids must be in range. None without
    Numba (:meth:`planner.info.MessagePassingView.believed_displacement_u` is the reference)."""
    if not (_kernels.NUMBA and _kernels.ENABLED):
        return None
    return _believed_displacement_jit(
        np.asarray(held_rows, np.int64),
        np.asarray(held_cols, np.int64),
        np.asarray(held_stamps, np.int64),
        int(n_drones),
        np.asarray(holders, np.int64),
        np.asarray(col_ids, np.int64),
        np.asarray(pos_hist_m, np.float64),
    )


def _near_counts(
    ax: np.ndarray,
    ay: np.ndarray,
    bx: np.ndarray,
    by: np.ndarray,
    er: np.ndarray,
    holder_first: bool,
    r2: float,
    n: int,
) -> tuple[np.ndarray, np.ndarray]:
    near = np.empty(len(er), dtype=np.bool_)
    count = np.zeros(n, dtype=np.int64)
    for e in range(len(er)):
        i = er[e]
        if holder_first:
            dx = ax[i] - bx[e]
            dy = ay[i] - by[e]
        else:
            dx = bx[e] - ax[i]
            dy = by[e] - ay[i]
        d2 = dx * dx
        d2 += dy * dy
        near[e] = d2 <= r2
        if near[e]:
            count[i] += 1
    return near, count


_near_counts_jit = _jit(_near_counts)


def near_counts(
    holder_u: np.ndarray, y_e: np.ndarray, er: np.ndarray, holder_first: bool, r2: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Per entry e whether |d|^2 <= r2 with d = holder_u[er[e]] - y_e[e] (``holder_first``) or
    y_e[e] - holder_u[er[e]], and per holder (len(holder_u),) how many entries are: DCCRS's
    ``np.einsum("ec,ec->e", d, d) <= r2`` and ``np.bincount(er[near])`` (einsum over two components
    sums x^2 then y^2 from zero, the same bits; tests/planner/test_kernels.py). None without Numba."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or holder_u.ndim != 2 or holder_u.shape[1] != 2:
        return None
    return _near_counts_jit(
        np.ascontiguousarray(holder_u[:, 0], dtype=np.float64),
        np.ascontiguousarray(holder_u[:, 1], dtype=np.float64),
        np.ascontiguousarray(y_e[:, 0], dtype=np.float64),
        np.ascontiguousarray(y_e[:, 1], dtype=np.float64),
        np.asarray(er, np.int64),
        bool(holder_first),
        float(r2),
        len(holder_u),
    )

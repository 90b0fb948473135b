"""Compiled glue of the message layer (Numba): the steps of :func:`planner.knowledge.propagate_entries`
before the hop (forwarded entries, the links' CSR adjacency, the cost model's counts) and the view
of :meth:`planner.knowledge.Knowledge._set_view`, each in one pass instead of a dozen NumPy calls;
and :func:`knowledge_step`, the whole entry update of a tick (own entries, the hop, the age and
distance cut-offs, the view) in one pass, which the message layer runs when it can (the separate
kernels and NumPy steps are its fallback and its reference).

At Table II's sizes a tick of the async planners makes thousands of small NumPy calls; these
replace ~20 of them per tick (selections, concatenations, bincounts, an argsort, a searchsorted,
a column_stack). DCCRS's believed displacements (a stamp lookup and a difference of two
positions per entry) and its neighbour counts over the entries are here too. The same rules as
:mod:`planner._graph_kernels` hold: integer and copy results, and the little float arithmetic
there is (the distance cut-off, the displacements, the neighbour test) in NumPy's operation order
without ``fastmath``, so the callers get exactly the NumPy path's arrays; the NumPy path stays the
reference (``_kernels.ENABLED = False``) and ``tests/planner/test_knowledge.py`` and
``tests/planner/test_kernels.py`` compare the two.
"""

from __future__ import annotations

import numpy as np

from planner import _kernels
from planner._graph_kernels import _jit

__all__ = [
    "hop_inputs",
    "entry_view",
    "knowledge_scratch",
    "knowledge_step",
    "believed_displacement",
    "near_counts",
    "velocity_match_near",
    "flood_tree_stamp",
]


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


def _step_displacement(pos_hist: np.ndarray, s: int, k: int) -> tuple[float, float]:
    """Drone k's displacement over step s (position at s minus at s - 1); (0, 0) for s < 1 (no
    earlier position, or no entry: s = -1)."""
    if s >= 1:
        return pos_hist[s, k, 0] - pos_hist[s - 1, k, 0], pos_hist[s, k, 1] - pos_hist[s - 1, k, 1]
    return 0.0, 0.0


if _kernels.NUMBA:
    from numba import njit as _njit

    _step_displacement = _njit(cache=True, inline="always")(_step_displacement)


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
    base = 0
    prev = -1
    for e in range(len(holders)):
        want = holders[e] * n + col_ids[e]
        if want < prev:  # the queries usually come in row-major order: search on from the last one
            base = 0
        prev = want
        # the first entry whose key is >= want (row-major keys are sorted): gallop from base, then
        # bisect (the same index as a bisection of the whole list)
        lo = base
        hi = base
        step = 1
        while hi < m and held_rows[hi] * n + held_cols[hi] < want:
            lo = hi + 1
            hi = lo + step
            step *= 2
        hi = min(hi, m)
        while lo < hi:
            mid = (lo + hi) >> 1
            if held_rows[mid] * n + held_cols[mid] < want:
                lo = mid + 1
            else:
                hi = mid
        base = lo
        s = -1
        if lo < m and held_rows[lo] * n + held_cols[lo] == want:
            s = held_stamps[lo]
        out[e, 0], out[e, 1] = _step_displacement(pos_hist, s, col_ids[e])
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
    a: np.ndarray,
    b: np.ndarray,
    er: np.ndarray,
    holder_first: bool,
    r2: float,
) -> tuple[np.ndarray, np.ndarray]:
    near = np.empty(len(er), dtype=np.bool_)
    count = np.zeros(len(a), dtype=np.int64)
    for e in range(len(er)):
        i = er[e]
        if holder_first:
            dx = a[i, 0] - b[e, 0]
            dy = a[i, 1] - b[e, 1]
        else:
            dx = b[e, 0] - a[i, 0]
            dy = b[e, 1] - a[i, 1]
        d2 = dx * dx
        d2 += dy * dy
        near[e] = d2 <= r2
        count[i] += int(d2 <= r2)  # no branch on an unpredictable test
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
        np.asarray(holder_u, dtype=np.float64),  # (n, 2) and (E, 2), any strides: read in place
        np.asarray(y_e, dtype=np.float64),
        np.asarray(er, np.int64),
        bool(holder_first),
        float(r2),
    )


def _velocity_match_near(
    disp_pot: np.ndarray,
    er: np.ndarray,
    near: np.ndarray,
    stamps: np.ndarray,
    view_cols: np.ndarray,
    ec: np.ndarray,
    pos_hist: np.ndarray,
    alpha: float,
    vmax: float,
) -> np.ndarray:
    n = len(disp_pot)
    count = np.zeros(n, dtype=np.int64)
    tx = np.zeros(n)
    ty = np.zeros(n)
    for e in range(len(er)):  # bincount's order: entry by entry
        if near[e]:
            i = er[e]
            s = stamps[e]
            dx, dy = _step_displacement(pos_hist, s, view_cols[ec[e]])
            count[i] += 1
            tx[i] += dx
            ty[i] += dy
    out = np.empty((n, 2))
    for i in range(n):
        ox = disp_pot[i, 0]
        oy = disp_pot[i, 1]
        if count[i] > 0:
            c = float(count[i])
            ox = (1.0 - alpha) * ox + alpha * (tx[i] / c)
            oy = (1.0 - alpha) * oy + alpha * (ty[i] / c)
        norm2 = ox * ox
        norm2 += oy * oy
        norm = np.sqrt(norm2)
        f = vmax / (norm if norm > 0 else 1.0)
        if not f != f:  # np.minimum(1.0, f): NaN stays NaN
            f = min(1.0, f)
        out[i, 0] = ox * f
        out[i, 1] = oy * f
    return out


_velocity_match_near_jit = _jit(_velocity_match_near)


def velocity_match_near(
    disp_pot_u: np.ndarray,
    er: np.ndarray,
    near_e: np.ndarray,
    stamps_e: np.ndarray,
    view_cols: np.ndarray,
    ec: np.ndarray,
    pos_hist_u: np.ndarray,
    alpha: float,
    vmax: float,
) -> np.ndarray | None:
    """DCCRS's velocity matching over the view's entries in one pass:
    :func:`planner.dccrs.velocity_match_entries` of the ``near_e`` (E,) bool entries (holder rows
    ``er``), each with the displacement pos_hist[s, k] - pos_hist[s - 1, k] (0 if s < 1) of its drone
    k = ``view_cols[ec[e]]`` at its stamp s = ``stamps_e[e]`` (what
    :meth:`planner.info.MessageView.believed_displacement_u` looks up), summed per holder in entry
    order as bincount does, then the same mean, blend and clip, element by element in NumPy's
    order (tests/planner/test_dccrs.py compares the two). None without Numba."""
    if not (_kernels.NUMBA and _kernels.ENABLED):
        return None
    return _velocity_match_near_jit(
        np.asarray(disp_pot_u, np.float64),
        np.asarray(er, np.int64),
        np.asarray(near_e, np.bool_),
        np.asarray(stamps_e, np.int64),
        np.asarray(view_cols, np.int64),
        np.asarray(ec, np.int64),
        np.asarray(pos_hist_u, np.float64),
        float(alpha),
        float(vmax),
    )


def _flood_tree_stamp(
    tree_stamp: np.ndarray,
    idx: np.ndarray,
    pairs: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    base_x: float,
    base_y: float,
    base_reach: float,
    t_step: int,
) -> bool:
    n = len(idx)
    ts = np.empty(n, dtype=np.int64)
    for j in range(n):
        if not 0 <= idx[j] < len(tree_stamp):
            return False
        ts[j] = tree_stamp[idx[j]]
    best = ts.copy()
    for p in range(len(pairs)):
        a = pairs[p, 0]
        b = pairs[p, 1]
        if not (0 <= a < n and 0 <= b < n):
            return False  # nothing written yet
        best[a] = max(best[a], ts[b])
        best[b] = max(best[b], ts[a])
    for j in range(n):
        dx = x[j] - base_x
        dy = y[j] - base_y
        if np.sqrt(dx * dx + dy * dy) <= base_reach:
            best[j] = t_step - 1
        tree_stamp[idx[j]] = best[j]
    return True


_flood_tree_stamp_jit = _jit(_flood_tree_stamp)


def flood_tree_stamp(
    tree_stamp: np.ndarray,
    idx: np.ndarray,
    pairs: np.ndarray,
    link_pos: np.ndarray,
    base: np.ndarray,
    base_reach: float,
    t_step: int,
) -> bool:
    """:func:`planner.knowledge._flood_tree_stamp` in one compiled pass (in place on
    ``tree_stamp``, int64): maxima over the links in integers, the base test as
    ``np.linalg.norm`` takes it (sqrt of x^2 + y^2, then <=), so the same stamps
    (tests/planner/test_knowledge.py). False (nothing done) without Numba, for arrays it does not
    take or for an index out of range."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or tree_stamp.dtype != np.int64:
        return False
    link_pos = np.asarray(link_pos, np.float64)
    base = np.asarray(base, np.float64)
    if link_pos.shape != (len(idx), 2) or base.shape != (2,):
        return False
    return _flood_tree_stamp_jit(
        tree_stamp,
        np.asarray(idx, np.int64),
        np.asarray(pairs, np.int64).reshape(-1, 2),
        link_pos[:, 0],
        link_pos[:, 1],
        float(base[0]),
        float(base[1]),
        float(base_reach),
        int(t_step),
    )


#: De Bruijn multiplier and table: the index of a word's lowest set bit ``low`` (a power of two) is
#: ``_LOW_BIT[(low * _DE_BRUIJN) >> 58]`` (mod 2^64), so the hop reads only the set bits of a word.
_DE_BRUIJN = 0x03F79D71B4CB0A89
_LOW_BIT = np.zeros(64, dtype=np.int64)
for _b in range(64):
    _LOW_BIT[((_DE_BRUIJN << _b) % 2**64) >> 58] = _b
del _b


def _room(a: np.ndarray, need: int) -> np.ndarray:
    """``a`` if it holds ``need`` items and is not far larger (scratch reused tick to tick), else a
    new int32 array with some slack. Its contents are not kept."""
    if need <= len(a) <= 4 * need + 4096:
        return a
    return np.empty(need + need // 4 + 64, dtype=np.int32)


_room_jit = _jit(_room)


def _knowledge_step(
    r: np.ndarray,
    c: np.ndarray,
    s: np.ndarray,
    alive: np.ndarray,
    own_first: bool,
    hop: bool,
    idx: np.ndarray,
    pairs: np.ndarray,
    cutoff: int,
    t_sent: int,
    max_level: int,
    max_per_bit_word: float,
    t_step: int,
    age_cut: int,
    hist: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    far2: float,
    radio2: float,
    forget: bool,
    low_bit: np.ndarray,
    scratch: tuple[np.ndarray, ...],
) -> tuple[bool, tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    n = len(alive)
    m_in = len(r)
    fc, fs, sets, kept_k, kept_s = scratch
    empty = np.empty(0, dtype=np.int64)
    fail = (empty, empty, empty, empty, empty, empty, empty, np.empty((2, 0)).T, empty)
    # 1. the forwarded entries (own entries first if ``own_first``), CSR by holder. Branch-free
    # (the filters are unpredictable): every entry is written, the count advances if it is kept; an
    # entry after the holder's own column goes one slot further, the own entry fills the gap.
    lo = cutoff if hop else -(2**62)
    fc = _room_jit(fc, m_in + n + 1)
    fs = _room_jit(fs, m_in + n + 1)
    start = np.zeros(n + 1, dtype=np.int64)
    q = 0
    e = 0
    bad = False  # the entries must be row-major, one per (row, col), ids in range
    for i in range(n):
        e0 = e
        while e < m_in and r[e] == i:
            e += 1
        prev = -1
        for f in range(e0, e):
            bad |= (c[f] <= prev) | (c[f] >= n)
            prev = c[f]
        if not own_first:
            for f in range(e0, e):
                fc[q] = c[f]
                fs[q] = s[f]
                q += int(s[f] >= lo)
        elif alive[i]:
            q0 = q
            below = 0  # kept entries left of the own column
            for f in range(e0, e):
                k = c[f]
                gt = int(k > i)
                fc[q + gt] = k
                fs[q + gt] = s[f]
                keep = int(s[f] >= lo) & int(k != i)
                q += keep
                below += keep & int(k < i)
            fc[q0 + below] = i
            fs[q0 + below] = t_step
            q += 1
        start[i + 1] = q
    if bad or e < m_in:
        return False, fail, scratch
    held = np.zeros(n, dtype=np.bool_)
    s_max = -(2**62)
    for f in range(q):
        held[fc[f]] = True
        s_max = max(s_max, fs[f])
    if hop and q > 0 and s_max > t_sent:
        return False, fail, scratch
    # 2. the links' CSR adjacency by destination (self-loops included) and the hop's cost model
    deg = np.ones(n, dtype=np.int64)
    for p in range(len(pairs)):
        deg[idx[pairs[p, 0]]] += 1
        deg[idx[pairs[p, 1]]] += 1
    link_start = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        link_start[i + 1] = link_start[i] + deg[i]
    fill = link_start[:-1].copy()
    link_src = np.empty(link_start[n], dtype=np.int64)
    for i in range(n):
        link_src[fill[i]] = i
        fill[i] += 1
    for p in range(len(pairs)):
        a = idx[pairs[p, 0]]
        b = idx[pairs[p, 1]]
        link_src[fill[a]] = b
        fill[a] += 1
        link_src[fill[b]] = a
        fill[b] += 1
    work = 0
    for i in range(n):
        work += (start[i + 1] - start[i]) * deg[i]
    col_of = np.full(n, -1, dtype=np.int64)
    n_k = 0
    for k in range(n):
        if held[k]:
            col_of[k] = n_k
            n_k += 1
    col_ids = np.empty(n_k, dtype=np.int64)
    for k in range(n):
        if held[k]:
            col_ids[col_of[k]] = k
    levels = max_level + 1
    words = (n_k + 63) // 64
    block = levels * words
    # 0: no hop (each holder keeps its forwarded entries), 1: per-entry maximum, 2: bit sets
    mode = 0
    if hop and q > 0 and len(pairs) > 0:
        bit_cost = levels * words * (link_start[n] + n) / max_per_bit_word
        mode = 1 if work < bit_cost else 2
    one = np.uint64(1)
    if mode == 2:
        # sets[i * block + L * words + w]: the columns holder i forwards with age <= L, one bit each:
        # each entry's bit at its own age, then OR-ed into the older levels
        if not (n * block <= len(sets) <= 4 * n * block + 4096):
            sets = np.empty(n * block + 64, dtype=np.uint64)
        sets[: n * block] = 0
        for i in range(n):
            for f in range(start[i], start[i + 1]):
                kk = col_of[fc[f]]
                sets[i * block + (t_sent - fs[f]) * words + (kk >> 6)] |= one << np.uint64(kk & 63)
            for w in range(i * block + words, (i + 1) * block):
                sets[w] |= sets[w - words]
    acc = np.zeros(block, dtype=np.uint64)
    best = np.full(n if mode == 1 else 0, -1, dtype=np.int64)
    row_k = np.empty(n + 1, dtype=np.int64)  # holder i's entries after the hop, columns ascending
    row_s = np.empty(n + 1, dtype=np.int64)
    cand_k = np.empty(n + 2, dtype=np.int64)  # its own entry and the entries past the age cut
    cand_s = np.empty(n + 2, dtype=np.int64)
    # 3. holder by holder: the hop, own entry, age cut, distance cut; the kept entries' columns and
    # stamps (int32: the scratch is what this pass's memory traffic is made of), counts per holder
    kept_k = _room_jit(kept_k, 2 * q + n + 16)
    kept_s = _room_jit(kept_s, len(kept_k))
    cap = min(len(kept_k), len(kept_s))
    kept_start = np.zeros(n + 1, dtype=np.int64)
    col_held = np.zeros(n, dtype=np.bool_)
    m = 0
    v = 0
    row_i = -1
    top = (levels - 1) * words
    db = np.uint64(_DE_BRUIJN)
    for i in range(n):
        kept_start[i + 1] = m
        if not alive[i]:
            continue
        row_i += 1
        nt = 0
        if mode == 0:
            for f in range(start[i], start[i + 1]):
                row_k[nt] = fc[f]
                row_s[nt] = fs[f]
                nt += 1
        elif mode == 1:
            for li in range(link_start[i], link_start[i + 1]):
                j = link_src[li]
                for f in range(start[j], start[j + 1]):
                    k = fc[f]
                    if best[k] < 0:
                        row_k[nt] = k
                        nt += 1
                    if fs[f] > best[k]:
                        best[k] = fs[f]
            row_k[:nt].sort()
            for f in range(nt):
                row_s[f] = best[row_k[f]]
                best[row_k[f]] = -1
        else:
            j = link_src[link_start[i]] * block
            for w in range(block):
                acc[w] = sets[j + w]
            for li in range(link_start[i] + 1, link_start[i + 1]):
                j = link_src[li] * block
                for w in range(block):
                    acc[w] |= sets[j + w]
        # own entry (in column order) and age cut, branch-free as in 1.
        nc = 0
        below = 0
        if mode == 2:  # the set bits straight into the candidates
            for w in range(words):
                x = acc[top + w]
                while x:
                    rest = x & (x - one)
                    low = x ^ rest
                    x = rest
                    age = 0  # the levels below the first that holds the column (nested sets)
                    for level in range(levels - 1):
                        age += int((acc[level * words + w] & low) == 0)
                    k = col_ids[w * 64 + low_bit[(low * db) >> np.uint64(58)]]
                    gt = int(k > i)
                    cand_k[nc + gt] = k
                    cand_s[nc + gt] = t_sent - age
                    keep = int(t_sent - age >= age_cut) & int(k != i)
                    nc += keep
                    below += keep & int(k < i)
        for f in range(nt):
            k = row_k[f]
            gt = int(k > i)
            cand_k[nc + gt] = k
            cand_s[nc + gt] = row_s[f]
            keep = int(row_s[f] >= age_cut) & int(k != i)
            nc += keep
            below += keep & int(k < i)
        cand_k[below] = i
        cand_s[below] = t_step
        nc += 1
        if m + nc > cap:
            while m + nc > cap:
                cap *= 2
            kept_k = np.concatenate((kept_k[:m], np.empty(cap - m, dtype=np.int32)))
            kept_s = np.concatenate((kept_s[:m], np.empty(cap - m, dtype=np.int32)))
        pxi = px[i]
        pyi = py[i]
        for f in range(nc):  # written unconditionally, kept by advancing the counts
            k = cand_k[f]
            st = cand_s[f]
            col_held[k] = True
            x_m = hist[st, k, 0]
            y_m = hist[st, k, 1]
            dx = x_m - pxi
            dy = y_m - pyi
            d2 = dx * dx
            d2 += dy * dy
            far = (d2 > far2) | (forget & (d2 <= radio2) & (st < t_sent))
            keep = 1 - int(far)
            kept_k[m] = k
            kept_s[m] = st
            m += keep
            v += keep & int(k != i)
        kept_start[i + 1] = m
    # 4. the view (alive holders, columns somebody holds) and the outputs, each written once
    view_rows = np.empty(row_i + 1, dtype=np.int64)
    q = 0
    for i in range(n):
        if alive[i]:
            view_rows[q] = i
            q += 1
    n_view = 0
    for k in range(n):
        if col_held[k]:
            col_of[k] = n_view
            n_view += 1
    view_cols = np.empty(n_view, dtype=np.int64)
    for k in range(n):
        if col_held[k]:
            view_cols[col_of[k]] = k
    rr = np.empty(m, dtype=np.int64)
    cc = np.empty(m, dtype=np.int64)
    ss = np.empty(m, dtype=np.int64)
    er = np.empty(v, dtype=np.int64)
    ec = np.empty(v, dtype=np.int64)
    es = np.empty(v, dtype=np.int64)
    bel = np.empty((2, v))  # returned as its (v, 2) transpose: each coordinate contiguous
    f = 0
    v = 0
    for row in range(len(view_rows)):
        i = view_rows[row]
        for f in range(kept_start[i], kept_start[i + 1]):
            k = int(kept_k[f])
            st = int(kept_s[f])
            rr[f] = i
            cc[f] = k
            ss[f] = st
            if k != i:
                er[v] = row
                ec[v] = col_of[k]
                es[v] = st
                bel[0, v] = hist[st, k, 0]
                bel[1, v] = hist[st, k, 1]
                v += 1
    return (
        True,
        (rr, cc, ss, view_rows, view_cols, er, ec, bel.T, es),
        (fc, fs, sets, kept_k, kept_s),
    )


_knowledge_step_jit = _jit(_knowledge_step)


def knowledge_scratch() -> tuple[np.ndarray, ...]:
    """Empty scratch arrays for :func:`knowledge_step` (it grows them and hands them back)."""
    e = np.empty(0, dtype=np.int32)
    return (e, e, np.empty(0, dtype=np.uint64), e, e)


def knowledge_step(
    rows: np.ndarray,
    cols: np.ndarray,
    stamps: np.ndarray,
    alive: np.ndarray,
    own_first: bool,
    hop: bool,
    idx: np.ndarray,
    pairs: np.ndarray,
    t_sent: int,
    max_level: int,
    max_per_bit_word: float,
    t_step: int,
    pos_hist_m: np.ndarray,
    pos_m: np.ndarray,
    dist_max_m: float,
    radio_range_m: float,
    forget: bool,
    scratch: tuple[np.ndarray, ...],
) -> tuple[tuple[np.ndarray, ...] | None, tuple[np.ndarray, ...]]:
    """The entries' part of :meth:`planner.knowledge.Knowledge.update` in one compiled pass: own
    entries (first if ``own_first``, the broadcast after the move), the hop of
    :func:`planner.knowledge.propagate_entries` (if ``hop``; links ``idx[pairs]``; the same cost
    model picks the per-entry maximum or the bit sets, here with the bits read through a de Bruijn
    table), then per holder what :func:`planner._kernels.finish_knowledge_update` and
    :func:`entry_view` do (own entry, age cut ``t_step - max_level``, distance cut, the view),
    without their (E,) intermediate arrays.

    Returns ``(result, scratch)``: result = (held rows, cols, stamps, view rows, view cols, entry
    rows, entry cols, believed (E, 2) in column-major order (each coordinate contiguous, what the
    descents read), entry stamps), integers and copies only, so exactly the arrays of the
    unfused path; None without Numba, or when the entries are not row-major or the hop's inputs are
    outside its range (the caller then runs the unfused path). ``scratch``
    (:func:`knowledge_scratch` at first) is reused from call to call: fresh arrays of a few MB per
    tick cost more in page faults than the pass itself (~1.7 us per 4 kB page measured here)."""
    if not (_kernels.NUMBA and _kernels.ENABLED) or not pos_hist_m.flags.c_contiguous:
        return None, scratch
    n = len(alive)
    if pos_hist_m.shape[1:] != (n, 2) or not 0 <= t_step < min(len(pos_hist_m), 2**31 - 1):
        return None, scratch  # positions out of the history's range; stamps kept as int32 inside
    pos_m = np.asarray(pos_m, np.float64)
    ok, res, scratch = _knowledge_step_jit(
        np.asarray(rows, np.int64),
        np.asarray(cols, np.int64),
        np.asarray(stamps, np.int64),
        np.asarray(alive, np.bool_),
        bool(own_first),
        bool(hop),
        np.asarray(idx, np.int64),
        np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2),
        max(int(t_sent) - int(max_level), 0),
        int(t_sent),
        int(max_level),
        float(max_per_bit_word),
        int(t_step),
        int(t_step) - int(max_level),
        pos_hist_m,
        np.ascontiguousarray(pos_m[:, 0]),
        np.ascontiguousarray(pos_m[:, 1]),
        dist_max_m * dist_max_m,
        radio_range_m * radio_range_m,
        bool(forget),
        _LOW_BIT,
        scratch,
    )
    return (res if ok else None), scratch

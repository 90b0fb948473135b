"""Asynchronous message passing: what each drone knows (docs/design/model.md §5.4, docs/design/architecture.md §3.2).

Each drone broadcasts its table to its radio neighbours; they receive it at the next step. For
every drone id a table keeps the most recent report (recency rule), and drops entries older than
``age_max_steps`` or farther than ``dist_max_m`` from the holder. The base-computed task tree is
flooded with the same rule.

Representation: a report about drone k made at step s always carries k's true position at s, so a
table entry is fully described by its *stamp* s. Beliefs are therefore a list of entries (holder i,
drone k, stamp s), read as an (N, N) table of stamps (-1 = unknown) through :class:`StampTable`
without any (N, N) array (memory O(N * neighbours)), and believed
positions are gathered from the history of true positions: ``pos_hist[stamp[i, k], k]``. This is
exact and keeps the state small; each step costs time in proportion to the entries and links (each
drone holds a few dozen entries once the swarm spreads), not N^2. :class:`KnowledgeDense` and
:func:`propagate_stamps_dense` are the previous dense-table implementation, kept for tests.

Size: ~1,000 lines, above the ~600 guideline, because the message layer, its NumPy paths (the
references of the compiled kernels in :mod:`planner._kernels`, :mod:`planner._graph_kernels` and
:mod:`planner._message_kernels`) and its two test references (the dense tables,
:class:`KnowledgeDense` and :func:`propagate_stamps_dense`) belong together: the references are
only meaningful next to the code they check.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Self

import numpy as np
from scipy.sparse import csr_matrix

from planner import _graph_kernels, _kernels, _message_kernels
from planner.geometry import neighbour_pairs, radio_pairs, step_toward

__all__ = [
    "Knowledge",
    "KnowledgeDense",
    "MessageLayer",
    "StampTable",
    "propagate_entries",
    "propagate_stamps",
    "propagate_stamps_dense",
    "propagate_stamps_reference",
    "UNKNOWN",
]

UNKNOWN = -1

#: Up to this many age levels (age_max_steps + 1) the one-hop maximum is taken on bit sets, one
#: OR-reduction over the links per level.
_BITSET_MAX_LEVELS = 16

#: Below this fraction of known entries (among holders x held columns) the one-hop product is
#: sparse x sparse (cost ~ links x entries per holder); above it, sparse x dense (the dense phase
#: right after take-off, when everybody hears everybody, is cheaper that way).
_SPARSE_ENTRY_FRACTION = 0.25

#: Cost of the per-entry maximum (:func:`planner._kernels.propagate_max`, one random access per
#: (link, entry)) against the compiled bit sets (:func:`planner._graph_kernels.hop_bitsets`, one
#: OR per (link, level, 64 columns)), per unit of work; measured at 500 and 2,000 drones.
_MAX_PER_BIT_WORD = 2.0

#: Above this many holders the bit sets are OR-ed by the compiled kernel (below it, NumPy's). The
#: kernel sizes its output per holder and reads the bits word by word; measured on the captured
#: one-hop calls of M / 1 %, L / 0 % and XL / 0 % runs it is 2-5x faster than NumPy's gather, and at
#: 2,000 packed drones ~10x (the gather holds ~370 MB per level there). The result is the same set of
#: entries in the same order whichever path runs (integer maxima), so this is a speed choice only.
_COMPILED_BITSET_MIN_HOLDERS = 0

#: Above this many holders the one-hop product uses a sparse adjacency matrix (below it the dense
#: product is cheaper than scipy's per-call overhead).
_SPARSE_MIN_HOLDERS = 256


def _select(mask: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """``a[mask]`` for each array (the arrays themselves when the mask keeps everything)."""
    if mask.all():
        return arrays
    take = np.flatnonzero(mask)
    return tuple(a[take] for a in arrays)


def propagate_entries(
    rows: np.ndarray,
    cols: np.ndarray,
    stamps: np.ndarray,
    n_holders: int,
    n_cols: int,
    pairs: np.ndarray,
    t_sent: int,
    age_max_steps: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One hop of the recency rule on an entry list: what every holder holds after hearing its
    neighbours, from the entries that are still forwarded.

    Parameters
    ----------
    rows, cols, stamps : (E,) int, the valid entries (holder, drone, stamp), at most one per (row, col)
    n_holders, n_cols : shape of the table the entries live in
    pairs : (P, 2) int, undirected links (i, j) among the holders (row ids)
    t_sent : step at which the tables were sent (every stamp is <= t_sent)
    age_max_steps : A; only entries with stamp >= max(t_sent - A, 0) are forwarded (or kept)

    Returns
    -------
    rows, cols, stamps : (E',) the entries new[i, k] = max_{j in {i} U N(i)} sent[j, k] over the
    forwarded entries ``sent``, in row-major order. Entries that are not forwarded are dropped from
    their own holder too (the caller's age cut-off removes them anyway).

    Notes
    -----
    With few age levels (the planners' ``age_max_steps`` is 3) the maximum is taken on bit sets
    (:func:`_propagate_bitsets`). Otherwise, the max-plus product of
    :func:`propagate_stamps_dense` (exponent encoding: an entry of age a is
    sent as 2^(b (A - a)) with 2^b > n_holders >= degree + 1), with the adjacency given self-loops
    (the holder's own entries). Once the swarm has spread it is a sparse x sparse product (the
    entry matrix): the work is the number of (link, entry) pairs, not links x columns; while the
    tables are mostly full (below ``_SPARSE_ENTRY_FRACTION`` empty) the entry matrix is expanded
    to a dense table of the held columns instead. The decoded level does not depend on the
    summation order, so the stamps are exactly those of the dense product either way. When b (A + 1) would overflow the float64
    exponent, the maximum per (row, col) is taken by sorting the candidates instead.
    """
    max_level = int(age_max_steps)
    cutoff = max(int(t_sent) - max_level, 0)
    if (
        _kernels.NUMBA
        and _kernels.ENABLED
        and max_level + 1 <= _BITSET_MAX_LEVELS
        and n_holders > _COMPILED_BITSET_MIN_HOLDERS
    ):
        # The steps below (selection, adjacency, cost model) in one compiled pass, then the hop.
        fr, fc, fs, entry_start, link_start, link_src, work, n_k, s_max, ordered = (
            _message_kernels.hop_inputs(rows, cols, stamps, n_holders, n_cols, pairs, cutoff)
        )
        if len(fr) == 0 or len(pairs) == 0:
            return fr, fc, fs
        if s_max <= t_sent and ordered:
            bit_cost = (
                (max_level + 1)
                * ((n_k + 63) // 64)
                * (len(link_src) + n_holders)
                / _MAX_PER_BIT_WORD
            )
            if work < bit_cost:
                return _kernels.propagate_max(entry_start, fc, fs, link_start, link_src, n_cols)
            return _graph_kernels.hop_bitsets(
                fr, fc, fs, n_holders, n_cols, link_start, link_src, int(t_sent), max_level
            )
    rows, cols, stamps = (np.asarray(a, dtype=np.int64) for a in (rows, cols, stamps))
    rows, cols, stamps = _select(stamps >= cutoff, rows, cols, stamps)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(rows) == 0 or len(pairs) == 0:
        return rows, cols, stamps
    loops = np.arange(n_holders, dtype=np.int64)
    src = np.concatenate([pairs[:, 1], pairs[:, 0], loops])  # j -> i, i -> j, i -> i
    dst = np.concatenate([pairs[:, 0], pairs[:, 1], loops])
    if _kernels.NUMBA and _kernels.ENABLED and stamps.max() <= t_sent:
        # Per-entry maximum over a CSR adjacency (compiled) when its work, one random access per
        # (link, entry) pair, is below the bit sets' (levels x (links x words + a few passes over
        # the holders x held columns table)). Measured at XL (500 drones): ~6 ns per (link, entry)
        # against ~0.5 ns per bit-set unit, so the bit sets stay faster there even once the swarm
        # has spread; the per-entry maximum wins when the table is wide and the entries few
        # (thousands of drones, a few dozen entries each), where the bit sets are O(N^2) per level.
        count = np.bincount(rows, minlength=n_holders)
        work = int(count @ np.bincount(src, minlength=n_holders))
        n_k = int(np.count_nonzero(np.bincount(cols, minlength=n_cols)))
        compiled_bits = n_holders > _COMPILED_BITSET_MIN_HOLDERS
        if compiled_bits:
            # the compiled bit sets' work: one OR per (link, level, word), one decode per (holder, level, word)
            bit_cost = (
                (max_level + 1) * ((n_k + 63) // 64) * (len(src) + n_holders) / _MAX_PER_BIT_WORD
            )
        else:
            # NumPy's bit sets: a gather of (links, words) per level and passes over the table
            bit_cost = (
                (max_level + 1) * (len(src) * ((n_k + 63) // 64) * 8 + 4 * n_holders * n_k) / 12
            )
        order = np.argsort(dst, kind="stable")
        link_start = np.searchsorted(dst[order], np.arange(n_holders + 1))
        if max_level + 1 > _BITSET_MAX_LEVELS or work < bit_cost:
            if np.any(rows[1:] < rows[:-1]):
                by_row = np.lexsort((cols, rows))
                rows, cols, stamps = rows[by_row], cols[by_row], stamps[by_row]
            return _kernels.propagate_max(
                np.concatenate([[0], np.cumsum(count)]),
                cols,
                stamps,
                link_start,
                src[order],
                n_cols,
            )
        if compiled_bits and stamps.min() >= t_sent - max_level:
            return _graph_kernels.hop_bitsets(
                rows,
                cols,
                stamps,
                n_holders,
                n_cols,
                link_start,
                src[order],
                int(t_sent),
                max_level,
            )
    if max_level + 1 <= _BITSET_MAX_LEVELS and stamps.max() <= t_sent:
        return _propagate_bitsets(
            rows, cols, stamps, n_holders, n_cols, src, dst, int(t_sent), max_level
        )
    bits = int(np.ceil(np.log2(n_holders + 1))) + 1  # 2^bits > n_holders >= deg + 1
    if bits * (max_level + 1) < 1000:
        level = max_level - np.minimum(t_sent - stamps, max_level)
        adj = csr_matrix((np.ones(len(src)), (dst, src)), shape=(n_holders, n_holders))
        adj.data[:] = 1.0  # a repeated link counts once
        held = np.bincount(cols, minlength=n_cols) > 0
        col_ids = np.flatnonzero(held)
        if len(rows) < _SPARSE_ENTRY_FRACTION * n_holders * len(col_ids):
            indptr = np.zeros(n_holders + 1, dtype=np.int64)
            np.cumsum(np.bincount(rows, minlength=n_holders), out=indptr[1:])
            code = csr_matrix(
                (np.ldexp(1.0, bits * level), cols, indptr), shape=(n_holders, n_cols)
            )
            total = adj @ code
            total.sort_indices()
            out_rows = np.repeat(np.arange(n_holders, dtype=np.int64), np.diff(total.indptr))
            out_level = max_level - (np.frexp(total.data)[1] - 1) // bits
            return out_rows, total.indices.astype(np.int64), t_sent - out_level
        # Sparse adjacency times the dense code table of the columns somebody holds.
        code = np.zeros((n_holders, len(col_ids)))
        code[rows, (np.cumsum(held) - 1)[cols]] = np.ldexp(1.0, bits * level)
        total = adj @ code
        out_rows, out_k = np.nonzero(total)
        out_level = max_level - (np.frexp(total[out_rows, out_k])[1] - 1) // bits
        return out_rows, col_ids[out_k], t_sent - out_level
    # Candidates (every entry of every neighbour and of the holder itself), then the freshest per key.
    order = np.argsort(src, kind="stable")
    src, dst = src[order], dst[order]
    count = np.bincount(rows, minlength=n_holders)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    per_link = count[src]
    link_of = np.repeat(np.arange(len(src)), per_link)
    offset = np.arange(len(link_of)) - np.repeat(np.cumsum(per_link) - per_link, per_link)
    take = start[src][link_of] + offset
    key = dst[link_of] * n_cols + cols[take]
    val = stamps[take]
    order = np.lexsort((val, key))
    key, val = key[order], val[order]
    last = np.r_[key[1:] != key[:-1], True]
    return key[last] // n_cols, key[last] % n_cols, val[last]


def _propagate_bitsets(
    rows: np.ndarray,
    cols: np.ndarray,
    stamps: np.ndarray,
    n_holders: int,
    n_cols: int,
    src: np.ndarray,
    dst: np.ndarray,
    t_sent: int,
    max_level: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`propagate_entries` for few age levels: for each level L, the set of drones a holder
    knows with age <= L is a bit row; a holder's new set is the OR of its neighbours' (and its own),
    so a level costs one gather of (links, columns / 64) words. The new age of an entry is the first
    level whose set holds it. Links ``src -> dst`` include a self-loop for every holder."""
    held = np.bincount(cols, minlength=n_cols) > 0
    col_ids = np.flatnonzero(held)
    n_k = len(col_ids)
    width = 64 * ((n_k + 63) // 64)
    age: np.ndarray = np.full(
        n_holders * width, 127, dtype=np.int8
    )  # 127: not held (max_level < 16)
    age[rows * width + (np.cumsum(held) - 1)[cols]] = t_sent - stamps
    age = age.reshape(n_holders, width)
    key = dst.astype(np.int16) if n_holders < 2**15 else dst  # small keys: radix sort
    order = np.argsort(key, kind="stable")
    link_src = src[order]
    starts = np.searchsorted(dst[order], np.arange(n_holders))  # every holder has its self-loop
    count = np.zeros((n_holders, n_k), dtype=np.uint8)  # levels whose set holds (i, k)
    for level in range(max_level + 1):
        sets = np.packbits(age <= level, axis=1, bitorder="little").view(np.uint64)  # (n, words)
        heard = np.bitwise_or.reduceat(sets[link_src], starts, axis=0).view(np.uint8)
        count += np.unpackbits(heard, axis=1, count=n_k, bitorder="little")
    flat = np.flatnonzero(count)  # row-major
    # held at age a: the sets of levels a..max_level hold it, count = max_level + 1 - a
    new_stamp = t_sent - (max_level + 1 - count.ravel()[flat].astype(np.int64))
    return flat // n_k, col_ids[flat % n_k], new_stamp


def propagate_stamps(
    stamp: np.ndarray,
    pairs: np.ndarray,
    t_sent: int | None = None,
    age_max_steps: int | None = None,
) -> np.ndarray:
    """One hop of the recency rule: new[i, k] = max(stamp[i, k], max_{j ~ i} stamp[j, k]).

    Parameters
    ----------
    stamp : (n, K) int, tables before receiving (row = holder, -1 = unknown)
    pairs : (P, 2) int, undirected links (i, j) among the n holders
    t_sent : step at which the tables were sent (default: the largest stamp)
    age_max_steps : entries older than this at ``t_sent`` are never forwarded (default: all ages)

    Returns
    -------
    (n, K) int, tables after receiving one message from every neighbour.

    Dense-table front end of :func:`propagate_entries` (the message layer itself works on entries);
    identical tables to :func:`propagate_stamps_dense` and :func:`propagate_stamps_reference`.
    """
    stamp = np.asarray(stamp)
    out = stamp.copy()
    n = len(stamp)
    if len(pairs) == 0 or n == 0:
        return out
    valid = stamp >= 0
    if not valid.any():
        return out
    t_sent = int(stamp[valid].max()) if t_sent is None else int(t_sent)
    max_level = t_sent - int(stamp[valid].min()) if age_max_steps is None else int(age_max_steps)
    r, c = np.nonzero(valid)
    nr, nc, ns = propagate_entries(r, c, stamp[r, c], n, stamp.shape[1], pairs, t_sent, max_level)
    out[nr, nc] = np.maximum(out[nr, nc], ns)
    return out


def propagate_stamps_dense(
    stamp: np.ndarray,
    pairs: np.ndarray,
    t_sent: int | None = None,
    age_max_steps: int | None = None,
) -> np.ndarray:
    """The previous (dense-table) implementation of :func:`propagate_stamps`, kept as a reference
    for tests and for :class:`KnowledgeDense`. One hop of the recency rule: new[i, k] = max(stamp[i, k], max_{j ~ i} stamp[j, k]).

    Parameters
    ----------
    stamp : (n, K) int, tables before receiving (row = holder, -1 = unknown)
    pairs : (P, 2) int, undirected links (i, j) among the n holders
    t_sent : step at which the tables were sent (default: the largest stamp)
    age_max_steps : entries older than this at ``t_sent`` are never forwarded (default: all ages)

    Returns
    -------
    (n, K) int, tables after receiving one message from every neighbour.

    Notes
    -----
    A max-plus product is not a BLAS operation, but it becomes one through an exponent encoding:
    with ages a = t_sent - stamp in [0, A] and 2^b greater than any degree, each entry is sent as
    the exactly representable float 2^(b (A - a)). A float64 product with the adjacency matrix sums
    at most ``deg < 2^b`` such powers, so the sum lies in [2^(b e), 2^(b (e + 1))) where A - e is
    the freshest age among the neighbours; ``np.frexp`` recovers e exactly from the binary exponent
    (no logarithms, no rounding at the boundary). One O(n^2 K) DGEMM replaces the O(E K) gather of
    an edge list (E ~ n^2 when everybody hears everybody). When b A would overflow the float64
    exponent range, the ages are resolved level by level instead (one product per age).
    """
    stamp = np.asarray(stamp)
    out = stamp.copy()
    n = len(stamp)
    if len(pairs) == 0 or n == 0:
        return out
    valid = stamp >= 0
    if not valid.any():
        return out
    t_sent = int(stamp[valid].max()) if t_sent is None else int(t_sent)
    if age_max_steps is None:
        max_level = t_sent - int(stamp[valid].min())  # the oldest valid age
        send = valid
    else:
        max_level = int(age_max_steps)
        send = stamp >= max(t_sent - max_level, 0)  # valid, age <= max_level
    bits = int(np.ceil(np.log2(n + 1))) + 1  # 2^bits > n - 1 >= any degree
    if bits * (max_level + 1) < 1000:
        code = np.zeros(stamp.shape)
        code[send] = np.ldexp(1.0, bits * (max_level - np.minimum(t_sent - stamp[send], max_level)))
        if n > _SPARSE_MIN_HOLDERS:
            # Radio links are sparse once the swarm spreads (a few dozen neighbours out of 500): a
            # sparse product costs O(links K) instead of O(n^2 K). The decoded level does not
            # depend on the summation order (the sum stays in its power-of-two bracket), so the
            # result is the same integer table as the dense product's.
            adj = csr_matrix(
                (
                    np.ones(2 * len(pairs)),
                    (
                        np.concatenate([pairs[:, 0], pairs[:, 1]]),
                        np.concatenate([pairs[:, 1], pairs[:, 0]]),
                    ),
                ),
                shape=(n, n),
            )
            total = adj @ code
        else:
            adj = np.zeros((n, n))
            adj[pairs[:, 0], pairs[:, 1]] = 1.0
            adj[pairs[:, 1], pairs[:, 0]] = 1.0
            total = adj @ code
        heard = total > 0
        level = max_level - (np.frexp(total[heard])[1] - 1) // bits
        out[heard] = np.maximum(out[heard], t_sent - level)
        return out
    age = np.where(valid, t_sent - stamp, np.iinfo(np.int64).max)
    adj = np.zeros((n, n), dtype=np.float32)
    adj[pairs[:, 0], pairs[:, 1]] = 1.0
    adj[pairs[:, 1], pairs[:, 0]] = 1.0
    unresolved = (adj @ send.astype(np.float32)) > 0
    for level in range(max_level + 1):
        rows = np.flatnonzero(unresolved.any(axis=1))
        if len(rows) == 0:
            break
        cols = np.flatnonzero(unresolved[rows].any(axis=0))
        hit = unresolved[np.ix_(rows, cols)] & (
            (adj[rows] @ (age[:, cols] == level).astype(np.float32)) > 0
        )
        r_hit, c_hit = np.nonzero(hit)
        out[rows[r_hit], cols[c_hit]] = np.maximum(out[rows[r_hit], cols[c_hit]], t_sent - level)
        unresolved[rows[r_hit], cols[c_hit]] = False
    return out


def propagate_stamps_reference(stamp: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Plain-loop version of :func:`propagate_stamps` (for tests)."""
    stamp = np.asarray(stamp)
    out = stamp.copy()
    for i, j in pairs:
        for k in range(stamp.shape[1]):
            out[i, k] = max(out[i, k], stamp[j, k])
            out[j, k] = max(out[j, k], stamp[i, k])
    return out


def _flood_tree_stamp(
    tree_stamp: np.ndarray,
    idx: np.ndarray,
    pairs: np.ndarray,
    link_pos_m: np.ndarray,
    base_m: np.ndarray,
    base_reach_m: float,
    t_step: int,
) -> None:
    """Deliver the task-tree stamps over one hop (in place on ``tree_stamp[idx]``).

    The stamp rides in the same messages as the reports but has its own staleness rule: every
    linked holder keeps the freshest stamp among itself and its neighbours (``pairs`` index
    ``idx``), and holders within ``base_reach_m`` of the base at ``link_pos_m`` (positions of
    ``idx``) receive the tree the base computed at step t - 1. Compiled when it can be
    (:func:`planner._message_kernels.flood_tree_stamp`, the same stamps; these lines are its
    reference).
    """
    if _message_kernels.flood_tree_stamp(
        tree_stamp, idx, pairs, link_pos_m, base_m, base_reach_m, t_step
    ):
        return
    ts = tree_stamp[idx]
    best = ts.copy()
    if len(pairs):
        np.maximum.at(best, pairs[:, 0], ts[pairs[:, 1]])
        np.maximum.at(best, pairs[:, 1], ts[pairs[:, 0]])
    at_base = np.linalg.norm(link_pos_m - base_m, axis=1) <= base_reach_m
    best[at_base] = t_step - 1
    tree_stamp[idx] = best


class StampTable:
    """The (N, N) stamp table of :class:`Knowledge`, read-only, over its entry list: memory
    O(entries), not O(N^2) (an int64 (N, N) array is 32 MB at 2,000 drones and 800 MB at 10,000).

    ``table[rows, cols]`` with integer index arrays (or ints; broadcast like NumPy's fancy indexing)
    looks the stamps up by binary search in the row-major entries (-1 = unknown); any other index,
    ``np.asarray(table)`` and comparisons build the dense array (tests, small swarms).
    """

    def __init__(self, n: int, rows: np.ndarray, cols: np.ndarray, stamps: np.ndarray) -> None:
        self.shape = (n, n)
        self._rows, self._cols, self._stamps = rows, cols, stamps
        self._keys: np.ndarray | None = None

    def lookup(self, rows: Any, cols: Any) -> np.ndarray:
        """Stamps at (rows, cols), broadcast; -1 where the holder knows nothing of the drone."""
        r, c = np.broadcast_arrays(
            np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
        )
        n = self.shape[0]
        if r.size and (r.min() < -n or r.max() >= n or c.min() < -n or c.max() >= n):
            raise IndexError(f"stamp index out of range for shape {self.shape}")
        want = np.where(r < 0, r + n, r) * n + np.where(c < 0, c + n, c)
        if len(self._rows) == 0:
            return np.full(want.shape, UNKNOWN, dtype=np.int64)
        if self._keys is None:
            self._keys = self._rows * n + self._cols  # row-major: sorted
        at = np.minimum(np.searchsorted(self._keys, want), len(self._keys) - 1)
        return np.where(self._keys[at] == want, self._stamps[at], UNKNOWN)

    def __getitem__(self, key: Any) -> Any:
        if (
            isinstance(key, tuple)
            and len(key) == 2
            and all(
                isinstance(k, (int, np.integer))
                or (isinstance(k, np.ndarray) and k.dtype.kind in "iu")
                for k in key
            )
        ):
            out = self.lookup(key[0], key[1])
            return out[()] if out.ndim == 0 else out
        return np.asarray(self)[key]

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        dense = np.full(self.shape, UNKNOWN, dtype=np.int64)
        dense[self._rows, self._cols] = self._stamps
        return dense if dtype is None else dense.astype(dtype)

    def __eq__(self, other: object) -> Any:  # elementwise, as an array
        return np.asarray(self) == other

    def __ne__(self, other: object) -> Any:  # elementwise, as an array
        return np.asarray(self) != other

    def __ge__(self, other: Any) -> Any:
        return np.asarray(self) >= other

    def __gt__(self, other: Any) -> Any:
        return np.asarray(self) > other

    def __le__(self, other: Any) -> Any:
        return np.asarray(self) <= other

    def __lt__(self, other: Any) -> Any:
        return np.asarray(self) < other

    __hash__ = None  # type: ignore[assignment]  # compared elementwise, like an array


@dataclass
class _StampTables:
    """What both implementations hold: the tree stamps and the history of true positions (see
    :class:`Knowledge` for the attributes), with the views derived from the stamp table."""

    tree_stamp: np.ndarray
    pos_hist_m: np.ndarray

    def _stamp_array(self) -> np.ndarray:
        raise NotImplementedError  # each implementation holds its table its own way

    def believed_positions_m(self) -> np.ndarray:
        """(N, N, 2): where drone i believes drone k is (garbage where stamp is unknown)."""
        stamp = self._stamp_array()
        n = stamp.shape[0]
        s = np.where(stamp >= 0, stamp, 0)
        return self.pos_hist_m[s, np.arange(n)[None, :]]

    def known(self) -> np.ndarray:
        """(N, N) bool: i holds a valid entry about k (k != i)."""
        k = self._stamp_array() != UNKNOWN
        np.fill_diagonal(k, False)
        return k


@dataclass
class Knowledge(_StampTables):
    """Per-drone beliefs of an episode under the asynchronous information model.

    The beliefs are held as a list of entries (holder, drone, stamp) in row-major order; once the
    swarm spreads each drone holds a few dozen of the N possible entries (the others are beyond
    ``dist_max`` or more than ``age_max_steps`` hops away), and every step of :meth:`update` costs
    time proportional to the entries and links, not N^2. ``stamp`` mirrors the list as a table.

    Attributes
    ----------
    stamp : (N, N) :class:`StampTable`, step of the freshest report drone i holds about drone k
        (-1 unknown): a read-only view of the entry list (no (N, N) array is kept)
    tree_stamp : (N,) int64, step at which the base computed drone i's copy of the task tree (-1 none)
    pos_hist_m : (T, N, 2) float64, true positions by step (the content of every report)
    held_rows, held_cols, held_stamps : (H,) int64, every valid entry (self entries included), row-major
    rows, cols : index arrays of the current *view*: alive holders and drones anybody knows about
    entry_rows, entry_cols : (E,) int, the known entries of the view (never the holder itself), as
        indices into ``rows`` and ``cols``, in row-major order
    entry_believed_m : (E, 2) believed position of each entry
    known_view : (len(rows), len(cols)) bool, the same entries as a mask (built on request)

    :meth:`view_entry_stamps` gives each view entry's stamp.
    """

    held_rows: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    held_cols: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    held_stamps: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    rows: np.ndarray | None = None
    cols: np.ndarray | None = None
    entry_rows: np.ndarray | None = None
    entry_cols: np.ndarray | None = None
    entry_believed_m: np.ndarray | None = None
    n_drones: int = 0
    #: (E,) the stamp of each view entry, set by the fused update (else built on request); cleared
    #: by every update (it describes this tick's entries only)
    _entry_stamps: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: scratch arrays of the compiled update, reused from tick to tick (no state)
    _scratch: tuple[np.ndarray, ...] = field(
        default_factory=_message_kernels.knowledge_scratch, repr=False, compare=False
    )
    #: the links of the last delivery, as :meth:`update` used them: (t_step, idx, pairs,
    #: link_pos), ``pairs`` (P, 2) indexing ``idx`` (the drones alive at link time) and
    #: ``link_pos`` the (N, 2) positions the links were measured at; None when nothing was
    #: delivered (the first step). Read by listeners of the same deliveries
    #: (planner/base_view.py); the update itself never reads it.
    last_delivery: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = field(
        default=None, repr=False, compare=False
    )

    @classmethod
    def empty(cls, n_drones: int, n_steps: int) -> Self:
        """Nothing known, no tree, room for ``n_steps`` + 1 steps of positions."""
        return cls(
            np.full(n_drones, UNKNOWN, dtype=np.int64),
            np.zeros((n_steps + 1, n_drones, 2)),
            n_drones=n_drones,
        )

    @property
    def stamp(self) -> StampTable:
        """The (N, N) stamp table as a read-only view of the entries (see :class:`StampTable`)."""
        return StampTable(self.n_drones, self.held_rows, self.held_cols, self.held_stamps)

    def _stamp_array(self) -> np.ndarray:
        return np.asarray(self.stamp)

    @property
    def known_view(self) -> np.ndarray:
        """(len(rows), len(cols)) bool: the holder knows the drone (never itself)."""
        assert self.rows is not None and self.cols is not None  # set by update()
        known = np.zeros((len(self.rows), len(self.cols)), dtype=bool)
        known[self.entry_rows, self.entry_cols] = True
        return known

    def view_entry_stamps(self) -> np.ndarray:
        """(E,) int64: the stamp of each view entry (``stamp[rows[entry_rows], cols[entry_cols]]``,
        what :meth:`StampTable.lookup` finds). The view entries are the held entries without the
        self ones, in the same order (only alive drones hold entries), so no search is needed."""
        if self._entry_stamps is None:
            r, c, s = self.held_rows, self.held_cols, self.held_stamps
            self._entry_stamps = s[r != c]
        return self._entry_stamps

    @staticmethod
    def _own(
        r: np.ndarray, c: np.ndarray, s: np.ndarray, alive: np.ndarray, t_step: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Drop the entries of dead holders; every alive holder's own entry is stamped ``t_step``."""
        r, c, s = _select(alive[r], r, c, s)
        own = r == c
        if np.count_nonzero(own) == np.count_nonzero(alive):  # the usual case: all present
            s = s.copy()
            s[own] = t_step
            return r, c, s
        a = np.flatnonzero(alive).astype(np.int64)
        r = np.concatenate([r[~own], a])
        c = np.concatenate([c[~own], a])
        s = np.concatenate([s[~own], np.full(len(a), t_step, dtype=np.int64)])
        order = np.argsort(r * len(alive) + c, kind="stable")
        return r[order], c[order], s[order]

    def update(
        self,
        t_step: int,
        pos_prev_m: np.ndarray | None,
        alive_prev: np.ndarray | None,
        pos_m: np.ndarray,
        alive: np.ndarray,
        radio_range_m: float,
        base_reach_m: float,
        age_max_steps: int,
        dist_max_m: float,
        base_m: np.ndarray,
        *,
        after_move: bool = False,
        forget_unheard: bool = False,
    ) -> None:
        """Deliver the messages broadcast during step t-1, then each drone records its own state at t.

        When a drone broadcasts within a step decides what a message carries:

        * ``after_move=False``: at the start of step t-1, before moving. Links at t-1 join the drones
          alive at t-1 within r, and a neighbour is seen where it was before its last move.
        * ``after_move=True``: at the end of step t-1, after moving. Links join the drones alive at t
          within r at their positions at t, so direct neighbours are seen where they are now, two-hop
          ones one step late, and so on (still one hop per step). A drone lost during t-1 sends nothing.

        Either way, the base sends the tree it computed at t-1 to drones within ``base_reach_m`` =
        min(R, r) of it over the same links, and nothing is delivered at the first step.
        ``forget_unheard``: a drone drops an entry about a drone it believes within radio range but
        did not hear in this delivery (what a mesh radio's neighbour table does on a missed beacon).
        Afterwards the view (``rows``, ``cols`` and the entries) describes every alive holder.
        """
        n = len(pos_m)
        alive = np.asarray(alive, dtype=bool)
        self.pos_hist_m[t_step] = pos_m
        self._entry_stamps = None  # last tick's
        if after_move:
            link_pos_m, link_alive, t_sent = pos_m, alive, t_step
            self.tree_stamp[~alive] = UNKNOWN
        else:
            link_pos_m, link_alive, t_sent = pos_prev_m, alive_prev, t_step - 1  # type: ignore[assignment]  # read only if pos_prev_m is not None
        idx = np.empty(0, np.intp)
        pairs = np.empty((0, 2), np.intp)
        if pos_prev_m is not None:
            idx = np.flatnonzero(link_alive)
            # Unordered pairs: the hop and the tree flood take maxima over the links (any order).
            if len(idx) > 1:
                pairs = radio_pairs(link_pos_m[idx], radio_range_m, ordered=False)
            _flood_tree_stamp(
                self.tree_stamp, idx, pairs, link_pos_m[idx], base_m, base_reach_m, t_step
            )
            self.last_delivery = (int(t_step), idx, pairs, link_pos_m)
        else:
            self.last_delivery = None
        # Own state is always fresh; dead drones hold nothing.
        self.tree_stamp[~alive] = UNKNOWN
        if (
            age_max_steps + 1 <= _BITSET_MAX_LEVELS
            and n > _COMPILED_BITSET_MIN_HOLDERS
            and len(self.held_rows) + n > 0
        ):
            # own entries, the hop and the lines at the end in one compiled pass, the same arrays
            # (tests/planner/test_knowledge.py); None without Numba or outside its input range
            fused, self._scratch = _message_kernels.knowledge_step(
                self.held_rows,
                self.held_cols,
                self.held_stamps,
                alive,
                after_move,
                pos_prev_m is not None,
                idx,
                pairs,
                int(t_sent),
                int(age_max_steps),
                _MAX_PER_BIT_WORD,
                int(t_step),
                self.pos_hist_m,
                pos_m,
                dist_max_m,
                radio_range_m,
                bool(forget_unheard and pos_prev_m is not None),
                self._scratch,
            )
            if fused is not None:
                self.held_rows, self.held_cols, self.held_stamps = fused[:3]
                self.rows, self.cols, self.entry_rows, self.entry_cols = fused[3:7]
                self.entry_believed_m = fused[7]
                self._entry_stamps = fused[8]
                return
        r, c, s = self.held_rows, self.held_cols, self.held_stamps
        if after_move:
            r, c, s = self._own(r, c, s, alive, t_step)
        if pos_prev_m is not None:
            # Holders outside ``idx`` have no links: they keep their forwarded entries (the others
            # are past the age cut-off below either way).
            r, c, s = propagate_entries(r, c, s, n, n, idx[pairs], t_sent, age_max_steps)
        if _kernels.NUMBA and _kernels.ENABLED and self.pos_hist_m.flags.c_contiguous:
            # the lines below in one compiled pass, bit for bit (tests/planner/test_kernels.py)
            pos_m = np.asarray(pos_m, float)
            r, c, s, col_held, bx, by = _kernels.finish_knowledge_update(
                np.asarray(r, np.int64),
                np.asarray(c, np.int64),
                np.asarray(s, np.int64),
                alive,
                int(t_step),
                int(t_step - age_max_steps),
                self.pos_hist_m,
                np.ascontiguousarray(pos_m[:, 0]),
                np.ascontiguousarray(pos_m[:, 1]),
                dist_max_m * dist_max_m,
                radio_range_m * radio_range_m,
                bool(forget_unheard and pos_prev_m is not None),
                int(t_sent),
            )
            self.held_rows, self.held_cols, self.held_stamps = r, c, s
            self._set_view(alive, col_held, r, c, bx, by)
            return
        r, c, s = self._own(r, c, s, alive, t_step)
        # Forget stale entries, then distant ones (measured from the holder's own position).
        r, c, s = _select(s >= t_step - age_max_steps, r, c, s)
        col_held = np.bincount(c, minlength=n) > 0  # known to somebody before the distance cut
        hist = self.pos_hist_m.reshape(-1, 2)
        at = s * n + c  # pos_hist_m[s, c], one coordinate at a time
        bx, by = hist[:, 0][at], hist[:, 1][at]
        dx, dy = bx - pos_m[:, 0][r], by - pos_m[:, 1][r]
        d2 = dx * dx
        d2 += dy * dy
        far = d2 > dist_max_m * dist_max_m
        if forget_unheard and pos_prev_m is not None:
            # Believed within range, yet not heard in this delivery (a direct neighbour's entry
            # carries the sending step): lost, or moved away since that report.
            far |= (d2 <= radio_range_m * radio_range_m) & (s < t_sent)
        r, c, s, bx, by = _select(~far, r, c, s, bx, by)
        self.held_rows, self.held_cols, self.held_stamps = r, c, s
        self._set_view(alive, col_held, r, c, bx, by)

    def _set_view(
        self,
        alive: np.ndarray,
        col_held: np.ndarray,
        r: np.ndarray,
        c: np.ndarray,
        bx: np.ndarray,
        by: np.ndarray,
    ) -> None:
        """The view of every alive holder from the kept entries (self entries left out)."""
        view = _message_kernels.entry_view(alive, col_held, r, c, bx, by)
        if view is not None:  # the lines below in one compiled pass (the same arrays)
            self.rows, self.cols, self.entry_rows, self.entry_cols, self.entry_believed_m = view
            return
        er, ec, bx, by = _select(r != c, r, c, bx, by)
        row_of = np.cumsum(alive) - 1
        col_of = np.cumsum(col_held) - 1
        self.rows, self.cols = np.flatnonzero(alive), np.flatnonzero(col_held)
        self.entry_rows, self.entry_cols = row_of[er], col_of[ec]
        self.entry_believed_m = np.column_stack([bx, by])


@dataclass
class KnowledgeDense(_StampTables):
    """The previous dense-table implementation of :class:`Knowledge` (for tests: every (N, N)
    operation in the open, the same semantics; :class:`Knowledge` must give identical tables).

    Attributes
    ----------
    stamp, tree_stamp, pos_hist_m : as in :class:`Knowledge`
    rows, cols : index arrays of the current *view*: alive holders and drones anybody knows about
    known_view : (len(rows), len(cols)) bool, holder knows the drone (never itself)
    entry_rows, entry_cols : (E,) int, the True entries of ``known_view`` in row-major order
    entry_believed_m : (E, 2) believed position of each entry
    """

    stamp: np.ndarray = field(default_factory=lambda: np.empty((0, 0), np.int64))
    rows: np.ndarray | None = None
    cols: np.ndarray | None = None
    known_view: np.ndarray | None = None
    entry_rows: np.ndarray | None = None
    entry_cols: np.ndarray | None = None
    entry_believed_m: np.ndarray | None = None

    @classmethod
    def empty(cls, n_drones: int, n_steps: int) -> Self:
        """Nothing known, no tree, room for ``n_steps`` + 1 steps of positions."""
        return cls(
            np.full(n_drones, UNKNOWN, dtype=np.int64),
            np.zeros((n_steps + 1, n_drones, 2)),
            np.full((n_drones, n_drones), UNKNOWN, dtype=np.int64),
        )

    def _stamp_array(self) -> np.ndarray:
        return self.stamp

    def update(
        self,
        t_step: int,
        pos_prev_m: np.ndarray | None,
        alive_prev: np.ndarray | None,
        pos_m: np.ndarray,
        alive: np.ndarray,
        radio_range_m: float,
        base_reach_m: float,
        age_max_steps: int,
        dist_max_m: float,
        base_m: np.ndarray,
        *,
        after_move: bool = False,
        forget_unheard: bool = False,
    ) -> None:
        """The dense (N, N) version of :meth:`Knowledge.update` (same semantics; the test reference)."""
        self.pos_hist_m[t_step] = pos_m
        if after_move:
            link_pos_m, link_alive, t_sent = pos_m, alive, t_step
            self.stamp[~alive] = UNKNOWN
            self.tree_stamp[~alive] = UNKNOWN
            own = np.flatnonzero(alive)
            self.stamp[own, own] = t_step
        else:
            link_pos_m, link_alive, t_sent = pos_prev_m, alive_prev, t_step - 1  # type: ignore[assignment]  # read only if pos_prev_m is not None
        if pos_prev_m is not None:
            idx = np.flatnonzero(link_alive)
            pairs = (
                neighbour_pairs(link_pos_m[idx], radio_range_m)
                if len(idx) > 1
                else np.empty((0, 2), np.intp)
            )
            held = self.stamp[idx]
            # Columns nobody holds (lost drones, once forgotten) cannot change: hop the others only.
            ck = np.flatnonzero((held >= 0).any(axis=0))
            if len(ck) < 0.8 * held.shape[1]:
                held[:, ck] = propagate_stamps_dense(held[:, ck], pairs, t_sent, age_max_steps)
                self.stamp[idx] = held
            else:
                self.stamp[idx] = propagate_stamps_dense(held, pairs, t_sent, age_max_steps)
            _flood_tree_stamp(
                self.tree_stamp, idx, pairs, link_pos_m[idx], base_m, base_reach_m, t_step
            )
        # Own state is always fresh; dead drones hold nothing.
        self.stamp[~alive] = UNKNOWN
        self.tree_stamp[~alive] = UNKNOWN
        rows = np.flatnonzero(alive)
        self.stamp[rows, rows] = t_step
        # Forget stale entries, then distant ones (measured from the holder's own position).
        self.stamp[self.stamp < t_step - age_max_steps] = UNKNOWN  # (UNKNOWN stays UNKNOWN)
        cols = np.flatnonzero((self.stamp[rows] != UNKNOWN).any(axis=0))
        sub = self.stamp[np.ix_(rows, cols)]
        # Only the known entries (a few dozen per holder once the swarm spreads) are gathered.
        er, ek = np.nonzero(sub != UNKNOWN)  # row-major
        believed = self.pos_hist_m[sub[er, ek], cols[ek]]  # (E, 2)
        diff = believed - pos_m[rows][er]
        d2 = np.einsum("ec,ec->e", diff, diff)
        far = d2 > dist_max_m * dist_max_m
        if forget_unheard and pos_prev_m is not None:
            # Believed within range, yet not heard in this delivery (a direct neighbour's entry
            # carries the sending step): lost, or moved away since that report.
            far |= (d2 <= radio_range_m * radio_range_m) & (sub[er, ek] < t_sent)
        sub[er[far], ek[far]] = UNKNOWN
        self.stamp[np.ix_(rows, cols)] = sub
        keep = ~far & (rows[er] != cols[ek])
        known = sub != UNKNOWN
        known &= rows[:, None] != cols[None, :]
        self.rows, self.cols, self.known_view = rows, cols, known
        self.entry_rows, self.entry_cols, self.entry_believed_m = er[keep], ek[keep], believed[keep]


class MessageLayer:
    """The asynchronous information model of one planner over a run (docs/design/model.md §5.4).

    Owns the :class:`Knowledge` tables, the previous tick needed to deliver messages, and a short
    history of what the base broadcast (PhiIREMAN: its task tree; DCCRS: the task positions), so
    that a drone holding broadcast stamp s acts on ``broadcast(s)``. Positions are in paper units.

    Parameters
    ----------
    n_drones, n_steps : table sizes (the history grows if a run outlasts ``n_steps``)
    radio_range_u, base_reach_u : link range r and the base's reach min(R, r)
    age_max_steps, dist_max_u : the recency rule's age and distance cut-offs
    stale_steps : a drone whose broadcast copy is older than this is stale (assumes disconnection)
    after_move, forget_unheard : when in a step a drone broadcasts, and whether it forgets neighbours
        it did not hear (:meth:`Knowledge.update`); the planners' parameters hold the defaults
    """

    @classmethod
    def from_params(
        cls, n_drones: int, n_steps: int, radio_range_u: float, base_reach_u: float, p: Any
    ) -> MessageLayer:
        """The layer with a planner's message timing (``age_max_steps``, ``dist_max``,
        ``tree_stale_steps``, ``broadcast_after_move``, ``forget_unheard`` of PhiremanParams,
        DccrsParams or ResilientParams)."""
        return cls(
            n_drones,
            n_steps,
            radio_range_u,
            base_reach_u,
            p.age_max_steps,
            p.dist_max,
            p.tree_stale_steps,
            after_move=p.broadcast_after_move,
            forget_unheard=p.forget_unheard,
        )

    def step_or_home(
        self,
        t_step: int,
        pos_u: np.ndarray,
        alive: np.ndarray,
        base_u: np.ndarray,
        payload: Any,
        planning: np.ndarray,
        vmax_u: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`step`, then the paper's rule for drones whose broadcast went stale: assume
        disconnection and fly to the known base location at full speed. Returns ``(stale,
        disp_u)``: the planning drones that are stale, and (N, 2) instructions (zero for the
        others, for the planner to fill)."""
        stale = planning & self.step(t_step, pos_u, np.asarray(alive, bool), base_u, payload)
        disp_u = np.zeros_like(pos_u)
        disp_u[stale] = step_toward(pos_u[stale], base_u, vmax_u)
        return stale, disp_u

    def __init__(
        self,
        n_drones: int,
        n_steps: int,
        radio_range_u: float,
        base_reach_u: float,
        age_max_steps: int,
        dist_max_u: float,
        stale_steps: int,
        *,
        after_move: bool,
        forget_unheard: bool,
    ) -> None:
        self.knowledge = Knowledge.empty(n_drones, n_steps + 1)
        self.radio_range_u = radio_range_u
        self.base_reach_u = base_reach_u
        self.age_max_steps = age_max_steps
        self.dist_max_u = dist_max_u
        self.stale_steps = stale_steps
        self.after_move = after_move
        self.forget_unheard = forget_unheard
        self._prev: tuple[np.ndarray, np.ndarray] | None = None
        self._broadcasts: dict[int, Any] = {}  # whatever the planner broadcasts (a TaskTree)

    def step(
        self,
        t_step: int,
        pos_u: np.ndarray,
        alive: np.ndarray,
        base_u: np.ndarray,
        broadcast: object,
    ) -> np.ndarray:
        """Deliver last tick's messages, record this tick's base broadcast; return the (N,) mask
        of drones whose broadcast copy is stale (never received or older than ``stale_steps``)."""
        kn = self.knowledge
        if t_step >= len(kn.pos_hist_m):  # runs longer than the problem's horizon (live use)
            kn.pos_hist_m = np.concatenate([kn.pos_hist_m, np.zeros_like(kn.pos_hist_m)])
        prev_pos, prev_alive = self._prev if self._prev is not None else (None, None)
        kn.update(
            t_step,
            prev_pos,
            prev_alive,
            pos_u,
            alive,
            self.radio_range_u,
            self.base_reach_u,
            self.age_max_steps,
            self.dist_max_u,
            base_u,
            after_move=self.after_move,
            forget_unheard=self.forget_unheard,
        )
        self._prev = (pos_u, alive)
        self._broadcasts[t_step] = broadcast
        for old in [s for s in self._broadcasts if s < t_step - self.stale_steps - 1]:
            del self._broadcasts[old]
        return (kn.tree_stamp < 0) | (t_step - kn.tree_stamp > self.stale_steps)

    def broadcast(self, stamp: int) -> Any:
        """What the base broadcast at step ``stamp`` (still held by some drone)."""
        return self._broadcasts[int(stamp)]

    def view(self, holders: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Believed positions (n, K, 2, zero where unknown), known mask (n, K) and broadcast
        stamps (n,) of alive ``holders`` (columns are ``knowledge.cols``). Dense; the planners use
        :meth:`view_entries`."""
        kn = self.knowledge
        assert kn.cols is not None  # set by update()
        er, ek, believed, stamps = self.view_entries(holders)
        dense = np.zeros((len(holders), len(kn.cols), 2))
        dense[er, ek] = believed
        known = np.zeros((len(holders), len(kn.cols)), dtype=bool)
        known[er, ek] = True
        return dense, known, stamps

    def view_entries(
        self, holders: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The known entries of alive ``holders`` (sorted): rows (E,) into ``holders``, columns (E,)
        into ``knowledge.cols``, in row-major order; believed positions (E, 2); broadcast stamps (n,).
        When every alive drone is asked for, the columns and positions are the layer's own arrays
        (read them, do not write them)."""
        kn = self.knowledge
        assert kn.rows is not None and kn.entry_rows is not None  # set by update()
        assert kn.entry_cols is not None and kn.entry_believed_m is not None
        holders = np.asarray(holders)
        if len(holders) == len(kn.rows) and np.array_equal(holders, kn.rows):
            # every alive drone (the usual tick): the view's own rows, no remapping
            er = kn.entry_rows.astype(np.intp)  # a copy, as below
            return er, kn.entry_cols, kn.entry_believed_m, kn.tree_stamp[holders]
        local = np.full(len(kn.rows), -1, dtype=np.intp)
        local[np.searchsorted(kn.rows, holders)] = np.arange(len(holders))  # holders are alive
        er = local[kn.entry_rows]
        er, ek, believed = _select(er >= 0, er, kn.entry_cols, kn.entry_believed_m)
        return er, ek, believed, kn.tree_stamp[holders]

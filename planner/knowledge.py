"""Asynchronous message passing: what each drone knows (PAPER_NOTES §5.4, ARCHITECTURE §4.4b).

Each drone broadcasts its table to its radio neighbours; they receive it at the next step. For
every drone id a table keeps the most recent report (recency rule), and drops entries older than
``age_max_steps`` or farther than ``dist_max_m`` from the holder. The base-computed task tree is
flooded with the same rule.

Representation: a report about drone k made at step s always carries k's true position at s, so a
table entry is fully described by its *stamp* s. Beliefs are therefore one ``(N, N)`` int array of
stamps (-1 = unknown), and believed positions are gathered from the history of true positions:
``pos_hist[stamp[i, k], k]``. This is exact and keeps the state small.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.geometry import neighbour_pairs

__all__ = ["Knowledge", "propagate_stamps", "propagate_stamps_reference", "UNKNOWN"]

UNKNOWN = -1
# Bound on the (edges x drones) scratch array of one propagation chunk (elements).
_CHUNK_ELEMENTS = 4_000_000


def propagate_stamps(stamp: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """One hop of the recency rule: new[i, k] = max(stamp[i, k], max_{j ~ i} stamp[j, k]).

    Parameters
    ----------
    stamp : (n, K) int, tables before receiving (row = holder)
    pairs : (P, 2) int, undirected links (i, j) among the n holders

    Returns
    -------
    (n, K) int, tables after receiving one message from every neighbour.

    Notes
    -----
    Vectorised with ``np.maximum.reduceat`` over the directed edge list sorted by receiver,
    processed in chunks so that scratch memory stays below ~32 MB even on complete graphs.
    """
    out = stamp.copy()
    if len(pairs) == 0:
        return out
    recv = np.concatenate([pairs[:, 0], pairs[:, 1]])
    send = np.concatenate([pairs[:, 1], pairs[:, 0]])
    order = np.argsort(recv, kind="stable")
    recv, send = recv[order], send[order]
    n_cols = stamp.shape[1]
    per_chunk = max(1, _CHUNK_ELEMENTS // max(n_cols, 1))
    heads = np.flatnonzero(np.r_[True, recv[1:] != recv[:-1]])  # first edge of each receiver
    bounds = np.r_[heads, len(recv)]
    g = 0
    while g < len(heads):
        # as many whole receivers as fit in one chunk (at least one)
        g_end = max(g + 1, int(np.searchsorted(bounds, bounds[g] + per_chunk, side="right")) - 1)
        g_end = min(g_end, len(heads))
        lo, hi = bounds[g], bounds[g_end]
        best = np.maximum.reduceat(stamp[send[lo:hi]], heads[g:g_end] - lo, axis=0)
        rows = recv[heads[g:g_end]]
        out[rows] = np.maximum(out[rows], best)
        g = g_end
    return out


def propagate_stamps_reference(stamp, pairs) -> np.ndarray:
    """Plain-loop version of :func:`propagate_stamps` (for tests)."""
    stamp = np.asarray(stamp)
    out = stamp.copy()
    for i, j in pairs:
        for k in range(stamp.shape[1]):
            out[i, k] = max(out[i, k], stamp[j, k])
            out[j, k] = max(out[j, k], stamp[i, k])
    return out


@dataclass
class Knowledge:
    """Per-drone beliefs of an episode under the asynchronous information model.

    Attributes
    ----------
    stamp : (N, N) int64, step of the freshest report drone i holds about drone k (-1 unknown)
    tree_stamp : (N,) int64, step at which the base computed drone i's copy of the task tree (-1 none)
    pos_hist_m : (T, N, 2) float64, true positions by step (the content of every report)
    """

    stamp: np.ndarray
    tree_stamp: np.ndarray
    pos_hist_m: np.ndarray

    @classmethod
    def empty(cls, n_drones: int, n_steps: int) -> "Knowledge":
        return cls(np.full((n_drones, n_drones), UNKNOWN, dtype=np.int64),
                   np.full(n_drones, UNKNOWN, dtype=np.int64),
                   np.zeros((n_steps + 1, n_drones, 2)))

    def update(self, t_step: int, pos_prev_m: np.ndarray | None, alive_prev: np.ndarray | None,
               pos_m: np.ndarray, alive: np.ndarray, radio_range_m: float, base_reach_m: float,
               age_max_steps: int, dist_max_m: float, base_m: np.ndarray) -> None:
        """Deliver the messages sent at step t-1, then each drone records its own state at t.

        Links at t-1 join alive drones within r (connected to the base or not); the base sends the
        tree it computed at t-1 to drones within ``base_reach_m`` = min(R, r).
        """
        n = len(pos_m)
        self.pos_hist_m[t_step] = pos_m
        if pos_prev_m is not None:
            idx = np.flatnonzero(alive_prev)
            pairs = idx[neighbour_pairs(pos_prev_m[idx], radio_range_m)] if len(idx) > 1 else np.empty((0, 2), int)
            # Tree stamps ride in the same messages: treat them as one extra column.
            table = np.concatenate([self.stamp, self.tree_stamp[:, None]], axis=1)
            sub = table[idx]
            local = np.searchsorted(idx, pairs) if len(pairs) else pairs
            sub = propagate_stamps(sub, local)
            table[idx] = sub
            at_base = alive_prev & (np.linalg.norm(pos_prev_m - base_m, axis=1) <= base_reach_m)
            table[at_base, n] = t_step - 1
            self.stamp, self.tree_stamp = table[:, :n], table[:, n].copy()
        # Own state is always fresh; dead drones hold nothing.
        self.stamp[np.arange(n), np.arange(n)] = np.where(alive, t_step, UNKNOWN)
        self.stamp[~alive] = UNKNOWN
        self.tree_stamp[~alive] = UNKNOWN
        # Forget stale or distant entries.
        too_old = (self.stamp != UNKNOWN) & (t_step - self.stamp > age_max_steps)
        believed = self.believed_positions_m()
        far = np.linalg.norm(believed - pos_m[:, None, :], axis=2) > dist_max_m
        self.stamp[too_old | (far & (self.stamp != UNKNOWN))] = UNKNOWN

    def believed_positions_m(self) -> np.ndarray:
        """(N, N, 2): where drone i believes drone k is (garbage where stamp is unknown)."""
        n = self.stamp.shape[0]
        s = np.where(self.stamp >= 0, self.stamp, 0)
        return self.pos_hist_m[s, np.arange(n)[None, :]]

    def known(self) -> np.ndarray:
        """(N, N) bool: i holds a valid entry about k (k != i)."""
        k = self.stamp != UNKNOWN
        np.fill_diagonal(k, False)
        return k

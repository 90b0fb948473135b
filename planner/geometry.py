"""Shared geometry: distances, radio connectivity, geodetic <-> local NED.

The emulator's radio model and the planner's connectivity metric both call :func:`active_mask`, so
"who is networked" means the same thing everywhere by construction (docs/design/architecture.md §1.2).

Inequalities follow the paper (docs/design/model.md §4): drone-drone and drone-base links use ``<=``; a task
is served only by a drone strictly closer than r (``<``).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pymap3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from planner import _graph_kernels, _kernels
from planner._graph_kernels import bounded_moves

__all__ = [
    "NORTH",
    "EAST",
    "DOWN",
    "pairwise_distance_m",
    "neighbour_pairs",
    "radio_pairs",
    "active_mask",
    "active_mask_reference",
    "tasks_connected",
    "step_toward",
    "bounded_moves",
    "geodetic_to_ned_m",
    "ned_to_geodetic",
]

NORTH, EAST, DOWN = 0, 1, 2

# Relative slack on range comparisons done through a KD-tree, whose ball query is exact but uses a
# different rounding path from the brute-force distance; pairs are re-checked exactly afterwards.
_KD_SLACK = 1e-9
# Above this many alive drones, connectivity uses scipy's connected components instead of a BFS.
_BFS_MAX_DRONES = 150


def pairwise_distance_m(a_m: np.ndarray, b_m: np.ndarray | None = None) -> np.ndarray:
    """Euclidean distances between rows.

    Parameters
    ----------
    a_m : (N, D) float64, metres
    b_m : (M, D) float64, metres, optional (defaults to ``a_m``)

    Returns
    -------
    (N, M) float64, metres
    """
    a_m = np.asarray(a_m, dtype=float)
    b_m = a_m if b_m is None else np.asarray(b_m, dtype=float)
    diff = a_m[:, None, :] - b_m[None, :, :]  # (N,1,D) - (1,M,D) -> (N,M,D)
    return np.sqrt(np.einsum("nmd,nmd->nm", diff, diff))


def neighbour_pairs(pos_m: np.ndarray, range_m: float) -> np.ndarray:
    """All unordered pairs (i < j) with ``|x_i - x_j| <= range_m``, as a (P, 2) int array.

    Uses a KD-tree (O(N log N + P)); the inclusive inequality is re-checked exactly.
    """
    pos_m = np.asarray(pos_m, dtype=float)
    if len(pos_m) < 2:
        return np.empty((0, 2), dtype=np.intp)
    pairs = neighbour_candidates(pos_m, range_m)
    if len(pairs) == 0:
        return np.empty((0, 2), dtype=np.intp)
    fast = _graph_kernels.pairs_within(pos_m, pairs, range_m)
    if fast is not None:  # the two lines below in one compiled pass, the same bits
        return fast.astype(np.intp, copy=False)
    return _recheck_pairs(pos_m, pairs, range_m)


def neighbour_candidates(pos_m: np.ndarray, range_m: float) -> np.ndarray:
    """The KD-tree's pairs (i < j) within ``range_m`` plus a relative and absolute 1e-9, in the
    tree's order, as (P, 2) int: a superset of :func:`neighbour_pairs`, which keeps those with
    ``|x_i - x_j| <= range_m`` exactly, in this order. ``pos_m``: (N, D) float64, N >= 2."""
    return cKDTree(pos_m).query_pairs(range_m * (1 + _KD_SLACK) + _KD_SLACK, output_type="ndarray")


def _recheck_pairs(pos_m: np.ndarray, pairs: np.ndarray, range_m: float) -> np.ndarray:
    """The pairs within ``range_m`` by NumPy (the reference of
    :func:`planner._graph_kernels.pairs_within`)."""
    d = np.linalg.norm(pos_m[pairs[:, 0]] - pos_m[pairs[:, 1]], axis=1)
    return pairs[d <= range_m].astype(np.intp)


def radio_pairs(pos_m: np.ndarray, range_m: float, ordered: bool = True) -> np.ndarray:
    """The pairs of :func:`neighbour_pairs` (the same set: the same inclusive test on the same
    distance), sorted by (i, j); for callers to whom the order does not matter (connectivity, the
    message hop). Compiled grid search (:func:`planner._kernels.grid_pairs`) when available and
    the swarm's bounding box holds at most a few cells per drone; else :func:`neighbour_pairs`
    (the reference, whose pair order is the KD-tree's). ``ordered=False``: the same set in no
    particular order (each pair still i < j), for callers that take maxima over the pairs.
    """
    pos_m = np.asarray(pos_m, dtype=float)
    n = len(pos_m)
    if (
        n < 2
        or not (_kernels.NUMBA and _kernels.ENABLED)
        or not np.isfinite(range_m)
        or range_m <= 0
    ):
        return neighbour_pairs(pos_m, range_m)
    if pos_m.ndim != 2 or pos_m.shape[1] != 2 or not np.isfinite(pos_m).all():
        return neighbour_pairs(pos_m, range_m)
    lo = pos_m.min(axis=0)
    hi = pos_m.max(axis=0)
    cell = float(range_m) * (1 + 1e-6)  # > range: a pair within range lies in adjacent cells
    nx = int((hi[0] - lo[0]) // cell) + 1
    ny = int((hi[1] - lo[1]) // cell) + 1
    if nx * ny > 8 * n + 4096:  # a sparse spread: the KD-tree is the better index
        return neighbour_pairs(pos_m, range_m)
    return _kernels.grid_pairs(
        np.ascontiguousarray(pos_m[:, 0]),
        np.ascontiguousarray(pos_m[:, 1]),
        float(range_m),
        cell,
        float(lo[0]),
        float(lo[1]),
        nx,
        ny,
        bool(ordered),
    ).astype(np.intp, copy=False)


def active_mask(
    pos_m: np.ndarray,
    alive: np.ndarray,
    radio_range_m: float,
    base_range_m: float,
    base_m: np.ndarray | None = None,
) -> np.ndarray:
    """Drones connected to the base through a chain of alive drones (the paper's a_i).

    a_i = alive_i and (|x_i - b| <= min(R, r) or exists active j with |x_i - x_j| <= r).
    Computed exactly as the connected component of the base in the graph of alive drones.

    Parameters
    ----------
    pos_m : (N, D) float64, metres
    alive : (N,) bool
    radio_range_m : float, r
    base_range_m : float, R
    base_m : (D,) float64, optional; the base position (origin by default)

    Returns
    -------
    (N,) bool

    Notes
    -----
    Small swarms: breadth-first search from the base over the KD-tree's neighbour pairs, one
    vectorised frontier expansion per hop (scipy.sparse's per-call validation dominated there).
    Large swarms: scipy's connected components in C (faster once there are thousands of links).
    """
    pos_m = np.asarray(pos_m, dtype=float)
    alive = np.asarray(alive, dtype=bool)
    n = len(pos_m)
    out = np.zeros(n, dtype=bool)
    idx = np.flatnonzero(alive)
    if len(idx) == 0:
        return out
    p = pos_m[idx]
    base = np.zeros(p.shape[1]) if base_m is None else np.asarray(base_m, dtype=float)
    reached = np.linalg.norm(p - base, axis=1) <= min(base_range_m, radio_range_m)
    if not reached.any():
        return out
    fast = _graph_kernels.reach_from(p, reached, radio_range_m)
    if fast is not None:  # a grid breadth-first search, no pair list (the same set)
        out[idx] = fast
        return out
    pairs = radio_pairs(p, radio_range_m)  # the order of the pairs does not matter here
    if len(p) > _BFS_MAX_DRONES:
        k = len(p)  # node k is the base, linked to every drone within its reach
        at_base = np.flatnonzero(reached)
        rows = np.concatenate([pairs[:, 0], np.full(len(at_base), k)])
        cols = np.concatenate([pairs[:, 1], at_base])
        graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(k + 1, k + 1))
        _, labels = connected_components(graph, directed=False)
        out[idx] = labels[:k] == labels[k]
        return out
    if len(pairs):
        src = np.concatenate([pairs[:, 0], pairs[:, 1]])
        dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
        order = np.argsort(src, kind="stable")
        src, dst = src[order], dst[order]
        start = np.searchsorted(src, np.arange(len(p)))
        stop = np.searchsorted(src, np.arange(len(p)), side="right")
        frontier = np.flatnonzero(reached)
        while len(frontier):
            # all neighbours of the frontier, by CSR slices gathered at once
            counts = stop[frontier] - start[frontier]
            if not counts.sum():
                break
            offsets = np.repeat(start[frontier] - np.cumsum(counts) + counts, counts) + np.arange(
                counts.sum()
            )
            nbrs = dst[offsets]
            new = np.unique(nbrs[~reached[nbrs]])
            reached[new] = True
            frontier = new
    out[idx] = reached
    return out


def active_mask_reference(
    pos_m: npt.ArrayLike,
    alive: np.ndarray,
    radio_range_m: float,
    base_range_m: float,
    base_m: npt.ArrayLike | None = None,
) -> np.ndarray:
    """Slow, obviously-correct fixed point of the paper's recursive definition (for tests)."""
    pos_m = np.asarray(pos_m, dtype=float)
    n = len(pos_m)
    base = np.zeros(pos_m.shape[1]) if base_m is None else np.asarray(base_m, dtype=float)
    active = [
        bool(alive[i])
        and float(np.linalg.norm(pos_m[i] - base)) <= min(base_range_m, radio_range_m)
        for i in range(n)
    ]
    changed = True
    while changed:
        changed = False
        for i in range(n):
            if active[i] or not alive[i]:
                continue
            for j in range(n):
                if active[j] and float(np.linalg.norm(pos_m[i] - pos_m[j])) <= radio_range_m:
                    active[i] = changed = True
                    break
    return np.array(active, dtype=bool)


def tasks_connected(
    task_pos_m: np.ndarray, drone_pos_m: np.ndarray, active: np.ndarray, radio_range_m: float
) -> np.ndarray:
    """A_i(t): task i has an active drone strictly within r.

    Parameters
    ----------
    task_pos_m : (M, D) float64, metres (a non-finite row is an unknown task: never connected)
    drone_pos_m : (N, D) float64, metres
    active : (N,) bool
    radio_range_m : float

    Returns
    -------
    (M,) bool
    """
    task_pos_m = np.asarray(task_pos_m, dtype=float)
    act = np.asarray(drone_pos_m, dtype=float)[np.asarray(active, dtype=bool)]
    if len(act) == 0 or len(task_pos_m) == 0:
        return np.zeros(len(task_pos_m), dtype=bool)
    known = np.isfinite(task_pos_m).all(axis=1)
    if not known.all():  # a task whose position is unknown (NaN: a stale crew) is not connected
        out = np.zeros(len(task_pos_m), dtype=bool)
        out[known] = tasks_connected(task_pos_m[known], drone_pos_m, active, radio_range_m)
        return out
    fast = _graph_kernels.any_within(task_pos_m, act, radio_range_m)
    if fast is not None:  # brute force, compiled: the same distance, no KD-tree per tick
        return fast
    d, _ = cKDTree(act).query(task_pos_m, k=1)
    return d < radio_range_m


def step_toward(pos_m: np.ndarray, target_m: np.ndarray, max_step_m: float) -> np.ndarray:
    """Displacements that move each row straight toward ``target_m`` by at most ``max_step_m``,
    never overshooting it (the RTNUA "fly home at constant speed" rule).

    Parameters
    ----------
    pos_m : (N, D) positions
    target_m : (D,) or (N, D) targets
    max_step_m : float, the largest displacement
    """
    to_target = np.asarray(target_m, dtype=float) - np.asarray(pos_m, dtype=float)
    dist = np.linalg.norm(to_target, axis=-1)
    return to_target * (np.minimum(max_step_m, dist) / np.where(dist > 0, dist, 1.0))[..., None]


def geodetic_to_ned_m(
    lat_deg: npt.ArrayLike,
    lon_deg: npt.ArrayLike,
    alt_amsl_m: npt.ArrayLike,
    origin_lat_deg: float,
    origin_lon_deg: float,
    origin_alt_amsl_m: float,
) -> np.ndarray:
    """WGS-84 geodetic to local NED metres around an origin (pymap3d, exact ellipsoid).

    Returns an (..., 3) array (north, east, down).
    """
    n, e, d = pymap3d.geodetic2ned(
        lat_deg, lon_deg, alt_amsl_m, origin_lat_deg, origin_lon_deg, origin_alt_amsl_m
    )
    return np.stack(np.broadcast_arrays(n, e, d), axis=-1).astype(float)


def ned_to_geodetic(
    ned_m: npt.ArrayLike, origin_lat_deg: float, origin_lon_deg: float, origin_alt_amsl_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local NED metres around an origin to (lat_deg, lon_deg, alt_amsl_m)."""
    ned_m = np.asarray(ned_m, dtype=float)
    lat, lon, alt = pymap3d.ned2geodetic(
        ned_m[..., NORTH],
        ned_m[..., EAST],
        ned_m[..., DOWN],
        origin_lat_deg,
        origin_lon_deg,
        origin_alt_amsl_m,
    )
    return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float), np.asarray(alt, dtype=float)

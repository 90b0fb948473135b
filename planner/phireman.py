"""PhiIREMAN: potential-field gradient descent around a semi-Steiner task tree.

Energy of drone i (paper, Sec. "Swarm Dynamics"; docs/design/model.md §5.1):

    E_i = Þ h_T(x_i) - ℳ sum_{j != i} 1 / max(|x_i - x_j|, d_min) + P/2 sum_{|x_i - x_j| < q_i + q_j} (q_i + q_j - |x_i - x_j|)^2

Each control tick the controller takes several gradient steps on the motion instructions and stops
at equilibrium, after ``max_descent_steps``, or when an instruction would exceed the speed limit
(docs/design/model.md §5.2, §9.3). All maths runs in *paper length units* (positions divided by
``problem.length_unit_m``), so the coefficients Þ, ℳ, P are scale-free; instructions are returned in
metres.

Two information models (``info``, planner.info):

* ``central``: one planner sees every networked drone and descends the total energy jointly (the
  ground station's view).
* ``async``: the paper's message passing (planner.knowledge): drone i plans from its own table of
  neighbour reports and its own copy of the base-computed tree, descending its energy with respect
  to its own instruction while the believed neighbours stay put; a drone whose tree copy is older
  than ``tree_stale_steps`` heads for the base.

Paper units and the conversions are planner.units.

This module is over ~600 lines because the descent, its reference transcriptions and the gradient
kernels it runs (each with the NumPy reference of a compiled twin) are read together; the planner
class itself is short.

Modelling choices that are inferences, not statements of the paper, are named parameters with the
defaults of :class:`PhiremanParams` (the only place they are defined).

References
----------
J. S. Kent, E. Stefani, B. Plancher, "Robust Geospatial Coordination of Multi-Agent Communications
Networks Under Attrition", IEEE RA-L 2026, arXiv:2512.02079.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np

from planner import _kernels
from planner.info import (
    PAPER_INFO,
    CentralView,
    MessageView,
    check_info,
    check_speed_rule,
    information_model,
    resolve_speed_rule,
)
from planner.methods import PlanOutput, TickInput
from planner.problem import ProblemConfig
from planner.steiner import TaskTree, distance_to_tree, maintain_task_tree
from planner.units import PaperUnits

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

__all__ = [
    "PhiremanParams",
    "PhiremanPlanner",
    "DescentResult",
    "task_gradient",
    "task_gradient_batched",
    "padded_segments",
    "TreeSegments",
    "pair_gradient",
    "pair_gradient_reference",
    "pair_gradient_entries",
    "descend",
    "descend_reference",
    "energy",
    "parse_params",
    "make_phireman",
    "make_phireman_central",
    "make_phireman_no_task",
    "make_phireman_nodes_only",
]

#: A gradient for :func:`descend`: ``(x, rows) -> (len(rows), 2)``.
Gradient = Callable[[np.ndarray, np.ndarray], np.ndarray]

#: Four arrays: per-entry (rows, a, ab, |ab|^2) or per-drone (a, ab, |ab|^2, valid) segments.
_Arrays4 = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

#: The entry columns of :func:`planner._kernels.entries_segment_gradient`: er, a_x, a_y, ab_x, ab_y, |ab|^2.
_Columns = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]

ParamsT = TypeVar("ParamsT", bound="DataclassInstance")


@dataclass(frozen=True)
class PhiremanParams:
    """Every PhiIREMAN parameter and its default (lengths in paper units, 1 unit = r / 2)."""

    thorn: float = 0.05
    """Þ, weight of the task-tree potential (paper default 0.05)."""
    attraction: float = 0.05
    """ℳ, weight of the gravity-like attraction between drones (paper default 0.05)."""
    repulsion: float = 0.3
    """P, stiffness of the elastic repulsion (paper default 0.3)."""
    repulsion_radius_ratio: float = 0.5
    """q_i = ratio * r_i ("nominally r_i / 2", paper)."""
    attraction_floor: float = 0.5
    """d_min, paper units: attraction evaluated as -ℳ / max(d, d_min) (docs/design/model.md §9.2)."""
    pair_factor: float = 2.0
    """c: 2 = gradient of the total energy (each pair counted in E_i and E_j), 1 = own energy."""
    step_size: float = 0.2
    """η, gradient step (paper units per unit force); grid-searched over 0.1 / 0.2 / 0.3 at S / 1 %
    (docs/tuning/phireman_S_1pct.md)."""
    max_descent_steps: int = 10
    """K_max, gradient steps per tick; grid-searched (tune)."""
    tolerance: float = 1e-3
    """Equilibrium: stop when every drone's step is below this, paper units."""
    speed_rule: str = "auto"
    """At the speed limit: 'uniform' scales the last step so the fastest drone moves exactly v and
    stops the descent (docs/design/model.md §9.3; needs one planner for all drones); 'per_drone' does that
    per drone and lets the others continue, each drone also stopping at its own equilibrium (what
    independent drones can do); 'clip' clips each drone to v and keeps iterating.
    'auto' = 'uniform' for central, 'per_drone' for async (planner.info.resolve_speed_rule)."""
    base_weight: float = 1.0
    """c_b, weight of the task-to-base path lengths in the tree cost (paper default 1.0)."""
    accept_ratio: float = 0.99
    """ν, a periodic rebuild is accepted only if cost_new < ν cost_current (paper 0.99)."""
    rebuild_period: int = 10
    """Ticks between full tree rebuilds (Steiner points are refined every tick)."""
    nodes_only: bool = False
    """Ablation: h_T is the distance to the nearest tree node instead of the nearest segment."""
    info: str = PAPER_INFO
    """'async' (paper's message passing) or 'central' (one planner sees D'(t)); planner.info."""
    age_max_steps: int = 3
    """Async: forget neighbour reports older than this many steps (grid-searched at S / 1 %,
    docs/tuning/phireman_S_1pct.md: 3 beats 5 and 10 — stale reports of lost drones attract)."""
    dist_max: float = 6.0
    """Async: forget neighbour reports farther than this, paper units (3 r)."""
    tree_stale_steps: int = 15
    """Async: a drone whose tree copy is older than this assumes disconnection and heads home."""
    broadcast_after_move: bool = True
    """Async: a drone broadcasts at the end of its step, after moving, so its neighbours receive
    where it is at the next step (False: at the start, so they see it one move late). The paper's
    "broadcasts ... received in the subsequent timestep" admits both; chosen at S / 1 %
    (docs/tuning/phireman_messages_S_1pct.md)."""
    forget_unheard: bool = True
    """Async: drop a neighbour believed within radio range but not heard in the last delivery
    (a mesh radio's neighbour timeout); chosen at S / 1 % with ``broadcast_after_move``."""

    def __post_init__(self) -> None:
        check_speed_rule(self.speed_rule)
        check_info(self.info)
        for name in (
            "step_size",
            "tolerance",
            "repulsion_radius_ratio",
            "accept_ratio",
            "dist_max",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("max_descent_steps", "rebuild_period", "age_max_steps", "tree_stale_steps"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


def parse_params(params: Mapping[str, Any], cls: type[ParamsT], **forced: Any) -> ParamsT:
    """Build a ``cls`` params dataclass from a mapping (strings are parsed as the field's type),
    rejecting unknown keys with the list of valid ones; ``forced`` values override ``params``."""
    valid = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(params) - set(valid))
    if unknown:
        raise ValueError(f"unknown parameter(s) {', '.join(unknown)}; valid: {', '.join(valid)}")
    kwargs: dict[str, Any] = {}
    for key, value in {**params, **forced}.items():
        default = valid[key].default
        kwargs[key] = (
            type(default)(value)
            if isinstance(default, (bool, int, float)) and not isinstance(value, str)
            else value
        )
        if isinstance(default, bool) and isinstance(value, str):
            kwargs[key] = value.lower() in ("1", "true", "yes", "on")
        elif isinstance(default, (int, float)) and isinstance(value, str):
            kwargs[key] = type(default)(float(value)) if isinstance(default, int) else float(value)
    return cls(**kwargs)


# --------------------------------------------------------------------------------------------
# Gradient terms (paper units). Each returns (n, 2).
# --------------------------------------------------------------------------------------------


def task_gradient(
    pos_u: np.ndarray, tree: TaskTree, thorn: float, nodes_only: bool = False
) -> np.ndarray:
    """∇ of Þ h_T(x): Þ times the unit vector from the nearest tree point to x (0 on the tree)."""
    if thorn == 0.0 or len(pos_u) == 0:
        return np.zeros_like(pos_u)
    dist, nearest = distance_to_tree(pos_u, tree, nodes_only=nodes_only)
    away = pos_u - nearest
    return thorn * away / np.where(dist > 1e-12, dist, np.inf)[:, None]


def padded_segments(
    trees: list[TaskTree], nodes_only: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stack the segments of several trees, padded: (V, E, 2) ends a and b and a (V, E) validity mask.

    With ``nodes_only`` (or a single-node tree) each node becomes a zero-length segment, so the
    nearest "segment" is the nearest node.
    """
    parts = []
    for tree in trees:
        if nodes_only or tree.n_nodes == 1:
            parts.append((tree.nodes_m, tree.nodes_m))
        else:
            parts.append(tree.segments())
    e_max = max(len(a) for a, _ in parts)
    seg_a = np.zeros((len(parts), e_max, 2))
    seg_b = np.zeros((len(parts), e_max, 2))
    valid = np.zeros((len(parts), e_max), dtype=bool)
    for v, (a, b) in enumerate(parts):  # loop over tree versions (a handful), not drones
        seg_a[v, : len(a)], seg_b[v, : len(b)], valid[v, : len(a)] = a, b, True
    return seg_a, seg_b, valid


def task_gradient_batched(
    pos_u: np.ndarray,
    seg_a: np.ndarray,
    seg_b: np.ndarray,
    valid: np.ndarray,
    version: np.ndarray,
    thorn: float,
) -> np.ndarray:
    """:func:`task_gradient` for drones that hold different tree versions, in one pass.

    Parameters
    ----------
    pos_u : (n, 2) positions
    seg_a, seg_b, valid : from :func:`padded_segments`, (V, E, 2), (V, E, 2), (V, E)
    version : (n,) int, which tree each drone holds (row of ``seg_a``)
    thorn : Þ
    """
    if thorn == 0.0 or len(pos_u) == 0:
        return np.zeros_like(pos_u)
    a, b, ok = seg_a[version], seg_b[version], valid[version]  # (n,E,2), (n,E,2), (n,E)
    ab = b - a
    ab2 = np.einsum("nec,nec->ne", ab, ab)
    ap = pos_u[:, None, :] - a  # (n,1,2) - (n,E,2) -> (n,E,2)
    t = np.clip(
        np.divide(np.einsum("nec,nec->ne", ap, ab), ab2, out=np.zeros_like(ab2), where=ab2 > 0),
        0,
        1,
    )
    foot = a + t[:, :, None] * ab
    off = pos_u[:, None, :] - foot
    d2 = np.where(ok, np.einsum("nec,nec->ne", off, off), np.inf)
    best = np.argmin(d2, axis=1)
    away = off[np.arange(len(pos_u)), best]
    dist = np.sqrt(d2[np.arange(len(pos_u)), best])
    return thorn * away / np.where(dist > 1e-12, dist, np.inf)[:, None]


class TreeSegments:
    """Each drone's tree segments, prepared once per tick for :func:`task_gradient_batched`.

    :meth:`gradient` equals ``task_gradient_batched(pos_u, *padded_segments(trees), version, Þ)``
    bit for bit (the same element-wise operations on the same values, the same first-minimum rule)
    but gathers the per-drone segments and computes ab and |ab|^2 once per tick instead of at every
    descent step.

    With ``pos0`` and ``radius`` (every later query of drone i lies within ``radius`` of
    ``pos0[i]``: a tick's descent never moves a drone farther than v), only the segments that can
    be nearest are kept: with D_s the distance to segment s and m0 = min_s D_s(pos0),
    |D_s(x) - D_s(pos0)| <= radius, so a segment with D_s(pos0) > m0 + 2 radius is never the
    nearest (nor tied with it). The kept ones stay in segment order, so the first minimum is the
    same. A few segments per drone instead of the whole tree (~200 at XL).

    Parameters
    ----------
    trees : the tree versions held by drones
    version : (n,) int, which tree each drone holds
    nodes_only : as :func:`padded_segments`
    pos0 : (n, 2), optional, the drones' positions at the start of the tick
    radius : how far from ``pos0`` the queries may lie
    """

    def __init__(
        self,
        trees: list[TaskTree],
        version: np.ndarray,
        nodes_only: bool = False,
        pos0: np.ndarray | None = None,
        radius: float = 0.0,
    ) -> None:
        seg_a, seg_b, valid = padded_segments(trees, nodes_only)
        self.n = len(version)
        self.entries: _Arrays4 | None = None
        self._columns: _Columns | None = None
        self._dense: _Arrays4 | None = None
        self._padded = (seg_a, seg_b, valid, np.asarray(version))
        if pos0 is not None and self.n and _kernels.NUMBA and _kernels.ENABLED:
            # Compiled pruning, the same candidates as the NumPy lines below (test_kernels.py);
            # per tree version, not per drone: ab and |ab|^2 of the V versions, gathered per entry.
            ab_v = seg_b - seg_a
            ab2_v = np.einsum("vec,vec->ve", ab_v, ab_v)
            pos0 = np.asarray(pos0, float)
            r, s = _kernels.prune_segments(
                np.ascontiguousarray(pos0[:, 0]),
                np.ascontiguousarray(pos0[:, 1]),
                np.asarray(version, np.int64),
                np.ascontiguousarray(seg_a[..., 0]),
                np.ascontiguousarray(seg_a[..., 1]),
                np.ascontiguousarray(ab_v[..., 0]),
                np.ascontiguousarray(ab_v[..., 1]),
                ab2_v,
                valid.sum(axis=1),
                2.0 * radius * (1 + 1e-9),
            )
            v = np.asarray(version)[r]
            self.entries = (r, seg_a[v, s], ab_v[v, s], ab2_v[v, s])
            return
        if pos0 is not None and self.n:
            d2 = self._d2(pos0, self.a, self.ab, self.ab2, self.valid)[1]
            dist = np.sqrt(d2)
            # generous rounding margin: distances are computed to ~1e-15 relative
            bound = dist.min(axis=1) + 2.0 * radius * (1 + 1e-9) + 1e-9 * (1.0 + dist.min(axis=1))
            r, s = np.nonzero(
                self.valid & (dist <= bound[:, None])
            )  # row-major: by drone, then segment
            self.entries = (r, self.a[r, s], self.ab[r, s], self.ab2[r, s])

    def _dense_arrays(self) -> _Arrays4:
        if self._dense is None:
            seg_a, seg_b, valid, version = self._padded
            a = seg_a[version]  # (n, E, 2)
            ab = seg_b[version] - a
            self._dense = (a, ab, np.einsum("nec,nec->ne", ab, ab), valid[version])
        return self._dense

    @property
    def a(self) -> np.ndarray:
        """(n, E, 2) each drone's segment starts (padded)."""
        return self._dense_arrays()[0]

    @property
    def ab(self) -> np.ndarray:
        """(n, E, 2) each drone's segment directions b - a."""
        return self._dense_arrays()[1]

    @property
    def ab2(self) -> np.ndarray:
        """(n, E) |b - a|^2."""
        return self._dense_arrays()[2]

    @property
    def valid(self) -> np.ndarray:
        """(n, E) bool, the segment exists (padding is False)."""
        return self._dense_arrays()[3]

    @staticmethod
    def _d2(
        pos_u: np.ndarray, a: np.ndarray, ab: np.ndarray, ab2: np.ndarray, ok: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        ap = pos_u[:, None, :] - a
        t = np.clip(
            np.divide(np.einsum("nec,nec->ne", ap, ab), ab2, out=np.zeros_like(ab2), where=ab2 > 0),
            0,
            1,
        )
        foot = a + t[:, :, None] * ab
        off = pos_u[:, None, :] - foot
        return off, np.where(ok, np.einsum("nec,nec->ne", off, off), np.inf)

    def gradient(self, pos_u: np.ndarray, rows: np.ndarray, thorn: float) -> np.ndarray:
        """(len(rows), 2) ∇ Þ h_T of drones ``rows`` at ``pos_u`` (len(rows), 2)."""
        if thorn == 0.0 or len(pos_u) == 0:
            return np.zeros_like(pos_u)
        if self.entries is not None:
            return self._gradient_entries(pos_u, rows, thorn)
        if len(rows) == self.n:
            a, ab, ab2, ok = self.a, self.ab, self.ab2, self.valid
        else:
            a, ab, ab2, ok = self.a[rows], self.ab[rows], self.ab2[rows], self.valid[rows]
        off, d2 = self._d2(pos_u, a, ab, ab2, ok)
        best = np.argmin(d2, axis=1)
        r = np.arange(len(pos_u))
        away = off[r, best]
        dist = np.sqrt(d2[r, best])
        return thorn * away / np.where(dist > 1e-12, dist, np.inf)[:, None]

    def _gradient_entries(self, pos_u: np.ndarray, rows: np.ndarray, thorn: float) -> np.ndarray:
        assert self.entries is not None  # the caller checks
        er, a, ab, ab2 = self.entries
        if len(rows) != self.n:
            chosen = np.zeros(self.n, dtype=bool)
            chosen[rows] = True
            take = chosen[er]
            er, a, ab, ab2 = (np.cumsum(chosen) - 1)[er[take]], a[take], ab[take], ab2[take]
        if _kernels.NUMBA and _kernels.ENABLED:
            # compiled twin of the NumPy lines below, bit for bit (tests/planner/test_kernels.py)
            cols: _Columns
            if self._columns is None or len(rows) != self.n:
                cols = (
                    np.asarray(er, np.int64),
                    np.ascontiguousarray(a[:, 0]),
                    np.ascontiguousarray(a[:, 1]),
                    np.ascontiguousarray(ab[:, 0]),
                    np.ascontiguousarray(ab[:, 1]),
                    np.ascontiguousarray(ab2),
                )
                if len(rows) == self.n:
                    self._columns = cols
            else:
                cols = self._columns
            pos_u = np.asarray(pos_u, float)
            return _kernels.entries_segment_gradient(
                np.ascontiguousarray(pos_u[:, 0]),
                np.ascontiguousarray(pos_u[:, 1]),
                *cols,
                len(pos_u),
                float(thorn),
            )
        return self._gradient_entries_numpy(pos_u, er, a, ab, ab2, thorn)

    @staticmethod
    def _gradient_entries_numpy(
        pos_u: np.ndarray,
        er: np.ndarray,
        a: np.ndarray,
        ab: np.ndarray,
        ab2: np.ndarray,
        thorn: float,
    ) -> np.ndarray:
        x = pos_u[er]
        ap = x - a
        t = np.clip(
            np.divide(np.einsum("ec,ec->e", ap, ab), ab2, out=np.zeros_like(ab2), where=ab2 > 0),
            0,
            1,
        )
        foot = a + t[:, None] * ab
        off = x - foot
        d2 = np.einsum("ec,ec->e", off, off)
        starts = np.flatnonzero(np.r_[True, er[1:] != er[:-1]])  # every drone has >= 1 entry
        low = np.minimum.reduceat(d2, starts)
        first = np.minimum.reduceat(np.where(d2 == low[er], np.arange(len(d2)), len(d2)), starts)
        away = off[first]
        dist = np.sqrt(d2[first])
        return thorn * away / np.where(dist > 1e-12, dist, np.inf)[:, None]


def pair_gradient(
    pos_u: np.ndarray,
    others_u: np.ndarray,
    mask: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
    others_sq: np.ndarray | None = None,
) -> np.ndarray:
    """∇ of the attraction and repulsion terms of each drone w.r.t. its own position.

    Parameters
    ----------
    pos_u : (n, 2) positions of the drones being planned, paper units
    others_u : (K, 2) positions shared by every drone (central view), or (n, K, 2) per-drone
        beliefs (async view)
    mask : (n, K) bool, which pairs interact (False for self and unknown drones)
    attraction, floor : ℳ and d_min
    repulsion, reach : P and q_i + q_j
    pair_factor : c (2 for the total energy)
    others_sq : optional |others|^2, (K,) or (n, K), when the caller reuses it across iterations

    Returns
    -------
    (n, 2): c ℳ Σ (x_i - x_j)/d^3 [d > d_min] - c P Σ (reach - d)(x_i - x_j)/d [d < reach]

    Notes
    -----
    Never materialises the (n, K, 2) difference array: with d^2 = |x|^2 + |y|^2 - 2 x.y and
    Σ_j w_ij (x_i - y_j) = x_i Σ_j w_ij - Σ_j w_ij y_j, the shared view costs two small matrix
    products and the per-drone view two passes over the beliefs. The expansion loses about
    |x|^2 eps in d^2, far below any distance that matters (cf. the reference test).
    """
    pos_u = np.asarray(pos_u, float)
    xx = np.einsum("nc,nc->n", pos_u, pos_u)
    if others_u.ndim == 2:
        yy = np.einsum("kc,kc->k", others_u, others_u) if others_sq is None else others_sq
        d2 = xx[:, None] + yy[None, :] - 2.0 * (pos_u @ others_u.T)
    else:
        yy = np.einsum("nkc,nkc->nk", others_u, others_u) if others_sq is None else others_sq
        d2 = xx[:, None] + yy - 2.0 * np.einsum("nkc,nc->nk", others_u, pos_u)
    np.maximum(d2, 0.0, out=d2)
    inv = np.zeros_like(d2)
    np.divide(1.0, np.sqrt(d2, out=np.empty_like(d2)), out=inv, where=mask & (d2 > 0))
    d = d2 * inv  # distance where the pair interacts, else 0
    coef = np.where(d > floor, attraction * inv * inv * inv, 0.0)
    coef -= np.where((d < reach) & (inv > 0), repulsion * (reach * inv - 1.0), 0.0)
    if others_u.ndim == 2:
        weighted = coef @ others_u
    else:
        weighted = np.einsum("nk,nkc->nc", coef, others_u)
    return pair_factor * (pos_u * coef.sum(axis=1)[:, None] - weighted)


def pair_gradient_entries(
    pos_u: np.ndarray,
    rows: np.ndarray,
    others_e: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
) -> np.ndarray:
    """:func:`pair_gradient` of the per-drone view from its interacting entries only.

    Parameters
    ----------
    pos_u : (n, 2) positions of the drones being planned, paper units
    rows : (E,) int, the holder of each entry (i, k) where the mask is True (any order)
    others_e : (E, 2) the believed position of entry e (``others_u[i, k]``)
    attraction, floor, repulsion, reach, pair_factor : as :func:`pair_gradient`

    Notes
    -----
    Work proportional to the entries (the async view is ~85 % masked once the swarm has spread:
    each drone hears a few dozen of the 500 at XL): the differences x_i - y_k are formed per entry
    and Σ_k coef_ik (x_i - y_k) is summed per drone by ``np.bincount``. Agrees with
    :func:`pair_gradient_reference` to rounding (the summation order differs from the dense kernel's,
    so the last bits may too).
    """
    return _pair_gradient_xy(
        pos_u,
        rows,
        others_e[:, 0],
        others_e[:, 1],
        attraction,
        floor,
        repulsion,
        reach,
        pair_factor,
    )


class _EntriesByDrone:
    """The view's entries (holder rows ``rows_e`` in row-major order, believed positions ``y_e``
    (E, 2)) grouped by holder, so that a descent can take the entries of the drones still moving.
    Coordinates are kept as two contiguous arrays, the form :func:`_pair_gradient_xy` reads."""

    def __init__(self, rows_e: np.ndarray, y_e: np.ndarray, n: int) -> None:
        self.n = n
        self.rows_e = rows_e
        # copies unless each coordinate is contiguous already (the fused knowledge update's view);
        # read only either way
        self.x, self.y = np.ascontiguousarray(y_e[:, 0]), np.ascontiguousarray(y_e[:, 1])
        self.start = np.searchsorted(rows_e, np.arange(n + 1))  # drone i's: start[i]:start[i + 1]
        self.count = np.diff(self.start)

    def of(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(holder index into ``rows``, x, y) of the entries of drones ``rows`` (sorted)."""
        if len(rows) == self.n:
            return self.rows_e, self.x, self.y
        count = self.count[rows]
        r_e = np.repeat(np.arange(len(rows)), count)
        take = np.arange(len(r_e)) + np.repeat(self.start[rows] - (np.cumsum(count) - count), count)
        return r_e, self.x[take], self.y[take]


def _pair_gradient_xy(
    pos_u: np.ndarray,
    rows: np.ndarray,
    others_x: np.ndarray,
    others_y: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
    weight: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`pair_gradient_entries` with the believed positions as two (E,) coordinate arrays;
    ``weight`` (n,), if given, scales each drone's attraction (DCCRS's density weighting).

    Runs the compiled :func:`planner._kernels.entries_pair_gradient` when available (bit for bit the same; :func:`_pair_gradient_xy_numpy` is its reference)."""
    if _kernels.NUMBA and _kernels.ENABLED:
        pos_u = np.asarray(pos_u, float)
        aw = (
            np.full(len(pos_u), float(attraction))
            if weight is None
            else attraction * np.asarray(weight, float)
        )  # the NumPy version's (ℳ w_i)
        return _kernels.entries_pair_gradient(
            np.ascontiguousarray(pos_u[:, 0]),
            np.ascontiguousarray(pos_u[:, 1]),
            np.asarray(rows, np.int64),
            np.asarray(others_x, float),
            np.asarray(others_y, float),
            len(pos_u),
            aw,
            float(floor),
            float(repulsion),
            float(reach),
            float(pair_factor),
        )
    return _pair_gradient_xy_numpy(
        pos_u, rows, others_x, others_y, attraction, floor, repulsion, reach, pair_factor, weight
    )


def _pair_gradient_xy_numpy(
    pos_u: np.ndarray,
    rows: np.ndarray,
    others_x: np.ndarray,
    others_y: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
    weight: np.ndarray | None = None,
) -> np.ndarray:
    """The NumPy version of :func:`_pair_gradient_xy` (the reference of its compiled kernel)."""
    n = len(pos_u)
    dx = pos_u[:, 0][rows] - others_x
    dy = pos_u[:, 1][rows] - others_y
    d2 = dx * dx
    d2 += dy * dy
    d = np.sqrt(d2)
    inv = np.divide(1.0, d, out=np.zeros_like(d), where=d > 0)
    coef = inv * inv
    coef *= inv
    coef *= (
        attraction if weight is None else (attraction * np.asarray(weight, float))[rows]
    )  # (w_i) ℳ / d^3, d > d_min ...
    coef[d <= floor] = 0.0
    push = np.flatnonzero(d < reach)  # ... - P (reach - d) / d where 0 < d < reach
    push = push[d[push] > 0]
    coef[push] -= repulsion * (reach * inv[push] - 1.0)
    dx *= coef
    dy *= coef
    out = np.empty((n, 2))
    out[:, 0] = np.bincount(rows, dx, minlength=n)
    out[:, 1] = np.bincount(rows, dy, minlength=n)
    out *= pair_factor
    return out


def pair_gradient_reference(
    pos_u: np.ndarray,
    others_u: np.ndarray,
    mask: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
) -> np.ndarray:
    """Loop-by-loop transcription of :func:`pair_gradient` (for tests)."""
    pos_u = np.asarray(pos_u, float)
    others_u = np.asarray(others_u, float)
    n = len(pos_u)
    if others_u.ndim == 2:
        others_u = np.broadcast_to(others_u, (n,) + others_u.shape)
    out = np.zeros((n, 2))
    for i in range(n):
        for k in range(others_u.shape[1]):
            if not mask[i, k]:
                continue
            dx = pos_u[i] - others_u[i, k]
            d = float(np.hypot(dx[0], dx[1]))
            if d == 0:
                continue
            if d > floor:
                out[i] += pair_factor * attraction * dx / d**3
            if d < reach:
                out[i] -= pair_factor * repulsion * (reach - d) * dx / d
    return out


def energy(pos_u: np.ndarray, tree: TaskTree | None, p: PhiremanParams, reach: float) -> float:
    """Total energy Σ_i E_i of drones at ``pos_u`` (central view), paper units (for tests/plots)."""
    n = len(pos_u)
    e = 0.0
    if tree is not None and p.thorn:
        e += p.thorn * distance_to_tree(pos_u, tree, nodes_only=p.nodes_only)[0].sum()
    if n > 1:
        d = np.sqrt(((pos_u[:, None] - pos_u[None]) ** 2).sum(-1))
        off = ~np.eye(n, dtype=bool)
        e += -p.attraction * (1.0 / np.maximum(d[off], p.attraction_floor)).sum()
        e += p.repulsion / 2 * (np.clip(reach - d[off], 0, None) ** 2).sum()
    return float(e)


# --------------------------------------------------------------------------------------------
# Descent
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DescentResult:
    """Outcome of one tick's descent."""

    disp_u: np.ndarray
    """(n, 2) instructions, paper units."""
    iterations: int
    """Gradient evaluations performed."""
    converged: bool
    """True only if the equilibrium test held."""
    hit_speed_limit: bool
    """True if the descent stopped (or clipped) at the speed limit."""


def _scale_to_limit(delta: np.ndarray, step: np.ndarray, vmax: float) -> np.ndarray:
    """Per row, the α in [0, 1] with |delta + α step| = vmax (|delta| <= vmax assumed)."""
    a = np.einsum("nc,nc->n", step, step)
    b = np.einsum("nc,nc->n", delta, step)
    c = np.einsum("nc,nc->n", delta, delta) - vmax**2
    disc = np.sqrt(np.maximum(b * b - a * c, 0.0))
    alpha = np.where(a > 0, (-b + disc) / np.where(a > 0, a, 1.0), 1.0)
    return np.clip(alpha, 0.0, 1.0)


class DescentParams(Protocol):
    """What :func:`descend` reads of its parameters (:class:`PhiremanParams`, DCCRS's)."""

    @property
    def step_size(self) -> float: ...
    @property
    def tolerance(self) -> float: ...
    @property
    def speed_rule(self) -> str: ...
    @property
    def max_descent_steps(self) -> int: ...


def descend(
    pos_u: np.ndarray, gradient: Gradient, vmax: float, p: DescentParams, separable: bool = False
) -> DescentResult:
    """Multi-step gradient descent on the instructions with the paper's stopping rules.

    Parameters
    ----------
    pos_u : (n, 2) start positions, paper units
    gradient : callable ``(x, rows) -> (len(rows), 2)``, the energy gradient of drones ``rows`` at
        positions ``x = pos_u + delta`` (``x`` holds every drone)
    vmax : speed limit per tick, paper units
    p : parameters (step_size, max_descent_steps, tolerance, speed_rule)
    separable : each drone's gradient depends only on its own instruction (the async model, where
        neighbours are believed positions that stay put); then drones that stopped are no longer
        evaluated, which is exact and much cheaper.
    """
    n = len(pos_u)
    delta = np.zeros((n, 2))
    moving = np.ones(n, dtype=bool)
    hit = False
    every = np.arange(n)
    for k in range(1, p.max_descent_steps + 1):
        step = np.zeros((n, 2))
        rows = np.flatnonzero(moving) if separable else every
        step[rows] = -p.step_size * gradient(pos_u + delta, rows)
        step[~moving] = 0.0
        if p.speed_rule == "per_drone":
            # Independent drones: each one's descent also ends at its own equilibrium.
            settled = moving & (np.abs(step).max(axis=1, initial=0.0) < p.tolerance)
            step[settled] = 0.0
            moving &= ~settled
            if not moving.any():
                return DescentResult(delta, k, True, hit)
        elif not n or np.max(np.abs(step)) < p.tolerance:
            return DescentResult(delta, k, True, hit)
        new = delta + step
        over = np.einsum("nc,nc->n", new, new) > vmax * vmax
        if not over.any():
            delta = new
            continue
        hit = True
        if p.speed_rule == "clip":
            norm = np.sqrt(np.einsum("nc,nc->n", new, new))
            delta = new * np.minimum(1.0, vmax / np.where(norm > 0, norm, 1.0))[:, None]
            continue
        alpha = _scale_to_limit(delta, step, vmax)
        if p.speed_rule == "uniform":
            delta = delta + alpha[over].min() * step
            return DescentResult(delta, k, False, hit)
        # per_drone: drones at the limit stop, the others keep descending
        delta = np.where(over[:, None], delta + alpha[:, None] * step, new)
        moving &= ~over
        if not moving.any():
            return DescentResult(delta, k, False, hit)
    return DescentResult(delta, p.max_descent_steps, False, hit)


def descend_reference(
    pos_u: np.ndarray, gradient: Gradient, vmax: float, p: DescentParams
) -> np.ndarray:
    """Per-drone loop version of :func:`descend` (instructions only; for tests)."""
    pos_u = np.asarray(pos_u, float)
    n = len(pos_u)
    delta = [np.zeros(2) for _ in range(n)]
    moving = [True] * n
    for _ in range(p.max_descent_steps):
        g = gradient(pos_u + np.array(delta).reshape(n, 2), np.arange(n))
        steps = [(-p.step_size * g[i]) if moving[i] else np.zeros(2) for i in range(n)]
        if p.speed_rule == "per_drone":
            for i in range(n):
                if moving[i] and float(np.max(np.abs(steps[i]))) < p.tolerance:
                    moving[i] = False
                    steps[i] = np.zeros(2)
            if not any(moving):
                break
        elif n == 0 or max(float(np.max(np.abs(s))) for s in steps) < p.tolerance:
            break
        new = [delta[i] + steps[i] for i in range(n)]
        over = [float(np.linalg.norm(new[i])) > vmax for i in range(n)]
        if not any(over):
            delta = new
            continue
        if p.speed_rule == "clip":
            delta = [
                x * min(1.0, vmax / float(np.linalg.norm(x))) if np.linalg.norm(x) > 0 else x
                for x in new
            ]
            continue

        def alpha(i: int) -> float:  # bisection: obviously correct, slow
            lo, hi = 0.0, 1.0
            for _ in range(60):
                mid = (lo + hi) / 2
                if np.linalg.norm(delta[i] + mid * steps[i]) > vmax:  # noqa: B023 - called in this iteration only
                    hi = mid
                else:
                    lo = mid
            return lo

        if p.speed_rule == "uniform":
            a = min(alpha(i) for i in range(n) if over[i])
            delta = [delta[i] + a * steps[i] for i in range(n)]
            break
        delta = [delta[i] + alpha(i) * steps[i] if over[i] else new[i] for i in range(n)]
        moving = [moving[i] and not over[i] for i in range(n)]
        if not any(moving):
            break
    return np.array(delta).reshape(n, 2)


# --------------------------------------------------------------------------------------------
# The planner
# --------------------------------------------------------------------------------------------


class PhiremanPlanner:
    """PhiIREMAN behind the registry interface (see planner.methods).

    ``params.info`` picks the information model (planner.info): ``info_model`` gives each tick the
    drones to plan and what they know; ``units`` converts metres to paper units and back.
    """

    params: PhiremanParams

    def __init__(
        self, problem: ProblemConfig, params: PhiremanParams, rng: np.random.Generator
    ) -> None:
        self.problem = problem
        self.rng = rng  # unused: PhiIREMAN is deterministic given its inputs
        self.units = PaperUnits.of(problem)
        if params.speed_rule == "auto":
            params = dataclasses.replace(
                params, speed_rule=resolve_speed_rule(params.speed_rule, params.info)
            )
        self.params = params
        self.reach_u = 2 * params.repulsion_radius_ratio * self.units.radio_range_u
        self.tree: TaskTree | None = None
        self.info_model = information_model(params.info, self.units, problem.n_steps, params)
        self.tree_transform: Callable[[TaskTree], TaskTree] | None = None
        """A map from the maintained tree to the tree the potential follows, both in metres,
        returning its argument itself when it changes nothing (planner.terrain_aware bends edges
        that relays cannot hold over terrain, docs/terrain.md §3); None: the maintained tree
        (the paper)."""

    # -- helpers --------------------------------------------------------------------------
    def _pair_grad(
        self,
        pos_u: np.ndarray,
        others_u: np.ndarray,
        mask: np.ndarray,
        others_sq: np.ndarray | None = None,
    ) -> np.ndarray:
        p = self.params
        return pair_gradient(
            pos_u,
            others_u,
            mask,
            p.attraction,
            p.attraction_floor,
            p.repulsion,
            self.reach_u,
            p.pair_factor,
            others_sq,
        )

    # -- main entry -----------------------------------------------------------------------
    def plan(self, tick: TickInput) -> PlanOutput:
        p, u = self.params, self.units
        pos_u = u.to_u(tick.pos_m)
        tasks_u = u.to_u(tick.task_pos_m)
        base_u = u.to_u(tick.base_m)
        self.tree = tree = maintain_task_tree(
            self.tree,
            base_u,
            tasks_u,
            tick.t_step,
            base_weight=p.base_weight,
            accept_ratio=p.accept_ratio,
            rebuild_period=p.rebuild_period,
        )
        if self.tree_transform is not None:
            tree_m = tree.scaled(u.unit_m)
            routed = self.tree_transform(tree_m)
            if routed is not tree_m:  # changed: back to paper units
                tree = routed.scaled(1.0 / u.unit_m)
        planning = np.asarray(tick.networked, bool) & np.asarray(tick.alive, bool)
        view = self.info_model.see(tick.t_step, pos_u, tick.alive, planning, base_u, tree)
        if isinstance(view, CentralView):
            disp_u, info = self._plan_central(pos_u, tree, view)
        else:
            disp_u, info = self._plan_async(pos_u, base_u, view)
        return PlanOutput(u.to_m(disp_u), tree=u.tree_to_m(tree), info=info)

    def _plan_central(
        self, pos_u: np.ndarray, tree: TaskTree, view: CentralView, *, compiled: bool = True
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """The networked drones descend the total energy jointly. ``compiled=False``: by the NumPy
        gradient even when the compiled one is available (it agrees to ~1e-13 m per tick, not bit
        for bit; the resilient planner's recorded runs used the NumPy one)."""
        p = self.params
        idx, disp_u = view.planned, view.disp_u
        if len(idx) == 0:
            return disp_u, view.info()
        grad: Gradient
        if compiled and _kernels.NUMBA and _kernels.ENABLED:
            # O(n) memory, compiled: the all-pairs sum without the (n, n) arrays, the tree
            # distance without the (n, E) ones (the NumPy branch below is the reference).
            if p.nodes_only or tree.n_nodes == 1:
                seg_a = seg_b = tree.nodes_m
            else:
                seg_a, seg_b = tree.segments()

            def grad(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
                task = (
                    _kernels.segment_gradient(x, seg_a, seg_b, p.thorn)
                    if p.thorn
                    else np.zeros_like(x)
                )
                return task + _kernels.central_pair_gradient(
                    x, p.attraction, p.attraction_floor, p.repulsion, self.reach_u, p.pair_factor
                )
        else:
            mask = ~np.eye(len(idx), dtype=bool)

            def grad(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
                return task_gradient(x, tree, p.thorn, p.nodes_only) + self._pair_grad(x, x, mask)

        res = descend(pos_u[idx], grad, self.units.max_step_u, p)
        disp_u[idx] = res.disp_u
        return disp_u, {"iterations": res.iterations, "converged": res.converged, **view.info()}

    def _plan_async(
        self, pos_u: np.ndarray, base_u: np.ndarray, view: MessageView
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Each fresh drone descends its own energy against its beliefs and its tree copy (the
        stale ones already head for ``base_u``)."""
        p = self.params
        idx, disp_u = view.planned, view.disp_u
        if len(idx) == 0:
            return disp_u, view.info()
        vmax_u = self.units.max_step_u
        # Only the known entries interact (pair_gradient_entries), work proportional to them.
        trees, version_of = view.broadcasts()
        segments = TreeSegments(trees, version_of, p.nodes_only, pos_u[idx], vmax_u)
        entries = _EntriesByDrone(view.rows_e, view.believed_u, len(idx))
        if (
            _kernels.NUMBA
            and _kernels.ENABLED
            and p.speed_rule == "per_drone"
            and segments.entries is not None
        ):
            # The whole descent in one compiled call, bit for bit the NumPy one below.
            res = _descend_separable_compiled(
                pos_u[idx], entries, segments, p, self.reach_u, vmax_u
            )
        else:

            def grad(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
                er, ox, oy = entries.of(rows)
                return _pair_gradient_xy(
                    x[rows],
                    er,
                    ox,
                    oy,
                    p.attraction,
                    p.attraction_floor,
                    p.repulsion,
                    self.reach_u,
                    p.pair_factor,
                ) + segments.gradient(x[rows], rows, p.thorn)

            res = descend(pos_u[idx], grad, vmax_u, p, separable=True)
        disp_u[idx] = res.disp_u
        return disp_u, {"iterations": res.iterations, "converged": res.converged, **view.info()}


def _descend_separable_compiled(
    pos_u: np.ndarray,
    entries: _EntriesByDrone,
    segments: TreeSegments,
    p: PhiremanParams,
    reach_u: float,
    vmax_u: float,
) -> DescentResult:
    """:func:`descend` (``separable=True``, 'per_drone' rule) of the async planner's gradient (pair
    term over ``entries`` + task term over ``segments``' candidate entries), by
    :func:`planner._kernels.descend_separable`; same :class:`DescentResult` bit for bit."""
    assert segments.entries is not None  # the callers check
    er, a, ab, ab2 = segments.entries
    seg_start = np.searchsorted(er, np.arange(len(pos_u) + 1))
    pos_u = np.asarray(pos_u, float)
    delta, stop, at_limit = _kernels.descend_separable(
        np.ascontiguousarray(pos_u[:, 0]),
        np.ascontiguousarray(pos_u[:, 1]),
        entries.start,
        entries.x,
        entries.y,
        seg_start,
        np.ascontiguousarray(a[:, 0]),
        np.ascontiguousarray(a[:, 1]),
        np.ascontiguousarray(ab[:, 0]),
        np.ascontiguousarray(ab[:, 1]),
        np.ascontiguousarray(ab2),
        float(p.attraction),
        float(p.attraction_floor),
        float(p.repulsion),
        float(reach_u),
        float(p.pair_factor),
        float(p.thorn),
        float(p.step_size),
        float(p.tolerance),
        float(vmax_u),
        int(p.max_descent_steps),
    )
    return _descent_result(delta, stop, at_limit, p.max_descent_steps)


def _descent_result(
    delta: np.ndarray, stop: np.ndarray, at_limit: np.ndarray, max_steps: int
) -> DescentResult:
    """The :class:`DescentResult` :func:`descend` (separable, 'per_drone') returns, from each drone's
    stopping step and cause as the compiled descents report them."""
    hit = bool(at_limit.any())
    last = int(stop.max())
    if last > max_steps:  # some drone never stopped
        return DescentResult(delta, max_steps, False, hit)
    # descend returns at the first step after which nobody moves: converged iff no drone that
    # stopped at that step stopped at the speed limit (the equilibrium test comes first)
    return DescentResult(delta, last, not bool((at_limit & (stop == last)).any()), hit)


def _make(
    problem: ProblemConfig, params: Mapping[str, Any], rng: np.random.Generator, **forced: Any
) -> PhiremanPlanner:
    return PhiremanPlanner(problem, parse_params(params, PhiremanParams, **forced), rng)


def make_phireman(
    problem: ProblemConfig, params: Mapping[str, Any], rng: np.random.Generator
) -> PhiremanPlanner:
    """PhiIREMAN with the parameters given (``info`` defaults to the paper's 'async')."""
    return _make(problem, params, rng)


def make_phireman_central(
    problem: ProblemConfig, params: Mapping[str, Any], rng: np.random.Generator
) -> PhiremanPlanner:
    """PhiIREMAN planned centrally from D'(t) (the ground station's information model)."""
    return _make(problem, params, rng, info="central")


def make_phireman_no_task(
    problem: ProblemConfig, params: Mapping[str, Any], rng: np.random.Generator
) -> PhiremanPlanner:
    """Ablation Þ = 0: no task-tree potential."""
    return _make(problem, params, rng, thorn=0.0)


def make_phireman_nodes_only(
    problem: ProblemConfig, params: Mapping[str, Any], rng: np.random.Generator
) -> PhiremanPlanner:
    """Ablation: the task potential is the distance to the nearest tree node."""
    return _make(problem, params, rng, nodes_only=True)

"""DCCRS baseline — a RECONSTRUCTION (the original DCCRS paper is not identified).

Kent et al. (RA-L 2026) compare PhiIREMAN with a flocking algorithm they call DCCRS "in the absence of
a name given in the manuscript". They describe it only as potential fields from attraction,
repulsion and velocity matching of neighbours, plus modifications for density and distance to the
leader, with tasks acting as leader drones; and they say PhiIREMAN differs from it by using a
Steiner-tree approximation instead of velocity matching and leader following. This module is the
parametric reconstruction of docs/design/model.md §3.3, i.e.

    DCCRS ≈ PhiIREMAN − task-tree potential + leader following + velocity matching
            (+ density weighting of the attraction, distance-to-leader weighting of the pull)

It is NOT the original algorithm; every report that uses it must say so (``PlanOutput.info["label"]``
carries :data:`LABEL`).

Per networked drone i at tick t (paper units, 1 unit = r / 2 at the paper's r = 2):

* N_i: drones known to i (believed positions) within r of x_i; ρ_i = |N_i| (fixed for the tick).
* Density weight w_i = clip((ρ* / max(ρ_i, 1))^β, w_min, w_max) scales i's attraction term.
* Leader potential E^L_i = k_L (d_i / r)^γ_L d_i, d_i = distance to the nearest leader (tasks, and the
  base if ``base_as_leader``), with d_i floored at ``leader_floor`` in the weight (linear continuation
  below the floor, so the pull stays finite). Its gradient is k_L (1+γ_L) (max(d,f)/r)^γ_L unit(x - y).
  γ_L = -1 makes E^L constant, i.e. no leader pull at all.
* Optional density gate ``leader_cap`` > 0: a drone that is not itself within r of its leader feels
  no leader pull when at least ``leader_cap`` other drones it knows of are already within r of it.
* Potential step: PhiIREMAN's multi-step descent (:func:`planner.phireman.descend`, same η, K_max,
  tolerance and speed rule) on w_i E^ℳ + E^P + E^L, giving δx_i^pot. The pair gradient uses
  PhiIREMAN's convention c (``pair_factor``) with drone i's own weight: c w_i ℳ Σ … − c P Σ ….
* Velocity matching: δx_i = (1 − α_v) δx_i^pot + α_v mean_{j ∈ N_i} v_j, where v_j is j's last
  executed displacement as known to i (pos(s) − pos(s−1) for i's stamp s of j; 0 if s = 0); a drone
  with no neighbours keeps δx_i^pot. Finally |δx_i| ≤ v.

Information (``info``, planner.info):

* ``async`` (default, as in the paper's comparison): PhiIREMAN's message layer
  (:class:`planner.info.MessagePassingInfo` over :class:`planner.knowledge.MessageLayer`). The
  base floods the task positions instead of a tree: drone i knows the tasks where they were at its
  flood stamp (``tasks_hist[tree_stamp[i]]``); a drone whose flood is older than
  ``tree_stale_steps`` assumes disconnection and heads for the base, as in PhiIREMAN.
* ``central``: one planner sees D'(t) with true positions, true task positions and the true
  previous displacements (for comparison).

With ``velocity_matching = 0``, ``leader_gain = 0`` and ``density_exponent = 0`` the planner reduces to
PhiIREMAN with Þ = 0 (plans equal to rounding, ~1e-12; tested tick by tick).

Defaults of the DCCRS-only parameters (γ_L = 1, α_v = 0.1, ρ* = 4, β = 0.5, base not a leader, no
cap) come from the grid search at S / 1 % recorded in docs/tuning/dccrs_S_1pct.md.

References
----------
J. S. Kent, E. Stefani, B. Plancher, "Robust Geospatial Coordination of Multi-Agent Communications
Networks Under Attrition", IEEE RA-L 2026, arXiv:2512.02079 (the only source on DCCRS).
C. W. Reynolds, "Flocks, herds and schools", SIGGRAPH 1987; R. Olfati-Saber, "Flocking for
multi-agent dynamic systems", IEEE TAC 51(3), 2006 (building blocks, not DCCRS itself).

Length (over the ~600 lines this code base aims for): the reconstruction is one algorithm whose
every term (density weight, attraction, velocity matching) sits beside its loop reference, and
its parameters and their documented provenance stay next to the code that uses them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner import _kernels, _message_kernels
from planner.info import (
    CentralView,
    MessageView,
    check_info,
    check_speed_rule,
    information_model,
    resolve_speed_rule,
)
from planner.methods import PlanOutput, TickInput
from planner.phireman import (
    DescentResult,
    PhiremanParams,
    _descent_result,
    _EntriesByDrone,
    _pair_gradient_xy,
    descend,
    parse_params,
)
from planner.problem import ProblemConfig
from planner.units import PaperUnits

__all__ = [
    "LABEL",
    "DccrsParams",
    "DccrsPlanner",
    "make_dccrs",
    "density_weight",
    "weighted_pair_gradient",
    "leader_gradient",
    "leader_gradient_reference",
    "leader_energy",
    "believed_velocities",
    "velocity_match",
    "velocity_match_reference",
    "weighted_pair_gradient_entries",
    "velocity_match_entries",
]

LABEL = "DCCRS (reconstruction, docs/design/model.md §3.3; original paper not identified)"

_PH = PhiremanParams()  # the hyper-parameters with PhiIREMAN equivalents take its defaults


@dataclass(frozen=True)
class DccrsParams:
    """Every parameter of the DCCRS reconstruction and its default (lengths in paper units).

    Shared hyper-parameters default to :class:`planner.phireman.PhiremanParams` (the paper set them
    identical to PhiIREMAN's); the DCCRS-only ones were grid-searched at S / 1 % (async), see
    docs/tuning/dccrs_S_1pct.md. This is a reconstruction, not the original DCCRS.
    """

    # --- shared with PhiIREMAN -----------------------------------------------------------
    attraction: float = _PH.attraction
    """ℳ, gravity-like attraction between drones (PhiIREMAN's)."""
    repulsion: float = _PH.repulsion
    """P, elastic repulsion stiffness (PhiIREMAN's)."""
    repulsion_radius_ratio: float = _PH.repulsion_radius_ratio
    """q_i = ratio * r_i."""
    attraction_floor: float = _PH.attraction_floor
    """d_min: attraction evaluated as -ℳ / max(d, d_min), paper units."""
    pair_factor: float = _PH.pair_factor
    """c on the pair terms (2 = PhiIREMAN's total-energy convention)."""
    step_size: float = _PH.step_size
    """η, gradient step."""
    max_descent_steps: int = _PH.max_descent_steps
    """K_max, gradient steps per tick."""
    tolerance: float = _PH.tolerance
    """Equilibrium threshold on every drone's step, paper units."""
    speed_rule: str = _PH.speed_rule
    """Speed-limit stopping rule of the descent (see planner.phireman.descend); 'auto' resolves as in
    PhiIREMAN ('uniform' for central, 'per_drone' for async)."""
    info: str = _PH.info
    """'async' (message passing) or 'central' (D'(t), true positions); planner.info."""
    age_max_steps: int = _PH.age_max_steps
    """Async: forget neighbour reports older than this many steps."""
    dist_max: float = _PH.dist_max
    """Async: forget neighbour reports farther than this, paper units."""
    tree_stale_steps: int = _PH.tree_stale_steps
    """Async: a drone whose base flood (task positions) is older than this heads home."""
    broadcast_after_move: bool = _PH.broadcast_after_move
    """Async: broadcast at the end of the step, after moving (the same message layer as PhiIREMAN)."""
    forget_unheard: bool = _PH.forget_unheard
    """Async: drop neighbours believed within range but not heard in the last delivery."""
    # --- DCCRS only (reconstruction; grid-searched) ---------------------------------------
    leader_gain: float = _PH.thorn
    """k_L, leader-following weight (PhiIREMAN's equivalent: Þ)."""
    leader_exponent: float = 1.0
    """γ_L in E^L = k_L (d/r)^γ_L d; grid {-1, -0.5, 0, 1} (-1 disables the pull); tuned 1."""
    leader_floor: float = _PH.attraction_floor
    """Distance floor (paper units) in the (d/r)^γ_L weight, keeps the pull finite for γ_L < 0."""
    density_target: float = 4.0
    """ρ*, neighbour count at which the attraction weight is 1; grid {3, 4, 6}; tuned 4."""
    density_exponent: float = 0.5
    """β in w = (ρ*/max(ρ,1))^β; grid {0.5, 1, 2}; tuned 0.5; 0 switches density weighting off."""
    density_weight_min: float = 0.25
    """Lower clip of the density weight."""
    density_weight_max: float = 4.0
    """Upper clip of the density weight."""
    velocity_matching: float = 0.1
    """α_v, share of the neighbours' mean last displacement in the instruction; grid {0.1, 0.3, 0.5};
    tuned 0.1."""
    base_as_leader: bool = False
    """Treat the base as an extra static leader (docs/design/model.md §3.3 item 7; faithful default: no; the
    search found +0.4 pp TU1 for True, well inside the noise)."""
    leader_cap: int = 0
    """Density gate: > 0 = no leader pull for a drone outside r of its leader once this many known
    drones are within r of that leader; 0 = off."""

    def __post_init__(self) -> None:
        check_speed_rule(self.speed_rule)
        check_info(self.info)
        for name in (
            "step_size",
            "tolerance",
            "repulsion_radius_ratio",
            "dist_max",
            "leader_floor",
            "density_weight_min",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("max_descent_steps", "age_max_steps", "tree_stale_steps"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not self.density_weight_min <= self.density_weight_max:
            raise ValueError(
                "density_weight_min must be <= density_weight_max, got "
                f"{self.density_weight_min} > {self.density_weight_max}"
            )
        if not 0.0 <= self.velocity_matching <= 1.0:
            raise ValueError(f"velocity_matching must be in [0, 1], got {self.velocity_matching}")
        if self.leader_exponent < -1.0:
            raise ValueError(
                f"leader_exponent must be >= -1 (E^L must not decrease with distance), "
                f"got {self.leader_exponent}"
            )
        if (
            self.density_target < 0
            or self.density_exponent < 0
            or self.leader_gain < 0
            or self.leader_cap < 0
        ):
            raise ValueError(
                "density_target, density_exponent, leader_gain and leader_cap must be >= 0"
            )


# --------------------------------------------------------------------------------------------
# Kernels (paper units). All vectorised over drones; references loop, for tests.
# --------------------------------------------------------------------------------------------


def density_weight(
    rho: np.ndarray, target: float, exponent: float, w_min: float, w_max: float
) -> np.ndarray:
    """w = clip((ρ* / max(ρ, 1))^β, w_min, w_max), per drone."""
    rho = np.maximum(np.asarray(rho, float), 1.0)
    return np.clip((target / rho) ** exponent, w_min, w_max)


def weighted_pair_gradient(
    pos_u: np.ndarray,
    others_u: np.ndarray,
    mask: np.ndarray,
    weight: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
) -> np.ndarray:
    """:func:`planner.phireman.pair_gradient` with drone i's attraction scaled by ``weight[i]``.

    Returns (n, 2): c w_i ℳ Σ (x_i - x_j)/d^3 [d > d_min] - c P Σ (reach - d)(x_i - x_j)/d [d < reach].
    Identical to ``pair_gradient`` (same operations) when ``weight`` is all ones.
    """
    diff = pos_u[:, None, :] - others_u
    d2 = np.einsum("nkc,nkc->nk", diff, diff)
    d = np.sqrt(d2)
    pull = mask & (d > floor)
    push = mask & (d < reach) & (d > 0)
    att = np.broadcast_to((attraction * np.asarray(weight, float))[:, None], d.shape)
    coef = np.divide(att, d * d2, out=np.zeros_like(d), where=pull)
    coef -= np.divide(repulsion * (reach - d), d, out=np.zeros_like(d), where=push)
    return pair_factor * np.einsum("nk,nkc->nc", coef, diff)


def weighted_pair_gradient_entries(
    pos_u: np.ndarray,
    rows: np.ndarray,
    others_e: np.ndarray,
    weight: np.ndarray,
    attraction: float,
    floor: float,
    repulsion: float,
    reach: float,
    pair_factor: float,
) -> np.ndarray:
    """:func:`weighted_pair_gradient` from the interacting entries of the per-drone view only.

    Parameters
    ----------
    pos_u : (n, 2) positions of the drones being planned
    rows : (E,) int, the holder of each True entry of the mask, entries in row-major order
    others_e : (E, 2) the believed position of each entry
    weight : (n,) density weights

    Notes
    -----
    Work proportional to the entries (the repulsion term only where 0 < d < reach); Σ_k coef_ik
    (x_i - y_k) is summed per drone by ``np.bincount``. Agrees with the dense kernel and the loops
    to rounding (not bit for bit: 1/d^3 is formed as (1/d)^3).
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
        weight=weight,
    )


def _leader_distances(pos_u: np.ndarray, leaders_u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) distance to the nearest leader (the first on ties) and (n, 2) the offset x - y to it;
    ``leaders_u`` (n, L, 2). The square root is taken of the nearest only."""
    diff = pos_u[:, None, :] - leaders_u  # (n, L, 2)
    d2 = np.einsum("nlc,nlc->nl", diff, diff)
    k = np.argmin(d2, axis=1)
    rows = np.arange(len(pos_u))
    return np.sqrt(d2[rows, k]), diff[rows, k]


def leader_gradient(
    pos_u: np.ndarray,
    leaders_u: np.ndarray,
    gain: np.ndarray,
    exponent: float,
    r: float,
    floor: float,
) -> np.ndarray:
    """∇ of E^L = k_L (d/r)^γ d toward the nearest leader, d floored at ``floor`` in the weight.

    Parameters
    ----------
    pos_u : (n, 2) drone positions
    leaders_u : (n, L, 2) each drone's leader positions, or (L, 2) shared; L >= 1
    gain : k_L, scalar or (n,) (0 switches a drone's pull off)
    exponent, r, floor : γ_L, the radio range and the distance floor (paper units)

    Returns
    -------
    (n, 2): k_L (1+γ) (max(d, f)/r)^γ (x - y)/d, 0 where d = 0.
    """
    n = len(pos_u)
    if n == 0 or np.all(np.asarray(gain) == 0) or exponent == -1.0:
        return np.zeros((n, 2))
    leaders_u = np.broadcast_to(leaders_u, (n,) + np.shape(leaders_u)[-2:])
    d, away = _leader_distances(pos_u, leaders_u)
    mag = np.asarray(gain, float) * (1.0 + exponent) * (np.maximum(d, floor) / r) ** exponent
    return away * np.divide(mag, d, out=np.zeros_like(d), where=d > 0)[:, None]


def leader_gradient_reference(
    pos_u: np.ndarray,
    leaders_u: np.ndarray,
    gain: np.ndarray,
    exponent: float,
    r: float,
    floor: float,
) -> np.ndarray:
    """Loop version of :func:`leader_gradient` (for tests)."""
    pos_u = np.asarray(pos_u, float)
    n = len(pos_u)
    leaders_u = np.broadcast_to(np.asarray(leaders_u, float), (n,) + np.shape(leaders_u)[-2:])
    gain = np.broadcast_to(np.asarray(gain, float), (n,))
    out = np.zeros((n, 2))
    for i in range(n):
        best, y = np.inf, None
        for k in range(leaders_u.shape[1]):
            dk = float(np.hypot(*(pos_u[i] - leaders_u[i, k])))
            if dk < best:
                best, y = dk, leaders_u[i, k]
        if best == 0:
            continue
        mag = gain[i] * (1 + exponent) * (max(best, floor) / r) ** exponent
        out[i] = mag * (pos_u[i] - y) / best
    return out


def leader_energy(
    pos_u: np.ndarray,
    leaders_u: np.ndarray,
    gain: np.ndarray,
    exponent: float,
    r: float,
    floor: float,
) -> np.ndarray:
    """(n,) E^L_i: k_L (d/r)^γ d for d >= f, continued linearly with the slope at f below it."""
    pos_u = np.asarray(pos_u, float)
    n = len(pos_u)
    leaders_u = np.broadcast_to(np.asarray(leaders_u, float), (n,) + np.shape(leaders_u)[-2:])
    d, _ = _leader_distances(pos_u, leaders_u)
    gain = np.asarray(gain, float)
    above = gain * (np.maximum(d, floor) / r) ** exponent * np.maximum(d, floor)
    below = gain * (1 + exponent) * (floor / r) ** exponent * (d - floor)
    return np.where(d >= floor, above, above + below)


def believed_velocities(
    stamp: np.ndarray, pos_hist: np.ndarray, cols: np.ndarray | None = None
) -> np.ndarray:
    """(n, K, 2): v_k as known to i, pos_hist[s, c_k] - pos_hist[s-1, c_k] with s = stamp[i, k].

    ``cols`` (K,) maps the columns of ``stamp`` to drone ids (default: column k is drone k). 0 where
    the stamp is unknown (< 0) or s = 0 (no displacement executed yet).
    """
    k = (np.arange(stamp.shape[1]) if cols is None else np.asarray(cols))[None, :]
    s = np.where(stamp >= 1, stamp, 1)
    vel = pos_hist[s, k] - pos_hist[s - 1, k]
    return np.where((stamp >= 1)[..., None], vel, 0.0)


def velocity_match(
    disp_pot_u: np.ndarray, neighbours: np.ndarray, vel_u: np.ndarray, alpha: float, vmax: float
) -> np.ndarray:
    """δx_i = (1-α) δx_i^pot + α mean_{j ∈ N_i} v_j (δx_i^pot if N_i is empty), clipped to |δx_i| <= v.

    Parameters
    ----------
    disp_pot_u : (n, 2) potential-field instructions
    neighbours : (n, K) bool, N_i (known and within r)
    vel_u : (n, K, 2) velocities of the K drones as known to each i
    """
    count = neighbours.sum(axis=1)
    total = np.einsum("nk,nkc->nc", neighbours.astype(float), vel_u)
    mean = total / np.maximum(count, 1)[:, None]
    out = np.where((count > 0)[:, None], (1.0 - alpha) * disp_pot_u + alpha * mean, disp_pot_u)
    norm = np.sqrt(np.einsum("nc,nc->n", out, out))
    return out * np.minimum(1.0, vmax / np.where(norm > 0, norm, 1.0))[:, None]


def velocity_match_entries(
    disp_pot_u: np.ndarray, rows: np.ndarray, vel_e: np.ndarray, alpha: float, vmax: float
) -> np.ndarray:
    """:func:`velocity_match` with N_i given as entries: ``rows`` (E,) the holder of each neighbour
    entry (row-major order) and ``vel_e`` (E, 2) its velocity. Bit-identical to the dense kernel
    (the neighbour sum is accumulated in column order, as einsum does)."""
    n = len(disp_pot_u)
    count = np.bincount(rows, minlength=n)
    total = np.empty((n, 2))
    total[:, 0] = np.bincount(rows, vel_e[:, 0], minlength=n)
    total[:, 1] = np.bincount(rows, vel_e[:, 1], minlength=n)
    mean = total / np.maximum(count, 1)[:, None]
    out = np.where((count > 0)[:, None], (1.0 - alpha) * disp_pot_u + alpha * mean, disp_pot_u)
    norm = np.sqrt(np.einsum("nc,nc->n", out, out))
    return out * np.minimum(1.0, vmax / np.where(norm > 0, norm, 1.0))[:, None]


def velocity_match_reference(
    disp_pot_u: np.ndarray, neighbours: np.ndarray, vel_u: np.ndarray, alpha: float, vmax: float
) -> np.ndarray:
    """Loop version of :func:`velocity_match` (for tests)."""
    n = len(disp_pot_u)
    out = np.zeros((n, 2))
    for i in range(n):
        js = [j for j in range(neighbours.shape[1]) if neighbours[i, j]]
        x = np.array(disp_pot_u[i], float)
        if js:
            x = (1 - alpha) * x + alpha * sum(vel_u[i, j] for j in js) / len(js)
        norm = float(np.hypot(*x))
        out[i] = x * vmax / norm if norm > vmax else x
    return out


# --------------------------------------------------------------------------------------------
# The planner
# --------------------------------------------------------------------------------------------


class DccrsPlanner:
    """DCCRS baseline — reconstruction of docs/design/model.md §3.3 (original paper not identified).

    Flocking (attraction with density weighting, repulsion, velocity matching) plus leader following
    toward the nearest task; no task tree. Same message layer and descent as PhiIREMAN.
    """

    def __init__(
        self, problem: ProblemConfig, params: DccrsParams, rng: np.random.Generator
    ) -> None:
        self.problem = problem
        self.rng = rng  # unused: deterministic given its inputs
        self.units = PaperUnits.of(problem)
        if params.speed_rule == "auto":  # as PhiIREMAN: one joint stop (central), per drone (async)
            params = dataclasses.replace(
                params, speed_rule=resolve_speed_rule(params.speed_rule, params.info)
            )
        self.params = params
        self.r_u = self.units.radio_range_u
        self.vmax_u = self.units.max_step_u
        self.reach_u = 2 * params.repulsion_radius_ratio * self.r_u
        self.info_model = information_model(params.info, self.units, problem.n_steps, params)

    # -- shared pieces ----------------------------------------------------------------------
    def _leaders(self, tasks_u: np.ndarray, base_u: np.ndarray) -> np.ndarray:
        """(…, L, 2): tasks, plus the base if ``base_as_leader``."""
        if not self.params.base_as_leader:
            return tasks_u
        base = np.broadcast_to(base_u, tasks_u.shape[:-2] + (1, 2))
        return np.concatenate([tasks_u, base], axis=-2)

    def _descend(
        self,
        pos_u: np.ndarray,
        others_u: np.ndarray,
        mask: np.ndarray,
        leaders_u: np.ndarray,
        joint: bool,
    ) -> tuple[DescentResult, np.ndarray, np.ndarray]:
        """Density weights, leader gate and the potential descent; returns (result, N_i, weights).

        ``joint``: the others are the planned drones themselves and move with the iterate (central,
        total energy); otherwise they are fixed beliefs (async, as in PhiIREMAN).
        """
        p = self.params
        diff = pos_u[:, None, :] - others_u
        near = mask & (np.einsum("nkc,nkc->nk", diff, diff) <= self.r_u**2)  # N_i
        rho = near.sum(axis=1)
        weight = density_weight(
            rho, p.density_target, p.density_exponent, p.density_weight_min, p.density_weight_max
        )

        def claims(
            y: np.ndarray,
        ) -> np.ndarray:  # known neighbours within r of each drone's leader point y
            dy = others_u - y[:, None, :]
            return (mask & (np.einsum("nkc,nkc->nk", dy, dy) <= self.r_u**2)).sum(axis=1)

        gain = self._leader_gain(pos_u, leaders_u, claims)

        def grad(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
            if joint:  # central: every drone, the others move with the iterate
                return weighted_pair_gradient(
                    x,
                    x[None, :, :],
                    mask,
                    weight,
                    p.attraction,
                    p.attraction_floor,
                    p.repulsion,
                    self.reach_u,
                    p.pair_factor,
                ) + leader_gradient(x, leaders_u, gain, p.leader_exponent, self.r_u, p.leader_floor)
            lead = leaders_u if leaders_u.ndim == 2 else leaders_u[rows]
            return weighted_pair_gradient(
                x[rows],
                others_u[rows],
                mask[rows],
                weight[rows],
                p.attraction,
                p.attraction_floor,
                p.repulsion,
                self.reach_u,
                p.pair_factor,
            ) + leader_gradient(
                x[rows], lead, gain[rows], p.leader_exponent, self.r_u, p.leader_floor
            )

        res = descend(pos_u, grad, self.vmax_u, p, separable=not joint)
        return res, near, weight

    def _leader_gain(
        self, pos_u: np.ndarray, leaders_u: np.ndarray, claims: Callable[[np.ndarray], np.ndarray]
    ) -> np.ndarray:
        """(n,) leader-following gain: 0 for a drone farther than r from its leader whose leader
        point already has ``leader_cap`` known neighbours (``claims(y)`` counts them)."""
        p = self.params
        n = len(pos_u)
        gain = np.full(n, p.leader_gain)
        if p.leader_cap > 0 and p.leader_gain > 0 and n:
            lead = np.broadcast_to(leaders_u, (n,) + leaders_u.shape[-2:])
            d, away = _leader_distances(pos_u, lead)
            claim = claims(pos_u - away)  # each drone's leader
            gain[(d > self.r_u) & (claim >= p.leader_cap)] = 0.0
        return gain

    def _descend_entries(
        self, pos_u: np.ndarray, er: np.ndarray, y_e: np.ndarray, leaders_u: np.ndarray
    ) -> tuple[DescentResult, np.ndarray, np.ndarray]:
        """:meth:`_descend` (async, fixed beliefs) from the known entries of the view: ``er`` (E,)
        holder rows in row-major order, ``y_e`` (E, 2) believed positions; leaders (n, L, 2).
        Returns (result, boolean over entries marking N_i, weights). Agrees with the dense one to rounding."""
        p = self.params
        n = len(pos_u)
        r2 = self.r_u**2
        fast = _message_kernels.near_counts(pos_u, y_e, er, True, r2)
        if fast is not None:  # the two lines below in one compiled pass (the same bits)
            near_e, rho = fast
        else:
            diff = pos_u[er] - y_e
            near_e = np.einsum("ec,ec->e", diff, diff) <= r2  # N_i, as entries
            rho = np.bincount(er[near_e], minlength=n)
        weight = density_weight(
            rho, p.density_target, p.density_exponent, p.density_weight_min, p.density_weight_max
        )

        def claims(y: np.ndarray) -> np.ndarray:  # the same count over the entries
            counted = _message_kernels.near_counts(y, y_e, er, False, r2)
            if counted is not None:
                return counted[1]
            dy = y_e - y[er]
            return np.bincount(er[np.einsum("ec,ec->e", dy, dy) <= r2], minlength=n)

        gain = self._leader_gain(pos_u, leaders_u, claims)

        entries = _EntriesByDrone(er, y_e, n)
        if (
            _kernels.NUMBA
            and _kernels.ENABLED
            and p.speed_rule == "per_drone"
            and n
            and leaders_u.shape[-2] >= 1
        ):
            # the whole descent compiled, bit for bit the NumPy one below (tests/planner/test_kernels.py)
            lead = np.broadcast_to(leaders_u, (n,) + leaders_u.shape[-2:])
            pos_u = np.asarray(pos_u, float)
            delta, stop, at_limit = _kernels.descend_separable_leader(
                np.ascontiguousarray(pos_u[:, 0]),
                np.ascontiguousarray(pos_u[:, 1]),
                entries.start,
                entries.x,
                entries.y,
                p.attraction * np.asarray(weight, float),
                np.ascontiguousarray(lead[..., 0]),
                np.ascontiguousarray(lead[..., 1]),
                np.asarray(gain, float),
                float(p.leader_exponent),
                float(self.r_u),
                float(p.leader_floor),
                float(p.attraction_floor),
                float(p.repulsion),
                float(self.reach_u),
                float(p.pair_factor),
                float(p.step_size),
                float(p.tolerance),
                float(self.vmax_u),
                int(p.max_descent_steps),
            )
            return _descent_result(delta, stop, at_limit, p.max_descent_steps), near_e, weight

        def grad(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
            lead = leaders_u if leaders_u.ndim == 2 else leaders_u[rows]
            r_e, ox, oy = entries.of(rows)
            return _pair_gradient_xy(
                x[rows],
                r_e,
                ox,
                oy,
                p.attraction,
                p.attraction_floor,
                p.repulsion,
                self.reach_u,
                p.pair_factor,
                weight=weight[rows],
            ) + leader_gradient(
                x[rows], lead, gain[rows], p.leader_exponent, self.r_u, p.leader_floor
            )

        res = descend(pos_u, grad, self.vmax_u, p, separable=True)
        return res, near_e, weight

    # -- main entry -----------------------------------------------------------------------
    def plan(self, tick: TickInput) -> PlanOutput:
        u = self.units
        pos_u = u.to_u(tick.pos_m)
        tasks_u = u.to_u(tick.task_pos_m)
        base_u = u.to_u(tick.base_m)
        planning = np.asarray(tick.networked, bool) & np.asarray(tick.alive, bool)
        # The base broadcasts the task positions it sees (in place of PhiIREMAN's tree).
        view = self.info_model.see(tick.t_step, pos_u, tick.alive, planning, base_u, tasks_u)
        if isinstance(view, CentralView):
            disp_u, info = self._plan_central(pos_u, tasks_u, base_u, view)
        else:
            disp_u, info = self._plan_async(pos_u, base_u, view)
        info["label"] = LABEL
        return PlanOutput(u.to_m(disp_u), tree=None, info=info)

    def _plan_central(
        self, pos_u: np.ndarray, tasks_u: np.ndarray, base_u: np.ndarray, view: CentralView
    ) -> tuple[np.ndarray, dict[str, Any]]:
        p = self.params
        idx, disp_u = view.planned, view.disp_u
        if len(idx) == 0:
            return disp_u, view.info()
        x = pos_u[idx]
        mask = ~np.eye(len(idx), dtype=bool)
        leaders = self._leaders(tasks_u, base_u)
        res, near, weight = self._descend(x, x[None, :, :], mask, leaders, joint=True)
        # true executed displacements t-1 -> t
        vel = (pos_u - view.prev_pos_u)[idx] if view.prev_pos_u is not None else np.zeros_like(x)
        disp_u[idx] = velocity_match(
            res.disp_u,
            near,
            np.broadcast_to(vel, (len(idx),) + vel.shape),
            p.velocity_matching,
            self.vmax_u,
        )
        return disp_u, {
            "iterations": res.iterations,
            "converged": res.converged,
            "mean_density_weight": float(weight.mean()),
        }

    def _plan_async(
        self, pos_u: np.ndarray, base_u: np.ndarray, view: MessageView
    ) -> tuple[np.ndarray, dict[str, Any]]:
        idx, disp_u = view.planned, view.disp_u  # stale drones already head home
        if len(idx) == 0:
            return disp_u, view.info()
        # Known entries of the view only (rows into idx, columns into the layer's columns, row-major).
        er = view.rows_e
        floods, version_of = view.broadcasts()  # the task positions each drone last received
        leaders = self._leaders(np.stack(floods)[version_of], base_u)
        res, near_e, weight = self._descend_entries(pos_u[idx], er, view.believed_u, leaders)
        disp_u[idx] = self._velocity_match(view, res.disp_u, near_e)
        return disp_u, {
            "iterations": res.iterations,
            "converged": res.converged,
            **view.info(),
            "mean_density_weight": float(weight.mean()),
        }

    def _velocity_match(
        self, view: MessageView, disp_pot_u: np.ndarray, near_e: np.ndarray
    ) -> np.ndarray:
        """:func:`velocity_match_entries` over the ``near_e`` entries of the view, each with the
        last displacement its holder believes of its drone."""
        p = self.params
        er, ek = view.rows_e, view.cols_e
        stamps_e = view.entry_stamps() if p.velocity_matching > 0 else None
        kn = view.layer.knowledge
        if stamps_e is not None and kn.cols is not None:
            # the lines below in one compiled pass, the stamps read from the entries instead of
            # searched, the same bits (tests/planner/test_dccrs.py); None without Numba
            fast = _message_kernels.velocity_match_near(
                disp_pot_u,
                er,
                near_e,
                stamps_e,
                kn.cols,
                ek,
                kn.pos_hist_m,
                p.velocity_matching,
                self.vmax_u,
            )
            if fast is not None:
                return fast
        nr = er[near_e]
        if p.velocity_matching > 0:
            vel = view.believed_displacement_u(view.planned[nr], ek[near_e])
            return velocity_match_entries(disp_pot_u, nr, vel, p.velocity_matching, self.vmax_u)
        return velocity_match_entries(disp_pot_u, nr, np.zeros((len(nr), 2)), 0.0, self.vmax_u)


def make_dccrs(
    problem: ProblemConfig, params: dict[str, Any], rng: np.random.Generator
) -> DccrsPlanner:
    """The DCCRS reconstruction (docs/design/model.md §3.3) with the parameters given (``info`` default 'async')."""
    return DccrsPlanner(problem, parse_params(params, DccrsParams), rng)

"""MCCST baseline: minimum connectivity-constraint spanning tree + CBF-QP (Luo, Yi, Sycara 2020).

Each tick, with perfect and instantaneous knowledge (the RTNUA paper's "cheating" MCCST), the
planner (docs/design/model.md §2.4):

1. takes the networked drones A = D'(t) and the base station b (a fixed node, u_b = 0);
2. gives drones tasks (``'balanced'``: at most ``task_capacity`` drones per task, default
   ceil(|A| / m), an exact assignment on drone-task distances with every task replicated
   ``capacity`` times; or ``'nearest'``), either once per run ("pre-tasked agents", the default)
   or every ``reassign_period`` ticks; a drone's subgroup is its task, the base is a subgroup of its
   own, untasked drones form another;
3. computes nominal controls u_hat_i = sat_v(k_p (y_task(i) - x_i)) (0 for untasked drones);
4. weighs every candidate edge of the communication graph of A + {b} (drone-drone |x_i - x_j| <= r,
   drone-base |x_i - b| <= min(R, r), the paper's inclusive inequality) by w_ij = -delta_ij with

       delta_ij = -2 (x_i - x_j)^T (u_hat_i - u_hat_j) + gamma (r_c^2 - d_ij^2)^3,

   divided by ``subgroup_factor`` when i and j are in different subgroups, and takes the minimum
   spanning tree (the MCCST: the N - 1 pairwise constraints with the most slack under the nominal
   controls);
5. filters the nominal controls through a CBF-QP over all u_i, i in A::

       min  sum_i |u_i - u_hat_i|^2 + slack_penalty * sum_e s_e^2
                                    + collision_slack_penalty * sum_c s_c^2
       s.t. 2 (x_i - x_j)^T (u_i - u_j) <= gamma (r_c^2 - d_ij^2)^3 + s_e    every tree edge
            -2 (x_i - x_j)^T (u_i - u_j) <= gamma (d_ij^2 - D_s^2)^3 + s_c   near pairs
            |u_ik| <= v / sqrt(2) per axis,   s >= 0

   (base edges constrain u_i only). Near pairs are those with d < D_s + 2v (farther pairs cannot
   reach D_s within a tick), limited to each drone's ``collision_neighbours`` nearest: without the
   cap the scaled-XL start (500 drones on a ring of radius 1 paper unit) gives 30,000 rows and
   OSQP needs ~20 s; with it, ~2,400 rows. Slacks exist only on rows whose barrier is already
   violated (right side < 0: a tree edge longer than r_c, e.g. right after a relay is lost, or a
   pair closer than D_s); every other row holds at u = 0, so the QP is always feasible
   (:func:`solve_cbf_qp`). With ``discrete_time=True`` both class-K functions gamma h^3 become the
   linear alpha h, i.e. (grad h . u) dt >= -alpha h.

Calibration (docs/tuning/mccst_calibration.md). The paper (Kent et al.) does not say how its
MCCST was tasked or tuned, only that its agents are "pre-tasked", that it has no attrition
anticipation or recovery (Table I) and that its parameters were grid-searched at S / 1 %. The
defaults of :class:`MccstParams` are a *calibration of this underspecified baseline against the
paper's reported MCCST numbers* (Table II, XS / S / M at 0, 1 and 2 % attrition, 20 seeds each),
not a derivation: among the variants tried, the smallest mean absolute error to the paper's TU1 and
TU2 (2.6 points, 16 of 18 values within 5 points; the previous default: 11.5 points, 4 of 18)
comes from

* static pre-tasking: the assignment is solved once, at a run's first tick, and a drone keeps its
  task until it is lost (``reassign_period=0``);
* one tasked drone per task (``task_capacity=1``); every other drone is an untasked relay that
  only moves when the tree barriers drag it;
* no recovery of tasks: a drone that leaves D' loses its task and rejoins as a relay
  (``keep_task_when_disconnected=False``);
* the authors' barrier gain taken literally, gamma = 1e4, with r_c = 0.95 r: the barrier binds only
  at the very edge of r_c, so one-tick overshoot breaks some tree links;
* a slow proportional go-to-task law, k_p = 0.02 per tick.

Those choices make MCCST weaker on purpose. The strongest variant found, ``STRONG_PARAMS``
(one drone per task re-chosen every tick, gamma = 1, kappa = 0.9, k_p = 1), scores above the
paper's MCCST in every configuration of the calibration set, and above the paper's PhiIREMAN at
S / 1 % (TU1 84.5, against 56.1 for the paper's MCCST and 80.8 for its PhiIREMAN).
``BALANCED_PARAMS`` is the pre-calibration default (every drone tasked, balanced assignment every
tick; S / 1 %: TU1 81.2). Report which variant was run.

Units. The planner works in *paper units*: positions are divided by ``problem.length_unit_m`` and
time is counted in ticks (one tick = ``problem.dt_s``), so u is a displacement per tick and
v = max_speed_m_s * dt_s / length_unit_m (0.15 in every preset). gamma is then in
1 / (paper length^4 * tick) and the defaults of :class:`MccstParams` hold for every size of the
scaled reading (docs/design/model.md §2.2: the authors' gamma = 1e4 in Robotarium metres and seconds maps
to gamma ~ 1 here; the calibrated default uses 1e4 unscaled). Outputs are converted back to
metres.

Radius margin (this guarantee holds for ``BALANCED_PARAMS`` / ``STRONG_PARAMS``, not for the
calibrated default, whose gamma = 1e4 and kappa = 0.95 deliberately give it up). Links exist up to
r (inclusive) but the barrier uses r_c = kappa * r (base:
kappa * min(R, r)). The CBF bounds only the first-order change of d^2 (by gamma h^3); the
second-order term |u_i - u_j|^2 <= (2v)^2 comes on top: d'^2 <= d^2 + gamma h^3 + 4 v^2. With
kappa = 0.9, r = 2, v = 0.15 and gamma <= 1 (so that gamma h^3 <= h wherever the speed bound does
not already keep d + 2v <= r_c) this gives d' <= 1.83 for d <= r_c, and d' <= 1.93 < r for a tree
edge that enters the tick anywhere in (r_c, r]. So every tree edge whose row needed no slack is
still a link after the move, and the tree keeps D' connected. Larger gamma trades that guarantee
for faster motion near r_c.

Why PIQP (default) or OSQP, called directly. The QP has 2|A| control variables plus one slack
per violated row and |A| + (#collision pairs) barrier rows: about 1000 variables and 2,500 barrier
rows for 500 drones, with a very sparse constraint matrix (each row touches at most two drones).
scipy's SLSQP and trust-constr work with dense Jacobians and Hessians (O(n^2) memory, O(n^3)
factorisations per iteration), which at this size costs seconds per tick; cvxpy would add a
canonicalisation pass per tick for no gain, because the matrices change every tick anyway. The
matrices are assembled with numpy index arrays (no Python loop over drones or edges) and each tick
is set up from scratch (the sparsity pattern changes with the tree and the collision pairs).

* PIQP (proximal interior point, sparse LDL^T; BSD-2, maintained, wheels for every platform) is
  the default since 2026-12-02: ~15 factorisations per tick whatever the conditioning, and the
  solution is the QP's optimum to ~1e-3 paper units. The slack penalties make this objective
  ~1e9 at a dense start, which leaves OSQP's ADMM, at eps 1e-4 after 100-500 iterations, up to
  ~0.15 paper units (more than a box width) from the optimum; measured on dumped XL ticks PIQP
  is 2-6x faster as well, after dropping rows that cannot bind (:func:`_solve_piqp`).
* OSQP (``solver='osqp'``, the solver of the earlier table rows) is kept for comparison and to
  reproduce those rows: warm-started at the clipped nominal controls, with ADMM's step size rho
  carried between ticks (``carry_rho``: the value OSQP's adaptive rule reached at the previous
  tick, ~3x fewer iterations at XL).

A PIQP solve is a pure function of its QP; an OSQP solve with ``carry_rho`` also depends on the
previous tick's.

If the solver does not return ``solved`` (OSQP's ``solved inaccurate`` is accepted and reported),
the planner falls back to the nominal controls clipped to the speed bound and says so in
``PlanOutput.info``. The final displacement is always clipped to |disp_i| <= v * dt in metres.

References
----------
W. Luo, S. Yi, K. Sycara, "Behavior Mixing with Minimum Global and Subgroup Connectivity
Maintenance for Large-Scale Multi-Robot Systems", ICRA 2020, pp. 9845-9851. Authors' MATLAB code:
ChendiDotLin/Online_Connectivity-aware_MultiRobot_Deployment (GetGraphWeight.m,
create_con_barrier_certificate.m). docs/design/model.md §2.

Size: ~1,230 lines, above the ~600 guideline: one method with its calibration notes, each step as a
testable function and the reference versions of the compiled paths (spanning tree, collision
pairs, constraint matrix) next to them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from collections.abc import Callable
from typing import Any

import numpy as np
import osqp
import piqp
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix, csc_matrix
from scipy.sparse.csgraph import minimum_spanning_tree
from scipy.spatial import cKDTree

from planner import _graph_kernels
from planner.geometry import neighbour_candidates, neighbour_pairs
from planner.methods import PlanOutput, TickInput
from planner.problem import ProblemConfig

__all__ = [
    "BALANCED_PARAMS",
    "STRONG_PARAMS",
    "MccstParams",
    "MccstPlanner",
    "make_mccst",
    "assign_tasks",
    "nominal_controls",
    "candidate_edges",
    "edge_slack",
    "collision_candidates",
    "spanning_tree_edges",
    "solve_cbf_qp",
    "QpResult",
]

ASSIGNMENT_RULES = ("balanced", "nearest")
SPEED_BOUNDS = ("box", "clip", "none")

#: Overrides that give the pre-calibration default: every networked drone tasked by a balanced
#: assignment re-solved each tick, gamma = 1 (rescaled), kappa = 0.9, saturated k_p = 1. The CBF
#: guarantee of the module docstring holds. Scores far above the paper's MCCST under attrition.
BALANCED_PARAMS: dict[str, Any] = {
    "reassign_period": 1,
    "task_capacity": 0,
    "keep_task_when_disconnected": True,
    "gamma": 1.0,
    "kappa": 0.9,
    "k_p": 1.0,
}

#: Overrides for the strongest variant found (best TU1 and TU2 on the calibration set): one drone
#: per task, re-chosen every tick (an implicit attrition recovery), every other drone an untasked
#: relay; gamma = 1, kappa = 0.9, k_p = 1. Beats the paper's PhiIREMAN at S / 1 %.
STRONG_PARAMS: dict[str, Any] = {**BALANCED_PARAMS, "task_capacity": 1}

#: OSQP statuses whose primal solution is used; anything else triggers the nominal fallback.
_ACCEPTED_STATUSES = ("solved", "solved inaccurate")
QP_SOLVERS = ("piqp", "osqp")


@dataclass(frozen=True)
class MccstParams:
    """Every MCCST hyper-parameter and its default (lengths in paper units, time in ticks)."""

    gamma: float = 1e4
    """CBF gain of the cubic class-K function gamma * h^3, 1 / (paper length^4 * tick). Calibrated
    default 1e4: the authors' value taken literally (docs/tuning/mccst_calibration.md); with it the
    barrier only binds within a few hundredths of r_c and one-tick overshoot can break tree links.
    ~1 is the authors' 1e4 rescaled to RTNUA units (docs/design/model.md §2.2) and, with kappa = 0.9, keeps
    every slack-free tree link within r (module docstring; ``BALANCED_PARAMS``)."""
    kappa: float = 0.95
    """Barrier radius as a fraction of the link radius: r_c = kappa * r (base: kappa * min(R, r)).
    Calibrated default 0.95; 0.9 is the margin that absorbs one-tick overshoot for gamma <= 1."""
    safety_radius: float = 0.5
    """Collision barrier radius D_s, paper units (RTNUA has no collisions; grid {0.1, 0.5, 1})."""
    k_p: float = 0.02
    """Nominal go-to-task gain, 1 / tick; u_hat = sat_v(k_p (y - x)). Calibrated default 0.02: the
    law saturates only beyond v / k_p = 7.5 paper units, i.e. a plain proportional approach with a
    ~50-tick time constant. 1 saturates until the drone is within v of its task."""
    hold_distance: float = 0.0
    """Nominal controls stop this far from the task, paper units (docs/design/model.md §2.4 step 3 allows a
    hold zone). 0 = drive onto the task point."""
    assignment: str = "balanced"
    """Subgroup rule: 'balanced' (exact, capacity ceil(|A| / m) per task) or 'nearest' task."""
    task_capacity: int = 1
    """'balanced' only: at most this many drones per task. 0: ceil(|A| / m), so every drone is
    tasked. k > 0 with k m < |A|: only k m drones are tasked (the optimal ones); the others have no
    task and hold position (u_hat = 0), moving only when the tree barriers drag them (relays)."""
    reassign_period: int = 0
    """When the task assignment is solved, in ticks. 1: every tick over the networked drones
    (attrition and task motion are absorbed: an implicit recovery mechanism). 0: once, at the
    first tick of a run, over every alive drone ("pre-tasked agents" read literally, as the
    authors' k-means subgroups are fixed up front); a drone then keeps its task until it is lost.
    K > 1: at the first tick and at every tick with t_step % K == 0, over the networked drones.
    Between solves drones keep their tasks; a networked drone without a task holds position."""
    keep_task_when_disconnected: bool = False
    """With ``reassign_period != 1``: a drone that leaves D' keeps its task when it rejoins (True)
    or loses it and, once networked again, holds position as an unassigned relay until the next
    solve (False)."""
    saturate_nominal: bool = True
    """u_hat = sat_v(k_p (y - x)) (True) or the unsaturated k_p (y - x) (False: only the QP's speed
    bound limits it, and far drones dominate the tree weights)."""
    subgroup_factor: float = 1e4
    """delta of edges between different subgroups is divided by this (authors: 1e4); 1 disables."""
    slack_penalty: float = 1e4
    """Weight of sum s^2 in the QP objective (dimensionless, relative to sum |u - u_hat|^2)."""
    collision_slack_penalty: float = 1e2
    """Weight of sum s^2 for the collision rows. Lower than ``slack_penalty`` because RTNUA has no
    collisions (the barrier only spreads the swarm) and because the dense start (all drones inside
    D_s of each other) makes these rows conflict; 1e2 cuts OSQP iterations there ~5x."""
    collision_neighbours: int = 8
    """Each drone gets collision rows with at most this many nearest drones closer than D_s + 2v
    (the union over drones is used), which bounds the rows by n * k even when the whole swarm starts
    inside D_s. 0 means no cap (every pair closer than D_s + 2v, as in the authors' code)."""
    speed_bound: str = "box"
    """'box': |u_ik| <= v / sqrt(2) per axis (authors' code; implies |u_i| <= v). 'clip': |u_ik| <= v
    in the QP, then the norm is clipped to v. 'none': no bound in the QP (the authors' default
    max_velocity = 120 m/s is never active), each drone's output is then clipped to v on its own,
    which can break a tree barrier that the QP solution satisfied."""
    discrete_time: bool = False
    """Use the linear class-K function alpha * h (discrete-time CBF) instead of gamma * h^3."""
    alpha: float = 0.5
    """Gain of the discrete-time variant, per tick, in (0, 1]: a barrier may close at most this
    fraction of its remaining margin h per tick."""
    solver: str = "piqp"
    """QP solver: 'piqp' (interior point, the default: see :func:`_solve_piqp`) or 'osqp' (ADMM,
    the solver of the table rows before 2026-12-02; ``solver_eps``, ``carry_rho`` as below)."""
    solver_eps: float = 1e-4
    """The solver's absolute and relative tolerance (PIQP: eps_abs / eps_rel; OSQP: the same names;
    constraint rows are in paper length^2 per tick). With OSQP:
    1e-3 cuts the XL QP solve ~2.3x (XL / 0 %, 6 seeds: 8.3 -> 4.8 s CPU per run) but leaves the
    controls of a median XL tick ~0.2 paper units (two box widths) from the exact optimum, against
    ~0.1 at 1e-4, and shifts paired means slightly down (S / 1 %, 100 seeds: TU1 -0.58 ± 0.54);
    not the default (docs/tuning/mccst_calibration.md §7)."""
    solver_max_iter: int = 10000
    """Iteration cap (PIQP or OSQP); hitting it is reported (and falls back to nominal controls)."""
    carry_rho: bool = True
    """Start each tick's ADMM at the step size rho that OSQP's adaptive-rho rule reached at the
    previous tick of the run (``info.rho_estimate``) instead of OSQP's default 0.1. Consecutive
    QPs differ by one tick of motion, so the adapted rho fits the next one: ~3x fewer iterations at
    XL. Both stop at the same tolerance, but ``solver_eps`` residuals leave this badly conditioned
    QP's controls up to ~0.05-0.1 paper units from the exact optimum whichever rho is used, so the
    returned point, and per-seed results, differ (100 seeds at S / 1 %, 30 at L / 1 %: mean TU1
    and TU2 within each other's 95 % CI; paired differences within 0.7 points). False: every
    tick starts at rho 0.1, the pre-carry behaviour, bit for bit (then ``plan`` is a pure
    function of its tick when ``reassign_period == 1``)."""

    def __post_init__(self) -> None:
        problems = []
        for name in (
            "gamma",
            "k_p",
            "slack_penalty",
            "collision_slack_penalty",
            "alpha",
            "solver_eps",
        ):
            if not getattr(self, name) > 0:
                problems.append(f"{name} must be > 0, got {getattr(self, name)!r}")
        if not self.alpha <= 1:
            problems.append(f"alpha must be in (0, 1], got {self.alpha!r}")
        if not 0 < self.kappa <= 1:
            problems.append(f"kappa must be in (0, 1], got {self.kappa!r}")
        if not self.hold_distance >= 0:
            problems.append(f"hold_distance must be >= 0, got {self.hold_distance!r}")
        if not self.safety_radius >= 0:
            problems.append(f"safety_radius must be >= 0, got {self.safety_radius!r}")
        if not self.subgroup_factor >= 1:
            problems.append(f"subgroup_factor must be >= 1, got {self.subgroup_factor!r}")
        if self.assignment not in ASSIGNMENT_RULES:
            problems.append(
                f"assignment must be one of {ASSIGNMENT_RULES}, got {self.assignment!r}"
            )
        if self.solver not in QP_SOLVERS:
            problems.append(f"solver must be one of {QP_SOLVERS}, got {self.solver!r}")
        if self.speed_bound not in SPEED_BOUNDS:
            problems.append(f"speed_bound must be one of {SPEED_BOUNDS}, got {self.speed_bound!r}")
        if not (isinstance(self.solver_max_iter, (int, np.integer)) and self.solver_max_iter >= 1):
            problems.append(f"solver_max_iter must be an int >= 1, got {self.solver_max_iter!r}")
        if not (isinstance(self.task_capacity, (int, np.integer)) and self.task_capacity >= 0):
            problems.append(f"task_capacity must be an int >= 0, got {self.task_capacity!r}")
        if not (isinstance(self.reassign_period, (int, np.integer)) and self.reassign_period >= 0):
            problems.append(f"reassign_period must be an int >= 0, got {self.reassign_period!r}")
        if not (
            isinstance(self.collision_neighbours, (int, np.integer))
            and self.collision_neighbours >= 0
        ):
            problems.append(
                f"collision_neighbours must be an int >= 0, got {self.collision_neighbours!r}"
            )
        if problems:
            raise ValueError("MccstParams: " + "; ".join(problems))

    @classmethod
    def from_dict(cls, params: dict[str, Any]) -> MccstParams:
        """Build from a ``params`` dict; unknown keys raise ValueError listing the valid ones."""
        valid = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(params) - set(valid))
        if unknown:
            raise ValueError(f"unknown mccst params {unknown}; valid params: {', '.join(valid)}")
        return cls(**params)


# --------------------------------------------------------------------------------------------
# One step of the method per function (each testable on its own).
# --------------------------------------------------------------------------------------------


def assign_tasks(
    pos: np.ndarray, task_pos: np.ndarray, rule: str = "balanced", capacity: int = 0
) -> np.ndarray:
    """Subgroups: the task index of every drone (-1: no task).

    Parameters
    ----------
    pos : (n, 2) float64
        Drone positions (any length unit).
    task_pos : (m, 2) float64, m >= 1
        Task positions (same unit).
    rule : {'balanced', 'nearest'}
        'balanced' minimises the total drone-task distance subject to at most ``capacity`` drones
        per task (exact: ``linear_sum_assignment`` with every task replicated ``capacity`` times);
        'nearest' picks each drone's closest task (``capacity`` is ignored).
    capacity : int
        'balanced' only. 0: ceil(n / m), so every drone gets a task. k > 0: at most k drones per
        task; if n > k m, only the k m drones of the optimal assignment get one, the rest get -1.

    Returns
    -------
    (n,) int
        Task index per drone, -1 for a drone left without one.
    """
    pos = np.asarray(pos, dtype=float)
    task_pos = np.asarray(task_pos, dtype=float)
    n, m = len(pos), len(task_pos)
    if n == 0:
        return np.zeros(0, dtype=np.intp)
    dist = np.linalg.norm(
        pos[:, None, :] - task_pos[None, :, :], axis=2
    )  # (n,1,2)-(1,m,2) -> (n,m)
    if rule == "nearest":
        return np.argmin(dist, axis=1).astype(np.intp)
    if rule != "balanced":
        raise ValueError(f"rule must be one of {ASSIGNMENT_RULES}, got {rule!r}")
    capacity = int(capacity) if capacity > 0 else -(-n // m)
    cost = np.repeat(dist, capacity, axis=1)  # column k * capacity + c is copy c of task k
    if n >= m * capacity:
        # Every column is used exactly once, so subtracting column minima keeps the optimum; it
        # makes scipy's shortest-augmenting-path solver 2-3x faster on clustered starts (500 drones
        # on the ring: ~50 ms -> ~20 ms). With n < m * capacity columns are left unused: no shift.
        cost -= cost.min(axis=0)
    rows, cols = linear_sum_assignment(cost)
    out = np.full(n, -1, dtype=np.intp)
    out[rows] = cols // capacity
    return out


def nominal_controls(
    pos: np.ndarray, goal: np.ndarray, k_p: float, speed: float, hold: float = 0.0
) -> np.ndarray:
    """u_hat_i = sat_speed(k_p (1 - hold / d_i)_+ (goal_i - x_i)), d_i = |goal_i - x_i|.

    A proportional go-to-goal law, norm-saturated, that stops on the circle of radius ``hold``
    around the goal (zero inside it); ``hold = 0`` is the plain law.

    Parameters
    ----------
    pos, goal : (n, 2) float64, paper units
    k_p : float, 1 / tick
    speed : float, paper units per tick
    hold : float, paper units

    Returns
    -------
    (n, 2) float64, paper units per tick, every row of norm <= speed.
    """
    offset = np.asarray(goal, dtype=float) - np.asarray(pos, dtype=float)
    if hold > 0:
        dist = np.linalg.norm(offset, axis=1)
        offset = offset * (np.maximum(dist - hold, 0.0) / np.maximum(dist, 1e-300))[:, None]
    return _clip_norm(k_p * offset, speed)


def candidate_edges(
    pos_m: np.ndarray, base_m: np.ndarray, radio_range_m: float, base_range_m: float
) -> np.ndarray:
    """Edges of the communication graph of the drones and the base.

    Parameters
    ----------
    pos_m : (n, 2) float64, metres
    base_m : (2,) float64, metres
    radio_range_m, base_range_m : float, metres (r and R)

    Returns
    -------
    (E, 2) int
        Pairs (i, j), i < j; j == n denotes the base. Drone links use |x_i - x_j| <= r, base links
        |x_i - b| <= min(R, r), in metres exactly as :func:`planner.geometry.active_mask` does.
    """
    n = len(pos_m)
    base_reach_m = min(base_range_m, radio_range_m)
    if n >= 2:
        raw = neighbour_candidates(pos_m, radio_range_m)
        fast = _graph_kernels.link_edges(pos_m, raw, radio_range_m, base_m, base_reach_m)
        if fast is not None:  # neighbour_pairs' re-check and the lines below in one pass
            return fast.astype(np.intp, copy=False)
    pairs = neighbour_pairs(pos_m, radio_range_m)
    at_base = np.flatnonzero(np.linalg.norm(pos_m - base_m, axis=1) <= base_reach_m)
    base_pairs = np.column_stack([at_base, np.full(len(at_base), n)])
    return np.concatenate([pairs.reshape(-1, 2), base_pairs]).astype(np.intp)


def collision_candidates(x: np.ndarray, reach: float, max_neighbours: int = 0) -> np.ndarray:
    """Drone pairs that get a collision barrier.

    Parameters
    ----------
    x : (n, 2) float64, paper units
    reach : float
        Pairs strictly closer than this (D_s + 2v: farther pairs cannot come within D_s this tick).
    max_neighbours : int
        If > 0, only each drone's ``max_neighbours`` nearest drones within ``reach`` (ties by index),
        taking the union over drones: at most n * max_neighbours pairs.

    Returns
    -------
    (C, 2) int, unique pairs i < j, sorted.
    """
    n = len(x)
    if n < 2:
        return np.zeros((0, 2), dtype=np.intp)
    if max_neighbours > 0:
        fast = _graph_kernels.knn_pairs(np.asarray(x, dtype=float), reach, max_neighbours)
        if fast is not None:
            return fast
    return _collision_candidates_reference(x, reach, max_neighbours)


def _collision_candidates_reference(
    x: np.ndarray, reach: float, max_neighbours: int = 0
) -> np.ndarray:
    """:func:`collision_candidates` by a KD-tree (the reference of the compiled grid search
    :func:`planner._graph_kernels.knn_pairs`, and the path without a cap)."""
    n = len(x)
    if n < 2:
        return np.zeros((0, 2), dtype=np.intp)
    tree = cKDTree(x)
    if max_neighbours <= 0:
        pairs = tree.query_pairs(reach, output_type="ndarray").reshape(-1, 2)
    else:
        k = min(max_neighbours + 1, n)  # +1: each drone is its own nearest point
        _, nbr = tree.query(x, k=k, distance_upper_bound=reach)
        nbr = np.asarray(nbr).reshape(n, k)
        owner = np.repeat(np.arange(n, dtype=np.int64), k)
        other = nbr.ravel().astype(np.int64)
        keep = (other < n) & (other != owner)  # missing neighbours are reported as n
        lo, hi = np.minimum(owner[keep], other[keep]), np.maximum(owner[keep], other[keep])
        key = np.unique(lo * n + hi)  # dedupe (i, j) / (j, i), sorted by (i, j)
        pairs = np.column_stack([key // n, key % n])
    pairs = pairs.astype(np.intp)
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.intp)
    d = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1)
    pairs = pairs[d < reach]
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))] if max_neighbours <= 0 else pairs


def _class_k(h: np.ndarray, params: MccstParams) -> np.ndarray:
    """The barrier's class-K function: gamma h^3 (continuous time) or alpha h (discrete time)."""
    return params.alpha * h if params.discrete_time else params.gamma * h**3


def _capped_class_k(h: np.ndarray, cap: np.ndarray, params: MccstParams) -> np.ndarray:
    """``np.minimum(_class_k(h, params), cap)`` (cap > 0), with the class-K function evaluated only
    where it may be below the cap.

    NumPy's float power (gamma h^3) costs ~25 ns an element; a row whose cheap estimate
    gamma (h h h) exceeds the cap by a relative 1e-9 (far beyond the few ulps between the two) is
    capped whatever the exact value. The power is elementwise, so evaluating it on a subset gives
    the same bits (tests/planner/test_mccst.py::test_capped_class_k_is_the_plain_minimum).
    """
    if params.discrete_time:
        return np.minimum(_class_k(h, params), cap)
    with np.errstate(over="ignore", invalid="ignore"):
        surely_capped = params.gamma * (h * h * h) > cap * (1.0 + 1e-9)  # NaN: not surely
    need = np.flatnonzero(~surely_capped)
    out = np.array(cap, dtype=float, copy=True)
    out[need] = np.minimum(_class_k(h[need], params), cap[need])
    return out


def edge_slack(
    x: np.ndarray,
    u_hat: np.ndarray,
    edges: np.ndarray,
    r_c: np.ndarray,
    subgroup: np.ndarray,
    params: MccstParams,
) -> np.ndarray:
    """delta_ij: the connectivity barrier's slack under the nominal controls (larger = safer).

    Parameters
    ----------
    x : (n + 1, 2) float64
        Node positions, paper units; row n is the base.
    u_hat : (n + 1, 2) float64
        Nominal controls, paper units per tick; row n (the base) is zero.
    edges : (E, 2) int
        Node pairs.
    r_c : (E,) float64
        Barrier radius of each edge, paper units.
    subgroup : (n + 1,) int
        Subgroup label per node (the base has its own).
    params : MccstParams

    Returns
    -------
    (E,) float64
        delta = -2 (x_i - x_j)^T (u_hat_i - u_hat_j) + K(r_c^2 - d^2), divided by
        ``subgroup_factor`` across subgroups. The MCCST edge weight is -delta.
    """
    fast = _graph_kernels.edge_terms(x, u_hat, edges, r_c, subgroup)
    if fast is not None:  # the lines below without the gathers
        h, dot, cross = fast
        class_k = _class_k(h, params)
        combined = _graph_kernels.slack_combine(dot, class_k, cross, params.subgroup_factor)
        if combined is not None:  # the two lines below in one pass
            return combined
        delta = -2.0 * dot + class_k
        return np.where(cross, delta / params.subgroup_factor, delta)
    i, j = edges[:, 0], edges[:, 1]
    diff = x[i] - x[j]
    h = r_c**2 - np.einsum("ek,ek->e", diff, diff)
    delta = -2.0 * np.einsum("ek,ek->e", diff, u_hat[i] - u_hat[j]) + _class_k(h, params)
    return np.where(subgroup[i] != subgroup[j], delta / params.subgroup_factor, delta)


def _argsort_stable(values: np.ndarray) -> np.ndarray:
    """``np.argsort(values, kind='stable')``, computed with the (SIMD) default sort when it is the
    same permutation.

    Without ties the ascending order is unique, so any sort gives it; numpy's default introsort is
    ~5x faster than its stable sort on 1e4-1e5 floats (the dense XL start has ~1e5 candidate
    edges). Ties (equal adjacent sorted values, or NaN) fall back to the stable sort, so ties stay
    broken by index exactly as before.
    """
    order = np.argsort(values)
    ranked = values[order]
    if len(ranked) > 1 and not np.all(ranked[1:] > ranked[:-1]):
        order = np.argsort(values, kind="stable")
    return order


def spanning_tree_edges(n_nodes: int, edges: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Indices of the edges of a minimum spanning tree (forest, if disconnected).

    The MST depends only on the order of the weights, so they are replaced by their ranks 1..E:
    strictly positive (scipy's sparse graphs treat 0 as "no edge" and the MCCST weights are often
    negative), exact, and tie-broken by edge index. The rank stored on each tree entry identifies
    the edge without any lookup of its orientation.

    Parameters
    ----------
    n_nodes : int
    edges : (E, 2) int, unique unordered pairs
    weights : (E,) float64

    Returns
    -------
    (T,) int, sorted indices into ``edges``; T = n_nodes - #components.

    Compiled Prim (:func:`planner._graph_kernels.mst_prim`, ~O(n^2 + E), no sort of the E
    weights) when available: under the strict order (weight, index) the forest is unique, so it is
    this exact edge set.
    """
    if len(edges) == 0:
        return np.zeros(0, dtype=np.intp)
    fast = _graph_kernels.mst_prim(n_nodes, edges, weights)
    if fast is not None:
        return fast
    return _spanning_tree_reference(n_nodes, edges, weights)


def _spanning_tree_reference(n_nodes: int, edges: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """:func:`spanning_tree_edges` by ranks and scipy's ``minimum_spanning_tree`` (the reference of
    the compiled Prim, :func:`planner._graph_kernels.mst_prim`, and its fallback)."""
    order = _argsort_stable(weights)
    rank = np.empty(len(edges), dtype=float)
    rank[order] = np.arange(1, len(edges) + 1)
    graph = coo_matrix((rank, (edges[:, 0], edges[:, 1])), shape=(n_nodes, n_nodes)).tocsr()
    tree = minimum_spanning_tree(graph)
    return np.sort(order[tree.data.astype(np.intp) - 1])


def _mst_reference(n_nodes: int, edges: np.ndarray, weights: np.ndarray) -> set[frozenset[int]]:
    """networkx's Kruskal MST on the same weights, as a set of node pairs (slow; for tests)."""
    import networkx as nx

    graph = nx.Graph()
    graph.add_nodes_from(range(n_nodes))
    for (i, j), w in zip(edges.tolist(), weights.tolist()):
        graph.add_edge(i, j, weight=w)
    return {frozenset(e) for e in nx.minimum_spanning_tree(graph, algorithm="kruskal").edges()}


@dataclass(frozen=True)
class QpResult:
    """Outcome of one CBF-QP solve."""

    u: np.ndarray
    """(n, 2) float64: filtered controls, paper units per tick (within the box bound)."""
    status: str
    """OSQP status string ('solved', 'solved inaccurate', 'maximum iterations reached', ...)."""
    used_solution: bool
    """False when the status was not accepted and ``u`` is the clipped nominal control."""
    iterations: int
    """OSQP iterations."""
    max_tree_slack: float
    """Largest connectivity-row slack (0 when every tree barrier holds), paper length^2 / tick;
    NaN after a fallback."""
    max_collision_slack: float
    """Largest collision-row slack, paper length^2 / tick; NaN after a fallback."""
    rho_estimate: float = float("nan")
    """OSQP's adapted ADMM step size at the end of the solve (to start the next tick's from)."""


def solve_cbf_qp(
    x: np.ndarray,
    u_hat: np.ndarray,
    tree: np.ndarray,
    r_c: np.ndarray,
    collision_pairs: np.ndarray,
    box: float,
    params: MccstParams,
    rho: float | None = None,
) -> QpResult:
    """Minimally modify the nominal controls so that the tree and collision barriers hold.

    Parameters
    ----------
    x : (n + 1, 2) float64
        Node positions, paper units; row n is the base (fixed, u_b = 0).
    u_hat : (n, 2) float64
        Nominal controls of the drones, paper units per tick.
    tree : (T, 2) int
        Connectivity edges to enforce (node n = base).
    r_c : (T,) float64
        Barrier radius of each tree edge.
    collision_pairs : (C, 2) int
        Drone pairs (both < n) that get a collision barrier.
    box : float
        Per-axis bound |u_ik| <= box.
    params : MccstParams
    rho : optional initial ADMM step size (default OSQP's 0.1); see ``MccstParams.carry_rho``

    Returns
    -------
    QpResult

    Notes
    -----
    Only rows whose barrier is already violated (right-hand side < 0: a tree edge longer than
    r_c, a pair closer than D_s) get a slack. Every other row is satisfied by u = 0, so u = 0 plus
    slacks equal to the violations is always feasible: the QP can never be infeasible, and it has
    2n + (#violated rows) variables instead of 2n + (#rows), which roughly halves OSQP's KKT system
    in dense swarms. A slack on a row that holds at u = 0 is never needed for feasibility.
    """
    n = len(u_hat)
    n_u = 2 * n
    n_tree, n_col = len(tree), len(collision_pairs)
    n_rows = n_tree + n_col

    fast = None
    if not params.discrete_time:
        fast = _graph_kernels.qp_rows(
            x, tree, r_c, collision_pairs, params.safety_radius, box, params.gamma
        )
    if fast is not None:  # _barrier_rows and _capped_class_k in one pass, the same bits
        i, j, coef, h, reach, cap, need = fast
        rhs = cap.copy()
        rhs[need] = np.minimum(_class_k(h[need], params), cap[need])
    else:
        i, j, coef, h, reach = _barrier_rows(x, tree, r_c, collision_pairs, box, params)
        rhs = _capped_class_k(h, reach + 1e-3, params)
    if params.solver == "piqp":
        return _solve_piqp(i, j, coef, rhs, reach, n_tree, u_hat, box, params)
    slack_rows = np.flatnonzero(rhs < 0)  # violated barriers only
    slack_is_tree = slack_rows < n_tree

    n_slack = len(slack_rows)
    a_mat = _constraint_matrix(i, j, coef, slack_rows, n)
    lower = np.concatenate([np.full(n_rows, -np.inf), np.full(n_u, -box), np.zeros(n_slack)])
    upper = np.concatenate([rhs, np.full(n_u, box), np.full(n_slack, np.inf)])
    p_mat, q_vec = _qp_objective(u_hat, slack_is_tree, params)

    solver = osqp.OSQP()
    # scaling=0: OSQP's Ruiz equilibration rescales the slack columns (P entry 2 * penalty) against
    # the control columns and then ADMM stalls whenever slacks are active: the three-link chain of
    # the tests hits 10,000 iterations with it and converges in ~200 without; the 500-drone dense
    # start needs ~250 instead of ~800. The rows are already well scaled (|coef| <= 2 r, |u| <= v).
    solver.setup(
        p_mat,
        q_vec,
        a_mat,
        lower,
        upper,
        verbose=False,
        eps_abs=params.solver_eps,
        eps_rel=params.solver_eps,
        max_iter=params.solver_max_iter,
        polishing=False,
        scaling=0,
        **({} if rho is None else {"rho": float(rho)}),
    )
    u_start = np.clip(u_hat, -box, box)
    solver.warm_start(x=np.concatenate([u_start.ravel(), -rhs[slack_rows]]))
    res = solver.solve(raise_error=False)
    status = str(res.info.status)
    if status in _ACCEPTED_STATUSES and res.x is not None and np.isfinite(res.x).all():
        u = np.clip(res.x[:n_u].reshape(n, 2), -box, box)  # absorb solver tolerance
        slack = np.maximum(res.x[n_u:], 0.0)
        return QpResult(
            u,
            status,
            True,
            int(res.info.iter),
            float(slack[slack_is_tree].max(initial=0.0)),
            float(slack[~slack_is_tree].max(initial=0.0)),
            float(res.info.rho_estimate),
        )
    return QpResult(u_start, status, False, int(res.info.iter), float("nan"), float("nan"))


def _barrier_rows(
    x: np.ndarray,
    tree: np.ndarray,
    r_c: np.ndarray,
    collision_pairs: np.ndarray,
    box: float,
    params: MccstParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The CBF-QP's barrier rows (the tree edges, then the collision pairs): their ends i, j,
    coefficients coef (R, 2), barrier values h and reach (the largest left side inside the box).
    The NumPy reference of :func:`planner._graph_kernels.qp_rows`."""
    n = len(x) - 1
    n_tree, n_col = len(tree), len(collision_pairs)
    # Barrier rows: coef_i . u_i + coef_j . u_j (- s_row) <= rhs. Tree: coef_i = 2 (x_i - x_j);
    # collision: coef_i = -2 (x_i - x_j); coef_j = -coef_i. Base ends (j == n) get no u_j entries.
    i = np.concatenate([tree[:, 0], collision_pairs[:, 0]]).astype(np.intp)
    j = np.concatenate([tree[:, 1], collision_pairs[:, 1]]).astype(np.intp)
    diff = x[i] - x[j]  # (rows, 2)
    d2 = np.einsum("ek,ek->e", diff, diff)
    sign = np.concatenate([np.ones(n_tree), -np.ones(n_col)])
    coef = 2.0 * sign[:, None] * diff  # (rows, 2)
    h = np.concatenate([r_c**2 - d2[:n_tree], d2[n_tree:] - params.safety_radius**2])
    # Under the box |u_ik| <= box a row's left side never exceeds sum |coef| * box, so capping the
    # right side there leaves the feasible set unchanged; it keeps inactive rows (gamma h^3 of a
    # short edge reaches ~30) from inflating OSQP's relative tolerance, which scales with |Ax|.
    reach = box * np.abs(coef).sum(axis=1) * np.where(j < n, 2.0, 1.0)
    return i, j, coef, h, reach


def _qp_objective(
    u_hat: np.ndarray, slack_tree: np.ndarray, params: MccstParams
) -> tuple[csc_matrix, np.ndarray]:
    """P (diagonal, CSC) and q of sum |u - u_hat|^2 + penalty sum s^2 = 1/2 z^T P z + q^T z + const,
    z = (u_0x, u_0y, ..., one slack per slacked row); ``slack_tree`` marks the tree rows' slacks."""
    n_u, n_slack = u_hat.size, len(slack_tree)
    n_var = n_u + n_slack
    penalty = np.where(slack_tree, params.slack_penalty, params.collision_slack_penalty)
    p_diag = np.concatenate([np.full(n_u, 2.0), 2.0 * penalty])
    diag_idx = np.arange(n_var + 1, dtype=np.int32)
    p_mat = _csc(p_diag, diag_idx[:-1], diag_idx, (n_var, n_var))
    return p_mat, np.concatenate([-2.0 * u_hat.ravel(), np.zeros(n_slack)])


def _solve_piqp(
    i: np.ndarray,
    j: np.ndarray,
    coef: np.ndarray,
    rhs: np.ndarray,
    reach: np.ndarray,
    n_tree: int,
    u_hat: np.ndarray,
    box: float,
    params: MccstParams,
) -> QpResult:
    """The CBF-QP of :func:`solve_cbf_qp` solved by PIQP (``params.solver == 'piqp'``).

    PIQP (Schwan, Jiang, Kuhn, Jones, "PIQP: A Proximal Interior-Point Quadratic Programming
    Solver", IEEE CDC 2023; BSD-2) is an interior-point method: ~15 sparse LDL^T factorisations
    per tick whatever the conditioning, where OSQP's ADMM needs 100-500 iterations here and still
    stops up to ~0.15 paper units (more than a box width) from the optimum, because the slack
    penalties make the objective ~1e9 and its relative tolerance loose on the controls (measured
    on dumped XL ticks: PIQP at eps 1e-6 is within ~2e-3 of a 1e-10 solve, 2-6x faster).

    Rows whose right side was capped at their reach (``rhs > reach``: the left side cannot exceed
    ``reach`` inside the box) can never bind and are dropped before the solve. That leaves the
    feasible set, hence the optimum, unchanged and removes half the rows of a typical XL tick.
    Barrier rows are one-sided (``G z <= h``); the box and s >= 0 are PIQP's native variable
    bounds.
    """
    n = len(u_hat)
    n_u = 2 * n
    fast = _graph_kernels.barrier_matrix(i, j, coef, rhs, reach, n)
    if fast is not None:  # the lines below in one pass, entry for entry
        data, indices, indptr, rows, slack_rows = fast
        g_mat = _csc(data, indices, indptr, (len(rows), n_u + len(slack_rows)))
    else:
        slack_rows = np.flatnonzero(rhs < 0)  # violated barriers only
        keep = rhs <= reach  # the others are capped, hence never active
        keep[slack_rows] = True  # violated rows (rhs < 0) always bind
        rows = np.flatnonzero(keep)
        new_row = np.cumsum(keep) - 1  # a kept row's index among the kept ones
        # The barrier rows of OSQP's matrix over the kept rows (its identity rows: PIQP's bounds).
        g_mat = _constraint_matrix(i[rows], j[rows], coef[rows], new_row[slack_rows], n, False)
    n_slack = len(slack_rows)
    slack_tree = slack_rows < n_tree
    vec = _graph_kernels.qp_vectors(
        u_hat, slack_tree, params.slack_penalty, params.collision_slack_penalty, box
    )
    if vec is not None:  # the lines below in one pass, the same arrays
        p_diag, q_vec, x_lo, x_hi = vec
        diag_idx = np.arange(n_u + n_slack + 1, dtype=np.int32)
        p_mat = _csc(p_diag, diag_idx[:-1], diag_idx, (n_u + n_slack, n_u + n_slack))
    else:
        p_mat, q_vec = _qp_objective(u_hat, slack_tree, params)
        x_lo = np.concatenate([np.full(n_u, -box), np.zeros(n_slack)])
        x_hi = np.concatenate([np.full(n_u, box), np.full(n_slack, np.inf)])

    solver = piqp.SparseSolver()
    settings = solver.settings
    settings.verbose = False
    settings.eps_abs = params.solver_eps
    settings.eps_rel = params.solver_eps
    settings.max_iter = params.solver_max_iter
    solver.setup(
        p_mat, q_vec, None, None, g_mat, np.full(len(rows), -np.inf), rhs[rows], x_lo, x_hi
    )
    status = solver.solve()
    result = solver.result
    z = result.x
    iters = int(result.info.iter)
    if status == piqp.PIQP_SOLVED and np.isfinite(z).all():
        # np.clip's value on finite entries, without its Python wrapper
        u = np.minimum(np.maximum(z[:n_u].reshape(n, 2), -box), box)
        if n_slack == 0:
            return QpResult(u, "solved", True, iters, 0.0, 0.0)
        slack = np.maximum(z[n_u:], 0.0)
        return QpResult(
            u,
            "solved",
            True,
            iters,
            float(slack[slack_tree].max(initial=0.0)),
            float(slack[~slack_tree].max(initial=0.0)),
        )
    u_start = np.clip(u_hat, -box, box)
    return QpResult(u_start, str(status), False, iters, float("nan"), float("nan"))


def _constraint_matrix(
    i: np.ndarray,
    j: np.ndarray,
    coef: np.ndarray,
    slack_rows: np.ndarray,
    n: int,
    bound_rows: bool = True,
) -> csc_matrix:
    """The CBF-QP constraint matrix, assembled directly in CSC form (sorted rows, no duplicates).

    Rows 0..R-1 are the barriers (row r: ``coef[r] . u_i - coef[r] . u_j``, the u_j part only when
    j < n, minus s on violated rows), then, with ``bound_rows``, one identity row per variable (the
    bounds: OSQP's form; PIQP takes the bounds natively and gets the R barrier rows only, the same
    entries as the first R rows of the full matrix). Variables: u_0x, u_0y, ..., u_(n-1)y, then
    one slack per entry of ``slack_rows`` (sorted). Equal, entry for entry, to the COO-built
    :func:`_constraint_matrix_reference` (its first R rows without ``bound_rows``), without
    scipy's COO-to-CSC conversion and index sort (~0.25 ms of ~1 ms per tick at M), nor its
    validation of the result (:func:`_csc`).
    """
    n_rows, n_slack = len(i), len(slack_rows)
    n_u = 2 * n
    n_var = n_u + n_slack
    extra = 1 if bound_rows else 0  # the identity entry closing each column
    j_is_drone = j < n
    rows = np.arange(n_rows)
    # Barrier entries of the drone columns, sorted by (drone, row): a node is never both ends of
    # a row, so within a drone the rows are distinct.
    node = np.concatenate([i, j[j_is_drone]])
    row = np.concatenate([rows, rows[j_is_drone]])
    val = np.concatenate([coef, -coef[j_is_drone]])  # (entries, 2): x and y columns
    order = np.argsort(node.astype(np.int64) * max(n_rows, 1) + row)
    node, row, val = node[order], row[order], val[order]
    per_drone = np.bincount(node, minlength=n)
    # Column 2d + k holds drone d's barrier rows, then (bound_rows) its bound row n_rows + 2d + k.
    nnz = np.concatenate([np.repeat(per_drone + extra, 2), np.full(n_slack, 1 + extra)])
    indptr = np.zeros(n_var + 1, dtype=np.int64)
    np.cumsum(nnz, out=indptr[1:])
    indices = np.empty(indptr[-1], dtype=np.int64)
    data = np.empty(indptr[-1])
    rank = np.arange(len(node)) - (np.cumsum(per_drone) - per_drone)[node]
    for k in range(2):  # the two axes, not drones
        at = indptr[2 * node + k] + rank
        indices[at] = row
        data[at] = val[:, k]
    slack_start = indptr[n_u:n_var]
    indices[slack_start] = slack_rows  # -s on its violated row
    data[slack_start] = -1.0
    if bound_rows:
        ctrl_end = indptr[1 : n_u + 1] - 1  # last entry of each drone column
        indices[ctrl_end] = n_rows + np.arange(n_u)
        data[ctrl_end] = 1.0
        indices[slack_start + 1] = n_rows + n_u + np.arange(n_slack)
        data[slack_start + 1] = 1.0
    n_out = n_rows + n_var if bound_rows else n_rows
    return _csc(data, indices.astype(np.int32), indptr.astype(np.int32), (n_out, n_var))


def _csc(
    data: np.ndarray, indices: np.ndarray, indptr: np.ndarray, shape: tuple[int, int]
) -> csc_matrix:
    """A ``csc_matrix`` around arrays that are valid by construction (float64 data, int32 sorted,
    duplicate-free row indices, int32 indptr of length shape[1] + 1), without the constructor's
    checks (dtype choice, index scans: ~40 us each, three times a tick). Equal, array for array,
    to ``csc_matrix((data, indices, indptr), shape=shape)``
    (tests/planner/test_mccst.py::test_unchecked_csc_is_the_checked_one)."""
    if not (
        data.dtype == np.float64
        and indices.dtype == np.int32
        and indptr.dtype == np.int32
        and len(indptr) == shape[1] + 1
        and len(indices) == len(data) == indptr[-1]
    ):
        return csc_matrix((data, indices, indptr), shape=shape)
    mat = csc_matrix.__new__(csc_matrix)
    mat.data, mat.indices, mat.indptr = data, indices, indptr
    mat._shape = (int(shape[0]), int(shape[1]))
    mat.maxprint = 50
    return mat


def _constraint_matrix_reference(
    i: np.ndarray, j: np.ndarray, coef: np.ndarray, slack_rows: np.ndarray, n: int
) -> csc_matrix:
    """COO-built twin of :func:`_constraint_matrix` (the pre-optimisation assembly; for tests)."""
    n_rows, n_slack = len(i), len(slack_rows)
    n_u = 2 * n
    n_var = n_u + n_slack
    xyz = np.arange(2)
    row_ids = np.arange(n_rows)
    j_is_drone = j < n
    a_rows = np.concatenate(
        [
            np.repeat(row_ids, 2),
            np.repeat(row_ids[j_is_drone], 2),
            slack_rows,
            n_rows + np.arange(n_var),
        ]
    )
    a_cols = np.concatenate(
        [
            (2 * i[:, None] + xyz).ravel(),
            (2 * j[j_is_drone][:, None] + xyz).ravel(),
            n_u + np.arange(n_slack),
            np.arange(n_var),
        ]
    )
    a_vals = np.concatenate(
        [coef.ravel(), -coef[j_is_drone].ravel(), -np.ones(n_slack), np.ones(n_var)]
    )
    return csc_matrix((a_vals, (a_rows, a_cols)), shape=(n_rows + n_var, n_var))


def _clip_norm(vec: np.ndarray, limit: float) -> np.ndarray:
    """Rows scaled down so that |row| <= limit holds exactly in floating point (new array).
    Compiled for (n, 2) float arrays (:func:`planner._graph_kernels.clip_norm`, the same bits)."""
    if np.ndim(vec) == 2 and np.shape(vec)[1] == 2 and np.result_type(vec) == np.float64:
        fast = _graph_kernels.clip_norm(vec, limit)
        if fast is not None:
            return fast
    return _clip_norm_reference(vec, limit)


def _clip_norm_reference(vec: np.ndarray, limit: float) -> np.ndarray:
    """:func:`_clip_norm` by NumPy (the reference of :func:`planner._graph_kernels.clip_norm`)."""
    norm = np.linalg.norm(vec, axis=1)
    over = norm > limit
    out = np.array(vec, dtype=float, copy=True)
    if over.any():
        out[over] *= (limit / norm[over])[:, None]
        # Rounding can leave |row| a few ulps above limit; shrink those rows a hair more.
        still = np.linalg.norm(out, axis=1) > limit
        out[still] *= 1.0 - 1e-12
    return out


# --------------------------------------------------------------------------------------------
# The planner.
# --------------------------------------------------------------------------------------------


class MccstPlanner:
    """Centralised MCCST controller with perfect knowledge (see the module docstring).

    With ``reassign_period == 1`` (per-tick assignment) ``plan`` is a pure function of its tick.
    Otherwise the planner remembers each drone's task between ticks (reset at t_step 0).
    """

    def __init__(self, problem: ProblemConfig, params: MccstParams) -> None:
        self.problem = problem
        self.params = params
        unit = problem.length_unit_m
        self._unit_m = unit
        self._radius = problem.radio_range_m / unit  # r, paper units
        self._base_radius = min(problem.base_range_m, problem.radio_range_m) / unit
        self._speed = problem.max_speed_m_s * problem.dt_s / unit  # v, paper units / tick
        self._max_disp_m = problem.max_speed_m_s * problem.dt_s
        per_axis = {"box": self._speed / np.sqrt(2.0), "clip": self._speed, "none": np.inf}[
            params.speed_bound
        ]
        self._box = float(per_axis)
        self._held_task: np.ndarray | None = None  # (N,) task per drone, -1 = none (persistent)
        self._last_t_step = -1
        self._rho: float | None = None  # carry_rho: last tick's adapted rho
        self._rho_t_step = -1
        #: Which candidate links hold besides the range (over terrain, line of sight: set by
        #: planner.terrain_aware): called with the tick, the members' indices in it and the
        #: (E, 2) candidate edges (j == len(members): the base); returns (E,) bool. None: every
        #: edge within range holds, the paper's disc.
        self.edge_filter: Callable[[TickInput, np.ndarray, np.ndarray], np.ndarray] | None = None

    def _persistent_tasks(
        self,
        tick: TickInput,
        pos_m: np.ndarray,
        networked: np.ndarray,
        members: np.ndarray,
        task_x: np.ndarray,
    ) -> np.ndarray:
        """Tasks of ``members`` when the assignment is not re-solved every tick.

        The state (one task per drone, -1 = none) is reset at a run's first tick (t_step 0, a
        t_step that does not increase, or a different drone count); that tick solves over every
        alive drone, and ticks with t_step % reassign_period == 0 (period > 1) re-solve over the
        networked ones. Otherwise drones keep their tasks; with ``keep_task_when_disconnected``
        False, a drone outside D' loses its task.
        """
        prm = self.params
        n_all = len(pos_m)
        unit = self._unit_m
        held = self._held_task
        fresh = (
            held is None
            or len(held) != n_all
            or tick.t_step == 0
            or tick.t_step <= self._last_t_step
        )
        self._last_t_step = tick.t_step
        if fresh or held is None:  # (held is None implies fresh: said for the type checker)
            held = np.full(n_all, -1, dtype=np.intp)
            alive = np.flatnonzero(np.asarray(tick.alive, dtype=bool))
            held[alive] = assign_tasks(
                pos_m[alive] / unit, task_x, prm.assignment, prm.task_capacity
            )
        elif prm.reassign_period > 1 and tick.t_step % prm.reassign_period == 0:
            held = np.full(n_all, -1, dtype=np.intp)
            held[members] = assign_tasks(
                pos_m[members] / unit, task_x, prm.assignment, prm.task_capacity
            )
        elif not prm.keep_task_when_disconnected:
            held = np.where(networked, held, -1)
        self._held_task = held
        return held[members]

    def plan(self, tick: TickInput) -> PlanOutput:
        """One MCCST tick: assignment, nominal controls, spanning tree, CBF-QP.

        Returns
        -------
        PlanOutput
            ``disp_m`` (N, 2) metres, zero rows for drones outside ``tick.networked``; ``info`` has
            'status' (OSQP status or 'empty'), 'fallback' (nominal controls used), 'iterations',
            'n_networked', 'n_tree_edges', 'n_collision_rows', 'n_components' (of the candidate
            graph; 1 when D' is consistent), 'max_tree_slack' and 'max_collision_slack' (paper
            length^2 / tick, NaN after a fallback), 'tree_edges'
            ((T, 2) drone indices, -1 = base) and 'task_of' ((N,) task index, -1 if not networked).
        """
        pos_m = np.asarray(tick.pos_m, dtype=float)
        if pos_m.ndim != 2 or pos_m.shape[1] != 2:
            raise ValueError(f"tick.pos_m must be (N, 2) metres, got shape {pos_m.shape}")
        n_all = len(pos_m)
        task_m = np.asarray(tick.task_pos_m, dtype=float).reshape(-1, 2)
        base_m = np.asarray(tick.base_m, dtype=float).reshape(2)
        networked = np.asarray(tick.networked, dtype=bool) & np.asarray(tick.alive, dtype=bool)
        members = np.flatnonzero(networked)
        disp_m = np.zeros((n_all, 2))
        task_of = np.full(n_all, -1, dtype=np.intp)
        n = len(members)
        info = {
            "status": "empty",
            "fallback": False,
            "iterations": 0,
            "n_networked": n,
            "n_tree_edges": 0,
            "n_collision_rows": 0,
            "n_components": 0,
            "max_tree_slack": 0.0,
            "max_collision_slack": 0.0,
            "tree_edges": np.zeros((0, 2), dtype=np.intp),
            "task_of": task_of,
        }
        if n == 0:
            return PlanOutput(disp_m=disp_m, info=info)
        prm = self.params
        unit = self._unit_m
        x = np.empty((n + 1, 2))  # (n+1, 2); row n is the base
        x[:n] = pos_m[members]
        x[n] = base_m
        x /= unit

        # 1-2. Subgroups and nominal controls.
        speed_hat = self._speed if prm.saturate_nominal else np.inf
        u_fast: np.ndarray | None = None
        if len(task_m) == 0:
            task_local = np.zeros(n, dtype=np.intp)
            goal = x[:n]
        else:
            if prm.reassign_period == 1:
                task_local = assign_tasks(x[:n], task_m / unit, prm.assignment, prm.task_capacity)
            else:
                task_local = self._persistent_tasks(tick, pos_m, networked, members, task_m / unit)
            if prm.hold_distance == 0:  # goal and nominal controls in one compiled pass
                u_fast = _graph_kernels.toward_tasks(
                    x[:n], task_m, task_local, unit, prm.k_p, speed_hat
                )
            if u_fast is None:
                has_task = task_local >= 0  # drones without one hold
                goal = np.where(has_task[:, None], task_m[np.maximum(task_local, 0)] / unit, x[:n])
        task_of[members] = task_local
        if u_fast is None:
            u_hat = nominal_controls(x[:n], goal, prm.k_p, speed_hat, prm.hold_distance)
        else:
            u_hat = u_fast

        # 3. Candidate graph and MCCST.
        edges = candidate_edges(
            pos_m[members], base_m, self.problem.radio_range_m, self.problem.base_range_m
        )
        if self.edge_filter is not None and len(edges):
            edges = edges[np.asarray(self.edge_filter(tick, members, edges), dtype=bool)]
        is_base_edge = edges[:, 1] == n
        r_c = prm.kappa * np.where(is_base_edge, self._base_radius, self._radius)
        # The base is its own subgroup (-1); drones without a task (-1 in task_local) form another.
        subgroup = np.empty(n + 1, dtype=np.intp)
        subgroup[:n] = np.where(task_local >= 0, task_local, -2)
        subgroup[n] = -1
        u_nodes = np.zeros((n + 1, 2))  # row n: the base does not move
        u_nodes[:n] = u_hat
        delta = edge_slack(x, u_nodes, edges, r_c, subgroup, prm)
        in_tree = spanning_tree_edges(n + 1, edges, -delta)
        tree = edges[in_tree]

        # 4. Collision pairs (drones only) and the CBF-QP.
        collision_pairs = collision_candidates(
            x[:n], prm.safety_radius + 2.0 * self._speed, prm.collision_neighbours
        )
        rho = None
        if prm.carry_rho:
            # A run's first tick (t_step 0, or a t_step that does not increase) starts at OSQP's
            # default, as does the tick after a fallback.
            if tick.t_step > self._rho_t_step and tick.t_step != 0:
                rho = self._rho
            self._rho_t_step = tick.t_step
        qp = solve_cbf_qp(x, u_hat, tree, r_c[in_tree], collision_pairs, self._box, prm, rho)
        if prm.carry_rho:
            self._rho = (
                qp.rho_estimate if qp.used_solution and np.isfinite(qp.rho_estimate) else None
            )

        disp_m[members] = _clip_norm(qp.u * unit, self._max_disp_m)
        tree_global = np.where(tree == n, -1, members[np.minimum(tree, n - 1)])
        info.update(
            status=qp.status,
            fallback=not qp.used_solution,
            iterations=qp.iterations,
            n_tree_edges=len(tree),
            n_collision_rows=len(collision_pairs),
            n_components=n + 1 - len(tree),
            max_tree_slack=qp.max_tree_slack,
            max_collision_slack=qp.max_collision_slack,
            tree_edges=tree_global,
        )
        return PlanOutput(disp_m=disp_m, tree=None, info=info)


def make_mccst(
    problem: ProblemConfig, params: dict[str, Any], rng: np.random.Generator
) -> MccstPlanner:
    """Registry factory (``METHODS['mccst']``).

    Parameters
    ----------
    problem : ProblemConfig
    params : dict
        Overrides of :class:`MccstParams` fields (paper units, ticks).
    rng : numpy.random.Generator
        Unused: MCCST is deterministic. Accepted for the common factory signature.

    Raises
    ------
    ValueError
        An unknown key in ``params`` (the message lists the valid ones) or an invalid value.
    """
    del rng
    return MccstPlanner(problem, MccstParams.from_dict(dict(params)))

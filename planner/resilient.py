"""ΦIREMAN-resilient: PhiIREMAN plus mechanisms that keep more tasks connected under attrition.

Beyond the paper (issue 15). The planner is :class:`planner.phireman.PhiremanPlanner` (same
energy, descent, message layer and task tree) with switchable mechanisms, each a parameter of
:class:`ResilientParams` so that it can be ablated (every one off is PhiIREMAN, bit for bit):

* **Coverage claims** (``claim_gain``, ``claim_reach``). The tree potential is flat along the
  tree, so nothing pulls a drone out to the end of a branch whose crew has lost its link; with
  few drones left the swarm sits near the base while a crew a few metres out is unserved. The
  base broadcasts, with the tree, the kept tasks it does not hear (below: what the base knows).
  A drone whose nearest
  such task is within ``claim_reach`` and who knows no drone nearer to it adds
  ``claim_gain`` × |x - task| to its energy (:func:`claim_targets`, :func:`claim_gradient`). The
  optional ``claim_tether`` keeps a claimer within a fraction of r of its anchor toward the base.

* **Triage** (``triage_length_per_drone``). The paper's tree spans every task whatever the number
  of drones left; under attrition the survivors are spread over every branch and too few to hold
  any of them. Here the base keeps, each tick, only the tasks the networked drones can afford: it
  adds tasks greedily by the tree length they add (their path to the part already kept, :func:
  `select_tasks`) while the kept length stays within ``triage_length_per_drone`` × |D'(t)|, and
  broadcasts the tree pruned to them (:func:`prune_tree`). With enough drones nothing is pruned
  and the planner is PhiIREMAN. The base uses |D'(t)|, which the paper's controller receives.
* **Rally points** (``rally``). The tree broadcast also defines one rally point per branch, on the
  branch at ``rally_dist`` from the base (:func:`rally_points`). A drone cut off from the network
  flies to the nearest rally point of the tree copy it holds (the last one it received while
  connected) instead of straight home; it is planned again as soon as it reconnects. If it has
  waited ``rally_wait_steps`` at the point without reconnecting it flies home. This changes the
  world's rule for this planner only: the planner exposes the per-drone targets as
  ``recovery_target_m`` and the world model (``vehicle_emu.world.World.step``) uses them when
  given (ArduPilot "RTL to the nearest rally point", PX4 "return to the closest safe point").
* **Task-motion prediction** (``predict_steps``). The base builds the tree on the tasks'
  positions extrapolated ``predict_steps`` ahead with an exponentially smoothed velocity.
* **Hazard awareness** (``hazard_avoid``, ``hazard_push_gain``; planner/hazard.py). With the
  mission's zones in ``TickInput.hazards`` (known to the station from the mission file), the
  broadcast tree is routed around the active zones (:func:`planner.hazard.route_tree`) and drones
  inside a zone are pushed toward its nearest boundary, except within r of a task inside it.
  Relays inside an active zone get a spare first (redundancy, below): "double them" where no
  way around exists.
* **Redundancy** (``redundancy_gain``, ``redundancy_reach``, ``redundancy_min_cut``;
  planner/redundancy.py). The base finds the networked drones whose loss alone would cut
  connected tasks (Tarjan low points on the mesh) and pulls the nearest spare (a drone on no
  task's fewest-hop path) onto each, most critical first; pairs persist while they make sense.
  The targets travel with the tree broadcast, like the open tasks of the claims.

What the base knows (``base_view``, issue 28). Like ΦIREMAN's, the base knows the true task
positions (it builds the tree from them, docs/design/model.md §5.4) and the mission's hazard
zones. What it needs beyond that, the mesh, depends on the information model:

* ``info='async'``, ``base_view='heard'`` (the default): only what the message layer delivered to
  it (planner/base_view.py). Every drone's report (its own position, the drones it heard, the
  crews it hears) is flooded to the base one hop per step over the layer's links and kept 15 steps
  (``tree_stale_steps``); the base's mesh is the two-way links of the reports it holds, its
  networked set is its component of that mesh, the crews it hears are those its networked drones
  report, the redundancy runs on that mesh, a spare's target is where its relay last reported
  being, and triage counts the drones heard at the previous step. A drone h hops out is seen
  h - 1 steps late; one whose reports do not reach the base is not seen.
* ``info='async'``, ``base_view='oracle'``: the planner as evaluated before issue 28
  (docs/results/resilient.md): the base reads, at each step, every networked drone's true
  position, the true mesh (a KD-tree on the true positions), the true networked set D'(t) and the
  true connected crews A(t) (:func:`planner.geometry.tasks_connected`); a spare's target is its
  relay's true position. Nothing ΦIREMAN's base receives.
* ``info='central'`` (the station): the planner sees D'(t) with true positions by definition
  (planner/info.py); ``base_view`` is not consulted.

The drones' side is the same in every variant: each acts on its own table of neighbour reports
and on the copy of the base's broadcast (tree, open crews, spare targets) it holds.

Defaults (docs/tuning/resilient.md): claims 0.03 / 4 (frozen at round 1), redundancy 0.3 / 8
(round 2, designed after round 1 had been evaluated on the paper's seeds 0-99), hazard awareness
on; triage, rally points and prediction off; all tuned with the oracle base, none re-tuned for the
heard base. Central information (the station) runs the same pulls in the joint descent
(:meth:`ResilientPlanner._plan_central_pulled`).

Units: as PhiIREMAN, every length parameter is in paper units (1 unit = r / 2); instructions and
``recovery_target_m`` are metres.

Length (about 1,000 lines, above the ~600 this code base aims for): each mechanism's kernel, its
slow reference and its parameter sit together so that an ablation switches one thing in one
file; the redundancy's graph work and the hazard geometry live in their own modules.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner import _kernels
from planner.geometry import tasks_connected
from planner.base_view import BaseListener, HeardMesh
from planner.hazard import (
    HazardMap,
    hazard_rate_per_s,
    push_gradient,
    route_tree,
    signed_depth,
)
from planner.info import CentralView, MessagePassingInfo, MessageView
from planner.methods import PlanOutput, TickInput
from planner.phireman import (
    PhiremanParams,
    PhiremanPlanner,
    TreeSegments,
    _descend_separable_compiled,
    _EntriesByDrone,
    _pair_gradient_xy,
    descend,
    parse_params,
    task_gradient,
)
from planner.problem import ProblemConfig
from planner.redundancy import RedundancyBook, backbone, critical_counts, mesh_graph
from planner.steiner import TaskTree, maintain_task_tree

__all__ = [
    "BASE_VIEWS",
    "ResilientParams",
    "ResilientPlanner",
    "task_paths",
    "select_tasks",
    "select_tasks_reference",
    "prune_tree",
    "rally_points",
    "rally_points_reference",
    "nearest_rally",
    "claim_targets",
    "claim_targets_reference",
    "claim_gradient",
    "claim_targets_central",
    "held_targets",
    "tether_anchors",
    "tether",
    "make_resilient",
]


#: Where the base's picture of the mesh comes from (``ResilientParams.base_view``).
BASE_VIEWS = ("heard", "oracle")


@dataclass(frozen=True)
class ResilientParams(PhiremanParams):
    """PhiIREMAN's parameters (same defaults) plus the resilience mechanisms (paper units)."""

    triage_length_per_drone: float = 0.0
    """Triage: tree length (paper units) the base budgets per networked drone; 0 or inf = off
    (every task kept, as PhiIREMAN)."""
    triage_keep_bonus: float = 0.2
    """Triage hysteresis: a task kept last tick competes with its added length times (1 - bonus)."""
    rally: bool = False
    """Rally points: a disconnected drone flies to the nearest rally point it knows, not home."""
    rally_dist: float = 2.0
    """Distance of each branch's rally point from the base along the branch, paper units (the base
    reaches min(R, r) = 2)."""
    rally_wait_steps: int = 10
    """Steps a disconnected drone waits at its rally point before flying home."""
    claim_gain: float = 0.03
    """Coverage claim: pull (a force, like Þ) of a drone toward its nearest unconnected task when
    that task is within ``claim_reach`` and no drone it knows is nearer to it; 0 = off. Chosen at
    S / 1 % and M / 2 % on seeds 1000-1099 (docs/tuning/resilient.md)."""
    claim_reach: float = 4.0
    """Coverage claim: only drones nearer than this to an unconnected task claim it, paper units."""
    claim_tether: float = 0.0
    """Coverage claim: a claiming drone's move is cut back so that it stays within this fraction
    of r of its anchor (the known drone within r nearest the base, or the base); 0 = no tether."""
    predict_steps: float = 0.0
    """Task-motion prediction: the tree is built on tasks extrapolated this many steps (0 = off)."""
    predict_smoothing: float = 0.3
    """Weight of the newest observed displacement in the smoothed task velocity."""
    redundancy_gain: float = 0.3
    """Redundancy: pull (a force, like Þ) of a spare drone toward the critical relay it is paired
    with (planner/redundancy.py); 0 = off. Chosen at S / 1 % (seeds 1000-1099) and M / 2 % (seeds
    1000-1049), docs/tuning/resilient.md."""
    redundancy_reach: float = 8.0
    """Redundancy: a spare is paired only with a critical relay within this distance, paper units."""
    redundancy_min_cut: int = 1
    """Redundancy: only relays whose loss alone would cut at least this many tasks get a spare."""
    # -- hazard awareness (planner/hazard.py; zones from ``TickInput.hazards``) --------------
    hazard_avoid: bool = True
    """Hazard awareness: the broadcast tree is routed around the active hazard zones (each edge
    crossing a zone, both ends outside, takes the shortest way around when it is at most
    ``hazard_detour_cap`` times the edge; planner.hazard.route_tree)."""
    hazard_push_gain: float = 1.0
    """Hazard awareness: a drone inside an active zone (or within ``hazard_margin`` of it) is
    pushed toward its nearest boundary with force gain x rate_per_s x dt_s (the zone's per-step
    loss hazard); no push within r of a task inside the zone. 0 = off."""
    hazard_margin: float = 0.5
    """Hazard awareness: clearance of the detours and reach of the push outside a zone, paper
    units."""
    hazard_detour_cap: float = 1.5
    """Hazard awareness: longest detour accepted, as a multiple of the edge it replaces."""
    # -- what the base knows (issue 28; planner/base_view.py) ----------------------------------
    base_view: str = "heard"
    """Where the base's picture of the mesh comes from under the asynchronous model (the claims'
    unconnected crews, the redundancy's mesh, positions and networked set): 'heard', the reports
    the message layer delivered to it (planner/base_view.py: each drone's position and neighbour
    list, flooded with the layer's delays and losses); 'oracle', the true positions, mesh and
    networked set of this tick (the planner evaluated before issue 28,
    docs/results/resilient.md). Central information (the station) sees the truth either way."""

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in (
            "triage_length_per_drone",
            "rally_dist",
            "predict_steps",
            "claim_gain",
            "claim_reach",
            "redundancy_gain",
            "redundancy_reach",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.triage_keep_bonus < 1.0:
            raise ValueError(f"triage_keep_bonus must be in [0, 1), got {self.triage_keep_bonus}")
        if not 0.0 < self.predict_smoothing <= 1.0:
            raise ValueError(f"predict_smoothing must be in (0, 1], got {self.predict_smoothing}")
        if self.rally_wait_steps < 0:
            raise ValueError(f"rally_wait_steps must be >= 0, got {self.rally_wait_steps}")
        if self.redundancy_min_cut < 1:
            raise ValueError(f"redundancy_min_cut must be >= 1, got {self.redundancy_min_cut}")
        for name in ("hazard_push_gain", "hazard_margin"):  # hazard awareness
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not self.hazard_detour_cap >= 1.0:
            raise ValueError(f"hazard_detour_cap must be >= 1, got {self.hazard_detour_cap}")
        if self.base_view not in BASE_VIEWS:
            raise ValueError(f"base_view must be one of {BASE_VIEWS}, got {self.base_view!r}")

    @property
    def triage_on(self) -> bool:
        return 0.0 < self.triage_length_per_drone < np.inf


# --------------------------------------------------------------------------------------------
# Triage: which tasks the drones can afford
# --------------------------------------------------------------------------------------------


def task_paths(tree: TaskTree) -> np.ndarray:
    """(M, K) bool: ``P[k, v]`` is True when node v lies on task k's tree path to the base (v != 0).

    Edge v -> parent(v) belongs to the path exactly when ``P[k, v]``. Vectorised over tasks; the
    loop runs over the tree depth.
    """
    m, k = tree.n_tasks, tree.n_nodes
    paths = np.zeros((m, k), dtype=bool)
    cur = np.arange(1, m + 1)
    rows = np.arange(m)
    for _ in range(k):
        live = cur > 0
        if not live.any():
            break
        paths[rows[live], cur[live]] = True
        cur = np.where(live, tree.parent[np.maximum(cur, 0)], 0)
    return paths


def select_tasks(
    tree: TaskTree, budget: float, kept: np.ndarray | None = None, keep_bonus: float = 0.0
) -> np.ndarray:
    """Greedy triage: the tasks whose union of tree paths fits in ``budget`` (tree length).

    Repeatedly adds the task whose path adds the least new length to the part already kept (the
    length of a task kept last tick counts ``1 - keep_bonus`` times for the ordering), until the
    next one would exceed ``budget``. The nearest task is always kept.

    Parameters
    ----------
    tree : the full task tree (any length unit)
    budget : the affordable tree length, same unit
    kept : (M,) bool, the tasks kept last tick (hysteresis), optional
    keep_bonus : in [0, 1)

    Returns
    -------
    (M,) bool, the kept tasks.
    """
    m = tree.n_tasks
    if m == 0:
        return np.zeros(0, dtype=bool)
    paths = task_paths(tree).astype(float)
    edge = tree.edge_lengths_m()
    favour = np.ones(m) if kept is None else np.where(kept, 1.0 - keep_bonus, 1.0)
    chosen = np.zeros(m, dtype=bool)
    uncovered = edge.copy()  # length of each node's parent edge not yet in the kept part
    uncovered[0] = 0.0
    used = 0.0
    for _ in range(m):  # loop over tasks added (<= M), vectorised over candidates
        added = paths @ uncovered
        order = np.where(chosen, np.inf, added * favour)
        k = int(np.argmin(order))
        if chosen[k]:
            break
        if chosen.any() and used + added[k] > budget:
            break
        chosen[k] = True
        used += added[k]
        uncovered[paths[k] > 0] = 0.0
    return chosen


def select_tasks_reference(
    tree: TaskTree, budget: float, kept: np.ndarray | None = None, keep_bonus: float = 0.0
) -> np.ndarray:
    """Loop-by-loop transcription of :func:`select_tasks` (walks parent pointers; for tests)."""
    m = tree.n_tasks
    edge = tree.edge_lengths_m()
    covered = {0}
    chosen = [False] * m
    used = 0.0

    def added(k: int) -> float:
        v, total = k + 1, 0.0
        while v not in covered:
            total += float(edge[v])
            v = int(tree.parent[v])
        return total

    for _ in range(m):
        best, best_key = None, np.inf
        for k in range(m):
            if chosen[k]:
                continue
            key = added(k) * ((1.0 - keep_bonus) if kept is not None and kept[k] else 1.0)
            if key < best_key:
                best, best_key = k, key
        if best is None:
            break
        a = added(best)
        if any(chosen) and used + a > budget:
            break
        chosen[best] = True
        used += a
        v = best + 1
        while v not in covered:
            covered.add(v)
            v = int(tree.parent[v])
    return np.array(chosen, dtype=bool)


def prune_tree(tree: TaskTree, keep: np.ndarray) -> TaskTree:
    """The tree restricted to the paths of the ``keep`` tasks (and any task node on them).

    Node order stays base, tasks, Steiner nodes (tasks and Steiner nodes in their old order); a
    Steiner node left with a single child is spliced out (its child hangs from its parent), since
    it no longer joins anything. ``keep`` all True returns ``tree`` itself.
    """
    keep = np.asarray(keep, dtype=bool)
    if keep.all():
        return tree
    on_path = task_paths(tree)[keep].any(axis=0)
    on_path[0] = True
    parent = tree.parent.copy()
    n_t = tree.n_tasks
    is_steiner = np.arange(tree.n_nodes) > n_t
    # Splice pass-through Steiner nodes, bottom-up until none is left (loop over tree nodes).
    changed = True
    while changed:
        changed = False
        kids = np.bincount(parent[1:][on_path[1:]], minlength=tree.n_nodes)
        lone = np.flatnonzero(on_path & is_steiner & (kids == 1))
        for s in lone:
            child = np.flatnonzero(on_path & (parent == s))
            parent[child] = parent[s]
            on_path[s] = False
            changed = True
            break
    old = np.flatnonzero(on_path)
    new_index = np.full(tree.n_nodes, -1, dtype=np.int64)
    new_index[old] = np.arange(len(old))
    new_parent = np.where(parent[old] < 0, -1, new_index[np.maximum(parent[old], 0)])
    new_parent[0] = -1
    n_tasks = int(np.count_nonzero(old[1:] <= n_t))
    return TaskTree(tree.nodes_m[old], new_parent, n_tasks)


# --------------------------------------------------------------------------------------------
# Rally points
# --------------------------------------------------------------------------------------------


def rally_points(tree: TaskTree, dist: float) -> np.ndarray:
    """(B, 2): one rally point per branch of the tree, at ``dist`` from the base along the branch.

    A branch is a child c of the base. The point lies on the path base -> c -> (first child ...)
    at tree distance ``dist`` from the base, following the first child at each node, or at the end
    of the path if it is shorter. Same length unit as the tree.
    """
    nodes, parent = tree.nodes_m, tree.parent
    branches = np.flatnonzero(parent == 0)
    if len(branches) == 0:
        return np.zeros((0, 2))
    first_child = np.full(tree.n_nodes, -1, dtype=np.int64)
    order = np.arange(tree.n_nodes - 1, 0, -1)  # reversed so the lowest child id wins
    first_child[parent[order]] = order
    edge = tree.edge_lengths_m()
    out = np.empty((len(branches), 2))
    at = np.zeros(len(branches), dtype=np.int64)  # current node (start: base)
    nxt = branches.copy()
    left = np.full(len(branches), float(dist))
    done = np.zeros(len(branches), dtype=bool)
    for _ in range(tree.n_nodes):  # loop over path depth, vectorised over branches
        if done.all():
            break
        go = ~done & (nxt >= 0)
        e = np.where(go, edge[np.maximum(nxt, 0)], 0.0)
        inside = go & (e >= left)
        frac = np.divide(left, e, out=np.zeros_like(left), where=e > 0)
        a, b = nodes[at], nodes[np.maximum(nxt, 0)]
        out[inside] = (a + frac[:, None] * (b - a))[inside]
        done |= inside
        end = ~done & (nxt < 0)  # path ended before dist: its last node
        out[end] = nodes[at][end]
        done |= end
        step = ~done
        left = np.where(step, left - e, left)
        at = np.where(step, nxt, at)
        nxt = np.where(step, first_child[np.maximum(nxt, 0)], nxt)
    return out


def rally_points_reference(tree: TaskTree, dist: float) -> np.ndarray:
    """Per-branch loop transcription of :func:`rally_points` (for tests)."""
    nodes, parent = tree.nodes_m, tree.parent
    pts = []
    for c in range(1, tree.n_nodes):
        if parent[c] != 0:
            continue
        a, v, left = 0, c, float(dist)
        while True:
            e = float(np.linalg.norm(nodes[v] - nodes[a]))
            if e >= left:
                pts.append(nodes[a] + (left / e if e > 0 else 0.0) * (nodes[v] - nodes[a]))
                break
            left -= e
            kids = [w for w in range(1, tree.n_nodes) if parent[w] == v]
            if not kids:
                pts.append(nodes[v].copy())
                break
            a, v = v, min(kids)
    return np.array(pts, dtype=float).reshape(-1, 2)


def nearest_rally(pos: np.ndarray, rally: np.ndarray) -> np.ndarray:
    """(n, 2): the nearest row of ``rally`` (B, 2) to each position (NaN rows if B = 0)."""
    pos = np.asarray(pos, float)
    if len(rally) == 0:
        return np.full_like(pos, np.nan)
    d2 = ((pos[:, None, :] - rally[None, :, :]) ** 2).sum(-1)
    return rally[np.argmin(d2, axis=1)]


# --------------------------------------------------------------------------------------------
# Coverage claims
# --------------------------------------------------------------------------------------------


def claim_targets(
    pos_u: np.ndarray,
    ent_r: np.ndarray,
    ent_y: np.ndarray,
    stamps: np.ndarray,
    open_by_stamp: dict[int, np.ndarray],
    reach: float,
) -> np.ndarray:
    """(n, 2): the unconnected task each drone claims (NaN rows: none).

    Drone i looks at the nearest task of the open (unconnected) tasks in the broadcast it holds
    (``open_by_stamp[stamps[i]]``); it claims it if the task lies within ``reach`` and no drone it
    knows (its entries: holder ``ent_r``, believed position ``ent_y``) is nearer to it (ties go to
    the claimer). One candidate per drone keeps the work proportional to the entries (XL has
    ~15,000, up to 250,000 while the swarm is still packed at take-off). Loops over broadcast
    versions (a handful), vectorised over drones, tasks and entries.
    """
    n = len(pos_u)
    out = np.full((n, 2), np.nan)
    ent_r = np.asarray(ent_r)
    cand = np.full(n, -1)  # index of the nearest open task
    d_own = np.full(n, np.inf)
    task_of = np.zeros((n, 2))
    for s in np.unique(stamps):
        tasks = open_by_stamp.get(int(s))
        if tasks is None or len(tasks) == 0:
            continue
        rows = np.flatnonzero(stamps == s)
        d = np.sqrt(((pos_u[rows, None, :] - tasks[None]) ** 2).sum(-1))  # (r, T)
        k = np.argmin(d, axis=1)
        near = d[np.arange(len(rows)), k]
        cand[rows] = k
        d_own[rows] = near
        task_of[rows] = tasks[k]
    ok = (cand >= 0) & (d_own < reach)
    if not ok.any():
        return out
    # Is a known drone nearer to the candidate task than the claimer? One pass over the entries.
    d_ent = np.sqrt(((ent_y - task_of[ent_r]) ** 2).sum(-1))
    d_other = np.full(n, np.inf)
    np.minimum.at(d_other, ent_r, d_ent)
    mine = ok & (d_own <= d_other)
    out[mine] = task_of[mine]
    return out


def claim_targets_reference(
    pos_u: np.ndarray,
    ent_r: np.ndarray,
    ent_y: np.ndarray,
    stamps: np.ndarray,
    open_by_stamp: dict[int, np.ndarray],
    reach: float,
) -> np.ndarray:
    """Per-drone loop transcription of :func:`claim_targets` (for tests)."""
    n = len(pos_u)
    out = np.full((n, 2), np.nan)
    for i in range(n):
        tasks = open_by_stamp.get(int(stamps[i]))
        if tasks is None or len(tasks) == 0:
            continue
        dists = [float(np.linalg.norm(pos_u[i] - t)) for t in tasks]
        t = tasks[int(np.argmin(dists))]
        d = min(dists)
        if d >= reach:
            continue
        others = [float(np.linalg.norm(ent_y[e] - t)) for e in range(len(ent_r)) if ent_r[e] == i]
        if others and min(others) < d:
            continue
        out[i] = t
    return out


def tether_anchors(
    pos_u: np.ndarray,
    ent_r: np.ndarray,
    ent_y: np.ndarray,
    base_u: np.ndarray,
    r_u: float,
    base_reach_u: float,
) -> np.ndarray:
    """(n, 2): each drone's anchor toward the base: the base if the drone is within its reach,
    else the known drone within r of it (believed position) nearest the base, else NaN."""
    n = len(pos_u)
    out = np.full((n, 2), np.nan)
    d_ent = np.linalg.norm(ent_y - pos_u[ent_r], axis=1)
    ok = d_ent <= r_u
    key = np.where(ok, np.linalg.norm(ent_y - base_u, axis=1), np.inf)
    best = np.full(n, np.inf)
    np.minimum.at(best, ent_r, key)
    first = np.full(n, -1)
    hit = np.flatnonzero(ok & (key == best[ent_r]))
    first[ent_r[hit[::-1]]] = hit[::-1]  # the first entry reaching the minimum
    has = first >= 0
    out[has] = ent_y[first[has]]
    at_base = np.linalg.norm(pos_u - base_u, axis=1) <= base_reach_u
    out[at_base] = base_u
    return out


def tether(new_u: np.ndarray, anchor_u: np.ndarray, length: float) -> np.ndarray:
    """Positions pulled back onto the disc of radius ``length`` around each anchor (NaN: unchanged)."""
    off = new_u - anchor_u
    d = np.linalg.norm(off, axis=1)
    over = np.isfinite(d) & (d > length)
    out = new_u.copy()
    out[over] = anchor_u[over] + off[over] * (length / d[over])[:, None]
    return out


def claim_gradient(pos_u: np.ndarray, target: np.ndarray, gain: float) -> np.ndarray:
    """∇ of gain · |x - target| (0 where the target is NaN or reached)."""
    off = pos_u - target
    d = np.sqrt((off**2).sum(-1))
    ok = np.isfinite(d) & (d > 1e-12)
    out = np.zeros_like(pos_u)
    out[ok] = gain * off[ok] / d[ok, None]
    return out


def claim_targets_central(
    pos_u: np.ndarray, open_tasks: np.ndarray | None, reach: float
) -> np.ndarray:
    """(n, 2): :func:`claim_targets` when every drone knows every other's position: drone i claims
    its nearest open task if it lies within ``reach`` and no drone is nearer to it."""
    n = len(pos_u)
    out = np.full((n, 2), np.nan)
    if open_tasks is None or len(open_tasks) == 0 or n == 0:
        return out
    d = np.sqrt(((pos_u[:, None, :] - open_tasks[None]) ** 2).sum(-1))  # (n, T)
    k = np.argmin(d, axis=1)
    d_own = d[np.arange(n), k]
    mine = (d_own < reach) & (d_own <= d.min(axis=0)[k])
    out[mine] = open_tasks[k[mine]]
    return out


def held_targets(
    idx: np.ndarray, stamps: np.ndarray, by_stamp: dict[int, np.ndarray]
) -> np.ndarray:
    """(n, 2): row ``idx[j]`` of the per-drone target table of the broadcast drone j holds
    (``by_stamp[stamps[j]]``; NaN rows when that broadcast is gone or has no target for it)."""
    out = np.full((len(idx), 2), np.nan)
    for s in np.unique(stamps):  # loop over broadcast versions held (a handful)
        table = by_stamp.get(int(s))
        if table is None:
            continue
        rows = np.flatnonzero(stamps == s)
        ok = idx[rows] < len(table)
        out[rows[ok]] = table[idx[rows[ok]]]
    return out


# --------------------------------------------------------------------------------------------
# The planner
# --------------------------------------------------------------------------------------------


class ResilientPlanner(PhiremanPlanner):
    """PhiIREMAN with claims, redundancy, hazard awareness, triage, rally points and task-motion
    prediction (see the module docstring).

    Attributes
    ----------
    recovery_target_m : (N, 2) or None
        After each :meth:`plan`, where each drone flies if the world finds it disconnected (NaN:
        home). None when rally points are off, so the world keeps the paper's rule.
    kept_tasks : (M,) bool
        The tasks the base kept at the last tick (all True without triage).
    """

    params: ResilientParams

    def __init__(self, problem: ProblemConfig, params: ResilientParams, rng: np.random.Generator):
        super().__init__(problem, params, rng)
        self.full_tree: TaskTree | None = None
        self.kept_tasks: np.ndarray | None = None
        self.recovery_target_m: np.ndarray | None = None
        self._task_prev_u: np.ndarray | None = None
        self._task_vel_u: np.ndarray | None = None
        self._rally_by_stamp: dict[int, np.ndarray] = {}  # broadcast stamp -> rally points (units)
        self._target_u: np.ndarray | None = None  # per-drone recovery target (NaN = none yet)
        self._waited = np.zeros(problem.n_drones, dtype=np.int64)
        self._open_by_stamp: dict[int, np.ndarray] = {}  # broadcast stamp -> unconnected kept tasks
        self._spare_by_stamp: dict[int, np.ndarray] = {}  # broadcast stamp -> (N, 2) spare targets
        self._book = RedundancyBook()
        self._hazards: HazardMap | None = None  # hazard awareness: the zones active this tick
        self._listener: BaseListener | None = None  # base_view='heard': the reports heard
        self._heard_networked = 0  # base_view='heard': |D'| as the base heard it last tick
        self.heard: HeardMesh | None = None  # base_view='heard': the base's picture this tick

    # -- the base's side ---------------------------------------------------------------------
    def _predicted_tasks(self, tasks_u: np.ndarray) -> np.ndarray:
        p = self.params
        if self._task_prev_u is None or len(self._task_prev_u) != len(tasks_u):
            self._task_vel_u = np.zeros_like(tasks_u)
        else:
            a = p.predict_smoothing
            assert self._task_vel_u is not None  # set together with _task_prev_u
            self._task_vel_u = (1 - a) * self._task_vel_u + a * (tasks_u - self._task_prev_u)
        self._task_prev_u = tasks_u.copy()
        if p.predict_steps <= 0:
            return tasks_u
        return tasks_u + p.predict_steps * self._task_vel_u

    def _base_tree(
        self, tick: TickInput, tasks_u: np.ndarray, base_u: np.ndarray, n_networked: int
    ) -> TaskTree:
        p = self.params
        self.full_tree = maintain_task_tree(
            self.full_tree,
            base_u,
            self._predicted_tasks(tasks_u),
            tick.t_step,
            base_weight=p.base_weight,
            accept_ratio=p.accept_ratio,
            rebuild_period=p.rebuild_period,
        )
        if p.triage_on and n_networked > 0:
            kept = select_tasks(
                self.full_tree,
                p.triage_length_per_drone * n_networked,
                self.kept_tasks,
                p.triage_keep_bonus,
            )
        else:
            kept = np.ones(self.full_tree.n_tasks, dtype=bool)
        self.kept_tasks = kept
        return self._hazard_route(prune_tree(self.full_tree, kept))

    # -- main entry --------------------------------------------------------------------------
    def plan(self, tick: TickInput) -> PlanOutput:
        if self.params.base_view == "heard" and isinstance(self.info_model, MessagePassingInfo):
            return self._plan_heard(tick)
        p, u = self.params, self.units
        pos_u = u.to_u(tick.pos_m)
        tasks_u = u.to_u(tick.task_pos_m)
        base_u = u.to_u(tick.base_m)
        alive = np.asarray(tick.alive, bool)
        networked = np.asarray(tick.networked, bool) & alive
        self._hazards = _active_hazards(tick, self.problem.dt_s, p)
        self.tree = self._base_tree(tick, tasks_u, base_u, int(networked.sum()))
        assert self.kept_tasks is not None  # set by _base_tree
        if p.rally:
            self._rally_by_stamp[tick.t_step] = rally_points(self.tree, p.rally_dist)
        if p.claim_gain > 0:
            # base_view='oracle': the base reads the true connected crews A(t) (issue 28: no
            # message brings it this; _plan_heard is what it can hear) and broadcasts the kept
            # tasks that are not connected.
            conn = tasks_connected(tasks_u, pos_u, networked, u.radio_range_u)
            self._open_by_stamp[tick.t_step] = tasks_u[self.kept_tasks & ~conn]
            for old in [s for s in self._open_by_stamp if s < tick.t_step - p.tree_stale_steps - 1]:
                del self._open_by_stamp[old]
        info: dict[str, Any] = {"kept_tasks": int(self.kept_tasks.sum())}
        if p.redundancy_gain > 0:
            info["spares"] = self._pair_spares(tick.t_step, pos_u, networked, tasks_u, base_u)
        view = self.info_model.see(tick.t_step, pos_u, tick.alive, networked, base_u, self.tree)
        if isinstance(view, CentralView):
            hz = self._hazard_term(pos_u[view.planned], [self.tree], np.zeros(len(view.planned)))
            if p.claim_gain > 0 or p.redundancy_gain > 0 or hz is not None:
                disp_u, more = self._plan_central_pulled(pos_u, tick.t_step, view, hz)
            else:
                # PhiIREMAN's central descent on the pruned tree, by the NumPy gradient (bit for bit
                # with this planner's recorded runs; PhiremanPlanner._plan_central).
                disp_u, more = self._plan_central(pos_u, self.tree, view, compiled=False)
        else:
            disp_u, more = self._plan_async(pos_u, base_u, view)
        info.update(more)
        if p.rally:
            self._update_recovery(pos_u, base_u, alive, networked, view.held_stamp)
        return PlanOutput(u.to_m(disp_u), tree=u.tree_to_m(self.tree), info=info)

    def _plan_heard(self, tick: TickInput) -> PlanOutput:
        """:meth:`plan` under the asynchronous model with ``base_view='heard'``: the base decides
        the open crews and the spares from what the message layer delivered to it at this step
        (planner/base_view.py), never from the truth. The order differs from the oracle's only in
        that the layer's delivery comes before those decisions (they are filed under this step's
        broadcast, which no drone holds before the next step), and triage, which shapes the
        broadcast tree itself, counts the drones the base heard at the previous step."""
        p, u = self.params, self.units
        pos_u = u.to_u(tick.pos_m)
        tasks_u = u.to_u(tick.task_pos_m)
        base_u = u.to_u(tick.base_m)
        alive = np.asarray(tick.alive, bool)
        networked = np.asarray(tick.networked, bool) & alive  # the world's: who is planned
        self._hazards = _active_hazards(tick, self.problem.dt_s, p)
        self.tree = self._base_tree(tick, tasks_u, base_u, self._heard_networked)
        assert self.kept_tasks is not None  # set by _base_tree
        if p.rally:
            self._rally_by_stamp[tick.t_step] = rally_points(self.tree, p.rally_dist)
        view = self.info_model.see(tick.t_step, pos_u, tick.alive, networked, base_u, self.tree)
        assert isinstance(view, MessageView)  # the asynchronous model
        if self._listener is None:
            self._listener = BaseListener(
                p.tree_stale_steps, p.broadcast_after_move, u.radio_range_u, u.base_reach_u
            )
        self._listener.record(tick.t_step, view.layer.knowledge, pos_u, alive, tasks_u, base_u)
        heard = self._listener.heard(tick.t_step, len(pos_u), len(tasks_u))
        self.heard = heard
        self._heard_networked = int(heard.networked.sum())
        info: dict[str, Any] = {
            "kept_tasks": int(self.kept_tasks.sum()),
            "heard_networked": self._heard_networked,
        }
        if p.claim_gain > 0:
            # The crews the base heard of (reported by a drone it believes networked).
            self._open_by_stamp[tick.t_step] = tasks_u[self.kept_tasks & ~heard.crews]
            for old in [s for s in self._open_by_stamp if s < tick.t_step - p.tree_stale_steps - 1]:
                del self._open_by_stamp[old]
        if p.redundancy_gain > 0:
            info["spares"] = self._pair_spares_heard(tick.t_step, heard)
        disp_u, more = self._plan_async(pos_u, base_u, view)
        info.update(more)
        if p.rally:
            self._update_recovery(pos_u, base_u, alive, networked, view.held_stamp)
        return PlanOutput(u.to_m(disp_u), tree=u.tree_to_m(self.tree), info=info)

    def _pair_spares_heard(self, t_step: int, heard: HeardMesh) -> int:
        """:meth:`_pair_spares` on the base's picture: its mesh, the positions of the reports it
        holds (a spare's target is its relay where the relay last reported being) and the drones
        it believes networked; returns the number of pairs."""
        p = self.params
        n = len(heard.stamp)
        graph = heard.graph()
        crit = critical_counts(graph, n)
        on = backbone(graph, n)
        priority = None
        if self._hazards is not None:
            known = np.isfinite(heard.pos_u).all(axis=1)
            in_zone = np.zeros(n, bool)
            in_zone[known] = (
                hazard_rate_per_s(
                    self._hazards, self.units.to_m(heard.pos_u[known]), t_step * self.problem.dt_s
                )
                > 0
            )
            priority = crit + (int(crit.max(initial=0)) + 1) * in_zone
        target = self._book.assign(
            heard.pos_u,
            heard.networked,
            crit,
            on,
            p.redundancy_reach,
            p.redundancy_min_cut,
            priority,
        )
        self._spare_by_stamp[t_step] = target
        for old in [s for s in self._spare_by_stamp if s < t_step - p.tree_stale_steps - 1]:
            del self._spare_by_stamp[old]
        return len(self._book.pair_of)

    def _plan_async(
        self, pos_u: np.ndarray, base_u: np.ndarray, view: MessageView
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """PhiIREMAN's asynchronous step (same code path) plus the coverage-claim pull."""
        p = self.params
        idx, disp_u = view.planned, view.disp_u  # stale drones already head home
        if len(idx) == 0:
            return disp_u, view.info()
        r_u, vmax_u = self.units.radio_range_u, self.units.max_step_u
        ent_r, ent_y, stamps = view.rows_e, view.believed_u, view.stamps
        trees, version_of = view.broadcasts()
        segments = TreeSegments(trees, version_of, p.nodes_only, pos_u[idx], vmax_u)
        entries = _EntriesByDrone(ent_r, ent_y, len(idx))
        claim = None
        if p.claim_gain > 0:
            claim = claim_targets(
                pos_u[idx], ent_r, ent_y, stamps, self._open_by_stamp, p.claim_reach
            )
            has_claim = np.isfinite(claim).all(axis=1)
            if not has_claim.any():
                claim = None
        spare = None
        if p.redundancy_gain > 0:
            spare = held_targets(idx, stamps, self._spare_by_stamp)
            if claim is not None:  # covering an open task comes first
                spare[np.isfinite(claim).all(axis=1)] = np.nan
            if not np.isfinite(spare).all(axis=1).any():
                spare = None
        hz = self._hazard_term(pos_u[idx], trees, version_of)

        def energy_grad(xs: np.ndarray, full: np.ndarray) -> np.ndarray:
            """∇ of drone ``full``'s energy at ``xs`` (its rows of x): PhiIREMAN's terms plus the
            claim and spare pulls and the hazard push."""
            er, ox, oy = entries.of(full)
            g = _pair_gradient_xy(
                xs,
                er,
                ox,
                oy,
                p.attraction,
                p.attraction_floor,
                p.repulsion,
                self.reach_u,
                p.pair_factor,
            ) + segments.gradient(xs, full, p.thorn)
            if claim is not None:
                g += claim_gradient(xs, claim[full], p.claim_gain)
            if spare is not None:
                g += claim_gradient(xs, spare[full], p.redundancy_gain)
            if hz is not None:
                g += hz.gradient(xs, full)
            return g

        if (
            _kernels.NUMBA
            and _kernels.ENABLED
            and p.speed_rule == "per_drone"
            and segments.entries is not None
        ):
            # The descent is separable (each drone against its fixed beliefs), so the drones with no
            # extra term take PhiIREMAN's compiled descent (bit for bit the NumPy one) and only those
            # with a claim, a spare pull or a hazard push run the NumPy descent of their whole
            # energy; same instructions as one NumPy descent of everybody (tests/planner/
            # test_resilient.py, tests/planner/test_hazard.py).
            res = _descend_separable_compiled(
                pos_u[idx], entries, segments, p, self.reach_u, vmax_u
            )
            disp_u[idx] = res.disp_u
            extra = np.zeros(len(idx), dtype=bool)  # drones whose energy has a term more
            for tgt in (claim, spare):
                if tgt is not None:
                    extra |= np.isfinite(tgt).all(axis=1)
            if hz is not None:
                extra |= hz.near
            if extra.any():
                crow = np.flatnonzero(extra)

                def grad_claimers(xs: np.ndarray, rows: np.ndarray) -> np.ndarray:
                    return energy_grad(xs[rows], crow[rows])

                sub = descend(pos_u[idx[crow]], grad_claimers, vmax_u, p, separable=True)
                disp_u[idx[crow]] = sub.disp_u
        else:
            res = descend(
                pos_u[idx], lambda x, rows: energy_grad(x[rows], rows), vmax_u, p, separable=True
            )
            disp_u[idx] = res.disp_u
        if claim is not None and p.claim_tether > 0:
            rows = np.flatnonzero(np.isfinite(claim).all(axis=1))
            anchor = tether_anchors(pos_u[idx], ent_r, ent_y, base_u, r_u, self.units.base_reach_u)
            x0, length = pos_u[idx][rows], p.claim_tether * r_u
            new = tether(x0 + disp_u[idx][rows], anchor[rows], length)
            # Already beyond the tether (stale anchor): only moves that do not pull away further.
            outside = np.linalg.norm(x0 - anchor[rows], axis=1) > length
            away = outside & (
                np.linalg.norm(x0 + disp_u[idx][rows] - anchor[rows], axis=1)
                > np.linalg.norm(x0 - anchor[rows], axis=1)
            )
            new[outside] = np.where(
                away[outside, None], x0[outside], (x0 + disp_u[idx][rows])[outside]
            )
            disp_u[idx[rows]] = new - x0
        return disp_u, {
            "iterations": res.iterations,
            "converged": res.converged,
            **view.info(),
            "claims": 0 if claim is None else int(np.isfinite(claim).all(axis=1).sum()),
            "spare_pulls": 0 if spare is None else int(np.isfinite(spare).all(axis=1).sum()),
        }

    def _pair_spares(
        self,
        t_step: int,
        pos_u: np.ndarray,
        networked: np.ndarray,
        tasks_u: np.ndarray,
        base_u: np.ndarray,
    ) -> int:
        """The base pairs spares with critical relays (planner/redundancy.py) and files the targets
        under this tick's broadcast stamp; returns the number of pairs. ``base_view='oracle'``
        and central information: the true positions and networked set (the heard variant is
        :meth:`_pair_spares_heard`)."""
        p, u = self.params, self.units
        graph = mesh_graph(pos_u, networked, tasks_u, base_u, u.radio_range_u, u.base_reach_u)
        crit = critical_counts(graph, len(pos_u))
        on = backbone(graph, len(pos_u))
        target = self._book.assign(
            pos_u,
            networked,
            crit,
            on,
            p.redundancy_reach,
            p.redundancy_min_cut,
            self._relay_priority(pos_u, crit, t_step * self.problem.dt_s),
        )
        self._spare_by_stamp[t_step] = target
        for old in [s for s in self._spare_by_stamp if s < t_step - p.tree_stale_steps - 1]:
            del self._spare_by_stamp[old]
        return len(self._book.pair_of)

    def _plan_central_pulled(
        self, pos_u: np.ndarray, t_step: int, view: CentralView, hz: _HazardPush | None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Central information with the claim and spare pulls and the hazard push: PhiIREMAN's
        joint NumPy descent (PhiremanPlanner._plan_central) plus those terms, every drone knowing
        every other."""
        p = self.params
        idx, disp_u = view.planned, view.disp_u
        if len(idx) == 0:
            return disp_u, view.info()
        x0 = pos_u[idx]
        claim = None
        if p.claim_gain > 0:
            claim = claim_targets_central(x0, self._open_by_stamp.get(t_step), p.claim_reach)
        spare = None
        if p.redundancy_gain > 0 and t_step in self._spare_by_stamp:
            spare = self._spare_by_stamp[t_step][idx].copy()
            if claim is not None:
                spare[np.isfinite(claim).all(axis=1)] = np.nan
        mask = ~np.eye(len(idx), dtype=bool)
        tree = self.tree
        assert tree is not None  # set by plan()

        def grad(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
            g = task_gradient(x, tree, p.thorn, p.nodes_only) + self._pair_grad(x, x, mask)
            if claim is not None:
                g = g + claim_gradient(x, claim, p.claim_gain)
            if spare is not None:
                g = g + claim_gradient(x, spare, p.redundancy_gain)
            if hz is not None:
                g = g + hz.gradient(x[rows], rows)
            return g

        res = descend(x0, grad, self.units.max_step_u, p)
        disp_u[idx] = res.disp_u
        return disp_u, {
            "iterations": res.iterations,
            "converged": res.converged,
            **view.info(),
            "claims": 0 if claim is None else int(np.isfinite(claim).all(axis=1).sum()),
            "spare_pulls": 0 if spare is None else int(np.isfinite(spare).all(axis=1).sum()),
        }

    def _relay_priority(self, pos_u: np.ndarray, crit: np.ndarray, t_s: float) -> np.ndarray | None:
        """Order in which critical relays get a spare: hazard awareness puts the relays inside an
        active zone first (the issue's "double them when [a path around] does not [exist]"),
        each group by the tasks its loss would cut; None (by cut count alone) without zones."""
        if self._hazards is None:
            return None
        in_zone = hazard_rate_per_s(self._hazards, self.units.to_m(pos_u), t_s) > 0
        return crit + (int(crit.max(initial=0)) + 1) * in_zone

    # -- hazard awareness (planner/hazard.py) --------------------------------------------------
    def _hazard_route(self, tree: TaskTree) -> TaskTree:
        """The tree routed around the active zones (``hazard_avoid``), in paper units."""
        p, u = self.params, self.units
        if not p.hazard_avoid or self._hazards is None:
            return tree
        tree_m = u.tree_to_m(tree)
        assert tree_m is not None  # a tree in, a tree out
        routed, _ = route_tree(
            tree_m, self._hazards, p.hazard_margin * u.unit_m, p.hazard_detour_cap
        )
        return dataclasses.replace(routed, nodes_m=u.to_u(routed.nodes_m))

    def _hazard_term(
        self, pos_u: np.ndarray, trees: list[Any], version_of: np.ndarray
    ) -> _HazardPush | None:
        """The push of the planned drones (rows of ``pos_u``) out of the active zones, or None.

        Each drone's weight on zone z is ``hazard_push_gain`` x rate_z x dt_s, 0 if a task inside
        z (of the tree copy the drone holds, ``trees[version_of[i]]``) is within r of it: that
        drone may be the one serving it."""
        p, u = self.params, self.units
        if p.hazard_push_gain <= 0 or self._hazards is None or len(pos_u) == 0:
            return None
        hm = self._hazards
        pos_m = u.to_m(pos_u)
        depth, _ = signed_depth(hm, pos_m)
        margin_m = p.hazard_margin * u.unit_m
        near = np.asarray((depth > -(margin_m + u.max_step_u * u.unit_m)).any(axis=1))
        if not near.any():
            return None
        rates = np.array([z.rate_per_s for z in hm.zones]) * self.problem.dt_s
        weight = np.broadcast_to(p.hazard_push_gain * rates, depth.shape).copy()
        r_m = u.radio_range_u * u.unit_m
        for v, tree in enumerate(trees):  # loop over tree versions held (few)
            rows = np.flatnonzero((version_of == v) & near)
            if tree is None or len(rows) == 0 or tree.n_tasks == 0:
                continue
            tasks_m = u.to_m(tree.nodes_m[1 : tree.n_tasks + 1])
            task_in = signed_depth(hm, tasks_m)[0] > 0  # (M, Z)
            if not task_in.any():
                continue
            d = np.linalg.norm(pos_m[rows, None, :] - tasks_m[None, :, :], axis=2)  # (n, M)
            serving = (d <= r_m).astype(float) @ task_in.astype(float) > 0  # (n, Z)
            weight[rows] = np.where(serving, 0.0, weight[rows])
        near &= (weight > 0).any(axis=1)
        if not near.any():
            return None
        return _HazardPush(hm, weight, margin_m, u.unit_m, near)

    def _update_recovery(
        self,
        pos_u: np.ndarray,
        base_u: np.ndarray,
        alive: np.ndarray,
        networked: np.ndarray,
        stamps: np.ndarray,
    ) -> None:
        """Per-drone rally targets: chosen when a drone is first seen disconnected, from the tree
        copy it holds; kept until it reconnects; home after ``rally_wait_steps`` at the point."""
        p = self.params
        n = len(pos_u)
        if self._target_u is None or len(self._target_u) != n or len(self._waited) != n:
            # Sized by the tick, not the problem: a station plans for the vehicles it has (fewer
            # than the mission's count on real links, more rows as vehicles are discovered);
            # rows keep their index, so the kept prefix stays with its drone.
            old_t = np.full((0, 2), np.nan) if self._target_u is None else self._target_u
            keep = min(n, len(old_t), len(self._waited))
            target_new, waited_new = np.full((n, 2), np.nan), np.zeros(n, dtype=np.int64)
            target_new[:keep], waited_new[:keep] = old_t[:keep], self._waited[:keep]
            self._target_u, self._waited = target_new, waited_new
        target = self._target_u
        target[networked] = np.nan
        self._waited[networked] = 0
        fresh = alive & ~networked & ~np.isfinite(target).all(axis=1)
        stamps = np.asarray(stamps)
        for s in np.unique(stamps[fresh]):  # loop over tree versions held, not drones
            rows = np.flatnonzero(fresh & (stamps == s))
            pts = self._rally_by_stamp.get(int(s)) if s >= 0 else None
            target[rows] = nearest_rally(pos_u[rows], pts) if pts is not None else np.nan
        # Waiting at the point (arrived, still cut off): count, then give up and fly home.
        has = alive & ~networked & np.isfinite(target).all(axis=1)
        arrived = np.zeros(n, dtype=bool)
        arrived[has] = np.linalg.norm(pos_u[has] - target[has], axis=1) <= 1e-6
        self._waited[arrived] += 1
        give_up = arrived & (self._waited > p.rally_wait_steps)
        target[give_up] = base_u
        # Forget rally sets no drone holds any more.
        held = set(np.unique(stamps[alive]).tolist())
        for s in [
            s for s in self._rally_by_stamp if s not in held and s != max(self._rally_by_stamp)
        ]:
            del self._rally_by_stamp[s]
        self.recovery_target_m = self.units.to_m(target)


@dataclass(frozen=True)
class _HazardPush:
    """The hazard push of one tick: :func:`planner.hazard.push_gradient` in paper units."""

    hazards: HazardMap
    weight: np.ndarray  # (n, Z) per planned drone and zone
    margin_m: float
    unit_m: float
    near: np.ndarray  # (n,) bool: drones the push may reach this tick

    def gradient(self, x_u: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return push_gradient(self.hazards, x_u * self.unit_m, self.weight[rows], self.margin_m)


def _active_hazards(tick: TickInput, dt_s: float, p: ResilientParams) -> HazardMap | None:
    """The zones active at this tick (mission time t_step x dt_s) when hazard awareness is on."""
    if tick.hazards is None or not (p.hazard_avoid or p.hazard_push_gain > 0):
        return None
    active = tick.hazards.active(tick.t_step * dt_s)
    return active if len(active) else None


def make_resilient(
    problem: ProblemConfig, params: dict[str, Any], rng: np.random.Generator
) -> ResilientPlanner:
    """ΦIREMAN-resilient with the parameters given (``info`` defaults to the paper's 'async')."""
    return ResilientPlanner(problem, parse_params(params, ResilientParams), rng)

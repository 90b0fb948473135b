"""Planning in 3-D over terrain: each drone's altitude, and relay positions that keep their links.

Two pieces of :class:`planner.terrain_aware.TerrainAwarePlanner` (docs/terrain.md §3):

* :func:`target_alt_amsl_m`, the altitude rule: a drone flies as high as the ceiling lets it,
  where it sees furthest, and lower only when it must. Flying on at full speed along its move, it
  can descend at most ``max_descent_m`` per step, so to stay under the ceiling over the ground
  ahead it may be no higher now than ``min_k (ground_k + ceiling + k * max_descent_m)`` over the
  samples ``k`` steps ahead. A drone heading for a canyon thus starts down before the rim, and
  crosses at the fastest its descent speed allows, instead of arriving at the rim at its cruise
  height and crawling down the wall. Never below ``clearance_m`` (plus a margin).
* :func:`relay_candidates`, the relay search: for a drone whose planned position would lose its
  link toward the base (or the last link of a crew it serves), a small set of nearby positions
  and altitudes (the move turned by a few angles, shortened, and the drone higher or lower) is
  tested with the compiled line-of-sight kernel against the drones that keep the mesh, and the
  crew; the candidate nearest the planned position that sees both ends wins.

* :func:`detour_tree`, the link predicate on the task tree's edges: an edge counts only if
  relays along it, at most ``relay_spacing_m`` apart at the ceiling, see each other
  (:func:`edges_relayable`); an edge that fails is bent through a Steiner node moved sideways
  from its midpoint, the shortest bend that passes, so the tree, and the potential that draws
  the drones to it, goes around a ridge instead of through it.

All are vectorised over drones, candidates and edges, each with a slow loop beside it
(``*_reference``) that tests/planner/test_terrain_heights.py compares it with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.steiner import TaskTree
from planner.terrain import Terrain, TerrainRadio, links_clear_reference

__all__ = [
    "HeightRule",
    "target_alt_amsl_m",
    "target_alt_amsl_m_reference",
    "candidate_moves",
    "relay_candidates",
    "relay_candidates_reference",
    "edges_relayable",
    "edges_relayable_reference",
    "detour_tree",
]


@dataclass(frozen=True)
class HeightRule:
    """How high a terrain-aware planner flies its drones (docs/terrain.md §3)."""

    clearance_m: float
    """The least height above the ground, metres (the mission's ``terrain.clearance_m``)."""
    ceiling_agl_m: float
    """The most height above the ground, metres (the mission's ``terrain.ceiling_agl_m``)."""
    max_climb_m: float
    """The largest climb in one step, metres (climb rate x control period)."""
    max_descent_m: float
    """The largest descent in one step, metres (descent rate x control period: the station
    limits descents to the vehicles' descent speed, docs/terrain.md §6.2)."""
    max_step_m: float
    """The longest horizontal move in one step, metres (speed x control period)."""
    margin_m: float = 3.0
    """Kept inside [clearance, ceiling], metres: the world shortens a step that ends a hair over
    the ceiling, and the ground between path samples can rise a little."""
    lookahead_steps: int = 40
    """How many steps of full-speed flight ahead the rule looks (40: 400 m at 10 m/s)."""
    angles_deg: tuple[float, ...] = (0.0, 45.0, -45.0, 90.0, -90.0)
    """Relay search: the planned move turned by these angles."""
    move_fractions: tuple[float, ...] = (1.0, 0.5)
    """Relay search: and scaled by these fractions (plus the drone staying put)."""
    relay_spacing_m: float | None = None
    """Tree edges: the longest hop between relays along an edge, metres; None: half the link
    budget's range."""

    def __post_init__(self) -> None:
        if not self.ceiling_agl_m - self.margin_m > self.clearance_m + self.margin_m:
            raise ValueError("HeightRule: no room between clearance and ceiling after margins")
        if not (
            self.max_climb_m > 0
            and self.max_descent_m > 0
            and self.max_step_m > 0
            and self.lookahead_steps >= 0
        ):
            raise ValueError("HeightRule: max_climb_m, max_descent_m and max_step_m must be > 0")

    @property
    def low_agl_m(self) -> float:
        """The lowest height above the ground the rule commands, metres."""
        return self.clearance_m + self.margin_m

    @property
    def high_agl_m(self) -> float:
        """The highest height above the ground the rule commands, metres."""
        return self.ceiling_agl_m - self.margin_m

    def reach_m(self, alt_now_m: np.ndarray, goal_m: np.ndarray) -> np.ndarray:
        """(N,) the altitude reached in one step from ``alt_now_m`` toward ``goal_m`` (metres
        AMSL): at most ``max_climb_m`` up and ``max_descent_m`` down."""
        now = np.asarray(alt_now_m, dtype=float)
        return np.asarray(now + np.clip(goal_m - now, -self.max_descent_m, self.max_climb_m))


def target_alt_amsl_m(
    terrain: Terrain, end_ne_m: np.ndarray, dir_ne: np.ndarray, rule: HeightRule
) -> np.ndarray:
    """(N,) the altitude AMSL each drone should reach at the end of its step, metres.

    ``end_ne_m`` (N, 2): where the step ends; ``dir_ne`` (N, 2): the unit direction it flies on
    (zero rows: a drone that holds its position, which only the ground under it limits). The
    highest altitude from which, flying on at ``max_step_m`` per step and descending at most
    ``max_descent_m`` per step, the drone stays under ``ceiling - margin`` at every sample ahead;
    never below ``clearance + margin`` over the end (module docstring)."""
    end = np.asarray(end_ne_m, dtype=float).reshape(-1, 2)
    k = np.arange(rule.lookahead_steps + 1, dtype=float)  # (K,)
    pts = end[:, None, :] + (k * rule.max_step_m)[None, :, None] * np.asarray(dir_ne)[:, None, :]
    g = terrain.height_m(pts)  # (N, K)
    cap = (g + (rule.high_agl_m + k * rule.max_descent_m)[None, :]).min(axis=1)
    return np.asarray(np.maximum(cap, g[:, 0] + rule.low_agl_m))


def target_alt_amsl_m_reference(
    terrain: Terrain, end_ne_m: np.ndarray, dir_ne: np.ndarray, rule: HeightRule
) -> np.ndarray:
    """:func:`target_alt_amsl_m` by plain loops (for tests)."""
    out = np.empty(len(end_ne_m))
    for i in range(len(end_ne_m)):
        n0, e0 = float(end_ne_m[i, 0]), float(end_ne_m[i, 1])
        best = math.inf
        for k in range(rule.lookahead_steps + 1):
            d = k * rule.max_step_m
            g = terrain.height_m_reference(n0 + d * dir_ne[i, 0], e0 + d * dir_ne[i, 1])
            best = min(best, g + rule.high_agl_m + k * rule.max_descent_m)
        out[i] = max(best, terrain.height_m_reference(n0, e0) + rule.low_agl_m)
    return out


def candidate_moves(disp_m: np.ndarray, rule: HeightRule) -> np.ndarray:
    """(B, C, 2) the relay search's horizontal moves for (B, 2) planned moves: each turned by
    ``angles_deg`` and scaled by ``move_fractions``, then staying put (the last candidate)."""
    a = np.deg2rad(np.asarray(rule.angles_deg, dtype=float))
    c, s = np.cos(a), np.sin(a)
    d = np.asarray(disp_m, dtype=float).reshape(-1, 2)
    turned = np.stack(
        [
            c[None, :] * d[:, :1] - s[None, :] * d[:, 1:],
            s[None, :] * d[:, :1] + c[None, :] * d[:, 1:],
        ],
        axis=-1,
    )  # (B, A, 2)
    f = np.asarray(rule.move_fractions, dtype=float)
    moves = (f[None, :, None, None] * turned[:, None, :, :]).reshape(len(d), -1, 2)
    return np.concatenate([moves, np.zeros((len(d), 1, 2))], axis=1)


def _candidates(
    terrain: Terrain,
    pos_ne_m: np.ndarray,
    alt_now_m: np.ndarray,
    disp_m: np.ndarray,
    alt_goal_m: np.ndarray,
    rule: HeightRule,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The candidates of :func:`relay_candidates`: (B, C*3, 2) positions, (B, C*3) altitudes
    AMSL (the goal, one climb step up, one descent step down; each within reach and within
    [clearance, ceiling] over its ground) and (B, C*3) bool, reachable."""
    moves = candidate_moves(disp_m, rule)  # (B, C, 2)
    b, c = moves.shape[:2]
    ne = pos_ne_m[:, None, :] + moves
    g = terrain.height_m(ne)  # (B, C)
    offsets = np.array([0.0, rule.max_climb_m, -rule.max_descent_m])
    alt = alt_goal_m[:, None, None] + offsets[None, None, :]  # (B, 1, 3)
    lo = alt_now_m[:, None, None] - rule.max_descent_m
    hi = alt_now_m[:, None, None] + rule.max_climb_m
    alt = np.clip(alt, lo, hi)
    alt = np.clip(alt, g[:, :, None] + rule.low_agl_m, g[:, :, None] + rule.high_agl_m)  # (B, C, 3)
    reach = (alt >= lo - 1e-9) & (alt <= hi + 1e-9)
    ne3 = np.broadcast_to(ne[:, :, None, :], (b, c, 3, 2)).reshape(b, c * 3, 2)
    return ne3, alt.reshape(b, c * 3), reach.reshape(b, c * 3)


def relay_candidates(
    radio: TerrainRadio,
    pos_ne_m: np.ndarray,
    alt_now_m: np.ndarray,
    disp_m: np.ndarray,
    alt_goal_m: np.ndarray,
    anchors_m: np.ndarray,
    crews_m: np.ndarray,
    needs_crew: np.ndarray,
    rule: HeightRule,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For B drones that would lose their links: the nearest candidate that sees both ends.

    Parameters
    ----------
    radio : the terrain radio
    pos_ne_m : (B, 2) where the drones are, metres
    alt_now_m : (B,) their altitudes AMSL, metres
    disp_m : (B, 2) their planned moves, metres
    alt_goal_m : (B,) the altitude AMSL they were to reach, metres (:func:`target_alt_amsl_m`)
    anchors_m : (A, 3) the antennas toward the base that keep the mesh (drones that keep their
        links, at their planned positions, and the base), north, east, metres AMSL
    crews_m : (M, 3) the crews' radios
    needs_crew : (B, M) bool, the crews each drone must keep a link to (it is their last one)
    rule : candidates and limits

    Returns
    -------
    found : (B,) bool, a candidate sees an anchor and every crew it needs
    ne_m : (B, 2) its position (the planned one where none is found), metres
    alt_m : (B,) its altitude AMSL, metres (the goal where none is found)
    """
    pos = np.asarray(pos_ne_m, dtype=float).reshape(-1, 2)
    ne, alt, ok = _candidates(radio.terrain, pos, alt_now_m, disp_m, alt_goal_m, rule)
    b, c = ok.shape
    cand3 = np.concatenate([ne, alt[:, :, None]], axis=2).reshape(b * c, 3)
    rng_m = radio.budget.max_range_m

    def sees(targets: np.ndarray, want: np.ndarray) -> np.ndarray:
        """(B*C, T) bool: candidate -> target link closes, only where ``want`` (B*C, T)."""
        ci, ti = np.nonzero(
            want
            & (np.hypot(*(cand3[:, None, :2] - targets[None, :, :2]).transpose(2, 0, 1)) <= rng_m)
        )
        out = np.zeros(want.shape, dtype=bool)
        if len(ci):
            out[ci, ti] = radio.links_clear(cand3[ci], targets[ti])
        return out

    anchors = np.asarray(anchors_m, dtype=float).reshape(-1, 3)
    flat_ok = ok.reshape(-1)
    to_anchor = sees(anchors, np.broadcast_to(flat_ok[:, None], (b * c, len(anchors))))
    good = to_anchor.any(axis=1) & flat_ok
    crews = np.asarray(crews_m, dtype=float).reshape(-1, 3)
    if len(crews):
        need = np.repeat(np.asarray(needs_crew, dtype=bool), c, axis=0) & good[:, None]
        to_crew = sees(crews, need)
        good &= (to_crew | ~need).all(axis=1)
    planned = pos + np.asarray(disp_m, dtype=float)
    cost = np.sum((ne - planned[:, None, :]) ** 2, axis=2) + (alt - alt_goal_m[:, None]) ** 2
    cost = np.where(good.reshape(b, c), cost, np.inf)
    pick = np.argmin(cost, axis=1)
    found = np.isfinite(cost[np.arange(b), pick])
    ne_out = np.where(found[:, None], ne[np.arange(b), pick], planned)
    alt_out = np.where(found, alt[np.arange(b), pick], alt_goal_m)
    return found, ne_out, alt_out


def relay_candidates_reference(
    radio: TerrainRadio,
    pos_ne_m: np.ndarray,
    alt_now_m: np.ndarray,
    disp_m: np.ndarray,
    alt_goal_m: np.ndarray,
    anchors_m: np.ndarray,
    crews_m: np.ndarray,
    needs_crew: np.ndarray,
    rule: HeightRule,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`relay_candidates` by plain loops over drones, candidates and ends (for tests)."""
    ne, alt, ok = _candidates(
        radio.terrain, np.asarray(pos_ne_m, float), alt_now_m, disp_m, alt_goal_m, rule
    )
    b, c = ok.shape
    found = np.zeros(b, dtype=bool)
    ne_out = np.asarray(pos_ne_m, float) + np.asarray(disp_m, float)
    alt_out = np.asarray(alt_goal_m, float).copy()
    for i in range(b):
        best, best_j = math.inf, -1
        for j in range(c):
            if not ok[i, j]:
                continue
            p = np.array([ne[i, j, 0], ne[i, j, 1], alt[i, j]])
            seen_anchor = False
            for a in np.asarray(anchors_m, float).reshape(-1, 3):
                if math.hypot(p[0] - a[0], p[1] - a[1]) > radio.budget.max_range_m:
                    continue
                if radio.links_clear(p[None], a[None])[0]:
                    seen_anchor = True
                    break
            if not seen_anchor:
                continue
            crews_ok = True
            for k, cr in enumerate(np.asarray(crews_m, float).reshape(-1, 3)):
                if not needs_crew[i, k]:
                    continue
                near = math.hypot(p[0] - cr[0], p[1] - cr[1]) <= radio.budget.max_range_m
                if not (near and radio.links_clear(p[None], cr[None])[0]):
                    crews_ok = False
                    break
            if not crews_ok:
                continue
            planned = np.asarray(pos_ne_m[i], float) + np.asarray(disp_m[i], float)
            cost = float(np.sum((ne[i, j] - planned) ** 2) + (alt[i, j] - alt_goal_m[i]) ** 2)
            if cost < best:
                best, best_j = cost, j
        if best_j >= 0:
            found[i] = True
            ne_out[i] = ne[i, best_j]
            alt_out[i] = alt[i, best_j]
    return found, ne_out, alt_out


# --------------------------------------------------------------------------------------------
# Tree edges over terrain


def _relay_samples(
    terrain: Terrain, a_ne_m: np.ndarray, b_ne_m: np.ndarray, spacing_m: float, agl_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The relays along E edges: (P, 3) and (P, 3) the two ends of every hop between
    consecutive relays (north, east, metres AMSL at ``agl_m`` over the ground) and (P,) the edge
    of each hop. An edge of length L has ceil(L / spacing_m) hops (at least 1)."""
    a = np.asarray(a_ne_m, dtype=float).reshape(-1, 2)
    b = np.asarray(b_ne_m, dtype=float).reshape(-1, 2)
    hops = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / spacing_m)).astype(np.int64)
    edge = np.repeat(np.arange(len(a)), hops)
    k = np.arange(int(hops.sum())) - np.repeat(np.cumsum(hops) - hops, hops)  # hop index in edge
    f0 = (k / hops[edge])[:, None]
    f1 = ((k + 1) / hops[edge])[:, None]
    p0 = a[edge] + f0 * (b - a)[edge]
    p1 = a[edge] + f1 * (b - a)[edge]
    h = terrain.height_m(np.concatenate([p0, p1])) + agl_m
    return (
        np.column_stack([p0, h[: len(p0)]]),
        np.column_stack([p1, h[len(p0) :]]),
        edge,
    )


def edges_relayable(
    radio: TerrainRadio, a_ne_m: np.ndarray, b_ne_m: np.ndarray, spacing_m: float, agl_m: float
) -> np.ndarray:
    """(E,) bool: relays every ``spacing_m`` at most along the edge a -> b, ``agl_m`` above the
    ground, see each other (the link predicate on the task tree's edges, docs/terrain.md §3)."""
    p0, p1, edge = _relay_samples(radio.terrain, a_ne_m, b_ne_m, spacing_m, agl_m)
    clear = radio.links_clear(p0, p1) if len(edge) else np.zeros(0, dtype=bool)
    blocked = np.bincount(edge[~clear], minlength=len(np.asarray(a_ne_m).reshape(-1, 2)))
    return np.asarray(blocked == 0)


def edges_relayable_reference(
    radio: TerrainRadio, a_ne_m: np.ndarray, b_ne_m: np.ndarray, spacing_m: float, agl_m: float
) -> np.ndarray:
    """:func:`edges_relayable` by plain loops over edges and hops (for tests)."""
    t = radio.terrain
    out = np.ones(len(a_ne_m), dtype=bool)
    for e in range(len(a_ne_m)):
        a, b = np.asarray(a_ne_m[e], float), np.asarray(b_ne_m[e], float)
        hops = max(1, int(math.ceil(float(np.linalg.norm(b - a)) / spacing_m)))
        for k in range(hops):
            p = a + (k / hops) * (b - a)
            q = a + ((k + 1) / hops) * (b - a)
            p3 = np.array([[p[0], p[1], t.height_m_reference(p[0], p[1]) + agl_m]])
            q3 = np.array([[q[0], q[1], t.height_m_reference(q[0], q[1]) + agl_m]])
            if not links_clear_reference(t, radio.budget, p3, q3)[0]:
                out[e] = False
                break
    return out


def detour_tree(
    tree_m: TaskTree,
    radio: TerrainRadio,
    rule: HeightRule,
    offsets_m: tuple[float, ...] = (100.0, -100.0, 200.0, -200.0, 300.0, -300.0, 400.0, -400.0),
) -> tuple[TaskTree, int]:
    """The task tree (metres) with every edge that relays cannot hold over the terrain
    (:func:`edges_relayable` at ``rule.high_agl_m``, relays every ``rule.relay_spacing_m``)
    bent through a new Steiner node: the shortest of the edge's midpoint moved sideways by
    ``offsets_m`` for which both halves can be relayed. An edge with no such detour stays as it
    is. Returns the tree and the number of edges bent."""
    spacing = rule.relay_spacing_m or radio.budget.max_range_m / 2.0
    a, b = tree_m.segments()  # child end, parent end
    ok = edges_relayable(radio, a, b, spacing, rule.high_agl_m)
    bad = np.flatnonzero(~ok & (np.linalg.norm(b - a, axis=1) > 0))
    if len(bad) == 0:
        return tree_m, 0
    ab = b[bad] - a[bad]
    perp = np.column_stack([-ab[:, 1], ab[:, 0]]) / np.linalg.norm(ab, axis=1)[:, None]
    off = np.asarray(offsets_m, dtype=float)
    mid = 0.5 * (a[bad] + b[bad])[:, None, :] + off[None, :, None] * perp[:, None, :]  # (B, O, 2)
    n_b, n_o = mid.shape[:2]
    m_flat = mid.reshape(-1, 2)
    a_rep = np.repeat(a[bad], n_o, axis=0)
    b_rep = np.repeat(b[bad], n_o, axis=0)
    both = edges_relayable(
        radio,
        np.concatenate([a_rep, m_flat]),
        np.concatenate([m_flat, b_rep]),
        spacing,
        rule.high_agl_m,
    )
    good = (both[: len(m_flat)] & both[len(m_flat) :]).reshape(n_b, n_o)
    length = np.linalg.norm(m_flat - a_rep, axis=1) + np.linalg.norm(b_rep - m_flat, axis=1)
    length = np.where(good, length.reshape(n_b, n_o), np.inf)
    pick = np.argmin(length, axis=1)
    bent = np.isfinite(length[np.arange(n_b), pick])
    if not bent.any():
        return tree_m, 0
    child = bad[bent] + 1  # segment e is node e + 1's edge to its parent
    new_nodes = mid[np.flatnonzero(bent), pick[bent]]
    k = tree_m.n_nodes
    parent = np.concatenate([tree_m.parent, tree_m.parent[child]])
    parent[child] = k + np.arange(len(child))
    nodes = np.concatenate([tree_m.nodes_m, new_nodes])
    return TaskTree(nodes, parent, tree_m.n_tasks), int(bent.sum())

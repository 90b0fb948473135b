"""Planning in 3-D over terrain: each drone's altitude, and relay positions that keep their links.

Two pieces of :class:`planner.terrain_aware.TerrainAwarePlanner` (docs/terrain.md §3):

* :func:`target_alt_amsl_m`, the altitude rule: a drone flies as high as the ceiling lets it,
  where it sees furthest, and lower only when it must. Flying on at full speed along its move, it
  can descend at most ``max_climb_m`` per step, so to stay under the ceiling over the ground
  ahead it may be no higher now than ``min_k (ground_k + ceiling + k * max_climb_m)`` over the
  samples ``k`` steps ahead. A drone heading for a canyon thus starts down before the rim, and
  crosses at the fastest the climb rate allows, instead of arriving at the rim at its cruise
  height and crawling down the wall. Never below ``clearance_m`` (plus a margin).
* :func:`relay_candidates`, the relay search: for a drone whose planned position would lose its
  link toward the base (or the last link of a crew it serves), a small set of nearby positions
  and altitudes (the move turned by a few angles, shortened, and the drone higher or lower) is
  tested with the compiled line-of-sight kernel against the drones that keep the mesh, and the
  crew; the candidate nearest the planned position that sees both ends wins.

Both are vectorised over drones and candidates, each with a slow loop beside it
(``*_reference``) that tests/planner/test_terrain_heights.py compares it with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.terrain import Terrain, TerrainRadio

__all__ = [
    "HeightRule",
    "target_alt_amsl_m",
    "target_alt_amsl_m_reference",
    "candidate_moves",
    "relay_candidates",
    "relay_candidates_reference",
]


@dataclass(frozen=True)
class HeightRule:
    """How high a terrain-aware planner flies its drones (docs/terrain.md §3)."""

    clearance_m: float
    """The least height above the ground, metres (the mission's ``terrain.clearance_m``)."""
    ceiling_agl_m: float
    """The most height above the ground, metres (the mission's ``terrain.ceiling_agl_m``)."""
    max_climb_m: float
    """The largest altitude change in one step, metres (climb rate x control period)."""
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

    def __post_init__(self) -> None:
        if not self.ceiling_agl_m - self.margin_m > self.clearance_m + self.margin_m:
            raise ValueError("HeightRule: no room between clearance and ceiling after margins")
        if not (self.max_climb_m > 0 and self.max_step_m > 0 and self.lookahead_steps >= 0):
            raise ValueError("HeightRule: max_climb_m and max_step_m must be > 0")

    @property
    def low_agl_m(self) -> float:
        """The lowest height above the ground the rule commands, metres."""
        return self.clearance_m + self.margin_m

    @property
    def high_agl_m(self) -> float:
        """The highest height above the ground the rule commands, metres."""
        return self.ceiling_agl_m - self.margin_m


def target_alt_amsl_m(
    terrain: Terrain, end_ne_m: np.ndarray, dir_ne: np.ndarray, rule: HeightRule
) -> np.ndarray:
    """(N,) the altitude AMSL each drone should reach at the end of its step, metres.

    ``end_ne_m`` (N, 2): where the step ends; ``dir_ne`` (N, 2): the unit direction it flies on
    (zero rows: a drone that holds its position, which only the ground under it limits). The
    highest altitude from which, flying on at ``max_step_m`` per step and descending at most
    ``max_climb_m`` per step, the drone stays under ``ceiling - margin`` at every sample ahead;
    never below ``clearance + margin`` over the end (module docstring)."""
    end = np.asarray(end_ne_m, dtype=float).reshape(-1, 2)
    k = np.arange(rule.lookahead_steps + 1, dtype=float)  # (K,)
    pts = end[:, None, :] + (k * rule.max_step_m)[None, :, None] * np.asarray(dir_ne)[:, None, :]
    g = terrain.height_m(pts)  # (N, K)
    cap = (g + (rule.high_agl_m + k * rule.max_climb_m)[None, :]).min(axis=1)
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
            best = min(best, g + rule.high_agl_m + k * rule.max_climb_m)
        out[i] = max(best, terrain.height_m_reference(n0, e0) + rule.low_agl_m)
    return out


def candidate_moves(disp_m: np.ndarray, rule: HeightRule) -> np.ndarray:
    """(B, C, 2) the relay search's horizontal moves for (B, 2) planned moves: each turned by
    ``angles_deg`` and scaled by ``move_fractions``, then staying put (the last candidate)."""
    a = np.deg2rad(np.asarray(rule.angles_deg, dtype=float))
    c, s = np.cos(a), np.sin(a)
    d = np.asarray(disp_m, dtype=float).reshape(-1, 2)
    turned = np.stack(
        [c[None, :] * d[:, :1] - s[None, :] * d[:, 1:], s[None, :] * d[:, :1] + c[None, :] * d[:, 1:]],
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
    AMSL (the goal, one climb step up, one down; each within reach and within [clearance,
    ceiling] over its ground) and (B, C*3) bool, reachable."""
    moves = candidate_moves(disp_m, rule)  # (B, C, 2)
    b, c = moves.shape[:2]
    ne = pos_ne_m[:, None, :] + moves
    g = terrain.height_m(ne)  # (B, C)
    offsets = np.array([0.0, rule.max_climb_m, -rule.max_climb_m])
    alt = alt_goal_m[:, None, None] + offsets[None, None, :]  # (B, 1, 3)
    alt = np.clip(alt, alt_now_m[:, None, None] - rule.max_climb_m, alt_now_m[:, None, None] + rule.max_climb_m)
    alt = np.clip(alt, g[:, :, None] + rule.low_agl_m, g[:, :, None] + rule.high_agl_m)  # (B, C, 3)
    reach = np.abs(alt - alt_now_m[:, None, None]) <= rule.max_climb_m + 1e-9
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
        ci, ti = np.nonzero(want & (np.hypot(*(cand3[:, None, :2] - targets[None, :, :2]).transpose(2, 0, 1)) <= rng_m))
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
    ne, alt, ok = _candidates(radio.terrain, np.asarray(pos_ne_m, float), alt_now_m, disp_m, alt_goal_m, rule)
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

"""Terrain-aware planning: any registered planner, with the links it keeps checked over terrain.

The planners of this package think in discs (docs/design/model.md §4): a link holds within r.
Over terrain (planner.terrain) a ridge or a canyon wall cuts links the disc keeps. This wrapper is
the link-predicate hook (docs/terrain.md §3): it takes the inner planner's displacements and,
before they are flown, predicts the mesh at the new positions with the terrain radio, and holds
back the moves that would cut a networked drone from the base or the last link of a connected
crew:

1. every networked drone moves by its full instruction;
2. drones that would drop out of the base's component, and drones that are a connected crew's
   only links when the crew would lose them, move by the next, shorter fraction
   (``fractions``), and the mesh is predicted again;
3. until nothing breaks or they stay put (a handful of passes, each one connectivity test).

A drone that stays put keeps its links to the drones that stay put; the truth decides the rest.

With a :class:`planner.terrain_heights.HeightRule` (``heights``) the wrapper plans in 3-D: each
drone gets its own altitude between the clearance and the ceiling
(:func:`planner.terrain_heights.target_alt_amsl_m`: as high as it may, lower ahead of low
ground), returned as ``PlanOutput.alt_agl_m``, and the mesh is predicted at those altitudes (from
``TickInput.alt_amsl_m``, what the drones fly at now). Before a breaking drone is held back, the
relay search (:func:`planner.terrain_heights.relay_candidates`) looks for a nearby position and
altitude that sees both ends: a drone that keeps the mesh, and every crew it is the last link of.
An inner planner that follows a task tree (``tree_transform``, planner.phireman) follows one whose
edges relays can hold over the terrain (:func:`planner.terrain_heights.detour_tree`).
Without ``heights`` every drone is predicted at ``alt_agl_m`` above the ground.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.methods import PlanOutput, Planner, TickInput
from planner.terrain import TerrainRadio
from planner.steiner import TaskTree
from planner.terrain_heights import (
    HeightRule,
    detour_tree,
    relay_candidates,
    target_alt_amsl_m,
)

__all__ = ["TerrainAwarePlanner"]


@dataclass
class TerrainAwarePlanner:
    """``inner`` with its moves checked against the terrain radio (module docstring)."""

    inner: Planner
    radio: TerrainRadio
    alt_agl_m: float
    """Height above the ground the drones fly at, metres."""
    crew_antenna_agl_m: float = 1.5
    """Height of a crew's radio above the ground, metres."""
    base_antenna_agl_m: float = 1.5
    """Height of the base's antenna above the ground, metres."""
    fractions: tuple[float, ...] = (1.0, 0.5, 0.0)
    """The move fractions tried, longest first; the last should be 0 (stay put)."""
    heights: HeightRule | None = None
    """Plan altitudes and search relay positions in 3-D (module docstring); None: every drone at
    ``alt_agl_m``, moves only held back."""

    def __post_init__(self) -> None:
        # In 3-D, an inner planner that follows a task tree follows one whose edges relays can
        # hold over the terrain (planner.terrain_heights.detour_tree).
        if self.heights is not None and hasattr(self.inner, "tree_transform"):
            self.inner.tree_transform = self._route_tree
        # An inner planner that keeps links of a candidate graph (planner.mccst) keeps only the
        # links that clear the terrain.
        if hasattr(self.inner, "edge_filter"):
            self.inner.edge_filter = self._edges_clear
        self.tree_bends = 0
        """Tree edges bent around the terrain at the last tick."""

    def _route_tree(self, tree_m: TaskTree) -> TaskTree:
        assert self.heights is not None  # set in 3-D only
        tree, self.tree_bends = detour_tree(tree_m, self.radio, self.heights)
        return tree

    def _edges_clear(self, tick: TickInput, members: np.ndarray, edges: np.ndarray) -> np.ndarray:
        """(E,) bool: which candidate links of the drones ``members`` (indices into the tick) hold
        over the terrain at their altitudes now; ``edges`` (E, 2), j == len(members) the base."""
        pos = np.asarray(tick.pos_m, dtype=float)[members]
        alt = self._alt_now(tick)[members]
        n = len(members)
        a = np.column_stack([pos[edges[:, 0]], alt[edges[:, 0]]])
        j = np.minimum(edges[:, 1], n - 1)
        b = np.column_stack([pos[j], alt[j]])
        base = np.array([tick.base_m[0], tick.base_m[1], self._base_h(tick)])
        b[edges[:, 1] == n] = base
        return self.radio.links_clear(a, b)

    def _alt_now(self, tick: TickInput) -> np.ndarray:
        """(N,) the drones' altitudes AMSL: from telemetry, or ``alt_agl_m`` over the ground."""
        if tick.alt_amsl_m is not None:
            return np.asarray(tick.alt_amsl_m, dtype=float)
        return self.radio.terrain.height_m(np.asarray(tick.pos_m, dtype=float)) + self.alt_agl_m

    def _mesh(
        self, pos_ne_m: np.ndarray, alt_m: np.ndarray, tick: TickInput, members: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The predicted (N,) networked mask and (M, N) crew links of ``members`` at
        ``pos_ne_m`` and (N,) altitudes AMSL ``alt_m``."""
        act = self.radio.active_mask(pos_ne_m, alt_m, members, tick.base_m, self._base_h(tick))
        tp = tick.task_pos_m
        m, n = len(tp), len(pos_ne_m)
        links = np.zeros((m, n), dtype=bool)
        rows = np.flatnonzero(act)
        if m and len(rows):
            t3 = self._crews(tick)
            d3 = np.column_stack([pos_ne_m[rows], alt_m[rows]])
            ti, k = np.divmod(np.arange(m * len(rows)), len(rows))
            near = np.hypot(*(t3[ti, :2] - d3[k, :2]).T) <= self.radio.budget.max_range_m
            ok = np.zeros(len(ti), dtype=bool)
            ok[near] = self.radio.links_clear(d3[k[near]], t3[ti[near]])
            links[ti[ok], rows[k[ok]]] = True
        return act, links

    def _base_h(self, tick: TickInput) -> float:
        """The base's antenna, metres AMSL."""
        return float(self.radio.terrain.height_m(tick.base_m[None])[0]) + self.base_antenna_agl_m

    def _crews(self, tick: TickInput) -> np.ndarray:
        """(M, 3) the crews' radios (north, east, metres AMSL)."""
        tp = np.asarray(tick.task_pos_m, dtype=float).reshape(-1, 2)
        return np.column_stack([tp, self.radio.terrain.height_m(tp) + self.crew_antenna_agl_m])

    def _altitudes(
        self, pos: np.ndarray, move: np.ndarray, alt_now: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(N,) the altitude goal AMSL at the end of each move and (N,) the altitude the drone
        reaches this step (the goal, within one climb or descent step of ``alt_now``)."""
        rule = self.heights
        if rule is None:
            goal = self.radio.terrain.height_m(pos + move) + self.alt_agl_m
            return goal, goal
        norm = np.linalg.norm(move, axis=1)
        direction = move / np.where(norm > 0, norm, 1.0)[:, None]
        goal = target_alt_amsl_m(self.radio.terrain, pos + move, direction, rule)
        return goal, rule.reach_m(alt_now, goal)

    def plan(self, tick: TickInput) -> PlanOutput:
        out = self.inner.plan(tick)
        disp = np.asarray(out.disp_m, dtype=float)
        pos = np.asarray(tick.pos_m, dtype=float)
        ground = self.radio.terrain
        alt_now = self._alt_now(tick)
        members = np.asarray(tick.networked, dtype=bool) & np.asarray(tick.alive, dtype=bool)
        level = np.zeros(len(pos), dtype=np.int64)  # index into fractions, per drone
        frac = np.asarray(self.fractions, dtype=float)
        now_act, now_links = self._mesh(pos, alt_now, tick, members)
        crews_now = now_links.any(axis=1)
        # Relays placed by the search (3-D only): their end position and altitude.
        placed = np.zeros(len(pos), dtype=bool)
        placed_ne, placed_alt = pos.copy(), alt_now.copy()
        tried = np.zeros(len(pos), dtype=bool)
        passes = 0
        for _ in range(3 * len(frac)):  # a handful of passes, each one predicted mesh
            move = frac[level][:, None] * disp
            goal, alt = self._altitudes(pos, move, alt_now)
            new = np.where(placed[:, None], placed_ne, pos + move)
            alt = np.where(placed, placed_alt, alt)
            act, links = self._mesh(new, alt, tick, members)
            passes += 1
            lost_crews = np.asarray(crews_now & ~links.any(axis=1))
            broken = members & now_act & ~act
            broken |= members & now_links[lost_crews].any(axis=0)
            broken &= level < len(frac) - 1
            if not broken.any():
                break
            again = broken & placed  # a placed relay that still breaks: held back instead
            placed &= ~again
            fresh = broken & ~again & ~tried & (self.heights is not None)
            if fresh.any():
                tried |= fresh
                rows = np.flatnonzero(fresh)
                needs = (now_links[:, rows] & lost_crews[:, None]).T  # (B, M)
                found, ne_f, alt_f = self._search(
                    tick,
                    pos[rows],
                    alt_now[rows],
                    move[rows],
                    goal[rows],
                    new,
                    alt,
                    act & ~broken,
                    needs,
                )
                placed[rows[found]] = True
                placed_ne[rows], placed_alt[rows] = ne_f, alt_f
            level[broken & ~placed] += 1
        final_move = np.where(placed[:, None], placed_ne - pos, frac[level][:, None] * disp)
        info = dict(out.info)
        info["terrain_held"] = int(((level > 0) & ~placed).sum())
        info["terrain_placed"] = int(placed.sum())
        info["terrain_passes"] = passes
        info["terrain_tree_bends"] = self.tree_bends
        alt_agl = None
        if self.heights is not None:
            goal, alt = self._altitudes(pos, final_move, alt_now)
            goal = np.where(placed, placed_alt, goal)
            alt_agl = goal - ground.height_m(pos + final_move)
        return PlanOutput(final_move, out.tree, info, alt_agl)

    def _search(
        self,
        tick: TickInput,
        pos: np.ndarray,
        alt_now: np.ndarray,
        move: np.ndarray,
        goal: np.ndarray,
        new: np.ndarray,
        alt: np.ndarray,
        keeps: np.ndarray,
        needs: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The relay search (:func:`planner.terrain_heights.relay_candidates`) for B drones at
        ``pos`` (B, 2) planning ``move`` (B, 2) to ``goal`` (B,): the anchors are the drones
        that keep the mesh (``keeps``, (N,) bool) at their planned positions ``new`` / ``alt``,
        and the base; ``needs`` (B, M), the crews each is the last link of."""
        assert self.heights is not None  # the 3-D planner only
        anchors = np.concatenate(
            [
                np.column_stack([new[keeps], alt[keeps]]),
                [[tick.base_m[0], tick.base_m[1], self._base_h(tick)]],
            ]
        )
        return relay_candidates(
            self.radio, pos, alt_now, move, goal, anchors, self._crews(tick), needs, self.heights
        )

"""Terrain-aware planning: any registered planner, with the links it keeps checked over terrain.

The planners of this package think in discs (docs/design/model.md §4): a link holds within r.
Over terrain (planner.terrain) a ridge or a canyon wall cuts links the disc keeps. This wrapper is
the link-predicate hook (docs/terrain.md §3): it takes the inner planner's displacements and,
before they are flown, predicts the mesh at the new positions with the terrain radio - drones at
``alt_agl_m`` above the map's ground, as the terrain-following autopilot flies them - and holds
back the moves that would cut a networked drone from the base or the last link of a connected
crew:

1. every networked drone moves by its full instruction;
2. drones that would drop out of the base's component, and drones that are a connected crew's
   only links when the crew would lose them, move by the next, shorter fraction
   (``fractions``), and the mesh is predicted again;
3. until nothing breaks or they stay put (a handful of passes, each one connectivity test).

A drone that stays put keeps its links to the drones that stay put; the truth decides the rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.methods import PlanOutput, Planner, TickInput
from planner.terrain import TerrainRadio

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

    def _mesh(
        self, pos_ne_m: np.ndarray, tick: TickInput, members: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The predicted (N,) networked mask and (M, N) crew links of ``members`` at
        ``pos_ne_m``."""
        ground = self.radio.terrain
        h = ground.height_m(pos_ne_m) + self.alt_agl_m
        base_h = float(ground.height_m(tick.base_m[None])[0]) + self.base_antenna_agl_m
        act = self.radio.active_mask(pos_ne_m, h, members, tick.base_m, base_h)
        tp = tick.task_pos_m
        m, n = len(tp), len(pos_ne_m)
        links = np.zeros((m, n), dtype=bool)
        rows = np.flatnonzero(act)
        if m and len(rows):
            t3 = np.column_stack([tp, ground.height_m(tp) + self.crew_antenna_agl_m])
            d3 = np.column_stack([pos_ne_m[rows], h[rows]])
            ti, k = np.divmod(np.arange(m * len(rows)), len(rows))
            near = np.hypot(*(t3[ti, :2] - d3[k, :2]).T) <= self.radio.budget.max_range_m
            ok = np.zeros(len(ti), dtype=bool)
            ok[near] = self.radio.links_clear(d3[k[near]], t3[ti[near]])
            links[ti[ok], rows[k[ok]]] = True
        return act, links

    def plan(self, tick: TickInput) -> PlanOutput:
        out = self.inner.plan(tick)
        disp = np.asarray(out.disp_m, dtype=float)
        pos = np.asarray(tick.pos_m, dtype=float)
        members = np.asarray(tick.networked, dtype=bool) & np.asarray(tick.alive, dtype=bool)
        level = np.zeros(len(pos), dtype=np.int64)  # index into fractions, per drone
        frac = np.asarray(self.fractions, dtype=float)
        now_act, now_links = self._mesh(pos, tick, members)
        crews_now = now_links.any(axis=1)
        passes = 0
        for _ in range(len(frac)):  # a handful of passes, each one predicted mesh
            new = pos + frac[level][:, None] * disp
            act, links = self._mesh(new, tick, members)
            passes += 1
            broken = members & now_act & ~act
            lost_crews = crews_now & ~links.any(axis=1)
            broken |= members & now_links[lost_crews].any(axis=0)
            broken &= level < len(frac) - 1
            if not broken.any():
                break
            level[broken] += 1
        info = dict(out.info)
        info["terrain_held"] = int((level > 0).sum())
        info["terrain_passes"] = passes
        return PlanOutput(disp * frac[level][:, None], out.tree, info)

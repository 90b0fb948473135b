"""planner.terrain_aware: the link guard holds moves that would cut a link behind a ridge."""

from __future__ import annotations

import numpy as np

from planner.methods import PlanOutput, TickInput
from planner.terrain import LinkBudget, Ridge, TerrainRadio, synthetic_terrain
from planner.terrain_aware import TerrainAwarePlanner


class _Fixed:
    """An inner planner that always answers the same displacements."""

    def __init__(self, disp_m: np.ndarray) -> None:
        self.disp_m = disp_m

    def plan(self, tick: TickInput) -> PlanOutput:
        return PlanOutput(self.disp_m.copy(), None, {"inner": 1})


def _setup(disp_m):
    # A 150 m ridge along north = 300; the base and drone 0 south of it, drone 1 on the crest.
    ground = synthetic_terrain([Ridge([(300.0, -600.0), (300.0, 600.0)], 150.0, 120.0)], 700, 10)
    radio = TerrainRadio(ground, LinkBudget())
    pos = np.array([[150.0, 0.0], [300.0, 0.0]])
    tick = TickInput(0, pos, np.ones(2, bool), np.ones(2, bool), np.array([[300.0, 50.0]]))
    return TerrainAwarePlanner(_Fixed(np.asarray(disp_m, float)), radio, 30.0, 1.5, 3.0), tick


def test_move_behind_the_ridge_is_held_and_others_pass():
    planner, tick = _setup([[5.0, 0.0], [200.0, 0.0]])  # drone 1 dives down the far side
    h = planner.radio.terrain.height_m(tick.pos_m) + 30.0
    assert planner.radio.active_mask(tick.pos_m, h, np.ones(2, bool), np.zeros(2), 3.0).all()
    out = planner.plan(tick)
    np.testing.assert_array_equal(out.disp_m[0], [5.0, 0.0])  # harmless: kept
    assert np.linalg.norm(out.disp_m[1]) < 200.0  # would leave the mesh: shortened or held
    new = tick.pos_m + out.disp_m
    h_new = planner.radio.terrain.height_m(new) + 30.0
    assert planner.radio.active_mask(new, h_new, np.ones(2, bool), np.zeros(2), 3.0).all()
    assert out.info["terrain_held"] == 1 and out.info["inner"] == 1


def test_moves_that_keep_the_mesh_are_untouched():
    planner, tick = _setup([[5.0, 3.0], [0.0, 10.0]])
    out = planner.plan(tick)
    np.testing.assert_array_equal(out.disp_m, [[5.0, 3.0], [0.0, 10.0]])
    assert out.info["terrain_held"] == 0

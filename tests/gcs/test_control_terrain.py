"""The station's tick over terrain with a planner that chooses altitudes (gcs/control.py,
docs/terrain.md §6.2): the planner is told the altitudes from telemetry, its heights become the
setpoints' heights above the ground, every setpoint's straight path clears the ground, and a
crossing from a rim over a canyon stays under the ceiling. In memory, explicit time."""

from __future__ import annotations

import numpy as np
import pytest

from gcs.control import (
    ControlConfig,
    TerrainAltitude,
    descent_fraction,
    descent_fraction_reference,
    terrain_targets,
    tick,
)
from planner.methods import PlanOutput, TickInput
from planner.terrain import Canyon, Hill, path_clearance_m, synthetic_terrain

ORIGIN_AMSL_M = 2100.0
# A canyon 250 m deep along north at 350 m east: floor 40 m either side, rims at 150 m.
CANYON = synthetic_terrain(
    [Canyon([(-1500.0, 350.0), (1500.0, 350.0)], 250.0, 40.0, 150.0)], 1500.0, 10.0, ORIGIN_AMSL_M
)
CLEARANCE_M, CEILING_M = 15.0, 120.0


class _East:
    """A planner that sends every drone ``step_m`` east and asks for ``agl_m`` above the ground;
    it keeps what it was told."""

    def __init__(self, step_m: float = 10.0, agl_m: float | list[float] = 117.0) -> None:
        self.step_m, self.agl_m = step_m, agl_m
        self.ticks: list[TickInput] = []

    def plan(self, t: TickInput) -> PlanOutput:
        self.ticks.append(t)
        n = len(t.pos_m)
        disp = np.zeros((n, 2))
        disp[:, 1] = self.step_m
        return PlanOutput(disp, alt_agl_m=np.broadcast_to(self.agl_m, (n,)).astype(float))


def _config(descent_step_m: float, n_layers: int = 1) -> ControlConfig:
    ta = TerrainAltitude(
        CANYON,
        ORIGIN_AMSL_M,
        clearance_m=CLEARANCE_M,
        ceiling_agl_m=CEILING_M,
        descent_step_m=descent_step_m,
    )
    return ControlConfig(cruise_alt_m=100.0, n_layers=n_layers, layer_spacing_m=5.0, terrain=ta)


def test_tick_tells_the_planner_the_altitudes_and_flies_its_heights():
    # Two vehicles over the flat west of the canyon; the planner wants them 60 m and 90 m up.
    planner = _East(step_m=5.0, agl_m=[60.0, 90.0])
    pos = np.array([[0.0, -300.0, -70.0], [50.0, -300.0, -110.0]])  # 70 m and 110 m up
    config = _config(descent_step_m=1.5)
    res = tick(pos, np.ones(2, bool), np.ones(2, bool), np.zeros((1, 2)), planner, 0, config)
    told = planner.ticks[0].alt_amsl_m
    assert told is not None
    assert told.tolist() == pytest.approx([ORIGIN_AMSL_M + 70.0, ORIGIN_AMSL_M + 110.0])
    alt = ORIGIN_AMSL_M - res.target_ned_m[:, 2]
    ground = CANYON.height_m(res.target_ned_m[:, :2])
    assert (alt - ground).tolist() == pytest.approx([60.0, 90.0])


def test_layers_fly_below_the_planners_height_never_under_the_clearance():
    planner = _East(step_m=5.0, agl_m=[100.0, 100.0, 16.0])
    pos = np.array([[0.0, -300.0, -100.0], [40.0, -300.0, -100.0], [80.0, -300.0, -20.0]])
    config = _config(descent_step_m=1.5, n_layers=3)  # rows 0, 1, 2: layers 0, 5, 10 m down
    res = tick(pos, np.ones(3, bool), np.ones(3, bool), np.zeros((1, 2)), planner, 0, config)
    agl = ORIGIN_AMSL_M - res.target_ned_m[:, 2] - CANYON.height_m(res.target_ned_m[:, :2])
    assert agl.tolist() == pytest.approx([100.0, 95.0, CLEARANCE_M])


def _cross(descent_step_m: float, max_ticks: int = 600) -> tuple[float, float, int]:
    """Fly one vehicle from the west plain, 117 m up, east across the canyon: each tick it reaches
    its target's position and descends at most 1.5 m or climbs at most 5 m towards its altitude.
    Returns the highest height above the ground it flew at, the least clearance of a setpoint's
    straight path and the ticks it took to pass 550 m east."""
    planner = _East()
    config = _config(descent_step_m)
    pos, alt = np.array([0.0, 0.0]), ORIGIN_AMSL_M + 117.0
    highest, least = 0.0, np.inf
    for t_step in range(max_ticks):
        if pos[1] > 550.0:
            return highest, least, t_step
        here = np.array([[pos[0], pos[1], ORIGIN_AMSL_M - alt]])
        res = tick(
            here, np.ones(1, bool), np.ones(1, bool), np.zeros((1, 2)), planner, t_step, config
        )
        target = res.target_ned_m[0]
        target_alt = ORIGIN_AMSL_M - target[2]
        least = min(
            least,
            float(
                path_clearance_m(
                    CANYON, pos[None], target[None, :2], np.array([alt]), np.array([target_alt]), 64
                )[0]
            ),
        )
        pos, alt = target[:2].copy(), alt + float(np.clip(target_alt - alt, -1.5, 5.0))
        highest = max(highest, alt - float(CANYON.height_m(pos[None])[0]))
    return highest, least, max_ticks


def test_a_canyon_crossing_walks_down_the_wall_under_the_ceiling():
    highest, least, ticks = _cross(descent_step_m=1.5)
    assert ticks < 600  # it gets across
    assert least >= CLEARANCE_M - 0.01  # every setpoint's straight path clears the ground
    assert highest <= CEILING_M + 0.01
    # Without the step limit the floor rule holds it at the rim's clearance over the canyon.
    highest_unlimited, least_unlimited, _ = _cross(descent_step_m=np.inf)
    assert least_unlimited >= CLEARANCE_M - 0.01
    assert highest_unlimited > CEILING_M + 100.0


def test_descent_fraction_against_its_reference(rng):
    terrain = synthetic_terrain(
        [
            Canyon([(-1500.0, 350.0), (1500.0, 380.0)], 250.0, 40.0, 150.0),
            Hill((300.0, -200.0), 150.0, 120.0),
        ],
        1500.0,
        10.0,
        ORIGIN_AMSL_M,
    )
    ta = TerrainAltitude(
        terrain, ORIGIN_AMSL_M, clearance_m=15.0, ceiling_agl_m=120.0, descent_step_m=1.5
    )
    n = 300
    pos = rng.uniform(-500.0, 700.0, size=(n, 2))
    tgt = pos + rng.uniform(-25.0, 25.0, size=(n, 2))
    alt = terrain.height_m(pos) + rng.uniform(10.0, 300.0, size=n)
    fast = descent_fraction(pos, alt, tgt, ta)
    slow = descent_fraction_reference(pos, alt, tgt, ta)
    np.testing.assert_allclose(fast, slow)
    assert 0 < (fast < 1).sum() < n  # some steps shortened, some not


def test_a_climb_toward_rising_ground_stays_under_the_ceiling_over_the_ground_it_leaves():
    # A vehicle over the canyon's floor (250 m down) heading up its west wall, asked for 117 m
    # above the target's ground: the target's altitude is capped at the ceiling over the floor
    # it leaves (and its clearance over the wall still wins where the two conflict).
    ta = _config(descent_step_m=4.0).terrain
    assert ta is not None
    pos = np.array([[0.0, 330.0, -(-250.0 + 110.0)]])  # over the floor, 110 m up
    target = np.array([[0.0, 295.0]])
    ground = CANYON.height_m(np.vstack([pos[:, :2], target])) - ORIGIN_AMSL_M
    assert ground[1] > ground[0] + 5.0  # the target's ground is higher
    out = terrain_targets(pos, target, np.array([117.0]), ta)
    alt = -out[0, 2]
    assert alt <= ground.min() + CEILING_M + 1e-6
    assert alt >= ground.max() + CLEARANCE_M

"""gcs.control.tick: targets = position + planner displacement, layers, geofence, masks."""

import numpy as np
import pytest

from gcs.control import ControlConfig, Geofence, layer_alt_m, tick
from planner.methods import PlanOutput, make_planner
from planner.problem import problem_preset


class _Fixed:
    """A planner that moves every planned drone by a fixed displacement."""

    def __init__(self, disp):
        self.disp = np.asarray(disp, float)
        self.seen = None

    def plan(self, t):
        self.seen = t
        return PlanOutput(np.where(t.networked[:, None], self.disp, 0.0), info={"iterations": 1})


def test_targets_are_position_plus_displacement_at_layer_altitude():
    pos = np.array([[0.0, 0.0, -30.0], [10.0, 5.0, -35.0], [np.nan] * 3, [20.0, 0.0, -40.0]])
    net = np.array([True, True, True, False])
    cfg = ControlConfig(cruise_alt_m=30.0, layer_spacing_m=5.0, n_layers=3)
    p = _Fixed([1.0, -2.0])
    r = tick(pos, net, np.ones(4, bool), np.zeros((2, 2)), p, 0, cfg)
    assert r.rows.tolist() == [0, 1]  # no fix / not networked: no target
    np.testing.assert_allclose(r.target_ned_m[:, :2], [[1.0, -2.0], [11.0, 3.0]])
    np.testing.assert_allclose(r.target_ned_m[:, 2], [-30.0, -35.0])
    assert not p.seen.networked[2] and not p.seen.networked[3]


def test_layers_cycle_and_fence_clips():
    cfg = ControlConfig(
        cruise_alt_m=40.0,
        layer_spacing_m=5.0,
        n_layers=3,
        geofence=Geofence.square(100.0, max_alt_m=48.0),
    )
    assert layer_alt_m([0, 1, 2, 3], cfg).tolist() == [40.0, 45.0, 48.0, 40.0]
    pos = np.array([[99.0, -99.0, -40.0]])
    r = tick(pos, [True], [True], np.zeros((1, 2)), _Fixed([5.0, -5.0]), 0, cfg)
    np.testing.assert_allclose(r.target_ned_m[0], [100.0, -100.0, -40.0])


def test_with_phireman_central_moves_within_speed_limit(rng):
    prob = problem_preset("S", 0.0).replace(
        length_unit_m=50.0, radio_range_m=100.0, base_range_m=100.0, max_speed_m_s=7.5
    )
    planner = make_planner("phireman-central", prob, {}, rng)
    pos = np.column_stack([rng.uniform(-50, 50, (20, 2)), np.full(20, -30.0)])
    r = tick(
        pos,
        np.ones(20, bool),
        np.ones(20, bool),
        rng.uniform(-200, 200, (5, 2)),
        planner,
        0,
        ControlConfig(),
    )
    step = np.linalg.norm(r.target_ned_m[:, :2] - pos[:, :2], axis=1)
    assert len(r.rows) == 20 and np.all(step <= 7.5 + 1e-6)


def test_empty_geofence_rejected():
    with pytest.raises(ValueError):
        Geofence(0.0, 0.0, -1.0, 1.0)

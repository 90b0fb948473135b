"""Shared geometry: connectivity against the recursive definition, inequalities, helpers."""

import numpy as np
import pytest

from planner.geometry import (
    active_mask,
    active_mask_reference,
    geodetic_to_ned_m,
    ned_to_geodetic,
    neighbour_pairs,
    step_toward,
    tasks_connected,
)


@pytest.mark.parametrize("n", [1, 5, 40, 149, 151, 300])  # both the BFS and the scipy path
def test_active_mask_matches_the_recursive_definition(rng, n):
    for _ in range(5):
        pos = rng.uniform(-8, 8, (n, 2))
        alive = rng.random(n) < 0.85
        assert np.array_equal(
            active_mask(pos, alive, 2.0, 2.0), active_mask_reference(pos, alive, 2.0, 2.0)
        )


def test_link_inequalities_are_the_papers():
    # drone links and the base use <=, task links use < (docs/design/model.md §4)
    pos = np.array([[2.0, 0.0], [4.0, 0.0]])
    assert active_mask(pos, np.ones(2, bool), 2.0, 2.0).tolist() == [True, True]
    assert active_mask(pos, np.array([False, True]), 2.0, 2.0).tolist() == [
        False,
        False,
    ]  # no relay
    assert tasks_connected(
        np.array([[6.0, 0.0], [5.9, 0.0]]), pos, np.ones(2, bool), 2.0
    ).tolist() == [False, True]
    assert len(neighbour_pairs(pos, 2.0)) == 1 and len(neighbour_pairs(pos, 1.999)) == 0


def test_step_toward_never_overshoots():
    d = step_toward(np.array([[3.0, 4.0], [0.1, 0.0], [0.0, 0.0]]), np.zeros(2), 1.0)
    assert np.allclose(d, [[-0.6, -0.8], [-0.1, 0.0], [0.0, 0.0]])


def test_geodetic_round_trip():
    ned = np.array([[120.0, -45.0, -30.0], [0.0, 0.0, 0.0]])
    lat, lon, alt = ned_to_geodetic(ned, 39.7596, -121.6219, 540.0)
    back = geodetic_to_ned_m(lat, lon, alt, 39.7596, -121.6219, 540.0)
    assert np.allclose(back, ned, atol=1e-6)
    assert alt[0] == pytest.approx(
        570.0, abs=0.01
    )  # 30 m up, plus ~1 mm of earth curvature at 128 m

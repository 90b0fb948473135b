"""planner.terrain: the profile of one link and the status of many (what the operator is shown)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.terrain import (
    EARTH_RADIUS_M,
    LINK_BLOCKED,
    LINK_OK,
    LINK_OUT_OF_RANGE,
    LINK_STATUS_NAMES,
    Canyon,
    LinkBudget,
    Ridge,
    TerrainRadio,
    link_profile,
    links_clear_reference,
    synthetic_terrain,
)


def test_profile_over_flat_ground_matches_hand_computed_values():
    flat = synthetic_terrain([], 600.0, 10.0, plane_amsl_m=100.0)
    budget = LinkBudget()
    prof = link_profile(flat, budget, (0.0, -500.0, 110.0), (0.0, 500.0, 130.0))
    # 1000 m horizontally, one sample every 10 m, both ends included.
    assert len(prof.distance_m) == 101
    assert prof.distance_m[0] == 0.0 and prof.distance_m[-1] == pytest.approx(1000.0)
    mid = 50
    lam = 299_792_458.0 / 2.4e9  # 0.1249 m
    assert prof.fresnel_radius_m[mid] == pytest.approx(math.sqrt(lam * 500 * 500 / 1000))  # 5.59 m
    assert prof.bulge_m[mid] == pytest.approx(500 * 500 / (2 * 4 / 3 * EARTH_RADIUS_M))  # 1.5 cm
    assert prof.los_amsl_m[mid] == pytest.approx(120.0)
    assert prof.ground_amsl_m[mid] == pytest.approx(100.0)
    assert prof.fresnel_radius_m[0] == 0.0 and prof.fresnel_radius_m[-1] == 0.0
    assert prof.slant_m == pytest.approx(math.hypot(1000.0, 20.0))
    assert prof.status == LINK_OK
    # The margin is least at the low end's neighbour, where the line is lowest and the zone
    # already a few metres wide, never at the ends.
    assert prof.margin_m[prof.worst] == pytest.approx(prof.margin_m[1:-1].min())
    assert 1 <= prof.worst <= 99
    # 20 m of air over 5.59 m of Fresnel radius at midpath: ratio 3.58 there, the minimum lower.
    assert prof.least_clearance_ratio <= (20.0 - prof.bulge_m[mid]) / 5.59 + 1e-3
    assert prof.least_clearance_ratio > 0.6


def test_profile_of_a_knife_edge_is_blocked_at_the_edge():
    # A 40 m wall midway; antennas at 41.8 m: 1.8 m over the edge, under 0.6 x 3.53 m.
    edge = synthetic_terrain([Ridge([(0.0, -300.0), (0.0, 300.0)], 40.0, 4.0)], 300.0, 1.0)
    prof = link_profile(edge, LinkBudget(), (-200.0, 0.0, 41.8), (200.0, 0.0, 41.8))
    assert prof.status == LINK_BLOCKED
    assert prof.distance_m[prof.worst] == pytest.approx(200.0)
    r1 = math.sqrt(LinkBudget().wavelength_m * 200.0 * 200.0 / 400.0)
    assert prof.fresnel_radius_m[prof.worst] == pytest.approx(r1)
    expected = (1.8 - 200 * 200 / (2 * 4 / 3 * EARTH_RADIUS_M)) / r1  # 0.51
    assert prof.least_clearance_ratio == pytest.approx(expected, abs=1e-6)
    assert prof.margin_m[prof.worst] == pytest.approx((expected - 0.6) * r1, abs=1e-6)
    # 0.4 of the zone clear is enough for the same link.
    loose = link_profile(
        edge, LinkBudget(fresnel_clear_fraction=0.4), (-200.0, 0.0, 41.8), (200.0, 0.0, 41.8)
    )
    assert loose.status == LINK_OK


def test_profile_out_of_range_whatever_lies_between():
    flat = synthetic_terrain([], 2000.0, 20.0)
    budget = LinkBudget(fade_margin_db=20.0)  # about 500 m
    prof = link_profile(flat, budget, (0.0, 0.0, 50.0), (budget.max_range_m + 5.0, 0.0, 50.0))
    assert prof.status == LINK_OUT_OF_RANGE
    assert prof.max_range_m == pytest.approx(budget.max_range_m)


@pytest.fixture
def canyon():
    return synthetic_terrain(
        [
            Canyon([(-800.0, 300.0), (800.0, 340.0)], 200.0, 30.0, 120.0),
            Ridge([(-800.0, 700.0), (800.0, 650.0)], 80.0, 200.0),
        ],
        half_width_m=900.0,
        spacing_m=15.0,
        plane_amsl_m=1000.0,
    )


def _random_links(rng, n):
    ne_a = rng.uniform(-850, 850, (n, 2))
    ne_b = ne_a + rng.uniform(-700, 700, (n, 2))
    h_a = 1000.0 + rng.uniform(-150, 150, n)
    h_b = 1000.0 + rng.uniform(-150, 150, n)
    return np.column_stack([ne_a, h_a]), np.column_stack([ne_b, h_b])


def test_link_status_agrees_with_the_reference_and_the_profile(canyon):
    rng = np.random.default_rng(7)
    budget = LinkBudget(fade_margin_db=20.0)
    radio = TerrainRadio(canyon, budget)
    a, b = _random_links(rng, 400)
    status = radio.link_status(a, b)
    clear = links_clear_reference(canyon, budget, a, b)
    far = np.linalg.norm(b - a, axis=1) > budget.max_range_m
    np.testing.assert_array_equal(status == LINK_OK, clear)
    np.testing.assert_array_equal(status == LINK_OUT_OF_RANGE, far)
    np.testing.assert_array_equal(status == LINK_BLOCKED, ~clear & ~far)
    # every class is present, so the test can tell them apart
    assert set(np.unique(status).tolist()) == {LINK_OK, LINK_BLOCKED, LINK_OUT_OF_RANGE}
    for k in range(0, 400, 7):  # the one-link profile gives each link the same verdict
        assert link_profile(canyon, budget, a[k], b[k]).status == status[k]
    assert LINK_STATUS_NAMES[LINK_BLOCKED] == "blocked by terrain"


def test_link_status_of_no_links_is_empty(canyon):
    out = TerrainRadio(canyon).link_status(np.empty((0, 3)), np.empty((0, 3)))
    assert out.shape == (0,) and out.dtype == np.int8

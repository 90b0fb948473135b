"""planner.terrain: heights, the link test (compiled vs reference), terrain connectivity."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner import _kernels
from planner.geometry import active_mask
from planner.terrain import (
    Canyon,
    Hill,
    LinkBudget,
    Ridge,
    Terrain,
    TerrainRadio,
    free_space_loss_db,
    links_clear_reference,
    path_clearance_m,
    synthetic_terrain,
)


@pytest.fixture
def canyon() -> Terrain:
    return synthetic_terrain(
        [
            Canyon([(-800.0, 300.0), (800.0, 340.0)], 200.0, 30.0, 120.0),
            Ridge([(-800.0, 700.0), (800.0, 650.0)], 80.0, 200.0),
            Hill((-300.0, -300.0), 60.0, 120.0),
        ],
        half_width_m=900.0,
        spacing_m=15.0,
        plane_amsl_m=1000.0,
    )


@pytest.fixture
def disabled(monkeypatch):
    """Run the callers' reference paths (the kernels switched off)."""
    monkeypatch.setattr(_kernels, "ENABLED", False)


def test_heights_compiled_numpy_and_reference_agree(canyon, rng, monkeypatch):
    pts = rng.uniform(-1000.0, 1000.0, (500, 2))  # some outside the grid: the edge's height
    fast = canyon.height_m(pts)
    monkeypatch.setattr(_kernels, "ENABLED", False)
    slow = canyon.height_m(pts)
    ref = np.array([canyon.height_m_reference(n, e) for n, e in pts])
    np.testing.assert_array_equal(slow, ref)
    np.testing.assert_array_equal(fast, ref)


def test_heights_exact_at_posts_and_linear_between(rng):
    grid = rng.uniform(0.0, 100.0, (4, 5))
    t = Terrain(grid, north0_m=-20.0, east0_m=10.0, spacing_m=10.0)
    assert t.height_m(np.array([[-20.0 + 10.0 * 2, 10.0 + 10.0 * 3]]))[0] == grid[2, 3]
    mid = t.height_m(np.array([[-15.0, 15.0]]))[0]  # the centre of cell (0, 0)
    assert mid == pytest.approx(grid[:2, :2].mean())
    assert t.height_m(np.zeros((3, 4, 2))).shape == (3, 4)


def test_canyon_scene_has_its_shape(canyon):
    h = canyon.height_m(np.array([[0.0, 320.0], [0.0, 0.0], [0.0, 675.0], [-300.0, -300.0]]))
    assert h[0] == pytest.approx(800.0, abs=1.0)  # the floor, 200 m down
    assert h[1] == pytest.approx(1000.0, abs=0.5)  # the plane (and the hill's tail)
    assert h[2] == pytest.approx(1080.0, abs=2.0)  # the ridge's crest
    assert h[3] == pytest.approx(1060.0, abs=1.0)  # the hill's top


def test_link_budget_range_is_where_free_space_loss_uses_the_budget():
    b = LinkBudget()
    assert b.max_path_loss_db == pytest.approx(20 + 2 + 2 + 90 - 10)
    assert float(free_space_loss_db(b.max_range_m, b.frequency_hz)) == pytest.approx(
        b.max_path_loss_db
    )
    assert 1000.0 < b.max_range_m < 2500.0  # a 2.4 GHz mesh radio: about a mile
    with pytest.raises(ValueError):
        LinkBudget(tx_power_dbm=-100.0)


def _random_links(rng, n):
    a = np.column_stack([rng.uniform(-900, 900, (n, 2)), rng.uniform(750.0, 1150.0, n)])
    b = np.column_stack([rng.uniform(-900, 900, (n, 2)), rng.uniform(750.0, 1150.0, n)])
    return a, b


def test_links_clear_compiled_equals_reference(canyon, rng):
    radio = TerrainRadio(canyon, LinkBudget())
    a, b = _random_links(rng, 3000)
    fast = radio.links_clear(a, b)
    ref = links_clear_reference(canyon, radio.budget, a, b)
    np.testing.assert_array_equal(fast, ref)
    assert 0.05 < fast.mean() < 0.95  # both outcomes exercised


def test_links_clear_without_numba_runs_the_reference(canyon, rng, disabled):
    radio = TerrainRadio(canyon, LinkBudget())
    a, b = _random_links(rng, 200)
    np.testing.assert_array_equal(
        radio.links_clear(a, b), links_clear_reference(canyon, radio.budget, a, b)
    )


def test_a_ridge_cuts_a_link_that_height_restores():
    ridge = synthetic_terrain([Ridge([(0.0, -500.0), (0.0, 500.0)], 50.0, 60.0)], 500.0, 5.0)
    radio = TerrainRadio(ridge, LinkBudget())
    low = radio.links_clear(np.array([[-200.0, 0.0, 10.0]]), np.array([[200.0, 0.0, 10.0]]))
    high = radio.links_clear(np.array([[-200.0, 0.0, 90.0]]), np.array([[200.0, 0.0, 90.0]]))
    assert not low[0] and high[0]
    # Over open ground the same low link holds: 10 m antennas clear 60 % of F1 (6.1 m at 400 m).
    open_ground = synthetic_terrain([], 500.0, 5.0)
    assert TerrainRadio(open_ground).links_clear(
        np.array([[-200.0, 0.0, 10.0]]), np.array([[200.0, 0.0, 10.0]])
    )[0]


def test_fresnel_fraction_decides_a_grazing_link():
    # A knife-edge wall 40 m high midway; antennas at 41.8 m: 1.8 m of clearance over the edge.
    edge = synthetic_terrain([Ridge([(0.0, -300.0), (0.0, 300.0)], 40.0, 4.0)], 300.0, 1.0)
    a, b = np.array([[-200.0, 0.0, 41.8]]), np.array([[200.0, 0.0, 41.8]])
    r1 = math.sqrt(LinkBudget().wavelength_m * 200.0 * 200.0 / 400.0)  # ~3.5 m
    assert 0.4 * r1 < 1.8 < 0.6 * r1
    assert not TerrainRadio(edge, LinkBudget(fresnel_clear_fraction=0.6)).links_clear(a, b)[0]
    assert TerrainRadio(edge, LinkBudget(fresnel_clear_fraction=0.4)).links_clear(a, b)[0]


def test_earth_curvature_blocks_a_long_low_link():
    flat = synthetic_terrain([], 12_000.0, 500.0)
    far = LinkBudget(tx_power_dbm=40.0, sensitivity_dbm=-110.0, fresnel_clear_fraction=0.0)
    a, b = np.array([[-10_000.0, 0.0, 5.0]]), np.array([[10_000.0, 0.0, 5.0]])
    bulge_mid = 10_000.0**2 / (2 * far.k_factor * 6_371_008.8)  # ~5.9 m > 5 m
    assert bulge_mid > 5.0
    assert not TerrainRadio(flat, far).links_clear(a, b)[0]
    no_curve = LinkBudget(
        tx_power_dbm=40.0, sensitivity_dbm=-110.0, fresnel_clear_fraction=0.0, k_factor=1e6
    )
    assert TerrainRadio(flat, no_curve).links_clear(a, b)[0]


def _active_reference(radio, pos, h, alive, base3):
    """The paper's recursive definition as a fixed point, links by the reference loop."""
    n = len(pos)
    p3 = np.column_stack([pos, h])
    act = [
        bool(alive[i])
        and bool(links_clear_reference(radio.terrain, radio.budget, p3[i : i + 1], base3[None])[0])
        for i in range(n)
    ]
    changed = True
    while changed:
        changed = False
        for i in range(n):
            if act[i] or not alive[i]:
                continue
            for j in range(n):
                if (
                    act[j]
                    and links_clear_reference(
                        radio.terrain, radio.budget, p3[i : i + 1], p3[j : j + 1]
                    )[0]
                ):
                    act[i] = changed = True
                    break
    return np.array(act)


@pytest.mark.parametrize("seed", range(4))
def test_terrain_active_mask_and_tasks_match_references(canyon, seed):
    rng = np.random.default_rng(seed)
    radio = TerrainRadio(canyon, LinkBudget(fade_margin_db=22.0))  # ~400 m: a sparse mesh
    n = 40
    pos = rng.uniform(-700, 700, (n, 2))
    h = canyon.height_m(pos) + rng.uniform(20.0, 120.0, n)
    alive = rng.random(n) < 0.9
    base3 = np.array([0.0, 0.0, float(canyon.height_m(np.zeros((1, 2)))[0]) + 3.0])
    act = radio.active_mask(pos, h, alive, base3[:2], base3[2])
    np.testing.assert_array_equal(act, _active_reference(radio, pos, h, alive, base3))
    tasks = rng.uniform(-700, 700, (12, 2))
    th = canyon.height_m(tasks) + 1.5
    got = radio.tasks_connected(tasks, th, pos, h, act)
    want = [
        any(
            links_clear_reference(
                canyon, radio.budget, np.array([[*pos[j], h[j]]]), np.array([[*tasks[k], th[k]]])
            )[0]
            for j in np.flatnonzero(act)
        )
        for k in range(len(tasks))
    ]
    np.testing.assert_array_equal(got, want)


def test_on_open_ground_the_terrain_radio_is_a_disc(rng):
    flat = synthetic_terrain([], 2000.0, 50.0)
    budget = LinkBudget(fresnel_clear_fraction=0.0, k_factor=1e9)  # no Fresnel, no bulge
    radio = TerrainRadio(flat, budget)
    pos = rng.uniform(-1500, 1500, (150, 2))
    h = np.full(150, 30.0)
    alive = rng.random(150) < 0.95
    r = budget.max_range_m
    np.testing.assert_array_equal(
        radio.active_mask(pos, h, alive, np.zeros(2), 30.0), active_mask(pos, alive, r, r)
    )


def test_path_clearance_sees_a_wall_between_the_ends():
    wall = synthetic_terrain([Ridge([(0.0, -100.0), (0.0, 100.0)], 50.0, 10.0)], 100.0, 1.0)
    c = path_clearance_m(
        wall, np.array([[-40.0, 0.0]]), np.array([[40.0, 0.0]]), np.array([30.0]), np.array([30.0])
    )
    assert c[0] == pytest.approx(-20.0, abs=0.5)

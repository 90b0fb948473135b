"""planner.terrain_heights and the 3-D terrain-aware planner: the altitude rule and the relay
search (fast vs reference), and what they do over a canyon and behind a ridge."""

from __future__ import annotations

import numpy as np
import pytest

from planner import _kernels
from planner.methods import PlanOutput, TickInput
from planner.terrain import Canyon, LinkBudget, Ridge, Terrain, TerrainRadio, synthetic_terrain
from planner.terrain_aware import TerrainAwarePlanner
from planner.steiner import TaskTree
from planner.terrain_heights import (
    HeightRule,
    candidate_moves,
    detour_tree,
    edges_relayable,
    edges_relayable_reference,
    relay_candidates,
    relay_candidates_reference,
    target_alt_amsl_m,
    target_alt_amsl_m_reference,
)

RULE = HeightRule(
    clearance_m=15.0, ceiling_agl_m=120.0, max_climb_m=5.0, max_descent_m=4.0, max_step_m=10.0
)


@pytest.fixture
def canyon() -> Terrain:
    """A canyon 250 m deep along east = 350 (rims at 200 and 500), a 60 m ridge at east = 800."""
    return synthetic_terrain(
        [
            Canyon([(-900.0, 350.0), (900.0, 350.0)], 250.0, 40.0, 150.0),
            Ridge([(-900.0, 800.0), (900.0, 800.0)], 60.0, 250.0),
        ],
        half_width_m=1000.0,
        spacing_m=10.0,
        plane_amsl_m=1000.0,
    )


@pytest.mark.parametrize("compiled", [True, False])
def test_altitude_rule_fast_and_reference_agree(canyon, rng, monkeypatch, compiled):
    monkeypatch.setattr(_kernels, "ENABLED", compiled)
    end = rng.uniform(-900.0, 900.0, (200, 2))
    ang = rng.uniform(0.0, 2 * np.pi, 200)
    direction = np.column_stack([np.cos(ang), np.sin(ang)])
    direction[::7] = 0.0  # some hold their position
    fast = target_alt_amsl_m(canyon, end, direction, RULE)
    slow = target_alt_amsl_m_reference(canyon, end, direction, RULE)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-9)


def test_altitude_rule_flies_high_and_descends_before_the_canyon(canyon):
    east = np.array([[0.0, 1.0]])
    idle = target_alt_amsl_m(canyon, np.array([[0.0, -500.0]]), np.zeros((1, 2)), RULE)
    assert idle[0] == pytest.approx(1000.0 + RULE.high_agl_m)  # at the ceiling, less the margin
    # Heading east 280 m before the rim: low enough to stay under the ceiling down the wall.
    ahead = target_alt_amsl_m(canyon, np.array([[0.0, -80.0]]), east, RULE)[0]
    assert ahead < 1000.0 + 40.0
    assert ahead >= 1000.0 + RULE.low_agl_m  # never under the clearance
    # Flying on at full speed and descending at the descent rate it stays under the ceiling.
    k = np.arange(RULE.lookahead_steps + 1)
    pts = np.column_stack([np.zeros(len(k)), -80.0 + 10.0 * k])
    assert (ahead - 4.0 * k - canyon.height_m(pts) <= RULE.high_agl_m + 1e-9).all()
    # ... and no lower than that needs: at some sample ahead it is exactly at the ceiling.
    assert (ahead - 4.0 * k - canyon.height_m(pts)).max() == pytest.approx(RULE.high_agl_m)
    # Heading away from the canyon: high again.
    away = target_alt_amsl_m(canyon, np.array([[0.0, 0.0]]), -east, RULE)[0]
    assert away == pytest.approx(1000.0 + RULE.high_agl_m)


def test_candidate_moves_turn_scale_and_stay():
    moves = candidate_moves(np.array([[10.0, 0.0]]), RULE)
    assert moves.shape == (1, len(RULE.angles_deg) * len(RULE.move_fractions) + 1, 2)
    np.testing.assert_allclose(moves[0, 0], [10.0, 0.0])
    np.testing.assert_allclose(moves[0, 3], [0.0, 10.0], atol=1e-12)  # turned 90 degrees
    np.testing.assert_allclose(moves[0, -1], [0.0, 0.0])
    lengths = np.linalg.norm(moves[0], axis=1)
    np.testing.assert_allclose(sorted(set(np.round(lengths, 9))), [0.0, 5.0, 10.0])


def _ridge_radio() -> TerrainRadio:
    """A 150 m ridge along north = 300."""
    ground = synthetic_terrain([Ridge([(300.0, -600.0), (300.0, 600.0)], 150.0, 120.0)], 700, 10)
    return TerrainRadio(ground, LinkBudget())


def test_relay_search_fast_and_reference_agree(rng):
    radio = _ridge_radio()
    b = 12
    pos = np.column_stack([rng.uniform(150.0, 450.0, b), rng.uniform(-200.0, 200.0, b)])
    ground = radio.terrain.height_m(pos)
    alt_now = ground + rng.uniform(20.0, 110.0, b)
    disp = rng.uniform(-10.0, 10.0, (b, 2))
    goal = alt_now + rng.uniform(-8.0, 8.0, b)
    anchors = np.array([[100.0, 0.0, 60.0], [150.0, 100.0, 60.0], [0.0, 0.0, 3.0]])
    crews = np.array([[300.0, 50.0, 151.5], [450.0, -50.0, 1.5]])
    needs = rng.random((b, 2)) < 0.4
    fast = relay_candidates(radio, pos, alt_now, disp, goal, anchors, crews, needs, RULE)
    slow = relay_candidates_reference(radio, pos, alt_now, disp, goal, anchors, crews, needs, RULE)
    np.testing.assert_array_equal(fast[0], slow[0])
    np.testing.assert_allclose(fast[1], slow[1])
    np.testing.assert_allclose(fast[2], slow[2])
    assert 0 < fast[0].sum() < b  # the test sees both outcomes


def test_relay_search_finds_a_position_that_sees_both_ends():
    radio = _ridge_radio()
    pos = np.array([[300.0, 0.0]])  # on the crest
    alt_now = radio.terrain.height_m(pos) + 30.0
    disp = np.array([[10.0, 0.0]])  # planned: down the far side
    anchors = np.array([[150.0, 0.0, 60.0]])  # the mesh, south of the ridge
    crews = np.array([[310.0, 50.0, 151.5]])  # a crew on the crest
    found, ne, alt = relay_candidates(
        radio, pos, alt_now, disp, alt_now + 5.0, anchors, crews, np.array([[True]]), RULE
    )
    assert found[0]
    p3 = np.array([[ne[0, 0], ne[0, 1], alt[0]]])
    assert radio.links_clear(p3, anchors)[0] and radio.links_clear(p3, crews)[0]
    assert -RULE.max_descent_m - 1e-9 <= alt[0] - alt_now[0] <= RULE.max_climb_m + 1e-9


def test_the_rule_descends_at_the_descent_rate_and_climbs_at_the_climb_rate(canyon):
    """Descents are limited by ``max_descent_m``, climbs by ``max_climb_m`` (the station's limits,
    docs/terrain.md §6.2): a slower descent starts down earlier before the canyon."""
    np.testing.assert_allclose(
        RULE.reach_m(np.array([100.0, 100.0]), np.array([0.0, 200.0])), [96.0, 105.0]
    )
    slow = HeightRule(
        clearance_m=15.0, ceiling_agl_m=120.0, max_climb_m=5.0, max_descent_m=1.5, max_step_m=10.0
    )
    east = np.array([[0.0, 1.0]])
    far = np.array([[0.0, -100.0]])  # 300 m before the west rim
    fast_alt = target_alt_amsl_m(canyon, far, east, RULE)[0]
    slow_alt = target_alt_amsl_m(canyon, far, east, slow)[0]
    assert slow_alt < fast_alt
    np.testing.assert_allclose(
        target_alt_amsl_m(canyon, far, east, slow),
        target_alt_amsl_m_reference(canyon, far, east, slow),
    )


def test_relay_candidates_step_up_by_the_climb_and_down_by_the_descent():
    radio = _ridge_radio()
    pos = np.array([[0.0, 0.0]])
    alt_now = radio.terrain.height_m(pos) + 60.0
    from planner.terrain_heights import _candidates

    _, alt, reach = _candidates(radio.terrain, pos, alt_now, np.zeros((1, 2)), alt_now, RULE)
    assert reach.all()
    np.testing.assert_allclose(sorted(set(np.round(alt[0] - alt_now[0], 9))), [-4.0, 0.0, 5.0])


class _Fixed:
    """An inner planner that always answers the same displacements."""

    def __init__(self, disp_m: np.ndarray) -> None:
        self.disp_m = disp_m

    def plan(self, tick: TickInput) -> PlanOutput:
        return PlanOutput(self.disp_m.copy(), None, {})


def test_3d_planner_keeps_the_mesh_and_commands_heights_in_the_band():
    radio = _ridge_radio()
    pos = np.array([[150.0, 0.0], [300.0, 0.0], [200.0, 150.0]])
    disp = np.array([[5.0, 0.0], [200.0, 0.0], [0.0, -10.0]])  # drone 1 dives behind the ridge
    alt_now = radio.terrain.height_m(pos) + 30.0
    tick = TickInput(
        0, pos, np.ones(3, bool), np.ones(3, bool), np.array([[310.0, 50.0]]), alt_amsl_m=alt_now
    )
    planner = TerrainAwarePlanner(_Fixed(disp), radio, 30.0, 1.5, 3.0, heights=RULE)
    out = planner.plan(tick)
    assert out.alt_agl_m is not None
    assert (out.alt_agl_m >= RULE.low_agl_m - 1e-9).all()
    assert (out.alt_agl_m <= RULE.high_agl_m + 1e-9).all()
    new = pos + out.disp_m
    alt = radio.terrain.height_m(new) + out.alt_agl_m
    alt = RULE.reach_m(alt_now, alt)
    assert radio.active_mask(new, alt, np.ones(3, bool), np.zeros(2), 3.0).all()
    assert np.linalg.norm(out.disp_m[1]) < 200.0
    np.testing.assert_array_equal(out.disp_m[[0, 2]], disp[[0, 2]])  # harmless: kept
    assert out.info["terrain_placed"] + out.info["terrain_held"] >= 1  # drone 1 was caught


def _wall_radio() -> TerrainRadio:
    """A 300 m wall along north = 300, from far west to east = 150, where it ends."""
    ground = synthetic_terrain([Ridge([(300.0, -900.0), (300.0, 150.0)], 300.0, 100.0)], 900, 10)
    return TerrainRadio(ground, LinkBudget(fade_margin_db=20.0))  # about 500 m


@pytest.mark.parametrize("compiled", [True, False])
def test_edges_relayable_fast_and_reference_agree(rng, monkeypatch, compiled):
    monkeypatch.setattr(_kernels, "ENABLED", compiled)
    radio = _wall_radio()
    a = rng.uniform(-700.0, 700.0, (40, 2))
    b = rng.uniform(-700.0, 700.0, (40, 2))
    b[0] = a[0]  # a zero-length edge
    fast = edges_relayable(radio, a, b, 250.0, RULE.high_agl_m)
    slow = edges_relayable_reference(radio, a, b, 250.0, RULE.high_agl_m)
    np.testing.assert_array_equal(fast, slow)
    assert 0 < fast.sum() < len(a)


def test_tree_edge_through_a_wall_is_bent_through_a_relayable_point():
    radio = _wall_radio()
    tree = TaskTree(np.array([[0.0, 0.0], [600.0, 0.0]]), np.array([-1, 0]), 1)
    a, b = tree.segments()
    assert not edges_relayable(radio, a, b, 250.0, RULE.high_agl_m)[0]
    bent, n = detour_tree(tree, radio, RULE)
    assert n == 1 and bent.n_nodes == 3 and bent.n_tasks == 1
    np.testing.assert_array_equal(bent.nodes_m[:2], tree.nodes_m)  # base and task stay
    assert bent.parent[1] == 2 and bent.parent[2] == 0  # task -> detour -> base
    a, b = bent.segments()
    assert edges_relayable(radio, a, b, 250.0, RULE.high_agl_m).all()
    # The shortest bend that passes: the nearest point on the crest (a relay there sees both
    # sides), not around the wall's end (east > 250, about 1000 m of edges).
    assert bent.nodes_m[2, 0] == pytest.approx(300.0)
    assert radio.terrain.height_m(bent.nodes_m[2:3])[0] > 250.0
    assert np.sum(bent.edge_lengths_m()) < 700.0
    same, n0 = detour_tree(bent, radio, RULE)
    assert n0 == 0 and same is bent  # nothing left to bend

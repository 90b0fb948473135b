"""MCCST over terrain: the terrain-aware wrapper gives MCCST a link predicate (planner.mccst
``edge_filter``, set by planner.terrain_aware), so its spanning tree keeps only links that clear
the terrain, not every pair within the disc's range."""

from __future__ import annotations

import numpy as np

from planner.mccst import make_mccst
from planner.methods import TickInput
from planner.problem import ProblemConfig
from planner.terrain import LinkBudget, Ridge, TerrainRadio, synthetic_terrain
from planner.terrain_aware import TerrainAwarePlanner

# A 150 m ridge along north = 300 between drone 0 (south) and drone 1 (north), 300 m apart, both
# 30 m above the ground; the base south of the ridge, a crew north of it.
GROUND = synthetic_terrain([Ridge([(300.0, -900.0), (300.0, 900.0)], 150.0, 120.0)], 900, 10)
RADIO = TerrainRadio(GROUND, LinkBudget())
POS = np.array([[150.0, 0.0], [450.0, 0.0]])
PROBLEM = ProblemConfig(
    n_drones=2, n_tasks=1, radio_range_m=400.0, base_range_m=400.0, max_speed_m_s=10.0
)


def _tick() -> TickInput:
    ones = np.ones(2, bool)
    alt = GROUND.height_m(POS) + 30.0
    return TickInput(0, POS, ones, ones, np.array([[550.0, 0.0]]), alt_amsl_m=alt)


def _tree(out) -> set[tuple[int, int]]:
    return {tuple(sorted(map(int, e))) for e in np.asarray(out.info["tree_edges"]).reshape(-1, 2)}


def test_mccst_over_terrain_keeps_no_tree_edge_through_the_ridge():
    tick = _tick()
    assert not RADIO.links_clear(
        np.column_stack([POS[:1], tick.alt_amsl_m[:1]]),
        np.column_stack([POS[1:], tick.alt_amsl_m[1:]]),
    ).any()  # the ridge cuts the pair
    plain = make_mccst(PROBLEM, {}, np.random.default_rng(0)).plan(tick)
    assert (0, 1) in _tree(plain)  # on the disc the pair is a link, kept in the tree
    inner = make_mccst(PROBLEM, {}, np.random.default_rng(0))
    aware = TerrainAwarePlanner(inner, RADIO, 30.0, 1.5, 3.0)
    assert inner.edge_filter is not None
    over = aware.plan(tick)
    assert (0, 1) not in _tree(over)
    assert (-1, 0) in _tree(over)  # the base's link to drone 0, in the open, holds


def test_the_link_predicate_is_the_terrain_radio():
    tick = _tick()
    aware = TerrainAwarePlanner(
        make_mccst(PROBLEM, {}, np.random.default_rng(0)), RADIO, 30.0, 1.5, 3.0
    )
    members = np.array([0, 1])
    edges = np.array([[0, 1], [0, 2], [1, 2]])  # 2 = the base
    ok = aware._edges_clear(tick, members, edges)
    base = np.array([0.0, 0.0, float(GROUND.height_m(np.zeros((1, 2)))[0]) + 3.0])
    d3 = np.column_stack([POS, tick.alt_amsl_m])
    want = [
        RADIO.links_clear(d3[:1], d3[1:2])[0],
        RADIO.links_clear(d3[:1], base[None])[0],
        RADIO.links_clear(d3[1:2], base[None])[0],
    ]
    assert ok.tolist() == want == [False, True, False]

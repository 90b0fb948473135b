"""Redundancy against single losses (planner/redundancy.py): critical relays against removing each
drone in turn, the spare pairing rules, and a hand-built chain that the mechanism doubles."""

import numpy as np
import pytest

from planner.geometry import active_mask
from planner.methods import TickInput, make_planner
from planner.problem import problem_preset
from planner.redundancy import (
    RedundancyBook,
    backbone,
    critical_counts,
    critical_counts_reference,
    mesh_graph,
)

BASE = np.zeros(2)


def _crit(pos, net, tasks, r=2.0):
    return critical_counts(mesh_graph(pos, net, tasks, BASE, r, r), len(pos))


def test_critical_counts_match_removing_each_drone(rng):
    for _ in range(200):
        n, m = int(rng.integers(1, 40)), int(rng.integers(1, 8))
        w = rng.uniform(1, 6)
        pos, tasks = rng.uniform(-w, w, (n, 2)), rng.uniform(-w, w, (m, 2))
        net = active_mask(pos, rng.random(n) < 0.9, 2.0, 2.0)
        expect = critical_counts_reference(pos, net, tasks, BASE, 2.0, 2.0)
        assert np.array_equal(_crit(pos, net, tasks), expect)  # compiled (Numba)
        g = mesh_graph(pos, net, tasks, BASE, 2.0, 2.0)
        assert np.array_equal(critical_counts(g, n, compiled=False), expect)  # plain Python


def test_chain_by_hand():
    # base - 0 - 1 - 2 - task A; drone 3 beside 1 bridges 0 and 2; task B hangs off drone 0 only.
    pos = np.array([[0.0, 1.5], [0.0, 3.0], [0.0, 4.5], [0.4, 3.0]])
    tasks = np.array([[0.0, 5.5], [-1.5, 1.5]])
    net = np.ones(4, bool)
    assert list(_crit(pos, net, tasks)) == [2, 0, 1, 0]
    g = mesh_graph(pos, net, tasks, BASE, 2.0, 2.0)
    on = backbone(g, 4)
    assert list(on) == [True, True, True, False]  # fewest hops, ties to the lowest row
    # without the bridge, drone 1 cuts task A too
    assert list(_crit(pos[:3], net[:3], tasks)) == [2, 1, 1]


def test_book_pairs_most_critical_first_and_keeps_pairs():
    pos = np.array([[0.0, 1.5], [0.0, 3.0], [1.0, 0.5], [5.0, 5.0]])
    net = np.array([True, True, True, True])
    crit = np.array([2, 1, 0, 0])
    on = np.array([True, True, False, False])
    book = RedundancyBook()
    tgt = book.assign(pos, net, crit, on, reach=4.0)
    assert book.pair_of == {2: 0}  # the near spare to the most critical relay; 3 is out of reach
    assert np.allclose(tgt[2], pos[0]) and np.isnan(tgt[[0, 1, 3]]).all()
    # next tick the relay is no longer critical (the spare bridges it): the pair stays
    tgt = book.assign(pos, net, np.array([0, 1, 0, 0]), on, reach=4.0)
    assert book.pair_of[2] == 0
    # the spare joins the backbone: the pair is dropped, and drone 1 gets nobody within reach
    book.assign(pos, net, np.array([0, 1, 0, 0]), np.array([True, True, True, False]), reach=1.0)
    assert book.pair_of == {}


@pytest.mark.parametrize("info", ["central", "async"])
def test_spares_double_the_critical_relays_of_a_chain(info):
    """A chain base -> task 5 m out held by 3 relays, 4 spares at the base, no attrition: with the
    mechanism on, the relays' single losses stop cutting the task; off, they still do. Under
    async with the base's true picture (base_view='oracle'). With the picture it hears
    (planner/base_view.py) the pairs churned on this chain when tried (relays and spares swap
    roles on delayed positions) and the cut count did not fall; not asserted here (what the heard
    base acts on is tested in tests/planner/test_base_view.py)."""
    problem = problem_preset("S", 0.0, n_drones=7, n_tasks=1)
    task = np.array([[0.0, 5.6]])
    start = np.array(
        [[0.0, 1.6], [0.0, 3.2], [0.0, 4.8], [0.3, 0.3], [-0.3, 0.3], [0.3, -0.3], [-0.3, -0.3]]
    )

    def final_cut(params):
        more = {"base_view": "oracle"} if info == "async" else {}
        planner = make_planner(
            "phireman-resilient",
            problem,
            {"info": info, **more, **params},
            np.random.default_rng(0),
        )
        pos = start.copy()
        cut = []
        for t in range(80):
            net = active_mask(pos, np.ones(len(pos), bool), 2.0, 2.0)
            out = planner.plan(TickInput(t, pos, np.ones(len(pos), bool), net, task))
            pos = pos + out.disp_m
            cut.append(int(_crit(pos, active_mask(pos, np.ones(7, bool), 2.0, 2.0), task).sum()))
        return cut

    off = final_cut({"redundancy_gain": 0.0, "claim_gain": 0.0})
    on = final_cut({"redundancy_gain": 0.3, "redundancy_reach": 8.0, "claim_gain": 0.0})
    assert sum(off[-20:]) > 0
    assert sum(on[-20:]) < sum(off[-20:])
    assert min(on[-20:]) == 0  # at times no single loss cuts the task (central: for good)


def test_relays_inside_a_hazard_zone_get_a_spare_first():
    """Two relays each holding one crew, one spare within reach of both: by cut count alone the
    lower row wins; with the second relay inside an active zone, the spare goes to it."""
    from planner.hazard import HazardMap, HazardZone

    problem = problem_preset("S", 0.0, n_drones=3, n_tasks=2)
    pos = np.array([[1.8, 0.0], [-1.8, 0.0], [0.0, 1.0]])  # relay A, relay B, spare
    tasks = np.array([[3.3, 0.0], [-3.3, 0.0]])
    zone = HazardMap((HazardZone(0.05, center_m=(-1.8, 0.0), radius_m=0.5),))

    def paired(hazards):
        planner = make_planner("phireman-resilient", problem, {"info": "central"})
        planner.plan(TickInput(0, pos, np.ones(3, bool), np.ones(3, bool), tasks, hazards=hazards))
        return planner._book.pair_of

    assert paired(None) == {2: 0}
    assert paired(zone) == {2: 1}

"""What the base of phireman-resilient hears (planner/base_view.py): the backward computation
against the forward flood of every table (the reference), delays and losses by hand, and the
planner acting on the heard picture only."""

import numpy as np
import pytest

from planner.base_view import BaseListener, heard_reference
from planner.geometry import active_mask, tasks_connected
from planner.knowledge import MessageLayer
from planner.methods import TickInput, make_planner
from planner.problem import problem_preset

R, BASE_REACH = 2.0, 2.0
BASE = np.zeros(2)


def _layer(n, n_steps, after_move, age=15):
    layer = MessageLayer(
        n, n_steps, R, BASE_REACH, 3, 6.0, 15, after_move=after_move, forget_unheard=True
    )
    return layer, BaseListener(age, after_move, R, BASE_REACH)


def _step(layer, listener, t, pos, alive, tasks):
    layer.step(t, pos, alive, BASE, None)
    listener.record(t, layer.knowledge, pos, alive, tasks, BASE)
    return listener.heard(t, len(pos), len(tasks))


def _same(a, b):
    assert np.array_equal(a.stamp, b.stamp)
    assert np.array_equal(a.pos_u, b.pos_u, equal_nan=True)
    assert np.array_equal(a.edges, b.edges)
    assert np.array_equal(a.at_base, b.at_base)
    assert np.array_equal(a.networked, b.networked)
    assert np.array_equal(a.crews, b.crews)
    pa = sorted(map(tuple, a.crew_pairs.tolist()))
    pb = sorted(map(tuple, b.crew_pairs.tolist()))
    assert pa == pb


@pytest.mark.parametrize("after_move", [True, False])
@pytest.mark.parametrize("age", [15, 3])
def test_listener_matches_the_forward_flood(after_move, age):
    """Random walks with losses: at every step the base's stamps, positions, two-way links,
    networked set and crews equal those of flooding every table forward, entry by entry."""
    rng = np.random.default_rng(7 + age + after_move)
    n, m, steps = 14, 3, 30
    pos = rng.uniform(-1.0, 1.0, (n, 2))
    tasks = rng.uniform(-5.0, 5.0, (m, 2))
    alive = np.ones(n, bool)
    layer, listener = _layer(n, steps, after_move, age)
    pos_hist, alive_hist, task_hist = [], [], []
    seen_far, unseen = False, False
    for t in range(steps):
        pos_hist.append(pos.copy())
        alive_hist.append(alive.copy())
        task_hist.append(tasks.copy())
        got = _step(layer, listener, t, pos.copy(), alive.copy(), tasks)
        ref = heard_reference(
            np.array(pos_hist),
            np.array(alive_hist),
            np.array(task_hist),
            t,
            R,
            BASE_REACH,
            BASE,
            age,
            after_move,
        )
        _same(got, ref)
        seen_far |= bool((got.stamp >= 0).any() and (got.stamp[got.stamp >= 0] < t - 2).any())
        unseen |= bool((alive & (got.stamp < 0)).any())
        step = rng.normal(0.0, 0.5, (n, 2)) + 0.15 * np.sign(pos)  # spread out
        pos = np.where(alive[:, None], pos + step, pos)
        tasks = tasks + rng.normal(0.0, 0.2, (m, 2))
        alive &= rng.random(n) >= 0.02
    assert seen_far and unseen  # the comparison covered delayed and missing reports


def _chain_positions():
    # base at the origin, four drones in a line 1.5 apart (one hop each), one drone far away
    return np.array([[0.0, 1.5], [0.0, 3.0], [0.0, 4.5], [0.0, 6.0], [10.0, 10.0]])


def test_a_drone_that_moved_is_seen_where_it_was():
    """Chain of hops 1..4 (after-move broadcasts): the base holds drone h's report of h - 1 steps
    ago, so the last drone, sliding sideways, is seen at its position 3 steps ago."""
    pos = _chain_positions()
    alive = np.ones(5, bool)
    tasks = np.zeros((0, 2))
    layer, listener = _layer(5, 20, True)
    hist = []
    for t in range(12):
        hist.append(pos.copy())
        heard = _step(layer, listener, t, pos.copy(), alive, tasks)
        pos[3, 0] += 0.1  # the last drone slides along x (still within r of drone 2)
    assert list(heard.stamp[:4]) == [11, 10, 9, 8]
    assert np.array_equal(heard.pos_u[3], hist[8][3])
    assert not np.array_equal(heard.pos_u[3], hist[11][3])
    assert np.array_equal(heard.pos_u[0], hist[11][0])  # the base's neighbour: now


def test_beyond_the_flood_nothing_is_heard():
    """The drone out of everybody's range is never heard; the chain is heard one hop per step,
    and so is the crew at its end (the truth connects it from the first step)."""
    pos = _chain_positions()
    alive = np.ones(5, bool)
    tasks = np.array([[0.0, 7.5]])  # within r of the last drone only
    layer, listener = _layer(5, 20, True)
    truth = tasks_connected(tasks, pos, active_mask(pos, alive, R, BASE_REACH), R)
    assert truth[0]
    stamps, crews, networked = [], [], []
    for t in range(7):
        heard = _step(layer, listener, t, pos.copy(), alive, tasks)
        stamps.append(heard.stamp.copy())
        crews.append(bool(heard.crews[0]))
        networked.append(heard.networked.copy())
    assert all(s[4] == -1 for s in stamps) and not any(nw[4] for nw in networked)
    assert np.isnan(heard.pos_u[4]).all()
    # drone h (0-based) is first heard at step h + 1 (nothing is delivered at step 0)
    first = [next(t for t, s in enumerate(stamps) if s[h] >= 0) for h in range(4)]
    assert first == [1, 2, 3, 4]
    # the crew needs the last drone's report and both ends of every link of the chain
    assert crews == [False, False, False, False, True, True, True]


def test_a_lost_relay_drops_out_when_its_neighbour_reports():
    """Drone 1 of the chain is lost at step 8: its last report still lists its links, but drone
    0's report of step 8 no longer does, so the base stops believing the chain behind it is
    networked at once (two-way check), although it still holds drone 1's old report."""
    pos = _chain_positions()
    alive = np.ones(5, bool)
    tasks = np.zeros((0, 2))
    layer, listener = _layer(5, 20, True)
    for t in range(8):
        heard = _step(layer, listener, t, pos.copy(), alive, tasks)
    assert heard.networked[:4].all()
    alive[1] = False
    heard = _step(layer, listener, 8, pos.copy(), alive, tasks)
    assert heard.stamp[1] == 7  # its last report (step 7, relayed by drone 0 at step 8)
    assert heard.networked[0] and not heard.networked[1:4].any()
    assert heard.stamp[2] >= 0 and heard.stamp[3] >= 0  # still held, no longer believed networked


def test_the_planner_acts_on_what_the_base_heard():
    """phireman-resilient (async, base_view='heard') on a chain to a crew with spares at the base:
    every spare target it files is the heard position of a relay the base believes networked, and
    at some step that differs from the relay's true position (the picture is delayed, not the
    truth); with base_view='oracle' every target is the relay's true position."""
    problem = problem_preset("S", 0.0, n_drones=7, n_tasks=1)
    task = np.array([[0.0, 5.6]])
    start = np.array(
        [[0.0, 1.6], [0.0, 3.2], [0.0, 4.8], [0.3, 0.3], [-0.3, 0.3], [0.3, -0.3], [-0.3, -0.3]]
    )
    alive = np.ones(7, bool)

    def run(base_view):
        planner = make_planner(
            "phireman-resilient",
            problem,
            {"claim_gain": 0.0, "base_view": base_view},
            np.random.default_rng(0),
        )
        pos = start.copy()
        differs = checked = 0
        for t in range(40):
            net = active_mask(pos, alive, R, BASE_REACH)
            out = planner.plan(TickInput(t, pos, alive, net, task))
            targets = planner._spare_by_stamp[t]
            for spare, relay in planner._book.pair_of.items():
                true_u = planner.units.to_u(pos[relay])
                if base_view == "heard":
                    heard = planner.heard
                    assert heard.networked[spare] and heard.networked[relay]
                    assert np.array_equal(targets[spare], heard.pos_u[relay])
                differs += not np.array_equal(targets[spare], true_u)
                checked += 1
            pos = pos + out.disp_m
        return checked, differs

    checked, differs = run("heard")
    assert checked > 0 and differs > 0
    checked, differs = run("oracle")
    assert checked > 0 and differs == 0


def test_base_view_is_validated():
    from planner.resilient import ResilientParams

    with pytest.raises(ValueError):
        ResilientParams(base_view="truth")

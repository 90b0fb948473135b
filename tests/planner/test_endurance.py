"""The rotation policy (planner/endurance.py) in a toy world: relays hold fixed posts, spares and
returning drones fly straight at the policy's speed, batteries drain at a constant rate in the air.
"""

from __future__ import annotations

import numpy as np
import pytest

from planner.endurance import (
    AIR,
    INBOUND,
    LOST,
    NO_BATTERY,
    READY,
    REFILL_MARGIN,
    RETURNING,
    SWAPPING,
    BaseResources,
    EnduranceParams,
    RotationPolicy,
    plan_fleet,
    reserve_frac,
    time_to_reserve_s,
)


def _toy_run(
    n: int,
    k: int,
    endurance_s: float,
    horizon_s: float,
    base: BaseResources,
    params: EnduranceParams,
    post_dist_m: float = 300.0,
    dt_s: float = 1.0,
    kill: dict[int, int] | None = None,
    spare_ratio: float = 0.0,
):
    """Fly the policy for ``horizon_s``: returns (policy, min battery in the air, min planned, log)."""
    rng = np.random.default_rng(0)
    ang = rng.uniform(0, 2 * np.pi, n)
    posts = post_dist_m * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    pol = RotationPolicy(n, k, base, params, spare_ratio=spare_ratio)
    pos = np.zeros((n, 2))
    pos[:k] = posts[:k]
    # Stagger the first batteries so that the first rotations do not all fall due at once.
    batt = np.ones(n)
    batt[:k] = np.linspace(1.0, 0.55, k)
    alive = np.ones(n, bool)
    rate = 1.0 / endurance_s
    post_of = np.arange(n)  # the post each planned drone holds
    min_air = 1.0
    min_planned = n
    events = []
    v = params.return_speed_m_s * dt_s
    for step in range(int(horizon_s / dt_s)):
        t = step * dt_s
        if kill and step in kill:
            alive[kill[step]] = False
        ph = pol.phase
        landed = (ph == RETURNING) & (np.hypot(pos[:, 0], pos[:, 1]) < 1.0)
        out = pol.step(
            t,
            pos,
            alive,
            batt,
            np.full(n, rate),
            networked=alive.copy(),
            landed_at_base=landed,
        )
        events.extend(out.events)
        batt[out.battery_swapped] = 1.0
        # A spare that took over holds its relay's post.
        for e in out.events:
            if e.kind == "handover":
                post_of[e.drone] = post_of[e.other]
        target = np.where(np.isnan(out.target_m), posts[post_of], out.target_m)
        d = target - pos
        dist = np.hypot(d[:, 0], d[:, 1])
        step_m = np.minimum(dist, v)
        with np.errstate(invalid="ignore", divide="ignore"):
            move = np.where(dist[:, None] > 0, d / np.where(dist > 0, dist, 1)[:, None], 0)
        pos = pos + move * step_m[:, None] * (alive & ~out.on_ground)[:, None]
        flying = alive & ~out.on_ground
        batt = np.where(flying, batt - rate * dt_s, batt)
        if flying.any():
            min_air = min(min_air, float(batt[flying].min()))
        min_planned = min(min_planned, int(np.count_nonzero(out.planned & alive)))
    return pol, min_air, min_planned, events


def test_reserve_grows_with_the_way_home_and_time_to_reserve_counts_down():
    p = EnduranceParams(critical_frac=0.1, margin_frac=0.05, return_speed_m_s=5.0)
    r = reserve_frac(np.array([0.0, 500.0]), np.array([1e-3, 1e-3]), p)
    assert r[0] == pytest.approx(0.15)
    assert r[1] == pytest.approx(0.15 + 1e-3 * 100.0)
    t = time_to_reserve_s(np.array([0.5, 0.15, np.nan]), np.full(3, 1e-3), np.zeros(3), p)
    assert t[0] == pytest.approx(350.0)
    assert t[1] == 0.0 and t[2] == 0.0  # due, and unknown -> due
    assert time_to_reserve_s(np.array([0.5]), np.array([0.0]), np.zeros(1), p)[0] == np.inf


def test_a_spare_launches_in_time_and_the_relay_leaves_only_after_the_handover():
    p = EnduranceParams(handover_s=0.0, launch_s=0.0, slack_s=10.0)
    base = BaseResources(pads=1, swap_time_s=10.0, spare_batteries=5)
    pol = RotationPolicy(2, 1, base, p)
    pos = np.array([[200.0, 0.0], [0.0, 0.0]])
    rate = np.full(2, 1e-3)
    ones = np.ones(2, bool)
    # Relay at 0.5: reserve = 0.15 + 1e-3 * 40 = 0.19, 310 s away; lead = 40 + 10 s: nothing yet.
    out = pol.step(0.0, pos, ones, np.array([0.5, 1.0]), rate, ones, np.zeros(2, bool))
    assert out.planned.tolist() == [True, False] and not out.events
    # At 0.24 it is 50 s from its reserve: the spare is launched toward the relay.
    out = pol.step(1.0, pos, ones, np.array([0.24, 1.0]), rate, ones, np.zeros(2, bool))
    assert [e.kind for e in out.events] == ["launch"]
    assert pol.phase.tolist() == [AIR, INBOUND]
    np.testing.assert_allclose(out.target_m[1], pos[0])
    # Not yet within the hold radius: the relay stays.
    pos2 = np.array([[200.0, 0.0], [150.0, 0.0]])
    pol.step(2.0, pos2, ones, np.array([0.23, 0.99]), rate, ones, np.zeros(2, bool))
    assert pol.phase.tolist() == [AIR, INBOUND]
    # Within the radius but not networked: the relay stays.
    pos3 = np.array([[200.0, 0.0], [195.0, 0.0]])
    net = np.array([True, False])
    pol.step(3.0, pos3, ones, np.array([0.22, 0.98]), rate, net, np.zeros(2, bool))
    assert pol.phase.tolist() == [AIR, INBOUND]
    out = pol.step(4.0, pos3, ones, np.array([0.21, 0.98]), rate, ones, np.zeros(2, bool))
    assert pol.phase.tolist() == [RETURNING, AIR]
    assert [e.kind for e in out.events] == ["handover", "return"]
    np.testing.assert_allclose(out.target_m[0], [0.0, 0.0])
    # Home: lands, takes the pad, swaps for 10 s, and is a spare again with a full battery.
    landed = np.array([True, False])
    pol.step(50.0, pos3, ones, np.array([0.17, 0.95]), rate, ones, landed)
    assert pol.phase[0] == SWAPPING and pol.stock == 4
    out = pol.step(60.0, pos3, ones, np.array([0.17, 0.95]), rate, ones, landed)
    assert pol.phase[0] == READY and out.battery_swapped.tolist() == [True, False]
    assert pol.summary()["rotations"] == 1 and pol.summary()["swaps"] == 1


def test_a_relay_whose_reserve_falls_after_the_mission_end_holds_its_post():
    p = EnduranceParams(handover_s=0.0, launch_s=0.0, slack_s=10.0)
    base = BaseResources(pads=1, swap_time_s=10.0, spare_batteries=5)
    pos = np.array([[200.0, 0.0], [0.0, 0.0]])
    rate = np.full(2, 1e-3)
    ones = np.ones(2, bool)
    batt = np.array([0.24, 1.0])  # 50 s from its reserve, within the 50-s lead: relieved ...
    pol = RotationPolicy(2, 1, base, p)
    out = pol.step(1000.0, pos, ones, batt, rate, ones, np.zeros(2, bool), end_s=1100.0)
    assert [e.kind for e in out.events] == ["launch"]
    # ... but not when the mission ends before its reserve, beyond the slack: it stays to the end.
    for end_s in (1030.0, 1039.0):
        pol = RotationPolicy(2, 1, base, p)
        out = pol.step(1000.0, pos, ones, batt, rate, ones, np.zeros(2, bool), end_s=end_s)
        assert not out.events and pol.phase.tolist() == [AIR, READY], end_s
    # Within the slack of the end (the estimate may still shorten): relieved.
    pol = RotationPolicy(2, 1, base, p)
    out = pol.step(1000.0, pos, ones, batt, rate, ones, np.zeros(2, bool), end_s=1041.0)
    assert [e.kind for e in out.events] == ["launch"]


def test_no_spare_is_spent_on_relays_that_last_to_the_end_of_the_mission():
    # Six relays due one after another, too close for the spares to turn around: the schedule
    # relieves the first ones early. With the mission's end known, the ones that last to it are
    # out of the schedule: fewer launches, and the ones due before the end are not pulled earlier.
    p = EnduranceParams(handover_s=0.0, launch_s=0.0, slack_s=10.0)
    base = BaseResources(pads=1, swap_time_s=60.0, spare_batteries=10)
    n, k = 9, 6
    pos = np.zeros((n, 2))
    pos[:k, 0] = 200.0
    rate = np.full(n, 1e-3)
    ones = np.ones(n, bool)
    batt = np.ones(n)
    batt[:k] = 0.19 + 1e-3 * np.array([60.0, 65.0, 70.0, 200.0, 205.0, 210.0])
    launched = {}
    for end_s in (np.inf, 150.0):
        pol = RotationPolicy(n, k, base, p)
        out = pol.step(0.0, pos, ones, batt, rate, ones, np.zeros(n, bool), end_s=end_s)
        launched[end_s] = sorted(e.other for e in out.events if e.kind == "launch")
    # Without the end, the three late relays (reserves at 200-210 s) push relay 2 (70 s) into
    # this tick's launches; with the mission over at 150 s they stay, and relay 2 waits.
    assert launched[np.inf] == [0, 1, 2]
    assert launched[150.0] == [0, 1]


def test_out_of_reserve_without_a_spare_goes_home_rather_than_reach_critical():
    p = EnduranceParams()
    pol = RotationPolicy(1, 1, BaseResources(), p)
    pos = np.array([[100.0, 0.0]])
    one = np.ones(1, bool)
    out = pol.step(0.0, pos, one, np.array([0.5]), np.array([1e-3]), one, ~one)
    assert [e.kind for e in out.events] == []
    # Reserve 0.15 + 20 s home = 0.17; at 0.25 it is 80 s away, inside the 85-s lead.
    out = pol.step(1.0, pos, one, np.array([0.25]), np.array([1e-3]), one, ~one)
    assert [e.kind for e in out.events] == ["no_spare"]  # due soon, nobody to send
    out = pol.step(2.0, pos, one, np.array([0.16]), np.array([1e-3]), one, ~one)
    assert [e.kind for e in out.events] == ["forced_return"]
    assert pol.phase[0] == RETURNING and pol.counters["forced_returns"] == 1


def test_a_lost_relay_lets_its_inbound_spare_join_the_plan():
    p = EnduranceParams(slack_s=1000.0)
    pol = RotationPolicy(2, 1, BaseResources(), p)
    pos = np.array([[100.0, 0.0], [0.0, 0.0]])
    both = np.ones(2, bool)
    pol.step(0.0, pos, both, np.array([0.5, 1.0]), np.full(2, 1e-3), both, ~both)
    assert pol.phase.tolist() == [AIR, INBOUND]
    out = pol.step(
        1.0, pos, np.array([False, True]), np.array([0.5, 1.0]), np.full(2, 1e-3), both, ~both
    )
    assert pol.phase[1] == AIR and out.planned.tolist() == [False, True]
    assert "lost" in [e.kind for e in out.events]


def test_batteries_charge_and_queue_for_chargers():
    base = BaseResources(
        pads=2, swap_time_s=5.0, spare_batteries=1, chargers=1, charge_time_s=100.0
    )
    pol = RotationPolicy(2, 0, base, EnduranceParams())
    pol.phase[:] = RETURNING
    pos = np.zeros((2, 2))
    both = np.ones(2, bool)
    out = pol.step(0.0, pos, both, np.full(2, 0.2), np.zeros(2), both, both)
    kinds = [e.kind for e in out.events]
    assert kinds.count("swap_start") == 1 and kinds.count("no_battery") == 1
    assert pol.stock == 0
    # The one battery out charges 100 s; the second drone waits on its pad until then.
    pol.step(50.0, pos, both, np.full(2, 0.2), np.zeros(2), both, both)
    assert pol.phase.tolist() == [READY, NO_BATTERY]
    pol.step(100.0, pos, both, np.full(2, 0.2), np.zeros(2), both, both)
    assert pol.phase[1] == SWAPPING
    out = pol.step(105.0, pos, both, np.full(2, 0.2), np.zeros(2), both, both)
    assert pol.phase.tolist() == [READY, READY] and out.battery_swapped[1]


def test_each_swap_takes_the_lowest_free_pad_and_frees_it_when_done_or_lost():
    """The pads the operator's view names (docs/design/endurance.md §8): one drone per pad, the
    lowest free one, free again after the swap or a loss; a drone waiting for a pad has none."""
    base = BaseResources(pads=2, swap_time_s=10.0, spare_batteries=10)
    pol = RotationPolicy(3, 0, base, EnduranceParams())
    pol.phase[:] = RETURNING
    pos = np.zeros((3, 2))
    alive = np.ones(3, bool)

    def step(t_s, landed):
        return pol.step(t_s, pos, alive, np.full(3, 0.2), np.zeros(3), alive, landed)

    step(0.0, np.array([False, True, False]))
    assert pol.pad.tolist() == [-1, 0, -1]
    step(1.0, np.ones(3, bool))
    assert pol.pad.tolist() == [1, 0, -1] and pol.phase[2] != SWAPPING  # no third pad
    alive[1] = False  # lost on pad 0: the pad is free for the drone waiting
    step(2.0, np.ones(3, bool))
    assert pol.pad.tolist() == [1, -1, 0] and pol.phase[2] == SWAPPING
    out = step(11.0, np.ones(3, bool))  # drone 0's swap (started at 1 s) is done
    assert out.battery_swapped[0] and pol.pad.tolist() == [-1, -1, 0]
    assert len(set(pol.pad[pol.pad >= 0].tolist())) == np.count_nonzero(pol.phase == SWAPPING)


def test_plan_fleet_never_plans_more_than_the_batteries_can_carry():
    """The defaults' 50 spare batteries and 16 chargers carry about 15 posts for two hours: the
    toy world then always has a charged spare to send (the bound's reason to exist); drones may
    wait on the ground for a battery, but no relay waits for a spare."""
    p = EnduranceParams()
    base = BaseResources()
    plan = plan_fleet(50, 1500.0, 7200.0, base, p, mean_dist_m=300.0)
    assert plan.limit == "batteries"
    pol, min_air, _, events = _toy_run(50, plan.flying, 1500.0, 7200.0, base, p)
    kinds = [e.kind for e in events]
    assert "no_spare" not in kinds and "forced_return" not in kinds
    assert min_air > p.critical_frac
    # A few more posts than planned run dry: the bound is tight, not just safe.
    _, _, _, events = _toy_run(50, plan.flying + 3, 1500.0, 7200.0, base, p)
    assert "no_spare" in [e.kind for e in events]


def test_plan_fleet_bounds_and_everything_flies_on_a_short_mission():
    p = EnduranceParams()
    base = BaseResources()
    short = plan_fleet(50, 1500.0, 200.0, base, p, mean_dist_m=300.0)
    assert short.flying == 50 and short.limit == "none"
    long = plan_fleet(50, 1500.0, 7200.0, base, p, mean_dist_m=300.0)
    assert 0 < long.flying < 50 and long.flying + long.spares == 50
    few_pads = plan_fleet(50, 1500.0, 7200.0, BaseResources(pads=1, swap_time_s=300.0), p, 300.0)
    assert few_pads.limit == "pads" and few_pads.flying < long.flying
    with pytest.raises(ValueError, match="no rotation is possible"):
        plan_fleet(50, 100.0, 7200.0, base, p, mean_dist_m=3000.0)


@pytest.mark.parametrize("seed_kill", [None, {900: 3, 2500: 0}])
def test_two_hours_in_the_toy_world_never_starve_and_never_reach_critical(seed_kill):
    """50 drones, 25-minute batteries, 4 pads, 60-s swaps, 2 hours (the wildfire_2h numbers)."""
    p = EnduranceParams()
    # 4 pads, 60-s swaps (the defaults) and batteries enough for most of the fleet to fly.
    base = BaseResources(spare_batteries=200, chargers=32)
    plan = plan_fleet(50, 1500.0, 7200.0, base, p, mean_dist_m=300.0)
    pol, min_air, min_planned, events = _toy_run(
        50, plan.flying, 1500.0, 7200.0, base, p, kill=seed_kill
    )
    kinds = [e.kind for e in events]
    assert min_air > p.critical_frac  # nobody at the critical level in the air
    assert kinds.count("forced_return") == 0
    assert plan.flying >= 30  # the batteries are not what bounds the plan here
    assert pol.counters["rotations"] >= plan.flying * 3  # each post rotated several times
    lost = len(seed_kill) if seed_kill else 0
    # The plan keeps its size (less the drones lost) except for one tick at a handover.
    assert min_planned >= plan.flying - lost - 1


def test_the_landing_counts_in_the_reserve_and_shortens_the_sortie():
    p0 = EnduranceParams(critical_frac=0.1, margin_frac=0.05, return_speed_m_s=5.0)
    p1 = EnduranceParams(critical_frac=0.1, margin_frac=0.05, return_speed_m_s=5.0, land_s=40.0)
    d, r = np.array([500.0]), np.array([1e-3])
    assert reserve_frac(d, r, p1)[0] == pytest.approx(reserve_frac(d, r, p0)[0] + 40e-3)
    base = BaseResources(pads=4, swap_time_s=60.0, spare_batteries=500, chargers=50)
    f0 = plan_fleet(50, 1500.0, 2400.0, base, p0, 150.0)
    f1 = plan_fleet(50, 1500.0, 2400.0, base, p1, 150.0)
    assert f1.sortie_s == pytest.approx(f0.sortie_s - 40.0)
    assert f0.limit == f1.limit == "fleet"
    assert f1.flying < f0.flying  # a longer cycle on the ground, fewer posts


def test_a_slower_landing_spaces_the_first_reliefs_further_apart():
    def first_launch_s(land_s: float) -> float:
        p = EnduranceParams(critical_frac=0.2, return_speed_m_s=7.5, land_s=land_s)
        pol = RotationPolicy(12, 10, BaseResources(), p)
        pos = np.zeros((12, 2))
        pos[:10, 0] = 150.0
        batt, t = np.ones(12), 0.0
        while t < 2000.0:
            out = pol.step(
                t,
                pos,
                np.ones(12, bool),
                batt,
                np.full(12, 1 / 1500),
                ~np.zeros(12, bool),
                np.zeros(12, bool),
            )
            if any(e.kind == "launch" for e in out.events):
                return t
            batt[:10] -= 1 / 1500
            t += 1.0
        raise AssertionError("no launch")

    assert first_launch_s(60.0) < first_launch_s(0.0)


def test_a_lost_drone_recovered_is_a_spare_again_and_only_a_lost_one():
    # Without the refill (on by default), which would fly the recovered spare into the post.
    pol = RotationPolicy(3, 2, BaseResources(), EnduranceParams(refill_lost=False))
    alive = np.array([True, False, True])
    pol.step(0.0, np.zeros((3, 2)), alive, np.ones(3), np.full(3, 1e-4), alive, ~alive)
    assert pol.phase[1] == LOST
    with pytest.raises(ValueError):
        pol.recovered(0, 1.0)
    ev = pol.recovered(1, 2.0)
    assert (ev.kind, ev.drone, ev.t_s) == ("recovered", 1, 2.0)
    assert pol.phase[1] == READY and pol.summary()["recovered"] == 1
    stock = pol.stock
    out = pol.step(
        3.0, np.zeros((3, 2)), np.ones(3, bool), np.ones(3), np.full(3, 1e-4), alive, ~alive
    )
    assert pol.phase[1] == READY and "lost" not in [e.kind for e in out.events]
    assert pol.stock == stock  # its battery did not come from the shelf


def test_posts_lost_in_the_air_are_refilled_from_the_spares_only_when_asked():
    """Ten drones die in the first 100 minutes of the toy two hours. Without ``refill_lost``
    the posts of the relays among them stay empty; with it the ready spares hold some again,
    as long as the spares left in circulation keep the plan's ratio to the posts, never more
    than K; either way no relay starves and nobody reaches the critical level in the air."""
    base = BaseResources(spare_batteries=200, chargers=32)
    plan = plan_fleet(50, 1500.0, 7200.0, base, EnduranceParams(), mean_dist_m=300.0)
    k, ratio = plan.flying, plan.ground_s / plan.sortie_s
    kill = {600 * (j + 1): j for j in range(10)}
    posts, refills = {}, {}
    for refill in (False, True):
        p = EnduranceParams(refill_lost=refill)
        pol, min_air, _, events = _toy_run(
            50, k, 1500.0, 7200.0, base, p, kill=kill, spare_ratio=ratio
        )
        kinds = [e.kind for e in events]
        assert min_air > p.critical_frac
        assert kinds.count("forced_return") == 0 and kinds.count("no_spare") == 0
        posts[refill] = int(np.count_nonzero(pol.phase == AIR))
        refills[refill] = kinds.count("refill")
        circulating = int(np.count_nonzero((pol.phase != AIR) & (pol.phase != LOST)))
        if refill:  # the spares a post needs kept, with the margin
            assert circulating >= REFILL_MARGIN * ratio * posts[refill] - 1
    assert refills[False] == 0 and posts[False] <= k - 5
    assert refills[True] >= 1 and posts[False] < posts[True] <= k


@pytest.mark.parametrize("turnaround_s", [0.0, 1000.0])
def test_a_refill_leaves_the_ready_spares_the_reliefs_due_before_one_could_come_back(turnaround_s):
    """Four posts, one lost in the air, two spares ready. Three relays are due for relief in
    about eight minutes, after their launch lead: a refill may take a spare only while the ready
    ones left cover every relief due within the lead and a spare's turnaround (a spare grounded
    now is back too late for them). Without a turnaround to count, the post is refilled."""
    n, k = 6, 4
    pol = RotationPolicy(
        n,
        k,
        BaseResources(),
        EnduranceParams(),
        spare_ratio=0.1,
        turnaround_s=turnaround_s,
    )
    pos = np.zeros((n, 2))
    pos[:k] = [[300.0, 0.0], [0.0, 300.0], [-300.0, 0.0], [0.0, -300.0]]
    alive = np.ones(n, bool)
    alive[3] = False  # lost in the air
    batt = np.array([0.6, 0.62, 0.64, 0.6, 1.0, 1.0])
    rate = np.full(n, 1.0 / 1500.0)
    out = pol.step(0.0, pos, alive, batt, rate, alive, np.zeros(n, bool))
    kinds = [e.kind for e in out.events]
    assert pol.phase[3] == LOST and "launch" not in kinds  # nobody's relief is due yet
    if turnaround_s == 0.0:
        assert kinds.count("refill") == 1 and int(np.count_nonzero(pol.phase == AIR)) == 4
    else:
        assert "refill" not in kinds and int(np.count_nonzero(pol.phase == READY)) == 2

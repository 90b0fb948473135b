"""Hazard awareness (planner/hazard.py and phireman-resilient's ``hazard_*`` parameters): the fast
geometry against its loop references, the tree routed around a disc in a hand-built scenario,
and, on a tiny mission, fewer drone-seconds inside the zone with the mechanism on."""

import dataclasses

import numpy as np
import pytest

from planner.hazard import (
    HazardMap,
    HazardZone,
    hazard_rate_per_s,
    hazard_rate_per_s_reference,
    push_gradient,
    route_tree,
    segment_length_in_zones,
    segment_lengths_per_zone,
    segment_lengths_per_zone_reference,
    signed_depth,
    signed_depth_reference,
    waypoints,
)
from planner.methods import TickInput, make_planner
from planner.problem import problem_preset
from planner.steiner import TaskTree

# A disc flaring up between 30 s and 150 s and a non-convex polygon active all the time (the
# shapes of mission/format/examples/hazard_zone.yaml, plus a notch).
ZONES = HazardMap(
    (
        HazardZone(0.05, center_m=(120.0, 100.0), radius_m=80.0, start_s=30.0, end_s=150.0),
        HazardZone(
            0.02,
            polygon_m=(
                (-250.0, -200.0),
                (-150.0, -250.0),
                (50.0, -120.0),
                (-60.0, -130.0),
                (20.0, -60.0),
            ),
        ),
        HazardZone(0.01, center_m=(-100.0, 150.0), radius_m=60.0),
    )
)


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def test_rate_field_matches_reference(rng):
    pos = rng.uniform(-300, 300, (400, 2))
    for t_s in (0.0, 30.0, 100.0, 150.0):
        fast = hazard_rate_per_s(ZONES, pos, t_s)
        assert np.allclose(fast, hazard_rate_per_s_reference(ZONES, pos, t_s), atol=0)
    assert hazard_rate_per_s(ZONES, [[120.0, 100.0]], 29.9)[0] == 0.0  # not active yet
    assert hazard_rate_per_s(ZONES, [[120.0, 100.0]], 30.0)[0] == 0.05
    assert (hazard_rate_per_s(None, pos, 0.0) == 0).all()


def test_segment_lengths_match_reference(rng):
    a, b = rng.uniform(-300, 300, (300, 2)), rng.uniform(-300, 300, (300, 2))
    fast = segment_lengths_per_zone(ZONES, a, b)
    assert (fast > 0).sum(0).min() > 10  # every zone is crossed by some segments
    assert np.allclose(fast, segment_lengths_per_zone_reference(ZONES, a, b), rtol=0, atol=1e-9)
    # ... and against sampling along each segment
    ts = (np.arange(2000) + 0.5) / 2000
    pts = a[:, None, :] + ts[None, :, None] * (b - a)[:, None, :]
    for z, zone in enumerate(ZONES.zones):
        inside = hazard_rate_per_s(HazardMap((zone,)), pts.reshape(-1, 2), 0.0 if z else 50.0) > 0
        sampled = inside.reshape(len(a), -1).mean(1) * np.linalg.norm(b - a, axis=1)
        assert np.allclose(fast[:, z], sampled, atol=0.5)


def test_segment_length_by_hand():
    disc = HazardMap((HazardZone(1.0, center_m=(0.0, 0.0), radius_m=1.0),))
    a, b = (
        np.array([[-3.0, 0.0], [-3.0, 2.0], [0.0, 0.0]]),
        np.array([[3.0, 0.0], [3.0, 2.0], [5.0, 0.0]]),
    )
    assert np.allclose(segment_length_in_zones(disc, a, b, 0.0), [2.0, 0.0, 1.0])


def test_signed_depth_matches_reference(rng):
    pos = rng.uniform(-300, 300, (400, 2))
    depth, inward = signed_depth(ZONES, pos)
    assert np.allclose(depth, signed_depth_reference(ZONES, pos), atol=1e-9)
    assert np.allclose(np.linalg.norm(inward, axis=2), 1.0)


def test_push_gradient_is_the_gradient_of_the_depth_energy(rng):
    pos = rng.uniform(-300, 300, (200, 2))
    weight = rng.uniform(0.5, 2.0, (len(pos), len(ZONES)))
    margin, h = 10.0, 1e-4

    def energy(x):
        return (weight * np.maximum(0.0, signed_depth_reference(ZONES, x) + margin)).sum(1)

    grad = push_gradient(ZONES, pos, weight, margin)
    num = np.stack(
        [(energy(pos + h * e) - energy(pos - h * e)) / (2 * h) for e in np.eye(2)], axis=1
    )
    # away from the kinks (the margin's edge, the polygons' medial axes) they agree
    assert np.mean(np.all(np.abs(grad - num) < 1e-5, axis=1)) > 0.95
    assert (np.abs(grad).sum(1) > 0).sum() > 20  # some points are pushed


def test_waypoints_are_outside_every_zone():
    wp = waypoints(ZONES, 10.0)
    assert len(wp) > 16
    assert (signed_depth(ZONES, wp)[0] <= -5.0).all()


# -- the tree routed around a disc (hand-built) -----------------------------------------------


HAZARD_OFF = {"hazard_avoid": False, "hazard_push_gain": 0.0}  # the defaults have it on


def _planner(info="central", **params):
    # S geometry: r = 2 paper units; length unit 1 m, so the task sits 10 units (10 m) north.
    p = problem_preset("S", 0.0).replace(n_drones=4, n_tasks=1)
    return make_planner("phireman-resilient", p, {"info": info, **HAZARD_OFF, **params})


def _path_to_base(tree: TaskTree, node: int) -> np.ndarray:
    pts = [tree.nodes_m[node]]
    while node != 0:
        node = int(tree.parent[node])
        pts.append(tree.nodes_m[node])
    return np.array(pts)


RING = np.array([[0.5, 0.0], [0.0, 0.5], [-0.5, 0.0], [0.0, -0.5]])


def _tick(hazards, task=(10.0, 0.0), t=0, pos=RING):
    return TickInput(t, pos, np.ones(4, bool), np.ones(4, bool), np.array([task]), hazards=hazards)


DISC = HazardMap((HazardZone(0.05, center_m=(5.0, 0.2), radius_m=2.0),))


def test_tree_is_routed_around_a_disc_on_the_straight_path():
    cap = 1.5
    out = _planner(hazard_avoid=True, hazard_detour_cap=cap).plan(_tick(DISC))
    path = _path_to_base(out.tree, 1)
    assert len(path) > 2  # detour nodes inserted
    inside = segment_length_in_zones(DISC, path[:-1], path[1:], 0.0)
    assert np.all(inside == 0.0)  # the path avoids the disc
    length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    assert 10.0 < length <= cap * 10.0
    # off: the straight edge
    plain = _planner().plan(_tick(DISC))
    assert plain.tree.n_nodes == 2


def test_detour_longer_than_the_cap_is_not_taken():
    big = HazardMap((HazardZone(0.05, center_m=(5.0, 0.0), radius_m=4.5),))
    out = _planner(hazard_avoid=True, hazard_detour_cap=1.1).plan(_tick(big))
    assert out.tree.n_nodes == 2  # kept straight: no path around within 1.1 x


def test_edge_to_a_task_inside_the_disc_is_kept():
    out = _planner(hazard_avoid=True).plan(_tick(DISC, task=(5.5, 0.0)))
    assert out.tree.n_nodes == 2 and np.allclose(out.tree.nodes_m[1], [5.5, 0.0])


def test_zone_not_active_is_ignored():
    late = HazardMap((dataclasses.replace(DISC.zones[0], start_s=100.0),))
    out = _planner(hazard_avoid=True).plan(_tick(late))
    assert out.tree.n_nodes == 2


def test_route_tree_moves_steiner_nodes_out_and_keeps_tasks():
    tree = TaskTree(
        np.array([[0.0, 0.0], [10.0, 3.0], [10.0, -3.0], [5.0, 0.0]]), np.array([-1, 3, 3, 0]), 2
    )
    routed, n = route_tree(tree, DISC, 0.5, 2.0)
    assert np.array_equal(routed.nodes_m[:3], tree.nodes_m[:3])  # base and tasks stay
    assert signed_depth(DISC, routed.nodes_m[3:])[0].max() < 0  # the Steiner node left the disc
    c = np.arange(1, routed.n_nodes)
    inside = segment_length_in_zones(DISC, routed.nodes_m[c], routed.nodes_m[routed.parent[c]], 0)
    assert inside.max() == 0.0 and n >= 1


# -- the planner contract ---------------------------------------------------------------------


@pytest.mark.parametrize("info", ["central", "async"])
def test_zones_given_but_mechanism_off_changes_nothing(info):
    a, b = _planner(info), _planner(info)
    for t in range(4):
        pa, pb = a.plan(_tick(None, t=t)), b.plan(_tick(DISC, t=t))
        assert np.array_equal(pa.disp_m, pb.disp_m)


@pytest.mark.parametrize("info", ["central", "async"])
def test_push_moves_a_drone_out_of_the_zone(info):
    hz = HazardMap((HazardZone(0.05, center_m=(0.0, 2.0), radius_m=1.0),))
    pos = np.array([[0.5, 0.0], [0.0, 1.5], [-0.5, 0.0], [0.0, -0.5]])
    on, off = _planner(info, hazard_push_gain=4.0), _planner(info)
    for t in range(4):  # async: the drones plan once the tree has reached them
        d_on = on.plan(_tick(hz, t=t, pos=pos)).disp_m
        d_off = off.plan(_tick(hz, t=t, pos=pos)).disp_m
    # drone 1 at (0, 1.5) is 0.5 deep in the disc: pushed out (further than without the push)
    depth_on = signed_depth(hz, pos[1:2] + d_on[1])[0][0, 0]
    depth_off = signed_depth(hz, pos[1:2] + d_off[1])[0][0, 0]
    assert depth_on < depth_off


def test_no_push_near_a_task_inside_the_zone():
    hz = HazardMap((HazardZone(0.05, center_m=(0.0, 1.0), radius_m=1.0),))
    tick = _tick(hz, task=(0.0, 1.0))  # the task at the centre, within r of every drone
    on = _planner(hazard_push_gain=4.0).plan(tick)
    off = _planner().plan(tick)
    assert np.array_equal(on.disp_m, off.disp_m)


def test_async_split_descent_equals_one_numpy_descent():
    """The compiled async path runs the pushed drones by NumPy and the others compiled; it must
    give what one NumPy descent of everybody gives."""
    from planner import _kernels

    if not _kernels.NUMBA:
        pytest.skip("no Numba: only the NumPy path exists")
    hz = HazardMap((HazardZone(0.05, center_m=(0.0, 1.0), radius_m=1.0),))
    outs = []
    for enabled in (True, False):
        old = _kernels.ENABLED
        _kernels.ENABLED = enabled
        try:
            pl = _planner("async", hazard_push_gain=4.0, hazard_avoid=True)
            outs.append([pl.plan(_tick(hz, t=t)).disp_m for t in range(4)])
        finally:
            _kernels.ENABLED = old
    for a, b in zip(*outs):
        assert np.allclose(a, b, atol=1e-12)


# -- a tiny mission: less time inside the zone -------------------------------------------------


def test_drones_spend_less_time_inside_the_zone_with_hazard_awareness():
    from mission.experiments.playback import run_inprocess
    from mission.format.scenario import hazard_map
    from mission.format.schema import (
        Attrition,
        Circle,
        HazardZone as MissionZone,
        LocalPoint,
        PlannerSpec,
    )
    from mission.format.schema import RunSpec
    from tests.small_mission import crew, small_mission

    zone = MissionZone(
        circle=Circle(center=LocalPoint(north_m=90.0, east_m=10.0), radius_m=40.0),
        rate_per_s=0.05,
    )
    base = small_mission(
        "hazard-tiny",
        RunSpec(duration_s=60.0, control_period_s=1.0, seed=0),
        count=8,
        tasks=(crew(180.0, 0.0),),  # a relay halfway (r = 100 m) would sit in the disc
        attrition=Attrition(hazard_zones=(zone,)),
    )
    hm = hazard_map(base.attrition)

    def inside_s(params):
        mission = dataclasses.replace(
            base, planner=PlannerSpec(method="phireman-resilient", params=params)
        )
        total = 0
        for seed in (0, 1):
            rec = run_inprocess(mission, seed).record
            rate = np.stack([hazard_rate_per_s(hm, p, 0.0) for p in rec.pos_m])
            total += int(((rate > 0) & rec.alive).sum())
        return total

    # The other pulls off, so that only the hazard mechanism differs.
    alone = {"claim_gain": 0.0, "redundancy_gain": 0.0}
    off = inside_s({**alone, **HAZARD_OFF})
    on = inside_s({**alone, "hazard_avoid": True, "hazard_push_gain": 1.0})
    assert off > 0 and on < 0.5 * off, (off, on)  # measured: 86 and 24 drone-steps

"""A cut branch's drones fly to the rally point, not home, and are reclaimed there (issue 15.3).

The whole flight path in memory (station, operator with ``phireman-resilient`` rally on, the
emulated swarm with each firmware's RTL rule, the radio, the mission world) on a virtual clock,
as tests/integration/test_pair.py flies it. One crew 240 m north of the base: one branch; the
station keeps its rally point on the vehicles (about 90 m north: ``rally_dist`` = 2 paper units
of 50 m, less gcs/rally.py ``RallyConfig.inward_m``). Once the relay chain stands, every drone within 130 m of the base is lost: the outer
drones are cut off, their GCS failsafe (ArduPilot FS_GCS_TIMEOUT 5 s; PX4 offboard loss
COM_OF_LOSS_T then Return) flies them to the rally point (about 100 m from the base and from
them) instead of home (their spawn, about 15 m from the base); at the rally point they are in
the base's range again and the station reclaims them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from small_mission import crew, small_mission
from mission.flight.ether import LockstepEther, station_for_swarm
from mission.flight.fly_options import FlyOptions
from mission.flight.mission_world import MissionWorld, build_swarm, mission_scenario
from mission.format.schema import (
    Mission,
    PlannerSpec,
    RunSpec,
)
from mission.flight.station_loop import make_operator

SEED = 3


def _mission(personality: str, rally: bool) -> Mission:
    return small_mission(
        "rally",
        RunSpec(duration_s=150.0, control_period_s=1.0, seed=SEED),
        count=6,
        personality=personality,
        tasks=(crew(240.0, 0.0),),
        planner=PlannerSpec(method="phireman-resilient", params={"rally": rally}),
    )


class Flight:
    def __init__(self, mission: Mission, params: dict | None = None) -> None:
        scenario = mission_scenario(mission, SEED)
        self.swarm = build_swarm(mission, scenario, seed=SEED, params=params)
        self.world = MissionWorld(mission, scenario, self.swarm)
        self.station = station_for_swarm(self.swarm)
        self.op = make_operator(
            mission,
            scenario,
            self.station,
            FlyOptions(wave_size=10),
            mission.vehicles.count,
            0.0,
            SEED,
        )
        self.ether = LockstepEther(self.swarm, self.station, np.random.default_rng(SEED))
        self.ether.on_event = self.op.handle_event
        self.started = False

    def _poll(self, now: float) -> None:
        self.op.poll(now)
        if not self.started and self.op.mission_t0_s is not None:
            self.started = True
            self.world.start(self.op.mission_t0_s)

    def run_until(self, t_s: float, every=None) -> None:
        while self.ether.now_s < t_s - 1e-9:
            self.ether.advance_to(
                min(t_s, self.ether.now_s + 0.5), poll=self._poll, poll_period_s=0.5
            )
            if every is not None:
                every()

    def run_until_phase(self, phase: str, limit_s: float = 200.0) -> None:
        while self.op.phase != phase and self.ether.now_s < limit_s:
            self.run_until(self.ether.now_s + 1.0)
        assert self.op.phase == phase


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_cut_branch_returns_to_the_rally_point_and_is_reclaimed(personality):
    f = Flight(_mission(personality, rally=True))
    f.run_until_phase("run")
    t0 = f.op.mission_t0_s
    f.run_until(t0 + 70.0)
    keeper = f.op.rally
    assert keeper is not None and keeper.points_ne_m is not None
    # On the branch, 10 m inside the base's reach (RallyConfig.inward_m).
    np.testing.assert_allclose(keeper.points_ne_m, [[90.0, 0.0]], atol=5.0)
    rally = keeper.points_ne_m[0]
    ids = [(0, int(s)) for s in f.swarm.sysid_of_index]
    assert all(keeper.up_to_date(vid) for vid in ids)  # every vehicle holds the set
    for core in f.swarm.cores:  # as the firmware stores it
        np.testing.assert_allclose(core.pers.rally_ne_m(), [rally], atol=0.5)

    pos = f.swarm.physics.pos_ned_m[:, :2]
    inner = np.flatnonzero(np.hypot(*pos.T) < 130.0)
    outer = np.flatnonzero(np.hypot(*pos.T) >= 130.0)
    assert len(outer) >= 1 and len(inner) >= 1, np.hypot(*pos.T)  # the chain stands
    now = f.ether.now_s
    for i in inner.tolist():
        f.swarm.attrition.add_kill(now, i)
    closest = {i: np.inf for i in outer.tolist()}
    sysid_of = {i: int(f.swarm.sysid_of_index[i]) for i in outer.tolist()}

    def track():
        # Only while the drone flies its own failsafe: once the station has reclaimed it, the
        # plan moves it (claims and spares may well bring it in toward the base).
        back = {s for _, _, s in f.op.reclaimed}
        p = f.swarm.physics.pos_ned_m[:, :2]
        for i in closest:
            if sysid_of[i] not in back:
                closest[i] = min(closest[i], float(np.hypot(*p[i])))

    f.run_until(now + 60.0, every=track)
    sysids = {int(f.swarm.sysid_of_index[i]) for i in outer.tolist()}
    for i in outer.tolist():
        core = f.swarm.cores[i]
        # The failsafe RTL chose the rally point, not home (chosen at RTL entry).
        np.testing.assert_allclose(core._rtl_dest_ned_m[:2], rally, atol=0.5)
        assert np.hypot(*(core._rtl_dest_ned_m[:2] - core.home_ned_m[:2])) > 50.0
        # ... flew toward it, never came back near the base (home is ~15 m from it) before the
        # station reclaimed it ...
        assert np.isfinite(closest[i]) and closest[i] > 60.0, closest
    # ... and the station took them back into the plan.
    assert sysids <= {s for _, _, s in f.op.reclaimed}


def test_without_rally_points_the_cut_drones_head_home():
    f = Flight(_mission("ardupilot", rally=False))
    assert f.op.rally is None
    f.run_until_phase("run")
    t0 = f.op.mission_t0_s
    f.run_until(t0 + 70.0)
    pos = f.swarm.physics.pos_ned_m[:, :2]
    outer = np.flatnonzero(np.hypot(*pos.T) >= 130.0)
    assert len(outer) >= 1
    now = f.ether.now_s
    for i in np.flatnonzero(np.hypot(*pos.T) < 130.0).tolist():
        f.swarm.attrition.add_kill(now, i)
    f.run_until(now + 20.0)
    for i in outer.tolist():
        core = f.swarm.cores[i]
        assert core.mode_name == "RTL" or (0, int(f.swarm.sysid_of_index[i])) in {
            (lid, s) for _, lid, s in f.op.reclaimed
        }
        np.testing.assert_allclose(core._rtl_dest_ned_m, core.home_ned_m)


def test_the_end_clears_the_rally_points_before_the_rtl_so_it_goes_home():
    mission = dataclasses.replace(
        _mission("ardupilot", rally=True),
        run=RunSpec(duration_s=40.0, control_period_s=1.0, seed=SEED),
    )
    f = Flight(mission)
    f.run_until_phase("run")
    f.run_until(f.op.mission_t0_s + 30.0)
    assert all(len(core.pers.rally_ne_m()) == 1 for core in f.swarm.cores)
    f.run_until_phase("done", limit_s=400.0)
    rtl = [core for core in f.swarm.cores if core.mode_name == "RTL"]
    assert len(rtl) == len(f.swarm.cores)  # the end command: RTL
    for core in rtl:
        assert core.pers.rally_ne_m().shape == (0, 2)  # cleared first ...
        np.testing.assert_allclose(core._rtl_dest_ned_m, core.home_ned_m)  # ... so: home
        assert core.landed and not core.armed


@pytest.mark.parametrize(
    "personality, boot, name, want",
    [
        ("ardupilot", {}, "RALLY_LIMIT_KM", 0.0),  # Copter default 0.3 km -> no limit
        ("px4", {"RTL_TYPE": 2}, "RTL_TYPE", 0.0),  # 2 ignores rally points -> 0
    ],
)
def test_the_audit_makes_the_firmware_use_rally_points(personality, boot, name, want):
    f = Flight(_mission(personality, rally=True), params=boot)
    f.run_until_phase("run")
    assert [core.params[name] for core in f.swarm.cores] == [want] * len(f.swarm.cores)
    changes = [c for c in f.op.param_changes if c["name"] == name]
    assert len(changes) == len(f.swarm.cores)
    assert all(c["ok"] and c["purpose"] == "rally" for c in changes)

"""A mission with a live MAVLink task (a crew tracker) flown in memory: the operator waits for the
tracker before launching, plans toward where the tracker says the crew is, holds its last fix
when it falls silent, and refuses to launch when a tracker is never heard."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from small_mission import crew, small_mission
from mission.flight.ether import LockstepEther, station_for_swarm
from mission.flight.fly_options import FlyOptions
from mission.flight.mission_world import build_swarm, mission_scenario
from mission.flight.station_loop import live_task_columns, make_operator
from mission.format.schema import (
    MavlinkSource,
    RunSpec,
    Task,
)
from planner.geometry import ned_to_geodetic

TRACKER = 200


class _Tracker:
    """A crew's tracker: HEARTBEAT (ground rover, no autopilot) and GLOBAL_POSITION_INT."""

    class _Null:
        def write(self, _data):
            pass

    def __init__(self):
        self.mav = mavlink.MAVLink(self._Null(), TRACKER, 1)

    def _pack(self, msg) -> bytes:
        data = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        return data

    def heartbeat(self) -> bytes:
        return self._pack(
            mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_GROUND_ROVER,
                mavlink.MAV_AUTOPILOT_INVALID,
                0,
                0,
                mavlink.MAV_STATE_ACTIVE,
                3,
            )
        )

    def global_position(self, lat_deg, lon_deg, alt_amsl_m, rel_alt_m) -> bytes:
        return self._pack(
            mavlink.MAVLink_global_position_int_message(
                1000,
                round(lat_deg * 1e7),
                round(lon_deg * 1e7),
                round(alt_amsl_m * 1000),
                round(rel_alt_m * 1000),
                0,
                0,
                0,
                0,
            )
        )


def _mission(duration_s=40.0):
    return small_mission(
        "live",
        RunSpec(duration_s=duration_s, control_period_s=1.0, seed=3),
        count=6,
        tasks=(crew(-40.0, -30.0), Task(name="crew", mavlink=MavlinkSource(sysid=TRACKER))),
    )


class _Flight:
    def __init__(self, mission, tracker_from_s=None, crew_ne_m=(120.0, 90.0), silent_after_s=None):
        self.mission = mission
        scenario = mission_scenario(mission, 3, live_tasks=True)
        swarm = build_swarm(mission, scenario, seed=3)
        self.station = station_for_swarm(
            swarm, task_sysids=tuple(live_task_columns(mission).values())
        )
        self.op = make_operator(
            mission, scenario, self.station, FlyOptions(wave_size=10), 6, 0.0, 3
        )
        self.ether = LockstepEther(swarm, self.station, np.random.default_rng(3))
        self.ether.on_event = self.op.handle_event
        self.tracker = _Tracker()
        o = mission.origin
        lat, lon, alt = ned_to_geodetic(
            np.array([*crew_ne_m, 0.0]), o.lat_deg, o.lon_deg, o.alt_amsl_m
        )
        self.fix = (float(lat), float(lon), float(alt))
        self.tracker_from_s, self.silent_after_s = tracker_from_s, silent_after_s
        self._next_fix_s = 0.0

    def _poll(self, now):
        if (
            self.tracker_from_s is not None
            and now >= self.tracker_from_s
            and (self.silent_after_s is None or now < self.silent_after_s)
            and now >= self._next_fix_s
        ):
            self._next_fix_s = now + 1.0
            link = self.station.links[0]
            link.receive_datagram(self.tracker.heartbeat(), ("tracker", 0), now)
            link.receive_datagram(self.tracker.global_position(*self.fix, 0.0), ("tracker", 0), now)
        self.op.poll(now)

    def run_until(self, t_s):
        while self.ether.now_s < t_s and not self.op.finished:
            self.ether.advance_to(
                min(t_s, self.ether.now_s + 1.0), poll=self._poll, poll_period_s=0.5
            )


def test_launch_waits_for_the_tracker_then_serves_the_crew():
    f = _Flight(_mission(), tracker_from_s=20.0)
    f.run_until(19.0)
    assert f.op.phase == "discover" and len(f.op.fleet) == 6  # every drone heard, crew not yet
    assert f.op.live_tasks.waiting_for() == (TRACKER,)
    f.run_until(150.0)
    assert f.op.phase in ("run", "end", "done")
    assert len(f.op.fleet) == 6  # the tracker never became a fleet row
    tasks = f.op.task_pos_fn(10.0)
    assert np.allclose(tasks, [[-40.0, -30.0], [120.0, 90.0]], atol=0.5)
    # The plan reached the crew: a drone ends up within radio range of it.
    recs = f.op.records
    assert recs and max(r.tasks_covered for r in recs) == 2


def test_a_silent_tracker_keeps_its_last_position():
    f = _Flight(_mission(duration_s=30.0), tracker_from_s=0.0, silent_after_s=12.0)
    f.run_until(200.0)
    assert f.op.phase == "done"
    assert f.op.live_tasks.silent(f.ether.now_s, 5.0) == (TRACKER,)
    assert np.allclose(f.op.task_pos_fn(25.0)[1], [120.0, 90.0], atol=0.5)


def test_a_tracker_never_heard_refuses_the_launch():
    f = _Flight(_mission(), tracker_from_s=None)
    f.run_until(400.0)
    assert f.op.phase == "refused"
    assert str(TRACKER) in f.op.refusal and "no position" in f.op.refusal
    assert f.op.records == []  # nothing took off

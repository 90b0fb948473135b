"""TAK crews flown in memory (lock-step ether, explicit time): CoT bytes go through the TAK
adapter's receive path (no socket) into the operator; the planner follows a crew that moves,
within one control tick, and plans a stale crew at the base (never its last position)."""

from __future__ import annotations

import numpy as np

from gcs.cot import cot_xml
from mission.flight.ether import LockstepEther, station_for_swarm
from mission.flight.fly_options import FlyOptions
from mission.flight.mission_world import build_swarm, mission_scenario
from mission.flight.station_loop import make_operator
from mission.flight.tak_link import TakConnection, TakLink
from mission.format.schema import RunSpec, TakSource, Task
from planner.geometry import ned_to_geodetic
from small_mission import small_mission

UNIX0 = 1_790_000_000.0


def _mission():
    return small_mission(
        "tak",
        RunSpec(duration_s=60.0, control_period_s=1.0, seed=3),
        count=6,
        tasks=(
            Task(name="Alpha", tak=TakSource(callsign="ALPHA")),
            Task(name="Bravo", tak=TakSource(uid="ANDROID-b")),
        ),
    )


class _Flight:
    def __init__(self, mission, alpha, bravo_silent_after_s):
        scenario = mission_scenario(mission, 3)
        swarm = build_swarm(mission, scenario, seed=3)
        self.station = station_for_swarm(swarm)
        self.op = make_operator(
            mission, scenario, self.station, FlyOptions(wave_size=10), 6, 0.0, 3
        )
        self.ether = LockstepEther(swarm, self.station, np.random.default_rng(3))
        self.ether.on_event = self.op.handle_event
        self.link = TakLink([], self.op.handle_event, clock=lambda: self.ether.now_s)
        self.conn = TakConnection("udp://in-memory")
        self.origin = mission.origin
        self.alpha, self.bravo_silent_after_s = alpha, bravo_silent_after_s
        self._next_s = 0.0
        self.inputs: list[tuple[int, np.ndarray]] = []
        plan = self.op.planner.plan

        def spy(tick):  # what the planner was given, tick by tick
            self.inputs.append((tick.t_step, np.array(tick.task_pos_m)))
            return plan(tick)

        self.op.planner.plan = spy

    def _send(self, uid, callsign, ne, now):
        o = self.origin
        lat, lon, _ = ned_to_geodetic(np.array([*ne, 0.0]), o.lat_deg, o.lon_deg, o.alt_amsl_m)
        data = cot_xml(
            uid=uid,
            type="a-f-G-U-C",
            lat_deg=float(lat),
            lon_deg=float(lon),
            now_unix_s=UNIX0 + now,
            stale_after_s=5.0,
            callsign=callsign,
        )
        assert self.link.receive(self.conn, data) is not None

    def _poll(self, now):
        if now >= self._next_s:
            self._next_s = now + 1.0
            self._send(
                "ANDROID-a",
                "ALPHA",
                self.alpha(self.op.t_mission_s(now) if self.op.mission_t0_s is not None else -1.0),
                now,
            )
            if self.op.mission_t0_s is None or self.op.t_mission_s(now) < self.bravo_silent_after_s:
                self._send("ANDROID-b", "BRAVO", (-70.0, 20.0), now)
        self.op.poll(now)

    def run_until(self, t_s):
        while self.ether.now_s < t_s and not self.op.finished:
            self.ether.advance_to(
                min(t_s, self.ether.now_s + 1.0), poll=self._poll, poll_period_s=0.25
            )


def test_planner_follows_a_tak_crew_and_plans_a_stale_one_at_the_base():
    # Alpha stands 60 m north, then at mission t = 20 s reports 150 m north, 40 m east.
    f = _Flight(_mission(), lambda t: (60.0, 0.0) if t < 20.0 else (150.0, 40.0), 30.0)
    f.run_until(400.0)
    op = f.op
    assert op.phase == "done", op.refusal
    assert op.tak.counters["reports"] > 50 and op.tak.counters["expired"] == 1
    steps = {s: pos for s, pos in f.inputs}
    # Latency: the first tick planned with Alpha's new position (ticks are 1 s apart, mission
    # t = t_step): the report sent at mission t in [20, 21) reaches the tick of t = 21.
    first_new = min(s for s, pos in steps.items() if abs(pos[0, 0] - 150.0) < 0.5)
    print(f"Alpha moved at mission t = 20 s; first planned at tick {first_new}")
    assert 20 <= first_new <= 21
    assert all(abs(pos[0, 0] - 60.0) < 0.5 for s, pos in steps.items() if s < 20)
    # Bravo: silent from t = 30 s, its last report stale 5 s later: planned at the base.
    stale_ticks = [s for s, pos in steps.items() if np.allclose(pos[1], 0.0)]
    last_bravo = max(s for s, pos in steps.items() if abs(pos[1, 0] + 70.0) < 0.5)
    print(
        f"Bravo silent at t = 30 s: last planned at its position at tick {last_bravo}, "
        f"at the base from tick {min(stale_ticks)}"
    )
    assert 30 <= last_bravo <= 35 and min(stale_ticks) == last_bravo + 1
    assert all(s in stale_ticks for s in steps if s > last_bravo)
    # Stale Bravo counts as not connected; Alpha, 150 m out (base range 100 m), is reached.
    recs = op.records
    assert all(r.tasks_covered <= 1 for r in recs if r.t_step > last_bravo)
    assert any(r.tasks_covered == 1 for r in recs if r.t_step > 40)

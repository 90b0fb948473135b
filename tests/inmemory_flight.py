"""A whole flight in memory, the operator and station against the emulated swarm over a lock-step
ether on a virtual clock (no sockets): the harness of tests/integration/test_pair.py and the
terrain failsafe test."""

from __future__ import annotations

import numpy as np

from mission.flight.ether import LockstepEther, station_for_swarm
from mission.flight.fly_options import FlyOptions
from mission.flight.mission_world import MissionWorld, build_swarm, mission_scenario
from mission.flight.station_loop import make_operator

__all__ = ["InMemoryFlight"]


class InMemoryFlight:
    """Operator + station + swarm over the ether, on a virtual clock."""

    def __init__(
        self, mission, loss=0.0, params=None, seed=3, record=False, ekf_ready_s=None, **opts
    ):
        scenario = mission_scenario(mission, seed)
        self.swarm = build_swarm(mission, scenario, seed=seed, params=params)
        if ekf_ready_s is not None:
            # What Swarm(ekf_ready_after_s=...) sets: arming refused ("PreArm: EKF not ready")
            # until then, like SITL for its first ~40 s.
            for core in self.swarm.cores:
                core._ekf_ready_s = float(ekf_ready_s)
        self.world = MissionWorld(mission, scenario, self.swarm)
        self.station = station_for_swarm(self.swarm, record_frames=record)
        self.op = make_operator(
            mission,
            scenario,
            self.station,
            FlyOptions(wave_size=10, **opts),
            mission.vehicles.count,
            0.0,
            seed,
        )
        self.ether = LockstepEther(self.swarm, self.station, np.random.default_rng(seed), loss=loss)
        self.events = []
        self.ether.on_event = self._on_event
        self.started = False

    def _on_event(self, ev):
        self.events.append(ev)
        self.op.handle_event(ev)

    def _poll(self, now):
        self.op.poll(now)
        if not self.started and self.op.mission_t0_s is not None:
            self.started = True
            self.world.start(self.op.mission_t0_s)

    def run_until(self, t_s):
        self.ether.advance_to(t_s, poll=self._poll, poll_period_s=0.5)

    def run_until_phase(self, phase, limit_s=400.0):
        while self.op.phase != phase and self.ether.now_s < limit_s:
            self.run_until(self.ether.now_s + 1.0)
        assert self.op.phase == phase, (self.op.phase, self.ether.now_s)

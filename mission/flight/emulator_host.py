"""Hosting the emulator for a flight: on the station's own event loop, or in its own process,
on a paced simulated clock shared with the station.

Lock-step pacing (docs/design/mavlink.md §4.3, ArduPilot SITL's lock-step idea): the emulator owns
simulated time (a shared double it advances from wall time x speed-up, never more than
:data:`PACE_SLACK_S` beyond the station's last acknowledged clock read), so a lagging process slows
the simulation down instead of making it jump past every vehicle's link failsafe
(:func:`mission.flight.runners.fly_emulated_async` explains the choice).

* :class:`InProcessEmulator` - the emulator on the station's loop (tests: the swarm is reachable);
* :class:`EmulatorProcess` - the emulator in its own process (the default), obeying a pipe;
* :func:`paced_values`, :func:`emulator_clock` - the shared clock of both sides.
"""

from __future__ import annotations

import asyncio
import logging

from mavedge.clock import PacedClock, SharedValue
from mission.flight.fly_options import RunnerError
from mission.flight.mission_world import MissionWorld, build_swarm, mission_scenario
from mission.format.schema import Mission
from vehicle_emu.udp import EmulatorServer

__all__ = [
    "PACE_SLACK_S",
    "paced_values",
    "emulator_clock",
    "build_world",
    "InProcessEmulator",
    "EmulatorProcess",
]

#: Lock-step pacing of the emulated backend (see :func:`fly_emulated_async`): the emulator never
#: runs more than this far (simulated seconds) ahead of the station's last acknowledged time.
#: Below every vehicle-side link deadline: ArduPilot FS_GCS_TIMEOUT (5 s) minus a heartbeat
#: period, PX4 COM_OF_LOSS_T (1 s) and, tightest, PX4's offboard signal rule (setpoints at
#: > 2 Hz: a gap over 0.5 s restarts the "more than a second of streaming" wait; with 0.5 s of
#: slack at 20x, PX4 vehicles were refused OFFBOARD). 0.25 s leaves room for a 0.1 s stream.
PACE_SLACK_S = 0.25


def paced_values(in_process: bool) -> tuple[SharedValue, SharedValue]:
    """The shared simulated time and the station's acknowledgement (doubles, no lock: one
    writer each; an aligned 8-byte store is atomic)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    return ctx.RawValue("d", 0.0), ctx.RawValue("d", 0.0)


def emulator_clock(speedup: float, sim: SharedValue, ack: SharedValue) -> PacedClock:
    # The step limit guards against the emulator's own stalls; below the slack it also cut
    # legitimate iterations short. An iteration that delivers a control tick's 500 setpoints
    # takes 15-35 ms at 10x, and with a 2-tick limit (20 ms) each one lost simulated time.
    # Any step is bounded by the slack anyway (t <= ack + slack, ack <= t), so a limit of the
    # slack keeps every guarantee: no vehicle ever runs more than PACE_SLACK_S past the
    # station (docs/results/scale.md, third pass).
    max_step_s = max(2 * _emulator_tick_s(speedup), PACE_SLACK_S)
    return PacedClock(speedup, sim, ack, max_step_s=max_step_s, slack_s=PACE_SLACK_S)


def _emulator_tick_s(speedup: float) -> float:
    # Above 10x, a 10 Hz autopilot tick keeps the emulator within one core for S-sized missions;
    # telemetry (4 Hz) and the 1 s control period are unaffected; physics sub-steps anyway.
    return 0.05 if speedup < 10 else 0.1


def build_world(
    mission: Mission, seed: int, personality: str | None, clock: PacedClock, params: dict | None
) -> MissionWorld:
    scenario = mission_scenario(mission, seed)
    swarm = build_swarm(
        mission,
        scenario,
        seed=seed,
        personality=personality,
        unix_time_at_zero_s=clock.unix_time_at_zero_s,
        params=params,
        tick_s=_emulator_tick_s(clock.speedup),
    )
    return MissionWorld(mission, scenario, swarm, seed=seed)


def _deepen_receive_queues(server: EmulatorServer, nbytes: int = 4 << 20) -> None:
    """A station's bursts (hundreds of parameter reads or setpoints at once) overflow the
    default ~200 kB socket queue; give each emulator socket a deeper one (capped by rmem_max)."""
    import socket

    for transport in server.transports:
        sock = transport.get_extra_info("socket")
        if sock is not None:
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, nbytes)
            except OSError:
                pass


class InProcessEmulator:
    """The emulator on the station's own event loop (small fleets, tests: the swarm is
    reachable for failure injection through :attr:`swarm`)."""

    def __init__(self, world: MissionWorld, clock: PacedClock) -> None:
        self.world = world
        self.swarm = world.swarm
        self.server = EmulatorServer(world.swarm, clock)

    async def start(self) -> list[tuple[str, int]]:
        await self.server.start()
        _deepen_receive_queues(self.server)
        return list(self.server.addresses)

    def start_mission(self, t0_s: float) -> None:
        self.world.start(t0_s)

    def end_mission(self) -> None:
        self.world.stop_attrition()

    def poll(self, now_s: float) -> None:
        self.world.poll(now_s)

    def kill(self, index: int) -> None:
        self.swarm.kill(index, self.server.clock.now(), "injected")

    def finish(self, duration_s: float) -> dict:
        return self.world.report(duration_s)

    def close(self) -> None:
        self.server.close()


def _emulator_process_main(
    conn,
    mission: Mission,
    seed: int,
    personality,
    speedup: float,
    sim: SharedValue,
    ack: SharedValue,
    params,
) -> None:
    """Entry point of the emulator process: serve, obey (start/end/kill/finish), report."""
    import signal

    # Ctrl-C reaches the whole process group: the station decides what the flight does (its
    # end sequence needs the emulator alive); the emulator ends when told over the pipe.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.getLogger().setLevel(logging.WARNING)

    async def main() -> None:
        clock = emulator_clock(speedup, sim, ack)
        world = build_world(mission, seed, personality, clock, params)
        server = EmulatorServer(world.swarm, clock)
        await server.start()
        _deepen_receive_queues(server)
        conn.send(("ready", list(server.addresses)))
        loop = asyncio.get_running_loop()
        done = loop.create_future()
        duration = {"s": mission.run.duration_s}

        def on_message() -> None:
            try:
                while conn.poll():
                    msg = conn.recv()
                    kind = msg[0]
                    if kind == "start":
                        world.start(msg[1])
                    elif kind == "end":
                        world.stop_attrition()
                    elif kind == "kill":
                        world.swarm.kill(int(msg[1]), clock.now(), "injected")
                    elif kind == "finish":
                        duration["s"] = msg[1]
                        if not done.done():
                            done.set_result(None)
            except (EOFError, OSError):
                if not done.done():
                    done.set_result(None)

        loop.add_reader(conn.fileno(), on_message)

        async def zones() -> None:
            while not done.done():
                world.poll(clock.now())
                await asyncio.sleep(clock.wall_delay_s(mission.run.control_period_s / 4))

        task = loop.create_task(zones())
        await done
        task.cancel()
        loop.remove_reader(conn.fileno())
        server.close()
        try:
            report = world.report(duration["s"])
            report["stats"]["pacing"] = dict(clock.stats)
            conn.send(("report", report))
        except (OSError, EOFError):
            pass

    asyncio.run(main())


class EmulatorProcess:
    """The emulator in its own process (the default: the station and the emulator each get a
    core), talking to the station only over loopback UDP; control messages over a pipe."""

    def __init__(
        self,
        mission: Mission,
        seed: int,
        personality,
        speedup: float,
        sim: SharedValue,
        ack: SharedValue,
        params: dict | None,
    ) -> None:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")  # a clean interpreter: no inherited loop or sockets
        self._conn, child = ctx.Pipe()
        self.proc = ctx.Process(
            target=_emulator_process_main,
            name="phireman-emulator",
            args=(child, mission, seed, personality, speedup, sim, ack, params),
            daemon=True,
        )
        self.swarm = None

    async def start(self) -> list[tuple[str, int]]:
        self.proc.start()
        loop = asyncio.get_running_loop()
        ok = await loop.run_in_executor(None, self._conn.poll, 60.0)
        if not ok:
            raise RunnerError("the emulator process did not start within 60 s")
        kind, addresses = self._conn.recv()
        return [tuple(a) for a in addresses]

    def start_mission(self, t0_s: float) -> None:
        self._conn.send(("start", t0_s))

    def end_mission(self) -> None:
        self._conn.send(("end",))

    def poll(self, now_s: float) -> None:
        pass

    def kill(self, index: int) -> None:
        self._conn.send(("kill", index))

    def finish(self, duration_s: float) -> dict:
        self._conn.send(("finish", duration_s))
        if not self._conn.poll(60.0):
            raise RunnerError("the emulator process did not report")
        kind, report = self._conn.recv()
        return report

    def close(self) -> None:
        try:
            self._conn.send(("finish", 0.0))
        except (OSError, ValueError):
            pass
        self.proc.join(5.0)
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(5.0)

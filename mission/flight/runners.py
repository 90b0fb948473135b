"""Drivers that fly a mission with the ground station (``gcs``), against the emulator or real links.

The composition root (docs/design/architecture.md §1.1, §3.1): this module and the ones it is cut
into are the only place where the station (:mod:`gcs`) and the emulator (:mod:`vehicle_emu`)
meet, and they meet only through bytes.

* :func:`fly_emulated` - builds a :class:`vehicle_emu.swarm.Swarm` from the mission, serves it on
  loopback UDP (ephemeral ports, the emulator in its own process) and flies it with the station
  over real sockets, both on one *paced* simulated clock (``run.speedup``: every timer of both
  sides follows it, docs/design/mavlink.md §4.2; lock-step pacing so that a stalled process slows the
  simulation down instead of tripping every vehicle's link failsafe, see
  :func:`fly_emulated_async`). Ground truth (TU1/TU2, arrays) comes from the emulator.
* Real links (:func:`fly_real`) stay on the wall clock: nobody can pause real vehicles.
* :func:`fly_real` - the same station code over ``--connect`` links (no emulator).
* :class:`LockstepEther` - the in-memory MAVLink driver (station cores <-> swarm, virtual clock,
  seeded loss): the same :class:`gcs.operations.Operator` with no sockets (tests, quick runs).

The pieces, from the top down (an import-linter contract in pyproject.toml keeps this order):

* :mod:`mission.flight.station_loop` - the station's asyncio loop, its operator and status;
* :mod:`mission.flight.emulator_host` - the emulator in process or in its own process, paced;
* :mod:`mission.flight.run_dir` - the run directory (see there for what it holds);
* :mod:`mission.flight.mission_world` - the emulator built for a mission and its world rules;
* :mod:`mission.flight.ether` - the in-memory ether;
* :mod:`mission.format.scenario`, :mod:`mission.flight.fly_options` - the seed's draws; options and errors.

Every name other modules and tests imported from here before the split is still importable
from here.
"""

from __future__ import annotations

import asyncio
import dataclasses
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gcs.operations import Operator
from gcs.operations.rotation_setup import SWAP_CONFIRM
from gcs.records import write_summary
from mavedge.clock import Clock, PacedReader, RealClock
from mission.flight.emulator_host import (
    PACE_SLACK_S,
    EmulatorProcess,
    InProcessEmulator,
    build_world,
    emulator_clock,
    paced_values,
)
from mission.flight.ether import LockstepEther, station_for_swarm
from mission.flight.fly_options import FlyOptions, RunnerError
from mission.flight.mission_world import (
    FENCE_MARGIN_M,
    POSITION_LOOP_TAU_S,
    MissionScenario,
    build_swarm,
    control_config,
    mission_scenario,
)
from mission.flight.run_dir import (
    FlightTimes,
    Records,
    flown_span_s,
    new_run_dir,
    run_meta,
    stopped_summary,
    summary as run_summary,
)
from mission.format.schema import Mission
from mission.flight.station_loop import (
    INTERRUPT_SETTLE_S,
    PLAN_SILENCE_S,
    live_task_columns,
    live_task_connections,
    run_station,
)
from vehicle_emu.swarm import Swarm

__all__ = [
    "FlyOptions",
    "FlyResult",
    "MissionScenario",
    "mission_scenario",
    "control_config",
    "build_swarm",
    "fly_emulated",
    "fly_real",
    "fly",
    "LockstepEther",
    "FENCE_MARGIN_M",
    "RunnerError",
    "station_for_swarm",
    "fly_emulated_async",
    "fly_real_async",
    # re-exported from the modules this one was cut into (importers of mission.flight.runners)
    "live_task_columns",
    "live_task_connections",
    "PLAN_SILENCE_S",
    "INTERRUPT_SETTLE_S",
    "POSITION_LOOP_TAU_S",
    "PACE_SLACK_S",
]


@dataclass
class FlyResult:
    run_dir: Path
    summary: dict
    operator: Operator
    swarm: Swarm | None = None


def _resolve(mission: Mission, opts: FlyOptions, *, real: bool = False) -> tuple[int, float]:
    """Seed and speed-up. Real links run on the vehicles' clock: 1x unless ``--speedup`` says
    they run faster (SITL ``--speedup``); the mission's ``run.speedup`` is the *emulator's*
    speed and never applies to them (at 20x against 1x vehicles every vehicle was declared
    lost)."""
    seed = mission.run.seed if opts.seed is None else int(opts.seed)
    if real:
        speedup = 1.0 if opts.speedup is None else float(opts.speedup)
    else:
        speedup = mission.run.speedup if opts.speedup is None else float(opts.speedup)
    if not speedup > 0:
        raise RunnerError(f"speedup must be > 0, got {speedup}")
    if opts.duration_s is not None and not opts.duration_s > 0:
        raise RunnerError(f"duration must be > 0, got {opts.duration_s}")
    return seed, speedup


def _sigterm_as_interrupt(stopped_by: list[str]) -> Callable[[], None]:
    """SIGTERM (``kill``, a service manager) ends the flight as Ctrl-C does: asyncio.run cancels
    the main task on SIGINT, and :func:`mission.flight.station_loop.run_station` turns that
    cancellation into the ``--on-interrupt`` command, closes the records and returns, so the
    run directory gets its summary.json. Returns the undo."""
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None  # called from a coroutine

    def on_term() -> None:
        stopped_by.append("SIGTERM")
        task.cancel()

    try:
        loop.add_signal_handler(signal.SIGTERM, on_term)
    except (NotImplementedError, RuntimeError, ValueError):  # not Unix, or not the main thread
        return lambda: None

    def undo() -> None:
        loop.remove_signal_handler(signal.SIGTERM)

    return undo


def _write_stopped(
    mission: Mission, seed: int, kind: str, run_dir: Path, exc: BaseException, wall0: float
) -> None:
    """A summary.json saying why, unless the flight already wrote its own."""
    if not (run_dir / "summary.json").exists():
        write_summary(
            run_dir / "summary.json",
            stopped_summary(mission, seed, kind, run_dir, exc, time.monotonic() - wall0),
        )


async def fly_emulated_async(mission: Mission, opts: FlyOptions) -> FlyResult:
    stopped_by: list[str] = []
    undo = _sigterm_as_interrupt(stopped_by)
    try:
        return await _fly_emulated(mission, opts, stopped_by)
    finally:
        undo()


async def _fly_emulated(mission: Mission, opts: FlyOptions, stopped_by: list[str]) -> FlyResult:
    seed, speedup = _resolve(mission, opts)
    if opts.duration_s:
        mission = dataclasses.replace(
            mission,
            run=dataclasses.replace(
                mission.run, duration_s=max(opts.duration_s, mission.run.control_period_s)
            ),
        )
    if mission.vehicles.emulated is None:
        raise RunnerError(
            "the mission flies real vehicles (vehicles.real); use --connect or an emulated mission"
        )
    scenario = mission_scenario(mission, seed)
    # Lock-step pacing (ArduPilot SITL's lock-step idea: "changing SIM_SPEEDUP must not change
    # the flight"). Emulator and station run in two processes on a loaded machine; with a clock
    # derived from wall time alone, a 0.25 s hiccup of the station at 20x is 5 s of simulated
    # time: every vehicle's GCS failsafe (FS_GCS_TIMEOUT 5 s; PX4 COM_OF_LOSS_T 1 s) fires at
    # once, although the station did nothing wrong in its own time. SITL driven by MAVProxy at
    # high SIM_SPEEDUP fails the same way (docs/design/mavlink.md §4.1). So the emulator owns simulated
    # time (a shared double it advances from wall time x speed-up, by at most two ticks per
    # iteration, never more than PACE_SLACK_S beyond the station's last clock read) and the
    # station's clock acknowledges every read: a lagging process slows the simulation instead
    # of making it jump. Packets still cross real loopback UDP sockets; only time is shared.
    # Sim time also stays at 0 while the emulator process starts, so its start-up is not
    # charged to the vehicles' clocks.
    sim, ack = paced_values(opts.emulator_in_process)
    clock: PacedReader = PacedReader(speedup, sim, ack)
    emu: InProcessEmulator | EmulatorProcess
    if opts.emulator_in_process:
        emu_clock = emulator_clock(speedup, sim, ack)
        emu = InProcessEmulator(
            build_world(mission, seed, opts.personality, emu_clock, opts.emulator_params), emu_clock
        )
    else:
        emu = EmulatorProcess(
            mission, seed, opts.personality, speedup, sim, ack, opts.emulator_params
        )
    addresses = await emu.start()
    connections = [f"udpout:{h}:{p}" for h, p in addresses]
    run_dir = new_run_dir(mission, opts, seed, "emulated")
    records = Records(
        run_dir, mission, run_meta(mission, opts, seed, "emulated", speedup, connections)
    )
    wall0 = time.monotonic()
    times = FlightTimes()
    try:
        op = await run_station(
            mission,
            scenario,
            connections,
            opts,
            records,
            clock=clock.now,
            speedup=speedup,
            expected=mission.vehicles.count,
            seed=seed,
            world=emu,
            max_sleep_s=PACE_SLACK_S / 4,
            ack=clock.acknowledge,
            times=times,
        )
        # The truth over the span the station's TU covers: the mission flown, up to Ctrl-C.
        report = emu.finish(flown_span_s(op))
        summary = run_summary(
            mission,
            op,
            seed,
            "emulated",
            time.monotonic() - wall0,
            speedup,
            report,
            run_dir,
            clock.now(),
            times,
        )
        if stopped_by:
            summary["stopped_by"] = stopped_by[0]
        arrays = report.pop("arrays")
        np.savez_compressed(run_dir / "truth.npz", **arrays)
        write_summary(run_dir / "summary.json", summary)
    except BaseException as exc:
        _write_stopped(mission, seed, "emulated", run_dir, exc, wall0)
        raise
    finally:
        emu.close()
        records.close()
    return FlyResult(run_dir, summary, op, emu.swarm)


def _expected_real(mission: Mission, opts: FlyOptions) -> int | None:
    """How many vehicles to wait for before the audit: ``--vehicles N``, else None (start once
    no new vehicle was heard for a few seconds). Not the mission's ``sysids``: a restarted
    station with one vehicle gone would wait the whole discovery timeout while the others fly
    home on their own failsafe."""
    return opts.expected_vehicles


async def fly_real_async(mission: Mission, opts: FlyOptions) -> FlyResult:
    stopped_by: list[str] = []
    undo = _sigterm_as_interrupt(stopped_by)
    try:
        return await _fly_real(mission, opts, stopped_by)
    finally:
        undo()


async def _fly_real(mission: Mission, opts: FlyOptions, stopped_by: list[str]) -> FlyResult:
    seed, speedup = _resolve(mission, opts, real=True)
    if opts.duration_s:
        mission = dataclasses.replace(
            mission,
            run=dataclasses.replace(
                mission.run, duration_s=max(opts.duration_s, mission.run.control_period_s)
            ),
        )
    connections = list(opts.connections) or (
        list(mission.vehicles.real.connections) if mission.vehicles.real else []
    )
    if not connections:
        raise RunnerError("no links: give --connect URL or a mission with vehicles.real")
    connections += live_task_connections(mission, connections)
    scenario = mission_scenario(mission, seed, live_tasks=True)
    # Real links run on the wall clock; --speedup > 1 only for vehicles whose clock runs faster
    # (SITL SIM_SPEEDUP, the emulator): the station's timers must follow theirs.
    # Wall time x speed-up on CLOCK_MONOTONIC (system-wide: a RealClock given this one's wall0_s
    # in another process reads the same time).
    clock: Clock = RealClock(speedup, time.monotonic)
    run_dir = new_run_dir(mission, opts, seed, "real")
    records = Records(run_dir, mission, run_meta(mission, opts, seed, "real", speedup, connections))
    wall0 = time.monotonic()
    times = FlightTimes()
    try:
        op = await run_station(
            mission,
            scenario,
            connections,
            opts,
            records,
            clock=clock.now,
            speedup=speedup,
            expected=_expected_real(mission, opts),
            seed=seed,
            times=times,
        )
        summary = run_summary(
            mission,
            op,
            seed,
            "real",
            time.monotonic() - wall0,
            speedup,
            None,
            run_dir,
            clock.now(),
            times,
        )
        if stopped_by:
            summary["stopped_by"] = stopped_by[0]
        write_summary(run_dir / "summary.json", summary)
    except BaseException as exc:
        _write_stopped(mission, seed, "real", run_dir, exc, wall0)
        raise
    finally:
        records.close()
    return FlyResult(run_dir, summary, op, None)


def _run(flight) -> FlyResult:
    try:
        return asyncio.run(flight)
    except asyncio.CancelledError:
        # SIGTERM before the station's loop, or a second one: stopped as by Ctrl-C (asyncio.run
        # itself turns a cancellation by SIGINT into KeyboardInterrupt).
        raise KeyboardInterrupt from None


def fly_emulated(mission: Mission, opts: FlyOptions | None = None) -> FlyResult:
    """Fly ``mission`` against the emulator over loopback UDP (see the module docstring)."""
    return _run(fly_emulated_async(mission, opts or FlyOptions()))


def fly_real(mission: Mission, opts: FlyOptions) -> FlyResult:
    """Fly ``mission`` over real links (``opts.connections`` or ``vehicles.real``)."""
    return _run(fly_real_async(mission, opts))


def with_battery_options(mission: Mission, opts: FlyOptions) -> Mission:
    """``mission`` as ``--battery`` / ``--rotation`` say (``--swap-confirm`` checked: it needs
    batteries too): endless batteries drop its
    ``endurance.battery`` (the station and the emulator both fly without), a rotation override
    replaces ``endurance.rotation``."""
    if opts.battery not in ("mission", "unlimited"):
        raise RunnerError(f"battery must be 'mission' or 'unlimited', got {opts.battery!r}")
    if opts.rotation not in ("mission", "on", "off"):
        raise RunnerError(f"rotation must be 'mission', 'on' or 'off', got {opts.rotation!r}")
    if opts.swap_confirm not in SWAP_CONFIRM:
        raise RunnerError(
            f"swap_confirm must be one of {', '.join(SWAP_CONFIRM)}, got {opts.swap_confirm!r}"
        )
    end = mission.endurance
    if end.battery is None:
        if opts.battery != "mission" or opts.rotation != "mission":
            raise RunnerError(
                "--battery and --rotation apply to a mission with batteries "
                "(an endurance.battery section, e.g. wildfire_2h)"
            )
        if opts.swap_confirm != "auto":
            raise RunnerError(
                "--swap-confirm applies to a mission with batteries (battery swaps on the "
                "base's pads: an endurance.battery section, e.g. wildfire_2h)"
            )
        return mission
    if opts.battery == "unlimited":
        end = dataclasses.replace(end, battery=None)
    elif opts.rotation != "mission":
        end = dataclasses.replace(end, rotation=opts.rotation == "on")
    return dataclasses.replace(mission, endurance=end)


def fly(mission: Mission, opts: FlyOptions | None = None) -> FlyResult:
    """Real links if any are given (options or mission), else the emulator."""
    opts = opts or FlyOptions()
    mission = with_battery_options(mission, opts)
    if opts.connections or mission.vehicles.real is not None:
        return fly_real(mission, opts)
    return fly_emulated(mission, opts)

"""Drivers that fly a mission with the ground station (``gcs``), against the emulator or real links.

The composition root (docs/design/architecture.md §1.1, §3.1): this module is the only place where the station
(:mod:`gcs`) and the emulator (:mod:`vehicle_emu`) meet, and they meet only through bytes.

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

A run directory holds: ``mission.yaml`` (resolved), ``run.json`` (seed, code version, options),
``flight.tlog`` (every frame both ways), ``events.jsonl``, ``metrics.csv`` (one row per control
tick), ``summary.json`` and, when emulated, ``truth.npz``. Records are written by a background
thread every half second (:mod:`gcs.records`), off the control path; ``close()`` writes the rest.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import math
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from collections.abc import Callable

import numpy as np

from gcs.aio import StationAdapter
from gcs.control import ControlConfig, Geofence
from gcs.events import TelemetryReceived
from gcs.fleet import FleetView, MissionOrigin
from gcs.link import StationConfig, StationLink
from gcs.operations import OperationsConfig, Operator, TickRecord
from gcs.records import EventLog, MetricsWriter, TlogWriter, write_summary
from gcs.station import Station
from gcs.tasks import LiveTasks
from gcs.wire import mavlink
from mission.schema import Mission
from planner.methods import make_planner
from planner.metrics import task_uptime
from planner.problem import ProblemConfig
from vehicle_emu.clock import PacedClock, PacedReader
from vehicle_emu.radio import RadioConfig
from vehicle_emu.swarm import Swarm
from vehicle_emu.udp import EmulatorServer
from vehicle_emu.world import spawn_streams

__all__ = ["FlyOptions", "FlyResult", "MissionScenario", "mission_scenario", "control_config",
           "build_swarm", "fly_emulated", "fly_real", "fly", "LockstepEther", "FENCE_MARGIN_M",
           "RunnerError"]

log = logging.getLogger(__name__)

#: After Ctrl-C, how long (wall seconds) the station keeps its links up for the vehicles to
#: confirm what they were told.
INTERRUPT_SETTLE_S = 5.0

#: Without a mission geofence, the fence is the task field plus this margin, metres.
FENCE_MARGIN_M = 100.0


#: A vehicle silent this long (simulated seconds) is out of the planned network D'(t).
PLAN_SILENCE_S = 2.0

#: Time constant of a multicopter's position loop (ArduPilot/PX4 position controllers, and the
#: emulator's ``Physics.tau_pos_s``): the station leads its targets by this much (ControlConfig).
POSITION_LOOP_TAU_S = 1.0


def _speed_params(personalities: list[str], max_speed_m_s: float, climb_rate_m_s: float,
                  user: dict | None) -> dict:
    """Per-vehicle parameters that make the emulated autopilots fly the mission's limits from
    boot, as the station would set them on real vehicles (:func:`gcs.limits.limit_params`, so
    the station finds nothing to write). Explicit overrides (``params``) win."""
    from gcs.autopilot import ARDUPILOT, PX4
    from gcs.limits import limit_params

    user = user or {}
    out = {}
    for i, p in enumerate(personalities):
        want = limit_params(ARDUPILOT if p == "ardupilot" else PX4, max_speed_m_s, climb_rate_m_s)
        out[i] = {k: v for k, v in want.items() if k not in user}
    return out


class RunnerError(ValueError):
    """A mission or option this runner cannot fly (reported to the user as a UserError)."""


# ------------------------------------------------------------------------------------------------
# What the mission implies: spawn, task tracks, fence


@dataclass(frozen=True)
class MissionScenario:
    """The deterministic part of one run of a mission, drawn from the seed."""

    spawn_ne_m: np.ndarray
    """(N, 2) start positions, mission frame, metres."""
    task_track_m: np.ndarray
    """(tau + 1, M, 2) task positions at t = k * control_period_s, metres."""
    dt_s: float

    def task_pos_m(self, t_s: float) -> np.ndarray:
        """(M, 2) task positions at mission time ``t_s`` (linear between steps, held at the ends)."""
        k = max(0.0, t_s) / self.dt_s
        last = len(self.task_track_m) - 1
        k0 = min(int(math.floor(k)), last)
        k1 = min(k0 + 1, last)
        a = min(max(k - k0, 0.0), 1.0) if k1 > k0 else 0.0
        return self.task_track_m[k0] * (1 - a) + self.task_track_m[k1] * a


def mission_scenario(mission: Mission, seed: int | None = None, *,
                     live_tasks: bool = False) -> MissionScenario:
    """Spawn positions and task tracks of ``mission`` for ``seed`` (default ``run.seed``).

    Random draws come from the run's *scenario* stream (:func:`vehicle_emu.world.spawn_streams`),
    in the in-process simulator's order: ring noise, then each task entry in file order (random
    starts, then walk increments).
    """
    from mission.playback import spawn_positions, task_track_m  # one drawing order for every backend

    seed = mission.run.seed if seed is None else seed
    rng = spawn_streams(seed).scenario
    spawn = spawn_positions(mission, rng)
    try:
        track, _ = task_track_m(mission, rng, mission.run.n_steps,
                                live="nan" if live_tasks else "refuse")
    except ValueError as exc:  # live MAVLink tasks
        raise RunnerError(str(exc)) from None
    return MissionScenario(spawn, track, mission.run.control_period_s)


def control_config(mission: Mission, scenario: MissionScenario | None = None) -> ControlConfig:
    """Altitude layers from the mission's flight limits; the mission's geofence, or by default the
    task field plus :data:`FENCE_MARGIN_M`."""
    lim = mission.vehicles.limits
    half = mission.problem_config().field_half_width_m
    if scenario is not None:
        half = max(half, float(np.abs(scenario.task_track_m).max(initial=0.0)),
                   float(np.abs(scenario.spawn_ne_m).max(initial=0.0)))
    fence = mission.geofence
    geofence = Geofence.square(fence.half_width_m if fence.half_width_m is not None else half + FENCE_MARGIN_M,
                               fence.max_alt_m if fence.max_alt_m is not None else math.inf)
    return ControlConfig(cruise_alt_m=lim.cruise_alt_m, layer_spacing_m=lim.layer_spacing_m,
                         n_layers=lim.n_layers, geofence=geofence,
                         lead=1.0 + POSITION_LOOP_TAU_S / mission.run.control_period_s)


def _personalities(mission: Mission, override: str | None) -> list[str]:
    n = mission.vehicles.count
    p = override or (mission.vehicles.emulated.personality if mission.vehicles.emulated else
                     "ardupilot")
    if p == "mixed":
        return ["ardupilot" if i % 2 == 0 else "px4" for i in range(n)]
    if p not in ("ardupilot", "px4"):
        raise RunnerError(f"unknown personality {p!r}; valid: ardupilot, px4, mixed")
    return [p] * n


class _MissionSwarm(Swarm):
    """A swarm whose full autopilot/physics tick runs at ``tick_s`` cadence only.

    ``Swarm.next_timer_s`` also wakes for every radio-delayed packet; the base class then runs a
    whole tick (every core, physics, radio) per delivery, which at 50 vehicles, per-hop latency
    and a 20x speed-up multiplies the emulator's CPU several times and starves its sockets.
    Between ticks only the delayed packets are delivered here.
    """

    def handle_timer(self, now_s: float) -> None:
        if self.stats["ticks"] and now_s < self.now_s + self.tick_s - 1e-9:
            self._deliver_delayed(now_s, inbound=True)
            return
        super().handle_timer(now_s)

    step = handle_timer


def build_swarm(mission: Mission, scenario: MissionScenario, *, seed: int,
                personality: str | None = None, unix_time_at_zero_s: float = 1.7e9,
                mux: bool = True, params: dict | None = None, tick_s: float = 0.05) -> Swarm:
    """The emulator for ``mission``: count, personality, spawn, radio, flight limits.

    Attrition is *not* armed here: :class:`_MissionWorld` switches it on when the station starts
    the mission (take-off is not part of the paper's horizon), then applies the background rate,
    the scripted losses and the hazard zones on the mission clock.
    """
    if mission.vehicles.emulated is None:
        raise RunnerError("the mission flies real vehicles (vehicles.real); use --connect or an "
                          "emulated mission")
    emu = mission.vehicles.emulated
    radio = RadioConfig(radio_range_m=emu.radio_range_m or mission.radio.range_m,
                        base_range_m=mission.radio.base_range_m,
                        latency_per_hop_s=mission.radio.latency_s,
                        loss_per_hop=min(mission.radio.loss_prob, 0.999))
    spawn = np.column_stack([scenario.spawn_ne_m, np.zeros(len(scenario.spawn_ne_m))])
    o = mission.origin
    pers = _personalities(mission, personality)
    swarm = _MissionSwarm(emu.count, personality=pers,
                  per_vehicle_params=_speed_params(pers, emu.max_speed_m_s, emu.climb_rate_m_s,
                                                   params),
                  home_lla=(o.lat_deg, o.lon_deg, o.alt_amsl_m), spawn_ned_m=spawn, radio=radio,
                  hazard_per_s=0.0, task_pos_fn=None, mux=mux, params=params,
                  rng=np.random.default_rng(np.random.SeedSequence([int(seed), 0xE1])),
                  truth_period_s=mission.run.control_period_s,
                  unix_time_at_zero_s=unix_time_at_zero_s, max_speed_h_m_s=emu.max_speed_m_s,
                  tick_s=tick_s, radio_period_s=0.2)
    swarm.physics.climb_rate_m_s[:] = emu.climb_rate_m_s
    return swarm


class _MissionWorld:
    """The mission's world rules applied to the emulator on the mission clock (runner side):
    attrition switched on at mission start, scripted losses, hazard zones, task motion for the
    ground truth. Never visible to the station.

    Losses follow the in-process world's draws (common random numbers, docs/design/model.md §6.1): at
    mission step ``t`` vehicle ``i`` is lost iff ``u[t, i] < p_i(t)``, with the uniforms of
    :func:`mission.playback.build_scenario` (the run's attrition stream) and the per-step
    probability of :func:`mission.playback.loss_probability` (background rate plus the active
    hazard zones containing the vehicle, from its true position at the step). The loss takes
    effect half a step later (the in-process world measures connectivity, then attrits, then
    moves), through the emulator's kill hook. Scripted losses happen at their exact times.
    The truth is sampled on the mission's step grid ``t0 + k * dt``, so both backends integrate
    TU1/TU2 over the same ``duration / dt`` instants of ``[0, duration)``.
    """

    def __init__(self, mission: Mission, scenario: MissionScenario, swarm: Swarm,
                 seed: int | None = None) -> None:
        from mission.playback import build_scenario

        self.mission = mission
        self.scenario = scenario
        self.swarm = swarm
        self.t0_s: float | None = None
        seed = mission.run.seed if seed is None else seed
        scn = build_scenario(mission, seed)
        self._attrition_u = scn.attrition_u
        self._step = 0
        self._stopped = False
        self._doomed = np.zeros(swarm.n, dtype=bool)
        self.losses: list[tuple[float, int, str]] = []
        swarm.task_pos_fn = self._task_pos
        # Sample 0 was recorded without tasks; restart the truth log with tasks from here on.
        tr = swarm.truth
        tr.t_s.clear()
        tr.pos_ned_m.clear()
        tr.alive.clear()
        tr.active.clear()
        tr.task_connected.clear()

    def _task_pos(self, t_s: float) -> np.ndarray:
        return self.scenario.task_pos_m(0.0 if self.t0_s is None else t_s - self.t0_s)

    def start(self, t0_s: float) -> None:
        """The station began the mission at emulator time ``t0_s``."""
        self.t0_s = t0_s
        self.swarm.attrition.hazard_per_s = np.zeros(self.swarm.n)
        for loss in self.mission.attrition.scripted:
            if loss.vehicle < self.swarm.n:
                self.swarm.attrition.add_kill(t0_s + loss.t_s, loss.vehicle)
                self._doomed[loss.vehicle] = True
                self.losses.append((loss.t_s, loss.vehicle, "scripted"))
        self.swarm.sample_truth_from(t0_s)
        self.poll(self.swarm.now_s)
        log.info("mission world started at t=%.2f s", t0_s)

    def poll(self, now_s: float) -> None:
        """Draw the losses of every mission step that has begun (call at least every dt/2)."""
        if self.t0_s is None or self._stopped:
            return
        from mission.playback import loss_probability

        dt = self.mission.run.control_period_s
        u = self._attrition_u
        while self._step < len(u) and now_s >= self.t0_s + self._step * dt - 1e-9:
            t = self._step
            pos = self.swarm.physics.pos_ned_m[:, :2]
            p = loss_probability(self.mission, t * dt, pos)
            hit = self.swarm.physics.alive & ~self._doomed & (u[t] < p)
            for i in np.flatnonzero(hit).tolist():
                self._doomed[i] = True
                self.swarm.attrition.add_kill(self.t0_s + (t + 0.5) * dt, i)
                self.losses.append(((t + 0.5) * dt, i, "attrition"))
            self._step += 1

    def stop_attrition(self) -> None:
        """The mission is over: no more random losses (the end is not part of the horizon)."""
        self._stopped = True
        self.t_end_s = self.swarm.now_s

    def report(self, duration_s: float) -> dict:
        """Ground truth for the summary and ``truth.npz`` (plain, picklable)."""
        truth = self.truth_tu(duration_s)
        truth["alive_end"] = int(self.swarm.alive.sum())
        arrays: dict[str, Any] = self.swarm.truth.arrays()
        arrays.update(mission_t0_s=np.float64(np.nan if self.t0_s is None else self.t0_s),
                      sysid_of_index=self.swarm.sysid_of_index,
                      network_of_index=self.swarm.network_of_index)
        stats: dict[str, float] = dict(self.swarm.stats)
        stats["cpu_s"] = time.process_time()
        return {"truth": truth, "stats": stats, "arrays": arrays}

    def truth_tu(self, duration_s: float) -> dict:
        """Ground-truth TU1/TU2 over the truth samples in [t0, t0 + duration)."""
        tr = self.swarm.truth
        if self.t0_s is None or not tr.task_connected:
            return {"tu1": None, "tu2": None, "samples": 0}
        t = np.asarray(tr.t_s)
        sel = (t >= self.t0_s - 1e-9) & (t < self.t0_s + duration_s - 1e-9)
        conn = np.asarray(tr.task_connected)[sel]
        if len(conn) == 0:
            return {"tu1": None, "tu2": None, "samples": 0}
        tu1, tu2 = task_uptime(conn)
        return {"tu1": tu1, "tu2": tu2, "samples": int(len(conn))}


# ------------------------------------------------------------------------------------------------
# Options, results, run directory


@dataclass
class FlyOptions:
    """What ``phireman fly`` passes to the runners."""

    seed: int | None = None
    personality: str | None = None
    speedup: float | None = None
    """None: the mission's ``run.speedup``."""
    duration_s: float | None = None
    out_dir: str | None = None
    end: str = "rtl"
    override_audit: bool = False
    apply_failsafes: bool = False
    """Write the safe lost-link parameters the audit asks for (PARAM_SET, echo-confirmed)."""
    connections: tuple[str, ...] = ()
    wave_size: int = 25
    status: Callable[[dict], None] | None = None
    """Called about twice a second (wall) with a status dict."""
    emulator_params: dict | None = None
    """Parameter overrides for every emulated vehicle (tests)."""
    discover_timeout_s: float = 30.0
    expected_vehicles: int | None = None
    end_wait: bool = True
    """After the mission, wait until the vehicles are down (or the end timeout)."""
    set_limits: bool = True
    """Write the mission's speed / climb limits into each vehicle's own parameters at launch."""
    restore_params: bool = False
    """After landing, write back every parameter the station changed."""
    on_interrupt: str = "end"
    """What Ctrl-C tells every reachable vehicle: 'end' (the mission's end action), 'hold',
    'rtl' or 'land'."""
    emulator_in_process: bool = False
    """Run the emulator on the station's event loop (tests: failure injection through
    ``world.swarm``) instead of its own process."""
    on_operator: Callable[[Operator, object], None] | None = None
    """Hook called on every poll with (operator, world or None) - tests inject failures here."""
    serve: str | None = None
    """``[HOST:]PORT``: serve the live web view there (:mod:`mission.live`)."""
    serve_actions: bool = True
    """Operator actions on the page (behind the key printed at start); False: read-only."""
    tiles: str | None = None
    """Background imagery of the live view: an XYZ tile folder or a URL template."""
    forward: tuple[str, ...] = ()
    """MAVLink forwarding outputs (``udpout:H:P``, ``udpin:H:P``, ``tcpin:H:P``, gcs.forward)."""
    forward_readonly: bool = False
    on_live: Callable[[dict], None] | None = None
    """Called once with the live view's url and operator key, the forwarders' addresses."""


@dataclass
class FlyResult:
    run_dir: Path
    summary: dict
    operator: Operator
    swarm: Swarm | None = None


def _code_version() -> str:
    root = Path(__file__).resolve().parent.parent
    try:
        out = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty"],
                             capture_output=True, text=True, timeout=5)
        if out.returncode == 0 and out.stdout.strip():
            return out.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    try:
        from importlib.metadata import version
        return version("phireman")
    except Exception:  # noqa: BLE001
        return "unknown"


def _new_run_dir(mission: Mission, opts: FlyOptions, seed: int, kind: str) -> Path:
    base = Path(opts.out_dir) if opts.out_dir else Path(mission.output.dir)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    name = f"{stamp}-fly-{mission.name}-{kind}-s{seed}"
    path = base / name
    k = 1
    while path.exists():
        k += 1
        path = base / f"{name}-{k}"
    path.mkdir(parents=True)
    return path


class _Records:
    """The run directory's writers (buffered, written every 0.5 s by a background thread)."""

    def __init__(self, run_dir: Path, mission: Mission, meta: dict) -> None:
        from mission.load import dump_mission

        self.dir = run_dir
        (run_dir / "mission.yaml").write_text(dump_mission(mission, "resolved mission of this run"),
                                              encoding="utf-8")
        (run_dir / "run.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n",
                                          encoding="utf-8")
        self.tlog = TlogWriter(run_dir / "flight.tlog")
        self.events = EventLog(run_dir / "events.jsonl")
        self.metrics = MetricsWriter(run_dir / "metrics.csv")

    def event(self, ev) -> None:
        if not isinstance(ev, TelemetryReceived):
            self.events.write(ev)

    def close(self) -> None:
        for w in (self.tlog, self.events, self.metrics):
            w.close()


# ------------------------------------------------------------------------------------------------
# The station loop (same code for emulated and real links)


def live_task_columns(mission: Mission) -> dict[int, int]:
    """Task column -> tracker sysid of every live MAVLink task (columns as in task_track_m)."""
    out, col = {}, 0
    for task in mission.tasks:
        if task.kind == "mavlink":
            assert task.mavlink is not None  # the schema's invariant
            out[col] = task.mavlink.sysid
        col += task.count
    return out


def live_task_connections(mission: Mission, connections: list[str]) -> list[str]:
    """Links to open for live task trackers that do not share one of ``connections``."""
    extra = []
    for task in mission.tasks:
        conn = task.mavlink.connection if task.kind == "mavlink" and task.mavlink else None
        if conn and conn not in connections and conn not in extra:
            extra.append(conn)
    return extra


def _station_config(mission: Mission, max_vehicles: int | None = None) -> StationConfig:
    key = None
    real = mission.vehicles.real
    if real is not None and real.signing_key_hex:
        key = bytes.fromhex(real.signing_key_hex)
    # Who is a vehicle (real links): the mission's sysids, else the first N heard (--vehicles).
    allowed = frozenset(real.sysids) if real is not None and real.sysids else None
    # Fleet-scale telemetry (docs/design/mavlink.md §2, Skybrush): position at 2 Hz is all the plan uses;
    # every other stream costs decode time at 50+ vehicles x speed-up.
    return StationConfig(signing_key=key, command_timeout_s=1.0, param_timeout_s=2.0,
                         allowed_sysids=allowed, max_vehicles=max_vehicles,
                         param_retries=4, task_sysids=tuple(live_task_columns(mission).values()),
                         stream_rates_hz=((mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 2.0),
                                          (mavlink.MAVLINK_MSG_ID_SYS_STATUS, 0.2)))


def _operations_config(mission: Mission, opts: FlyOptions, expected: int | None) -> OperationsConfig:
    lim = mission.vehicles.limits
    return OperationsConfig(
        max_speed_m_s=lim.max_speed_m_s, climb_rate_m_s=lim.climb_rate_m_s,
        set_limits=opts.set_limits, restore_params=opts.restore_params,
        expected_vehicles=expected, discover_timeout_s=opts.discover_timeout_s,
        override_audit=opts.override_audit, apply_failsafes=opts.apply_failsafes,
        wave_size=opts.wave_size,
        control_period_s=mission.run.control_period_s,
        duration_s=opts.duration_s or mission.run.duration_s, end=opts.end,
        radio_range_m=mission.radio.range_m, poll_period_s=0.5)


def _planner_spec(mission: Mission) -> tuple[str, ProblemConfig, dict]:
    """(method, problem, params) of the station's planner for ``mission``."""
    problem = mission.problem_config()
    method = mission.planner.method
    params = dict(mission.planner.params)
    if method == "phireman":
        params["info"] = "central"  # the station plans centrally from D'(t)
    return method, problem, params


def _warm_up_planner(method: str, problem, params: dict, scenario: MissionScenario) -> None:
    """Run a throw-away planner of the same kind for two ticks on a small made-up fleet, so
    that everything its first real tick needs (imports, Numba kernels compiled or loaded from
    their cache) is ready before the flight: the station's loop must never stall in flight
    (a first tick that compiled for ~10 s stopped heartbeats and setpoints: ArduCopter's GCS
    failsafe acts after FS_GCS_TIMEOUT 5 s, PX4's offboard loss after COM_OF_LOSS_T 1 s)."""
    from planner.methods import TickInput

    t0 = time.monotonic()
    rng = np.random.default_rng(0)
    tasks = np.nan_to_num(np.asarray(scenario.task_pos_m(0.0), dtype=float).reshape(-1, 2))
    half = max(float(np.abs(tasks).max(initial=0.0)), 10.0)
    n = 8
    pos = rng.uniform(-half / 4, half / 4, size=(n, 2))
    throwaway = make_planner(method, problem, dict(params), np.random.default_rng(0))
    for t_step in range(2):
        throwaway.plan(TickInput(t_step, pos, np.ones(n, bool), np.ones(n, bool), tasks))
    log.info("planner %s warmed up in %.2f s", method, time.monotonic() - t0)


def _make_operator(mission: Mission, scenario: MissionScenario, station: Station,
                   opts: FlyOptions, expected: int | None, now_s: float, seed: int) -> Operator:
    o = mission.origin
    # D'(t) for planning: a vehicle streaming position at 2 Hz (plus 1 Hz heartbeats) that has
    # been silent for 2 s has missed four reports: plan without it (the link still declares it
    # lost only after its own vehicle_timeout_s). With the 5 s link timeout, a drone that died
    # stayed a planned relay for 5 s (about 2.5 drones at any time at 1 %/s attrition).
    fleet = FleetView(MissionOrigin(o.lat_deg, o.lon_deg, o.alt_amsl_m),
                      timeout_s=min(PLAN_SILENCE_S, station.links[0].config.vehicle_timeout_s))
    method, problem, params = _planner_spec(mission)
    planner = make_planner(method, problem, params, spawn_streams(seed).algorithm)
    live = live_task_columns(mission)
    return Operator(station, fleet, planner, scenario.task_pos_m, control_config(mission, scenario),
                    _operations_config(mission, opts, expected), now_s=now_s,
                    live_tasks=LiveTasks(fleet.origin, live) if live else None)


def _status_dict(op: Operator, now_s: float, rec: TickRecord | None, world) -> dict:
    snap = op.fleet.snapshot(now_s)
    modes: dict[str, int] = {}
    for m, lost in zip(snap.mode, snap.lost):
        key = "LOST" if lost else m
        modes[key] = modes.get(key, 0) + 1
    last = op.records[-1] if op.records else None
    d = {"phase": op.phase, "t_s": now_s, "t_mission_s": op.t_mission_s(now_s),
         "duration_s": op.config.duration_s, "fleet": snap.n_vehicles,
         "networked": int(snap.networked.sum()), "returning": int(snap.returning.sum()),
         "lost": int(snap.lost.sum()), "modes": modes,
         "tasks_covered": last.tasks_covered if last else 0,
         "n_tasks": last.n_tasks if last else 0,
         "tu1": last.tu1_so_far if last else None, "tu2": last.tu2_so_far if last else None,
         "command_failures": op.counters["command_failures"], "end_t0_s": op.end_t0_s,
         "failsafes": len(op.failsafe_texts),
         "last_failsafe": op.failsafe_texts[-1] if op.failsafe_texts else None,
         "reclaims": len(op.reclaimed),
         "wall_s": time.monotonic()}
    if world is not None and getattr(world, "swarm", None) is not None:
        d["truth_alive"] = int(world.swarm.alive.sum())
    return d


async def _run_station(mission: Mission, scenario: MissionScenario, connections: list[str],
                       opts: FlyOptions, records: _Records, *, clock: Callable[[], float],
                       speedup: float, expected: int | None, seed: int,
                       world: _InProcessEmulator | _EmulatorProcess | None = None,
                       max_sleep_s: float = math.inf,
                       ack: Callable[[float], None] | None = None) -> Operator:
    """The station's loop. ``max_sleep_s`` (simulated seconds): wake at least this often even
    when idle, so a paced emulator is never starved of clock acknowledgements."""
    # Before any link is open (a stall now costs nothing; in flight it trips failsafes).
    _warm_up_planner(*_planner_spec(mission), scenario)
    cfg = _station_config(mission, expected if world is None else None)
    if opts.forward:
        # A forwarded GCS (QGroundControl, MAVProxy) wants the telemetry the station itself
        # does not use: do not turn it off (gcs.link disable_unused_messages).
        cfg = dataclasses.replace(cfg, disable_unused_messages=False)
    holder: dict = {}

    def on_event(ev) -> None:
        records.event(ev)
        for listener in holder.get("listeners", ()):
            listener(ev)
        op = holder.get("op")
        if op is not None:
            op.handle_event(ev)
        else:
            holder.setdefault("early", []).append(ev)

    adapters = []
    try:
        for i, conn in enumerate(connections):
            # A link down at start (a vehicle not booted yet, a radio not plugged in) is
            # retried in the background and reported (LinkDown / LinkUp in events.jsonl),
            # never fatal while others work; only a mistake waiting cannot fix raises.
            adapters.append(await StationAdapter(conn, cfg, link_id=i, clock=clock,
                                                 tlog=records.tlog, on_event=on_event,
                                                 time_scale=speedup,
                                                 on_link_event=records.events.write).start())
    except (OSError, ValueError) as exc:
        for a in adapters:
            a.close()
        raise RunnerError(f"cannot open link {conn!r}: {exc}") from exc
    station = Station([a.core for a in adapters])  # type: ignore[misc]  # started: each has a core
    op = _make_operator(mission, scenario, station, opts, expected, clock(), seed)
    holder["op"] = op
    op.on_action = records.events.write  # operator actions in events.jsonl, with their source
    for ev in holder.pop("early", []):
        op.handle_event(ev)
    extras = []
    if opts.serve or opts.forward:  # the live view and MAVLink forwarding, on this loop
        from mission.live import attach

        try:
            extras = await attach(op, adapters, mission=mission, opts=opts, clock=clock,
                                  records=records, listeners=holder.setdefault("listeners", []))
        except (OSError, ValueError) as exc:
            for a in adapters:
                a.close()
            raise RunnerError(f"cannot serve / forward: {exc}") from exc
    last_status = -math.inf
    started = ended = False
    interrupted_wall: float | None = None
    try:
        while True:
            if interrupted_wall is not None:
                # Ctrl-C: keep the links up until every vehicle heard confirmed what it was
                # told (or INTERRUPT_SETTLE_S of wall time), so acks and the .tlog are complete.
                settled = all(ok for _, _, ok in op.interrupt_report(clock()))
                if settled or time.monotonic() - interrupted_wall >= INTERRUPT_SETTLE_S:
                    break
            elif op.finished:
                break
            try:
                now = clock()
                rec = op.poll(now)
                if ack is not None:
                    ack(now)  # lock-step: everything due up to `now` is done (see PacedReader)
                if world is not None:
                    if not started and op.mission_t0_s is not None:
                        started = True
                        world.start_mission(op.mission_t0_s)
                    if started and not ended and op.phase not in ("launch", "run"):
                        ended = True
                        world.end_mission()
                    world.poll(now)
                if opts.on_operator is not None:
                    opts.on_operator(op, world)
                if rec is not None:
                    records.metrics.write(rec.row())
                if op.phase == "done" and not opts.end_wait:
                    break
                if op.phase == "end" and not opts.end_wait:
                    op.phase = "done"
                for a in adapters:
                    a.transmit()
                wall = time.monotonic()
                if opts.status is not None and (wall - last_status >= 0.5 or op.finished):
                    last_status = wall
                    d = _status_dict(op, now, rec, world)
                    d["speedup"] = speedup
                    d["links_down"] = [(a.link_id, a.spec.text, a.down_reason)
                                       for a in adapters if not a.connected]
                    opts.status(d)
                delay = max(0.0, min(op.next_poll_s(now) - clock(), max_sleep_s) / speedup)
                await asyncio.sleep(delay)
            except asyncio.CancelledError:
                # Ctrl-C (asyncio.run cancels the main task on the first SIGINT; a second one
                # raises KeyboardInterrupt and abandons the flight).
                task = asyncio.current_task()
                if interrupted_wall is not None or task is None:
                    raise
                task.uncancel()
                interrupted_wall = time.monotonic()
                log.info("interrupted: telling every vehicle to %s", opts.on_interrupt)
                op.interrupt(opts.on_interrupt, clock())
                for a in adapters:
                    a.transmit()
    finally:
        for x in extras:
            await x.aclose()
        for a in adapters:
            a.close()
    return op


def _summary(mission: Mission, op: Operator, seed: int, kind: str, wall_s: float,
             speedup: float, report: dict | None, run_dir: Path, now_s: float) -> dict:
    tu1, tu2 = op.station_tu()
    recs = op.records
    sim_s = (recs[-1].t_mission_s + mission.run.control_period_s) if recs else 0.0
    s = {
        "mission": mission.name, "backend": kind, "seed": seed, "phase": op.phase,
        "station": {"tu1": tu1, "tu2": tu2, "ticks": len(recs)},
        "duration_s": op.config.duration_s, "mission_s_flown": sim_s,
        "wall_s": wall_s, "speedup_requested": speedup, "station_cpu_s": time.process_time(),
        "speedup_achieved": (now_s - op.t_start_s) / wall_s if wall_s > 0 else None,
        "mission_t0_s": op.mission_t0_s,
        "vehicles_discovered": len(op.fleet),
        "refusal": op.refusal,
        "live_tasks": None if op.live_tasks is None else {
            "sysids": list(op.live_tasks.sysids), "never_heard": list(op.live_tasks.waiting_for())},
        "reclaimed": len(op.reclaimed), "counters": op.counters,
        "interrupted": op.interrupted, "end_status": op.end_status,
        "interrupt_report": None if op.interrupted is None else [
            {"link_id": v[0], "sysid": v[1], "state": text, "confirmed": ok}
            for v, text, ok in op.interrupt_report(now_s)],
        "param_changes": op.param_changes, "limit_warnings": op.limit_warnings,
        "operator_actions": [dataclasses.asdict(a) for a in op.actions],
        "links": [{"link_id": l.link_id, "frames_out": l.stats.frames_out,
                   "frames_in": l.stats.decode.frames, "bad_data": l.stats.decode.bad_data,
                   "raw_frames": l.stats.decode.raw_frames,
                   "signature_rejected": l.stats.decode.signature_rejected,
                   "stream_fallbacks": l.stats.data_stream_fallbacks,
                   "refused_sysids": l.stats.refused_sysids,
                   "refused_by_sysid": dict(l.stats.refused_by_sysid),
                   "inconsistent_frames": l.stats.inconsistent_frames,
                   "messages_disabled": l.stats.messages_disabled}
                  for l in op.station.links],
        "audit": None if op.audit_report is None else {
            "cleared_to_fly": op.audit_report.cleared_to_fly,
            "overridden": op.audit_report.overridden,
            "unsafe": [[a.link_id, a.sysid] for a in op.audit_report.unsafe]},
        "run_dir": str(run_dir),
    }
    if recs:
        s["final"] = recs[-1].row()
    if report is not None:
        s["truth"] = report["truth"]
        s["emulator"] = report["stats"]
    return s


def _meta(mission: Mission, opts: FlyOptions, seed: int, kind: str, speedup: float,
          connections) -> dict:
    return {"seed": seed, "code_version": _code_version(), "backend": kind, "speedup": speedup,
            "connections": list(connections), "python": sys.version.split()[0],
            "options": {f.name: getattr(opts, f.name) for f in dataclasses.fields(opts)
                        if f.name not in ("status", "on_operator", "on_live")},
            "started_unix_s": time.time()}


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


class SimClock:
    """Simulated time = (monotonic wall time - ``wall0``) x speed-up, shared across processes
    (CLOCK_MONOTONIC is system-wide), so the emulator and the station follow one clock."""

    def __init__(self, speedup: float, wall0: float | None = None) -> None:
        self.speedup = float(speedup)
        self.wall0 = time.monotonic() if wall0 is None else float(wall0)
        self.unix_time_at_zero_s = time.time() - (time.monotonic() - self.wall0)

    def now(self) -> float:
        return (time.monotonic() - self.wall0) * self.speedup

    def wall_delay_s(self, dt_s: float) -> float:
        return max(0.0, dt_s / self.speedup)


#: Lock-step pacing of the emulated backend (see :func:`fly_emulated_async`): the emulator never
#: runs more than this far (simulated seconds) ahead of the station's last acknowledged time.
#: Below every vehicle-side link deadline: ArduPilot FS_GCS_TIMEOUT (5 s) minus a heartbeat
#: period, PX4 COM_OF_LOSS_T (1 s) and, tightest, PX4's offboard signal rule (setpoints at
#: > 2 Hz: a gap over 0.5 s restarts the "more than a second of streaming" wait; with 0.5 s of
#: slack at 20x, PX4 vehicles were refused OFFBOARD). 0.25 s leaves room for a 0.1 s stream.
PACE_SLACK_S = 0.25


def _paced_values(in_process: bool):
    """The shared simulated time and the station's acknowledgement (doubles, no lock: one
    writer each; an aligned 8-byte store is atomic)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    return ctx.RawValue("d", 0.0), ctx.RawValue("d", 0.0)


def _emulator_clock(speedup: float, sim, ack) -> PacedClock:
    return PacedClock(speedup, sim, ack, max_step_s=2 * _emulator_tick_s(speedup),
                      slack_s=PACE_SLACK_S)


def _emulator_tick_s(speedup: float) -> float:
    # Above 10x, a 10 Hz autopilot tick keeps the emulator within one core for S-sized missions;
    # telemetry (4 Hz) and the 1 s control period are unaffected; physics sub-steps anyway.
    return 0.05 if speedup < 10 else 0.1


def _build_world(mission: Mission, seed: int, personality: str | None, clock,
                 params: dict | None) -> _MissionWorld:
    scenario = mission_scenario(mission, seed)
    swarm = build_swarm(mission, scenario, seed=seed, personality=personality,
                        unix_time_at_zero_s=clock.unix_time_at_zero_s, params=params,
                        tick_s=_emulator_tick_s(clock.speedup))
    return _MissionWorld(mission, scenario, swarm, seed=seed)


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


class _InProcessEmulator:
    """The emulator on the station's own event loop (small fleets, tests: the swarm is
    reachable for failure injection through :attr:`swarm`)."""

    def __init__(self, world: _MissionWorld, clock: PacedClock) -> None:
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


def _emulator_process_main(conn, mission: Mission, seed: int, personality, speedup: float,
                           sim, ack, params) -> None:
    """Entry point of the emulator process: serve, obey (start/end/kill/finish), report."""
    import signal

    # Ctrl-C reaches the whole process group: the station decides what the flight does (its
    # end sequence needs the emulator alive); the emulator ends when told over the pipe.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.getLogger().setLevel(logging.WARNING)

    async def main() -> None:
        clock = _emulator_clock(speedup, sim, ack)
        world = _build_world(mission, seed, personality, clock, params)
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


class _EmulatorProcess:
    """The emulator in its own process (the default: the station and the emulator each get a
    core), talking to the station only over loopback UDP; control messages over a pipe."""

    def __init__(self, mission: Mission, seed: int, personality, speedup: float, sim, ack,
                 params: dict | None) -> None:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")  # a clean interpreter: no inherited loop or sockets
        self._conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_emulator_process_main, name="phireman-emulator",
                                args=(child, mission, seed, personality, speedup, sim, ack,
                                      params), daemon=True)
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


async def fly_emulated_async(mission: Mission, opts: FlyOptions) -> FlyResult:
    seed, speedup = _resolve(mission, opts)
    if opts.duration_s:
        mission = dataclasses.replace(mission, run=dataclasses.replace(
            mission.run, duration_s=max(opts.duration_s, mission.run.control_period_s)))
    if mission.vehicles.emulated is None:
        raise RunnerError("the mission flies real vehicles (vehicles.real); use --connect or an "
                          "emulated mission")
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
    sim, ack = _paced_values(opts.emulator_in_process)
    clock = PacedReader(speedup, sim, ack)
    emu: _InProcessEmulator | _EmulatorProcess
    if opts.emulator_in_process:
        emu_clock = _emulator_clock(speedup, sim, ack)
        emu = _InProcessEmulator(_build_world(mission, seed, opts.personality, emu_clock,
                                              opts.emulator_params), emu_clock)
    else:
        emu = _EmulatorProcess(mission, seed, opts.personality, speedup, sim, ack,
                               opts.emulator_params)
    addresses = await emu.start()
    connections = [f"udpout:{h}:{p}" for h, p in addresses]
    run_dir = _new_run_dir(mission, opts, seed, "emulated")
    records = _Records(run_dir, mission, _meta(mission, opts, seed, "emulated", speedup,
                                               connections))
    wall0 = time.monotonic()
    try:
        op = await _run_station(mission, scenario, connections, opts, records, clock=clock.now,
                                speedup=speedup, expected=mission.vehicles.count, seed=seed,
                                world=emu, max_sleep_s=PACE_SLACK_S / 4,
                                ack=clock.acknowledge)
        report = emu.finish(op.config.duration_s)
        summary = _summary(mission, op, seed, "emulated", time.monotonic() - wall0, speedup,
                           report, run_dir, clock.now())
        arrays = report.pop("arrays")
        np.savez_compressed(run_dir / "truth.npz", **arrays)
        write_summary(run_dir / "summary.json", summary)
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
    seed, speedup = _resolve(mission, opts, real=True)
    if opts.duration_s:
        mission = dataclasses.replace(mission, run=dataclasses.replace(
            mission.run, duration_s=max(opts.duration_s, mission.run.control_period_s)))
    connections = list(opts.connections) or (
        list(mission.vehicles.real.connections) if mission.vehicles.real else [])
    if not connections:
        raise RunnerError("no links: give --connect URL or a mission with vehicles.real")
    connections += live_task_connections(mission, connections)
    scenario = mission_scenario(mission, seed, live_tasks=True)
    # Real links run on the wall clock; --speedup > 1 only for vehicles whose clock runs faster
    # (SITL SIM_SPEEDUP, the emulator): the station's timers must follow theirs.
    clock = SimClock(speedup)
    run_dir = _new_run_dir(mission, opts, seed, "real")
    records = _Records(run_dir, mission, _meta(mission, opts, seed, "real", speedup, connections))
    wall0 = time.monotonic()
    try:
        op = await _run_station(mission, scenario, connections, opts, records, clock=clock.now,
                                speedup=speedup, expected=_expected_real(mission, opts),
                                seed=seed)
        summary = _summary(mission, op, seed, "real", time.monotonic() - wall0, speedup, None,
                           run_dir, clock.now())
        write_summary(run_dir / "summary.json", summary)
    finally:
        records.close()
    return FlyResult(run_dir, summary, op, None)


def fly_emulated(mission: Mission, opts: FlyOptions | None = None) -> FlyResult:
    """Fly ``mission`` against the emulator over loopback UDP (see the module docstring)."""
    return asyncio.run(fly_emulated_async(mission, opts or FlyOptions()))


def fly_real(mission: Mission, opts: FlyOptions) -> FlyResult:
    """Fly ``mission`` over real links (``opts.connections`` or ``vehicles.real``)."""
    return asyncio.run(fly_real_async(mission, opts))


def fly(mission: Mission, opts: FlyOptions | None = None) -> FlyResult:
    """Real links if any are given (options or mission), else the emulator."""
    opts = opts or FlyOptions()
    if opts.connections or mission.vehicles.real is not None:
        return fly_real(mission, opts)
    return fly_emulated(mission, opts)


# ------------------------------------------------------------------------------------------------
# In-memory lockstep driver (tests): station cores <-> swarm through a seeded lossy ether


class LockstepEther:
    """The station's links and a swarm exchanging datagrams in memory on a virtual clock.

    Station link ``k`` talks to the swarm's endpoint ``k`` (the swarm must be ``mux=True``).
    ``loss`` drops each datagram (either direction) with that probability, from ``rng``;
    ``cut(link)`` / ``restore(link)`` sever a whole link (a dead station, a cable pulled).
    """

    def __init__(self, swarm: Swarm, station: Station, rng: np.random.Generator,
                 loss: float = 0.0, now_s: float = 0.0) -> None:
        if not swarm.mux:
            raise ValueError("LockstepEther needs Swarm(mux=True): one endpoint per network")
        self.swarm = swarm
        self.station = station
        self.rng = rng
        self.loss = float(loss)
        self.now_s = float(now_s)
        self.cut_links: set[int] = set()
        self.on_event: Callable | None = None
        self.frames_to_vehicles = 0
        self.frames_to_station = 0

    def _drop(self) -> bool:
        return self.loss > 0 and self.rng.random() < self.loss

    def pump(self) -> None:
        """Move everything queued on both sides (repeat until quiet)."""
        for _ in range(4):
            moved = 0
            for lid, data, _addr in self.station.datagrams_to_send(self.now_s):
                if lid in self.cut_links or self._drop():
                    continue
                self.swarm.receive_datagram(lid, data, ("gcs", lid), self.now_s)
                self.frames_to_vehicles += 1
                moved += 1
            for endpoint, data, addr in self.swarm.datagrams_to_send(self.now_s):
                if addr != ("gcs", endpoint) or endpoint in self.cut_links or self._drop():
                    continue
                self.station.link(endpoint).receive_datagram(data, ("emu", endpoint), self.now_s)
                self.frames_to_station += 1
                moved += 1
            for ev in self.station.events():
                if self.on_event is not None:
                    self.on_event(ev)
            if not moved:
                break

    def advance_to(self, t_s: float, *, poll: Callable[[float], None] | None = None,
                   poll_period_s: float | None = None) -> None:
        """Run both sides up to ``t_s``: swarm ticks, station timers, optional poll callback."""
        next_poll = self.now_s if poll is not None else math.inf
        while True:
            t_swarm = self.swarm.next_timer_s()
            t_station = self.station.next_timer_s()
            t_next = min(t_swarm, t_station if t_station is not None else math.inf, next_poll)
            if t_next > t_s:
                break
            self.now_s = max(self.now_s, t_next)
            if self.now_s >= t_swarm - 1e-12:
                self.swarm.handle_timer(self.now_s)
            if t_station is not None and self.now_s >= t_station:
                self.station.handle_timer(self.now_s)
            if poll is not None and self.now_s >= next_poll:
                poll(self.now_s)
                next_poll = self.now_s + (poll_period_s or 0.25)
            self.pump()
        self.now_s = t_s


def station_for_swarm(swarm: Swarm, now_s: float = 0.0, **config) -> Station:
    """A station with one in-memory link per MAVLink network of ``swarm`` (for the ether)."""
    cfg = StationConfig(static_peers=(), **config)
    links = [StationLink(dataclasses.replace(cfg, static_peers=(("emu", k),)), link_id=k,
                         now_s=now_s) for k in range(swarm.n_networks)]
    return Station(links)


__all__ += ["station_for_swarm", "fly_emulated_async", "fly_real_async"]

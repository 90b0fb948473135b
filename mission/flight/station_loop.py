"""The ground station's loop of a flight: the same code for emulated and real links.

* :func:`run_station` - opens the links, builds the :class:`gcs.operations.Operator`, polls it
  on the flight's clock until the mission is done (or Ctrl-C has settled), records every event
  and tick into the run directory (:class:`mission.flight.run_dir.Records`) and drives the emulator's
  world rules when there is an emulator;
* :func:`make_operator` - the operator for a mission (planner, fleet view, control and operations
  configuration): also what the in-memory tests drive through :class:`mission.flight.ether.LockstepEther`;
* the planner is warmed up before any link opens, so the loop never stalls in flight.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from gcs.aio import StationAdapter
from gcs.control import ControlConfig
from gcs.fleet import FleetView, MissionOrigin
from gcs.landing import FIRMWARE_DEFAULTS, landing_descent
from gcs.link import StationConfig
from gcs.operations import OperationsConfig, Operator, TickRecord
from gcs.operations.rotation import RotationSetup
from planner.endurance import EnduranceParams
from gcs.rally import RallyConfig, RallyKeeper
from gcs.station import Station
from gcs.tak import CrewMatch, TakCrews
from gcs.tasks import LiveTasks
from gcs.terrain import TerrainServer, mission_heights
from gcs.wire import mavlink
from mission.flight.fly_options import FlyOptions, RunnerError
from mission.flight.mission_world import MissionScenario, control_config
from mission.flight.run_dir import FlightTimes, Records
from mission.format.schema import Mission
from mission.format.terrain import terrain_aware_planner, terrain_radio
from planner.methods import Planner, make_planner
from planner.problem import ProblemConfig
from planner.terrain import TerrainRadio
from vehicle_emu.world import spawn_streams

if TYPE_CHECKING:
    from mission.flight.emulator_host import EmulatorProcess, InProcessEmulator

__all__ = [
    "run_station",
    "make_operator",
    "live_task_columns",
    "live_task_connections",
    "tak_task_columns",
    "tak_urls",
    "INTERRUPT_SETTLE_S",
    "PLAN_SILENCE_S",
]

log = logging.getLogger(__name__)

#: After Ctrl-C, how long (wall seconds) the station keeps its links up for the vehicles to
#: confirm what they were told.
INTERRUPT_SETTLE_S = 5.0

#: A vehicle silent this long (simulated seconds) is out of the planned network D'(t).
PLAN_SILENCE_S = 2.0


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


def tak_task_columns(mission: Mission) -> dict[int, CrewMatch]:
    """Task column -> its TAK contact matcher, for every ``tak`` crew (a pattern's slots: one
    column each, named ``NAME 0``, ``NAME 1``, ...)."""
    out, col = {}, 0
    for i, task in enumerate(mission.tasks):
        src = task.tak
        if src is not None:
            label = task.name or f"task {i}"
            for k in range(task.count):
                out[col + k] = CrewMatch(
                    name=label if task.count == 1 else f"{label} {k}",
                    uid=src.uid,
                    callsign=src.callsign,
                    callsign_pattern=src.callsign_pattern,
                    callsign_regex=src.callsign_regex,
                )
        col += task.count
    return out


def tak_urls(mission: Mission, given: tuple[str, ...] | list[str]) -> list[str]:
    """The TAK connections of a flight: ``given`` (``--tak``), then every crew's own ``url``;
    crews without one listen on ``given``, or on ATAK's mesh SA multicast if none is given."""
    from mission.flight.tak_link import MESH_SA_URL

    urls = list(dict.fromkeys(given))
    for task in mission.tasks:
        if task.tak is None:
            continue
        url = task.tak.url or (None if given else MESH_SA_URL)
        if url is not None and url not in urls:
            urls.append(url)
    return urls


def _station_config(
    mission: Mission, max_vehicles: int | None = None, *, health: bool = False
) -> StationConfig:
    """The station links' configuration; ``health``: the live page is served, so ask for and
    fold what a pilot watches (GPS, sensors, estimator, radio: gcs.link_health)."""
    key = None
    real = mission.vehicles.real
    if real is not None and real.signing_key_hex:
        key = bytes.fromhex(real.signing_key_hex)
    # Who is a vehicle (real links): the mission's sysids, else the first N heard (--vehicles).
    allowed = frozenset(real.sysids) if real is not None and real.sysids else None
    # Fleet-scale telemetry (docs/design/mavlink.md §2, Skybrush): position at 2 Hz is all the plan uses;
    # every other stream costs decode time at 50+ vehicles x speed-up.
    batteries = mission.endurance.battery is not None
    # The page's GPS and estimator rows (docs/live_view.md): GPS_RAW_INT at 1 Hz (ArduCopter
    # and PX4 both stream it); EKF_STATUS_REPORT is ArduPilot's (GCS_Common.cpp, MSG_EKF_STATUS_
    # REPORT), ESTIMATOR_STATUS PX4's (mavlink_main.cpp configure_streams_to_default, 0.5 Hz in
    # MAVLINK_MODE_NORMAL): each refuses the other's, which the link logs once and moves on.
    health_rates = (
        (
            (mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, 1.0),
            (mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT, 1.0),
            (mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS, 0.5),
        )
        if health
        else ()
    )
    return StationConfig(
        battery_telemetry=batteries,
        health_telemetry=health,
        signing_key=key,
        command_timeout_s=1.0,
        param_timeout_s=2.0,
        allowed_sysids=allowed,
        max_vehicles=max_vehicles,
        param_retries=4,
        task_sysids=tuple(live_task_columns(mission).values()),
        stream_rates_hz=(
            (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 2.0),
            # The rotation's drain estimate wants the battery's level changes to the second.
            (mavlink.MAVLINK_MSG_ID_SYS_STATUS, 1.0 if batteries or health else 0.2),
            *health_rates,
        )
        # Over terrain, ArduPilot's terrain requests and reports. GCS_Common.cpp
        # map_message_id_to_ap_message maps TERRAIN_REQUEST to MSG_TERRAIN ("request also does
        # report") in older firmware; newer firmware has MSG_TERRAIN_REQUEST and
        # MSG_TERRAIN_REPORT apart (ArduCopter SITL 4.7-dev sent requests and no report with the
        # first alone). Both asked; a refusal (PX4, or the id an old firmware lacks) is logged.
        + (
            (
                (mavlink.MAVLINK_MSG_ID_TERRAIN_REQUEST, 1.0),
                (mavlink.MAVLINK_MSG_ID_TERRAIN_REPORT, 1.0),
            )
            if mission.terrain is not None
            else ()
        ),
    )


def _operations_config(
    mission: Mission, opts: FlyOptions, expected: int | None, control: ControlConfig | None = None
) -> OperationsConfig:
    """The operator's settings for ``mission`` flown with ``opts``; ``control`` (the station's
    :func:`mission.format.scenario.control_config`): over terrain, the least return altitude the
    audit requires."""
    lim = mission.vehicles.limits
    spec = mission.endurance.battery
    # Battery failsafes: required with batteries; on real firmware without them, at least warned
    # about (a real drone has a battery whatever the mission says); the emulator without
    # batteries has no battery parameters to read.
    real = bool(opts.connections) or mission.vehicles.real is not None
    battery_audit = "require" if spec is not None else "warn" if real else "off"
    return OperationsConfig(
        battery_audit=battery_audit,
        battery_low_frac=spec.low_frac if spec is not None else None,
        rtl_min_alt_m=(
            None
            if control is None or control.terrain is None
            else control.terrain.rtl_min_alt_m(control.geofence)
        ),
        max_speed_m_s=lim.max_speed_m_s,
        climb_rate_m_s=lim.climb_rate_m_s,
        descent_rate_m_s=lim.descent_rate_m_s,
        set_limits=opts.set_limits,
        restore_params=opts.restore_params,
        expected_vehicles=expected,
        discover_timeout_s=opts.discover_timeout_s,
        override_audit=opts.override_audit,
        apply_failsafes=opts.apply_failsafes,
        wave_size=opts.wave_size,
        control_period_s=mission.run.control_period_s,
        duration_s=opts.duration_s or mission.run.duration_s,
        end=opts.end,
        radio_range_m=mission.radio.range_m,
        poll_period_s=0.5,
    )


def _planner_spec(mission: Mission) -> tuple[str, ProblemConfig, dict]:
    """(method, problem, params) of the station's planner for ``mission``: central information
    (planner.info) unless the mission's ``planner.info`` says otherwise (PlannerSpec.run_params)."""
    return mission.planner.method, mission.problem_config(), mission.planner.run_params()


def station_planner(
    mission: Mission,
    method: str,
    problem: ProblemConfig,
    params: dict,
    rng: np.random.Generator,
    radio: TerrainRadio | None,
) -> Planner:
    """The station's planner: ``method`` on ``problem``; over a ``radio.model: terrain`` mission's
    ``radio``, planning in 3-D as the in-process world's ``--terrain-aware on`` does
    (:func:`mission.format.terrain.terrain_aware_planner`, docs/terrain.md §6.2)."""
    planner = make_planner(method, problem, params, rng)
    if radio is None:
        return planner
    return terrain_aware_planner(planner, mission, radio, problem.max_speed_m_s * problem.dt_s)


def _warm_up_planner(
    mission: Mission,
    method: str,
    problem: ProblemConfig,
    params: dict,
    scenario: MissionScenario,
    radio: TerrainRadio | None,
) -> None:
    """Run a throw-away planner of the same kind for two ticks on a small made-up fleet, so
    that everything its first real tick needs (imports, Numba kernels compiled or loaded from
    their cache, the terrain radio's line-of-sight kernel) is ready before the flight: the
    station's loop must never stall in flight (a first tick that compiled for ~10 s stopped
    heartbeats and setpoints: ArduCopter's GCS failsafe acts after FS_GCS_TIMEOUT 5 s, PX4's
    offboard loss after COM_OF_LOSS_T 1 s)."""
    from planner.methods import TickInput

    t0 = time.monotonic()
    rng = np.random.default_rng(0)
    tasks = np.nan_to_num(np.asarray(scenario.task_pos_m(0.0), dtype=float).reshape(-1, 2))
    half = max(float(np.abs(tasks).max(initial=0.0)), 10.0)
    n = 8
    pos = rng.uniform(-half / 4, half / 4, size=(n, 2))
    # A fleet of n (phireman-resilient's rally bookkeeping is sized by the problem's drones).
    throwaway = station_planner(
        mission,
        method,
        dataclasses.replace(problem, n_drones=n),
        dict(params),
        np.random.default_rng(0),
        radio,
    )
    alt = None if radio is None else radio.terrain.height_m(pos) + 50.0
    for t_step in range(2):
        throwaway.plan(
            TickInput(t_step, pos, np.ones(n, bool), np.ones(n, bool), tasks, alt_amsl_m=alt)
        )
    log.info("planner %s warmed up in %.2f s", method, time.monotonic() - t0)


def make_operator(
    mission: Mission,
    scenario: MissionScenario,
    station: Station,
    opts: FlyOptions,
    expected: int | None,
    now_s: float,
    seed: int,
) -> Operator:
    """The operator that flies ``mission`` with ``station``: its fleet view (D'(t)), the
    mission's planner on the run's algorithm stream, the control and operations configuration
    and, for live MAVLink tasks, their trackers. ``expected``: vehicles to wait for (None: until
    no new vehicle is heard for a while)."""
    o = mission.origin
    # D'(t) for planning: a vehicle streaming position at 2 Hz (plus 1 Hz heartbeats) that has
    # been silent for 2 s has missed four reports: plan without it (the link still declares it
    # lost only after its own vehicle_timeout_s). With the 5 s link timeout, a drone that died
    # stayed a planned relay for 5 s (about 2.5 drones at any time at 1 %/s attrition).
    fleet = FleetView(
        MissionOrigin(o.lat_deg, o.lon_deg, o.alt_amsl_m),
        timeout_s=min(PLAN_SILENCE_S, station.links[0].config.vehicle_timeout_s),
    )
    method, problem, params = _planner_spec(mission)
    control = control_config(mission, scenario, over_terrain=True)
    radio = None if control.terrain is None else control.terrain.radio
    planner = station_planner(
        mission, method, problem, params, spawn_streams(seed).algorithm, radio
    )
    live = live_task_columns(mission)
    tak = tak_task_columns(mission)
    return Operator(
        station,
        fleet,
        planner,
        scenario.task_pos_m,
        control,
        _operations_config(mission, opts, expected, control),
        now_s=now_s,
        live_tasks=LiveTasks(fleet.origin, live) if live else None,
        rally=_rally_keeper(mission, params),
        rotation=rotation_setup(mission, scenario, opts.swap_confirm, expected),
        tak=TakCrews(fleet.origin, tak) if tak else None,
    )


def rotation_fleet_size(
    mission: Mission, scenario: MissionScenario, expected: int | None = None
) -> int:
    """How many vehicles the rotation shares the posts among: the real vehicles' ``sysids`` when
    the mission lists them, else the vehicles to wait for (``--vehicles N``, or the emulator's
    count), else the mission's count. A real mission's count is its links, and one link may
    carry several vehicles (every PX4 SITL instance on UDP 14550): sized by links, a rotation
    of three PX4 vehicles was one of one drone, everything flew and nothing rotated."""
    real = mission.vehicles.real
    if real is not None and real.sysids:
        return len(real.sysids)
    if expected:
        return expected
    return len(scenario.spawn_ne_m)


def landing_descent_s(alt_m: float) -> float:
    """Seconds from ``alt_m`` above the pad to the ground at the firmware's default landing
    speeds, the slower of the two (ArduCopter's: WPNAV_SPEED_DN 1.5 m/s down to LAND_ALT_LOW 10 m,
    then LAND_SPEED 0.5 m/s; PX4's ends at 0.7 m/s): the plan before the audit has read the
    vehicles' own (:mod:`gcs.landing`, ``RotationSetup.use_landing``)."""
    return max(landing_descent(ap).time_s(alt_m) for ap in FIRMWARE_DEFAULTS)


def rotation_setup(
    mission: Mission,
    scenario: MissionScenario,
    swap_confirm: str = "auto",
    expected: int | None = None,
) -> RotationSetup | None:
    """The station's relay rotation for a mission with batteries (None without): the policy the
    in-process run builds too (:meth:`mission.format.schema.EnduranceSpec.policy`) for
    :func:`rotation_fleet_size` vehicles, and what the mission says of the batteries (nominal
    hover drain, the drain at full speed). ``swap_confirm``: who ends a swap
    (``FlyOptions.swap_confirm``); ``expected``: the vehicles to wait for (``--vehicles N``)."""
    end = mission.endurance
    spec = end.battery
    if spec is None:
        return None
    n = rotation_fleet_size(mission, scenario, expected)
    tasks = np.asarray(scenario.task_pos_m(0.0), dtype=float).reshape(-1, 2)
    dist = np.hypot(*tasks[np.isfinite(tasks).all(axis=1)].T)
    mean_post_m = 0.5 * float(dist.mean()) if dist.size else 0.0
    lim = mission.vehicles.limits
    top_m = lim.cruise_alt_m + (lim.n_layers - 1) * lim.layer_spacing_m
    # What the paper's 2-D world does not fly and the vehicles do: the climb to the flight layer
    # after take-off, and the landing descent at the pad (docs/design/endurance.md §7).
    launch_s = EnduranceParams().launch_s + top_m / lim.climb_rate_m_s

    def policy_for(land_s: float):
        flight = {"launch_s": launch_s, "land_s": land_s}
        return end.policy(n, mission.run.duration_s, lim.max_speed_m_s, mean_post_m, flight=flight)

    try:
        policy = policy_for(landing_descent_s(top_m))
    except ValueError as exc:  # e.g. a battery too small to reach the posts and come back
        raise RunnerError(
            f"mission {mission.name}: {exc} (endurance.battery.endurance_s, or --rotation off)"
        ) from exc
    log.info("rotation: %d of %d fly at once", policy.flying, n)
    return RotationSetup(
        policy,
        hover_drain_per_s=1.0 / spec.endurance_s,
        return_drain_factor=1.0 + spec.speed_drain_frac,
        swap_confirm=swap_confirm,
        land_from_m=top_m,
        # The audit reads the vehicles' landing parameters; the plan then counts their own
        # descent, unless the mission set its own land_s (docs/design/endurance.md §7).
        replan=None if "land_s" in end.params else policy_for,
    )


def _rally_keeper(mission: Mission, params: dict) -> RallyKeeper | None:
    """Rally points on the vehicles (gcs/rally.py) when the planner publishes them:
    ``phireman-resilient`` with ``rally: true``; at the mission's cruise altitude."""
    if mission.planner.method != "phireman-resilient" or not params.get("rally", False):
        return None
    o = mission.origin
    return RallyKeeper(
        o.lat_deg, o.lon_deg, RallyConfig(alt_above_home_m=mission.vehicles.limits.cruise_alt_m)
    )


def _status_dict(op: Operator, now_s: float, rec: TickRecord | None, world, n_tasks: int) -> dict:
    """The status for people (``FlyOptions.status``). ``n_tasks``: the mission's crews, shown
    from the start; ``tasks_covered`` is None until the first control tick measured it."""
    snap = op.fleet.snapshot(now_s)
    modes: dict[str, int] = {}
    for m, lost in zip(snap.mode, snap.lost):
        key = "LOST" if lost else m
        modes[key] = modes.get(key, 0) + 1
    last = op.records[-1] if op.records else None
    d = {
        "phase": op.phase,
        "t_s": now_s,
        "t_mission_s": op.t_mission_s(now_s),
        "duration_s": op.config.duration_s,
        "fleet": snap.n_vehicles,
        "networked": int(snap.networked.sum()),
        "returning": int(snap.returning.sum()),
        "lost": int(snap.lost.sum()),
        "modes": modes,
        "tasks_covered": last.tasks_covered if last else None,
        "n_tasks": last.n_tasks if last else n_tasks,
        "fleet_expected": op.config.expected_vehicles,
        "tu1": last.tu1_so_far if last else None,
        "tu2": last.tu2_so_far if last else None,
        "command_failures": op.counters["command_failures"],
        "end_t0_s": op.end_t0_s,
        "failsafes": len(op.failsafe_texts),
        "last_failsafe": op.failsafe_texts[-1] if op.failsafe_texts else None,
        "reclaims": len(op.reclaimed),
        "rally_failures": len(op.rally.failures) if op.rally is not None else 0,
        "last_rally_failure": op.rally.failures[-1]
        if op.rally is not None and op.rally.failures
        else None,
        "wall_s": time.monotonic(),
    }
    rot = op.rotation_summary()
    if rot is not None:
        d["rotation"] = rot
    if world is not None and getattr(world, "swarm", None) is not None:
        d["truth_alive"] = int(world.swarm.alive.sum())
    return d


async def run_station(
    mission: Mission,
    scenario: MissionScenario,
    connections: list[str],
    opts: FlyOptions,
    records: Records,
    *,
    clock: Callable[[], float],
    speedup: float,
    expected: int | None,
    seed: int,
    world: InProcessEmulator | EmulatorProcess | None = None,
    max_sleep_s: float = math.inf,
    ack: Callable[[float], None] | None = None,
    times: FlightTimes | None = None,
) -> Operator:
    """The station's loop. ``max_sleep_s`` (simulated seconds): wake at least this often even
    when idle, so a paced emulator is never starved of clock acknowledgements. ``times``: where
    the mission phase's start and end (and Ctrl-C) are noted on both clocks."""
    times = FlightTimes() if times is None else times
    # Before any link is open (a stall now costs nothing; in flight it trips failsafes).
    _warm_up_planner(mission, *_planner_spec(mission), scenario, terrain_radio(mission))
    cfg = _station_config(
        mission, expected if world is None else None, health=bool(getattr(opts, "serve", None))
    )
    if opts.forward:
        # A forwarded GCS (QGroundControl, MAVProxy) wants the telemetry the station itself
        # does not use: do not turn it off (gcs.link disable_unused_messages).
        cfg = dataclasses.replace(cfg, disable_unused_messages=False)
    holder: dict = {}
    records.battery_events = mission.endurance.battery is not None

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
            adapters.append(
                await StationAdapter(
                    conn,
                    cfg,
                    link_id=i,
                    clock=clock,
                    tlog=records.tlog,
                    on_event=on_event,
                    time_scale=speedup,
                    on_link_event=records.events.write,
                ).start()
            )
    except (OSError, ValueError) as exc:
        for a in adapters:
            a.close()
        raise RunnerError(f"cannot open link {conn!r}: {exc}") from exc
    station = Station([a.core for a in adapters])  # type: ignore[misc]  # started: each has a core
    try:
        serve_terrain(mission, station)
        op = make_operator(mission, scenario, station, opts, expected, clock(), seed)
    except BaseException:  # e.g. RunnerError: no link may outlive the run (or write its tlog)
        for a in adapters:
            a.close()
        raise
    holder["op"] = op
    op.on_action = records.events.write  # operator actions in events.jsonl, with their source
    if op.rally is not None:  # failed rally uploads: events.jsonl and the live view, not the fleet

        def on_rally_failure(ev) -> None:
            records.event(ev)
            for listener in holder.get("listeners", ()):
                listener(ev)

        op.rally.on_failure = on_rally_failure
    for ev in holder.pop("early", []):
        op.handle_event(ev)
    extras = []
    if opts.serve or opts.forward:  # the live view and MAVLink forwarding, on this loop
        if opts.attach_view is None:
            for a in adapters:
                a.close()
            raise RunnerError(
                "--serve / --forward: no live view was given (FlyOptions.attach_view)"
            )
        try:
            extras = await opts.attach_view(
                op,
                adapters,
                mission=mission,
                opts=opts,
                clock=clock,
                records=records,
                listeners=holder.setdefault("listeners", []),
            )
        except (OSError, ValueError) as exc:
            for a in adapters:
                a.close()
            raise RunnerError(f"cannot serve / forward: {exc}") from exc
    urls = tak_urls(mission, opts.tak)
    tak_link = None
    if urls:  # crews from TAK, the mesh published on TAK: on this loop, never blocking a tick
        from mission.flight.tak_link import TakLink

        try:
            tak_link = await TakLink(
                urls, on_event, clock=clock, speedup=speedup, tls=opts.tak_tls
            ).start()
        except (OSError, ValueError, SyntaxError) as exc:
            for a in adapters:
                a.close()
            for x in extras:
                await x.aclose()
            raise RunnerError(f"cannot open TAK connection: {exc}") from exc
        extras.append(tak_link)
        if opts.on_tak is not None:
            opts.on_tak({"urls": list(urls)})
        if opts.tak and opts.attach_tak is not None:
            extras[:0] = await opts.attach_tak(
                op, tak_link, mission=mission, opts=opts, clock=clock, speedup=speedup
            )
    last_status = -math.inf
    due_s = -math.inf  # the operator's next deadline (simulated s), as of the last poll
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
                if ack is not None:
                    # Lock-step (see PacedReader): before this poll, everything due before the
                    # operator's next deadline is done (the links' timers run on their own), so
                    # the emulator may go on while a control tick is computed. Acknowledging only
                    # after each poll left it stale by the last poll plus the sleep: at 500
                    # vehicles and 10x every control tick held the emulator back
                    # (docs/results/scale.md).
                    ack(min(now, due_s))
                    # Then everything the vehicles sent is read (StationAdapter.drain), while
                    # the emulator goes on at most the slack past that acknowledgement: the
                    # station reads at most that late, where asyncio's one datagram a loop
                    # iteration let the queue, and the lag, grow without bound.
                    for a in adapters:
                        a.drain()
                    now = clock()
                rec = op.poll(now)
                times.note(op, now, time.monotonic())
                if ack is not None:
                    ack(now)  # everything due up to `now` is done
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
                    records.rotation(op, now)
                if op.phase == "done" and not opts.end_wait:
                    break
                if op.phase == "end" and not opts.end_wait:
                    op.phase = "done"
                for a in adapters:
                    a.transmit()
                wall = time.monotonic()
                if opts.status is not None and (wall - last_status >= 0.5 or op.finished):
                    last_status = wall
                    d = _status_dict(op, now, rec, world, mission.n_tasks)
                    d["speedup"] = speedup
                    d["links_down"] = [
                        (a.link_id, a.spec.text, a.down_reason) for a in adapters if not a.connected
                    ]
                    opts.status(d)
                due_s = op.next_poll_s(now)
                delay = max(0.0, min(due_s - clock(), max_sleep_s) / speedup)
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
                times.interrupt_s = clock()
                op.interrupt(opts.on_interrupt, times.interrupt_s)
                times.note(op, times.interrupt_s, interrupted_wall)
                for a in adapters:
                    a.transmit()
    finally:
        if op.phase == "refused" and not len(op.fleet):
            # Nothing heard: say what was tried, in the summary too (Operator.refusal).
            op.refusal = f"{op.refusal}; tried {_links_tried(adapters)}"
        for x in extras:
            await x.aclose()
        for a in adapters:
            if a.drained:
                log.info(
                    "link %d: %d datagrams read by drain, at most %d queued at once",
                    a.link_id,
                    a.drained,
                    a.drained_max,
                )
            a.close()
    return op


def serve_terrain(mission: Mission, station: Station) -> TerrainServer | None:
    """Answer the vehicles' TERRAIN_REQUEST from the mission's DEM on every link (gcs/terrain.py,
    docs/terrain.md §6); nothing for a mission without terrain. Returns the server."""
    if mission.terrain is None:
        return None
    from mission.format.terrain import build_terrain

    dem = build_terrain(mission)
    assert dem is not None  # a terrain section
    o = mission.origin
    server = TerrainServer(mission_heights(dem, o.lat_deg, o.lon_deg, o.alt_amsl_m))
    for link in station.links:
        link.terrain_server = server
    return server


def _links_tried(adapters) -> str:
    """'link 0 udpout:127.0.0.1:9 (open), link 1 tcp:127.0.0.1:9 (down: Connection refused)'."""
    return ", ".join(
        f"link {a.link_id} {a.spec.text} "
        f"({'open' if a.connected else 'down: ' + (a.down_reason or 'not connected')})"
        for a in adapters
    )

"""The operator's machine: inputs (link events), phases, and the run phase's control tick.

Two dispatch tables drive :class:`Operator`, in the manner of h11's ``_state.py``:

* **events**: :meth:`Operator.handle_event` folds every vehicle event into the fleet view, then
  looks its type up in ``Operator._EVENT_HANDLERS`` (type -> handler; a subclass of a listed type
  gets its base's handler) instead of an ``isinstance`` chain. A crew's tracker position
  (``TaskPositionReceived``) is no vehicle: it goes to ``Operator._SYSTEM_HANDLERS`` and never
  into the fleet.
* **phases**: :meth:`Operator.poll` calls the handler of the current phase from
  ``Operator._POLL`` (``_poll_<phase>``); when a handler moves the operator to a later phase,
  that phase's handler runs in the same poll (as the if-chain it replaces did), each at most
  once. Every transition goes through :meth:`Operator._enter` with a :class:`Trigger`, checked
  against :data:`gcs.operations.phases.TRANSITIONS`.

The audit, launch, end and operator-action steps are mixins in their own modules (see each
module's docstring for the seam); this module holds the state they share, set up in
:meth:`Operator.__init__`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from gcs import audit as audit_mod
from gcs.autopilot import adapter_for
from gcs.control import ControlConfig, tick
from gcs.events import (
    CommandFailed,
    CommandTimedOut,
    Event,
    ParamReceived,
    ParamSetConfirmed,
    ParamSetFailed,
    ParamTimedOut,
    ModeChanged,
    StatusText,
    TaskPositionReceived,
    VehicleDiscovered,
    VehicleLost,
    HomePositionReceived,
    VehicleRebooted,
    VehicleRecovered,
)
from gcs.fleet import FleetSnapshot, FleetView
from gcs.operations.actions import OperatorActions
from gcs.operations.audit import AuditStep
from gcs.operations.config import OperationsConfig, OperatorAction, TickRecord, _Row
from gcs.operations.end import EndStep
from gcs.operations.late_audit import LateAudit, LateAuditStep
from gcs.operations.launch import LaunchStep
from gcs.operations.phases import Phase, Trigger, next_phase
from gcs.operations.rally import RallyStep
from gcs.operations.rotation import RotationSetup, RotationStep
from gcs.rally import MissionProtocolReceived, RallyKeeper
from gcs.station import Station
from gcs.tak import TakContactReported, TakCrews
from gcs.tasks import LiveTasks
from planner.geometry import tasks_connected
from planner.methods import Planner
from planner.metrics import uptime_series

__all__ = ["Operator"]

log = logging.getLogger(__name__)


def _lookup(table: Mapping[Any, Callable[..., None]], cls: type) -> Callable[..., None] | None:
    """``table``'s entry for ``cls`` or its nearest listed base class (None if none).

    Memoised per (table, class): the tables are the class-level constants below, and the
    operator looks up every event it folds (a GLOBAL_POSITION_INT per vehicle and second)."""
    key = (id(table), cls)
    hit = _LOOKUPS.get(key)
    if hit is not None and hit[0] is table:  # the same table object (its id is not reused)
        return hit[1]
    found = None
    for base in cls.__mro__:
        handler = table.get(base)
        if handler is not None:
            found = handler
            break
    _LOOKUPS[key] = (table, found)
    return found


_LOOKUPS: dict[
    tuple[int, type], tuple[Mapping[Any, Callable[..., None]], Callable[..., None] | None]
] = {}


class Operator(
    AuditStep, LateAuditStep, LaunchStep, EndStep, OperatorActions, RallyStep, RotationStep
):
    """Launch, run, end and reclaim (see the :mod:`gcs.operations` docstring).

    Parameters
    ----------
    station : Station - the links (sans-I/O cores)
    fleet : FleetView - in the mission frame
    planner : the mission's planner (central information unless the mission's ``planner.info``
        says async; see ``mission.format.schema.PlannerSpec.run_params``)
    task_pos_fn : callable ``t_mission_s -> (M, 2)`` task positions, metres
    control : altitudes and geofence
    config : sequencing
    now_s : core time at construction
    rally : keeps the planner's rally points on the vehicles (gcs.operations.rally); None: off
    rotation : relays rotated through the base (gcs.operations.rotation), for a mission with
        batteries; None: every vehicle flies the whole mission, as before
    """

    def __init__(
        self,
        station: Station,
        fleet: FleetView,
        planner: Planner,
        task_pos_fn: Callable[[float], np.ndarray],
        control: ControlConfig,
        config: OperationsConfig = OperationsConfig(),
        *,
        now_s: float = 0.0,
        gcs_sysid: int = 255,
        live_tasks: LiveTasks | None = None,
        rally: RallyKeeper | None = None,
        rotation: RotationSetup | None = None,
        tak: TakCrews | None = None,
    ) -> None:
        self.station = station
        self.rotation = rotation
        self.fleet = fleet
        self.planner = planner
        self.live_tasks = live_tasks
        self.rally = rally
        self.tak = tak
        """Crews from TAK (gcs.tak): their columns are NaN while unknown (never heard or stale)."""
        if live_tasks is not None:
            base_fn = task_pos_fn
            task_pos_fn = lambda t_s: live_tasks.fill(base_fn(t_s))  # noqa: E731
        if tak is not None:
            inner_fn = task_pos_fn
            task_pos_fn = lambda t_s: tak.fill(inner_fn(t_s))  # noqa: E731
        self.task_pos_fn = task_pos_fn
        self.refusal: str | None = None
        """Why the flight was refused (phase 'refused'), for people."""
        self.control = control
        self.config = config
        self.gcs_sysid = gcs_sysid
        self._phase = Phase.DISCOVER
        self.t_start_s = now_s
        self._phase_since_s = now_s
        self._last_discovery_s = now_s
        self._rows: dict[int, _Row] = {}
        self._params: dict[tuple[int, int], dict[str, float]] = {}
        self._params_pending: set[tuple[int, int, str]] = set()
        self._last_param_s = -math.inf
        """When the last audit parameter was received (optional reads wait a little after it)."""
        self._known: set[tuple[int, int]] = set()
        self._audit_vids: set[tuple[int, int]] = set()
        """The vehicles the fleet's pre-flight audit read (every other one is audited on its own
        before it may fly: ``late_audits``)."""
        self.late_audits: dict[tuple[int, int], LateAudit] = {}
        """Vehicles discovered after the fleet audit -> their own audit
        (:mod:`gcs.operations.late_audit`)."""
        self.audit_report: audit_mod.AuditReport | None = None
        self.initial_audit_report: audit_mod.AuditReport | None = None
        """The audit before ``apply_failsafes`` changed anything (None if nothing was set)."""
        self.param_changes: list[dict[str, Any]] = []
        """One dict per parameter write: link_id, sysid, name, previous, value, ok, reason."""
        self._param_types: dict[tuple[int, int], dict[str, int]] = {}
        self._sets_pending: set[tuple[int, int, str]] = set()
        self._fixes_sent_s: float | None = None
        self._limits_sent_s: float | None = None
        self._restore_sent_s: float | None = None
        self._rally_params_sent_s: float | None = None
        self.limit_warnings: list[str] = []
        """Vehicles whose own speed limits could not be read or set (for people)."""
        self.prearm: dict[tuple[int, int], tuple[float, str]] = {}
        """Latest arming refusal text per vehicle ("PreArm: ..." STATUSTEXT) while launching."""
        self._audit_round = 1
        self._waves: list[list[int]] = []
        self._launch_since_s = now_s
        self._launch_gave_up = False
        self._wave = 0
        self._wave_since_s = now_s
        self.mission_t0_s: float | None = None
        self._next_tick_s = math.inf
        self._t_step = 0
        self._connected: list[np.ndarray] = []
        self.records: list[TickRecord] = []
        self.end_t0_s: float | None = None
        self.reclaimed: list[tuple[float, int, int]] = []
        """(t_s, link_id, sysid) of every airborne vehicle seen back in the guided mode after the
        station switched it from another mode (a failsafe RTL, or found flying by a restarted
        station)."""
        self.counters = {
            "reclaim_attempts": 0,
            "relaunches": 0,
            "command_failures": 0,
            "lost": 0,
            "recovered": 0,
            "takeoff_climbs": 0,
        }
        self.released: dict[tuple[int, int], str] = {}
        """Vehicles an operator took out of the plan -> the action that did it (hold, rtl, land,
        release, or ``override``: a forwarded client's command, honoured). The operator never
        plans, reclaims or relaunches them; nor end-commands those sent home or down, or taken
        by a forwarded client."""
        self.overrides: dict[tuple[int, int], OperatorAction] = {}
        """Vehicles a forwarded client took (``released`` ``override``) -> the record saying who,
        with which command and when (:meth:`forwarded_override`)."""
        self._refusals_logged: dict[tuple[int, int], tuple[float, str, str]] = {}
        self.failsafe_texts: list[tuple[float, tuple[int, int], str]] = []
        """(t_s, vid, text) of every failsafe STATUSTEXT a vehicle sent."""
        self.interrupted: str | None = None
        """Set by :meth:`interrupt` (Ctrl-C): the action every vehicle was told."""
        self.end_status: dict[str, int] | None = None
        """At the end: vehicles heard on the ground / still in the air, and not heard."""
        self.actions: list[OperatorAction] = []
        self.on_action: Callable[[OperatorAction], None] | None = None
        """Called with every :class:`OperatorAction` (the runner writes it to events.jsonl)."""

    # ------------------------------------------------------------------ phase

    @property
    def phase(self) -> Phase:
        """The current phase: a :class:`Phase`, which is a ``str`` (``op.phase == "run"``)."""
        return self._phase

    @phase.setter
    def phase(self, value: str) -> None:
        # A driver's override (a runner that stops at "end" without waiting, a test hook that
        # stops the flight): set as told, like the plain attribute it replaces; not a transition
        # of the machine, so not checked against the table.
        self._phase = Phase(value)

    @property
    def finished(self) -> bool:
        return self._phase in (Phase.DONE, Phase.REFUSED)

    def _enter(self, trigger: Trigger, now_s: float) -> None:
        """Move to the phase ``trigger`` leads to from the current one (the table,
        :data:`gcs.operations.phases.TRANSITIONS`); IllegalTransition if it leads nowhere."""
        phase = next_phase(self._phase, trigger)
        log.info("phase %s -> %s (%s) at t=%.1f s", self._phase, phase, trigger, now_s)
        self._phase = phase
        self._phase_since_s = now_s

    # ------------------------------------------------------------------ inputs

    def handle_event(self, event: Event) -> None:
        """Fold one link event into the fleet and the operator's bookkeeping."""
        handler = _lookup(self._SYSTEM_HANDLERS, type(event))
        if handler is not None:  # not a vehicle: never a fleet row
            handler(self, event)
            return
        self.fleet.apply(event)
        key = (event.link_id, event.sysid)
        handler = _lookup(self._EVENT_HANDLERS, type(event))
        if handler is not None:
            handler(self, event, key)

    def _on_task_position(self, event: TaskPositionReceived) -> None:
        if self.live_tasks is not None:  # a crew's tracker
            self.live_tasks.apply(event)

    def _on_tak_report(self, event: TakContactReported) -> None:
        if self.tak is not None:  # a crew's TAK phone
            self.tak.apply(event)

    @property
    def crews_connected(self) -> np.ndarray | None:
        """(M,) bool: which crews the last control tick found networked (None before it)."""
        return self._connected[-1] if self._connected else None

    def _on_vehicle_discovered(self, event: VehicleDiscovered, key: tuple[int, int]) -> None:
        self._known.add(key)
        self._last_discovery_s = event.t_s
        self._rows.setdefault(self.fleet.index_of(*key), _Row())

    def _on_status_text(self, event: StatusText, key: tuple[int, int]) -> None:
        text = event.text.strip()
        if self.rally is not None:  # "RTL: unsupported MAV_FRAME": its rally points are unusable
            self.rally.on_status_text(key, text, event.t_s)
        # ArduPilot AP_Arming::check_failed: "PreArm: ..." / "Arm: ..."; PX4 commander:
        # "Arming denied: ...", "Preflight Fail: ...".
        low = text.lower()
        # ArduPilot events.cpp "Failsafe" texts (e.g. "GCS Failsafe"), PX4 commander
        # "Failsafe activated: ..." / "... failsafe ...": shown to the operator as they come;
        # the end of one ("GCS Failsafe Cleared", StatusText.kind "recovered") is not a warning.
        if ("failsafe" in low or "fail-safe" in low) and event.kind != "recovered":
            self.failsafe_texts.append((event.t_s, key, text))
        if text.startswith(("PreArm", "Arm:", "Arming denied", "Preflight Fail")):
            old = self.prearm.get(key)
            self.prearm[key] = (event.t_s, text)
            if (old is None or old[1] != text) and self._phase in (Phase.LAUNCH, Phase.RUN):
                log.warning("link %d sysid %d not ready to arm: %s", *key, text)

    def _on_vehicle_lost(self, event: VehicleLost, key: tuple[int, int]) -> None:
        self.counters["lost"] += 1

    def _on_vehicle_recovered(self, event: VehicleRecovered, key: tuple[int, int]) -> None:
        self.counters["recovered"] += 1
        row = self._rows.get(self.fleet.index_of(*key))
        if row is not None:
            row.next_action_s = -math.inf  # act on it at the next poll

    #: Events from systems that are not vehicles (no fleet row): type -> handler(op, event).
    _SYSTEM_HANDLERS: dict[type, Callable[..., None]] = {
        TaskPositionReceived: _on_task_position,
        TakContactReported: _on_tak_report,
    }

    #: Vehicle events, after the fleet view folded them: type -> handler(op, event, vid).
    #: Types not listed (telemetry, mode, armed, home, acks) only update the fleet view.
    _EVENT_HANDLERS: dict[type, Callable[..., None]] = {
        VehicleDiscovered: _on_vehicle_discovered,
        ParamReceived: AuditStep._on_param_received,
        ParamTimedOut: AuditStep._on_param_timed_out,
        ParamSetConfirmed: AuditStep._on_param_set,
        ParamSetFailed: AuditStep._on_param_set,
        StatusText: _on_status_text,
        CommandFailed: LaunchStep._on_command_failed,
        CommandTimedOut: LaunchStep._on_command_failed,
        VehicleLost: _on_vehicle_lost,
        VehicleRecovered: _on_vehicle_recovered,
        MissionProtocolReceived: RallyStep._on_mission_protocol,
        ModeChanged: RotationStep._rotation_on_mode,
        VehicleRebooted: RotationStep._rotation_on_reboot,
        HomePositionReceived: RotationStep._rotation_on_home,
    }

    # ------------------------------------------------------------------ timing

    def next_poll_s(self, now_s: float) -> float:
        return min(now_s + self.config.poll_period_s, self._next_tick_s)

    def t_mission_s(self, now_s: float) -> float:
        return 0.0 if self.mission_t0_s is None else max(0.0, now_s - self.mission_t0_s)

    # ------------------------------------------------------------------ the machine

    def poll(self, now_s: float) -> TickRecord | None:
        """Advance the phases; returns the metrics of a control tick if one ran."""
        snap = self.fleet.snapshot(now_s)
        if self.tak is not None:
            self.tak.expire(now_s)  # a crew past its CoT stale time is unknown from now on
        rows = self._rows
        for i in range(snap.n_vehicles):  # a row for every vehicle (built only when missing)
            if i not in rows:
                rows[i] = _Row()
        self._poll_late_audits(snap, now_s)  # vehicles discovered after the fleet audit
        record = None
        polled: set[Phase] = set()
        while self._phase not in polled:  # a phase entered during this poll is polled too
            polled.add(self._phase)
            rec = self._POLL[self._phase](self, snap, now_s)
            if rec is not None:
                record = rec
        self._rally_poll(snap, now_s)
        return record

    def _poll_discover(self, snap: FleetSnapshot, now_s: float) -> None:
        """Wait for the fleet (``expected_vehicles``, or settled, or ``discover_timeout_s``) and
        every live task's first position; then audit (or launch), or refuse. Nothing heard by
        ``discover_timeout_s`` is refused too (a wrong port or an autopilot not started does
        not fix itself; the caller says what it tried)."""
        cfg = self.config
        n = snap.n_vehicles
        waited = now_s - self._phase_since_s
        if not n and waited >= cfg.discover_timeout_s:
            self.refusal = f"no vehicle heard within {cfg.discover_timeout_s:g} s"
            log.warning("refusing to launch: %s", self.refusal)
            self._enter(Trigger.NOTHING_HEARD, now_s)
            return
        if n and (
            (cfg.expected_vehicles is not None and n >= cfg.expected_vehicles)
            or (
                cfg.expected_vehicles is None
                and now_s - self._last_discovery_s >= cfg.discover_settle_s
            )
            or waited >= cfg.discover_timeout_s
        ):
            trackers = self.live_tasks.waiting_for() if self.live_tasks is not None else ()
            crews = self.tak.waiting_for() if self.tak is not None else ()
            if not trackers and not crews:
                self._start_audit(snap, now_s)
            elif waited >= cfg.discover_timeout_s + cfg.task_wait_timeout_s:
                unseen = []
                if trackers:
                    unseen.append(f"live task tracker(s) sysid {', '.join(map(str, trackers))}")
                if crews:
                    unseen.append(f"TAK crew(s) {', '.join(crews)}")
                self.refusal = f"no position from {' nor '.join(unseen)} after {waited:.0f} s"
                log.warning("refusing to launch: %s", self.refusal)
                self._enter(Trigger.TASKS_UNSEEN, now_s)

    def _poll_run(self, snap: FleetSnapshot, now_s: float) -> TickRecord | None:
        """A control tick every ``control_period_s``, reclaim, and the end after
        ``duration_s``."""
        cfg = self.config
        record = None
        if now_s >= self._next_tick_s:
            record = self._control_tick(snap, now_s)
            self._next_tick_s += cfg.control_period_s
            if self._next_tick_s <= now_s:
                self._next_tick_s = now_s + cfg.control_period_s
        self._reclaim(snap, now_s)
        assert self.mission_t0_s is not None  # set when the run phase starts
        if now_s - self.mission_t0_s >= cfg.duration_s - 1e-9 and self._t_step >= 1:
            self.begin_end(now_s)
        return record

    def _poll_finished(self, snap: FleetSnapshot, now_s: float) -> None:
        """Done or refused: nothing more to do."""

    #: The handler of each phase (every phase has one).
    _POLL = {
        Phase.DISCOVER: _poll_discover,
        Phase.AUDIT: AuditStep._poll_audit,
        Phase.LAUNCH: LaunchStep._poll_launch,
        Phase.RUN: _poll_run,
        Phase.END: EndStep._poll_end,
        Phase.DONE: _poll_finished,
        Phase.REFUSED: _poll_finished,
    }

    # ------------------------------------------------------------------ helpers

    def _vid(self, snap: FleetSnapshot, i: int) -> tuple[int, int]:
        return int(snap.link_id[i]), int(snap.sysid_of_index[i])

    def _in_plan(self, snap: FleetSnapshot) -> np.ndarray:
        """(N,) bool: rows not taken out of the plan by an operator action, nor waiting for (or
        refused by) their own pre-flight audit (discovered after the fleet's)."""
        ok = self._audit_gate(snap)
        if self.released:
            for i in range(snap.n_vehicles):
                ok[i] = self._vid(snap, i) not in self.released
        return ok

    # ------------------------------------------------------------------ run

    def _control_tick(self, snap: FleetSnapshot, now_s: float) -> TickRecord:
        alt = self._height_m(snap)
        heard = ~snap.lost
        airborne = heard & snap.armed & np.isfinite(alt) & (alt > self.config.airborne_alt_m)
        airborne &= self._in_plan(snap)  # released vehicles are neither planned nor relays
        plan_alive = heard & self._audit_gate(snap)  # a vehicle not audited yet is not in the plan
        if self.rotation is not None:
            # Only the rotation's ``air`` vehicles reach the planner (docs/design/endurance.md
            # §1): spares on the ground, inbound and returning ones are not in its fleet.
            planned = self._rotation_step(snap, alt, now_s)
            airborne &= planned
            plan_alive &= planned
        t_m = self.t_mission_s(now_s)
        task_pos = np.asarray(self.task_pos_fn(t_m), dtype=float).reshape(-1, 2)
        result = tick(
            snap.pos_ned_m, airborne, plan_alive, task_pos, self.planner, self._t_step, self.control
        )
        self._send_targets(snap, result.rows, result.target_ned_m, now_s)
        self._rally_after_tick(now_s)
        ne = np.where(snap.has_position[:, None], snap.pos_ned_m[:, :2], np.inf)
        known = np.isfinite(task_pos).all(axis=1)  # an unknown crew is never connected
        ta = self.control.terrain
        if ta is not None and ta.radio is not None:
            # Over terrain: a heard vehicle's link to the crew's radio must clear the DEM.
            crews = np.where(known[:, None], task_pos, 0.0)
            covered = (
                ta.radio.tasks_connected(
                    crews,
                    ta.terrain.height_m(crews) + ta.crew_antenna_agl_m,
                    np.where(snap.has_position[:, None], snap.pos_ned_m[:, :2], 0.0),
                    ta.origin_amsl_m - np.nan_to_num(snap.pos_ned_m[:, 2]),
                    heard & snap.has_position,
                )
                & known
            )
        else:
            covered = (
                tasks_connected(
                    np.where(known[:, None], task_pos, np.inf),
                    ne,
                    heard & snap.has_position,
                    self.config.radio_range_m,
                )
                & known
            )
        self._connected.append(covered)
        series = uptime_series(np.asarray(self._connected))
        adapters = [adapter_for(int(a)) for a in snap.autopilot]
        guided = sum(ad.is_guided(int(m)) for ad, m in zip(adapters, snap.custom_mode))
        rec = TickRecord(
            t_s=now_s,
            t_mission_s=t_m,
            t_step=self._t_step,
            fleet=snap.n_vehicles,
            networked=int(snap.networked.sum()),
            planned=len(result.rows),
            lost=int(snap.lost.sum()),
            returning=int(snap.returning.sum()),
            guided=int(guided),
            tasks_covered=int(covered.sum()),
            n_tasks=len(task_pos),
            tu1_so_far=series.tu1,
            tu2_so_far=series.tu2,
            plan_iterations=result.info.get("iterations"),
        )
        self.records.append(rec)
        self._t_step += 1
        return rec

    def station_tu(self) -> tuple[float, float]:
        """(TU1, TU2) over the run's ticks, from what the station saw."""
        if not self._connected:
            return 0.0, 0.0
        s = uptime_series(np.asarray(self._connected))
        return s.tu1, s.tu2

"""Flight operations: launch, run, end and reclaim, on top of the station core and the fleet view.

Sans-I/O like everything under ``gcs``: the :class:`Operator` is fed link events
(:meth:`Operator.handle_event`) and polled with an explicit ``now_s`` (:meth:`Operator.poll`);
it calls the :class:`~gcs.station.Station`'s local API (which only queues frames). A driver (the
asyncio adapters, or an in-memory ether in tests) moves the bytes and calls :meth:`poll` at
:meth:`next_poll_s`. It never reads a clock and never sees ground truth.

Phases (``Operator.phase``)::

    discover -> audit -> launch -> run -> end -> done
    discover / audit -> refused (a live task never heard; a blocking audit finding and no
                                 override)

* **discover**: wait for ``expected_vehicles`` HEARTBEATs (or ``discover_timeout_s``, or
  ``discover_settle_s`` without a new vehicle when no count is expected), and for the first
  position of every live task tracker (:mod:`gcs.tasks`; refused after ``task_wait_timeout_s``).
* **audit**: read the lost-link parameters of every vehicle (:mod:`gcs.audit`); refuse unless
  every vehicle is safe or ``override_audit``. With ``apply_failsafes`` (and only then: no
  failsafe parameter is ever written otherwise), every fixable blocking finding is first fixed by a
  PARAM_SET confirmed by the vehicle's PARAM_VALUE echo (:func:`gcs.audit.failsafe_fixes`), and
  the fleet re-audited with the echoed values; ``param_changes`` records every write. Then,
  with ``set_limits``, the mission's speed and climb limits are written into each vehicle's
  own parameters (:mod:`gcs.limits`), each confirmed by its echo.
* **launch**: in waves of ``wave_size``: GUIDED (ArduPilot) / pre-streamed OFFBOARD (PX4), arm,
  take off to the vehicle's layer; the next wave starts as soon as most of this one is off the
  ground (waves spread the command burst and the take-off, they do not wait for the climb);
  the run starts when most of the fleet has climbed. A vehicle that is armed and taking off is
  left alone (never re-armed or sent a second take-off), and a vehicle whose commands fail is
  retried with an exponential back-off, never in a tight loop.
* **run**: every ``control_period_s``, :func:`gcs.control.tick` plans for every vehicle the
  station hears that is armed and airborne; one SET_POSITION_TARGET_GLOBAL_INT each.
* **end**: RTL or LAND every vehicle heard; done when every vehicle heard has landed (disarmed),
  or after ``end_timeout_s`` (``end_status`` says how many were still in the air).

**Reclaim** runs in every phase after discovery: a vehicle heard again that is not in the guided
mode (back from a failsafe RTL, or found in RTL by a restarted station) is switched back to
GUIDED/OFFBOARD (PX4: after streaming setpoints at its current position) and rejoins the plan;
one that already landed and disarmed is armed and launched again. Vehicles are identified by
``(link_id, sysid)``, which :class:`~gcs.fleet.FleetView` maps to a stable row.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from gcs import audit as audit_mod
from gcs.autopilot import adapter_for
from gcs import limits as limits_mod
from gcs.control import ControlConfig, layer_alt_m, tick
from gcs.events import (
    CommandFailed, CommandTimedOut, Event, ParamReceived, ParamSetConfirmed, ParamSetFailed,
    ParamTimedOut, StatusText, TaskPositionReceived,
    VehicleDiscovered, VehicleLost, VehicleRecovered,
)
from gcs.fleet import FleetSnapshot, FleetView
from gcs.link import LinkUsageError, UnknownVehicle
from gcs.wire import mavlink
from gcs.station import Station
from gcs.tasks import LiveTasks
from planner.geometry import tasks_connected
from planner.methods import Planner
from planner.metrics import uptime_series

__all__ = ["OperationsConfig", "Operator", "PHASES", "TickRecord", "OperatorAction",
           "OPERATOR_ACTIONS"]

log = logging.getLogger(__name__)

PHASES = ("discover", "audit", "launch", "run", "end", "done", "refused")


@dataclass(frozen=True)
class OperationsConfig:
    """Sequencing and timing. Times are station-core seconds (the vehicles' clock under
    speed-up); units in the names."""

    expected_vehicles: int | None = None
    """Start as soon as this many vehicles are discovered (None: wait ``discover_settle_s``)."""
    discover_timeout_s: float = 30.0
    discover_settle_s: float = 3.0
    audit: bool = True
    override_audit: bool = False
    audit_timeout_s: float = 60.0
    audit_rounds: int = 3
    """Parameter reads that timed out are requested again, up to this many rounds in all."""
    apply_failsafes: bool = False
    """Fix fixable blocking audit findings by PARAM_SET (:func:`gcs.audit.failsafe_fixes`:
    ArduPilot FS_GCS_ENABLE, the GCS sysid; PX4 NAV_DLL_ACT, NAV_RCL_ACT, COM_OBL_RC_ACT,
    COM_OBL_ACT, COM_DLL_EXCEPT) before re-auditing. No failsafe parameter is ever written
    without it (the mission's speed limits are, see ``set_limits``)."""
    max_speed_m_s: float | None = None
    """The mission's horizontal speed limit; with ``set_limits`` written into each vehicle's own
    parameters at launch (:mod:`gcs.limits`). None: the firmware's limits are left alone."""
    climb_rate_m_s: float | None = None
    set_limits: bool = True
    restore_params: bool = False
    """After landing, write back the previous value of every parameter the station changed."""
    wave_size: int = 10
    wave_timeout_s: float = 40.0
    """A wave (and the final climb) waits at most this long for its vehicles."""
    wave_airborne_frac: float = 0.8
    """The next wave starts when this fraction of the wave's live vehicles is airborne."""
    wave_climbed_frac: float = 0.8
    """The run starts when this fraction of the fleet's live vehicles is above
    ``climbed_alt_frac`` of its target altitude."""
    climbed_alt_frac: float = 0.7
    takeoff_grace_s: float = 6.0
    """After a take-off command, an armed vehicle still on the ground is given this long to leave
    it before the take-off is sent again (below ArduCopter's DISARM_DELAY, 10 s)."""
    max_backoff_s: float = 24.0
    """Back-off cap after repeated command failures on one vehicle."""
    prearm_retry_s: float = 5.0
    """A vehicle that refused to arm (not ready: ArduPilot MAV_RESULT_FAILED with a "PreArm:"
    STATUSTEXT while the EKF/GPS converge, ~40 s in SITL; PX4 TEMPORARILY_REJECTED) is asked
    again this often, without exponential back-off; the launch waits for it."""
    launch_timeout_s: float = 300.0
    """The launch gives up waiting for vehicles that keep refusing to arm after this long
    (from the start of the launch) and starts the run with those that flew."""
    control_period_s: float = 1.0
    duration_s: float = 200.0
    """Length of the run phase (the mission), seconds."""
    end: str = "rtl"
    """'rtl' or 'land'."""
    end_timeout_s: float = 180.0
    action_retry_s: float = 3.0
    """Minimum time between two mode/arm/takeoff attempts on one vehicle."""
    airborne_alt_m: float = 2.0
    """Above home by more than this = airborne."""
    radio_range_m: float = math.inf
    """For "tasks covered as the station sees them" (a task within range of a networked vehicle)."""
    poll_period_s: float = 0.25
    task_wait_timeout_s: float = 120.0
    """Live tasks (crew trackers): after discovery, wait at most this long for every tracker's
    first position before refusing to launch (a task the station cannot see cannot be served)."""

    def __post_init__(self) -> None:
        if self.end not in ("rtl", "land"):
            raise ValueError(f"end must be 'rtl' or 'land', got {self.end!r}")
        if self.wave_size < 1:
            raise ValueError("wave_size must be >= 1")
        for name in ("control_period_s", "duration_s", "poll_period_s", "action_retry_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")


@dataclass(frozen=True)
class TickRecord:
    """Per-tick metrics as the station saw them."""

    t_s: float
    t_mission_s: float
    t_step: int
    fleet: int
    networked: int
    planned: int
    lost: int
    returning: int
    guided: int
    tasks_covered: int
    n_tasks: int
    tu1_so_far: float
    tu2_so_far: float
    plan_iterations: int | None = None

    def row(self) -> dict:
        return dict(self.__dict__)


#: What an operator may ask of one vehicle (or of all): ``hold`` (leave the plan, hover where it
#: is at its layer, still in GUIDED/OFFBOARD so the link failsafes still apply), ``rtl``, ``land``
#: (leave the plan, the firmware's RTL / LAND mode), ``release`` (leave the plan, keep the last
#: target) and ``rejoin`` (back into the plan: reclaimed like a vehicle back from a failsafe).
OPERATOR_ACTIONS = ("hold", "rtl", "land", "release", "rejoin")


@dataclass(frozen=True)
class OperatorAction:
    """One operator request, as recorded in ``events.jsonl`` (who asked, what, for whom)."""

    t_s: float
    action: str
    link_id: int
    sysid: int
    source: str
    """Where it came from (e.g. ``web 127.0.0.1``, ``cli``)."""
    result: str
    """``sent``, ``released``, ``rejoined`` or why nothing was sent."""


@dataclass
class _Row:
    next_action_s: float = -math.inf
    launched: bool = False
    flew: bool = False
    """Seen airborne at least once (a later take-off is a relaunch)."""
    takeoff_s: float = -math.inf
    """When the last take-off was commanded."""
    failures: int = 0
    """Consecutive failed attempts (exponential back-off); an attempt's commands (GUIDED, arm,
    take-off) failing together count once."""
    attempt: int = 0
    failed_attempt: int = -1
    refused_attempt: int = -1
    not_ready_s: float = -math.inf
    """When the vehicle last refused to arm (not ready yet)."""
    reclaims: int = 0
    reclaiming: bool = False
    """GUIDED/OFFBOARD was asked of it while airborne in another mode; counted as a reclaim once
    it is seen back in the guided mode (the same on a first run and after a station restart)."""
    armed_seen_s: float = -math.inf
    """When it was first seen armed after its last take-off command."""


class Operator:
    """Launch, run, end and reclaim (see the module docstring).

    Parameters
    ----------
    station : Station - the links (sans-I/O cores)
    fleet : FleetView - in the mission frame
    planner : a central planner (``make_planner('phireman-central', ...)``)
    task_pos_fn : callable ``t_mission_s -> (M, 2)`` task positions, metres
    control : altitudes and geofence
    config : sequencing
    now_s : core time at construction
    """

    def __init__(self, station: Station, fleet: FleetView, planner: Planner,
                 task_pos_fn: Callable[[float], np.ndarray], control: ControlConfig,
                 config: OperationsConfig = OperationsConfig(), *, now_s: float = 0.0,
                 gcs_sysid: int = 255, live_tasks: LiveTasks | None = None) -> None:
        self.station = station
        self.fleet = fleet
        self.planner = planner
        self.live_tasks = live_tasks
        self.task_pos_fn = task_pos_fn if live_tasks is None else (
            lambda t_s: live_tasks.fill(task_pos_fn(t_s)))
        self.refusal: str | None = None
        """Why the flight was refused (phase 'refused'), for people."""
        self.control = control
        self.config = config
        self.gcs_sysid = gcs_sysid
        self.phase = "discover"
        self.t_start_s = now_s
        self._phase_since_s = now_s
        self._last_discovery_s = now_s
        self._rows: dict[int, _Row] = {}
        self._params: dict[tuple[int, int], dict[str, float]] = {}
        self._params_pending: set[tuple[int, int, str]] = set()
        self._known: set[tuple[int, int]] = set()
        self.audit_report: audit_mod.AuditReport | None = None
        self.initial_audit_report: audit_mod.AuditReport | None = None
        """The audit before ``apply_failsafes`` changed anything (None if nothing was set)."""
        self.param_changes: list[dict] = []
        """One dict per parameter write: link_id, sysid, name, previous, value, ok, reason."""
        self._param_types: dict[tuple[int, int], dict[str, int]] = {}
        self._sets_pending: set[tuple[int, int, str]] = set()
        self._fixes_sent_s: float | None = None
        self._limits_sent_s: float | None = None
        self._restore_sent_s: float | None = None
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
        self.counters = {"reclaim_attempts": 0, "relaunches": 0, "command_failures": 0,
                         "lost": 0, "recovered": 0}
        self.released: dict[tuple[int, int], str] = {}
        """Vehicles an operator took out of the plan -> the action that did it (hold, rtl, land,
        release). The operator never plans, reclaims, relaunches or end-commands them."""
        self.failsafe_texts: list[tuple[float, tuple[int, int], str]] = []
        """(t_s, vid, text) of every failsafe STATUSTEXT a vehicle sent."""
        self.interrupted: str | None = None
        """Set by :meth:`interrupt` (Ctrl-C): the action every vehicle was told."""
        self.end_status: dict[str, int] | None = None
        """At the end: vehicles heard on the ground / still in the air, and not heard."""
        self.actions: list[OperatorAction] = []
        self.on_action: Callable[[OperatorAction], None] | None = None
        """Called with every :class:`OperatorAction` (the runner writes it to events.jsonl)."""

    # ------------------------------------------------------------------ inputs

    def handle_event(self, event: Event) -> None:
        """Fold one link event into the fleet and the operator's bookkeeping."""
        if isinstance(event, TaskPositionReceived):  # a crew's tracker: never a fleet row
            if self.live_tasks is not None:
                self.live_tasks.apply(event)
            return
        self.fleet.apply(event)
        key = (event.link_id, event.sysid)
        if isinstance(event, VehicleDiscovered):
            self._known.add(key)
            self._last_discovery_s = event.t_s
            self._rows.setdefault(self.fleet.index_of(*key), _Row())
        elif isinstance(event, ParamReceived):
            self._params.setdefault(key, {})[event.name] = event.value
            self._param_types.setdefault(key, {})[event.name] = event.param_type
            self._params_pending.discard((*key, event.name))
            # Renamed parameters: the firmware has one spelling; stop asking for the other.
            for alt in audit_mod.ALTERNATIVE_NAMES.get(event.name, ()):
                if (*key, alt) in self._params_pending:
                    self._params_pending.discard((*key, alt))
                    try:
                        self.station.link(key[0]).cancel_param(key[1], alt, event.t_s)
                    except (KeyError, IndexError):
                        pass
            for extra in audit_mod.FOLLOW_UP_PARAMS.get(event.name, ()):
                if self.phase == "audit" and extra not in self._params.get(key, {}):
                    self._params_pending.add((*key, extra))
                    self.station.request_param(key, extra, event.t_s)
        elif isinstance(event, ParamTimedOut):
            self._params_pending.discard((*key, event.name))
        elif isinstance(event, (ParamSetConfirmed, ParamSetFailed)):
            if (*key, event.name) in self._sets_pending:
                self._sets_pending.discard((*key, event.name))
                ok = isinstance(event, ParamSetConfirmed)
                change = {"link_id": key[0], "sysid": key[1], "name": event.name,
                          "previous": event.previous if ok else None,
                          "value": event.value, "ok": ok,
                          "reason": "" if ok else event.reason}
                if not ok:
                    change["requested"] = event.requested
                for c in reversed(self.param_changes):  # the latest write of this name
                    if (c["link_id"], c["sysid"], c["name"]) == (*key, event.name):
                        change["previous"] = c["previous"]
                        c.update(change)
                        break
                (log.info if ok else log.warning)(
                    "link %d sysid %d: %s %s", *key, event.name,
                    f"set to {event.value:g}" if ok else f"NOT set: {event.reason}")
        elif isinstance(event, StatusText):
            text = event.text.strip()
            # ArduPilot AP_Arming::check_failed: "PreArm: ..." / "Arm: ..."; PX4 commander:
            # "Arming denied: ...", "Preflight Fail: ...".
            low = text.lower()
            # ArduPilot events.cpp "Failsafe" texts (e.g. "GCS Failsafe"), PX4 commander
            # "Failsafe activated: ..." / "... failsafe ...": shown to the operator as they come.
            if "failsafe" in low or "fail-safe" in low:
                self.failsafe_texts.append((event.t_s, key, text))
            if text.startswith(("PreArm", "Arm:", "Arming denied", "Preflight Fail")):
                old = self.prearm.get(key)
                self.prearm[key] = (event.t_s, text)
                if (old is None or old[1] != text) and self.phase in ("launch", "run"):
                    log.warning("link %d sysid %d not ready to arm: %s", *key, text)
        elif isinstance(event, (CommandFailed, CommandTimedOut)):
            self.counters["command_failures"] += 1
            row = self._rows.get(self.fleet.index_of(*key)) if key in self._known else None
            refused_arm = (isinstance(event, CommandFailed)
                           and event.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM
                           and event.result in (mavlink.MAV_RESULT_FAILED,
                                                mavlink.MAV_RESULT_TEMPORARILY_REJECTED,
                                                mavlink.MAV_RESULT_DENIED))
            if row is not None:
                if refused_arm:
                    # Not ready (EKF/GPS converging): ask again at a steady pace, no back-off
                    # (ArduPilot GCS_Common.cpp handle_command_component_arm_disarm answers
                    # MAV_RESULT_FAILED; PX4 Commander.cpp TEMPORARILY_REJECTED).
                    row.not_ready_s = event.t_s
                    row.refused_attempt = row.attempt
                    if row.failed_attempt == row.attempt:  # its take-off failed first: uncount
                        row.failures = max(0, row.failures - 1)
                        row.failed_attempt = -1
                    row.next_action_s = event.t_s + self.config.prearm_retry_s
                elif row.failed_attempt != row.attempt and row.refused_attempt != row.attempt:
                    row.failed_attempt = row.attempt
                    row.failures += 1
                    # Back off: the next attempt waits action_retry_s x 2^(failures-1), capped.
                    backoff = min(self.config.action_retry_s * 2 ** (row.failures - 1),
                                  self.config.max_backoff_s)
                    row.next_action_s = max(row.next_action_s, event.t_s + backoff)
                row.takeoff_s = -math.inf  # the take-off is not under way: the back-off rules
            log.info("link %d sysid %d: command %d %s", event.link_id, event.sysid,
                     event.command, type(event).__name__)
        elif isinstance(event, VehicleLost):
            self.counters["lost"] += 1
        elif isinstance(event, VehicleRecovered):
            self.counters["recovered"] += 1
            row = self._rows.get(self.fleet.index_of(*key))
            if row is not None:
                row.next_action_s = -math.inf  # act on it at the next poll

    # ------------------------------------------------------------------ operator actions

    def operator_command(self, action: str, vid: tuple[int, int] | None, now_s: float,
                         source: str = "") -> list[OperatorAction]:
        """An operator's request for one vehicle ``(link_id, sysid)`` or, with ``vid=None``, for
        every vehicle heard. Goes through the station's normal command path (acks, retries,
        events, .tlog); returns what was done, one :class:`OperatorAction` per vehicle."""
        if action not in OPERATOR_ACTIONS:
            raise ValueError(f"unknown action {action!r}; valid: {', '.join(OPERATOR_ACTIONS)}")
        snap = self.fleet.snapshot(now_s)
        if vid is None:
            rows = [i for i in range(snap.n_vehicles) if not snap.lost[i]]
        else:
            if tuple(vid) not in self._known:
                raise UnknownVehicle(f"no vehicle link {vid[0]} sysid {vid[1]}")
            rows = [self.fleet.index_of(*vid)]
        out = []
        for i in rows:
            v = self._vid(snap, i)
            result = self._operator_act(action, snap, i, v, now_s)
            rec = OperatorAction(now_s, action, v[0], v[1], source, result)
            self.actions.append(rec)
            log.warning("operator %s: %s link %d sysid %d -> %s", source or "?", action, *v, result)
            if self.on_action is not None:
                self.on_action(rec)
            out.append(rec)
        return out

    def _operator_act(self, action: str, snap: FleetSnapshot, i: int, vid: tuple[int, int],
                      now_s: float) -> str:
        if action == "rejoin":
            if self.released.pop(vid, None) is None:
                return "was not released"
            row = self._rows.setdefault(i, _Row())
            row.next_action_s = -math.inf  # reclaimed at the next poll like a recovered vehicle
            return "rejoined"
        self.released[vid] = action
        try:
            if action == "hold":
                if not snap.has_position[i]:
                    return "released (no position yet: holds its last target)"
                self._hold(snap, [i], now_s)
                return "sent"
            if action in ("rtl", "land"):
                self.station.clear_position_target(vid, now_s)
                (self.station.rtl if action == "rtl" else self.station.land)(vid, now_s)
                return "sent"
        except (LinkUsageError, UnknownVehicle, ValueError) as exc:
            return f"not sent: {exc}"
        return "released"

    def interrupt(self, action: str, now_s: float) -> None:
        """The operator stopped the flight (Ctrl-C): ``end`` -> the mission's end action (RTL or
        LAND), else ``hold`` / ``rtl`` / ``land`` for every vehicle heard; planning stops."""
        self.interrupted = action
        if action == "end":
            if self.phase in ("discover", "audit", "refused"):
                self._enter("done", now_s)  # nothing was launched: nothing to tell anyone
            else:
                self.begin_end(now_s)
            return
        self.operator_command(action, None, now_s, source="interrupt")
        self._enter("done", now_s)

    def interrupt_report(self, now_s: float) -> list[tuple[tuple[int, int], str, bool]]:
        """After :meth:`interrupt`: per vehicle ``(vid, what it was told and what it does now,
        obeying)`` for people."""
        snap = self.fleet.snapshot(now_s)
        out = []
        for i in range(snap.n_vehicles):
            vid = self._vid(snap, i)
            adapter = adapter_for(int(snap.autopilot[i]))
            mode, armed = snap.mode[i], bool(snap.armed[i])
            action = self.interrupted or "end"
            if action == "end":
                action = self.config.end  # the mission's end action: "rtl" or "land"
            if snap.lost[i]:
                out.append((vid, f"not heard (lost or out of range; last mode {mode}): its own "
                                 "link-loss failsafe decides", False))
                continue
            if not armed:
                out.append((vid, f"on the ground ({mode})", True))
                continue
            want = {"rtl": (adapter.rtl_mode, adapter.land_mode), "land": (adapter.land_mode,),
                    "hold": (adapter.guided_mode,)}.get(action, ())
            ok = mode in want
            told = {"rtl": "RTL", "land": "LAND", "hold": "HOLD where it is"}.get(action, action)
            out.append((vid, f"told {told}; now {mode}" if ok else
                        f"told {told}; no confirmation yet (mode {mode}): if the station is "
                        "gone, its link-loss failsafe acts", ok))
        return out

    # ------------------------------------------------------------------ timing

    def next_poll_s(self, now_s: float) -> float:
        return min(now_s + self.config.poll_period_s, self._next_tick_s)

    def t_mission_s(self, now_s: float) -> float:
        return 0.0 if self.mission_t0_s is None else max(0.0, now_s - self.mission_t0_s)

    @property
    def finished(self) -> bool:
        return self.phase in ("done", "refused")

    def _enter(self, phase: str, now_s: float) -> None:
        log.info("phase %s -> %s at t=%.1f s", self.phase, phase, now_s)
        self.phase = phase
        self._phase_since_s = now_s

    # ------------------------------------------------------------------ the machine

    def poll(self, now_s: float) -> TickRecord | None:
        """Advance the phases; returns the metrics of a control tick if one ran."""
        cfg = self.config
        snap = self.fleet.snapshot(now_s)
        for i in range(snap.n_vehicles):
            self._rows.setdefault(i, _Row())
        if self.phase == "discover":
            n = snap.n_vehicles
            waited = now_s - self._phase_since_s
            if n and ((cfg.expected_vehicles is not None and n >= cfg.expected_vehicles)
                      or (cfg.expected_vehicles is None
                          and now_s - self._last_discovery_s >= cfg.discover_settle_s)
                      or waited >= cfg.discover_timeout_s):
                waiting = self.live_tasks.waiting_for() if self.live_tasks is not None else ()
                if not waiting:
                    self._start_audit(snap, now_s)
                elif waited >= cfg.discover_timeout_s + cfg.task_wait_timeout_s:
                    self.refusal = ("no position from live task tracker(s) sysid "
                                    f"{', '.join(map(str, waiting))} after {waited:.0f} s")
                    log.warning("refusing to launch: %s", self.refusal)
                    self._enter("refused", now_s)
        if self.phase == "audit":
            self._poll_audit(snap, now_s)
        if self.phase == "launch":
            self._poll_launch(snap, now_s)
        record = None
        if self.phase == "run":
            if now_s >= self._next_tick_s:
                record = self._control_tick(snap, now_s)
                self._next_tick_s += cfg.control_period_s
                if self._next_tick_s <= now_s:
                    self._next_tick_s = now_s + cfg.control_period_s
            self._reclaim(snap, now_s)
            if now_s - self.mission_t0_s >= cfg.duration_s - 1e-9 and self._t_step >= 1:
                self.begin_end(now_s)
        if self.phase == "end":
            self._poll_end(snap, now_s)
        return record

    # ------------------------------------------------------------------ audit

    def _vid(self, snap: FleetSnapshot, i: int) -> tuple[int, int]:
        return int(snap.link_id[i]), int(snap.sysid_of_index[i])

    def _in_plan(self, snap: FleetSnapshot) -> np.ndarray:
        """(N,) bool: rows not taken out of the plan by an operator action."""
        ok = np.ones(snap.n_vehicles, dtype=bool)
        if self.released:
            for i in range(snap.n_vehicles):
                ok[i] = self._vid(snap, i) not in self.released
        return ok

    def _start_audit(self, snap: FleetSnapshot, now_s: float) -> None:
        log.info("discovered %d vehicle(s)", snap.n_vehicles)
        if not self.config.audit:
            self._start_launch(snap, now_s)
            return
        self._enter("audit", now_s)
        for i in range(snap.n_vehicles):
            vid = self._vid(snap, i)
            names = list(audit_mod.params_still_needed(int(snap.autopilot[i]), {}))
            if self._limits_wanted():
                names += [n for n in limits_mod.LIMIT_PARAMS.get(int(snap.autopilot[i]), ())
                          if n not in names]
            for name in names:
                self._params_pending.add((*vid, name))
                self.station.request_param(vid, name, now_s)

    def _poll_audit(self, snap: FleetSnapshot, now_s: float) -> None:
        in_time = now_s - self._phase_since_s < self.config.audit_timeout_s
        if self._params_pending and in_time:
            return
        if in_time and self._audit_round < self.config.audit_rounds:
            # Another round for whatever timed out (a loaded link, a vehicle still booting);
            # names a firmware does not have (the other GCS-sysid spelling) just time out again.
            self._audit_round += 1
            for i in range(snap.n_vehicles):
                vid = self._vid(snap, i)
                got = self._params.get(vid, {})
                for name in audit_mod.params_still_needed(int(snap.autopilot[i]), got):
                    if name not in audit_mod.OPTIONAL_PARAMS and not snap.lost[i]:
                        self._params_pending.add((*vid, name))
                        self.station.request_param(vid, name, now_s)
            if self._params_pending:
                return
        vehicles = {self._vid(snap, i): (int(snap.autopilot[i]),
                                         self._params.get(self._vid(snap, i), {}))
                    for i in range(snap.n_vehicles)}
        if self.config.apply_failsafes:
            if self._fixes_sent_s is None:
                if self._send_fixes(vehicles, now_s):
                    return
            elif self._sets_pending \
                    and now_s - self._fixes_sent_s < self.config.audit_timeout_s:
                return  # the link ends every set with Confirmed or Failed; this is a backstop
        report = audit_mod.audit_fleet(vehicles, self.gcs_sysid,
                                       override=self.config.override_audit)
        self.audit_report = report
        if not report.cleared_to_fly:
            log.warning("pre-flight audit refused the flight:\n%s", report.summary())
            self.refusal = "the pre-flight audit found unsafe lost-link settings"
            self._enter("refused", now_s)
            return
        if report.overridden:
            log.warning("pre-flight audit OVERRIDDEN:\n%s", report.summary())
        if self._limits_wanted():
            if self._limits_sent_s is None:
                if self._send_limits(vehicles, now_s):
                    return
            elif self._sets_pending \
                    and now_s - self._limits_sent_s < self.config.audit_timeout_s:
                return
        self._start_launch(snap, now_s)

    def _limits_wanted(self) -> bool:
        return self.config.set_limits and self.config.max_speed_m_s is not None

    def _send_limits(self, vehicles, now_s: float) -> bool:
        """PARAM_SET the mission's speed / climb limits where a vehicle differs; True if any
        write was sent (each is confirmed by its PARAM_VALUE echo, ``param_changes``)."""
        cfg = self.config
        self._limits_sent_s = now_s
        climb = cfg.climb_rate_m_s if cfg.climb_rate_m_s is not None else math.inf
        for vid, (autopilot, params) in sorted(vehicles.items()):
            wanted = limits_mod.LIMIT_PARAMS.get(autopilot, ())
            missing = [n for n in wanted if n not in params]
            if missing:
                self.limit_warnings.append(
                    f"link {vid[0]} sysid {vid[1]}: could not read {', '.join(missing)}: the "
                    "mission's speed limits are not enforced by this vehicle")
                log.warning("%s", self.limit_warnings[-1])
            if not math.isfinite(climb):
                params = {k: v for k, v in params.items() if k != "WPNAV_SPEED_UP"
                          and k != "MPC_Z_VEL_MAX_UP"}
            for name, value in limits_mod.limit_writes(autopilot, params, cfg.max_speed_m_s,
                                                       climb if math.isfinite(climb) else 1.0):
                self._set_param(vid, name, value, params.get(name), "limit", now_s)
        return bool(self._sets_pending)

    def _set_param(self, vid: tuple[int, int], name: str, value: float, previous: float | None,
                   purpose: str, now_s: float) -> bool:
        ptype = self._param_types.get(vid, {}).get(name)
        if ptype is None:
            return False
        try:
            self.station.set_param(vid, name, value, ptype, now_s, previous=previous)
        except (UnknownVehicle, ValueError) as exc:
            log.warning("link %d sysid %d: cannot set %s: %s", *vid, name, exc)
            return False
        self._sets_pending.add((*vid, name))
        self.param_changes.append({"link_id": vid[0], "sysid": vid[1], "name": name,
                                   "previous": previous, "value": value, "ok": None,
                                   "reason": "pending", "purpose": purpose})
        log.info("link %d sysid %d: setting %s %g -> %g (%s)", *vid, name,
                 math.nan if previous is None else previous, value, purpose)
        return True

    def _send_fixes(self, vehicles, now_s: float) -> bool:
        """PARAM_SET every fixable blocking finding; True if any write was sent."""
        before = audit_mod.audit_fleet(vehicles, self.gcs_sysid)
        self._fixes_sent_s = now_s
        for va in before.unsafe:
            vid = (va.link_id, va.sysid)
            autopilot, params = vehicles[vid]
            for name, value in audit_mod.failsafe_fixes(autopilot, params, self.gcs_sysid):
                self._set_param(vid, name, value, params.get(name), "failsafe", now_s)
        if self._sets_pending:
            self.initial_audit_report = before
            return True
        return False

    # ------------------------------------------------------------------ launch

    def not_ready(self, snap: FleetSnapshot, now_s: float) -> list[tuple[int, int]]:
        """Heard, unarmed vehicles that refused to arm recently (still converging)."""
        out = []
        for i in range(snap.n_vehicles):
            row = self._rows.get(i)
            if row is None or snap.lost[i] or snap.armed[i]:
                continue
            if now_s - row.not_ready_s <= 2 * self.config.prearm_retry_s + 2.0:
                out.append(self._vid(snap, i))
        return out

    def _start_launch(self, snap: FleetSnapshot, now_s: float) -> None:
        self._enter("launch", now_s)
        self._launch_since_s = now_s
        rows = list(range(snap.n_vehicles))
        k = self.config.wave_size
        self._waves = [rows[j:j + k] for j in range(0, len(rows), k)]
        self._wave = 0
        self._wave_since_s = now_s

    def _alt_above_home_m(self, snap: FleetSnapshot) -> np.ndarray:
        # Mission NED down is relative to the mission origin's altitude; home AMSL per vehicle.
        alt_amsl = self.fleet.origin.alt_amsl_m - snap.pos_ned_m[:, 2]
        return alt_amsl - snap.home_amsl_m

    def _poll_launch(self, snap: FleetSnapshot, now_s: float) -> None:
        cfg = self.config
        alt = self._alt_above_home_m(snap)
        heard = ~snap.lost
        fin = np.isfinite(alt)
        airborne = heard & snap.armed & fin & (alt > cfg.airborne_alt_m)
        if self._wave < len(self._waves):
            wave = [i for i in self._waves[self._wave] if i < snap.n_vehicles]
            live = int(heard[wave].sum()) if wave else 0
            up = int(airborne[wave].sum()) if wave else 0
            if up >= cfg.wave_airborne_frac * max(1, live) \
                    or now_s - self._wave_since_s >= cfg.wave_timeout_s:
                log.info("wave %d/%d: %d/%d airborne at t=%.1f s", self._wave + 1,
                         len(self._waves), up, len(wave), now_s)
                self._wave += 1
                self._wave_since_s = now_s
        # Every started wave (and late discoveries): launch / keep flying.
        in_plan = self._in_plan(snap)
        for w in self._waves[:self._wave + 1]:
            for i in w:
                if i < snap.n_vehicles and heard[i] and in_plan[i]:
                    self._drive(snap, i, alt, now_s)
        if self._wave >= len(self._waves):
            rows = np.flatnonzero(heard)
            target = layer_alt_m(rows, self.control)
            climbed = fin[rows] & (np.where(fin[rows], alt[rows], 0.0)
                                   >= cfg.climbed_alt_frac * target)
            waiting = self.not_ready(snap, now_s)
            in_time = now_s - self._launch_since_s < cfg.launch_timeout_s
            if waiting and in_time:
                # Vehicles still refusing to arm (SITL: EKF/GPS ~40 s after boot): the climb
                # timeout counts from when the last of them was still not ready.
                self._wave_since_s = now_s
            elif waiting and not self._launch_gave_up:
                self._launch_gave_up = True
                log.warning("launch: %d vehicle(s) still not ready to arm after %.0f s: %s",
                            len(waiting), cfg.launch_timeout_s,
                            "; ".join(f"link {l} sysid {s}: {self.prearm.get((l, s), (0, '?'))[1]}"
                                      for l, s in waiting))
            if climbed.sum() >= cfg.wave_climbed_frac * max(1, len(rows)) \
                    or now_s - self._wave_since_s >= cfg.wave_timeout_s:
                log.info("launch complete at t=%.1f s: %d/%d climbed", now_s,
                         int(climbed.sum()), len(rows))
                self._start_run(now_s)

    def _start_run(self, now_s: float) -> None:
        self._enter("run", now_s)
        self.mission_t0_s = now_s
        self._next_tick_s = now_s
        self._t_step = 0

    def _drive(self, snap: FleetSnapshot, i: int, alt: np.ndarray, now_s: float,
               hold_position: bool = False) -> bool:
        """Bring vehicle ``i`` to "armed, airborne, guided"; returns True if it already is."""
        row = self._rows.setdefault(i, _Row())
        adapter = adapter_for(int(snap.autopilot[i]))
        guided = adapter.is_guided(int(snap.custom_mode[i]))
        armed = bool(snap.armed[i])
        airborne = bool(np.isfinite(alt[i]) and alt[i] > self.config.airborne_alt_m and armed)
        if airborne:
            row.flew = True
        if guided and airborne:
            row.failures = 0
            row.not_ready_s = -math.inf
            if row.reclaiming:
                row.reclaiming = False
                row.reclaims += 1
                self.reclaimed.append((now_s, *self._vid(snap, i)))
                log.info("reclaimed link %d sysid %d", *self._vid(snap, i))
            return True
        if armed and row.armed_seen_s < row.takeoff_s:
            row.armed_seen_s = now_s
        if now_s < row.next_action_s:
            return False
        # Taking off: leave it alone (no second GUIDED/OFFBOARD, arm or take-off) for
        # takeoff_grace_s after the command, and again after it was first seen armed (PX4 arms
        # only after more than a second of setpoint streaming, then ramps the climb up over
        # MPC_TKO_RAMP_T: its 2 m can take longer than the grace counted from the command).
        if not airborne and (now_s - row.takeoff_s < self.config.takeoff_grace_s
                             or (armed and guided and row.armed_seen_s >= row.takeoff_s
                                 and now_s - row.armed_seen_s < self.config.takeoff_grace_s)):
            return False
        vid = self._vid(snap, i)
        target_alt = float(layer_alt_m([i], self.control)[0])
        row.next_action_s = now_s + self.config.action_retry_s
        row.attempt += 1
        try:
            if airborne:
                # Reclaim in flight: hold where it is (at its layer), then the guided mode.
                if snap.has_position[i]:
                    self._hold(snap, [i], now_s)
                self.station.engage_guided(vid, now_s)
                self.counters["reclaim_attempts"] += 1
                row.reclaiming = True
                log.info("reclaiming link %d sysid %d from %s", *vid, snap.mode[i])
                return False
            if row.flew:
                self.counters["relaunches"] += 1  # it flew, landed (e.g. RTL) and goes again
                row.flew = False
            row.launched = True
            row.takeoff_s = now_s
            if adapter.takeoff_by_offboard_climb:
                if not snap.has_position[i]:
                    return False
                self.station.takeoff(vid, target_alt, now_s)  # stream, OFFBOARD, arm (PX4)
            else:
                if not guided:
                    self.station.engage_guided(vid, now_s)
                if not armed:
                    self.station.arm(vid, now_s)
                self.station.takeoff(vid, target_alt, now_s)
        except (LinkUsageError, UnknownVehicle) as exc:
            log.info("link %d sysid %d: %s", *vid, exc)
        except ValueError as exc:  # e.g. unknown autopilot: nothing we can command
            log.warning("link %d sysid %d: %s", *vid, exc)
        return False

    def _hold(self, snap: FleetSnapshot, rows, now_s: float) -> None:
        rows = np.asarray(rows, dtype=int)
        target = np.column_stack([snap.pos_ned_m[rows, :2], -layer_alt_m(rows, self.control)])
        self._send_targets(snap, rows, target, now_s)

    def _send_targets(self, snap: FleetSnapshot, rows: np.ndarray, target_ned_m: np.ndarray,
                      now_s: float) -> int:
        if len(rows) == 0:
            return 0
        lat, lon, alt_rel = self.fleet.targets_to_global(rows, target_ned_m)
        sent = 0
        for k, i in enumerate(rows.tolist()):  # the codec edge: one frame per vehicle
            if not math.isfinite(alt_rel[k]):
                continue
            self.station.set_position_target(self._vid(snap, i), float(lat[k]), float(lon[k]),
                                             float(alt_rel[k]), now_s)
            sent += 1
        return sent

    # ------------------------------------------------------------------ run

    def _control_tick(self, snap: FleetSnapshot, now_s: float) -> TickRecord:
        alt = self._alt_above_home_m(snap)
        heard = ~snap.lost
        airborne = heard & snap.armed & np.isfinite(alt) & (alt > self.config.airborne_alt_m)
        airborne &= self._in_plan(snap)  # released vehicles are neither planned nor relays
        t_m = self.t_mission_s(now_s)
        task_pos = np.asarray(self.task_pos_fn(t_m), dtype=float).reshape(-1, 2)
        result = tick(snap.pos_ned_m, airborne, heard, task_pos, self.planner, self._t_step,
                      self.control)
        self._send_targets(snap, result.rows, result.target_ned_m, now_s)
        ne = np.where(snap.has_position[:, None], snap.pos_ned_m[:, :2], np.inf)
        covered = tasks_connected(task_pos, ne, heard & snap.has_position,
                                  self.config.radio_range_m)
        self._connected.append(covered)
        series = uptime_series(np.asarray(self._connected))
        adapters = [adapter_for(int(a)) for a in snap.autopilot]
        guided = sum(ad.is_guided(int(m)) for ad, m in zip(adapters, snap.custom_mode))
        rec = TickRecord(
            t_s=now_s, t_mission_s=t_m, t_step=self._t_step, fleet=snap.n_vehicles,
            networked=int(snap.networked.sum()), planned=len(result.rows),
            lost=int(snap.lost.sum()), returning=int(snap.returning.sum()), guided=int(guided),
            tasks_covered=int(covered.sum()), n_tasks=len(task_pos), tu1_so_far=series.tu1,
            tu2_so_far=series.tu2, plan_iterations=result.info.get("iterations"))
        self.records.append(rec)
        self._t_step += 1
        return rec

    def _reclaim(self, snap: FleetSnapshot, now_s: float) -> None:
        alt = self._alt_above_home_m(snap)
        for i in np.flatnonzero(~snap.lost & self._in_plan(snap)).tolist():
            self._drive(snap, i, alt, now_s)

    def station_tu(self) -> tuple[float, float]:
        """(TU1, TU2) over the run's ticks, from what the station saw."""
        if not self._connected:
            return 0.0, 0.0
        s = uptime_series(np.asarray(self._connected))
        return s.tu1, s.tu2

    # ------------------------------------------------------------------ end

    def begin_end(self, now_s: float) -> None:
        """Stop planning and send every vehicle home (RTL) or down (LAND)."""
        if self.phase in ("end", "done", "refused"):
            return
        self._enter("end", now_s)
        self.end_t0_s = now_s
        for row in self._rows.values():
            row.next_action_s = -math.inf

    def _restore(self, now_s: float) -> bool:
        """Write back the previous value of every parameter the station changed (once); True
        while the echoes are awaited."""
        if self._restore_sent_s is None:
            self._restore_sent_s = now_s
            done: set[tuple[int, int, str]] = set()
            for c in list(reversed(self.param_changes)):
                key = (c["link_id"], c["sysid"], c["name"])
                if key in done or c.get("purpose") == "restore" or not c.get("ok") \
                        or c.get("previous") is None:
                    continue
                done.add(key)
                self._set_param(key[:2], key[2], float(c["previous"]), float(c["value"]),
                                "restore", now_s)
        return bool(self._sets_pending) and now_s - self._restore_sent_s < 10.0

    def _poll_end(self, snap: FleetSnapshot, now_s: float) -> None:
        """Send the end command until obeyed; done once every vehicle heard is on the ground
        (disarmed: ArduCopter and PX4 both disarm after landing at the end of RTL / LAND), or at
        ``end_timeout_s`` (:attr:`end_status` then says how many were still in the air)."""
        airborne = 0
        for i in np.flatnonzero(~snap.lost).tolist():
            if not snap.armed[i]:
                continue  # on the ground
            airborne += 1
            adapter = adapter_for(int(snap.autopilot[i]))
            mode = snap.mode[i]
            vid = self._vid(snap, i)
            # Obeying (or already coming down on its own, e.g. a battery failsafe LAND), or an
            # operator sent it home / down: the vehicle finishes on its own.
            if mode in (adapter.rtl_mode, adapter.land_mode) \
                    or self.released.get(vid) in ("rtl", "land"):
                continue
            row = self._rows.setdefault(i, _Row())
            if now_s < row.next_action_s:
                continue
            row.next_action_s = now_s + self.config.action_retry_s
            try:
                self.station.clear_position_target(vid, now_s)
                if self.config.end == "rtl":
                    self.station.rtl(vid, now_s)
                else:
                    self.station.land(vid, now_s)
            except (LinkUsageError, UnknownVehicle, ValueError) as exc:
                log.info("link %d sysid %d: %s", *vid, exc)
        heard = int((~snap.lost).sum())
        self.end_status = {"on_ground": heard - airborne, "in_air": airborne,
                           "not_heard": int(snap.lost.sum())}
        if airborne == 0 or now_s - self._phase_since_s >= self.config.end_timeout_s:
            if self.config.restore_params and self._restore(now_s):
                return  # wait for the echoes (or restore_timeout_s)
            if airborne:
                log.info("end: %d vehicle(s) still in the air after %.0f s (returning on "
                         "their own)", airborne, now_s - self._phase_since_s)
            self._enter("done", now_s)

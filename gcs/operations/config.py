"""The operator's configuration and records: what it is told (:class:`OperationsConfig`) and what
it reports (:class:`TickRecord`, :class:`OperatorAction`), plus its per-vehicle bookkeeping.

Plain data, split from the machine (:mod:`gcs.operations.operator`) so each step module imports
them without importing the operator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

__all__ = [
    "OperationsConfig",
    "TickRecord",
    "OPERATOR_ACTIONS",
    "OperatorAction",
    "OVERRIDE",
    "OVERRIDE_REFUSED",
    "override_label",
]


@dataclass(frozen=True)
class OperationsConfig:
    """Sequencing and timing. Times are station-core seconds (the vehicles' clock under
    speed-up); units in the names."""

    expected_vehicles: int | None = None
    """Start as soon as this many vehicles are discovered (None: wait ``discover_settle_s``)."""
    discover_timeout_s: float = 30.0
    """Start with the vehicles heard after this long; refuse (``Operator.refusal``) if none was.
    ``math.inf``: wait for the first vehicle for ever."""
    discover_settle_s: float = 3.0
    audit: bool = True
    override_audit: bool = False
    audit_timeout_s: float = 60.0
    """The audit's reads give up this long after the audit began or after the last parameter
    answered, whichever is later; writes are confirmed within this of being sent."""
    audit_rounds: int = 3
    """Parameter reads that timed out are requested again, up to this many rounds in all."""
    apply_failsafes: bool = False
    """Fix fixable blocking audit findings by PARAM_SET (:func:`gcs.audit.failsafe_fixes`:
    ArduPilot FS_GCS_ENABLE, the GCS sysid; PX4 NAV_DLL_ACT, NAV_RCL_ACT, COM_OBL_RC_ACT,
    COM_OBL_ACT, COM_DLL_EXCEPT) before re-auditing. No failsafe parameter is ever written
    without it (the mission's speed limits are, see ``set_limits``)."""
    battery_audit: str = "off"
    """Battery failsafes in the audit (:func:`gcs.audit.audit_battery`): ``off`` (not read),
    ``warn`` (a mission without batteries on real firmware: reported, never refused) or
    ``require`` (a mission with batteries: a drone must return at the firmware's first battery
    action). With ``apply_failsafes`` the low action is written as return to launch."""
    battery_low_frac: float | None = None
    """The mission's low level (``endurance.battery.low_frac``), compared with the firmware's."""
    rtl_min_alt_m: float | None = None
    """Over terrain, the least altitude above home at which the firmware's RTL may fly home
    (:func:`gcs.audit.audit_rtl_altitude`; with ``apply_failsafes`` written). None: a flat earth,
    not audited."""
    max_speed_m_s: float | None = None
    """The mission's horizontal speed limit; with ``set_limits`` written into each vehicle's own
    parameters at launch (:mod:`gcs.limits`). None: the firmware's limits are left alone."""
    climb_rate_m_s: float | None = None
    descent_rate_m_s: float | None = None
    """The mission's descent speed, m/s, written with the other limits (:mod:`gcs.limits`);
    None: the firmware's own is left alone."""
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
    liftoff_alt_m: float = 1.0
    """Armed in GUIDED above home by more than this (but not yet airborne) = off the ground: a
    take-off that stopped short. The launch then climbs it with a position target instead of a
    second NAV_TAKEOFF, which ArduCopter refuses once off the ground (docs/design/mavlink.md §3)."""
    radio_range_m: float = math.inf
    """For "tasks covered as the station sees them" (a task within range of a networked vehicle)."""
    poll_period_s: float = 0.25
    task_wait_timeout_s: float = 120.0
    """Live tasks (crew trackers): after discovery, wait at most this long for every tracker's
    first position before refusing to launch (a task the station cannot see cannot be served)."""

    def __post_init__(self) -> None:
        if self.end not in ("rtl", "land"):
            raise ValueError(f"end must be 'rtl' or 'land', got {self.end!r}")
        if self.battery_audit not in ("off", "warn", "require"):
            raise ValueError(
                f"battery_audit must be off, warn or require, got {self.battery_audit!r}"
            )
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

    def row(self) -> dict[str, Any]:
        return dict(self.__dict__)


#: What an operator may ask of one vehicle (or of all): ``hold`` (leave the plan, hover where it
#: is at its layer, still in GUIDED/OFFBOARD so the link failsafes still apply), ``rtl``, ``land``
#: (leave the plan, the firmware's RTL / LAND mode), ``release`` (leave the plan, keep the last
#: target) and ``rejoin`` (back into the plan: reclaimed like a vehicle back from a failsafe);
#: ``confirm_swap``: the ground crew changed the battery of the vehicle on a pad (relay rotation,
#: docs/design/endurance.md §8; one vehicle at a time, never "all").
OPERATOR_ACTIONS = ("hold", "rtl", "land", "release", "rejoin", "confirm_swap")

#: The records of a forwarded client's override (``phireman fly --forward-overrides``;
#: :meth:`gcs.operations.Operator.forwarded_override`), never asked by the station's operator:
#: ``override`` (honoured: the vehicle left the plan, as held, until ``rejoin``) and
#: ``override-refused`` (not passed on: the vehicle stays in the plan).
OVERRIDE = "override"
OVERRIDE_REFUSED = "override-refused"


def override_label(source: str, result: str) -> str:
    """What the live page says of a vehicle a forwarded client took (the record's ``source``
    and ``result``): ``taken by 127.0.0.1:14550 sysid 254: SET_MODE RTL (t+42 s)``."""
    return f"taken by {source}: {result}"


@dataclass(frozen=True)
class OperatorAction:
    """One operator request, as recorded in ``events.jsonl`` (who asked, what, for whom)."""

    t_s: float
    action: str
    link_id: int
    sysid: int
    source: str
    """Where it came from (e.g. ``web 127.0.0.1``, ``cli``; a forwarded client's address and
    sysid for :data:`OVERRIDE` / :data:`OVERRIDE_REFUSED`)."""
    result: str
    """``sent``, ``released``, ``rejoined``, ``swap confirmed ...`` or why nothing was done; for
    an override, the client's command and when (``SET_MODE RTL (t+42 s)``)."""


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
    climb_sent: bool = False
    """The last attempt climbed it by a position target (a take-off stopped short); the next one
    sends NAV_TAKEOFF again, so a vehicle whose altitude reads high on the ground is not stuck."""

"""Events the station core emits: frozen, validated, named as past-tense facts (docs/design/architecture.md §2.2).

Every event carries the vehicle identity ``(link_id, sysid)`` and the core time ``t_s`` at which the
core learned the fact. The constructors validate, so a NaN or an out-of-range sysid can never
become an event.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = [
    "Event",
    "VehicleDiscovered",
    "VehicleLost",
    "VehicleRecovered",
    "ModeChanged",
    "ArmedChanged",
    "TelemetryReceived",
    "CommandAcked",
    "CommandInProgress",
    "CommandFailed",
    "CommandTimedOut",
    "ParamReceived",
    "ParamTimedOut",
    "ParamSetConfirmed",
    "ParamSetFailed",
    "StatusText",
    "BatteryReceived",
    "VehicleRebooted",
    "GpsReceived",
    "SensorsReceived",
    "EstimatorReceived",
    "RadioStatusReceived",
    "HEALTH_EVENTS",
    "HomePositionReceived",
    "TaskPositionReceived",
    "LinkEvent",
    "LinkUp",
    "LinkDown",
]


def _finite(name: str, value: float) -> None:
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")


def _all_finite(*values: object) -> bool:
    """Would :func:`_finite` accept every value? (One call for the common case; the caller
    then runs its :func:`_finite` checks, in their order, only to raise the right error.)"""
    isfinite = math.isfinite
    for value in values:
        if not isinstance(value, (int, float)) or not isfinite(value):
            return False
    return True


@dataclass(frozen=True)
class Event:
    link_id: int
    """Which link (station core) the vehicle was heard on."""
    sysid: int
    """MAVLink system id of the vehicle, 1..255."""
    t_s: float
    """Core time of the fact, seconds."""

    def __post_init__(self) -> None:
        if not isinstance(self.sysid, int) or not 1 <= self.sysid <= 255:
            raise ValueError(f"sysid must be an int in 1..255, got {self.sysid!r}")
        if not isinstance(self.link_id, int) or self.link_id < 0:
            raise ValueError(f"link_id must be a non-negative int, got {self.link_id!r}")
        _finite("t_s", self.t_s)


@dataclass(frozen=True)
class VehicleDiscovered(Event):
    autopilot: int = 0
    """HEARTBEAT.autopilot (MAV_AUTOPILOT: 3 ArduPilot, 12 PX4)."""
    vehicle_type: int = 0
    """HEARTBEAT.type (MAV_TYPE)."""
    custom_mode: int = 0
    mode: str = ""
    armed: bool = False


@dataclass(frozen=True)
class VehicleLost(Event):
    last_heartbeat_s: float = 0.0
    """Core time of the last heartbeat heard."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _finite("last_heartbeat_s", self.last_heartbeat_s)


@dataclass(frozen=True)
class VehicleRecovered(Event):
    silent_s: float = 0.0
    """How long the vehicle was silent, seconds."""
    custom_mode: int = 0
    mode: str = ""


@dataclass(frozen=True)
class ModeChanged(Event):
    custom_mode: int = 0
    mode: str = ""
    previous_mode: str = ""


@dataclass(frozen=True)
class ArmedChanged(Event):
    armed: bool = False


@dataclass(frozen=True)
class TelemetryReceived(Event):
    """A GLOBAL_POSITION_INT, converted to SI."""

    lat_deg: float = 0.0
    lon_deg: float = 0.0
    alt_amsl_m: float = 0.0
    rel_alt_m: float = 0.0
    """Altitude above home, metres (so home AMSL = alt_amsl_m - rel_alt_m)."""
    vel_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_rad: float | None = None
    """Heading, rad in (-pi, pi], 0 = north; None if the vehicle does not know it."""
    time_boot_s: float = 0.0
    """The vehicle's own clock (GLOBAL_POSITION_INT.time_boot_ms), seconds."""

    def __post_init__(self) -> None:
        super().__post_init__()
        # One GLOBAL_POSITION_INT each: the finite checks at once, one by one only to fail.
        if not _all_finite(
            self.lat_deg, self.lon_deg, self.alt_amsl_m, self.rel_alt_m, self.time_boot_s
        ):
            for name in ("lat_deg", "lon_deg", "alt_amsl_m", "rel_alt_m", "time_boot_s"):
                _finite(name, getattr(self, name))
        if not -90.0 <= self.lat_deg <= 90.0 or not -180.0 <= self.lon_deg <= 180.0:
            raise ValueError(f"lat/lon out of range: {self.lat_deg}, {self.lon_deg}")
        if len(self.vel_ned_m_s) != 3:
            raise ValueError("vel_ned_m_s must have 3 components")
        if not _all_finite(*self.vel_ned_m_s):
            for v in self.vel_ned_m_s:
                _finite("vel_ned_m_s", v)
        if self.yaw_rad is not None:
            _finite("yaw_rad", self.yaw_rad)


@dataclass(frozen=True)
class _GeoPoint(Event):
    """A geodetic point heard from a system (checked finite and on the globe)."""

    lat_deg: float = 0.0
    lon_deg: float = 0.0
    alt_amsl_m: float = 0.0
    """Altitude above mean sea level, metres."""

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("lat_deg", "lon_deg", "alt_amsl_m"):
            _finite(name, getattr(self, name))
        if not -90.0 <= self.lat_deg <= 90.0 or not -180.0 <= self.lon_deg <= 180.0:
            raise ValueError(f"lat/lon out of range: {self.lat_deg}, {self.lon_deg}")


@dataclass(frozen=True)
class HomePositionReceived(_GeoPoint):
    """The vehicle's home (HOME_POSITION, message 242), emitted when first heard and whenever it
    changes (both autopilots reset home when they arm). ``alt_amsl_m`` is the datum of
    GLOBAL_RELATIVE_ALT frames."""


@dataclass(frozen=True)
class TaskPositionReceived(_GeoPoint):
    """A GLOBAL_POSITION_INT from a *task* system (a crew's tracker, a rover), not a vehicle the
    station flies: ``sysid`` is one of ``StationConfig.task_sysids``."""


@dataclass(frozen=True)
class _CommandEvent(Event):
    command: int = 0
    """MAV_CMD id."""
    request_id: int = 0
    """The id returned by the core's send call, to correlate."""


@dataclass(frozen=True)
class CommandAcked(_CommandEvent):
    attempts: int = 1


@dataclass(frozen=True)
class CommandInProgress(_CommandEvent):
    progress: int = 0
    """Percent, 0..100 (255 = unknown)."""


@dataclass(frozen=True)
class CommandFailed(_CommandEvent):
    result: int | None = None
    """MAV_RESULT from COMMAND_ACK, or None if the core gave up for a local reason."""
    reason: str = ""


@dataclass(frozen=True)
class CommandTimedOut(_CommandEvent):
    attempts: int = 0


@dataclass(frozen=True)
class ParamReceived(Event):
    name: str = ""
    value: float = 0.0
    param_type: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.name:
            raise ValueError("param name must not be empty")


@dataclass(frozen=True)
class ParamTimedOut(Event):
    name: str = ""
    attempts: int = 0


@dataclass(frozen=True)
class ParamSetConfirmed(Event):
    """A PARAM_SET echoed back by the vehicle's PARAM_VALUE with the value asked for."""

    name: str = ""
    value: float = 0.0
    previous: float | None = None
    """The value read before the set, if the caller said (for the record)."""
    param_type: int = 0
    attempts: int = 1


@dataclass(frozen=True)
class ParamSetFailed(Event):
    """A PARAM_SET that did not take: no echo after every retry, or the vehicle echoed another
    value (ArduPilot echoes the old value of a write-protected parameter, GCS_Param.cpp)."""

    name: str = ""
    requested: float = 0.0
    value: float | None = None
    """What the vehicle echoed (None: nothing)."""
    reason: str = ""
    attempts: int = 0


#: STATUSTEXT endings that report a failsafe over, in each firmware's words: ArduCopter
#: ArduCopter/events.cpp ``Copter::failsafe_gcs_off_event`` "GCS Failsafe Cleared" and
#: ``failsafe_radio_off_event`` "Radio Failsafe Cleared" (both MAV_SEVERITY_WARNING),
#: ArduCopter/ekf_check.cpp ``failsafe_ekf_off_event`` "EKF Failsafe Cleared" (CRITICAL); PX4
#: src/modules/commander/Commander.cpp ``Commander::dataLinkCheck`` "GCS connection regained"
#: (INFO). The severity cannot tell them from bad news (ArduPilot sends them at WARNING and
#: above), the words can.
_GOOD_NEWS_ENDINGS = ("failsafe cleared", "connection regained")


@dataclass(frozen=True)
class StatusText(Event):
    severity: int = 6
    """MAV_SEVERITY (0 emergency .. 7 debug)."""
    text: str = ""

    @property
    def kind(self) -> str:
        """How to show it: ``"recovered"`` for a failsafe that ended (:data:`_GOOD_NEWS_ENDINGS`,
        whatever its severity), ``"failsafe"`` for a failsafe or anything at WARNING (4) or worse,
        else ``"status"``."""
        low = self.text.strip().lower()
        if low.endswith(_GOOD_NEWS_ENDINGS):
            return "recovered"
        if self.severity <= 4 or "fail" in low:
            return "failsafe"
        return "status"


def _optional_finite(name: str, value: float | None) -> None:
    if value is not None:
        _finite(name, value)


@dataclass(frozen=True)
class BatteryReceived(Event):
    """A battery report (SYS_STATUS or BATTERY_STATUS), converted to SI; None: not reported.

    MAVLink's "unknown" values (``battery_remaining`` -1, ``voltage_battery`` UINT16_MAX,
    ``current_battery`` -1, ``current_consumed`` -1, ``time_remaining`` 0) become None at the
    codec edge (:mod:`gcs.link_discovery`), never a number.
    """

    source: str = "SYS_STATUS"
    """``SYS_STATUS`` or ``BATTERY_STATUS``."""
    remaining_frac: float | None = None
    """Remaining charge, fraction of capacity in [0, 1] (whole percent on the wire)."""
    voltage_v: float | None = None
    current_a: float | None = None
    consumed_mah: float | None = None
    """Charge used since boot, mAh (BATTERY_STATUS ``current_consumed``)."""
    time_remaining_s: float | None = None
    """The autopilot's own estimate (BATTERY_STATUS ``time_remaining``)."""
    charge_state: int = 0
    """MAV_BATTERY_CHARGE_STATE (0 undefined, 1 OK, 2 low, 3 critical, 4 emergency, 5 failed,
    6 unhealthy, 7 charging)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.source not in ("SYS_STATUS", "BATTERY_STATUS"):
            raise ValueError(f"unknown battery source {self.source!r}")
        for name in ("remaining_frac", "voltage_v", "current_a", "consumed_mah"):
            _optional_finite(name, getattr(self, name))
        _optional_finite("time_remaining_s", self.time_remaining_s)
        if self.remaining_frac is not None and not 0.0 <= self.remaining_frac <= 1.0:
            raise ValueError(f"remaining_frac must be in [0, 1], got {self.remaining_frac}")


@dataclass(frozen=True)
class GpsReceived(Event):
    """GPS_RAW_INT (common.xml): the receiver's fix, what a pilot reads before trusting a
    position. ``fix_type`` is GPS_FIX_TYPE (0 no GPS, 1 no fix, 2 2D, 3 3D, 4 DGPS, 5 RTK float,
    6 RTK fixed); ``satellites`` None where the wire says unknown (255)."""

    fix_type: int = 0
    satellites: int | None = None
    hdop: float | None = None
    """Horizontal dilution of precision (``eph`` / 100; None where the wire says UINT16_MAX)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 <= self.fix_type <= 255:
            raise ValueError(f"fix_type must be in 0..255, got {self.fix_type}")
        if self.satellites is not None and not 0 <= self.satellites < 255:
            raise ValueError(f"satellites must be in 0..254, got {self.satellites}")
        _optional_finite("hdop", self.hdop)


@dataclass(frozen=True)
class SensorsReceived(Event):
    """SYS_STATUS's sensor bitmasks (MAV_SYS_STATUS_SENSOR): present, enabled, healthy. A sensor
    present and enabled but not healthy is what a pilot must see."""

    present: int = 0
    enabled: int = 0
    health: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("present", "enabled", "health"):
            v = getattr(self, name)
            if not 0 <= v < 2**64:
                raise ValueError(f"{name} must be a 64-bit mask, got {v}")


@dataclass(frozen=True)
class EstimatorReceived(Event):
    """The navigation filter's own report: ArduPilot's EKF_STATUS_REPORT (ardupilotmega.xml,
    EKF_STATUS_FLAGS) or PX4's ESTIMATOR_STATUS (common.xml, ESTIMATOR_STATUS_FLAGS).

    ``flags`` as the wire has them (the two enums share bits 0-9); ``variance`` the worst of the
    velocity / position / compass test ratios (both messages report them scaled so that 1.0 is
    the filter's rejection threshold), None if not reported."""

    source: str = "EKF_STATUS_REPORT"
    flags: int = 0
    variance: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.source not in ("EKF_STATUS_REPORT", "ESTIMATOR_STATUS"):
            raise ValueError(f"unknown estimator source {self.source!r}")
        if not 0 <= self.flags < 2**32:
            raise ValueError(f"flags must be a 32-bit mask, got {self.flags}")
        _optional_finite("variance", self.variance)


@dataclass(frozen=True)
class RadioStatusReceived(Event):
    """RADIO_STATUS (common.xml) attributed to this vehicle: its telemetry radio's received
    signal strength, local (``rssi``, at the ground end) and remote (``remrssi``, at the
    vehicle's end), in the radio's units (SiK: 0..254, about 1.9 x dBm + 255, rssi "unknown"
    255 -> None); ``rxerrors`` and ``fixed`` as counted by the radio."""

    rssi: int | None = None
    remrssi: int | None = None
    noise: int | None = None
    remnoise: int | None = None
    rxerrors: int = 0
    fixed: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("rssi", "remrssi", "noise", "remnoise"):
            v = getattr(self, name)
            if v is not None and not 0 <= v <= 254:
                raise ValueError(f"{name} must be in 0..254 or None, got {v}")


#: What a pilot watches, up to a few per vehicle per second: the live view folds them, the run's
#: events.jsonl does not keep them (the .tlog has every frame they came from).
HEALTH_EVENTS = (GpsReceived, SensorsReceived, EstimatorReceived, RadioStatusReceived)


@dataclass(frozen=True)
class VehicleRebooted(Event):
    """The vehicle's clock (``time_boot_ms``) went back: it was power-cycled (a battery swap) or
    rebooted, and comes back as the same vehicle (same link and sysid), not a new one. Emitted
    with its first report after the reboot, whether or not the link had declared it lost."""

    previous_boot_s: float = 0.0
    """Its clock at the last report before the reboot, seconds."""
    time_boot_s: float = 0.0
    """Its clock now, seconds."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _finite("previous_boot_s", self.previous_boot_s)
        _finite("time_boot_s", self.time_boot_s)


# ------------------------------------------------------------------------------------------------
# Link state: about a transport, not a vehicle (no sysid), so not an Event. Emitted by the
# asyncio adapter (gcs.aio.StationAdapter), once per change.


@dataclass(frozen=True)
class LinkEvent:
    link_id: int
    """Which link (adapter) changed state."""
    t_s: float
    """Core time of the change, seconds."""
    connection: str = ""
    """The connection string, as given (``tcp:127.0.0.1:5760``)."""

    def __post_init__(self) -> None:
        if not isinstance(self.link_id, int) or self.link_id < 0:
            raise ValueError(f"link_id must be a non-negative int, got {self.link_id!r}")
        _finite("t_s", self.t_s)


@dataclass(frozen=True)
class LinkUp(LinkEvent):
    """The transport is up: bound, connected or opened (at start, or again after LinkDown)."""


@dataclass(frozen=True)
class LinkDown(LinkEvent):
    """The transport is down (never connected yet, or lost); the adapter keeps retrying."""

    reason: str = ""

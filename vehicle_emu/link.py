"""Sans-I/O vehicle-side MAVLink core: one emulated autopilot (ArduPilot Copter or PX4).

Surface (aioquic style, docs/design/architecture.md §2.1)::

    core.receive_datagram(data, addr, now_s)    # bytes in
    core.handle_timer(now_s)                    # timers: failsafes, timeouts, telemetry
    core.datagrams_to_send(now_s) -> [(bytes, addr)]
    core.next_timer_s() -> float | None
    core.next_event() -> EmulatorEvent | None

The core never reads a clock, opens a socket or sleeps: every time is the ``now_s`` argument
(vehicle clock, seconds). ``addr`` is opaque; the core returns ``None`` as destination, meaning
"every peer of the link this vehicle is on" (the router / adapter owns addressing, as a serial
or UDP port in ArduPilot does: ``GCS_MAVLINK`` sends on its channel, not to a peer).

Physics is shared: a core owns a row ``index`` of a :class:`vehicle_emu.physics.Physics` (its
targets, its position). In a :class:`vehicle_emu.swarm.Swarm` the physics of all vehicles is
stepped once per tick (vectorised) and the swarm calls :meth:`VehicleCore.update_autopilot` and
:meth:`VehicleCore.emit_telemetry` around that step. A core created without a physics object
owns a one-row physics and steps it in :meth:`handle_timer` (handy for unit tests).

Personalities (chosen per vehicle) reproduce the rules GCS code must cope with; the firmware
rule each piece follows is cited where it is implemented. Simplifications are listed in
``docs`` of :class:`VehicleCore`.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, fields

import numpy as np

from mavedge.modes import px4_custom_mode
from mavedge.params import param_id_to_str as _pid_str
from mavedge.setpoints import ACC_BITS as _ACC_BITS
from mavedge.setpoints import POS_BITS as _POS_BITS
from mavedge.setpoints import VEL_BITS as _VEL_BITS
from planner.geometry import DOWN, EAST, NORTH, geodetic_to_ned_m

from . import events as ev
from . import wire
from .missions import MissionServer
from .params import ParamTable, defaults_for
from .physics import CTRL_POS, CTRL_VEL, Physics
from .wire import dialect as mavlink

__all__ = [
    "VehicleCore", "CoreStats", "RateLimitedLog", "ARDUPILOT_MODES", "PX4_MODES", "px4_custom_mode",
    "PERSONALITIES",
]

log = logging.getLogger(__name__)

PERSONALITIES = ("ardupilot", "px4")

# ---------------------------------------------------------------------------------------------
# Mode tables
# ---------------------------------------------------------------------------------------------

#: ArduCopter mode numbers (HEARTBEAT.custom_mode), mavlink ardupilotmega ``COPTER_MODE``;
#: value -> (name, behaviour). Behaviours: 'guided' (external targets), 'hold', 'rtl', 'land'.
#: Modes that need a pilot (STABILIZE, ALT_HOLD, ...) hold position: there is no RC here.
ARDUPILOT_MODES: dict[int, tuple[str, str]] = {
    0: ("STABILIZE", "hold"), 1: ("ACRO", "hold"), 2: ("ALT_HOLD", "hold"), 3: ("AUTO", "hold"),
    4: ("GUIDED", "guided"), 5: ("LOITER", "hold"), 6: ("RTL", "rtl"), 7: ("CIRCLE", "hold"),
    9: ("LAND", "land"), 16: ("POSHOLD", "hold"), 17: ("BRAKE", "hold"), 21: ("SMART_RTL", "rtl"),
}
#: ArduCopter ``Mode::allows_arming`` is false for AUTO (without AUTO_OPTIONS), RTL, LAND,
#: SMART_RTL, BRAKE, CIRCLE (ArduCopter/mode_*.h).
_AP_ARMABLE = frozenset({0, 1, 2, 4, 5, 16})
AP_AUTO, AP_GUIDED, AP_LOITER, AP_RTL, AP_LAND = 3, 4, 5, 6, 9
#: Modes whose ``is_autopilot()`` is false (ArduCopter/mode.h): STABILIZE, ACRO, ALT_HOLD,
#: LOITER, POSHOLD, BRAKE. AUTO, GUIDED, RTL, CIRCLE, LAND and SMART_RTL are autopilot modes.
_AP_PILOT_MODES = frozenset({0, 1, 2, 5, 16, 17})


#: PX4 (main, sub) -> (name, behaviour).
PX4_MODES: dict[tuple[int, int], tuple[str, str]] = {
    (1, 0): ("MANUAL", "hold"), (2, 0): ("ALTCTL", "hold"), (3, 0): ("POSCTL", "hold"),
    (4, 1): ("AUTO.READY", "hold"), (4, 2): ("AUTO.TAKEOFF", "takeoff"),
    (4, 3): ("AUTO.LOITER", "hold"), (4, 4): ("AUTO.MISSION", "hold"),
    (4, 5): ("AUTO.RTL", "rtl"), (4, 6): ("AUTO.LAND", "land"),
    (5, 0): ("ACRO", "hold"), (6, 0): ("OFFBOARD", "guided"), (7, 0): ("STABILIZED", "hold"),
}
PX4_POSCTL, PX4_OFFBOARD = (3, 0), (6, 0)
PX4_TAKEOFF, PX4_LOITER, PX4_MISSION, PX4_RTL, PX4_LAND = (4, 2), (4, 3), (4, 4), (4, 5), (4, 6)
_PX4_NOT_ARMABLE = frozenset({PX4_RTL, PX4_LAND})
#: COM_OBL_RC_ACT (failsafe.h ``offboard_loss_failsafe_mode``) as PX4's
#: src/modules/commander/failsafe/failsafe.cpp ``Failsafe::fromOffboardLossActParam`` maps it:
#: 3 Return, 4 Land, 5 Hold are modes the vehicle flies by itself; 6 Terminate and 7 Disarm stop
#: the motors (below); 0 Position, 1 Altitude, 2 Stabilized (and, through ``default:``, any
#: other value, as Position) are manual-mode fallbacks for a pilot (next comment).
_PX4_OBL_ACT = {3: PX4_RTL, 4: PX4_LAND, 5: PX4_LOITER}
#: COM_OBL_RC_ACT values that stop the motors in the air (Terminate, Disarm).
_PX4_OBL_STOP = frozenset({6, 7})
# The manual fallbacks need a manual control signal and an emulated vehicle never has one (no
# RC, no joystick). PX4's ``Failsafe::checkModeFallback`` (failsafe.cpp; PR #26289, main 2026-01,
# backported to 1.16) then replaces the fallback: ``if (status_flags.manual_control_signal_lost
# && manualControlFallbackAction(action)) action = manualControlLossFallbackAction();``, the
# RC-loss action of NAV_RCL_ACT. Its "Last, check can_run" step does not undo that: ``modeCanRun``
# ignores the manual-control requirement (framework.cpp), so the intended POSCTL/ALTCTL/STAB
# "can run" and the NAV_RCL_ACT action stands, even when it is "none".
#: NAV_DLL_ACT and NAV_RCL_ACT (failsafe.h ``gcs_connection_loss_failsafe_mode``) as
#: failsafe.cpp ``Failsafe::fromNavDllOrRclActParam`` maps them: 1 Hold, 2 Return, 3 Land;
#: 5 Terminate and 6 Disarm stop the motors (:data:`_PX4_NAV_STOP`); 0 Disabled, 7 "Hold mode, no
#: failsafe" and unknown values (``default:``) are ``Action::None``: no failsafe action.
_PX4_NAV_ACT = {1: PX4_LOITER, 2: PX4_RTL, 3: PX4_LAND}
_PX4_NAV_STOP = frozenset({5, 6})

# ---------------------------------------------------------------------------------------------
# Streams
# ---------------------------------------------------------------------------------------------

M_HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
M_SYS_STATUS = mavlink.MAVLINK_MSG_ID_SYS_STATUS
M_GPS_RAW_INT = mavlink.MAVLINK_MSG_ID_GPS_RAW_INT
M_LOCAL_POSITION_NED = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
M_GLOBAL_POSITION_INT = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
M_GPS_GLOBAL_ORIGIN = mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN
M_POSITION_TARGET_LOCAL_NED = mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED
M_POSITION_TARGET_GLOBAL_INT = mavlink.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT
M_AUTOPILOT_VERSION = mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION
M_HOME_POSITION = mavlink.MAVLINK_MSG_ID_HOME_POSITION
M_EXTENDED_SYS_STATE = mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE
M_MISSION_CURRENT = mavlink.MAVLINK_MSG_ID_MISSION_CURRENT
M_ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE
M_VFR_HUD = mavlink.MAVLINK_MSG_ID_VFR_HUD

#: PX4's mavlink module streams without being asked (``src/modules/mavlink/mavlink_main.cpp``,
#: ``configure_streams_to_default``, MAVLINK_MODE_NORMAL/ONBOARD; rates approximate, Hz).
#: ArduPilot streams nothing but HEARTBEAT until asked (measured on SITL, docs/design/mavlink.md §5.1).
PX4_DEFAULT_RATES_HZ = {
    M_HEARTBEAT: 1.0, M_SYS_STATUS: 1.0, M_EXTENDED_SYS_STATE: 1.0, M_GLOBAL_POSITION_INT: 5.0,
    M_LOCAL_POSITION_NED: 5.0, M_GPS_RAW_INT: 1.0, M_HOME_POSITION: 0.5,
    M_POSITION_TARGET_LOCAL_NED: 1.5, M_POSITION_TARGET_GLOBAL_INT: 1.5,
}
ARDUPILOT_DEFAULT_RATES_HZ = {M_HEARTBEAT: 1.0}

#: ArduCopter REQUEST_DATA_STREAM groups (ArduCopter/GCS_Mavlink.cpp ``STREAM_*_msgs``),
#: restricted to messages this emulator produces. EXTENDED_SYS_STATE and
#: POSITION_TARGET_LOCAL_NED are placed in EXTENDED_STATUS (approximation).
_AP_STREAM_GROUPS = {
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: (M_SYS_STATUS, M_GPS_RAW_INT, M_MISSION_CURRENT,
                                              M_POSITION_TARGET_GLOBAL_INT, M_EXTENDED_SYS_STATE,
                                              M_POSITION_TARGET_LOCAL_NED),
    mavlink.MAV_DATA_STREAM_POSITION: (M_GLOBAL_POSITION_INT, M_LOCAL_POSITION_NED),
    mavlink.MAV_DATA_STREAM_EXTRA1: (M_ATTITUDE,),
    mavlink.MAV_DATA_STREAM_EXTRA2: (M_VFR_HUD,),
}

_GCS_HEARTBEAT_TYPE = mavlink.MAV_TYPE_GCS
_FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force (ArduPilot & PX4)

# type_mask ignore bits (POSITION_TARGET_TYPEMASK); a group counts as ignored if ANY of its
# three bits is set: ArduCopter GCS_Mavlink.cpp tests ``type_mask & POS_IGNORE`` with
# POS_IGNORE = X|Y|Z, so masking only Z drops the whole position (docs/design/mavlink.md §1.4); PX4
# mavlink_receiver.cpp does the same per vector group (mavros#402).
# (mavedge.setpoints POS_BITS, VEL_BITS, ACC_BITS)
_LOCAL_FRAMES = (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
                 mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED)
_GLOBAL_AMSL = (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT)
_PX4_GLOBAL_INT_FRAMES = (mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                          mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT)
_GLOBAL_REL = (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
               mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT, mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT)

_R = mavlink  # short alias for MAV_RESULT_* below
MAX_DATAGRAM_BYTES = 1200
TICK_S = 0.05

#: ArduPilot AP_Math/location.cpp ``check_lat(int32_t)`` / ``check_lng(int32_t)``:
#: ``labs(lat) <= 90*1e7`` and ``labs(lng) <= 180*1e7`` (degE7, bounds included).
_AP_LAT_E7_MAX, _AP_LON_E7_MAX = 900_000_000, 1_800_000_000
#: PX4 mavlink_receiver.cpp handle_message_command_int: x == y == INT32_MAX means "not given"
#: (param5/6 = NaN); x == y == 0x7ff80000 is "NAN was by accident sent as int" -> DENIED.
_INT32_MAX, _NAN_AS_INT = 2**31 - 1, 0x7FF80000
#: PX4 lib/geo/geo.h CONSTANTS_RADIUS_OF_EARTH (m), used by MapProjection.
_PX4_EARTH_RADIUS_M = 6371000.0


#: Largest finite float32: every float field on the wire (and every float in both firmwares'
#: position paths) is single precision.
_FLT_MAX = float(np.finfo(np.float32).max)


def _f32(v: float) -> float:
    """Saturate to the float32 range so that packing a wire float never overflows (NaN kept)."""
    v = float(v)
    return _FLT_MAX if v > _FLT_MAX else (-_FLT_MAX if v < -_FLT_MAX else v)


def _e7_sat(deg: float) -> int:
    """degE7 for an int32 field; non-finite -> INT32_MAX (MAVLink's "unknown" for lat/lon),
    clamped to int32 (mavedge.units.deg_to_e7)."""
    return wire.lat_e7_from_deg(deg)


def _f32_norm_overflows(vec) -> bool:
    """True when the float32 Euclidean norm of ``vec`` is infinite (x*x overflows)."""
    with np.errstate(over="ignore"):
        v = np.asarray(vec, dtype=np.float64).astype(np.float32)
        return not np.isfinite(np.sqrt(np.sum(v * v, dtype=np.float32)))


def ap_check_latlng_e7(lat_e7: int, lon_e7: int) -> bool:
    """ArduPilot ``check_latlng(int32_t lat, int32_t lng)`` (AP_Math/location.cpp)."""
    return abs(int(lat_e7)) <= _AP_LAT_E7_MAX and abs(int(lon_e7)) <= _AP_LON_E7_MAX


def px4_map_project(lat_deg: float, lon_deg: float, ref_lat_deg: float,
                    ref_lon_deg: float) -> tuple[float, float]:
    """PX4 lib/geo/geo.cpp ``MapProjection::project``: azimuthal equidistant projection on a
    sphere of radius CONSTANTS_RADIUS_OF_EARTH around the EKF origin; (north_m, east_m) as
    float32, like the firmware's ``float &x, float &y``.

    PX4 does not range-check the latitude / longitude it is given (neither mavlink_receiver.cpp
    nor navigator_main.cpp DO_REPOSITION do): a latitude of 100 deg is, through sin/cos, the
    point at 80 deg on the far meridian, and the vehicle is sent there.
    """
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    ref_lat, ref_lon = math.radians(ref_lat_deg), math.radians(ref_lon_deg)
    sin_lat, cos_lat = math.sin(lat), math.cos(lat)
    ref_sin, ref_cos = math.sin(ref_lat), math.cos(ref_lat)
    cos_d_lon = math.cos(lon - ref_lon)
    arg = min(1.0, max(-1.0, ref_sin * sin_lat + ref_cos * cos_lat * cos_d_lon))
    c = math.acos(arg)
    k = c / math.sin(c) if abs(c) > 0 else 1.0
    x = k * (ref_cos * sin_lat - ref_sin * cos_lat * cos_d_lon) * _PX4_EARTH_RADIUS_M
    y = k * cos_lat * math.sin(lon - ref_lon) * _PX4_EARTH_RADIUS_M
    return float(np.float32(x)), float(np.float32(y))


@dataclass
class CoreStats:
    """Counters of one core (remote bytes are counted, never raised)."""

    datagrams_in: int = 0
    messages_in: int = 0
    bad_data: int = 0
    unknown_msg_ids: int = 0
    truncated_bytes: int = 0
    signing_rejected: int = 0
    not_for_us: int = 0
    unhandled: int = 0
    handler_errors: int = 0
    telemetry_errors: int = 0
    commands: int = 0
    setpoints: int = 0
    setpoints_ignored: int = 0
    gcs_heartbeats: int = 0
    messages_out: int = 0
    bytes_out: int = 0
    dropped_dead: int = 0

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class RateLimitedLog:
    """Log at most one record per ``key`` per ``interval_s`` (explicit time, sans-I/O).

    Remote input can repeat a fault thousands of times a second (a garbage stream, a client
    speaking an unknown dialect); each is counted in the stats, but the log gets one line per
    key and interval, and the next line says how many were suppressed in between (the
    ``GCS_MAVLINK`` "N messages suppressed" idea; MAVProxy does likewise for repeated
    errors). Keys are categories, never peer addresses, so the table stays small; it is capped
    at ``max_keys`` anyway (oldest dropped).
    """

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0,
                 max_keys: int = 256) -> None:
        self.logger = logger
        self.interval_s = float(interval_s)
        self.max_keys = int(max_keys)
        self._state: dict = {}   # key -> [last_logged_s, n_suppressed]
        self.n_logged = 0
        self.n_suppressed = 0

    def log(self, now_s: float, key, level: int, msg: str, *args, **kwargs) -> bool:
        """Log ``msg % args`` unless ``key`` was logged less than ``interval_s`` ago."""
        st = self._state.get(key)
        if st is not None and now_s - st[0] < self.interval_s:
            st[1] += 1
            self.n_suppressed += 1
            return False
        if st is not None and st[1]:
            msg = msg + " (%d more suppressed in the last %.0f s)"
            args = args + (st[1], now_s - st[0])
        if st is None and len(self._state) >= self.max_keys:
            self._state.pop(next(iter(self._state)))
        self._state[key] = [now_s, 0]
        self.n_logged += 1
        self.logger.log(level, msg, *args, **kwargs)
        return True


class VehicleCore:
    """One emulated autopilot.

    Parameters
    ----------
    sysid : int
        MAVLink system id (1..254; 255 is the GCS by convention).
    personality : {'ardupilot', 'px4'}
    now_s : float
        Vehicle clock at boot (``time_boot_ms`` counts from here).
    physics : Physics, optional
        Shared physics; the core uses row ``index``. Without it the core owns a one-row
        physics placed at ``origin_lla`` and steps it in :meth:`handle_timer`.
    index : int
        Row in ``physics``.
    origin_lla : (lat_deg, lon_deg, alt_amsl_m)
        World origin when the core owns its physics.
    params : mapping, optional
        Parameter overrides (native units, see :mod:`vehicle_emu.params`).
    signing_key : bytes, optional
        32-byte MAVLink 2 signing key.
    trusted_addrs : collection, optional
        Source addresses from which SETUP_SIGNING is honoured ("trusted link": the analogue of
        a USB cable; ArduPilot and PX4 refuse key changes over an arbitrary radio link).
        SETUP_SIGNING is also refused while armed (PX4 behaviour, docs/design/mavlink.md §3).
    ekf_ready_after_s : float
        Arming is refused until this long after boot (SITL needs ~40 s; default 0).
    unix_time_at_zero_s : float
        Wall-clock Unix time corresponding to ``now_s == 0``; used only for MAVLink signing
        timestamps (the firmware uses GPS time there).
    log_limiter : RateLimitedLog, optional
        Rate limit for warnings caused by remote input (a Swarm shares one among its cores).

    Notes
    -----
    Home and the EKF origin are the vehicle's spawn position (as SITL with per-instance
    offsets); LOCAL_NED on the wire is relative to it. Local NED is modelled as the world NED
    shifted by the origin (flat earth over the swarm area, error < 0.1 m per km).
    Yaw follows the velocity direction; yaw / yaw-rate / acceleration setpoints are parsed but
    not flown (acceleration-only targets make ArduPilot hold, like its "invalid input" path).
    """

    def __init__(self, sysid: int, personality: str = "ardupilot", *, now_s: float = 0.0,
                 physics: Physics | None = None, index: int = 0,
                 origin_lla: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 params=None, signing_key: bytes | None = None, trusted_addrs=(),
                 ekf_ready_after_s: float = 0.0, unix_time_at_zero_s: float = 1.7e9,
                 network: int = 0, log_limiter: RateLimitedLog | None = None) -> None:
        if personality not in PERSONALITIES:
            raise ValueError(f"personality must be one of {PERSONALITIES}, got {personality!r}")
        if not 1 <= int(sysid) <= 254:
            raise ValueError(f"vehicle sysid must be 1..254, got {sysid}")
        self.sysid = int(sysid)
        self.network = int(network)
        self.personality = personality
        self.is_px4 = personality == "px4"
        self.compid = mavlink.MAV_COMP_ID_AUTOPILOT1
        self._owns_physics = physics is None
        if physics is None:
            physics = Physics(np.zeros((1, 3)), origin_lla=origin_lla)
            index = 0
        self.physics = physics
        self.index = int(index)
        self.alive = True
        self._boot_s = float(now_s)
        self._physics_t_s = float(now_s)
        self._last_timer_s = float(now_s)
        self._unix_at_zero_s = float(unix_time_at_zero_s)
        self._ekf_ready_s = float(now_s) + float(ekf_ready_after_s)
        self.trusted_addrs = frozenset(trusted_addrs)

        spec = defaults_for(personality)
        overrides = dict(params or {})
        sysid_param = "MAV_SYS_ID" if self.is_px4 else "SYSID_THISMAV"
        overrides.setdefault(sysid_param, self.sysid)
        self.params = ParamTable(spec, overrides)

        allow_unsigned = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS,
                                    mavlink.MAVLINK_MSG_ID_SETUP_SIGNING})
        self._codec = wire.Codec(self.sysid, self.compid, signing_key=signing_key,
                                 allow_unsigned_ids=allow_unsigned)
        self.stats = CoreStats()
        self._out: list[bytes] = []
        self._events: deque = deque()
        self._logged_types: set[str] = set()
        #: Warnings caused by remote input go through this (shared by a Swarm's cores).
        self.log_limiter = log_limiter if log_limiter is not None else RateLimitedLog(log)

        # Home / EKF origin = spawn point (world NED and geodetic).
        i = self.index
        self.home_ned_m = physics.pos_ned_m[i].copy()
        if self._owns_physics:
            physics.update_geodetic()
        self.home_lla = (float(physics.lat_deg[i]), float(physics.lon_deg[i]),
                         float(physics.alt_amsl_m[i]))

        # Autopilot state.
        self.armed = False
        self._armed_since_s: float | None = None
        self._landed_armed_since_s: float | None = None
        self._has_taken_off = False
        if self.is_px4:
            self._mode_key = px4_custom_mode(*PX4_LOITER)  # PX4 boots in Hold
            self.mode_name, self._behaviour = PX4_MODES[PX4_LOITER]
        else:
            self._mode_key = 0
            self.mode_name, self._behaviour = ARDUPILOT_MODES[0]
        self._rtl_phase = ""
        self._rtl_cruise_down_m: float | None = None
        self._takeoff_target_down_m: float | None = None
        self._vel_target_s: float | None = None
        self._target_mask = 0b110111111000  # what POSITION_TARGET_* reports
        self._last_gcs_hb_s: float | None = None
        self.gcs_failsafe = False
        # PX4 offboard signal (setpoint stream) tracking.
        self._sp_last_s: float | None = None
        self._offboard_target = None
        self.offboard_failsafe = False

        defaults = PX4_DEFAULT_RATES_HZ if self.is_px4 else ARDUPILOT_DEFAULT_RATES_HZ
        self._default_interval_s = {k: 1.0 / v for k, v in defaults.items()}
        self._interval_s: dict[int, float] = dict(self._default_interval_s)
        self._next_due_s: dict[int, float] = {k: float(now_s) for k in self._interval_s}
        self._builders = {
            M_HEARTBEAT: self._msg_heartbeat, M_SYS_STATUS: self._msg_sys_status,
            M_GPS_RAW_INT: self._msg_gps_raw_int, M_LOCAL_POSITION_NED: self._msg_local_position,
            M_GLOBAL_POSITION_INT: self._msg_global_position,
            M_GPS_GLOBAL_ORIGIN: self._msg_gps_global_origin,
            M_POSITION_TARGET_LOCAL_NED: self._msg_position_target_local,
            M_POSITION_TARGET_GLOBAL_INT: self._msg_position_target_global,
            M_AUTOPILOT_VERSION: self._msg_autopilot_version,
            M_HOME_POSITION: self._msg_home_position,
            M_EXTENDED_SYS_STATE: self._msg_extended_sys_state,
            M_MISSION_CURRENT: self._msg_mission_current,
            M_ATTITUDE: self._msg_attitude,
            M_VFR_HUD: self._msg_vfr_hud,
        }
        self._missions = MissionServer(self._send, self.is_px4, lambda: self.home_lla)
        nop = self._nop
        self._handlers = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_LONG": self._on_command_long,
            "COMMAND_INT": self._on_command_int,
            "SET_MODE": self._on_set_mode,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_set_position_target_local,
            "SET_POSITION_TARGET_GLOBAL_INT": self._on_set_position_target_global,
            "REQUEST_DATA_STREAM": self._on_request_data_stream,
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_SET": self._on_param_set,
            "TIMESYNC": self._on_timesync,
            "PING": self._on_ping,
            "SETUP_SIGNING": self._on_setup_signing,
            "MISSION_REQUEST_LIST": self._on_mission_request_list,
            "MISSION_REQUEST_INT": self._on_mission_request_int,
            "MISSION_REQUEST": self._on_mission_request,
            "MISSION_COUNT": self._on_mission_count,
            "MISSION_ITEM_INT": self._on_mission_item,
            "MISSION_ITEM": self._on_mission_item,
            "MISSION_CLEAR_ALL": self._on_mission_clear_all,
            "MISSION_ACK": nop,  # end of a download: nothing to do (no state kept)
            # Explicit ignores (skybrush-style nop handlers): traffic a GCS legitimately sends
            # that this emulator has no use for.
            "RADIO_STATUS": nop, "COMMAND_ACK": nop, "SYSTEM_TIME": nop, "PARAM_VALUE": nop,
            "MANUAL_CONTROL": nop, "RC_CHANNELS_OVERRIDE": nop, "GPS_GLOBAL_ORIGIN": nop,
            "STATUSTEXT": nop, "ATTITUDE": nop, "GLOBAL_POSITION_INT": nop,
            "LOCAL_POSITION_NED": nop, "SYS_STATUS": nop,
        }
        self._apply_params()

    # =========================================================================================
    # Public sans-I/O surface
    # =========================================================================================

    def receive_datagram(self, data: bytes, addr, now_s: float) -> None:
        """Feed one datagram (any number of frames, possibly garbage or truncated)."""
        st = self.stats
        st.datagrams_in += 1
        if not self.alive:
            st.dropped_dead += 1
            return
        res = self._codec.decode_datagram(data)
        st.bad_data += res.n_bad
        st.unknown_msg_ids += res.n_unknown
        st.truncated_bytes += res.n_truncated_bytes
        if res.n_signature_rejected:
            st.signing_rejected += res.n_signature_rejected
            self._warn_limited(now_s, "signing", "sysid %d: rejected %d frame(s) failing "
                               "MAVLink signing from %s", self.sysid,
                               res.n_signature_rejected, addr, level=logging.INFO)
        if res.n_bad or res.n_unknown:
            self._warn_limited(now_s, "bad_data", "sysid %d: %d bad frame(s), %d unknown "
                               "message id(s) from %s (totals: %d bad, %d unknown)", self.sysid,
                               res.n_bad, res.n_unknown, addr, st.bad_data, st.unknown_msg_ids)
        for msg in res.messages:
            self.receive_message(msg, addr, now_s)

    def receive_message(self, msg, addr, now_s: float) -> None:
        """Handle one decoded message (used by :meth:`receive_datagram`)."""
        st = self.stats
        st.messages_in += 1
        mtype = msg.get_type()
        handler = self._handlers.get(mtype)
        if handler is None:
            st.unhandled += 1
            if mtype not in self._logged_types:
                self._logged_types.add(mtype)
                log.info("sysid %d: ignoring message type %s (logged once)", self.sysid, mtype)
            return
        try:
            handler(msg, addr, now_s)
        except Exception:  # noqa: BLE001 - a handler bug must not kill the adapter loop
            st.handler_errors += 1
            self._warn_limited(now_s, f"handler:{mtype}", "sysid %d: handler for %s failed",
                               self.sysid, mtype, level=logging.ERROR, exc_info=True)

    def handle_timer(self, now_s: float) -> None:
        """Run timers: (own physics), autopilot rules, due telemetry."""
        if not self.alive:
            return
        if self._owns_physics:
            dt = now_s - self._physics_t_s
            if dt > 0:
                self.physics.step(dt)
                self.physics.update_geodetic()
                self._physics_t_s = now_s
        self.update_autopilot(now_s)
        self.emit_telemetry(now_s)
        self._last_timer_s = now_s

    def next_timer_s(self) -> float | None:
        if not self.alive:
            return None
        return self._last_timer_s + TICK_S

    def datagrams_to_send(self, now_s: float) -> list[tuple[bytes, object]]:
        """Frames queued since the last call, packed into datagrams of <= 1200 bytes.

        Destination ``None`` = every peer of this vehicle's link (see module docstring).
        """
        if not self._out:
            return []
        frames, self._out = self._out, []
        out, cur, size = [], [], 0
        for f in frames:
            if size + len(f) > MAX_DATAGRAM_BYTES and cur:
                out.append((b"".join(cur), None))
                cur, size = [], 0
            cur.append(f)
            size += len(f)
        if cur:
            out.append((b"".join(cur), None))
        return out

    def next_event(self):
        return self._events.popleft() if self._events else None

    def kill(self) -> None:
        """The vehicle is lost: silent forever, queued output discarded."""
        self.alive = False
        self._out.clear()

    # -- convenience accessors (ground truth side, not wire) -----------------------------------

    @property
    def custom_mode(self) -> int:
        return self._mode_key

    @property
    def signing_enabled(self) -> bool:
        return self._codec.signing_enabled

    @property
    def landed(self) -> bool:
        return bool(self.physics.landed[self.index])

    @property
    def local_pos_ned_m(self) -> np.ndarray:
        """(3,) position relative to this vehicle's EKF origin (what LOCAL_POSITION_NED says)."""
        return self.physics.pos_ned_m[self.index] - self.home_ned_m

    def set_stream_rate(self, msg_id: int, rate_hz: float, now_s: float) -> None:
        """Local API: stream ``msg_id`` at ``rate_hz`` (0 stops it)."""
        self._set_interval(msg_id, 1.0 / rate_hz if rate_hz > 0 else -1.0, now_s)

    # =========================================================================================
    # Autopilot logic (timers)
    # =========================================================================================

    def update_autopilot(self, now_s: float) -> None:
        """Mode state machines, timeouts and failsafes, before the physics step."""
        if not self.alive:
            return
        ph, i = self.physics, self.index
        landed = bool(ph.landed[i])

        # Auto-disarm of an armed copter left on the ground. ArduCopter motors.cpp
        # auto_disarm_check (DISARM_DELAY, default 10 s); PX4 COM_DISARM_PRFLT before takeoff
        # (commander_params.yaml) and COM_DISARM_LAND (2 s) after a landing.
        if self.armed and landed and self._takeoff_target_down_m is None:
            if self._landed_armed_since_s is None:
                self._landed_armed_since_s = now_s
            if self.is_px4:
                delay = (2.0 if self._has_taken_off else self.params["COM_DISARM_PRFLT"])
            else:
                delay = self.params["DISARM_DELAY"]
            if delay > 0 and now_s - self._landed_armed_since_s >= delay:
                self._disarm(now_s, "auto_disarm")
        else:
            self._landed_armed_since_s = None
        if self.armed and not landed:
            self._has_taken_off = True

        beh = self._behaviour
        # Takeoff progress (ArduPilot guided takeoff, PX4 AUTO.TAKEOFF).
        if self._takeoff_target_down_m is not None:
            if abs(ph.pos_ned_m[i, DOWN] - self._takeoff_target_down_m) < 0.3:
                self._takeoff_target_down_m = None
                if self.is_px4 and beh == "takeoff":
                    # PX4 navigator switches to Hold (AUTO.LOITER) after takeoff.
                    self._set_mode(px4_custom_mode(*PX4_LOITER), now_s, "takeoff_complete")
            elif not self.armed:
                self._takeoff_target_down_m = None

        if beh == "rtl":
            self._run_rtl(now_s)
        elif beh == "land":
            if landed and self.armed:
                # ArduCopter land mode disarms on touchdown; PX4 AUTO.LAND likewise.
                self._disarm(now_s, "landed")

        # ArduPilot GUID_TIMEOUT: velocity/acceleration targets stop after the timeout
        # (ArduCopter mode_guided.cpp: ``if (millis() - update_time_ms > get_timeout_ms())``
        # zero the velocity target). Position targets persist.
        if (not self.is_px4 and beh == "guided" and self._vel_target_s is not None
                and now_s - self._vel_target_s > self.params["GUID_TIMEOUT"]):
            self._vel_target_s = None
            ph.command_velocity(i, (0.0, 0.0, 0.0))

        # PX4 offboard loss: no setpoint for COM_OF_LOSS_T (offboardCheck.cpp), then the mode
        # fallback of failsafe.cpp Failsafe::checkModeFallback, once per loss (a fallback of
        # "none" leaves the vehicle in OFFBOARD; a setpoint arriving again ends the loss).
        if self.is_px4 and beh == "guided":
            if self._offboard_signal_ok(now_s):
                self.offboard_failsafe = False
            elif not self.offboard_failsafe:
                self.offboard_failsafe = True
                action = self._px4_offboard_loss(now_s)
                self._events.append(ev.FailsafeTriggered(self.sysid, now_s, "offboard", action))

        self._missions.update(now_s)
        self._check_gcs_link(now_s)

    def _px4_offboard_loss(self, now_s: float) -> str:
        """Act on a lost offboard signal; returns the action taken ("NONE" for none).

        failsafe.cpp ``Failsafe::checkModeFallback``: COM_OBL_RC_ACT through
        ``fromOffboardLossActParam``; a manual fallback (0-2, or an unknown value) without
        manual control becomes NAV_RCL_ACT's action through ``fromNavDllOrRclActParam``
        (PR #26289; see the comment above :data:`_PX4_NAV_ACT`). NAV_RCL_ACT 0 / 7 is ``Action::None``: the
        vehicle stays in OFFBOARD and the physics keeps the last target (PX4's multicopter
        position controller keeps the last ``trajectory_setpoint``). Terminate and Disarm
        stop the motors: in the air the vehicle falls (physics drops a disarmed vehicle).
        """
        act = int(self.params["COM_OBL_RC_ACT"])
        if act in _PX4_OBL_STOP:
            target, stop = None, True
        elif act in _PX4_OBL_ACT:
            target, stop = _PX4_OBL_ACT[act], False
        else:  # 0-2 and ``default:`` (Position): no manual control -> NAV_RCL_ACT
            rcl = int(self.params["NAV_RCL_ACT"])
            target, stop = _PX4_NAV_ACT.get(rcl), rcl in _PX4_NAV_STOP
        if stop:
            if not self.armed:
                return "NONE"
            self._statustext(now_s, mavlink.MAV_SEVERITY_CRITICAL,
                             "Failsafe activated: No offboard signal")
            self._disarm(now_s, "failsafe", force=True)
            return "DISARM"
        if target is None:
            return "NONE"
        self._set_mode(px4_custom_mode(*target), now_s, "failsafe")
        self._statustext(now_s, mavlink.MAV_SEVERITY_WARNING,
                         "Failsafe activated: No offboard signal")
        return PX4_MODES[target][0]

    def _check_gcs_link(self, now_s: float) -> None:
        """GCS failsafe.

        ArduPilot (ArduCopter/events.cpp ``failsafe_gcs_check``): disabled when FS_GCS_ENABLE=0;
        inactive until a heartbeat from SYSID_MYGCS was seen; triggers when the last one is
        older than FS_GCS_TIMEOUT; clears when heartbeats resume, but the vehicle stays in the
        failsafe mode until a GCS changes it (measured on SITL, docs/design/mavlink.md §5.1).
        PX4: data-link loss after COM_DL_LOSS_T without a GCS heartbeat, action NAV_DLL_ACT.
        """
        last = self._last_gcs_hb_s
        if last is None:
            return
        if self.is_px4:
            enabled = self.params["NAV_DLL_ACT"] > 0
            timeout = self.params["COM_DL_LOSS_T"]
        else:
            enabled = self.params["FS_GCS_ENABLE"] > 0
            timeout = self.params["FS_GCS_TIMEOUT"]
        if not enabled:
            self.gcs_failsafe = False
            return
        lost = now_s - last > timeout
        if lost and not self.gcs_failsafe:
            self.gcs_failsafe = True
            action = self._gcs_failsafe_action(now_s)
            log.info("sysid %d: GCS link lost at t=%.2f s -> %s", self.sysid, now_s, action)
            self._events.append(ev.FailsafeTriggered(self.sysid, now_s, "gcs", action))
        elif not lost and self.gcs_failsafe:
            self.gcs_failsafe = False
            self._events.append(ev.GcsLinkRegained(self.sysid, now_s))
            self._statustext(now_s, mavlink.MAV_SEVERITY_INFO, "GCS Failsafe Cleared")

    def _gcs_failsafe_action(self, now_s: float) -> str:
        if not self.armed:
            return "NONE"
        if self.physics.landed[self.index]:
            # ArduCopter should_disarm_on_failsafe(): landed -> disarm.
            self._disarm(now_s, "failsafe")
            return "DISARM"
        if self.is_px4:
            act = int(self.params["NAV_DLL_ACT"])
            if act in _PX4_NAV_STOP:
                self._disarm(now_s, "failsafe", force=True)
                return "DISARM"
            target = _PX4_NAV_ACT.get(act)
            if target is None:
                return "NONE"
            self._set_mode(px4_custom_mode(*target), now_s, "failsafe")
            self._statustext(now_s, mavlink.MAV_SEVERITY_CRITICAL,
                             "Failsafe activated: No connection to ground control station")
            return PX4_MODES[target][0]
        fs = int(self.params["FS_GCS_ENABLE"])
        if self._behaviour in ("rtl", "land"):
            # RTL: the failsafe's set_mode(RTL) is a no-op in RTL. LAND (simplification): the
            # firmware switches a landing copter to the FS_GCS_ENABLE action unless FS_OPTIONS
            # bit 3 (8, continue landing) is set; here it always continues landing.
            return "NONE"
        # ArduCopter/events.cpp Copter::failsafe_gcs_on_event, FS_OPTIONS (Copter.h
        # FailsafeOption): bit 1 (2, GCS_CONTINUE_IF_AUTO) continues AUTO; bit 4 (16,
        # GCS_CONTINUE_IF_PILOT_CONTROL) continues a mode with ``!flightmode->is_autopilot()``.
        # Bit 2 (4, RC_CONTINUE_IF_GUIDED) is the RC failsafe only: GUIDED is an autopilot mode
        # (mode.h ModeGuided::is_autopilot), so no bit keeps GUIDED on a GCS failsafe.
        opts = int(self.params["FS_OPTIONS"])
        if self._mode_key == AP_AUTO and opts & 2:
            return "NONE"
        if opts & 16 and self._mode_key in _AP_PILOT_MODES:
            return "NONE"
        mode = AP_LAND if fs == 5 else AP_RTL  # 1, 2, 3, 4 end in RTL here (no SmartRTL path)
        self._set_mode(mode, now_s, "failsafe")
        self._statustext(now_s, mavlink.MAV_SEVERITY_CRITICAL, "GCS Failsafe")
        return ARDUPILOT_MODES[mode][0]

    def _run_rtl(self, now_s: float) -> None:
        """RTL: climb to the return altitude, fly home horizontally, then land (default) or
        hover.

        ArduCopter mode_rtl.cpp: climb to max(RTL_ALT, current altitude), return at RTL_SPEED
        (0 -> WPNAV_SPEED), final descent to RTL_ALT_FINAL; 0 (default) lands and disarms.
        PX4 navigator/rtl: climb to RTL_RETURN_ALT, return at MPC_XY_CRUISE, land unless
        RTL_LAND_DELAY < 0 (then hover at RTL_DESCEND_ALT). We land by default because both
        firmwares do; a hovering drone at home would also be a relay for the paper's base,
        which the paper's model does not assume.
        """
        ph, i = self.physics, self.index
        if not self.armed:
            return
        pos = ph.pos_ned_m[i]
        home = self.home_ned_m
        phase = self._rtl_phase
        if phase == "climb":
            if self._rtl_cruise_down_m is None:  # return altitude fixed at RTL entry
                self._rtl_cruise_down_m = float(min(pos[DOWN], home[DOWN] - self._rtl_alt_m))
                ph.command_position(i, (pos[NORTH], pos[EAST], self._rtl_cruise_down_m))
            if pos[DOWN] - self._rtl_cruise_down_m > 0.5:
                return
            self._rtl_phase = phase = "return"
        if phase == "return":
            dist_h = math.hypot(pos[NORTH] - home[NORTH], pos[EAST] - home[EAST])
            ph.max_speed_h_m_s[i] = self._auto_speed_m_s
            if dist_h > 1.0:
                ph.command_position(i, (home[NORTH], home[EAST], self._rtl_cruise_down_m))
                return
            self._rtl_phase = phase = "final"
        if phase == "final":
            if self._rtl_hover_alt_m is not None:
                ph.command_position(i, (home[NORTH], home[EAST],
                                        home[DOWN] - self._rtl_hover_alt_m))
                self._rtl_phase = "hover"
            else:
                ph.command_land(i)
                self._rtl_phase = "land"
        elif phase == "land" and ph.landed[i]:
            self._disarm(now_s, "landed")

    # =========================================================================================
    # Telemetry
    # =========================================================================================

    def emit_telemetry(self, now_s: float) -> None:
        """Encode every stream that is due (after the physics step)."""
        if not self.alive:
            return
        due = self._next_due_s
        intervals = self._interval_s
        if self._codec.signing_enabled:
            self._codec.advance_signing_timestamp(
                wire.signing_timestamp_from_s(self._unix_at_zero_s + now_s))
        for msg_id, t_due in due.items():
            if now_s + 1e-9 >= t_due:
                interval = intervals[msg_id]
                # Keep phase, but never burst to catch up after a long gap.
                nxt = t_due + interval
                due[msg_id] = nxt if nxt > now_s else now_s + interval
                try:
                    self._send(self._builders[msg_id](now_s))
                except Exception:  # noqa: BLE001 - a bad value must not stop the other streams
                    self.stats.telemetry_errors += 1
                    self._warn_limited(now_s, f"telemetry:{msg_id}",
                                       "sysid %d: building message %d failed", self.sysid,
                                       msg_id, exc_info=True)

    def _send(self, msg) -> None:
        buf = self._codec.encode(msg)
        self._out.append(buf)
        self.stats.messages_out += 1
        self.stats.bytes_out += len(buf)

    def _set_interval(self, msg_id: int, interval_s: float, now_s: float) -> bool:
        if msg_id not in self._builders:
            return False
        if interval_s == 0:  # 0 = default rate
            interval_s = self._default_interval_s.get(msg_id, -1.0)
        if interval_s < 0:
            self._interval_s.pop(msg_id, None)
            self._next_due_s.pop(msg_id, None)
        else:
            interval_s = max(interval_s, 0.001)
            self._interval_s[msg_id] = interval_s
            self._next_due_s[msg_id] = now_s
        return True

    def _boot_ms(self, now_s: float) -> int:
        return wire.time_boot_ms_from_s(now_s - self._boot_s)

    def _msg_heartbeat(self, now_s: float):
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self._behaviour != "hold":
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if self.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if self.gcs_failsafe and self.armed:
            status = mavlink.MAV_STATE_CRITICAL
        else:
            status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        autopilot = (mavlink.MAV_AUTOPILOT_PX4 if self.is_px4
                     else mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
        return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, autopilot, base,
                                                 self._mode_key, status, 3)

    def _msg_sys_status(self, now_s: float):
        sensors = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                   | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
                   | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
                   | mavlink.MAV_SYS_STATUS_SENSOR_GPS)
        batt = float(self.physics.battery_frac[self.index])
        health = sensors
        if not self.is_px4:
            # ArduPilot GCS_Common.cpp update_sensor_status_flags: GEOFENCE is "healthy"
            # unless the fence has failed, even when no fence is present (MAVProxy's fence
            # module reports "fence breach" otherwise).
            health |= mavlink.MAV_SYS_STATUS_GEOFENCE
        return mavlink.MAVLink_sys_status_message(
            sensors, sensors, health, 100, int(10500 + 2100 * batt), -1, int(round(batt * 100)),
            0, 0, 0, 0, 0, 0)

    def _msg_global_position(self, now_s: float):
        ph, i = self.physics, self.index
        vel = ph.vel_ned_m_s[i]
        alt = float(ph.alt_amsl_m[i])
        return mavlink.MAVLink_global_position_int_message(
            self._boot_ms(now_s), wire.lat_e7_from_deg(ph.lat_deg[i]),
            wire.lat_e7_from_deg(ph.lon_deg[i]), wire.alt_mm_from_m(alt),
            wire.alt_mm_from_m(alt - self.home_lla[2]),
            wire.cm_s_from_m_s(vel[NORTH]), wire.cm_s_from_m_s(vel[EAST]),
            wire.cm_s_from_m_s(vel[DOWN]), wire.hdg_cdeg_from_rad(ph.yaw_rad[i]))

    def _msg_local_position(self, now_s: float):
        ph, i = self.physics, self.index
        p = ph.pos_ned_m[i] - self.home_ned_m
        v = ph.vel_ned_m_s[i]
        return mavlink.MAVLink_local_position_ned_message(
            self._boot_ms(now_s), *(_f32(c) for c in (p[NORTH], p[EAST], p[DOWN], v[NORTH],
                                                       v[EAST], v[DOWN])))

    def _msg_gps_raw_int(self, now_s: float):
        ph, i = self.physics, self.index
        v = ph.vel_ned_m_s[i]
        speed = math.hypot(v[NORTH], v[EAST])
        cog = wire.cdeg_from_rad_unsigned(math.atan2(v[EAST], v[NORTH])) if speed > 0.1 else 65535
        return mavlink.MAVLink_gps_raw_int_message(
            wire.time_usec_from_s(now_s - self._boot_s), mavlink.GPS_FIX_TYPE_3D_FIX,
            wire.lat_e7_from_deg(ph.lat_deg[i]), wire.lat_e7_from_deg(ph.lon_deg[i]),
            wire.alt_mm_from_m(ph.alt_amsl_m[i]), 80, 120,
            min(65534, int(round(speed * 100))), cog, 12)

    def _msg_home_position(self, now_s: float):
        lat, lon, alt = self.home_lla
        return mavlink.MAVLink_home_position_message(
            wire.lat_e7_from_deg(lat), wire.lat_e7_from_deg(lon), wire.alt_mm_from_m(alt),
            0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
            wire.time_usec_from_s(now_s - self._boot_s))

    def _msg_gps_global_origin(self, now_s: float):
        lat, lon, alt = self.home_lla
        return mavlink.MAVLink_gps_global_origin_message(
            wire.lat_e7_from_deg(lat), wire.lat_e7_from_deg(lon), wire.alt_mm_from_m(alt),
            wire.time_usec_from_s(now_s - self._boot_s))

    def _msg_attitude(self, now_s: float):
        """ATTITUDE: level flight, yaw along the velocity (the physics has no attitude)."""
        yaw = float(self.physics.yaw_rad[self.index])
        yaw = math.atan2(math.sin(yaw), math.cos(yaw))  # -pi..pi (common.xml ATTITUDE.yaw)
        return mavlink.MAVLink_attitude_message(self._boot_ms(now_s), 0.0, 0.0, yaw,
                                                0.0, 0.0, 0.0)

    def _msg_vfr_hud(self, now_s: float):
        """VFR_HUD (GCS_Common.cpp send_vfr_hud): alt is AMSL (vfr_hud_alt), climb up-positive,
        heading 0..360 deg; throttle is a hover guess when flying."""
        ph, i = self.physics, self.index
        v = ph.vel_ned_m_s[i]
        speed = math.hypot(v[NORTH], v[EAST])
        heading = wire.hdg_cdeg_from_rad(ph.yaw_rad[i]) // 100
        throttle = 0 if ph.landed[i] or not self.armed else 50
        return mavlink.MAVLink_vfr_hud_message(speed, speed, heading, throttle,
                                               float(ph.alt_amsl_m[i]), float(-v[DOWN]))

    def _msg_mission_current(self, now_s: float):
        """MISSION_CURRENT: no item is ever active (AUTO is not flown). ``total`` excludes
        ArduPilot's home item (common.xml MISSION_CURRENT.total)."""
        total = self._missions.count(mavlink.MAV_MISSION_TYPE_MISSION) - (0 if self.is_px4 else 1)
        state = (mavlink.MISSION_STATE_NOT_STARTED if total > 0
                 else mavlink.MISSION_STATE_NO_MISSION)
        return mavlink.MAVLink_mission_current_message(0, total, state, 0)

    def _msg_extended_sys_state(self, now_s: float):
        ph, i = self.physics, self.index
        if ph.landed[i]:
            state = mavlink.MAV_LANDED_STATE_ON_GROUND
        elif ph.vel_ned_m_s[i, DOWN] > 0.2 and self._behaviour in ("land", "rtl"):
            state = mavlink.MAV_LANDED_STATE_LANDING
        elif self._takeoff_target_down_m is not None:
            state = mavlink.MAV_LANDED_STATE_TAKEOFF
        else:
            state = mavlink.MAV_LANDED_STATE_IN_AIR
        return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_MC, state)

    def _target_local(self):
        ph, i = self.physics, self.index
        if ph.ctrl[i] == CTRL_VEL:
            return np.zeros(3), ph.target_vel_ned_m_s[i], 0b110111000111
        return ph.target_pos_ned_m[i] - self.home_ned_m, ph.target_vel_ned_m_s[i], 0b110111000000

    def _msg_position_target_local(self, now_s: float):
        p, v, mask = self._target_local()
        return mavlink.MAVLink_position_target_local_ned_message(
            self._boot_ms(now_s), mavlink.MAV_FRAME_LOCAL_NED, mask,
            *(_f32(c) for c in (p[0], p[1], p[2], v[0], v[1], v[2])), 0.0, 0.0, 0.0, 0.0, 0.0)

    def _msg_position_target_global(self, now_s: float):
        ph, i = self.physics, self.index
        from planner.geometry import ned_to_geodetic  # scalar path, low rate
        _, v, mask = self._target_local()
        with np.errstate(all="ignore"):
            lat, lon, alt = ned_to_geodetic(ph.target_pos_ned_m[i], *ph.origin_lla)
        return mavlink.MAVLink_position_target_global_int_message(
            self._boot_ms(now_s), mavlink.MAV_FRAME_GLOBAL_INT, mask, _e7_sat(lat), _e7_sat(lon),
            *(_f32(c) for c in (alt, v[0], v[1], v[2])), 0.0, 0.0, 0.0, 0.0, 0.0)

    def _msg_autopilot_version(self, now_s: float):
        # ArduCopter GCS_Mavlink.cpp GCS_MAVLINK_Copter::capabilities (+ GCS_Common: C_CAST,
        # MAVLINK2, MISSION_FENCE, MISSION_RALLY); PX4 mavlink_main.cpp
        # send_autopilot_capabilities. Left out on purpose, because the emulator does not
        # implement them and a GCS would try them: FTP (QGC would fetch params / metadata over
        # MAVLink FTP), SET_ATTITUDE_TARGET, FLIGHT_TERMINATION, SET_ACTUATOR_TARGET, TERRAIN.
        caps = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY)
        if self.is_px4:
            caps |= (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
                     | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT)
            sw = (1 << 24) | (15 << 16) | (0 << 8) | 0xFF  # 1.15.0 release
        else:
            caps |= mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
            sw = (4 << 24) | (6 << 16) | (0 << 8) | 0xFF  # 4.6.0 official
        uid = (self.network << 16) | self.sysid
        return mavlink.MAVLink_autopilot_version_message(
            caps, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, uid)

    def _statustext(self, now_s: float, severity: int, text: str) -> None:
        self._send(mavlink.MAVLink_statustext_message(severity, text.encode()[:50]))

    # =========================================================================================
    # Inbound handlers
    # =========================================================================================

    def _nop(self, msg, addr, now_s: float) -> None:
        return None

    def _warn_limited(self, now_s: float, key: str, msg: str, *args,
                      level: int = logging.WARNING, **kwargs) -> bool:
        return self.log_limiter.log(now_s, key, level, msg, *args, **kwargs)

    def _for_me(self, target_system: int, target_component: int) -> bool:
        ok = target_system in (0, self.sysid) and target_component in (0, self.compid)
        if not ok:
            self.stats.not_for_us += 1
        return ok

    def _on_heartbeat(self, msg, addr, now_s: float) -> None:
        if msg.type != _GCS_HEARTBEAT_TYPE:
            return
        src = msg.get_srcSystem()
        if self.is_px4:
            # PX4 ignores GCS heartbeats carrying its own sysid (PX4 PR #11998).
            if src == self.sysid:
                return
        elif src != int(self.params["SYSID_MYGCS"]):
            # ArduPilot counts only heartbeats from SYSID_MYGCS (GCS_Common.cpp handle_heartbeat)
            return
        self.stats.gcs_heartbeats += 1
        self._last_gcs_hb_s = now_s
        self._check_gcs_link(now_s)

    # -- commands -----------------------------------------------------------------------------

    def _on_command_long(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        params = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
        self._command(m.command, params, None, m, now_s)

    def _on_command_int(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        # COMMAND_INT: x, y are degE7 for global frames; z is float.
        params = (m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z)
        self._command(m.command, params, m.frame, m, now_s)

    def _ack(self, command: int, result: int, m, now_s: float) -> None:
        self._send(mavlink.MAVLink_command_ack_message(command, result, 0, 0, m.get_srcSystem(),
                                                       m.get_srcComponent()))
        self._events.append(ev.CommandHandled(self.sysid, now_s, int(command), int(result)))

    def _command(self, cmd: int, p: tuple, frame, m, now_s: float) -> None:
        self.stats.commands += 1
        result, after = self._dispatch_command(cmd, p, frame, m, now_s)
        self._ack(cmd, result, m, now_s)
        if after is not None:
            after()  # messages that must follow the ACK (REQUEST_MESSAGE semantics)

    def _dispatch_command(self, cmd: int, p: tuple, frame, m, now_s: float):
        C = mavlink
        if cmd == C.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._cmd_arm(p, now_s), None
        if cmd == C.MAV_CMD_DO_SET_MODE:
            return self._cmd_set_mode(p, now_s), None
        if cmd == C.MAV_CMD_NAV_TAKEOFF:
            return self._cmd_takeoff(p, now_s), None
        if cmd == C.MAV_CMD_NAV_LAND:
            key = px4_custom_mode(*PX4_LAND) if self.is_px4 else AP_LAND
            return (C.MAV_RESULT_ACCEPTED if self._set_mode(key, now_s, "command")
                    else C.MAV_RESULT_FAILED), None
        if cmd == C.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            key = px4_custom_mode(*PX4_RTL) if self.is_px4 else AP_RTL
            return (C.MAV_RESULT_ACCEPTED if self._set_mode(key, now_s, "command")
                    else C.MAV_RESULT_FAILED), None
        if cmd == C.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id = int(p[0]) if math.isfinite(p[0]) else -1
            interval_us = p[1]
            if not math.isfinite(interval_us):
                return C.MAV_RESULT_DENIED, None
            interval_s = -1.0 if interval_us < 0 else interval_us * 1e-6
            ok = self._set_interval(msg_id, interval_s, now_s)
            return (C.MAV_RESULT_ACCEPTED if ok else C.MAV_RESULT_FAILED), None
        if cmd == C.MAV_CMD_REQUEST_MESSAGE:
            msg_id = int(p[0]) if math.isfinite(p[0]) else -1
            builder = self._builders.get(msg_id)
            if builder is None:
                # ArduPilot GCS_Common.cpp handle_command_request_message: no ap_message for
                # the id -> MAV_RESULT_FAILED; PX4 mavlink_receiver.cpp
                # handle_request_message_command: no stream sent -> DENIED.
                return (C.MAV_RESULT_DENIED if self.is_px4 else C.MAV_RESULT_FAILED), None
            return C.MAV_RESULT_ACCEPTED, lambda: self._send(builder(now_s))
        if cmd == C.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return C.MAV_RESULT_ACCEPTED, lambda: self._send(self._msg_autopilot_version(now_s))
        if cmd == C.MAV_CMD_GET_HOME_POSITION:
            return C.MAV_RESULT_ACCEPTED, lambda: self._send(self._msg_home_position(now_s))
        if cmd == C.MAV_CMD_DO_CHANGE_SPEED:
            speed = p[1]
            if not (math.isfinite(speed) and speed > 0):
                return C.MAV_RESULT_DENIED, None
            self._guided_speed_m_s = min(float(speed), 30.0)
            if self._behaviour == "guided":
                self.physics.max_speed_h_m_s[self.index] = self._guided_speed_m_s
            return C.MAV_RESULT_ACCEPTED, None
        if cmd == C.MAV_CMD_DO_REPOSITION:
            return self._cmd_reposition(p, frame, now_s), None
        return C.MAV_RESULT_UNSUPPORTED, None

    def _cmd_arm(self, p: tuple, now_s: float) -> int:
        C = mavlink
        reject = C.MAV_RESULT_TEMPORARILY_REJECTED if self.is_px4 else C.MAV_RESULT_FAILED
        force = abs(p[1] - _FORCE_MAGIC) < 0.5
        if p[0] == 1:
            if self.armed:
                return C.MAV_RESULT_ACCEPTED
            if not force:
                if now_s < self._ekf_ready_s:
                    self._statustext(now_s, C.MAV_SEVERITY_CRITICAL, "PreArm: EKF not ready")
                    return reject
                if self.is_px4:
                    mode = self._px4_mode_pair()
                    if mode in _PX4_NOT_ARMABLE or (mode == PX4_OFFBOARD
                                                    and not self._offboard_signal_ok(now_s)):
                        self._statustext(now_s, C.MAV_SEVERITY_CRITICAL,
                                         "Arming denied: mode not armable")
                        return reject
                elif self._mode_key not in _AP_ARMABLE:
                    self._statustext(now_s, C.MAV_SEVERITY_CRITICAL, "Arm: Mode not armable")
                    return reject
            self._arm(now_s)
            return C.MAV_RESULT_ACCEPTED
        if p[0] == 0:
            if not self.armed:
                return C.MAV_RESULT_ACCEPTED
            if not force and not self.physics.landed[self.index]:
                # Both firmwares refuse a MAVLink disarm in flight unless forced.
                return reject
            self._disarm(now_s, "command", force=force)
            return C.MAV_RESULT_ACCEPTED
        return C.MAV_RESULT_DENIED

    def _arm(self, now_s: float) -> None:
        ph, i = self.physics, self.index
        self.armed = True
        ph.armed[i] = True
        self._armed_since_s = now_s
        self._landed_armed_since_s = None
        self._has_taken_off = False
        ph.hold(i)
        if self._behaviour == "guided" and self.is_px4 and self._offboard_target is not None:
            self._apply_target(self._offboard_target, now_s)
        self._events.append(ev.ArmingChanged(self.sysid, now_s, True, "command"))
        self._statustext(now_s, mavlink.MAV_SEVERITY_INFO, "Arming motors")

    def _disarm(self, now_s: float, reason: str, force: bool = False) -> None:
        ph, i = self.physics, self.index
        self.armed = False
        ph.armed[i] = False
        ph.hold(i)
        self._takeoff_target_down_m = None
        self._vel_target_s = None
        self._events.append(ev.ArmingChanged(self.sysid, now_s, False, reason))
        self._statustext(now_s, mavlink.MAV_SEVERITY_INFO, "Disarming motors")

    def _px4_mode_pair(self) -> tuple[int, int]:
        return ((self._mode_key >> 16) & 0xFF, (self._mode_key >> 24) & 0xFF)

    def _cmd_set_mode(self, p: tuple, now_s: float) -> int:
        C = mavlink
        if not all(math.isfinite(v) for v in p[:3]):
            return C.MAV_RESULT_DENIED
        base_mode = int(p[0])
        if not base_mode & C.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return C.MAV_RESULT_UNSUPPORTED if not self.is_px4 else C.MAV_RESULT_DENIED
        if self.is_px4:
            # PX4 Commander.cpp DO_SET_MODE: param2 = main mode, param3 = sub mode, unpacked.
            # A packed word in param2 (e.g. 393216) is not a main mode: rejected here (PX4
            # truncates it to 0 and may ack while nothing changes; rejecting is the safer
            # emulation of "nothing changes").
            main, sub = int(p[1]), int(p[2])
            if main == 4 and sub == 0:
                sub = 4  # AUTO without sub mode = AUTO.MISSION
            if (main, sub) not in PX4_MODES and (main, 0) in PX4_MODES:
                sub = 0
            if (main, sub) not in PX4_MODES:
                return C.MAV_RESULT_TEMPORARILY_REJECTED
            if (main, sub) == PX4_OFFBOARD and not self._offboard_signal_ok(now_s):
                # Commander: "Switching to Offboard is currently not available"
                self._statustext(now_s, C.MAV_SEVERITY_CRITICAL,
                                 "Switching to Offboard is currently not available")
                return C.MAV_RESULT_TEMPORARILY_REJECTED
            if (main, sub) == PX4_TAKEOFF:
                return self._cmd_takeoff((0, 0, 0, 0, 0, 0, float("nan")), now_s)
            if (main, sub) == PX4_MISSION:
                return self._refuse_auto(now_s, C.MAV_RESULT_TEMPORARILY_REJECTED)
            self._set_mode(px4_custom_mode(main, sub), now_s, "command")
            return C.MAV_RESULT_ACCEPTED
        custom = int(p[1])
        if custom not in ARDUPILOT_MODES:
            return C.MAV_RESULT_FAILED
        if custom == AP_AUTO:
            return self._refuse_auto(now_s, C.MAV_RESULT_FAILED)
        self._set_mode(custom, now_s, "command")
        return C.MAV_RESULT_ACCEPTED

    def _refuse_auto(self, now_s: float, result: int) -> int:
        """AUTO / AUTO.MISSION is not flown by this emulator: refuse it loudly.

        With no mission stored both firmwares refuse too: ArduCopter ModeAuto::init needs
        ``mission.num_commands() > 1`` ("Flight mode change failed"); PX4 Commander denies
        Mission mode without a valid mission. With a stored mission the firmware would fly it;
        the emulator stores uploads but says it does not fly them (a GCS must not believe the
        vehicle is flying a plan)."""
        if self._missions.has_mission():
            self._statustext(now_s, mavlink.MAV_SEVERITY_WARNING,
                             "Emulator: AUTO missions are not flown")
        elif self.is_px4:
            self._statustext(now_s, mavlink.MAV_SEVERITY_CRITICAL,
                             "Switching to Mission is currently not possible")
        else:
            self._statustext(now_s, mavlink.MAV_SEVERITY_WARNING, "Flight mode change failed")
        return result

    def _on_set_mode(self, m, addr, now_s: float) -> None:
        if m.target_system != self.sysid:
            self.stats.not_for_us += 1
            return
        self.stats.commands += 1
        C = mavlink
        if self.is_px4:
            main, sub = (m.custom_mode >> 16) & 0xFF, (m.custom_mode >> 24) & 0xFF
            result = self._cmd_set_mode((m.base_mode, main, sub), now_s)
            # PX4 turns SET_MODE into a vehicle_command DO_SET_MODE and acks that command.
            self._ack(C.MAV_CMD_DO_SET_MODE, result, m, now_s)
        else:
            result = self._cmd_set_mode((m.base_mode, m.custom_mode, 0), now_s)
            # ArduPilot acks SET_MODE with command = 11 (the message id), GCS_Common.cpp
            # handle_set_mode: "extraordinarily improper ... but mavproxy needs it".
            self._ack(mavlink.MAVLINK_MSG_ID_SET_MODE, result, m, now_s)

    def _set_mode(self, key: int, now_s: float, reason: str) -> bool:
        """Enter a mode (by custom_mode value); returns False for unknown modes."""
        if self.is_px4:
            pair = ((key >> 16) & 0xFF, (key >> 24) & 0xFF)
            if pair not in PX4_MODES:
                return False
            name, beh = PX4_MODES[pair]
        else:
            if key not in ARDUPILOT_MODES:
                return False
            name, beh = ARDUPILOT_MODES[key]
        ph, i = self.physics, self.index
        changed = key != self._mode_key
        self._mode_key, self.mode_name, self._behaviour = key, name, beh
        if reason != "failsafe":
            self.offboard_failsafe = False
        self._vel_target_s = None
        if beh != "takeoff":
            self._takeoff_target_down_m = None
        ph.max_speed_h_m_s[i] = self._guided_speed_m_s if beh == "guided" else self._auto_speed_m_s
        if beh == "rtl":
            self._rtl_phase = "climb"
            self._rtl_cruise_down_m = None
        elif beh == "land":
            ph.command_land(i)
        elif beh == "guided" and self.is_px4 and self._offboard_target is not None:
            self._apply_target(self._offboard_target, now_s)
        elif beh != "takeoff":
            ph.hold(i)
        if changed:
            self._events.append(ev.ModeChanged(self.sysid, now_s, name, key, reason))
        return True

    def _cmd_takeoff(self, p: tuple, now_s: float) -> int:
        """ArduCopter Mode::do_user_takeoff: armed, landed, a mode with user takeoff (GUIDED),
        target above the current altitude; param7 = altitude above home (m).
        PX4: armed and landed; param7 = AMSL altitude, NaN -> MIS_TAKEOFF_ALT above home;
        switches to AUTO.TAKEOFF, then Hold when reached."""
        C = mavlink
        ph, i = self.physics, self.index
        if self.is_px4:
            reject = C.MAV_RESULT_TEMPORARILY_REJECTED
            if not self.armed or not ph.landed[i]:
                return reject
            alt_amsl = p[6]
            if math.isfinite(alt_amsl) and alt_amsl - self.home_lla[2] > 0.5:
                alt_above_home = alt_amsl - self.home_lla[2]
            else:
                alt_above_home = self.params["MIS_TAKEOFF_ALT"]
            self._set_mode(px4_custom_mode(*PX4_TAKEOFF), now_s, "command")
        else:
            reject = C.MAV_RESULT_FAILED
            alt_above_home = p[6]
            if not self.armed or not ph.landed[i] or self._mode_key != AP_GUIDED:
                return reject
            cur_alt = self.home_ned_m[DOWN] - ph.pos_ned_m[i, DOWN]
            if not math.isfinite(alt_above_home) or alt_above_home <= cur_alt:
                return reject
        target_down = float(self.home_ned_m[DOWN] - alt_above_home)
        self._takeoff_target_down_m = target_down
        self._landed_armed_since_s = None
        ph.command_position(i, (ph.pos_ned_m[i, NORTH], ph.pos_ned_m[i, EAST], target_down))
        self._events.append(ev.TakeoffStarted(self.sysid, now_s, float(alt_above_home)))
        return C.MAV_RESULT_ACCEPTED

    def _cmd_reposition(self, p: tuple, frame, now_s: float) -> int:
        """MAV_CMD_DO_REPOSITION (ArduCopter >= 4.1, GCS_Mavlink.cpp handle_command_int_do_
        reposition): switches to GUIDED when flying; rejects a NaN altitude."""
        C = mavlink
        if frame is None or not self.armed or self.physics.landed[self.index]:
            return C.MAV_RESULT_FAILED
        if not math.isfinite(p[6]):
            return C.MAV_RESULT_FAILED
        x, y = int(p[4]), int(p[5])
        keep_horizontal = False
        if self.is_px4:
            # mavlink_receiver.cpp handle_message_command_int (see _NAN_AS_INT, _INT32_MAX);
            # navigator_main.cpp DO_REPOSITION keeps the current lat/lon when they are NaN.
            if x == y == _NAN_AS_INT:
                return C.MAV_RESULT_DENIED
            if x == y == _INT32_MAX:  # altitude only: convert it at home, keep north/east
                x, y = (wire.lat_e7_from_deg(v) for v in self.home_lla[:2])
                keep_horizontal = True
        # ArduCopter handle_command_int_do_reposition: ``if (!check_latlng(packet.x, packet.y))
        # return MAV_RESULT_DENIED`` (inside _global_to_world); PX4 has no such check.
        pos = self._global_to_world(x, y, float(p[6]), frame)
        if pos is None:
            return C.MAV_RESULT_DENIED
        if keep_horizontal:
            pos[:2] = self.physics.target_pos_ned_m[self.index, :2]
        guided = px4_custom_mode(*PX4_LOITER) if self.is_px4 else AP_GUIDED
        if self._mode_key != guided:
            self._set_mode(guided, now_s, "command")
        self.physics.command_position(self.index, pos)
        return C.MAV_RESULT_ACCEPTED

    # -- setpoints ----------------------------------------------------------------------------

    def _global_frame_ok(self, frame: int) -> bool:
        # PX4 mavlink_receiver.cpp handle_message_set_position_target_global_int accepts only the
        # _INT frames 5, 6, 11 ("invalid coordinate frame" otherwise); ArduCopter also takes
        # 0, 3, 10 (mavlink_coordinate_frame_to_location_alt_frame).
        return frame in (_PX4_GLOBAL_INT_FRAMES if self.is_px4 else _GLOBAL_AMSL + _GLOBAL_REL)

    def _global_to_world(self, lat_e7: int, lon_e7: int, alt_m: float, frame: int):
        """A global target -> world NED (m), or None where the firmware refuses it.

        ArduPilot: ``check_latlng`` first (ArduCopter/GCS_Mavlink.cpp
        handle_message_set_position_target_global_int "sanity check location",
        handle_command_int_do_reposition, both before the frame is looked at).
        PX4: no range check; mavlink_receiver.cpp handle_message_set_position_target_global_int
        (and the navigator for DO_REPOSITION) project with ``MapProjection::project`` around the
        EKF origin and take ``z = ref_alt - alt``. In range the emulator's ellipsoid geodesy
        stands in for that spherical projection (they agree to 0.3 %, and it is the geodesy the
        emulator's telemetry uses); off the globe the firmware's projection itself is used
        (:func:`px4_map_project`), so the vehicle sets off where PX4 would send it.
        """
        if not self.is_px4 and not ap_check_latlng_e7(lat_e7, lon_e7):
            return None
        if not self._global_frame_ok(frame):
            return None
        if frame in _GLOBAL_AMSL:
            alt_amsl = alt_m
        else:  # _GLOBAL_REL: flat terrain at home altitude, terrain-relative == home-relative
            alt_amsl = alt_m + self.home_lla[2]
        lat_deg, lon_deg = wire.deg_from_lat_e7(lat_e7), wire.deg_from_lat_e7(lon_e7)
        if self.is_px4 and not ap_check_latlng_e7(lat_e7, lon_e7):
            north, east = px4_map_project(lat_deg, lon_deg, *self.home_lla[:2])
            return self.home_ned_m + np.array((north, east, self.home_lla[2] - alt_amsl))
        return geodetic_to_ned_m(lat_deg, lon_deg, alt_amsl, *self.physics.origin_lla)

    def _note_setpoint(self, now_s: float) -> None:
        """PX4 offboard signal. mavlink_receiver.cpp handle_message_set_position_target_local_ned
        / _global_int publish ``offboard_control_mode`` (timestamp = now) for every setpoint that
        carries a position, velocity or acceleration in a supported frame; nothing else counts."""
        self._sp_last_s = now_s

    def _offboard_signal_ok(self, now_s: float) -> bool:
        """PX4 HealthAndArmingChecks/checks/offboardCheck.cpp OffboardChecks::checkAndReport:
        ``data_is_recent = now < offboard_control_mode.timestamp + COM_OF_LOSS_T``; the mode
        requirement is only that, so ONE recent setpoint is enough to switch to OFFBOARD (the
        "stream for > 1 s at > 2 Hz" of the PX4 docs is advice, not a firmware check)."""
        return (self._sp_last_s is not None
                and now_s < self._sp_last_s + self.params["COM_OF_LOSS_T"])

    def _on_set_position_target_local(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        self.stats.setpoints += 1
        frame = m.coordinate_frame
        if frame not in _LOCAL_FRAMES:
            # PX4: "coordinate frame unsupported", returns before offboard_control_mode.
            self.stats.setpoints_ignored += 1
            return
        mask = m.type_mask
        if self.is_px4 and (mask & (_POS_BITS | _VEL_BITS | _ACC_BITS)) != (
                _POS_BITS | _VEL_BITS | _ACC_BITS):
            # PX4 publishes offboard_control_mode when ocm.position || velocity || acceleration.
            self._note_setpoint(now_s)
        ph, i = self.physics, self.index
        pos = vel = None
        yaw = ph.yaw_rad[i]
        cy, sy = math.cos(yaw), math.sin(yaw)
        body = frame in (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED)
        if not self.is_px4 and any(
                abs(c) * 100.0 > _FLT_MAX for c in (m.x, m.y, m.z, m.vx, m.vy, m.vz)):
            # ArduCopter/GCS_Mavlink.cpp handle_message_set_position_target_local_ned "convert
            # to cm": ``packet.x * 100.0f`` is +-inf in float beyond FLT_MAX / 100 (3.4e36 m):
            # not a usable target; the emulator's rule for non-finite input (ignore) applies.
            self.stats.setpoints_ignored += 1
            return
        if not mask & _POS_BITS:
            x, y, z = m.x, m.y, m.z
            if body:  # ArduCopter rotate_body_frame_to_NE
                x, y = x * cy - y * sy, x * sy + y * cy
            if frame == mavlink.MAV_FRAME_LOCAL_NED:
                pos = self.home_ned_m + (x, y, z)   # LOCAL_NED is relative to the EKF origin
            else:
                pos = ph.pos_ned_m[i] + (x, y, z)   # offset and body frames: relative to vehicle
        if not mask & _VEL_BITS:
            vx, vy = m.vx, m.vy
            if body:
                vx, vy = vx * cy - vy * sy, vx * sy + vy * cy
            vel = np.array((vx, vy, m.vz))
        self._accept_target(pos, vel, mask, now_s)

    def _on_set_position_target_global(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        self.stats.setpoints += 1
        mask = m.type_mask
        pos = vel = None
        if not mask & _POS_BITS:
            pos = self._global_to_world(m.lat_int, m.lon_int, m.alt, m.coordinate_frame)
            if pos is None:
                self.stats.setpoints_ignored += 1
                if not self.is_px4 and self._behaviour == "guided" and self.armed:
                    # ArduCopter: bad location or frame -> "input is not valid so stop"
                    # (copter.mode_guided.init(true)): brake and hold.
                    self.physics.hold(self.index)
                    self._vel_target_s = None
                return
        elif not self._global_frame_ok(m.coordinate_frame):
            self.stats.setpoints_ignored += 1
            return
        if self.is_px4 and (mask & (_POS_BITS | _VEL_BITS | _ACC_BITS)) != (
                _POS_BITS | _VEL_BITS | _ACC_BITS):
            # A dropped setpoint publishes no offboard_control_mode: it is no offboard signal.
            self._note_setpoint(now_s)
        if not mask & _VEL_BITS:
            vel = np.array((m.vx, m.vy, m.vz))
        self._accept_target(pos, vel, mask, now_s)

    def _accept_target(self, pos, vel, mask: int, now_s: float) -> None:
        if (pos is not None and not np.all(np.isfinite(pos))) or (
                vel is not None and not np.all(np.isfinite(vel))):
            self.stats.setpoints_ignored += 1
            return
        target = (pos, vel, mask)
        if self.is_px4:
            # PX4 keeps the latest setpoint; it is flown only in OFFBOARD.
            self._offboard_target = target
            if self._behaviour != "guided":
                return
        elif self._behaviour != "guided":
            # ArduCopter: "exit if vehicle is not in Guided mode or Auto-Guided mode".
            self.stats.setpoints_ignored += 1
            return
        if not self.is_px4 and self.physics.landed[self.index] and (
                self._takeoff_target_down_m is None):
            # ArduCopter guided on the ground: make_safe_ground_handling; take off first.
            self.stats.setpoints_ignored += 1
            return
        self._apply_target(target, now_s)

    def _apply_target(self, target, now_s: float) -> None:
        pos, vel, mask = target
        ph, i = self.physics, self.index
        if self.is_px4 and not self.armed:
            return
        if pos is not None:
            if self.is_px4 and _f32_norm_overflows(pos[:2] - ph.pos_ned_m[i, :2]):
                # PX4 mc_pos_control PositionControl::_positionControl: the horizontal velocity
                # setpoint is ControlMath::constrainXY(vel_sp_position.xy(), ..., lim), which for
                # ``v0.length() >= max`` returns ``v0.normalized() * max``; a float32 error whose
                # squared norm overflows has an infinite length, normalized() is then 0: no
                # horizontal motion. The vehicle keeps its north/east (the altitude still flies).
                pos = np.array((ph.pos_ned_m[i, NORTH], ph.pos_ned_m[i, EAST], pos[DOWN]))
            ph.command_position(i, pos, vel)
            self._vel_target_s = None
            self._takeoff_target_down_m = None
        elif vel is not None:
            ph.command_velocity(i, vel)
            self._vel_target_s = now_s
            self._takeoff_target_down_m = None
        elif not self.is_px4:
            # ArduCopter: "input is not valid so stop" -> mode_guided.init(true).
            ph.hold(i)
        self._target_mask = mask

    # -- mission protocol (vehicle_emu.missions) ---------------------------------------------

    def _on_mission_request_list(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_request_list(m, now_s)

    def _on_mission_request_int(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_request(m, now_s, as_int=True)

    def _on_mission_request(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_request(m, now_s, as_int=False)

    def _on_mission_count(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_count(m, now_s)

    def _on_mission_clear_all(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_clear_all(m, now_s)

    def _on_mission_item(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        if not self.is_px4 and m.current in (2, 3) and (
                getattr(m, "mission_type", 0) == mavlink.MAV_MISSION_TYPE_MISSION):
            # ArduPilot GCS_Common.cpp handle_mission_item: current = 2 is a "guided mode"
            # waypoint (MAVProxy ``guided``, Mission Planner "Fly To Here"), current = 3 an
            # altitude change; answered with MISSION_ACK, ACCEPTED or ERROR.
            ok = self._guided_mission_item(m, now_s)
            self._send(mavlink.MAVLink_mission_ack_message(
                m.get_srcSystem(), m.get_srcComponent(),
                mavlink.MAV_MISSION_ACCEPTED if ok else mavlink.MAV_MISSION_ERROR,
                mavlink.MAV_MISSION_TYPE_MISSION))
            return
        self._missions.on_item(m, now_s)

    def _guided_mission_item(self, m, now_s: float) -> bool:
        """ArduCopter ModeAuto::do_guided: "only process guided waypoint if we are in guided
        mode"; NAV_WAYPOINT -> ModeGuided::set_destination. current = 3:
        handle_change_alt_request (keep the horizontal target, change the altitude)."""
        ph, i = self.physics, self.index
        if self._behaviour != "guided" or not self.armed or (
                ph.landed[i] and self._takeoff_target_down_m is None):
            return False
        if m.get_type() == "MISSION_ITEM":
            lat_e7, lon_e7 = wire.lat_e7_from_deg(m.x), wire.lat_e7_from_deg(m.y)
        else:
            lat_e7, lon_e7 = m.x, m.y
        if m.current == 2 and m.command != mavlink.MAV_CMD_NAV_WAYPOINT:
            return False
        if m.current == 3:  # altitude only: x, y are unused (often 0)
            lat_e7, lon_e7 = (wire.lat_e7_from_deg(v) for v in self.home_lla[:2])
        if not (math.isfinite(m.z) and math.isfinite(lat_e7) and math.isfinite(lon_e7)):
            return False
        pos = self._global_to_world(int(lat_e7), int(lon_e7), float(m.z), m.frame)
        if pos is None:
            return False
        if m.current == 3:
            pos = np.array((ph.target_pos_ned_m[i, NORTH], ph.target_pos_ned_m[i, EAST], pos[DOWN]))
        self._apply_target((np.asarray(pos, dtype=float), None, 0b110111111000), now_s)
        return True

    # -- streams ------------------------------------------------------------------------------

    def _on_request_data_stream(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        if self.is_px4:
            return  # PX4 does not implement REQUEST_DATA_STREAM
        groups = (list(_AP_STREAM_GROUPS) if m.req_stream_id == mavlink.MAV_DATA_STREAM_ALL
                  else [m.req_stream_id])
        on = m.start_stop != 0 and m.req_message_rate > 0
        for g in groups:
            for msg_id in _AP_STREAM_GROUPS.get(g, ()):
                self._set_interval(msg_id, 1.0 / m.req_message_rate if on else -1.0, now_s)

    # -- parameters ---------------------------------------------------------------------------

    def _send_param(self, name: str) -> None:
        ptype = self.params.param_type(name)
        value = wire.param_to_wire_float(self.params[name], ptype, bytewise=self.is_px4)
        self._send(mavlink.MAVLink_param_value_message(
            name.encode(), value, ptype, len(self.params), self.params.index_of(name)))

    def _on_param_request_list(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        for name in self.params.names():
            self._send_param(name)

    def _on_param_request_read(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        name = self.params.name_at(m.param_index) if m.param_index >= 0 else _pid_str(m.param_id)
        if name is not None and name in self.params:
            self._send_param(name)

    def _on_param_set(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        name = _pid_str(m.param_id)
        if name not in self.params:
            return  # both firmwares stay silent on unknown names
        ptype = self.params.param_type(name)
        try:
            value = wire.param_from_wire_float(m.param_value, ptype, bytewise=self.is_px4)
        except ValueError:
            self.stats.bad_data += 1
            return
        if not math.isfinite(value):
            self.stats.bad_data += 1
            return
        stored = self.params.set(name, value)
        self._apply_params()
        self._events.append(ev.ParamChanged(self.sysid, now_s, name, stored))
        self._send_param(name)

    def _apply_params(self) -> None:
        """Derive SI limits from the parameter table (native units -> m, m/s)."""
        P, ph, i = self.params, self.physics, self.index
        if self.is_px4:
            self._guided_speed_m_s = P["MPC_XY_VEL_MAX"]
            self._auto_speed_m_s = P["MPC_XY_CRUISE"]
            ph.climb_rate_m_s[i] = P["MPC_Z_VEL_MAX_UP"]
            ph.descent_rate_m_s[i] = P["MPC_Z_VEL_MAX_DN"]
            ph.land_speed_m_s[i] = P["MPC_LAND_SPEED"]
            self._rtl_alt_m = P["RTL_RETURN_ALT"]
            self._rtl_hover_alt_m = P["RTL_DESCEND_ALT"] if P["RTL_LAND_DELAY"] < 0 else None
        else:
            self._guided_speed_m_s = P["WPNAV_SPEED"] / 100.0
            rtl_speed = P["RTL_SPEED"]
            self._auto_speed_m_s = (rtl_speed if rtl_speed > 0 else P["WPNAV_SPEED"]) / 100.0
            ph.climb_rate_m_s[i] = P["WPNAV_SPEED_UP"] / 100.0
            ph.descent_rate_m_s[i] = P["WPNAV_SPEED_DN"] / 100.0
            ph.land_speed_m_s[i] = P["LAND_SPEED"] / 100.0
            self._rtl_alt_m = P["RTL_ALT"] / 100.0
            final = P["RTL_ALT_FINAL"] / 100.0
            self._rtl_hover_alt_m = final if final > 0 else None
        beh = getattr(self, "_behaviour", "hold")
        ph.max_speed_h_m_s[i] = self._guided_speed_m_s if beh == "guided" else self._auto_speed_m_s

    # -- misc ---------------------------------------------------------------------------------

    def _on_timesync(self, m, addr, now_s: float) -> None:
        # TIMESYNC: a request has tc1 == 0; reply with tc1 = our time, ts1 mirrored.
        # tc1 is never 0 in a reply (ArduPilot uses micros64() * 1000, PX4 the hrt clock in
        # ns; a reply with tc1 == 0 would read as a new request): at least 1 ns.
        if m.tc1 == 0:
            self._send(mavlink.MAVLink_timesync_message(
                max(1, wire.time_ns_from_s(now_s - self._boot_s)), m.ts1))

    def _on_ping(self, m, addr, now_s: float) -> None:
        # PING request: target_system == 0; reply targets the requester (common.xml PING).
        if m.target_system == 0:
            self._send(mavlink.MAVLink_ping_message(m.time_usec, m.seq, m.get_srcSystem(),
                                                   m.get_srcComponent()))

    def _on_setup_signing(self, m, addr, now_s: float) -> None:
        if m.target_system != self.sysid:
            self.stats.not_for_us += 1
            return
        if addr not in self.trusted_addrs or self.armed:
            self.stats.signing_rejected += 1
            self._warn_limited(now_s, "setup_signing", "sysid %d: SETUP_SIGNING from untrusted "
                               "link %s (or armed) refused", self.sysid, addr)
            return
        key = bytes(bytearray(m.secret_key)) if not isinstance(m.secret_key, bytes) else m.secret_key
        self._codec.set_signing_key(key, initial_timestamp=m.initial_timestamp)
        enabled = self._codec.signing_enabled
        log.info("sysid %d: signing %s via SETUP_SIGNING", self.sysid,
                 "enabled" if enabled else "disabled")
        self._events.append(ev.SigningChanged(self.sysid, now_s, enabled))

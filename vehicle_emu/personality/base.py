"""What both autopilot personalities share, and the hooks where they differ.

A personality is a strategy object bound to one :class:`vehicle_emu.link.VehicleCore`
(``self.core``): it reads and changes the core's autopilot state (``armed``, ``_mode_key``,
``_behaviour``, targets) and its row of the shared physics. Class attributes are the wire facts
and tables; methods are the firmware rules, each citing the source it follows.
"""

from __future__ import annotations

import math

import numpy as np

from mavedge import mavlink
from mavedge.units import deg_to_e7, e7_to_deg
from planner.geometry import geodetic_to_ned_m

from ..geodesy import NedOrigin, ned_origin

#: AUTOPILOT_VERSION.capabilities both firmwares announce and the emulator implements (each
#: personality adds its parameter encoding); FTP, SET_ATTITUDE_TARGET, FLIGHT_TERMINATION,
#: TERRAIN are left out on purpose: the emulator does not implement them and a GCS would try.
COMMON_CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
)

__all__ = [
    "Personality",
    "ap_check_latlng_e7",
    "px4_map_project",
    "FLT_MAX",
    "LOCAL_FRAMES",
    "GLOBAL_AMSL",
    "GLOBAL_REL",
    "TARGET_MASK_POSITION",
]

#: Largest finite float32: every float field on the wire (and every float in both firmwares'
#: position paths) is single precision.
FLT_MAX = float(np.finfo(np.float32).max)

LOCAL_FRAMES = (
    mavlink.MAV_FRAME_LOCAL_NED,
    mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
    mavlink.MAV_FRAME_BODY_NED,
    mavlink.MAV_FRAME_BODY_OFFSET_NED,
)
GLOBAL_AMSL = (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT)
GLOBAL_REL = (
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
)
#: type_mask of a position-only target (what POSITION_TARGET_* reports after a guided item).
TARGET_MASK_POSITION = 0b110111111000

#: ArduPilot AP_Math/location.cpp ``check_lat(int32_t)`` / ``check_lng(int32_t)``:
#: ``labs(lat) <= 90*1e7`` and ``labs(lng) <= 180*1e7`` (degE7, bounds included).
_AP_LAT_E7_MAX, _AP_LON_E7_MAX = 900_000_000, 1_800_000_000
#: PX4 lib/geo/geo.h CONSTANTS_RADIUS_OF_EARTH (m), used by MapProjection.
_PX4_EARTH_RADIUS_M = 6371000.0


def ap_check_latlng_e7(lat_e7: int, lon_e7: int) -> bool:
    """ArduPilot ``check_latlng(int32_t lat, int32_t lng)`` (AP_Math/location.cpp)."""
    return abs(int(lat_e7)) <= _AP_LAT_E7_MAX and abs(int(lon_e7)) <= _AP_LON_E7_MAX


def px4_map_project(
    lat_deg: float, lon_deg: float, ref_lat_deg: float, ref_lon_deg: float
) -> tuple[float, float]:
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


class Personality:
    """Firmware rules of one autopilot, bound to ``core``. Subclasses fill the tables."""

    name = ""
    autopilot = mavlink.MAV_AUTOPILOT_GENERIC
    """HEARTBEAT.autopilot."""
    sysid_param = ""
    """Parameter holding the vehicle's own sysid."""
    modes: dict[int, tuple[str, str]] = {}
    """HEARTBEAT.custom_mode -> (name, behaviour); behaviours 'guided', 'hold', 'rtl', 'land',
    'takeoff'."""
    boot_mode = 0
    land_mode = 0
    rtl_mode = 0
    reposition_mode = 0
    """The mode DO_REPOSITION flies in."""
    default_rates_hz: dict[int, float] = {}
    """Streams sent without being asked (msg id -> Hz)."""
    arm_reject = mavlink.MAV_RESULT_FAILED
    """COMMAND_ACK result of a refused arm / disarm / takeoff."""
    no_such_message = mavlink.MAV_RESULT_FAILED
    """COMMAND_ACK result of REQUEST_MESSAGE for a message the vehicle cannot send."""
    param_bytewise = False
    """PARAM_VALUE integers are copied byte-wise (PX4) rather than C-cast (ArduPilot)."""
    capabilities = 0
    """AUTOPILOT_VERSION.capabilities."""
    sw_version = 0
    """AUTOPILOT_VERSION.flight_sw_version."""
    sys_status_health_extra = 0
    """SYS_STATUS health bits reported on top of the present sensors."""
    estimator_msgid: int | None = None
    """The navigation filter's report this firmware streams (ArduPilot EKF_STATUS_REPORT, PX4
    ESTIMATOR_STATUS); the other one is refused."""
    mission_home_items = 0
    """Items of a mission list that are not part of the mission (ArduPilot's home at seq 0)."""
    global_frames: tuple[int, ...] = ()
    """Frames accepted for SET_POSITION_TARGET_GLOBAL_INT / global commands."""
    guided_mission_items = False
    """MISSION_ITEM(_INT) with current = 2 / 3 are guided waypoints (ArduPilot)."""

    def __init__(self, core) -> None:
        self.core = core
        self._ned_origin_of: tuple | None = None
        """The ``physics.origin_lla`` tuple :attr:`_ned_origin` was made for."""
        self._ned_origin: NedOrigin | None = None

    # -- modes ----------------------------------------------------------------------------

    def mode_info(self, key: int) -> tuple[str, str] | None:
        """(name, behaviour) of a custom_mode value, None if the firmware has no such mode."""
        return self.modes.get(key)

    def cmd_set_mode(self, p: tuple, now_s: float) -> int:
        """MAV_CMD_DO_SET_MODE (params 1-3); returns the MAV_RESULT."""
        raise NotImplementedError

    def on_set_mode_message(self, m, now_s: float) -> None:
        """SET_MODE (message 11), already checked to be for us: set and acknowledge."""
        raise NotImplementedError

    def refuse_auto(self, now_s: float, result: int) -> int:
        """AUTO / AUTO.MISSION is not flown by this emulator: refuse it loudly.

        With no mission stored both firmwares refuse too: ArduCopter ModeAuto::init needs
        ``mission.num_commands() > 1`` ("Flight mode change failed"); PX4 Commander denies
        Mission mode without a valid mission. With a stored mission the firmware would fly it;
        the emulator stores uploads but says it does not fly them (a GCS must not believe the
        vehicle is flying a plan)."""
        core = self.core
        if core._missions.has_mission():
            core._statustext(
                now_s, mavlink.MAV_SEVERITY_WARNING, "Emulator: AUTO missions are not flown"
            )
        else:
            core._statustext(now_s, *self.no_mission_text)
        return result

    no_mission_text: tuple[int, str] = (mavlink.MAV_SEVERITY_WARNING, "")
    gcs_regained_text: tuple[int, str] = (mavlink.MAV_SEVERITY_INFO, "")
    """(severity, STATUSTEXT) when GCS heartbeats come back after a GCS failsafe, in the
    firmware's own words (each personality); empty: nothing is said."""

    def resume_offboard(self, now_s: float) -> bool:
        """On entering the guided mode: fly a setpoint kept from before (PX4); True if so."""
        return False

    # -- arming and takeoff ---------------------------------------------------------------

    def arm_refusal(self, now_s: float) -> str | None:
        """Pre-arm mode check: the STATUSTEXT of a refusal, or None to arm."""
        raise NotImplementedError

    def on_armed(self, now_s: float) -> None:
        """After arming (the physics already holds)."""

    def auto_disarm_delay_s(self) -> float:
        """How long an armed vehicle may sit on the ground before it disarms itself."""
        raise NotImplementedError

    def cmd_takeoff(self, p: tuple, now_s: float) -> tuple[int, float | None]:
        """MAV_CMD_NAV_TAKEOFF checks: (result, altitude above home or None when refused)."""
        raise NotImplementedError

    def on_takeoff_reached(self, now_s: float, behaviour: str) -> None:
        """The takeoff altitude was reached."""

    # -- failsafes ------------------------------------------------------------------------

    def guided_watchdog(self, now_s: float, behaviour: str) -> None:
        """Per-tick check of the guided mode's input (velocity timeout, offboard signal); the
        core calls it only while ``behaviour == 'guided'`` (it does nothing in other modes)."""

    def accepts_gcs_heartbeat(self, src_sysid: int) -> bool:
        """Whether a MAV_TYPE_GCS heartbeat from ``src_sysid`` keeps the link alive."""
        raise NotImplementedError

    def gcs_failsafe_config(self) -> tuple[bool, float]:
        """(enabled, timeout_s) of the GCS-loss failsafe: a function of ``core.params`` alone
        (the core keeps it until the table's ``stamp`` changes)."""
        raise NotImplementedError

    def gcs_failsafe_action(self, now_s: float) -> str:
        """Act on a lost GCS link while armed and flying; returns the action's name."""
        raise NotImplementedError

    # -- setpoints ------------------------------------------------------------------------

    def note_setpoint_mask(self, mask: int, now_s: float) -> None:
        """A setpoint in a supported frame arrived with ``mask`` (PX4 offboard signal)."""

    def local_target_unusable(self, m) -> bool:
        """SET_POSITION_TARGET_LOCAL_NED values the firmware cannot use (ignored)."""
        return False

    def on_bad_global_target(self) -> None:
        """A global target whose position the firmware refuses."""

    def accept_target(self, target, now_s: float) -> None:
        """A finite (pos, vel, mask) target: keep, fly or ignore it."""
        raise NotImplementedError

    def limit_target_position(self, pos):
        """The position the controller actually flies towards (``pos`` by default)."""
        return pos

    def can_fly_target(self) -> bool:
        return True

    def on_empty_target(self) -> None:
        """A target with neither position nor velocity (acceleration / yaw only)."""

    def reposition_xy(self, x: int, y: int) -> tuple[int, int, bool] | None:
        """DO_REPOSITION x / y (degE7): (x, y, keep_horizontal), or None to deny."""
        return x, y, False

    def precheck_latlng(self, lat_e7: int, lon_e7: int) -> bool:
        """Whether a global target passes the firmware's range check before its frame."""
        return True

    def off_globe(
        self, lat_e7: int, lon_e7: int, lat_deg: float, lon_deg: float, alt_amsl_m: float
    ):
        """World NED (m) of an off-globe target the firmware still flies to, else None."""
        return None

    def global_to_world(self, lat_e7: int, lon_e7: int, alt_m: float, frame: int):
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
        core = self.core
        if not self.precheck_latlng(lat_e7, lon_e7):
            return None
        if frame not in self.global_frames:
            return None
        if frame in GLOBAL_AMSL:
            alt_amsl = alt_m
        else:  # GLOBAL_REL: flat terrain at home altitude, terrain-relative == home-relative
            alt_amsl = alt_m + core.home_lla[2]
        lat_deg, lon_deg = e7_to_deg(lat_e7), e7_to_deg(lon_e7)
        if not ap_check_latlng_e7(lat_e7, lon_e7):
            pos = self.off_globe(lat_e7, lon_e7, lat_deg, lon_deg, alt_amsl)
            if pos is not None:
                return pos
        # geodetic_to_ned_m to the bit, without its per-call origin work (vehicle_emu/geodesy.py)
        origin_lla = core.physics.origin_lla
        nedo = self._ned_origin
        if nedo is None or origin_lla is not self._ned_origin_of:
            nedo = self._ned_origin = ned_origin(*origin_lla)
            self._ned_origin_of = origin_lla
        return nedo.ned_m(lat_deg, lon_deg, alt_amsl)

    def home_e7(self) -> tuple[int, int]:
        return deg_to_e7(self.core.home_lla[0]), deg_to_e7(self.core.home_lla[1])

    # -- return (RTL) -------------------------------------------------------------------

    def rally_ne_m(self) -> np.ndarray:
        """(K, 2) world north / east (m) of the stored rally points, in upload order.

        Items in a global frame only (lat / lon in degE7); a point at lat = lon = 0 is skipped, as
        ArduPilot's ``AP_Rally::get_rally_point_with_index`` "sanity check" and PX4's
        ``RTL::extractValidSafePointPosition`` (null island) both do. The altitude of a rally point
        is not used: the emulator returns at the RTL altitude (see :meth:`rtl_destination_ned_m`).
        """
        core = self.core
        out = []
        for it in core._missions.items.get(mavlink.MAV_MISSION_TYPE_RALLY, ()):
            if it.frame not in GLOBAL_AMSL + GLOBAL_REL or (it.x == 0 and it.y == 0):
                continue
            ned = geodetic_to_ned_m(
                e7_to_deg(it.x), e7_to_deg(it.y), core.home_lla[2], *core.physics.origin_lla
            )
            out.append((float(ned[0]), float(ned[1])))
        return np.array(out, dtype=float).reshape(-1, 2)

    def update(self, now_s: float) -> None:
        """Every tick, after the core's timers: the firmware's own periodic work."""

    def command_int_frame(self, frame: int) -> int:
        """The frame a COMMAND_INT's x / y / z are read in (the firmware may ignore the one sent)."""
        return frame

    def rtl_destination_ned_m(self, now_s: float) -> np.ndarray:
        """World NED (m) of where RTL flies, chosen when RTL starts (down: home's; the return
        altitude is the core's). Home here; each firmware's rally-point rule in the subclasses."""
        return self.core.home_ned_m.copy()

    def _rally_or_home(self, ne_m: np.ndarray | None) -> np.ndarray:
        """Home, or the rally point ``ne_m`` at home's down."""
        home = self.core.home_ned_m
        if ne_m is None:
            return home.copy()
        return np.array((ne_m[0], ne_m[1], home[2]), dtype=float)

    # -- streams and parameters -----------------------------------------------------------

    def on_request_data_stream(self, m, now_s: float) -> None:
        """REQUEST_DATA_STREAM, already checked to be for us."""

    def apply_params(self) -> None:
        """Derive SI limits from the parameter table (native units -> m, m/s) into the core."""
        raise NotImplementedError

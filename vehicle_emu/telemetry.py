"""Telemetry of one emulated vehicle: the message builders and the stream scheduler.

A builder turns a :class:`vehicle_emu.link.VehicleCore`'s state (its physics row, mode, arming)
into one pymavlink message, in wire units through :mod:`mavedge.units`; what differs between
autopilots comes from the core's personality (``core.pers``: HEARTBEAT.autopilot, capabilities,
health bits). :class:`StreamScheduler` keeps each stream's interval and next due time, the way
both firmwares' stream code does (phase kept, no burst to catch up after a gap).
"""

from __future__ import annotations

import math
from typing import Any, SupportsFloat

import numpy as np

from mavedge import mavlink
from mavedge.units import (
    deg_to_e7,
    m_s_to_cm_s,
    m_to_mm,
    s_to_time_boot_ms,
    s_to_time_usec,
    yaw_rad_to_hdg_cdeg,
)
from planner.geometry import DOWN, EAST, NORTH

from . import _kernels
from .physics import CTRL_VEL

__all__ = [
    "StreamScheduler",
    "BUILDERS",
    "f32",
    "M_HEARTBEAT",
    "M_SYS_STATUS",
    "M_GPS_RAW_INT",
    "M_LOCAL_POSITION_NED",
    "M_GLOBAL_POSITION_INT",
    "M_GPS_GLOBAL_ORIGIN",
    "M_POSITION_TARGET_LOCAL_NED",
    "M_POSITION_TARGET_GLOBAL_INT",
    "M_AUTOPILOT_VERSION",
    "M_HOME_POSITION",
    "M_EXTENDED_SYS_STATE",
    "M_MISSION_CURRENT",
    "M_ATTITUDE",
    "M_VFR_HUD",
    "M_BATTERY_STATUS",
    "M_EKF_STATUS_REPORT",
    "M_ESTIMATOR_STATUS",
    "satellites_of",
    "ESTIMATOR_FLAGS_OK",
    "ESTIMATOR_RATIO",
]

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
M_BATTERY_STATUS = mavlink.MAVLINK_MSG_ID_BATTERY_STATUS
M_EKF_STATUS_REPORT = mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT
M_ESTIMATOR_STATUS = mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS

#: What a healthy GPS-aided filter reports: attitude, horizontal and vertical velocity, relative
#: and absolute horizontal position, absolute vertical position, and both predicted horizontal
#: positions (EKF_STATUS_FLAGS / ESTIMATOR_STATUS_FLAGS share these bits; ArduPilot
#: libraries/AP_NavEKF3/AP_NavEKF3_Outputs.cpp NavEKF3_core::send_status_report, PX4
#: src/modules/mavlink/streams/ESTIMATOR_STATUS.hpp). No rangefinder: no AGL height.
ESTIMATOR_FLAGS_OK = 1 | 2 | 4 | 8 | 16 | 32 | 256 | 512
#: The filter's innovation test ratios (velocity, positions, compass) in steady flight: well
#: below 1.0, the rejection threshold.
ESTIMATOR_RATIO = 0.1

#: Largest finite float32 (every float field on the wire is single precision).
_FLT_MAX = float(np.finfo(np.float32).max)


def f32(v: SupportsFloat) -> float:
    """Saturate to the float32 range so that packing a wire float never overflows (NaN kept)."""
    v = float(v)
    return _FLT_MAX if v > _FLT_MAX else (-_FLT_MAX if v < -_FLT_MAX else v)


class StreamScheduler:
    """Interval and next due time of every stream of one vehicle (msg id -> seconds)."""

    __slots__ = ("default_interval_s", "interval_s", "next_due_s", "next_any_s", "_mirror")

    def __init__(self, default_rates_hz: dict[int, float], now_s: float) -> None:
        self.default_interval_s = {k: 1.0 / v for k, v in default_rates_hz.items()}
        self.interval_s: dict[int, float] = dict(self.default_interval_s)
        self.next_due_s: dict[int, float] = {k: float(now_s) for k in self.interval_s}
        self.next_any_s = min(self.next_due_s.values(), default=math.inf)
        """Earliest due time of any stream (a swarm skips vehicles with nothing due)."""
        self._mirror: tuple[Any, int] | None = None

    def mirror_into(self, array, index: int) -> None:
        """Keep ``array[index]`` equal to :attr:`next_any_s` (a swarm's vector of them)."""
        self._mirror = (array, index)
        array[index] = self.next_any_s

    def _update_next_any(self) -> None:
        self.next_any_s = nxt = min(self.next_due_s.values(), default=math.inf)
        if self._mirror is not None:
            self._mirror[0][self._mirror[1]] = nxt

    def set_interval(self, msg_id: int, interval_s: float, now_s: float) -> bool:
        """Stream ``msg_id`` every ``interval_s`` (0 = default, < 0 = off); False if we have
        no builder for it (MAV_CMD_SET_MESSAGE_INTERVAL is then refused)."""
        if msg_id not in BUILDERS:
            return False
        if interval_s == 0:  # 0 = default rate
            interval_s = self.default_interval_s.get(msg_id, -1.0)
        if interval_s < 0:
            self.interval_s.pop(msg_id, None)
            self.next_due_s.pop(msg_id, None)
        else:
            interval_s = max(interval_s, 0.001)
            self.interval_s[msg_id] = interval_s
            self.next_due_s[msg_id] = now_s
        self._update_next_any()
        return True

    def due(self, now_s: float) -> list[int]:
        """Message ids due at ``now_s``, each rescheduled: keep phase, but never burst to catch
        up after a long gap."""
        out = []
        due = self.next_due_s
        intervals = self.interval_s
        # min(next_due_s.values(), default=inf) after the update, in the same pass (the same
        # comparisons as min: the first value, replaced by any later one that is smaller)
        nxt_any = None
        for msg_id, t_due in due.items():
            if now_s + 1e-9 >= t_due:
                nxt = t_due + intervals[msg_id]
                t_due = due[msg_id] = nxt if nxt > now_s else now_s + intervals[msg_id]
                out.append(msg_id)
            if nxt_any is None or t_due < nxt_any:
                nxt_any = t_due
        if nxt_any is None:
            nxt_any = math.inf
        self.next_any_s = nxt_any
        if self._mirror is not None:
            self._mirror[0][self._mirror[1]] = nxt_any
        return out


# --------------------------------------------------------------------------------------------
# Builders: (core, now_s) -> pymavlink message
# --------------------------------------------------------------------------------------------


def _boot_ms(core, now_s: float) -> int:
    return s_to_time_boot_ms(now_s - core._boot_s)


def heartbeat(core, now_s: float):
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    if core._behaviour != "hold":
        base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
    if core.armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    if core.gcs_failsafe and core.armed:
        status = mavlink.MAV_STATE_CRITICAL
    else:
        status = mavlink.MAV_STATE_ACTIVE if core.armed else mavlink.MAV_STATE_STANDBY
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, core.pers.autopilot, base, core._mode_key, status, 3
    )


SYS_STATUS_SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
)


def sys_status(core, now_s: float):
    if core.batt is not None:
        return _sys_status_battery(core)
    sensors = SYS_STATUS_SENSORS
    batt = float(core.physics.battery_frac[core.index])
    health = sensors | core.pers.sys_status_health_extra
    return mavlink.MAVLink_sys_status_message(
        sensors,
        sensors,
        health,
        100,
        int(10500 + 2100 * batt),
        -1,
        int(round(batt * 100)),
        0,
        0,
        0,
        0,
        0,
        0,
    )


def _sys_status_battery(core):
    """SYS_STATUS of a vehicle with a battery: the battery fields and sensor bits as its
    firmware fills them (vehicle_emu.battery_monitor)."""
    bits, health_bit, voltage_mv, current_ca, remaining = core.batt.sys_status_fields()
    sensors = SYS_STATUS_SENSORS | bits
    health = SYS_STATUS_SENSORS | health_bit | core.pers.sys_status_health_extra
    return mavlink.MAVLink_sys_status_message(
        sensors, sensors, health, 100, voltage_mv, current_ca, remaining, 0, 0, 0, 0, 0, 0
    )


def battery_status(core, now_s: float):
    """BATTERY_STATUS as the vehicle's firmware fills it (vehicle_emu.battery_monitor)."""
    if core.batt is None:
        raise ValueError("BATTERY_STATUS of a vehicle without a battery")
    return core.batt.battery_status(now_s)


def global_position_int(core, now_s: float):
    ph, i = core.physics, core.index
    vel = ph.vel_ned_m_s[i]
    alt = float(ph.alt_amsl_m[i])
    return mavlink.MAVLink_global_position_int_message(
        _boot_ms(core, now_s),
        deg_to_e7(ph.lat_deg[i]),
        deg_to_e7(ph.lon_deg[i]),
        m_to_mm(alt),
        m_to_mm(alt - core.home_lla[2]),
        m_s_to_cm_s(vel[NORTH]),
        m_s_to_cm_s(vel[EAST]),
        m_s_to_cm_s(vel[DOWN]),
        yaw_rad_to_hdg_cdeg(ph.yaw_rad[i]),
    )


def local_position_ned(core, now_s: float):
    ph, i = core.physics, core.index
    p = ph.pos_ned_m[i] - core.home_ned_m
    v = ph.vel_ned_m_s[i]
    return mavlink.MAVLink_local_position_ned_message(
        _boot_ms(core, now_s),
        *(f32(c) for c in (p[NORTH], p[EAST], p[DOWN], v[NORTH], v[EAST], v[DOWN])),
    )


def satellites_of(sysid):
    """Satellites the emulated receiver sees: 10..16 by sysid (a fixed sky per vehicle, so a
    page or a test can tell vehicles apart; the emulator has no GNSS model)."""
    return 10 + sysid % 7


def gps_raw_int(core, now_s: float):
    ph, i = core.physics, core.index
    v = ph.vel_ned_m_s[i]
    speed = math.hypot(v[NORTH], v[EAST])
    cog = yaw_rad_to_hdg_cdeg(math.atan2(v[EAST], v[NORTH])) if speed > 0.1 else 65535
    return mavlink.MAVLink_gps_raw_int_message(
        s_to_time_usec(now_s - core._boot_s),
        mavlink.GPS_FIX_TYPE_3D_FIX,
        deg_to_e7(ph.lat_deg[i]),
        deg_to_e7(ph.lon_deg[i]),
        m_to_mm(ph.alt_amsl_m[i]),
        80,
        120,
        min(65534, int(round(speed * 100))),
        cog,
        satellites_of(core.sysid),
    )


def home_position(core, now_s: float):
    lat, lon, alt = core.home_lla
    return mavlink.MAVLink_home_position_message(
        deg_to_e7(lat),
        deg_to_e7(lon),
        m_to_mm(alt),
        0.0,
        0.0,
        0.0,
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        0.0,
        0.0,
        s_to_time_usec(now_s - core._boot_s),
    )


def gps_global_origin(core, now_s: float):
    lat, lon, alt = core.home_lla
    return mavlink.MAVLink_gps_global_origin_message(
        deg_to_e7(lat), deg_to_e7(lon), m_to_mm(alt), s_to_time_usec(now_s - core._boot_s)
    )


def attitude(core, now_s: float):
    """ATTITUDE: level flight, yaw along the velocity (the physics has no attitude)."""
    yaw = float(core.physics.yaw_rad[core.index])
    yaw = math.atan2(math.sin(yaw), math.cos(yaw))  # -pi..pi (common.xml ATTITUDE.yaw)
    return mavlink.MAVLink_attitude_message(_boot_ms(core, now_s), 0.0, 0.0, yaw, 0.0, 0.0, 0.0)


def vfr_hud(core, now_s: float):
    """VFR_HUD (GCS_Common.cpp send_vfr_hud): alt is AMSL (vfr_hud_alt), climb up-positive,
    heading 0..360 deg; throttle is a hover guess when flying."""
    ph, i = core.physics, core.index
    v = ph.vel_ned_m_s[i]
    speed = math.hypot(v[NORTH], v[EAST])
    heading = yaw_rad_to_hdg_cdeg(ph.yaw_rad[i]) // 100
    throttle = 0 if ph.landed[i] or not core.armed else 50
    return mavlink.MAVLink_vfr_hud_message(
        speed, speed, heading, throttle, float(ph.alt_amsl_m[i]), float(-v[DOWN])
    )


def mission_current(core, now_s: float):
    """MISSION_CURRENT: no item is ever active (AUTO is not flown). ``total`` excludes
    ArduPilot's home item (common.xml MISSION_CURRENT.total)."""
    total = core._missions.count(mavlink.MAV_MISSION_TYPE_MISSION) - core.pers.mission_home_items
    state = mavlink.MISSION_STATE_NOT_STARTED if total > 0 else mavlink.MISSION_STATE_NO_MISSION
    return mavlink.MAVLink_mission_current_message(0, total, state, 0)


def extended_sys_state(core, now_s: float):
    ph, i = core.physics, core.index
    if ph.landed[i]:
        state = mavlink.MAV_LANDED_STATE_ON_GROUND
    elif ph.vel_ned_m_s[i, DOWN] > 0.2 and core._behaviour in ("land", "rtl"):
        state = mavlink.MAV_LANDED_STATE_LANDING
    elif core._takeoff_target_down_m is not None:
        state = mavlink.MAV_LANDED_STATE_TAKEOFF
    else:
        state = mavlink.MAV_LANDED_STATE_IN_AIR
    return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_MC, state)


def _target_local(core):
    ph, i = core.physics, core.index
    if ph.ctrl[i] == CTRL_VEL:
        return np.zeros(3), ph.target_vel_ned_m_s[i], 0b110111000111
    return ph.target_pos_ned_m[i] - core.home_ned_m, ph.target_vel_ned_m_s[i], 0b110111000000


def position_target_local_ned(core, now_s: float):
    p, v, mask = _target_local(core)
    return mavlink.MAVLink_position_target_local_ned_message(
        _boot_ms(core, now_s),
        mavlink.MAV_FRAME_LOCAL_NED,
        mask,
        *(f32(c) for c in (p[0], p[1], p[2], v[0], v[1], v[2])),
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
    )


def position_target_global_int(core, now_s: float):
    ph, i = core.physics, core.index
    _, v, mask = _target_local(core)
    lat, lon, alt = _kernels.ned_to_geodetic(ph.target_pos_ned_m[i], *ph.origin_lla)
    return mavlink.MAVLink_position_target_global_int_message(
        _boot_ms(core, now_s),
        mavlink.MAV_FRAME_GLOBAL_INT,
        mask,
        deg_to_e7(lat),
        deg_to_e7(lon),
        *(f32(c) for c in (alt, v[0], v[1], v[2])),
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
    )


def autopilot_version(core, now_s: float):
    # Capabilities and version per personality (vehicle_emu.personality.*).
    uid = (core.network << 16) | core.sysid
    return mavlink.MAVLink_autopilot_version_message(
        core.pers.capabilities, core.pers.sw_version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, uid
    )


def ekf_status_report(core, now_s: float):
    """ArduPilot's EKF_STATUS_REPORT (a healthy filter)."""
    r = ESTIMATOR_RATIO
    return mavlink.MAVLink_ekf_status_report_message(ESTIMATOR_FLAGS_OK, r, r, r, r, 0.0, 0.0)


def estimator_status(core, now_s: float):
    """PX4's ESTIMATOR_STATUS (a healthy filter)."""
    r = ESTIMATOR_RATIO
    return mavlink.MAVLink_estimator_status_message(
        s_to_time_usec(now_s - core._boot_s), ESTIMATOR_FLAGS_OK, r, r, r, r, 0.0, 0.0, 0.5, 0.5
    )


#: msg id -> builder(core, now_s).
BUILDERS = {
    M_HEARTBEAT: heartbeat,
    M_SYS_STATUS: sys_status,
    M_GPS_RAW_INT: gps_raw_int,
    M_LOCAL_POSITION_NED: local_position_ned,
    M_GLOBAL_POSITION_INT: global_position_int,
    M_GPS_GLOBAL_ORIGIN: gps_global_origin,
    M_POSITION_TARGET_LOCAL_NED: position_target_local_ned,
    M_POSITION_TARGET_GLOBAL_INT: position_target_global_int,
    M_AUTOPILOT_VERSION: autopilot_version,
    M_HOME_POSITION: home_position,
    M_EXTENDED_SYS_STATE: extended_sys_state,
    M_MISSION_CURRENT: mission_current,
    M_ATTITUDE: attitude,
    M_VFR_HUD: vfr_hud,
    M_BATTERY_STATUS: battery_status,
    M_EKF_STATUS_REPORT: ekf_status_report,
    M_ESTIMATOR_STATUS: estimator_status,
}

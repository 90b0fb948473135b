"""ArduPilot Copter (4.6) as a GCS meets it over MAVLink."""

from __future__ import annotations

import math

import numpy as np

from mavedge import mavlink
from mavedge.modes import ARDUCOPTER_MODES
from vehicle_emu.telemetry import M_HEARTBEAT

from .base import (
    COMMON_CAPABILITIES,
    FLT_MAX,
    GLOBAL_AMSL,
    GLOBAL_REL,
    Personality,
    ap_check_latlng_e7,
)

__all__ = ["ArduPilot", "ARDUPILOT_MODES", "AP_AUTO", "AP_GUIDED", "AP_LOITER", "AP_RTL", "AP_LAND"]

_C = mavlink

#: ArduCopter mode numbers (HEARTBEAT.custom_mode, mavedge.modes from pymavlink COPTER_MODE)
#: -> (name, behaviour). Modes that need a pilot (STABILIZE, ALT_HOLD, ...) hold position:
#: there is no RC here.
_BEHAVIOURS = {
    "STABILIZE": "hold",
    "ACRO": "hold",
    "ALT_HOLD": "hold",
    "AUTO": "hold",
    "GUIDED": "guided",
    "LOITER": "hold",
    "RTL": "rtl",
    "CIRCLE": "hold",
    "LAND": "land",
    "POSHOLD": "hold",
    "BRAKE": "hold",
    "SMART_RTL": "rtl",
}
ARDUPILOT_MODES: dict[int, tuple[str, str]] = {
    ARDUCOPTER_MODES[name]: (name, beh) for name, beh in _BEHAVIOURS.items()
}
AP_AUTO, AP_GUIDED, AP_LOITER, AP_RTL, AP_LAND = 3, 4, 5, 6, 9
#: ArduCopter ``Mode::allows_arming`` is false for AUTO (without AUTO_OPTIONS), RTL, LAND,
#: SMART_RTL, BRAKE, CIRCLE (ArduCopter/mode_*.h).
_AP_ARMABLE = frozenset({0, 1, 2, 4, 5, 16})
#: Modes whose ``is_autopilot()`` is false (ArduCopter/mode.h): STABILIZE, ACRO, ALT_HOLD,
#: LOITER, POSHOLD, BRAKE. AUTO, GUIDED, RTL, CIRCLE, LAND and SMART_RTL are autopilot modes.
_AP_PILOT_MODES = frozenset({0, 1, 2, 5, 16, 17})

_M = mavlink
#: ArduCopter REQUEST_DATA_STREAM groups (ArduCopter/GCS_Mavlink.cpp ``STREAM_*_msgs``),
#: restricted to messages this emulator produces. EXTENDED_SYS_STATE and
#: POSITION_TARGET_LOCAL_NED are placed in EXTENDED_STATUS (approximation).
AP_STREAM_GROUPS = {
    _M.MAV_DATA_STREAM_EXTENDED_STATUS: (
        _M.MAVLINK_MSG_ID_SYS_STATUS,
        _M.MAVLINK_MSG_ID_GPS_RAW_INT,
        _M.MAVLINK_MSG_ID_MISSION_CURRENT,
        _M.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT,
        _M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
        _M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED,
    ),
    _M.MAV_DATA_STREAM_POSITION: (
        _M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
        _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    ),
    _M.MAV_DATA_STREAM_EXTRA1: (_M.MAVLINK_MSG_ID_ATTITUDE,),
    _M.MAV_DATA_STREAM_EXTRA2: (_M.MAVLINK_MSG_ID_VFR_HUD,),
    # STREAM_EXTRA3_msgs: MSG_BATTERY_STATUS (refused by a vehicle without a battery),
    # MSG_EKF_STATUS_REPORT.
    _M.MAV_DATA_STREAM_EXTRA3: (
        _M.MAVLINK_MSG_ID_BATTERY_STATUS,
        _M.MAVLINK_MSG_ID_EKF_STATUS_REPORT,
    ),
}


class ArduPilot(Personality):
    """ArduCopter: GUIDED takes targets, GCS failsafe after FS_GCS_TIMEOUT, C-cast params."""

    name = "ardupilot"
    autopilot = _C.MAV_AUTOPILOT_ARDUPILOTMEGA
    sysid_param = "SYSID_THISMAV"
    modes = ARDUPILOT_MODES
    boot_mode = 0  # STABILIZE
    land_mode = AP_LAND
    rtl_mode = AP_RTL
    reposition_mode = AP_GUIDED
    #: ArduPilot streams nothing but HEARTBEAT until asked (measured on SITL,
    #: docs/design/mavlink.md §5.1).
    default_rates_hz = {M_HEARTBEAT: 1.0}
    arm_reject = _C.MAV_RESULT_FAILED
    # GCS_Common.cpp handle_command_request_message: no ap_message for the id -> FAILED.
    no_such_message = _C.MAV_RESULT_FAILED
    param_bytewise = False
    # ArduCopter GCS_Mavlink.cpp GCS_MAVLINK_Copter::capabilities (+ GCS_Common: C_CAST,
    # MAVLINK2, MISSION_FENCE, MISSION_RALLY), less what the emulator lacks (base.py).
    capabilities = COMMON_CAPABILITIES | _C.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    sw_version = (4 << 24) | (6 << 16) | (0 << 8) | 0xFF  # 4.6.0 official
    # GCS_Common.cpp update_sensor_status_flags: GEOFENCE is "healthy" unless the fence has
    # failed, even when no fence is present (MAVProxy's fence module reports "fence breach"
    # otherwise).
    sys_status_health_extra = _C.MAV_SYS_STATUS_GEOFENCE
    # AP_NavEKF3_Outputs.cpp NavEKF3_core::send_status_report, in STREAM_EXTRA3.
    estimator_msgid = _C.MAVLINK_MSG_ID_EKF_STATUS_REPORT
    mission_home_items = 1
    # mavlink_coordinate_frame_to_location_alt_frame: 0, 3, 10 and the _INT frames 5, 6, 11.
    global_frames = GLOBAL_AMSL + GLOBAL_REL
    guided_mission_items = True
    no_mission_text = (_C.MAV_SEVERITY_WARNING, "Flight mode change failed")
    # ArduCopter/events.cpp Copter::failsafe_gcs_off_event: send_text(MAV_SEVERITY_WARNING, ...).
    gcs_regained_text = (_C.MAV_SEVERITY_WARNING, "GCS Failsafe Cleared")

    # -- modes ----------------------------------------------------------------------------

    def cmd_set_mode(self, p: tuple, now_s: float) -> int:
        if not all(math.isfinite(v) for v in p[:3]):
            return _C.MAV_RESULT_DENIED
        if not int(p[0]) & _C.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return _C.MAV_RESULT_UNSUPPORTED
        custom = int(p[1])
        if custom not in ARDUPILOT_MODES:
            return _C.MAV_RESULT_FAILED
        if custom == AP_AUTO:
            return self.refuse_auto(now_s, _C.MAV_RESULT_FAILED)
        self.core._set_mode(custom, now_s, "command")
        return _C.MAV_RESULT_ACCEPTED

    def on_set_mode_message(self, m, now_s: float) -> None:
        result = self.cmd_set_mode((m.base_mode, m.custom_mode, 0), now_s)
        # ArduPilot acks SET_MODE with command = 11 (the message id), GCS_Common.cpp
        # handle_set_mode: "extraordinarily improper ... but mavproxy needs it".
        self.core._ack(_C.MAVLINK_MSG_ID_SET_MODE, result, m, now_s)

    # -- arming and takeoff ---------------------------------------------------------------

    def arm_refusal(self, now_s: float) -> str | None:
        if self.core._mode_key not in _AP_ARMABLE:
            return "Arm: Mode not armable"
        return None

    def auto_disarm_delay_s(self) -> float:
        # ArduCopter motors.cpp auto_disarm_check (DISARM_DELAY, default 10 s).
        return self.core.params["DISARM_DELAY"]

    def cmd_takeoff(self, p: tuple, now_s: float) -> tuple[int, float | None]:
        """ArduCopter Mode::do_user_takeoff: armed, landed, a mode with user takeoff (GUIDED),
        target above the current altitude; param7 = altitude above home (m)."""
        core = self.core
        ph, i = core.physics, core.index
        alt_above_home = p[6]
        if not core.armed or not ph.landed[i] or core._mode_key != AP_GUIDED:
            return self.arm_reject, None
        cur_alt = core.home_ned_m[2] - ph.pos_ned_m[i, 2]
        if not math.isfinite(alt_above_home) or alt_above_home <= cur_alt:
            return self.arm_reject, None
        return _C.MAV_RESULT_ACCEPTED, float(alt_above_home)

    # -- failsafes ------------------------------------------------------------------------

    def guided_watchdog(self, now_s: float, behaviour: str) -> None:
        # GUID_TIMEOUT: velocity/acceleration targets stop after the timeout (ArduCopter
        # mode_guided.cpp: ``if (millis() - update_time_ms > get_timeout_ms())`` zero the
        # velocity target). Position targets persist.
        core = self.core
        if (
            behaviour == "guided"
            and core._vel_target_s is not None
            and now_s - core._vel_target_s > core.params["GUID_TIMEOUT"]
        ):
            core._vel_target_s = None
            core.physics.command_velocity(core.index, (0.0, 0.0, 0.0))

    def accepts_gcs_heartbeat(self, src_sysid: int) -> bool:
        # ArduPilot counts only heartbeats from SYSID_MYGCS (GCS_Common.cpp handle_heartbeat).
        return src_sysid == int(self.core.params["SYSID_MYGCS"])

    def gcs_failsafe_config(self) -> tuple[bool, float]:
        P = self.core.params
        return P["FS_GCS_ENABLE"] > 0, P["FS_GCS_TIMEOUT"]

    def gcs_failsafe_action(self, now_s: float) -> str:
        core = self.core
        fs = int(core.params["FS_GCS_ENABLE"])
        if core._behaviour in ("rtl", "land"):
            # RTL: the failsafe's set_mode(RTL) is a no-op in RTL. LAND (simplification): the
            # firmware switches a landing copter to the FS_GCS_ENABLE action unless FS_OPTIONS
            # bit 3 (8, continue landing) is set; here it always continues landing.
            return "NONE"
        # ArduCopter/events.cpp Copter::failsafe_gcs_on_event, FS_OPTIONS (Copter.h
        # FailsafeOption): bit 1 (2, GCS_CONTINUE_IF_AUTO) continues AUTO; bit 4 (16,
        # GCS_CONTINUE_IF_PILOT_CONTROL) continues a mode with ``!flightmode->is_autopilot()``.
        # Bit 2 (4, RC_CONTINUE_IF_GUIDED) is the RC failsafe only: GUIDED is an autopilot mode
        # (mode.h ModeGuided::is_autopilot), so no bit keeps GUIDED on a GCS failsafe.
        opts = int(core.params["FS_OPTIONS"])
        if core._mode_key == AP_AUTO and opts & 2:
            return "NONE"
        if opts & 16 and core._mode_key in _AP_PILOT_MODES:
            return "NONE"
        mode = AP_LAND if fs == 5 else AP_RTL  # 1, 2, 3, 4 end in RTL here (no SmartRTL path)
        core._set_mode(mode, now_s, "failsafe")
        core._statustext(now_s, _C.MAV_SEVERITY_CRITICAL, "GCS Failsafe")
        return ARDUPILOT_MODES[mode][0]

    # -- setpoints ------------------------------------------------------------------------

    def local_target_unusable(self, m) -> bool:
        # ArduCopter/GCS_Mavlink.cpp handle_message_set_position_target_local_ned "convert to
        # cm": ``packet.x * 100.0f`` is +-inf in float beyond FLT_MAX / 100 (3.4e36 m): not a
        # usable target; the emulator's rule for non-finite input (ignore) applies.
        return any(abs(c) * 100.0 > FLT_MAX for c in (m.x, m.y, m.z, m.vx, m.vy, m.vz))

    def on_bad_global_target(self) -> None:
        core = self.core
        if core._behaviour == "guided" and core.armed:
            # ArduCopter: bad location or frame -> "input is not valid so stop"
            # (copter.mode_guided.init(true)): brake and hold.
            core.physics.hold(core.index)
            core._vel_target_s = None

    def accept_target(self, target, now_s: float) -> None:
        core = self.core
        if core._behaviour != "guided":
            # ArduCopter: "exit if vehicle is not in Guided mode or Auto-Guided mode".
            core.stats.setpoints_ignored += 1
            return
        if core.physics.landed[core.index] and core._takeoff_target_down_m is None:
            # ArduCopter guided on the ground: make_safe_ground_handling; take off first.
            core.stats.setpoints_ignored += 1
            return
        core._apply_target(target, now_s)

    def on_empty_target(self) -> None:
        # ArduCopter: "input is not valid so stop" -> mode_guided.init(true).
        self.core.physics.hold(self.core.index)

    def precheck_latlng(self, lat_e7: int, lon_e7: int) -> bool:
        # ArduCopter handle_command_int_do_reposition / set_position_target_global_int:
        # ``if (!check_latlng(packet.x, packet.y)) return MAV_RESULT_DENIED``.
        return ap_check_latlng_e7(lat_e7, lon_e7)

    # -- return (RTL) ---------------------------------------------------------------------

    def rtl_destination_ned_m(self, now_s: float) -> np.ndarray:
        """ArduCopter RTL returns to ``AP_Rally::calc_best_rally_or_home_location`` (ArduCopter/
        mode_rtl.cpp ``ModeRTL::compute_return_target``, at RTL entry through ``build_path``),
        libraries/AP_Rally/AP_Rally.cpp:

        * ``find_nearest_rally_point``: the nearest stored point (the first of equals, strict
          ``dis < min_dis``); none if ``RALLY_LIMIT_KM`` > 0 and it is farther than that (then home);
        * ``calc_best_rally_or_home_location``: that point if ``RALLY_INCL_HOME`` = 0 or it is
          nearer than home (strict ``<``), else home.

        ``AP_Rally_Copter::is_valid`` (the point inside the fence) is not modelled: every point is
        valid.
        """
        core = self.core
        pts = self.rally_ne_m()
        if len(pts) == 0:
            return self._rally_or_home(None)
        pos = core.physics.pos_ned_m[core.index, :2]
        dist = np.hypot(*(pts - pos).T)
        k = int(np.argmin(dist))  # first of equal minima, as the strict loop
        limit_km = float(core.params["RALLY_LIMIT_KM"])
        if limit_km > 0 and dist[k] > limit_km * 1000.0:
            return self._rally_or_home(None)
        d_home = float(np.hypot(*(core.home_ned_m[:2] - pos)))
        if not int(core.params["RALLY_INCL_HOME"]) or dist[k] < d_home:
            return self._rally_or_home(pts[k])
        return self._rally_or_home(None)

    # -- streams and parameters -----------------------------------------------------------

    def on_request_data_stream(self, m, now_s: float) -> None:
        groups = (
            list(AP_STREAM_GROUPS)
            if m.req_stream_id == _C.MAV_DATA_STREAM_ALL
            else [m.req_stream_id]
        )
        on = m.start_stop != 0 and m.req_message_rate > 0
        for g in groups:
            for msg_id in AP_STREAM_GROUPS.get(g, ()):
                self.core._set_interval(msg_id, 1.0 / m.req_message_rate if on else -1.0, now_s)

    def apply_params(self) -> None:
        core = self.core
        P, ph, i = core.params, core.physics, core.index
        core._guided_speed_m_s = P["WPNAV_SPEED"] / 100.0
        rtl_speed = P["RTL_SPEED"]
        core._auto_speed_m_s = (rtl_speed if rtl_speed > 0 else P["WPNAV_SPEED"]) / 100.0
        ph.climb_rate_m_s[i] = P["WPNAV_SPEED_UP"] / 100.0
        ph.descent_rate_m_s[i] = P["WPNAV_SPEED_DN"] / 100.0
        ph.land_speed_m_s[i] = P["LAND_SPEED"] / 100.0
        # mode.cpp Mode::land_run_vertical_control: LAND_SPEED_HIGH (0: WPNAV_SPEED_DN) down to
        # LAND_ALT_LOW (at least 1 m), then LAND_SPEED.
        high = P["LAND_SPEED_HIGH"]
        ph.land_fast_m_s[i] = (high if high > 0 else P["WPNAV_SPEED_DN"]) / 100.0
        ph.land_slow_alt_m[i] = ph.land_crawl_alt_m[i] = max(P["LAND_ALT_LOW"], 100.0) / 100.0
        core._rtl_alt_m = P["RTL_ALT"] / 100.0
        final = P["RTL_ALT_FINAL"] / 100.0
        core._rtl_hover_alt_m = final if final > 0 else None

"""PX4 (1.15) multicopter as a GCS meets it over MAVLink."""

from __future__ import annotations

import math

import numpy as np

from mavedge import mavlink
from mavedge.modes import PX4_NAMES, px4_custom_mode, px4_main_sub
from mavedge.setpoints import ACC_BITS, POS_BITS, VEL_BITS
from mavedge.units import INT32_MAX
from vehicle_emu import events as ev
from vehicle_emu.telemetry import (
    M_ESTIMATOR_STATUS,
    M_EXTENDED_SYS_STATE,
    M_GLOBAL_POSITION_INT,
    M_GPS_RAW_INT,
    M_HEARTBEAT,
    M_HOME_POSITION,
    M_LOCAL_POSITION_NED,
    M_POSITION_TARGET_GLOBAL_INT,
    M_POSITION_TARGET_LOCAL_NED,
    M_SYS_STATUS,
)

from mavedge.units import e7_to_deg
from planner.geometry import geodetic_to_ned_m

from .base import COMMON_CAPABILITIES, Personality, px4_map_project

__all__ = ["PX4", "PX4_MODES", "PX4_DEFAULT_RATES_HZ"]

_C = mavlink

#: PX4 (main, sub) (px4_custom_mode.h, names from mavedge.modes) -> (name, behaviour).
_BEHAVIOURS = {
    (1, 0): "hold",
    (2, 0): "hold",
    (3, 0): "hold",
    (4, 1): "hold",
    (4, 2): "takeoff",
    (4, 3): "hold",
    (4, 4): "hold",
    (4, 5): "rtl",
    (4, 6): "land",
    (5, 0): "hold",
    (6, 0): "guided",
    (7, 0): "hold",
}
PX4_MODES: dict[tuple[int, int], tuple[str, str]] = {
    pair: (PX4_NAMES[pair], beh) for pair, beh in _BEHAVIOURS.items()
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
#: src/modules/commander/failsafe/framework.cpp ``FailsafeBase::notifyUser``: for any action but
#: a warning, ``mavlink_log_critical(..., "Failsafe activated\t")`` is the one STATUSTEXT (the
#: cause and the new mode are sent as events only).
_PX4_FAILSAFE_TEXT = (_C.MAV_SEVERITY_CRITICAL, "Failsafe activated")
_PX4_NAV_STOP = frozenset({5, 6})

#: PX4's mavlink module streams without being asked (``src/modules/mavlink/mavlink_main.cpp``,
#: ``configure_streams_to_default``, MAVLINK_MODE_NORMAL/ONBOARD; rates approximate, Hz).
PX4_DEFAULT_RATES_HZ = {
    M_HEARTBEAT: 1.0,
    M_SYS_STATUS: 1.0,
    M_EXTENDED_SYS_STATE: 1.0,
    M_GLOBAL_POSITION_INT: 5.0,
    M_LOCAL_POSITION_NED: 5.0,
    M_GPS_RAW_INT: 1.0,
    M_HOME_POSITION: 0.5,
    M_POSITION_TARGET_LOCAL_NED: 1.5,
    M_POSITION_TARGET_GLOBAL_INT: 1.5,
    # mavlink_main.cpp Mavlink::configure_streams_to_default, MAVLINK_MODE_NORMAL.
    M_ESTIMATOR_STATUS: 0.5,
}

#: PX4 mavlink_receiver.cpp handle_message_command_int: x == y == INT32_MAX means "not given"
#: (param5/6 = NaN); x == y == 0x7ff80000 is "NAN was by accident sent as int" -> DENIED.
_NAN_AS_INT = 0x7FF80000
_ALL_GROUPS = POS_BITS | VEL_BITS | ACC_BITS


#: src/modules/navigator/rtl.cpp ``MAX_DIST_FROM_HOME_FOR_LAND_APPROACHES`` (m): rally points this
#: close to home are ignored; ``MIN_DIST_THRESHOLD`` (m): the margin a nearer point needs.
_PX4_RALLY_NEAR_HOME_M = 10.0
_PX4_RALLY_MIN_DIST_M = 2.0
#: The rally-point frames ``RTL::setSafepointAsDestination`` (rtl.cpp, PX4 up to main of
#: 2026-03-29) can fly to: 0 GLOBAL and 3 GLOBAL_RELATIVE_ALT. The mission receiver stores the
#: frame as sent (mavlink_mission.cpp ``parse_mavlink_mission_item``), so a frame-5/6 point is
#: stored, read back and still chosen by ``RTL::findClosestSafePoint``, but has no destination.
_PX4_RTL_FRAMES = (_C.MAV_FRAME_GLOBAL, _C.MAV_FRAME_GLOBAL_RELATIVE_ALT)
#: rtl.cpp ``RTL::on_inactive``: "Limit inactive calculation to 0.5Hz" (destination re-chosen,
#: and the frame complaint repeated, every 2 s while Return is not active).
_PX4_RTL_CHECK_PERIOD_S = 2.0
#: rtl.cpp ``RTL::setSafepointAsDestination``, ``mavlink_log_critical`` (severity 2).
_PX4_UNSUPPORTED_FRAME_TEXT = "RTL: unsupported MAV_FRAME"


#: Below this in every component a float32 norm of two or three components is finite:
#: (1e18 (1 + 2**-24))**2 * 3 < FLT_MAX (3.4e38).
_F32_NORM_SAFE = 1e18


def _f32_norm_overflows(vec) -> bool:
    """True when the float32 Euclidean norm of ``vec`` (2 or 3 components) is infinite (x*x
    overflows, or a component is not finite); Python floats for the usual small offsets, the
    float32 arithmetic (:func:`_f32_norm_overflows_ref`) otherwise."""
    safe = _F32_NORM_SAFE
    for c in vec:
        if not abs(c) < safe:  # NaN too
            return _f32_norm_overflows_ref(vec)
    return False


def _f32_norm_overflows_ref(vec) -> bool:
    """True when the float32 Euclidean norm of ``vec`` is infinite (x*x overflows)."""
    with np.errstate(over="ignore"):
        v = np.asarray(vec, dtype=np.float64).astype(np.float32)
        return not np.isfinite(np.sqrt(np.sum(v * v, dtype=np.float32)))


def _key(pair: tuple[int, int]) -> int:
    return px4_custom_mode(*pair)


class PX4(Personality):
    """PX4: OFFBOARD needs a setpoint stream, failsafes from NAV_DLL_ACT / COM_OBL_RC_ACT,
    byte-wise params, boots in Hold."""

    name = "px4"
    autopilot = _C.MAV_AUTOPILOT_PX4
    sysid_param = "MAV_SYS_ID"
    modes = {_key(pair): v for pair, v in PX4_MODES.items()}
    boot_mode = _key(PX4_LOITER)  # PX4 boots in Hold
    land_mode = _key(PX4_LAND)
    rtl_mode = _key(PX4_RTL)
    reposition_mode = _key(PX4_LOITER)
    default_rates_hz = PX4_DEFAULT_RATES_HZ
    estimator_msgid = M_ESTIMATOR_STATUS
    arm_reject = _C.MAV_RESULT_TEMPORARILY_REJECTED
    # mavlink_receiver.cpp handle_request_message_command: no stream sent -> DENIED.
    no_such_message = _C.MAV_RESULT_DENIED
    param_bytewise = True
    # mavlink_main.cpp send_autopilot_capabilities, less what the emulator lacks (base.py).
    capabilities = (
        COMMON_CAPABILITIES
        | _C.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        | _C.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    )
    sw_version = (1 << 24) | (15 << 16) | (0 << 8) | 0xFF  # 1.15.0 release
    sys_status_health_extra = 0
    mission_home_items = 0
    # handle_message_set_position_target_global_int accepts only the _INT frames 5, 6, 11
    # ("invalid coordinate frame" otherwise).
    global_frames = (
        _C.MAV_FRAME_GLOBAL_INT,
        _C.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        _C.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
    )
    # Frame 11 there is alt + vehicle_global_position.terrain_alt (the ground under the vehicle,
    # from a distance sensor), and the setpoint is dropped while terrain_alt_valid is false: the
    # emulated PX4 has no distance sensor (docs/terrain.md §6.2).
    terrain_setpoint_needs_estimate = True
    guided_mission_items = False
    no_mission_text = (_C.MAV_SEVERITY_CRITICAL, "Switching to Mission is currently not possible")
    # src/modules/commander/Commander.cpp Commander::dataLinkCheck: mavlink_log_info(...,
    # "GCS connection regained\t") when a GCS heartbeat ends a data-link loss.
    gcs_regained_text = (_C.MAV_SEVERITY_INFO, "GCS connection regained")

    def __init__(self, core) -> None:
        super().__init__(core)
        self._rtl_check_s = -math.inf
        """When Return last re-chose its destination while inactive (``RTL::on_inactive``)."""
        self.sp_last_s: float | None = None
        """When the last setpoint counting as offboard signal arrived."""
        self.offboard_target = None
        """The latest setpoint (pos, vel, mask); PX4 keeps it and flies it in OFFBOARD."""

    def _pair(self) -> tuple[int, int]:
        return px4_main_sub(self.core._mode_key)

    # -- offboard signal ------------------------------------------------------------------

    def offboard_signal_ok(self, now_s: float) -> bool:
        """PX4 HealthAndArmingChecks/checks/offboardCheck.cpp OffboardChecks::checkAndReport:
        ``data_is_recent = now < offboard_control_mode.timestamp + COM_OF_LOSS_T``; the mode
        requirement is only that, so ONE recent setpoint is enough to switch to OFFBOARD (the
        "stream for > 1 s at > 2 Hz" of the PX4 docs is advice, not a firmware check)."""
        return (
            self.sp_last_s is not None
            and now_s < self.sp_last_s + self.core.params["COM_OF_LOSS_T"]
        )

    def note_setpoint_mask(self, mask: int, now_s: float) -> None:
        """mavlink_receiver.cpp handle_message_set_position_target_local_ned / _global_int
        publish ``offboard_control_mode`` (timestamp = now) when ocm.position || velocity ||
        acceleration, i.e. unless every vector group is ignored; a dropped setpoint publishes
        nothing and is no offboard signal."""
        if (mask & _ALL_GROUPS) != _ALL_GROUPS:
            self.sp_last_s = now_s

    # -- modes ----------------------------------------------------------------------------

    def cmd_set_mode(self, p: tuple, now_s: float) -> int:
        core = self.core
        if not all(math.isfinite(v) for v in p[:3]):
            return _C.MAV_RESULT_DENIED
        if not int(p[0]) & _C.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return _C.MAV_RESULT_DENIED
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
            return _C.MAV_RESULT_TEMPORARILY_REJECTED
        if (main, sub) == PX4_OFFBOARD and not self.offboard_signal_ok(now_s):
            # Commander: "Switching to Offboard is currently not available"
            core._statustext(
                now_s, _C.MAV_SEVERITY_CRITICAL, "Switching to Offboard is currently not available"
            )
            return _C.MAV_RESULT_TEMPORARILY_REJECTED
        if (main, sub) == PX4_TAKEOFF:
            return core._cmd_takeoff((0, 0, 0, 0, 0, 0, float("nan")), now_s)
        if (main, sub) == PX4_MISSION:
            return self.refuse_auto(now_s, _C.MAV_RESULT_TEMPORARILY_REJECTED)
        core._set_mode(px4_custom_mode(main, sub), now_s, "command")
        return _C.MAV_RESULT_ACCEPTED

    def on_set_mode_message(self, m, now_s: float) -> None:
        main, sub = px4_main_sub(m.custom_mode)
        result = self.cmd_set_mode((m.base_mode, main, sub), now_s)
        # PX4 turns SET_MODE into a vehicle_command DO_SET_MODE and acks that command.
        self.core._ack(_C.MAV_CMD_DO_SET_MODE, result, m, now_s)

    def resume_offboard(self, now_s: float) -> bool:
        if self.offboard_target is None:
            return False
        self.core._apply_target(self.offboard_target, now_s)
        return True

    # -- arming and takeoff ---------------------------------------------------------------

    def arm_refusal(self, now_s: float) -> str | None:
        mode = self._pair()
        if mode in _PX4_NOT_ARMABLE or (
            mode == PX4_OFFBOARD and not self.offboard_signal_ok(now_s)
        ):
            return "Arming denied: mode not armable"
        return None

    def on_armed(self, now_s: float) -> None:
        if self.core._behaviour == "guided":
            self.resume_offboard(now_s)

    def auto_disarm_delay_s(self) -> float:
        # PX4 COM_DISARM_PRFLT before takeoff (commander_params.yaml) and COM_DISARM_LAND
        # (2 s) after a landing.
        core = self.core
        return 2.0 if core._has_taken_off else core.params["COM_DISARM_PRFLT"]

    def cmd_takeoff(self, p: tuple, now_s: float) -> tuple[int, float | None]:
        """PX4: armed and landed; param7 = AMSL altitude, NaN -> MIS_TAKEOFF_ALT above home;
        switches to AUTO.TAKEOFF, then Hold when reached."""
        core = self.core
        if not core.armed or not core.physics.landed[core.index]:
            return self.arm_reject, None
        alt_amsl = p[6]
        if math.isfinite(alt_amsl) and alt_amsl - core.home_lla[2] > 0.5:
            alt_above_home = alt_amsl - core.home_lla[2]
        else:
            alt_above_home = core.params["MIS_TAKEOFF_ALT"]
        core._set_mode(_key(PX4_TAKEOFF), now_s, "command")
        return _C.MAV_RESULT_ACCEPTED, float(alt_above_home)

    def on_takeoff_reached(self, now_s: float, behaviour: str) -> None:
        if behaviour == "takeoff":
            # PX4 navigator switches to Hold (AUTO.LOITER) after takeoff.
            self.core._set_mode(_key(PX4_LOITER), now_s, "takeoff_complete")

    # -- failsafes ------------------------------------------------------------------------

    def guided_watchdog(self, now_s: float, behaviour: str) -> None:
        # PX4 offboard loss: no setpoint for COM_OF_LOSS_T (offboardCheck.cpp), then the mode
        # fallback of failsafe.cpp Failsafe::checkModeFallback, once per loss (a fallback of
        # "none" leaves the vehicle in OFFBOARD; a setpoint arriving again ends the loss).
        core = self.core
        if behaviour != "guided":
            return
        if self.offboard_signal_ok(now_s):
            core.offboard_failsafe = False
        elif not core.offboard_failsafe:
            core.offboard_failsafe = True
            action = self._offboard_loss(now_s)
            core._events.append(ev.FailsafeTriggered(core.sysid, now_s, "offboard", action))

    def _offboard_loss(self, now_s: float) -> str:
        """Act on a lost offboard signal; returns the action taken ("NONE" for none).

        failsafe.cpp ``Failsafe::checkModeFallback``: COM_OBL_RC_ACT through
        ``fromOffboardLossActParam``; a manual fallback (0-2, or an unknown value) without
        manual control becomes NAV_RCL_ACT's action through ``fromNavDllOrRclActParam``
        (PR #26289; see the comment above :data:`_PX4_NAV_ACT`). NAV_RCL_ACT 0 / 7 is
        ``Action::None``: the vehicle stays in OFFBOARD and the physics keeps the last target
        (PX4's multicopter position controller keeps the last ``trajectory_setpoint``).
        Terminate and Disarm stop the motors: in the air the vehicle falls (physics drops a
        disarmed vehicle).
        """
        core = self.core
        act = int(core.params["COM_OBL_RC_ACT"])
        if act in _PX4_OBL_STOP:
            target, stop = None, True
        elif act in _PX4_OBL_ACT:
            target, stop = _PX4_OBL_ACT[act], False
        else:  # 0-2 and ``default:`` (Position): no manual control -> NAV_RCL_ACT
            rcl = int(core.params["NAV_RCL_ACT"])
            target, stop = _PX4_NAV_ACT.get(rcl), rcl in _PX4_NAV_STOP
        if stop:
            if not core.armed:
                return "NONE"
            core._statustext(now_s, *_PX4_FAILSAFE_TEXT)
            core._disarm(now_s, "failsafe", force=True)
            return "DISARM"
        if target is None:
            return "NONE"
        core._set_mode(_key(target), now_s, "failsafe")
        core._statustext(now_s, *_PX4_FAILSAFE_TEXT)
        return PX4_MODES[target][0]

    def accepts_gcs_heartbeat(self, src_sysid: int) -> bool:
        # PX4 ignores GCS heartbeats carrying its own sysid (PX4 PR #11998).
        return src_sysid != self.core.sysid

    def gcs_failsafe_config(self) -> tuple[bool, float]:
        # Data-link loss after COM_DL_LOSS_T without a GCS heartbeat, action NAV_DLL_ACT.
        P = self.core.params
        return P["NAV_DLL_ACT"] > 0, P["COM_DL_LOSS_T"]

    def gcs_failsafe_action(self, now_s: float) -> str:
        # PX4's words: Commander.cpp Commander::dataLinkCheck ``mavlink_log_info(...,
        # "Connection to ground station lost\t")`` (INFO), then the failsafe's own
        # (_PX4_FAILSAFE_TEXT); the cause and the mode go out only as events (framework.cpp).
        core = self.core
        core._statustext(now_s, _C.MAV_SEVERITY_INFO, "Connection to ground station lost")
        act = int(core.params["NAV_DLL_ACT"])
        if act in _PX4_NAV_STOP:
            core._statustext(now_s, *_PX4_FAILSAFE_TEXT)
            core._disarm(now_s, "failsafe", force=True)
            return "DISARM"
        target = _PX4_NAV_ACT.get(act)
        if target is None:
            return "NONE"
        core._set_mode(_key(target), now_s, "failsafe")
        core._statustext(now_s, *_PX4_FAILSAFE_TEXT)
        return PX4_MODES[target][0]

    # -- setpoints ------------------------------------------------------------------------

    def accept_target(self, target, now_s: float) -> None:
        # PX4 keeps the latest setpoint; it is flown only in OFFBOARD.
        self.offboard_target = target
        if self.core._behaviour != "guided":
            return
        self.core._apply_target(target, now_s)

    def can_fly_target(self) -> bool:
        return self.core.armed

    def limit_target_position(self, pos):
        ph, i = self.core.physics, self.core.index
        cur = ph.pos_ned_m[i]
        if _f32_norm_overflows((float(pos[0]) - float(cur[0]), float(pos[1]) - float(cur[1]))):
            # PX4 mc_pos_control PositionControl::_positionControl: the horizontal velocity
            # setpoint is ControlMath::constrainXY(vel_sp_position.xy(), ..., lim), which for
            # ``v0.length() >= max`` returns ``v0.normalized() * max``; a float32 error whose
            # squared norm overflows has an infinite length, normalized() is then 0: no
            # horizontal motion. The vehicle keeps its north/east (the altitude still flies).
            return np.array((ph.pos_ned_m[i, 0], ph.pos_ned_m[i, 1], pos[2]))
        return pos

    def reposition_xy(self, x: int, y: int) -> tuple[int, int, bool] | None:
        # mavlink_receiver.cpp handle_message_command_int (see _NAN_AS_INT); navigator_main.cpp
        # DO_REPOSITION keeps the current lat/lon when they are NaN (x == y == INT32_MAX).
        if x == y == _NAN_AS_INT:
            return None
        if x == y == INT32_MAX:  # altitude only: convert it at home, keep north/east
            hx, hy = self.home_e7()
            return hx, hy, True
        return x, y, False

    def off_globe(
        self, lat_e7: int, lon_e7: int, lat_deg: float, lon_deg: float, alt_amsl_m: float
    ):
        core = self.core
        north, east = px4_map_project(lat_deg, lon_deg, *core.home_lla[:2])
        return core.home_ned_m + np.array((north, east, core.home_lla[2] - alt_amsl_m))

    # -- return (RTL) ---------------------------------------------------------------------

    def rtl_destination_ned_m(self, now_s: float) -> np.ndarray:
        """PX4 Return's destination, chosen on activation (src/modules/navigator/rtl.cpp
        ``RTL::on_activation`` -> ``RTL::setRtlTypeAndDestination`` -> ``RTL::findRtlDestination``
        -> ``RTL::findClosestSafePoint``), by ``RTL_TYPE`` (rtl_params.c):

        * 0 (default) and 3: the closest of home and the rally points (mission landings are not
          flown by the emulator); 1: the closest rally point, home only without one
          (``prioritize_safe_points_over_home``: ``min_dist`` starts at FLT_MAX); 5: the closest
          rally point, else where it is (the current position);
        * 2 and 4 return along the mission / to its landing and do not consider rally points:
          home here (the emulator flies no missions);
        * a rally point within ``MAX_DIST_FROM_HOME_FOR_LAND_APPROACHES`` (10 m) of home is
          ignored (except with 5), and one wins only when nearer than the best so far by
          ``MIN_DIST_THRESHOLD`` (2 m): ``(dist + MIN_DIST_THRESHOLD) < min_dist``;
        * the winner is chosen by its latitude / longitude whatever its frame, but
          ``RTL::setSafepointAsDestination`` sets a destination only for frames 0 and 3
          (:data:`_PX4_RTL_FRAMES`); for any other it says "RTL: unsupported MAV_FRAME" and
          leaves the destination unset: the vehicle stays where it is (hovers) instead of
          returning.
        """
        core = self.core
        if int(core.params["RTL_TYPE"]) in (2, 4):
            return self._rally_or_home(None)
        rtl_type = int(core.params["RTL_TYPE"])
        pos = core.physics.pos_ned_m[core.index, :2]
        best = self._closest_safe_point(now_s)
        if best is None:
            if rtl_type == 5:
                return np.array((pos[0], pos[1], core.home_ned_m[2]), dtype=float)
            return self._rally_or_home(None)
        ne_m, frame = best
        if frame not in _PX4_RTL_FRAMES:
            # No destination: hold here (the core's RTL does nothing more in "hover").
            here = core.physics.pos_ned_m[core.index].copy()
            core.physics.command_position(core.index, here)
            core._rtl_phase = "hover"
            return here
        return self._rally_or_home(ne_m)

    def _closest_safe_point(self, now_s: float) -> tuple[np.ndarray, int] | None:
        """``RTL::findRtlDestination`` / ``findClosestSafePoint`` for RTL_TYPE 0, 1, 3, 5: the
        chosen rally point (north / east m, its stored frame), None for home. Every far-enough
        point in a frame ``setSafepointAsDestination`` cannot use sends its STATUSTEXT, as the
        firmware does for each such point on every evaluation."""
        core = self.core
        rtl_type = int(core.params["RTL_TYPE"])
        pos = core.physics.pos_ned_m[core.index, :2]
        home_ne = core.home_ned_m[:2]
        min_dist = math.inf if rtl_type in (1, 5) else float(np.hypot(*(home_ne - pos)))
        best = None
        for pt, frame in self._safe_points():  # a handful of stored points
            if rtl_type != 5 and float(np.hypot(*(pt - home_ne))) <= _PX4_RALLY_NEAR_HOME_M:
                continue
            if frame not in _PX4_RTL_FRAMES:
                core._statustext(now_s, _C.MAV_SEVERITY_CRITICAL, _PX4_UNSUPPORTED_FRAME_TEXT)
            dist = float(np.hypot(*(pt - pos)))
            if dist + _PX4_RALLY_MIN_DIST_M < min_dist:
                min_dist, best = dist, (pt, frame)
        return best

    def _safe_points(self) -> list[tuple[np.ndarray, int]]:
        """(north / east m, stored frame) of the rally items, in upload order (PX4 keeps the
        frame as sent; only global frames are accepted, vehicle_emu/missions.py)."""
        core = self.core
        items = core._missions.items.get(_C.MAV_MISSION_TYPE_RALLY, ())
        out = []
        for it in items:
            ned = geodetic_to_ned_m(
                e7_to_deg(it.x), e7_to_deg(it.y), core.home_lla[2], *core.physics.origin_lla
            )
            out.append((np.array((float(ned[0]), float(ned[1]))), int(it.frame)))
        return out

    def update(self, now_s: float) -> None:
        """``RTL::on_inactive`` every 2 s: the destination is chosen again (and an unusable
        rally point complained about, "RTL: unsupported MAV_FRAME" each time)."""
        core = self.core
        if core._behaviour == "rtl" or now_s - self._rtl_check_s < _PX4_RTL_CHECK_PERIOD_S:
            return
        self._rtl_check_s = now_s
        if int(core.params["RTL_TYPE"]) not in (2, 4) and core._missions.items.get(
            _C.MAV_MISSION_TYPE_RALLY
        ):
            self._closest_safe_point(now_s)

    def command_int_frame(self, frame: int) -> int:
        """mavlink_receiver.cpp ``MavlinkReceiver::handle_message_command_int`` copies x / y
        (degE7 -> deg) and z to param5-7 without looking at the frame, and the navigator takes
        DO_REPOSITION's param7 as AMSL (navigator_main.cpp ``position_setpoint.alt =
        cmd.param7``): every frame reads as GLOBAL_INT. (PX4 main of 2026-02-25 to 2026-03-03
        answered frames other than 5 with MAV_RESULT_COMMAND_UNSUPPORTED_MAV_FRAME, PR #26408,
        reverted by #26626.)"""
        return _C.MAV_FRAME_GLOBAL_INT

    # -- parameters -----------------------------------------------------------------------

    def apply_params(self) -> None:
        core = self.core
        P, ph, i = core.params, core.physics, core.index
        core._guided_speed_m_s = P["MPC_XY_VEL_MAX"]
        core._auto_speed_m_s = P["MPC_XY_CRUISE"]
        ph.climb_rate_m_s[i] = P["MPC_Z_VEL_MAX_UP"]
        ph.descent_rate_m_s[i] = P["MPC_Z_VEL_MAX_DN"]
        # FlightTaskAuto::_prepareLandSetpoints: MPC_Z_VEL_MAX_DN at MPC_LAND_ALT1 (at least
        # ALT2, updateParams), linearly to MPC_LAND_SPEED at MPC_LAND_ALT2; the trajectory at most
        # MPC_Z_V_AUTO_DN (_updateTrajConstraints), which a lower one meets below ALT1.
        land, top, cap = P["MPC_LAND_SPEED"], P["MPC_Z_VEL_MAX_DN"], P["MPC_Z_V_AUTO_DN"]
        lo = P["MPC_LAND_ALT2"]
        hi = max(P["MPC_LAND_ALT1"], lo)
        if cap < top and top > land:
            hi = lo + (hi - lo) * max(0.0, cap - land) / (top - land)
        ph.land_fast_m_s[i] = min(top, cap)
        ph.land_speed_m_s[i] = min(land, top, cap)
        ph.land_slow_alt_m[i], ph.land_crawl_alt_m[i] = hi, lo
        core._rtl_alt_m = P["RTL_RETURN_ALT"]
        core._rtl_hover_alt_m = P["RTL_DESCEND_ALT"] if P["RTL_LAND_DELAY"] < 0 else None

"""COMMAND_LONG / COMMAND_INT and SET_MODE for :class:`vehicle_emu.link.VehicleCore`: the command
dispatch and its ACK, arming, mode changes, takeoff, reposition, message requests.
"""

from __future__ import annotations

import math

from planner.geometry import DOWN, EAST, NORTH

from . import events as ev
from . import telemetry as tm
from .core_setpoints import SetpointHandlers
from .wire import dialect as mavlink

__all__ = ["CommandHandlers"]

_FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force (ArduPilot & PX4)


class CommandHandlers(SetpointHandlers):
    """Commands (a mixin of :class:`vehicle_emu.link.VehicleCore`)."""

    def _on_command_long(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        params = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
        self._command(m.command, params, None, m, now_s)

    def _on_command_int(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        # COMMAND_INT: x, y are degE7 for global frames; z is float. The frame as the firmware
        # reads it (PX4 ignores it: personality/px4.py command_int_frame).
        params = (m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z)
        self._command(m.command, params, self.pers.command_int_frame(m.frame), m, now_s)

    def _ack(self, command: int, result: int, m, now_s: float) -> None:
        self._send(
            mavlink.MAVLink_command_ack_message(
                command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()
            )
        )
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
            key = self.pers.land_mode
            return (
                C.MAV_RESULT_ACCEPTED
                if self._set_mode(key, now_s, "command")
                else C.MAV_RESULT_FAILED
            ), None
        if cmd == C.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            key = self.pers.rtl_mode
            return (
                C.MAV_RESULT_ACCEPTED
                if self._set_mode(key, now_s, "command")
                else C.MAV_RESULT_FAILED
            ), None
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
            builder = tm.BUILDERS.get(msg_id) if self._can_send(msg_id) else None
            if builder is None:
                return self.pers.no_such_message, None
            return C.MAV_RESULT_ACCEPTED, lambda: self._send(builder(self, now_s))
        if cmd == C.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return C.MAV_RESULT_ACCEPTED, lambda: self._send(tm.autopilot_version(self, now_s))
        if cmd == C.MAV_CMD_GET_HOME_POSITION:
            return C.MAV_RESULT_ACCEPTED, lambda: self._send(tm.home_position(self, now_s))
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
        reject = self.pers.arm_reject
        force = abs(p[1] - _FORCE_MAGIC) < 0.5
        if p[0] == 1:
            if self.armed:
                return C.MAV_RESULT_ACCEPTED
            if not force:
                if now_s < self._ekf_ready_s:
                    self._statustext(now_s, C.MAV_SEVERITY_CRITICAL, "PreArm: EKF not ready")
                    return reject
                refusal = self.pers.arm_refusal(now_s)
                if refusal is not None:
                    self._statustext(now_s, C.MAV_SEVERITY_CRITICAL, refusal)
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

    def _cmd_set_mode(self, p: tuple, now_s: float) -> int:
        return self.pers.cmd_set_mode(p, now_s)

    def _on_set_mode(self, m, addr, now_s: float) -> None:
        if m.target_system != self.sysid:
            self.stats.not_for_us += 1
            return
        self.stats.commands += 1
        self.pers.on_set_mode_message(m, now_s)

    def _cmd_takeoff(self, p: tuple, now_s: float) -> int:
        """MAV_CMD_NAV_TAKEOFF: the personality checks it (and PX4 enters AUTO.TAKEOFF), then
        the vehicle climbs to the altitude above home."""
        ph, i = self.physics, self.index
        result, alt_above_home = self.pers.cmd_takeoff(p, now_s)
        if alt_above_home is None:
            return result
        target_down = float(self.home_ned_m[DOWN] - alt_above_home)
        self._takeoff_target_down_m = target_down
        self._landed_armed_since_s = None
        ph.command_position(i, (ph.pos_ned_m[i, NORTH], ph.pos_ned_m[i, EAST], target_down))
        self._events.append(ev.TakeoffStarted(self.sysid, now_s, float(alt_above_home)))
        return result

    def _cmd_reposition(self, p: tuple, frame, now_s: float) -> int:
        """MAV_CMD_DO_REPOSITION (ArduCopter >= 4.1, GCS_Mavlink.cpp handle_command_int_do_
        reposition): switches to GUIDED when flying; rejects a NaN altitude."""
        C = mavlink
        if frame is None or not self.armed or self.physics.landed[self.index]:
            return C.MAV_RESULT_FAILED
        if not math.isfinite(p[6]):
            return C.MAV_RESULT_FAILED
        xy = self.pers.reposition_xy(int(p[4]), int(p[5]))
        if xy is None:
            return C.MAV_RESULT_DENIED
        x, y, keep_horizontal = xy
        # ArduCopter handle_command_int_do_reposition: ``if (!check_latlng(packet.x, packet.y))
        # return MAV_RESULT_DENIED`` (inside _global_to_world); PX4 has no such check.
        pos = self._global_to_world(x, y, float(p[6]), frame)
        if pos is None:
            return C.MAV_RESULT_DENIED
        if keep_horizontal:
            pos[:2] = self.physics.target_pos_ned_m[self.index, :2]
        guided = self.pers.reposition_mode
        if self._mode_key != guided:
            self._set_mode(guided, now_s, "command")
        self.physics.command_position(self.index, pos)
        return C.MAV_RESULT_ACCEPTED

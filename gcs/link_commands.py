"""Commands with ACK matching for :class:`gcs.link.StationLink`: one in flight per (vehicle,
command id) (COMMAND_ACK names only the command id), the rest queued; re-sends with an
incremented ``confirmation``; MAV_RESULT_IN_PROGRESS waits without re-sending (mavlink.io command
protocol); the outcome as an event, or to an internal callback (the station's own requests).
"""

from __future__ import annotations

from collections import deque
from typing import Any

from gcs import wire
from gcs.autopilot import CommandSpec
from gcs.events import CommandAcked, CommandFailed, CommandInProgress, CommandTimedOut
from gcs.link_state import (
    _AUTOPILOT_COMPID,
    _CMD_SET_MESSAGE_INTERVAL,
    LinkState,
    LinkUsageError,
    _Command,
    _result_name,
    _Vehicle,
)
from gcs.wire import mavlink

__all__ = ["CommandTracker"]


class CommandTracker(LinkState):
    """Command / ACK tracking (a mixin of :class:`gcs.link.StationLink`)."""

    def _new_command(
        self, sysid: int, command: int, params: tuple[float, ...], *, use_int: bool
    ) -> _Command:
        cmd = _Command(self._next_request_id, sysid, command, tuple(params), use_int)
        self._next_request_id += 1
        return cmd

    def _submit(self, cmd: _Command, now_s: float) -> None:
        key = (cmd.sysid, cmd.command)
        if key in self._commands:
            # One in-flight command per (target, command id): an ACK names only the command id.
            self._queued.setdefault(key, deque()).append(cmd)
        else:
            self._commands[key] = cmd
            self._transmit_command(cmd, now_s)

    def _transmit_command(self, cmd: _Command, now_s: float) -> None:
        v = self._vehicles[cmd.sysid]
        if cmd.use_int:
            frame, p1, p2, p3, p4, x, y, z = cmd.params
            msg = mavlink.MAVLink_command_int_message(
                cmd.sysid,
                cmd.component,
                int(frame),
                cmd.command,
                0,
                0,
                p1,
                p2,
                p3,
                p4,
                int(x),
                int(y),
                z,
            )
        else:
            # confirmation: 0 on the first send, incremented on every re-send (mavlink.io).
            msg = mavlink.MAVLink_command_long_message(
                cmd.sysid, cmd.component, cmd.command, min(cmd.attempts, 255), *cmd.params
            )
        cmd.attempts += 1
        cmd.deadline_s = now_s + self.config.command_timeout_s
        self._wake(cmd.deadline_s)
        self._send(msg, v.addr, now_s)

    def _finish_command(self, cmd: _Command, now_s: float, result: int | None) -> None:
        key = (cmd.sysid, cmd.command)
        del self._commands[key]
        if cmd.internal is not None:
            cmd.internal(result, now_s)
        elif result is None:
            self._emit(
                CommandTimedOut(
                    self.link_id, cmd.sysid, now_s, cmd.command, cmd.request_id, cmd.attempts
                )
            )
        elif result == mavlink.MAV_RESULT_ACCEPTED:
            self._emit(
                CommandAcked(
                    self.link_id, cmd.sysid, now_s, cmd.command, cmd.request_id, cmd.attempts
                )
            )
        else:
            self._emit(
                CommandFailed(
                    self.link_id,
                    cmd.sysid,
                    now_s,
                    cmd.command,
                    cmd.request_id,
                    int(result),
                    _result_name(result),
                )
            )
        queue = self._queued.get(key)
        if queue:
            nxt = queue.popleft()
            if not queue:
                del self._queued[key]
            if cmd.sysid in self._vehicles:
                self._commands[key] = nxt
                self._transmit_command(nxt, now_s)
        elif cmd.command == _CMD_SET_MESSAGE_INTERVAL and cmd.sysid in self._vehicles:
            self._pump_disables(self._vehicles[cmd.sysid], now_s)

    def send_command_long(
        self,
        sysid: int,
        command: int,
        params: tuple[float, ...] = (0.0,) * 7,
        now_s: float = 0.0,
        *,
        component: int = _AUTOPILOT_COMPID,
    ) -> int:
        """Send a COMMAND_LONG with ACK matching and retries; returns the request id.

        Outcome events: CommandAcked, CommandInProgress, CommandFailed, CommandTimedOut.
        """
        self._get(sysid)
        params = tuple(float(p) for p in params)
        if len(params) != 7:
            raise ValueError(f"COMMAND_LONG takes 7 params, got {len(params)}")
        cmd = self._new_command(sysid, command, params, use_int=False)
        cmd.component = component
        self._submit(cmd, now_s)
        return cmd.request_id

    def send_command_int(
        self,
        sysid: int,
        command: int,
        *,
        frame: int,
        params: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0),
        lat_deg: float = 0.0,
        lon_deg: float = 0.0,
        alt_m: float = 0.0,
        now_s: float = 0.0,
    ) -> int:
        """Send a COMMAND_INT (positional commands: x/y as degE7); returns the request id.

        ``frame`` and ``alt_m`` say what the caller means; on the wire they go as the vehicle's
        firmware reads them (``adapter.command_int_frame``). PX4 takes x / y as latitude /
        longitude and z as AMSL whatever the frame (src/modules/mavlink/mavlink_receiver.cpp
        ``MavlinkReceiver::handle_message_command_int`` copies them to param5-7 without looking
        at it; src/modules/navigator/navigator_main.cpp DO_REPOSITION: ``position_setpoint.alt =
        cmd.param7``), and main of 2026-02-25 to 2026-03-03 answered any frame but
        MAV_FRAME_GLOBAL_INT with MAV_RESULT_COMMAND_UNSUPPORTED_MAV_FRAME (PX4 PR #26408,
        reverted by #26626): so PX4 gets frame 5, a relative altitude made AMSL with the home
        altitude (HOME_POSITION, else GLOBAL_POSITION_INT ``alt - relative_alt``).

        Raises LinkUsageError for a frame the firmware cannot be given (local, terrain on PX4)
        or when the home altitude is needed and not known yet.
        """
        v = self._get(sysid)
        p = tuple(float(x) for x in params)
        if len(p) != 4:
            raise ValueError(f"COMMAND_INT takes 4 params, got {len(p)}")
        want = v.adapter.command_int_frame
        if want is not None and frame != want:
            if frame in (
                mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            ):
                alt_m = float(alt_m) + self._home_alt_amsl_m(v)
            elif frame not in (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_MISSION):
                raise LinkUsageError(
                    f"sysid {sysid} ({v.adapter.name}): COMMAND_INT in frame {frame} cannot be "
                    f"sent (the firmware reads frame {want} only)"
                )
            frame = want
        cmd = self._new_command(
            sysid,
            command,
            (frame, *p, wire.deg_to_e7(lat_deg), wire.deg_to_e7(lon_deg), float(alt_m)),
            use_int=True,
        )
        self._submit(cmd, now_s)
        return cmd.request_id

    def _home_alt_amsl_m(self, v: _Vehicle) -> float:
        """HOME_POSITION's altitude; until it arrives, GLOBAL_POSITION_INT ``alt -
        relative_alt`` (on PX4 the two come from different estimates and their difference moves
        by metres in flight, so it is only a stand-in)."""
        if v.home is not None:
            return v.home.alt_amsl_m
        if v.position is None:
            raise LinkUsageError(f"sysid {v.sysid}: no position yet, home altitude unknown")
        return v.position.alt_amsl_m - v.position.rel_alt_m

    def _send_spec(self, sysid: int, spec: CommandSpec, now_s: float) -> int:
        v = self._get(sysid)
        cmd = self._new_command(sysid, spec.command, spec.params, use_int=False)
        if spec.after_prestream and v.adapter.prestream_s > 0:
            if v.setpoint is None:
                raise LinkUsageError(
                    f"sysid {sysid} ({v.adapter.name}): stream position targets "
                    "(set_position_target) before switching to offboard or arming"
                )
            if now_s < v.setpoint_since_s + v.adapter.prestream_s:
                v.deferred.append(cmd)  # sent by handle_timer once the stream is old enough
                self._wake(v.setpoint_since_s + v.adapter.prestream_s)
                return cmd.request_id
        self._submit(cmd, now_s)
        return cmd.request_id

    def _on_command_ack(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.config.sysid):
            return  # an ACK for another station
        cmd = self._commands.get((v.sysid, msg.command))
        if cmd is None:
            self.stats.unexpected_acks += 1
            return
        if msg.result == mavlink.MAV_RESULT_IN_PROGRESS:
            # Keep waiting, never re-send: a re-send would restart the action (mavlink.io command).
            cmd.in_progress = True
            cmd.deadline_s = now_s + self.config.command_in_progress_timeout_s
            self._wake(cmd.deadline_s)
            if cmd.internal is None:
                self._emit(
                    CommandInProgress(
                        self.link_id, v.sysid, now_s, cmd.command, cmd.request_id, int(msg.progress)
                    )
                )
            return
        self._finish_command(cmd, now_s, msg.result)

    def _pump_disables(self, v: _Vehicle, now_s: float) -> None:
        """Send the next queued stop of an unused message (:mod:`gcs.link_streams`): called
        when a SET_MESSAGE_INTERVAL slot frees up."""
        raise NotImplementedError

"""Telemetry streams for :class:`gcs.link.StationLink`: the configured rates requested by
SET_MESSAGE_INTERVAL (REQUEST_DATA_STREAM as the fallback), re-requested when telemetry goes
stale, and the messages the station does not use asked to stop (``disable_unused_messages``).
"""

from __future__ import annotations

import logging
import math

from gcs import wire
from gcs.link_commands import CommandTracker
from gcs.link_state import _AUTOPILOT_COMPID, _CMD_SET_MESSAGE_INTERVAL, _result_name, _Vehicle
from gcs.wire import mavlink

__all__ = ["StreamRequests"]

#: The link's log lines keep the logger they always had (StationLink was one module).
log = logging.getLogger("gcs.link")

_MSG = mavlink  # message-id constants live on the dialect module

#: REQUEST_DATA_STREAM fallback: which legacy stream group carries each message (ArduPilot
#: GCS_Common.cpp STREAM_* tables).
_DATA_STREAM_OF_MSG = {
    _MSG.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: mavlink.MAV_DATA_STREAM_POSITION,
    _MSG.MAVLINK_MSG_ID_LOCAL_POSITION_NED: mavlink.MAV_DATA_STREAM_POSITION,
    _MSG.MAVLINK_MSG_ID_SYS_STATUS: mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    _MSG.MAVLINK_MSG_ID_GPS_RAW_INT: mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    _MSG.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    _MSG.MAVLINK_MSG_ID_ATTITUDE: mavlink.MAV_DATA_STREAM_EXTRA1,
    _MSG.MAVLINK_MSG_ID_VFR_HUD: mavlink.MAV_DATA_STREAM_EXTRA2,
}


class StreamRequests(CommandTracker):
    """Stream requests and stops (a mixin of :class:`gcs.link.StationLink`)."""

    # ------------------------------------------------------------------ streams

    def _stale_due_s(self, v: _Vehicle) -> float:
        cfg = self.config
        if not cfg.stale_msgids:
            return math.inf
        get = v.last_msg_s.get
        last = math.inf
        for m in cfg.stale_msgids:  # min() of a generator costs more at fleet scale
            t = get(m, -math.inf)
            if t < last:
                last = t
        return max(last, v.last_stream_request_s) + cfg.telemetry_stale_s

    def request_streams(self, sysid: int, now_s: float) -> None:
        """(Re-)request the configured telemetry rates from one vehicle."""
        self._request_streams(self._get(sysid), now_s)

    def _request_streams(self, v: _Vehicle, now_s: float) -> None:
        v.last_stream_request_s = now_s
        if v.use_data_stream:
            self._send_data_streams(v, now_s)
            return
        for msgid, rate_hz in self.config.stream_rates_hz:
            key = (v.sysid, _CMD_SET_MESSAGE_INTERVAL)
            pending = [self._commands.get(key), *self._queued.get(key, ())]
            if any(
                c is not None and c.internal is not None and c.params[0] == msgid for c in pending
            ):
                continue  # already asked and waiting
            params = (float(msgid), wire.hz_to_interval_us(rate_hz), 0.0, 0.0, 0.0, 0.0, 0.0)
            cmd = self._new_command(v.sysid, _CMD_SET_MESSAGE_INTERVAL, params, use_int=False)
            cmd.internal = lambda result, t_s, v=v, m=msgid: self._on_interval_result(
                v, result, t_s, m
            )
            self._submit(cmd, now_s)

    def _on_interval_result(
        self, v: _Vehicle, result: int | None, now_s: float, msgid: int = 0
    ) -> None:
        if result == mavlink.MAV_RESULT_ACCEPTED:
            v.interval_accepted = True
            return
        if v.use_data_stream:
            return
        if result not in (None, mavlink.MAV_RESULT_UNSUPPORTED) and v.interval_accepted:
            # The command works on this vehicle; it just cannot stream this one message.
            log.info(
                "link %d sysid %d: message %d interval refused (%s)",
                self.link_id,
                v.sysid,
                msgid,
                _result_name(result),
            )
            return
        # No ACK, UNSUPPORTED, or refused before anything was accepted: older ArduPilot and
        # some routers. Fall back to REQUEST_DATA_STREAM for this vehicle from now on (Skybrush
        # pattern, docs/design/mavlink.md §1.2).
        log.info(
            "link %d sysid %d: SET_MESSAGE_INTERVAL result %s, falling back to REQUEST_DATA_STREAM",
            self.link_id,
            v.sysid,
            result,
        )
        v.use_data_stream = True
        self.stats.data_stream_fallbacks += 1
        key = (v.sysid, _CMD_SET_MESSAGE_INTERVAL)
        self._queued.pop(key, None)
        self._send_data_streams(v, now_s)

    def _send_data_streams(self, v: _Vehicle, now_s: float) -> None:
        rates: dict[int, float] = {}
        for msgid, rate_hz in self.config.stream_rates_hz:
            stream = _DATA_STREAM_OF_MSG.get(msgid)
            if stream is not None:
                rates[stream] = max(rates.get(stream, 0.0), rate_hz)
        for stream, rate_hz in rates.items():
            msg = mavlink.MAVLink_request_data_stream_message(
                v.sysid, _AUTOPILOT_COMPID, stream, max(1, int(round(rate_hz))), 1
            )
            self._send(msg, v.addr, now_s)

    # ------------------------------------------------------------------ unused messages

    def _note_unused(self, v: _Vehicle, msgid: int, now_s: float) -> None:
        """A frame the station does not use, from ``v``'s autopilot: ask it to stop that
        message, once, and again (up to ``disable_attempts``) if it keeps coming."""
        if msgid in self._used_msgids or v.use_data_stream or msgid in v.disable_queue:
            return  # the REQUEST_DATA_STREAM fallback has no per-message stop
        tries, last_s = v.disable_tries.get(msgid, (0, -math.inf))
        if tries >= self.config.disable_attempts or now_s - last_s < self.config.disable_retry_s:
            return
        v.disable_tries[msgid] = (tries + 1, now_s)
        v.disable_queue[msgid] = None
        self._pump_disables(v, now_s)

    def _pump_disables(self, v: _Vehicle, now_s: float) -> None:
        # One at a time, and only when no stream request is in flight or queued for this
        # vehicle: COMMAND_ACK names only the command id, and the station's own stream requests
        # must never wait behind a batch of stops.
        key = (v.sysid, _CMD_SET_MESSAGE_INTERVAL)
        if (
            not v.disable_queue
            or key in self._commands
            or self._queued.get(key)
            or v.lost
            or v.sysid not in self._vehicles
        ):
            return
        msgid = next(iter(v.disable_queue))
        del v.disable_queue[msgid]
        params = (float(msgid), -1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        cmd = self._new_command(v.sysid, _CMD_SET_MESSAGE_INTERVAL, params, use_int=False)
        cmd.retries = 1  # best effort; the message itself tells us if it did not stop
        cmd.internal = lambda result, t_s, v=v, m=msgid: self._on_disable_result(v, m, result, t_s)
        self.stats.disable_requests += 1
        self._submit(cmd, now_s)

    def _on_disable_result(self, v: _Vehicle, msgid: int, result: int | None, now_s: float) -> None:
        if result == mavlink.MAV_RESULT_ACCEPTED:
            self.stats.messages_disabled += 1
            log.debug("link %d sysid %d: message %d stopped", self.link_id, v.sysid, msgid)
        elif result is not None:
            # DENIED / FAILED: not a stream this autopilot can stop (a reply to something,
            # or no ap_message for it in ArduPilot): never ask again.
            v.disable_tries[msgid] = (self.config.disable_attempts, now_s)
            log.info(
                "link %d sysid %d: cannot stop message %d (%s)",
                self.link_id,
                v.sysid,
                msgid,
                _result_name(result),
            )

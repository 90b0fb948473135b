"""The parameter protocol for :class:`gcs.link.StationLink`: reads (PARAM_REQUEST_READ, at most
``params_in_flight`` outstanding, re-sent until PARAM_VALUE) and writes (PARAM_SET, confirmed
only by the PARAM_VALUE echo, refused by PARAM_ERROR).
"""

from __future__ import annotations

import math
from typing import Any

from gcs import wire
from gcs.events import ParamReceived, ParamSetConfirmed, ParamSetFailed
from gcs.link_state import _AUTOPILOT_COMPID, LinkState, _ParamRequest, _ParamSet, _Vehicle
from gcs.wire import mavlink

__all__ = ["ParamProtocol"]


class ParamProtocol(LinkState):
    """Parameter reads and writes (a mixin of :class:`gcs.link.StationLink`)."""

    def request_param(self, sysid: int, name: str, now_s: float) -> None:
        """PARAM_REQUEST_READ by name, re-sent until PARAM_VALUE (ParamReceived) or ParamTimedOut."""
        self._get(sysid)
        if not name or len(name) > 16:
            raise ValueError(f"param name must be 1..16 characters, got {name!r}")
        key = (sysid, name)
        if key not in self._params and key not in self._param_queue:
            self._param_queue[key] = _ParamRequest(sysid, name)
            self._pump_params(now_s)

    def cancel_param(self, sysid: int, name: str, now_s: float) -> bool:
        """Forget a pending read (no ParamTimedOut): e.g. the other spelling of a renamed
        parameter was read. Returns True if one was pending."""
        key = (sysid, name)
        found = (self._params.pop(key, None) or self._param_queue.pop(key, None)) is not None
        self._pump_params(now_s)
        return found

    def _pump_params(self, now_s: float) -> None:
        limit = self.config.params_in_flight
        while self._param_queue and len(self._params) < limit:
            key = next(iter(self._param_queue))
            req = self._param_queue.pop(key)
            if req.sysid not in self._vehicles:
                continue
            self._params[key] = req
            self._transmit_param_request(req, now_s)

    def set_param(
        self,
        sysid: int,
        name: str,
        value: float,
        param_type: int,
        now_s: float,
        *,
        previous: float | None = None,
    ) -> None:
        """PARAM_SET, re-sent until the PARAM_VALUE echo carries ``value``.

        ``param_type`` is the MAV_PARAM_TYPE the vehicle reported for ``name`` (PX4 refuses a
        set whose type differs). Integers are encoded as the autopilot expects (byte-wise for
        PX4, :func:`gcs.wire.encode_param_value`). Outcome: ParamSetConfirmed, or ParamSetFailed
        after ``param_retries`` re-sends every ``param_timeout_s`` (the retry policy of reads);
        the echo also arrives as ParamReceived. A new set of the same name replaces a pending one.
        """
        v = self._get(sysid)
        if not name or len(name) > 16:
            raise ValueError(f"param name must be 1..16 characters, got {name!r}")
        wire.encode_param_value(value, param_type, bytewise=v.adapter.param_bytewise)  # validate
        ps = _ParamSet(sysid, name, float(value), int(param_type), previous)
        self._param_sets[(sysid, name)] = ps
        self._transmit_param_set(ps, now_s)

    def _transmit_param_set(self, ps: _ParamSet, now_s: float) -> None:
        v = self._vehicles[ps.sysid]
        wire_value = wire.encode_param_value(
            ps.value, ps.param_type, bytewise=v.adapter.param_bytewise
        )
        msg = mavlink.MAVLink_param_set_message(
            ps.sysid, _AUTOPILOT_COMPID, ps.name.encode("ascii"), wire_value, ps.param_type
        )
        ps.attempts += 1
        ps.deadline_s = now_s + self.config.param_timeout_s
        self._wake(ps.deadline_s)
        self._send(msg, v.addr, now_s)

    def _transmit_param_request(self, req: _ParamRequest, now_s: float) -> None:
        v = self._vehicles[req.sysid]
        msg = mavlink.MAVLink_param_request_read_message(
            req.sysid, _AUTOPILOT_COMPID, req.name.encode("ascii"), -1
        )
        req.attempts += 1
        req.deadline_s = now_s + self.config.param_timeout_s
        self._wake(req.deadline_s)
        self._send(msg, v.addr, now_s)

    def _on_param_value(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        name = wire.param_id_to_str(msg.param_id)
        if not name:
            self.stats.invalid_telemetry += 1
            return
        value = wire.decode_param_value(
            msg.param_value, msg.param_type, bytewise=v.adapter.param_bytewise
        )
        if not math.isfinite(value):
            self.stats.invalid_telemetry += 1
            return
        self._params.pop((v.sysid, name), None)
        self._param_queue.pop((v.sysid, name), None)
        self._emit(ParamReceived(self.link_id, v.sysid, now_s, name, value, msg.param_type))
        self._pump_params(now_s)
        ps = self._param_sets.get((v.sysid, name))
        if ps is not None:
            self._on_param_set_echo(ps, value, now_s)

    def _on_param_set_echo(self, ps: _ParamSet, value: float, now_s: float) -> None:
        # Both firmwares confirm a set only by a PARAM_VALUE with the stored value: PX4 sends it
        # from the PARAM_SET handler (send_param, src/modules/mavlink/mavlink_parameters.cpp);
        # ArduPilot's save() notifies every channel, and a refused write echoes the *old* value
        # with "Param write denied" (libraries/GCS_MAVLink/GCS_Param.cpp handle_param_set).
        key = (ps.sysid, ps.name)
        if wire.param_values_equal(ps.value, value, ps.param_type):
            del self._param_sets[key]
            self._emit(
                ParamSetConfirmed(
                    self.link_id,
                    ps.sysid,
                    now_s,
                    ps.name,
                    value,
                    ps.previous,
                    ps.param_type,
                    ps.attempts,
                )
            )
        elif ps.attempts <= self.config.param_retries:
            # Maybe the answer to an earlier read, crossing our set on the wire: ask again.
            self._transmit_param_set(ps, now_s)
        else:
            del self._param_sets[key]
            self._emit(
                ParamSetFailed(
                    self.link_id,
                    ps.sysid,
                    now_s,
                    ps.name,
                    ps.value,
                    value,
                    f"the vehicle kept {value:g}",
                    ps.attempts,
                )
            )

    def _on_param_error(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        # PARAM_ERROR (newer ArduPilot GCS_Param.cpp send_param_error): a precise refusal.
        name = wire.param_id_to_str(msg.param_id)
        ps = self._param_sets.pop((v.sysid, name), None)
        if ps is None:
            self.stats.ignored_messages += 1
            return
        entry = mavlink.enums["MAV_PARAM_ERROR"].get(msg.error)
        reason = entry.name if entry is not None else f"MAV_PARAM_ERROR({msg.error})"
        self._emit(
            ParamSetFailed(self.link_id, v.sysid, now_s, name, ps.value, None, reason, ps.attempts)
        )

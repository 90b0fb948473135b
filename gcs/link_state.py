"""The state of one :class:`gcs.link.StationLink` (:class:`LinkState`) and its records.

:class:`gcs.link.StationLink` is cut along its protocol's seams into mixins that all work on this
state: command / ACK tracking (:mod:`gcs.link_commands`), telemetry stream requests and stops
(:mod:`gcs.link_streams`), who is a vehicle and what it reports (:mod:`gcs.link_discovery`),
vehicle actions and setpoints (:mod:`gcs.link_actions`) and the parameter protocol
(:mod:`gcs.link_params`). The attributes are declared here, once, with their types;
``StationLink.__init__`` sets them. The records (a vehicle as the link knows it, a pending
command, a parameter read or write) and the sending helpers every mixin uses live here too.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from gcs import wire
from gcs.autopilot import Adapter
from gcs.events import Event, HomePositionReceived, TelemetryReceived
from gcs.link_config import Addr, LinkStats, StationConfig
from gcs.link_quality import SeqCounter
from gcs.wire import mavlink

__all__ = ["LinkState", "Addr", "UnknownVehicle", "LinkUsageError"]

#: The link's log lines keep the logger they always had (StationLink was one module).
log = logging.getLogger("gcs.link")


_CMD_SET_MESSAGE_INTERVAL = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL  # 511
_AUTOPILOT_COMPID = mavlink.MAV_COMP_ID_AUTOPILOT1  # 1


class UnknownVehicle(KeyError):
    """Local error: a call named a sysid this link has never discovered."""


class LinkUsageError(RuntimeError):
    """Local error: a call that cannot be honoured in the current state (e.g. no position yet)."""


@dataclass
class _Vehicle:
    sysid: int
    addr: Addr
    autopilot: int
    vehicle_type: int
    adapter: Adapter
    custom_mode: int
    base_mode: int
    last_heartbeat_s: float
    lost: bool = False
    addr_heard_s: float = -math.inf
    """Core time of the last frame from ``addr``."""
    last_msg_s: dict[int, float] = field(default_factory=dict)
    use_data_stream: bool = False
    interval_accepted: bool = False
    last_stream_request_s: float = -math.inf
    position: TelemetryReceived | None = None
    time_boot_s: float = -math.inf
    """The vehicle's clock at its last GLOBAL_POSITION_INT (a jump back: it rebooted)."""
    setpoint: tuple[float, float, float, int] | None = None  # lat, lon, alt, frame
    setpoint_since_s: float = math.nan
    setpoint_next_s: float = math.inf
    deferred: list[Any] = field(default_factory=list)  # _Command waiting for prestream
    home: HomePositionReceived | None = None
    home_request_s: float = math.inf
    """When to (re-)request HOME_POSITION (inf: not needed, or one request is in flight)."""
    home_by_get_home: bool = False
    """REQUEST_MESSAGE unsupported: use the older MAV_CMD_GET_HOME_POSITION."""
    disable_tries: dict[int, tuple[int, float]] = field(default_factory=dict)
    """msgid -> (requests so far, core time of the last one) for unused messages."""
    disable_queue: dict[int, None] = field(default_factory=dict)
    """Unused message ids waiting for the SET_MESSAGE_INTERVAL slot to be free."""
    seq: SeqCounter = field(default_factory=SeqCounter)
    """Sequence gaps of its autopilot's frames: packet loss (gcs.link_quality)."""

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)


@dataclass
class _Command:
    request_id: int
    sysid: int
    command: int
    params: tuple[float, ...]  # 7 for COMMAND_LONG; (frame, p1..p4, x, y, z) for INT
    use_int: bool
    internal: Callable[[int | None, float], None] | None = None  # stream bookkeeping (result, now)
    attempts: int = 0
    deadline_s: float = math.inf
    in_progress: bool = False
    component: int = _AUTOPILOT_COMPID
    retries: int | None = None
    """Re-sends before giving up (None: ``StationConfig.command_retries``)."""


@dataclass
class _ParamRequest:
    sysid: int
    name: str
    attempts: int = 0
    deadline_s: float = math.inf


@dataclass
class _ParamSet:
    sysid: int
    name: str
    value: float
    param_type: int
    previous: float | None = None
    attempts: int = 0
    deadline_s: float = math.inf


class _RateLimitedLog:
    """Warnings at most once per ``interval_s`` of core time per key, with the count skipped."""

    def __init__(self, interval_s: float) -> None:
        self.interval_s = interval_s
        self._last_s: dict[tuple[Any, ...], float] = {}
        self._skipped: dict[tuple[Any, ...], int] = {}

    def __call__(self, key: tuple[Any, ...], now_s: float, fmt: str, *args: object) -> None:
        last = self._last_s.get(key)
        if last is not None and now_s - last < self.interval_s:
            self._skipped[key] = self._skipped.get(key, 0) + 1
            return
        self._last_s[key] = now_s
        skipped = self._skipped.pop(key, 0)
        if skipped:
            fmt += " [%d similar warnings suppressed]"
            args = (*args, skipped)
        log.warning(fmt, *args)


def _result_name(result: int) -> str:
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name if entry is not None else f"MAV_RESULT({result})"


class LinkState:
    """The attributes of a :class:`gcs.link.StationLink` (set by its ``__init__``) and the
    helpers every part of it uses to send, emit and look vehicles up."""

    config: StationConfig
    link_id: int
    _codec: wire.Codec
    stats: LinkStats
    _t0_s: float
    _decoders: dict[Addr, wire.Decoder]
    _peers: dict[Addr, None]
    _vehicles: dict[int, _Vehicle]
    _events: deque[Event]
    _out: list[tuple[bytes, Addr]]
    _frames: list[tuple[float, bool, bytes]]
    _next_heartbeat_s: float
    _commands: dict[tuple[int, int], _Command]
    _queued: dict[tuple[int, int], deque[_Command]]
    _params: dict[tuple[int, str], _ParamRequest]
    _param_queue: dict[tuple[int, str], _ParamRequest]
    _param_sets: dict[tuple[int, str], _ParamSet]
    _next_request_id: int
    _warned_types: set[str]
    _warned_own_sysid: bool
    _task_sysids: frozenset[int]
    _task_fix_s: dict[int, float]
    _task_request_s: dict[int, float]
    _timer_hint_s: float
    _warn: _RateLimitedLog
    _used_msgids: frozenset[int] | set[int]

    def _wake(self, t_s: float) -> None:
        if t_s < self._timer_hint_s:
            self._timer_hint_s = t_s

    def _get(self, sysid: int) -> _Vehicle:
        try:
            return self._vehicles[sysid]
        except KeyError:
            raise UnknownVehicle(f"link {self.link_id}: no vehicle with sysid {sysid}") from None

    def _emit(self, event: Event) -> None:
        self._events.append(event)

    def _emit_converted(
        self,
        convert: Callable[[int, int, float, Any], Event],
        v: _Vehicle,
        msg: Any,
        now_s: float,
    ) -> None:
        """The event ``convert`` (a codec-edge converter) makes of vehicle ``v``'s ``msg``; a
        value no event accepts (ValueError) is counted as invalid telemetry instead."""
        try:
            ev = convert(self.link_id, v.sysid, now_s, msg)
        except ValueError:
            self.stats.invalid_telemetry += 1
            return
        self._emit(ev)

    def _send(self, msg: Any, addr: Addr, now_s: float) -> None:
        if self._codec.signing:
            self._codec.set_signing_time(now_s + self.config.unix_time_at_zero_s)
        frame = self._codec.encode(msg)
        self._out.append((frame, addr))
        self.stats.frames_out += 1
        if self.config.record_frames:
            self._frames.append((now_s + self.config.unix_time_at_zero_s, True, frame))

    def _broadcast(self, msg: Any, now_s: float) -> None:
        # Each peer gets its own frame (same seq is fine for a broadcast: encode once).
        if not self._peers:
            return
        if self._codec.signing:
            self._codec.set_signing_time(now_s + self.config.unix_time_at_zero_s)
        frame = self._codec.encode(msg)
        if self.config.record_frames:
            self._frames.append((now_s + self.config.unix_time_at_zero_s, True, frame))
        for addr in self._peers:
            self._out.append((frame, addr))
            self.stats.frames_out += 1

    def _heartbeat_msg(self) -> Any:
        # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, base_mode 0, state ACTIVE (mavlink.io heartbeat).
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )

"""The station-side MAVLink core for one link: bytes and ``now_s`` in, bytes and events out.

No sockets, no clock, no threads (docs/design/architecture.md §2.1; aioquic's surface):

* inputs: :meth:`StationLink.receive_datagram`, :meth:`StationLink.handle_timer` and local calls
  (:meth:`~StationLink.set_mode`, :meth:`~StationLink.arm`, :meth:`~StationLink.takeoff`,
  :meth:`~StationLink.set_position_target`, :meth:`~StationLink.request_param`, ...), each with
  an explicit ``now_s``;
* outputs: :meth:`~StationLink.datagrams_to_send`, :meth:`~StationLink.next_timer_s`,
  :meth:`~StationLink.next_event`.

``addr`` is opaque: a UDP ``(host, port)``, a TCP peer, a serial port name, or anything hashable
an in-memory ether uses. The core keeps its own sysid -> address table: a message *to* a vehicle
goes only to the address that vehicle was last heard from; only broadcasts (our HEARTBEAT) go to
every peer. This is deliberately not mavutil's ``udpin`` behaviour of sending everything to
everyone (docs/design/mavlink.md §5.3), which at 250 vehicles per network multiplies traffic by 250.

Errors: a misuse of this API (unknown sysid, unknown mode name) raises; anything a remote sends
is counted in :attr:`StationLink.stats` and dropped, never raised (docs/design/architecture.md §7).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any
from collections.abc import Callable, Hashable

from gcs import wire
from gcs.autopilot import Adapter, CommandSpec, adapter_for
from gcs.events import (
    ArmedChanged, CommandAcked, CommandFailed, CommandInProgress, CommandTimedOut, Event,
    HomePositionReceived, ModeChanged, ParamReceived, ParamSetConfirmed, ParamSetFailed, ParamTimedOut, StatusText,
    TaskPositionReceived,
    TelemetryReceived, VehicleDiscovered, VehicleLost, VehicleRecovered,
)
from gcs.rally import mission_event
from gcs.wire import mavlink

__all__ = ["StationConfig", "StationLink", "VehicleInfo", "LinkStats", "UnknownVehicle",
           "LinkUsageError", "NON_VEHICLE_TYPES", "DEFAULT_STREAM_RATES_HZ"]

log = logging.getLogger(__name__)

Addr = Hashable

#: HEARTBEAT.type values that never create a vehicle (docs/design/mavlink.md §1.1): another GCS, a
#: companion computer, a gimbal, an ADS-B receiver.
NON_VEHICLE_TYPES = frozenset({
    mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_TYPE_GIMBAL,
    mavlink.MAV_TYPE_ADSB,
})

_MSG = mavlink  # message-id constants live on the dialect module
#: Telemetry we ask for (Skybrush's fleet-scale rates, docs/design/mavlink.md §2): message id -> Hz.
DEFAULT_STREAM_RATES_HZ: tuple[tuple[int, float], ...] = (
    (_MSG.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 4.0),
    (_MSG.MAVLINK_MSG_ID_SYS_STATUS, 1.0),
    (_MSG.MAVLINK_MSG_ID_GPS_RAW_INT, 1.0),
    (_MSG.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 1.0),
)

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

_CMD_SET_MESSAGE_INTERVAL = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL  # 511
_AUTOPILOT_COMPID = mavlink.MAV_COMP_ID_AUTOPILOT1                 # 1


class UnknownVehicle(KeyError):
    """Local error: a call named a sysid this link has never discovered."""


class LinkUsageError(RuntimeError):
    """Local error: a call that cannot be honoured in the current state (e.g. no position yet)."""


@dataclass(frozen=True)
class StationConfig:
    """Station identity and protocol timing. Units are in the field names."""

    sysid: int = 255
    """Our MAVLink system id. 255 is ArduPilot's default SYSID_MYGCS / MAV_GCS_SYSID, the only
    sender whose heartbeats count for the GCS failsafe (docs/design/mavlink.md §1.1)."""
    compid: int = mavlink.MAV_COMP_ID_MISSIONPLANNER
    """Our component id: 190 (MAV_COMP_ID_MISSIONPLANNER), what QGroundControl and Mission Planner
    send (QGC ``MAVLinkProtocol::getComponentId``). Not 0: component 0 is the broadcast *target*
    address (mavlink.io routing), ambiguous as a source."""
    heartbeat_period_s: float = 1.0
    vehicle_timeout_s: float = 5.0
    """No HEARTBEAT for this long -> VehicleLost (mavlink.io: 4-5 missed; Skybrush: 5 s)."""
    command_timeout_s: float = 0.5
    """COMMAND_ACK wait per attempt (MAVSDK / pymavswarm default)."""
    command_retries: int = 3
    """Re-sends after the first attempt (confirmation 1..retries) before CommandTimedOut."""
    command_in_progress_timeout_s: float = 5.0
    """After MAV_RESULT_IN_PROGRESS, wait this long for the final ACK (no re-sends)."""
    param_timeout_s: float = 1.0
    param_retries: int = 3
    params_in_flight: int = 16
    """At most this many PARAM_REQUEST_READs outstanding per link; the rest wait their turn (a
    fleet audit is hundreds of reads: sent at once they overflow receive queues and radios)."""
    stream_rates_hz: tuple[tuple[int, float], ...] = DEFAULT_STREAM_RATES_HZ
    """(message id, Hz) pairs requested from every vehicle on discovery and recovery."""
    stale_msgids: tuple[int, ...] = (_MSG.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,)
    """Messages whose silence (while heartbeats still arrive) triggers a re-request."""
    telemetry_stale_s: float = 3.0
    static_peers: tuple[Addr, ...] = ()
    """Addresses to heartbeat even before hearing them (udpout, tcp)."""
    datagram: bool = True
    """True for UDP (drop incomplete trailing frames), False for byte streams (TCP, serial)."""
    signing_key: bytes | None = None
    """32-byte MAVLink 2 signing key; outgoing frames are signed when set."""
    accept_unsigned: bool = True
    """With a key: still accept unsigned incoming frames (pymavlink allow_unsigned_callback)."""
    unix_time_offset_s: float = 0.0
    """``unix time = now_s + offset``; only for signing timestamps and frame records."""
    record_frames: bool = False
    """Keep every frame in and out for :meth:`StationLink.take_frames` (the .tlog)."""
    task_sysids: tuple[int, ...] = ()
    """MAVLink systems that are *tasks* (crew trackers, rovers): never discovered as vehicles,
    never commanded; their GLOBAL_POSITION_INT (any component) becomes TaskPositionReceived, and
    the station asks them for it (SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM) until it arrives."""
    task_position_rate_hz: float = 1.0
    allowed_sysids: frozenset[int] | None = None
    """Only these sysids may become vehicles on this link (None: any). Frames from the others
    are counted in ``LinkStats.refused_sysids`` / ``refused_by_sysid`` and dropped."""
    max_vehicles: int | None = None
    """At most this many vehicles on this link: the first heard; later sysids are refused."""
    address_hold_s: float = 2.0
    """Datagram links: a vehicle heard from its address within this long keeps that address;
    frames with its sysid from another address meanwhile are counted as inconsistent and
    dropped. Only a HEARTBEAT from a new address moves a vehicle whose old one went silent."""
    warn_interval_s: float = 10.0
    """Rate limit of the warnings about refused and inconsistent frames (per kind)."""
    request_home_position: bool = True
    """Ask every vehicle for HOME_POSITION (MAV_CMD_REQUEST_MESSAGE) on discovery, recovery and
    arming, and every ``home_request_period_s`` until one arrives."""
    home_request_period_s: float = 5.0
    disable_unused_messages: bool = True
    """Turn off what the station does not use: when a vehicle's autopilot sends a message the
    station neither handles nor asked for (``stream_rates_hz``, ``stale_msgids``), send it
    MAV_CMD_SET_MESSAGE_INTERVAL with interval -1 ("stop sending": ArduPilot GCS_Common.cpp
    set_message_interval; PX4 MavlinkReceiver::set_message_interval, rate 0 stops the stream).
    PX4 streams ~300 frames/s per vehicle on a GCS link by default; the station reads 3 of them.
    Only this channel of the vehicle is affected (both autopilots keep intervals per link)."""
    disable_retry_s: float = 10.0
    """A message still arriving this long after we asked to stop it is asked again ..."""
    disable_attempts: int = 3
    """... at most this many times per (vehicle, message) (reset when the vehicle reboots)."""

    def __post_init__(self) -> None:
        if not 1 <= self.sysid <= 255:
            raise ValueError(f"sysid must be in 1..255, got {self.sysid}")
        if not 1 <= self.compid <= 255:
            raise ValueError(f"compid must be in 1..255 (0 is broadcast), got {self.compid}")
        if self.sysid in self.task_sysids:
            raise ValueError(f"task_sysids must not contain our own sysid {self.sysid}")
        if any(not 1 <= t <= 255 for t in self.task_sysids):
            raise ValueError(f"task_sysids must be in 1..255, got {self.task_sysids}")
        for name in ("heartbeat_period_s", "vehicle_timeout_s", "command_timeout_s",
                     "param_timeout_s", "telemetry_stale_s", "command_in_progress_timeout_s",
                     "task_position_rate_hz", "home_request_period_s", "disable_retry_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be > 0, got {v}")
        if self.disable_attempts < 0:
            raise ValueError("disable_attempts must be >= 0")
        if self.params_in_flight < 1:
            raise ValueError("params_in_flight must be >= 1")
        if self.command_retries < 0 or self.param_retries < 0:
            raise ValueError("retries must be >= 0")
        if self.allowed_sysids is not None:
            allowed = frozenset(int(s) for s in self.allowed_sysids)
            if any(not 1 <= s <= 255 for s in allowed):
                raise ValueError(f"allowed_sysids must be in 1..255, got {sorted(allowed)}")
            object.__setattr__(self, "allowed_sysids", allowed)
        if self.max_vehicles is not None and self.max_vehicles < 1:
            raise ValueError(f"max_vehicles must be >= 1 or None, got {self.max_vehicles}")
        for name in ("address_hold_s", "warn_interval_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be >= 0, got {v}")


@dataclass
class LinkStats:
    """Counters for everything the core dropped or did (the decoder counts live in ``decode``)."""

    decode: wire.DecodeStats = field(default_factory=wire.DecodeStats)
    frames_out: int = 0
    from_unknown_sysid: int = 0
    """Non-heartbeat messages from a sysid we have not discovered."""
    non_vehicle_heartbeats: int = 0
    own_sysid: int = 0
    """Messages claiming our own sysid (another station configured like us?)."""
    ignored_messages: int = 0
    handler_errors: int = 0
    invalid_telemetry: int = 0
    unexpected_acks: int = 0
    data_stream_fallbacks: int = 0
    stream_rerequests: int = 0
    task_heartbeats: int = 0
    """Heartbeats from task systems (``StationConfig.task_sysids``), never vehicles."""
    refused_sysids: int = 0
    """Frames from sysids that may not become vehicles (``allowed_sysids``, ``max_vehicles``)."""
    refused_by_sysid: dict[int, int] = field(default_factory=dict)
    """The same, per sysid."""
    messages_disabled: int = 0
    """SET_MESSAGE_INTERVAL(-1) requests the vehicles accepted (``disable_unused_messages``)."""
    disable_requests: int = 0
    """SET_MESSAGE_INTERVAL(-1) requests sent (first sends; the command retries not counted)."""
    inconsistent_frames: int = 0
    """Frames that contradict what a vehicle has been: another autopilot or vehicle type in its
    HEARTBEAT, or (datagram links) its sysid from a second address while the first is live."""


@dataclass(frozen=True)
class VehicleInfo:
    """A read-only view of one vehicle as this link knows it."""

    link_id: int
    sysid: int
    autopilot: int
    vehicle_type: int
    adapter: str
    custom_mode: int
    mode: str
    armed: bool
    lost: bool
    last_heartbeat_s: float
    streaming_setpoints: bool
    home_alt_amsl_m: float = math.nan
    """From HOME_POSITION; NaN until the vehicle sent one."""


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
    setpoint: tuple[float, float, float, int] | None = None   # lat, lon, alt, frame
    setpoint_since_s: float = math.nan
    setpoint_next_s: float = math.inf
    deferred: list[Any] = field(default_factory=list)         # _Command waiting for prestream
    home: HomePositionReceived | None = None
    home_request_s: float = math.inf
    """When to (re-)request HOME_POSITION (inf: not needed, or one request is in flight)."""
    home_by_get_home: bool = False
    """REQUEST_MESSAGE unsupported: use the older MAV_CMD_GET_HOME_POSITION."""
    disable_tries: dict[int, tuple[int, float]] = field(default_factory=dict)
    """msgid -> (requests so far, core time of the last one) for unused messages."""
    disable_queue: dict[int, None] = field(default_factory=dict)
    """Unused message ids waiting for the SET_MESSAGE_INTERVAL slot to be free."""

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)


@dataclass
class _Command:
    request_id: int
    sysid: int
    command: int
    params: tuple[float, ...]          # 7 for COMMAND_LONG; (frame, p1..p4, x, y, z) for INT
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


class StationLink:
    """One link's station core (see the module docstring)."""

    def __init__(self, config: StationConfig | None = None, *, link_id: int = 0,
                 now_s: float = 0.0) -> None:
        self.config = config or StationConfig()
        self.link_id = link_id
        self._codec = wire.Codec(self.config.sysid, self.config.compid,
                                 signing_key=self.config.signing_key,
                                 signing_link_id=link_id & 0xFF,
                                 accept_unsigned=self.config.accept_unsigned,
                                 full_msgids=_DECODED_MSGIDS)
        self.stats = LinkStats(decode=self._codec.stats)
        self._t0_s = now_s
        self._decoders: dict[Addr, wire.Decoder] = {}
        self._peers: dict[Addr, None] = dict.fromkeys(self.config.static_peers)
        self._vehicles: dict[int, _Vehicle] = {}
        self._events: deque[Event] = deque()
        self._out: list[tuple[bytes, Addr]] = []
        self._frames: list[tuple[float, bool, bytes]] = []
        self._next_heartbeat_s = now_s
        self._commands: dict[tuple[int, int], _Command] = {}
        self._queued: dict[tuple[int, int], deque[_Command]] = {}
        self._params: dict[tuple[int, str], _ParamRequest] = {}
        self._param_queue: dict[tuple[int, str], _ParamRequest] = {}
        """Requests waiting for a free slot (``params_in_flight``), in request order."""
        self._param_sets: dict[tuple[int, str], _ParamSet] = {}
        self._next_request_id = 1
        self._warned_types: set[str] = set()
        self._warned_own_sysid = False
        self._task_sysids = frozenset(self.config.task_sysids)
        self._task_fix_s: dict[int, float] = {}
        self._task_request_s: dict[int, float] = {}
        self._timer_hint_s = now_s
        self._warn = _RateLimitedLog(self.config.warn_interval_s)
        self._used_msgids = (_NEVER_DISABLE
                             | {m for m, _ in self.config.stream_rates_hz}
                             | set(self.config.stale_msgids))

    # ------------------------------------------------------------------ outputs

    def datagrams_to_send(self, now_s: float) -> list[tuple[bytes, Addr]]:
        """Everything queued for the wire, one MAVLink frame per datagram, in order."""
        out, self._out = self._out, []
        return out

    def next_event(self) -> Event | None:
        return self._events.popleft() if self._events else None

    def take_frames(self) -> list[tuple[float, bool, bytes]]:
        """Recorded frames ``(unix_time_s, outgoing, frame)`` since the last call (record_frames)."""
        out, self._frames = self._frames, []
        return out

    def next_timer_s(self) -> float | None:
        """The earliest core time at which :meth:`handle_timer` may have work to do.

        O(1): a lower bound kept up to date as deadlines are set (a receive can only push
        deadlines later), recomputed exactly by :meth:`handle_timer`. An early wake-up is
        harmless; a late one never happens.
        """
        return self._timer_hint_s if math.isfinite(self._timer_hint_s) else None

    def _wake(self, t_s: float) -> None:
        if t_s < self._timer_hint_s:
            self._timer_hint_s = t_s

    def _compute_next_timer_s(self) -> float:
        cfg = self.config
        t = self._next_heartbeat_s
        for cmd in self._commands.values():
            t = min(t, cmd.deadline_s)
        for req in self._params.values():
            t = min(t, req.deadline_s)
        for ps in self._param_sets.values():
            t = min(t, ps.deadline_s)
        for v in self._vehicles.values():
            if not v.lost:
                t = min(t, v.last_heartbeat_s + cfg.vehicle_timeout_s, self._stale_due_s(v))
            if not v.lost:
                t = min(t, v.setpoint_next_s)
            if v.deferred:
                t = min(t, v.setpoint_since_s + v.adapter.prestream_s)
            if not v.lost:
                t = min(t, v.home_request_s)
        return t

    # ------------------------------------------------------------------ queries

    def vehicles(self) -> list[VehicleInfo]:
        return [self._info(v) for v in self._vehicles.values()]

    def vehicle(self, sysid: int) -> VehicleInfo:
        return self._info(self._get(sysid))

    def networked_sysids(self) -> list[int]:
        return [s for s, v in self._vehicles.items() if not v.lost]

    def address_of(self, sysid: int) -> Addr:
        return self._get(sysid).addr

    def _info(self, v: _Vehicle) -> VehicleInfo:
        return VehicleInfo(self.link_id, v.sysid, v.autopilot, v.vehicle_type, v.adapter.name,
                           v.custom_mode, v.adapter.mode_name(v.custom_mode), v.armed, v.lost,
                           v.last_heartbeat_s, v.setpoint is not None,
                           v.home.alt_amsl_m if v.home is not None else math.nan)

    def _get(self, sysid: int) -> _Vehicle:
        try:
            return self._vehicles[sysid]
        except KeyError:
            raise UnknownVehicle(f"link {self.link_id}: no vehicle with sysid {sysid}") from None

    # ------------------------------------------------------------------ sending

    def _emit(self, event: Event) -> None:
        self._events.append(event)

    def _send(self, msg: Any, addr: Addr, now_s: float) -> None:
        if self._codec.signing:
            self._codec.set_signing_time(now_s + self.config.unix_time_offset_s)
        frame = self._codec.encode(msg)
        self._out.append((frame, addr))
        self.stats.frames_out += 1
        if self.config.record_frames:
            self._frames.append((now_s + self.config.unix_time_offset_s, True, frame))

    def _broadcast(self, msg: Any, now_s: float) -> None:
        # Each peer gets its own frame (same seq is fine for a broadcast: encode once).
        if not self._peers:
            return
        if self._codec.signing:
            self._codec.set_signing_time(now_s + self.config.unix_time_offset_s)
        frame = self._codec.encode(msg)
        if self.config.record_frames:
            self._frames.append((now_s + self.config.unix_time_offset_s, True, frame))
        for addr in self._peers:
            self._out.append((frame, addr))
            self.stats.frames_out += 1

    def _heartbeat_msg(self) -> Any:
        # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, base_mode 0, state ACTIVE (mavlink.io heartbeat).
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
            mavlink.MAV_STATE_ACTIVE, 3)

    # ------------------------------------------------------------------ receiving

    def reset_stream(self, addr: Addr) -> None:
        """A byte stream from ``addr`` was re-opened (TCP reconnect, serial re-plug): forget any
        partial frame of the old one, so it cannot be glued to the new stream's bytes."""
        self._decoders.pop(addr, None)

    def receive_datagram(self, data: bytes, addr: Addr, now_s: float) -> None:
        """Feed bytes heard from ``addr``. Never raises for remote garbage (it is counted)."""
        dec = self._decoders.get(addr)
        if dec is None:
            dec = self._decoders[addr] = self._codec.new_decoder()
        for msg in dec.feed(bytes(data), datagram=self.config.datagram):
            self._peers.setdefault(addr, None)
            if self.config.record_frames:
                self._frames.append((now_s + self.config.unix_time_offset_s, False,
                                     bytes(msg.get_msgbuf())))
            try:
                self._dispatch(msg, addr, now_s)
            except Exception:  # a handler bug must not take the link down
                self.stats.handler_errors += 1
                log.exception("link %d: handler error on %s from sysid %d", self.link_id,
                              msg.get_type(), msg.get_srcSystem())

    def _dispatch(self, msg: Any, addr: Addr, now_s: float) -> None:
        kind = msg.get_type()
        sysid = msg.get_srcSystem()
        if sysid == self.config.sysid:
            self.stats.own_sysid += 1
            if kind == "HEARTBEAT" and not self._warned_own_sysid:
                # E.g. MAVProxy (sim_vehicle.py's default, sysid 255): ArduPilot counts every
                # heartbeat from SYSID_MYGCS / MAV_GCS_SYSID for its GCS failsafe
                # (GCS_Common.cpp handle_heartbeat), so that GCS keeps the failsafe from
                # triggering when we are gone. Never a vehicle, never us.
                self._warned_own_sysid = True
                log.warning("link %d: another system sends heartbeats with our sysid %d "
                            "(compid %d, MAVProxy?): its heartbeats also feed the vehicles' GCS "
                            "failsafe; run SITL with --no-mavproxy or give one of us another "
                            "sysid", self.link_id, sysid, msg.get_srcComponent())
            return
        if sysid in self._task_sysids:
            self._on_task_message(msg, addr, now_s)
            return
        v = self._vehicles.get(sysid)
        if v is None:
            if kind == "HEARTBEAT" and not self._is_vehicle_heartbeat(msg):
                self.stats.non_vehicle_heartbeats += 1
            elif not self._may_become_vehicle(sysid):
                self._refuse(sysid, kind, addr, now_s)
            elif kind == "HEARTBEAT":
                self._discover(msg, addr, now_s)
            else:
                self.stats.from_unknown_sysid += 1
            return
        if msg.get_srcComponent() == _AUTOPILOT_COMPID and self.config.datagram:
            # Its other components (gimbal, companion) may well talk from other ports; only
            # the autopilot's own frames define where the vehicle is.
            if addr == v.addr:
                v.addr_heard_s = now_s
            elif not self._moved(v, msg, kind, addr, now_s):
                return
        if kind == "HEARTBEAT":
            self._on_heartbeat(v, msg, addr, now_s)
            return
        if msg.get_srcComponent() != _AUTOPILOT_COMPID:
            self.stats.ignored_messages += 1  # gimbal, camera, companion: not the autopilot
            return
        v.last_msg_s[msg.get_msgId()] = now_s
        handler = _HANDLERS.get(kind)
        if handler is not None:
            handler(self, v, msg, now_s)
        else:
            self.stats.ignored_messages += 1
            if self.config.disable_unused_messages:
                self._note_unused(v, msg.get_msgId(), now_s)
            if kind not in _IGNORED and kind not in self._warned_types:
                self._warned_types.add(kind)
                log.info("link %d: ignoring %s (first seen from sysid %d)", self.link_id, kind,
                         sysid)

    # ------------------------------------------------------------------ who is a vehicle

    @staticmethod
    def _is_vehicle_heartbeat(msg: Any) -> bool:
        return (msg.get_srcComponent() == _AUTOPILOT_COMPID and msg.type not in NON_VEHICLE_TYPES
                and msg.get_srcSystem() != 0)

    def _may_become_vehicle(self, sysid: int) -> bool:
        cfg = self.config
        if cfg.allowed_sysids is not None and sysid not in cfg.allowed_sysids:
            return False
        return cfg.max_vehicles is None or len(self._vehicles) < cfg.max_vehicles

    def _refuse(self, sysid: int, kind: str, addr: Addr, now_s: float) -> None:
        st = self.stats
        st.refused_sysids += 1
        st.refused_by_sysid[sysid] = st.refused_by_sysid.get(sysid, 0) + 1
        self._warn(("refused",), now_s, "link %d: refused %s from sysid %d at %s (not an allowed "
                   "vehicle on this link; %d refused so far)", self.link_id, kind, sysid, addr,
                   st.refused_sysids)

    def _inconsistent(self, v: _Vehicle, now_s: float, what: str, *args: object) -> None:
        self.stats.inconsistent_frames += 1
        self._warn(("inconsistent", v.sysid), now_s, "link %d sysid %d: " + what + " (%d such "
                   "frames dropped on this link)", self.link_id, v.sysid, *args,
                   self.stats.inconsistent_frames)

    def _identity_changed(self, v: _Vehicle, msg: Any) -> bool:
        return msg.autopilot != v.autopilot or msg.type != v.vehicle_type

    def _moved(self, v: _Vehicle, msg: Any, kind: str, addr: Addr, now_s: float) -> bool:
        """A datagram with ``v``'s sysid from an address other than ``v.addr``: True if the
        vehicle really moved there (its old address silent, a consistent HEARTBEAT from the
        new one), after which the frame is processed; False if it is dropped."""
        if now_s - v.addr_heard_s < self.config.address_hold_s:
            # Two live sources of one sysid: a duplicate route, a misconfigured second vehicle
            # or a forger. Keep the first; never flip-flop commands between them.
            self._inconsistent(v, now_s, "%s from %s while %s is live; kept %s", kind, addr,
                               v.addr, v.addr)
            return False
        if kind != "HEARTBEAT" or not self._is_vehicle_heartbeat(msg) \
                or (self._identity_changed(v, msg) and not v.lost):
            self._inconsistent(v, now_s, "%s from %s, not its address %s (silent %.1f s)", kind,
                               addr, v.addr, now_s - v.addr_heard_s)
            return False
        log.info("link %d sysid %d: moved from %s to %s (old address silent %.1f s)",
                 self.link_id, v.sysid, v.addr, addr, now_s - v.addr_heard_s)
        v.addr, v.addr_heard_s = addr, now_s  # a reboot or a NAT rebinding
        return True

    def _discover(self, msg: Any, addr: Addr, now_s: float) -> None:
        sysid = msg.get_srcSystem()
        adapter = adapter_for(msg.autopilot)
        v = _Vehicle(sysid, addr, msg.autopilot, msg.type, adapter, msg.custom_mode,
                     msg.base_mode, now_s, addr_heard_s=now_s)
        v.last_msg_s[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = now_s
        self._vehicles[sysid] = v
        self._wake(now_s + self.config.vehicle_timeout_s)
        self._emit(VehicleDiscovered(self.link_id, sysid, now_s, msg.autopilot, msg.type,
                                     msg.custom_mode, adapter.mode_name(msg.custom_mode),
                                     v.armed))
        # QGC sends a heartbeat at once so the vehicle knows its GCS (and arms its failsafe).
        self._send(self._heartbeat_msg(), addr, now_s)
        self._request_streams(v, now_s)
        self._request_home(v, now_s)

    def _on_heartbeat(self, v: _Vehicle, msg: Any, addr: Addr, now_s: float) -> None:
        sysid = v.sysid
        if not self._is_vehicle_heartbeat(msg):
            self.stats.non_vehicle_heartbeats += 1  # its gimbal, companion computer, ...
            return
        if self._identity_changed(v, msg):
            if not v.lost:
                # A live vehicle does not change firmware or frame: this is another system
                # using its sysid (or noise that passed the CRC). Its mode would be decoded with
                # the wrong adapter: drop the whole heartbeat.
                self._inconsistent(v, now_s, "HEARTBEAT with autopilot %d type %d, but it is "
                                   "autopilot %d type %d", msg.autopilot, msg.type, v.autopilot,
                                   v.vehicle_type)
                return
            # Silent for a whole timeout, then back as something else: re-flashed or replaced.
            log.warning("link %d sysid %d: back as autopilot %d type %d (was %d type %d)",
                        self.link_id, sysid, msg.autopilot, msg.type, v.autopilot,
                        v.vehicle_type)
            v.autopilot, v.adapter = msg.autopilot, adapter_for(msg.autopilot)
        v.last_msg_s[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = now_s
        was_lost, silent_s = v.lost, now_s - v.last_heartbeat_s
        v.last_heartbeat_s = now_s
        was_armed, old_mode = v.armed, v.custom_mode
        v.custom_mode, v.base_mode, v.vehicle_type = msg.custom_mode, msg.base_mode, msg.type
        if was_lost:
            v.lost = False
            self._wake(now_s + self.config.vehicle_timeout_s)
            self._emit(VehicleRecovered(self.link_id, sysid, now_s, silent_s, v.custom_mode,
                                        v.adapter.mode_name(v.custom_mode)))
            self._send(self._heartbeat_msg(), addr, now_s)
            self._request_streams(v, now_s)  # it may have rebooted and forgotten our rates
            self._request_home(v, now_s)
            v.disable_tries.clear()  # ... and our stops: a reboot restores the default streams
            v.disable_queue.clear()
        if old_mode != v.custom_mode:
            self._emit(ModeChanged(self.link_id, sysid, now_s, v.custom_mode,
                                   v.adapter.mode_name(v.custom_mode),
                                   v.adapter.mode_name(old_mode)))
        if was_armed != v.armed:
            self._emit(ArmedChanged(self.link_id, sysid, now_s, v.armed))
            if v.armed:
                # Both autopilots move home to where they arm (ArduCopter AP_Arming_Copter::arm
                # set_home_to_current_location; PX4 Commander::set_home_position on arming):
                # ask for the new one rather than wait for the next unsolicited message.
                self._request_home(v, now_s)

    def _on_task_message(self, msg: Any, addr: Addr, now_s: float) -> None:
        """A task system: its position, and a position stream request while none arrives."""
        sysid = msg.get_srcSystem()
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            if msg.lat == 0 and msg.lon == 0:  # no fix yet
                self.stats.invalid_telemetry += 1
                return
            try:
                ev = TaskPositionReceived(self.link_id, sysid, now_s,
                                          lat_deg=wire.e7_to_deg(msg.lat),
                                          lon_deg=wire.e7_to_deg(msg.lon),
                                          alt_amsl_m=wire.mm_to_m(msg.alt))
            except ValueError:
                self.stats.invalid_telemetry += 1
                return
            self._task_fix_s[sysid] = now_s
            self._emit(ev)
        elif kind == "HEARTBEAT":
            self.stats.task_heartbeats += 1
            last_fix = self._task_fix_s.get(sysid, -math.inf)
            last_req = self._task_request_s.get(sysid, -math.inf)
            if (now_s - last_fix > self.config.telemetry_stale_s
                    and now_s - last_req >= self.config.telemetry_stale_s):
                self._task_request_s[sysid] = now_s
                self._request_task_position(sysid, msg.get_srcComponent(), addr, now_s)
        else:
            self.stats.ignored_messages += 1

    def _request_task_position(self, sysid: int, compid: int, addr: Addr, now_s: float) -> None:
        """Fire-and-forget: trackers differ (an ArduPilot Rover streams only when asked; a plain
        tracker streams anyway and ignores both). No ACK is awaited: a task is never commanded."""
        hz = self.config.task_position_rate_hz
        self._send(mavlink.MAVLink_command_long_message(
            sysid, compid, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, wire.hz_to_interval_us(hz),
            0, 0, 0, 0, 0), addr, now_s)
        self._send(mavlink.MAVLink_request_data_stream_message(
            sysid, compid, mavlink.MAV_DATA_STREAM_POSITION, max(1, int(round(hz))), 1),
            addr, now_s)

    def _on_global_position(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        if msg.lat == 0 and msg.lon == 0:  # ArduPilot before a GPS fix
            self.stats.invalid_telemetry += 1
            return
        try:
            ev = TelemetryReceived(
                self.link_id, v.sysid, now_s,
                lat_deg=wire.e7_to_deg(msg.lat), lon_deg=wire.e7_to_deg(msg.lon),
                alt_amsl_m=wire.mm_to_m(msg.alt), rel_alt_m=wire.mm_to_m(msg.relative_alt),
                vel_ned_m_s=(wire.cm_s_to_m_s(msg.vx), wire.cm_s_to_m_s(msg.vy),
                             wire.cm_s_to_m_s(msg.vz)),
                yaw_rad=wire.hdg_cdeg_to_yaw_rad(msg.hdg), time_boot_s=msg.time_boot_ms / 1000.0)
        except ValueError:
            self.stats.invalid_telemetry += 1
            return
        v.position = ev
        self._emit(ev)

    def _on_home_position(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        if msg.latitude == 0 and msg.longitude == 0:  # no home yet
            self.stats.invalid_telemetry += 1
            return
        try:
            ev = HomePositionReceived(self.link_id, v.sysid, now_s,
                                      lat_deg=wire.e7_to_deg(msg.latitude),
                                      lon_deg=wire.e7_to_deg(msg.longitude),
                                      alt_amsl_m=wire.mm_to_m(msg.altitude))
        except ValueError:
            self.stats.invalid_telemetry += 1
            return
        v.home_request_s = math.inf
        old = v.home
        v.home = ev
        if old is None or (old.lat_deg, old.lon_deg, old.alt_amsl_m) != (
                ev.lat_deg, ev.lon_deg, ev.alt_amsl_m):
            self._emit(ev)  # PX4 streams it every 2 s: only news become events

    def _request_home(self, v: _Vehicle, now_s: float) -> None:
        """MAV_CMD_REQUEST_MESSAGE(HOME_POSITION) (PX4 mavlink_receiver.cpp
        handle_message_command_long -> request_message; ArduPilot GCS_Common.cpp
        handle_command_request_message, MSG_HOME), or MAV_CMD_GET_HOME_POSITION on firmware
        without it. Re-sent every ``home_request_period_s`` until HOME_POSITION arrives: before a
        GPS fix neither autopilot has a home to send."""
        if not self.config.request_home_position:
            return
        v.home_request_s = math.inf  # re-armed when this command finishes without a home
        if v.home_by_get_home:
            command, params = mavlink.MAV_CMD_GET_HOME_POSITION, (0.0,) * 7
        else:
            command = mavlink.MAV_CMD_REQUEST_MESSAGE
            params = (float(mavlink.MAVLINK_MSG_ID_HOME_POSITION),) + (0.0,) * 6
        key = (v.sysid, command)
        if any(c is not None and c.internal is not None
               for c in (self._commands.get(key), *self._queued.get(key, ()))):
            return  # already asked and waiting
        cmd = self._new_command(v.sysid, command, params, use_int=False)
        cmd.internal = lambda result, t_s, v=v: self._on_home_request_result(v, result, t_s)
        self._submit(cmd, now_s)

    def _on_home_request_result(self, v: _Vehicle, result: int | None, now_s: float) -> None:
        if result == mavlink.MAV_RESULT_UNSUPPORTED and not v.home_by_get_home:
            v.home_by_get_home = True
        elif result not in (None, mavlink.MAV_RESULT_ACCEPTED):
            log.debug("link %d sysid %d: HOME_POSITION request refused (%s)", self.link_id,
                      v.sysid, _result_name(result))
        if v.home is None or result != mavlink.MAV_RESULT_ACCEPTED:
            # The message follows the ACK; if it never comes, ask again later.
            v.home_request_s = now_s + self.config.home_request_period_s
            self._wake(v.home_request_s)

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
                self._emit(CommandInProgress(self.link_id, v.sysid, now_s, cmd.command,
                                             cmd.request_id, int(msg.progress)))
            return
        self._finish_command(cmd, now_s, msg.result)

    def _on_param_value(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        name = wire.param_id_to_str(msg.param_id)
        if not name:
            self.stats.invalid_telemetry += 1
            return
        value = wire.decode_param_value(msg.param_value, msg.param_type,
                                        bytewise=v.adapter.param_bytewise)
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
            self._emit(ParamSetConfirmed(self.link_id, ps.sysid, now_s, ps.name, value,
                                         ps.previous, ps.param_type, ps.attempts))
        elif ps.attempts <= self.config.param_retries:
            # Maybe the answer to an earlier read, crossing our set on the wire: ask again.
            self._transmit_param_set(ps, now_s)
        else:
            del self._param_sets[key]
            self._emit(ParamSetFailed(self.link_id, ps.sysid, now_s, ps.name, ps.value, value,
                                      f"the vehicle kept {value:g}", ps.attempts))

    def _on_param_error(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        # PARAM_ERROR (newer ArduPilot GCS_Param.cpp send_param_error): a precise refusal.
        name = wire.param_id_to_str(msg.param_id)
        ps = self._param_sets.pop((v.sysid, name), None)
        if ps is None:
            self.stats.ignored_messages += 1
            return
        entry = mavlink.enums["MAV_PARAM_ERROR"].get(msg.error)
        reason = entry.name if entry is not None else f"MAV_PARAM_ERROR({msg.error})"
        self._emit(ParamSetFailed(self.link_id, v.sysid, now_s, name, ps.value, None, reason,
                                  ps.attempts))

    # Rally points (gcs/rally.py): the vehicle's replies to an upload go to its keeper as events.
    def _on_mission_protocol(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        self._emit(mission_event(self.link_id, v.sysid, msg, now_s))

    def send_message(self, sysid: int, msg: Any, now_s: float) -> None:
        """Queue one ready-made message to a vehicle (its last address): gcs/rally.py's uploads."""
        self._send(msg, self._get(sysid).addr, now_s)

    def _on_statustext(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        text = msg.text
        if isinstance(text, bytes):
            text = text.decode("utf-8", errors="replace")
        self._emit(StatusText(self.link_id, v.sysid, now_s, int(msg.severity),
                              text.rstrip("\x00")))

    # ------------------------------------------------------------------ timers

    def handle_timer(self, now_s: float) -> None:
        """Do everything due at or before ``now_s``: heartbeat, retries, losses, resends."""
        cfg = self.config
        if now_s >= self._next_heartbeat_s:
            self._broadcast(self._heartbeat_msg(), now_s)
            self._next_heartbeat_s += cfg.heartbeat_period_s
            if self._next_heartbeat_s <= now_s:  # we were late: do not burst to catch up
                self._next_heartbeat_s = now_s + cfg.heartbeat_period_s
        for cmd in [c for c in self._commands.values() if c.deadline_s <= now_s]:
            retries = cfg.command_retries if cmd.retries is None else cmd.retries
            if not cmd.in_progress and cmd.attempts <= retries:
                self._transmit_command(cmd, now_s)  # confirmation = attempts so far
            else:
                self._finish_command(cmd, now_s, None)
        for req in [r for r in self._params.values() if r.deadline_s <= now_s]:
            if req.attempts <= cfg.param_retries:
                self._transmit_param_request(req, now_s)
            else:
                del self._params[(req.sysid, req.name)]
                self._emit(ParamTimedOut(self.link_id, req.sysid, now_s, req.name, req.attempts))
        self._pump_params(now_s)
        for ps in [p for p in self._param_sets.values() if p.deadline_s <= now_s]:
            if ps.attempts <= cfg.param_retries:
                self._transmit_param_set(ps, now_s)
            else:
                del self._param_sets[(ps.sysid, ps.name)]
                self._emit(ParamSetFailed(self.link_id, ps.sysid, now_s, ps.name, ps.value, None,
                                          "no PARAM_VALUE echo", ps.attempts))
        for v in self._vehicles.values():
            if not v.lost and now_s >= v.last_heartbeat_s + cfg.vehicle_timeout_s:
                v.lost = True
                self._emit(VehicleLost(self.link_id, v.sysid, now_s, v.last_heartbeat_s))
            if not v.lost and now_s >= self._stale_due_s(v):
                self.stats.stream_rerequests += 1
                log.info("link %d sysid %d: telemetry stale, re-requesting streams",
                         self.link_id, v.sysid)
                self._request_streams(v, now_s)
            # Batch resends: whatever is due within half a period goes now, so a fleet's
            # staggered streams coalesce into few wake-ups (each wake-up scans every vehicle).
            if v.setpoint is not None and not v.lost \
                    and now_s >= v.setpoint_next_s - 0.5 * v.adapter.setpoint_period_s:
                # A silent vehicle is not streamed to (dead ones are most of a fleet's silence
                # late in a mission); on recovery it is reclaimed with a fresh target.
                self._send_setpoint(v, now_s)
            if not v.lost and now_s >= v.home_request_s:
                if v.home is None:
                    self._request_home(v, now_s)
                else:
                    v.home_request_s = math.inf
            if v.deferred and now_s >= v.setpoint_since_s + v.adapter.prestream_s:
                deferred, v.deferred = v.deferred, []
                for cmd in deferred:
                    self._submit(cmd, now_s)
        self._timer_hint_s = self._compute_next_timer_s()

    # ------------------------------------------------------------------ streams

    def _stale_due_s(self, v: _Vehicle) -> float:
        if not self.config.stale_msgids:
            return math.inf
        last = min(v.last_msg_s.get(m, -math.inf) for m in self.config.stale_msgids)
        return max(last, v.last_stream_request_s) + self.config.telemetry_stale_s

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
            if any(c is not None and c.internal is not None and c.params[0] == msgid
                   for c in pending):
                continue  # already asked and waiting
            params = (float(msgid), wire.hz_to_interval_us(rate_hz), 0.0, 0.0, 0.0, 0.0, 0.0)
            cmd = self._new_command(v.sysid, _CMD_SET_MESSAGE_INTERVAL, params, use_int=False)
            cmd.internal = (lambda result, t_s, v=v, m=msgid:
                            self._on_interval_result(v, result, t_s, m))
            self._submit(cmd, now_s)

    def _on_interval_result(self, v: _Vehicle, result: int | None, now_s: float,
                            msgid: int = 0) -> None:
        if result == mavlink.MAV_RESULT_ACCEPTED:
            v.interval_accepted = True
            return
        if v.use_data_stream:
            return
        if result not in (None, mavlink.MAV_RESULT_UNSUPPORTED) and v.interval_accepted:
            # The command works on this vehicle; it just cannot stream this one message.
            log.info("link %d sysid %d: message %d interval refused (%s)", self.link_id,
                     v.sysid, msgid, _result_name(result))
            return
        # No ACK, UNSUPPORTED, or refused before anything was accepted: older ArduPilot and
        # some routers. Fall back to REQUEST_DATA_STREAM for this vehicle from now on (Skybrush
        # pattern, docs/design/mavlink.md §1.2).
        log.info("link %d sysid %d: SET_MESSAGE_INTERVAL result %s, falling back to "
                 "REQUEST_DATA_STREAM", self.link_id, v.sysid, result)
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
                v.sysid, _AUTOPILOT_COMPID, stream, max(1, int(round(rate_hz))), 1)
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
        if not v.disable_queue or key in self._commands or self._queued.get(key) \
                or v.lost or v.sysid not in self._vehicles:
            return
        msgid = next(iter(v.disable_queue))
        del v.disable_queue[msgid]
        params = (float(msgid), -1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        cmd = self._new_command(v.sysid, _CMD_SET_MESSAGE_INTERVAL, params, use_int=False)
        cmd.retries = 1  # best effort; the message itself tells us if it did not stop
        cmd.internal = lambda result, t_s, v=v, m=msgid: self._on_disable_result(v, m, result, t_s)
        self.stats.disable_requests += 1
        self._submit(cmd, now_s)

    def _on_disable_result(self, v: _Vehicle, msgid: int, result: int | None,
                           now_s: float) -> None:
        if result == mavlink.MAV_RESULT_ACCEPTED:
            self.stats.messages_disabled += 1
            log.debug("link %d sysid %d: message %d stopped", self.link_id, v.sysid, msgid)
        elif result is not None:
            # DENIED / FAILED: not a stream this autopilot can stop (a reply to something,
            # or no ap_message for it in ArduPilot): never ask again.
            v.disable_tries[msgid] = (self.config.disable_attempts, now_s)
            log.info("link %d sysid %d: cannot stop message %d (%s)", self.link_id, v.sysid,
                     msgid, _result_name(result))

    # ------------------------------------------------------------------ commands

    def _new_command(self, sysid: int, command: int, params: tuple[float, ...], *, use_int: bool) -> _Command:
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
                cmd.sysid, cmd.component, int(frame), cmd.command, 0, 0, p1, p2, p3, p4,
                int(x), int(y), z)
        else:
            # confirmation: 0 on the first send, incremented on every re-send (mavlink.io).
            msg = mavlink.MAVLink_command_long_message(
                cmd.sysid, cmd.component, cmd.command, min(cmd.attempts, 255), *cmd.params)
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
            self._emit(CommandTimedOut(self.link_id, cmd.sysid, now_s, cmd.command,
                                       cmd.request_id, cmd.attempts))
        elif result == mavlink.MAV_RESULT_ACCEPTED:
            self._emit(CommandAcked(self.link_id, cmd.sysid, now_s, cmd.command, cmd.request_id,
                                    cmd.attempts))
        else:
            self._emit(CommandFailed(self.link_id, cmd.sysid, now_s, cmd.command, cmd.request_id,
                                     int(result), _result_name(result)))
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

    def send_command_long(self, sysid: int, command: int, params: tuple[float, ...] = (0.0,) * 7, now_s: float = 0.0,
                          *, component: int = _AUTOPILOT_COMPID) -> int:
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

    def send_command_int(self, sysid: int, command: int, *, frame: int,
                         params: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0), lat_deg: float = 0.0, lon_deg: float = 0.0,
                         alt_m: float = 0.0, now_s: float = 0.0) -> int:
        """Send a COMMAND_INT (positional commands: x/y as degE7); returns the request id."""
        self._get(sysid)
        p = tuple(float(v) for v in params)
        if len(p) != 4:
            raise ValueError(f"COMMAND_INT takes 4 params, got {len(p)}")
        cmd = self._new_command(sysid, command, (frame, *p, wire.deg_to_e7(lat_deg),
                                                 wire.deg_to_e7(lon_deg), float(alt_m)),
                                use_int=True)
        self._submit(cmd, now_s)
        return cmd.request_id

    def _send_spec(self, sysid: int, spec: CommandSpec, now_s: float) -> int:
        v = self._get(sysid)
        cmd = self._new_command(sysid, spec.command, spec.params, use_int=False)
        if spec.after_prestream and v.adapter.prestream_s > 0:
            if v.setpoint is None:
                raise LinkUsageError(
                    f"sysid {sysid} ({v.adapter.name}): stream position targets "
                    "(set_position_target) before switching to offboard or arming")
            if now_s < v.setpoint_since_s + v.adapter.prestream_s:
                v.deferred.append(cmd)  # sent by handle_timer once the stream is old enough
                self._wake(v.setpoint_since_s + v.adapter.prestream_s)
                return cmd.request_id
        self._submit(cmd, now_s)
        return cmd.request_id

    # ------------------------------------------------------------------ vehicle actions

    def set_mode(self, sysid: int, mode: str, now_s: float) -> int:
        """Request a flight mode by name (adapter table); confirmed later by ModeChanged."""
        return self._send_spec(sysid, self._get(sysid).adapter.set_mode(mode), now_s)

    def engage_guided(self, sysid: int, now_s: float) -> int:
        """GUIDED (ArduPilot) or OFFBOARD (PX4, held until setpoints have pre-streamed)."""
        return self.set_mode(sysid, self._get(sysid).adapter.guided_mode, now_s)

    def arm(self, sysid: int, now_s: float) -> int:
        """Arm (MAV_CMD_COMPONENT_ARM_DISARM param1 = 1; never forced)."""
        return self._send_spec(sysid, self._get(sysid).adapter.arm(), now_s)

    def disarm(self, sysid: int, now_s: float) -> int:
        return self._send_spec(sysid, self._get(sysid).adapter.disarm(), now_s)

    def rtl(self, sysid: int, now_s: float) -> int:
        return self.set_mode(sysid, self._get(sysid).adapter.rtl_mode, now_s)

    def land(self, sysid: int, now_s: float) -> int:
        return self.set_mode(sysid, self._get(sysid).adapter.land_mode, now_s)

    def takeoff(self, sysid: int, alt_above_home_m: float, now_s: float) -> int | None:
        """Take off to ``alt_above_home_m``.

        ArduPilot: NAV_TAKEOFF (the vehicle must already be GUIDED and armed); returns its
        request id. PX4: a position target above the current position (needs telemetry), then
        OFFBOARD and arm, both held until the setpoints have pre-streamed; returns the arm
        request id.
        """
        v = self._get(sysid)
        if not alt_above_home_m > 0:
            raise ValueError(f"takeoff altitude must be > 0 m, got {alt_above_home_m}")
        if v.adapter.takeoff_by_offboard_climb:
            if v.position is None:
                raise LinkUsageError(f"sysid {sysid}: no position yet, cannot climb in offboard")
            self.set_position_target(sysid, v.position.lat_deg, v.position.lon_deg,
                                     alt_above_home_m, now_s)
            self.engage_guided(sysid, now_s)
            return self.arm(sysid, now_s)
        spec = v.adapter.takeoff(alt_above_home_m)
        assert spec is not None
        return self._send_spec(sysid, spec, now_s)

    def set_position_target(self, sysid: int, lat_deg: float, lon_deg: float, alt_m: float,
                            now_s: float, *, frame: int | None = None) -> None:
        """Set (and keep re-sending) a SET_POSITION_TARGET_GLOBAL_INT position target.

        ``alt_m`` is above the vehicle's home unless ``frame`` is given (then it is in that
        frame). On the wire it goes in the adapter's frame: ArduPilot GLOBAL_RELATIVE_ALT_INT (6,
        a Location ABOVE_HOME, ArduCopter GCS_Mavlink.cpp); PX4 GLOBAL_INT (5) with the AMSL
        altitude home + ``alt_m``, home AMSL being HOME_POSITION's altitude (GLOBAL_POSITION_INT
        ``alt - relative_alt`` until one arrives; PX4's frame-6 conversion in
        mavlink_receiver.cpp computes ``home.alt - alt - ref_alt``, right only when home is at
        the EKF origin's altitude). Sent at once, then re-sent every
        ``adapter.setpoint_period_s`` (1 s ArduPilot, 0.1 s PX4) until
        :meth:`clear_position_target`, so a lost datagram or a GUID_TIMEOUT never leaves the
        vehicle without a target and PX4 keeps its OFFBOARD stream.

        Raises LinkUsageError if the frame needs the home altitude and neither HOME_POSITION nor
        a position came yet.
        """
        v = self._get(sysid)
        fr = v.adapter.setpoint_frame if frame is None else frame
        if frame is None and fr == mavlink.MAV_FRAME_GLOBAL_INT:
            alt_m = float(alt_m) + self._home_alt_amsl_m(v)
        # Validate now (a local error) rather than at the next resend.
        wire.position_target_global_int(target_system=sysid, lat_deg=lat_deg, lon_deg=lon_deg,
                                        alt_m=alt_m, frame=fr)
        if v.setpoint is None:
            v.setpoint_since_s = now_s
        v.setpoint = (float(lat_deg), float(lon_deg), float(alt_m), fr)
        self._send_setpoint(v, now_s)

    def _home_alt_amsl_m(self, v: _Vehicle) -> float:
        """HOME_POSITION's altitude; until it arrives, GLOBAL_POSITION_INT ``alt -
        relative_alt`` (on PX4 the two come from different estimates and their difference moves
        by metres in flight, so it is only a stand-in)."""
        if v.home is not None:
            return v.home.alt_amsl_m
        if v.position is None:
            raise LinkUsageError(f"sysid {v.sysid}: no position yet, home altitude unknown")
        return v.position.alt_amsl_m - v.position.rel_alt_m

    def clear_position_target(self, sysid: int, now_s: float) -> None:
        """Stop re-sending the position target (commands waiting for the pre-stream fail)."""
        v = self._get(sysid)
        v.setpoint, v.setpoint_next_s, v.setpoint_since_s = None, math.inf, math.nan
        for cmd in v.deferred:
            self._emit(CommandFailed(self.link_id, sysid, now_s, cmd.command, cmd.request_id,
                                     None, "setpoint stream stopped before it was long enough"))
        v.deferred = []

    def _send_setpoint(self, v: _Vehicle, now_s: float) -> None:
        assert v.setpoint is not None
        lat, lon, alt, frame = v.setpoint
        msg = wire.position_target_global_int(
            target_system=v.sysid, lat_deg=lat, lon_deg=lon, alt_m=alt, frame=frame,
            time_boot_s=now_s - self._t0_s)
        self._send(msg, v.addr, now_s)
        v.setpoint_next_s = now_s + v.adapter.setpoint_period_s
        self._wake(v.setpoint_next_s)

    # ------------------------------------------------------------------ parameters

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

    def set_param(self, sysid: int, name: str, value: float, param_type: int, now_s: float,
                  *, previous: float | None = None) -> None:
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
        wire_value = wire.encode_param_value(ps.value, ps.param_type,
                                             bytewise=v.adapter.param_bytewise)
        msg = mavlink.MAVLink_param_set_message(ps.sysid, _AUTOPILOT_COMPID,
                                                ps.name.encode("ascii"), wire_value,
                                                ps.param_type)
        ps.attempts += 1
        ps.deadline_s = now_s + self.config.param_timeout_s
        self._wake(ps.deadline_s)
        self._send(msg, v.addr, now_s)

    def _transmit_param_request(self, req: _ParamRequest, now_s: float) -> None:
        v = self._vehicles[req.sysid]
        msg = mavlink.MAVLink_param_request_read_message(
            req.sysid, _AUTOPILOT_COMPID, req.name.encode("ascii"), -1)
        req.attempts += 1
        req.deadline_s = now_s + self.config.param_timeout_s
        self._wake(req.deadline_s)
        self._send(msg, v.addr, now_s)


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


_HANDLERS: dict[str, Callable[[StationLink, _Vehicle, Any, float], None]] = {
    "GLOBAL_POSITION_INT": StationLink._on_global_position,
    "COMMAND_ACK": StationLink._on_command_ack,
    "PARAM_VALUE": StationLink._on_param_value,
    "PARAM_ERROR": StationLink._on_param_error,
    "STATUSTEXT": StationLink._on_statustext,
    "HOME_POSITION": StationLink._on_home_position,
    "MISSION_REQUEST": StationLink._on_mission_protocol,       # gcs/rally.py
    "MISSION_REQUEST_INT": StationLink._on_mission_protocol,
    "MISSION_ACK": StationLink._on_mission_protocol,
}

#: Fully decoded; every other known message stays a checked :class:`~gcs.wire.RawFrame`.
_DECODED_MSGIDS = frozenset(
    getattr(mavlink, f"MAVLINK_MSG_ID_{name}") for name in ("HEARTBEAT", *_HANDLERS))

#: Never asked to stop, used or not: replies to requests (ours or another GCS's), protocol
#: traffic, one-off notices; stopping them is refused at best and breaks a protocol at worst.
_NEVER_DISABLE = _DECODED_MSGIDS | frozenset(
    getattr(mavlink, f"MAVLINK_MSG_ID_{name}") for name in (
        "AUTOPILOT_VERSION", "TIMESYNC", "PING", "SYSTEM_TIME", "MESSAGE_INTERVAL",
        "COMMAND_LONG", "COMMAND_INT", "PARAM_REQUEST_READ", "PARAM_SET", "PARAM_EXT_VALUE",
        "PARAM_EXT_ACK", "MISSION_COUNT", "MISSION_ITEM", "MISSION_ITEM_INT", "MISSION_REQUEST",
        "MISSION_REQUEST_INT", "MISSION_ACK", "MISSION_ITEM_REACHED", "MISSION_REQUEST_LIST",
        "FILE_TRANSFER_PROTOCOL", "LOG_ENTRY", "LOG_DATA", "FENCE_POINT", "RALLY_POINT",
        "MAG_CAL_PROGRESS", "MAG_CAL_REPORT", "SETUP_SIGNING", "RADIO_STATUS",
        "SET_POSITION_TARGET_GLOBAL_INT", "SET_POSITION_TARGET_LOCAL_NED", "SET_MODE",
        "REQUEST_DATA_STREAM"))

#: Known and deliberately ignored here (requested for display or future use; counted only).
_IGNORED = frozenset({
    "SYS_STATUS", "GPS_RAW_INT", "EXTENDED_SYS_STATE", "LOCAL_POSITION_NED", "ATTITUDE",
    "VFR_HUD", "GPS_GLOBAL_ORIGIN", "POSITION_TARGET_GLOBAL_INT",
    "POSITION_TARGET_LOCAL_NED", "RADIO_STATUS", "TIMESYNC", "SYSTEM_TIME", "BATTERY_STATUS",
    "PARAM_REQUEST_READ", "MISSION_CURRENT", "NAV_CONTROLLER_OUTPUT", "AUTOPILOT_VERSION",
    "PING", "ALTITUDE", "ESTIMATOR_STATUS", "VIBRATION", "HIGHRES_IMU", "SCALED_IMU",
    "RAW_IMU", "SCALED_PRESSURE", "SERVO_OUTPUT_RAW", "RC_CHANNELS", "AHRS", "AHRS2",
    "EKF_STATUS_REPORT", "POWER_STATUS", "MEMINFO", "TERRAIN_REPORT", "SIMSTATE",
})

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

This module keeps the link's surface (outputs, queries, receive and dispatch, timers) and the
dispatch tables. Its configuration and counters (:class:`StationConfig`, :class:`LinkStats`,
re-exported here) live in :mod:`gcs.link_config`, below the state and the mixins, so that nothing
imports this module back. The protocol's parts are mixins of :class:`StationLink`, all on one
state declared once (:class:`gcs.link_state.LinkState`):

* :mod:`gcs.link_commands` - commands with ACK matching, retries and queueing;
* :mod:`gcs.link_streams` - telemetry stream requests and stops of unused messages;
* :mod:`gcs.link_discovery` - who is a vehicle, task systems, what a vehicle reports;
* :mod:`gcs.link_health` - what a pilot watches (GPS, sensors, estimator, radio, packet loss);
* :mod:`gcs.link_actions` - modes, arming, takeoff, the re-sent position target;
* :mod:`gcs.link_params` - parameter reads and writes.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from gcs import wire
from gcs.events import Event, ParamSetFailed, ParamTimedOut, VehicleLost
from gcs.link_actions import VehicleActions
from gcs.link_config import DEFAULT_STREAM_RATES_HZ, LinkStats, StationConfig
from gcs.link_discovery import NON_VEHICLE_TYPES, VehicleDiscovery
from gcs.link_params import ParamProtocol
from gcs.link_state import (
    _AUTOPILOT_COMPID,
    Addr,
    LinkUsageError,
    UnknownVehicle,
    _Command,
    _ParamRequest,
    _ParamSet,
    _RateLimitedLog,
    _Vehicle,
)
from gcs.rally import mission_event
from gcs.wire import mavlink

__all__ = [
    "StationConfig",
    "StationLink",
    "VehicleInfo",
    "LinkStats",
    "UnknownVehicle",
    "LinkUsageError",
    "NON_VEHICLE_TYPES",
    "DEFAULT_STREAM_RATES_HZ",
]

log = logging.getLogger(__name__)


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


class StationLink(VehicleDiscovery, VehicleActions, ParamProtocol):
    """One link's station core (see the module docstring)."""

    def __init__(
        self, config: StationConfig | None = None, *, link_id: int = 0, now_s: float = 0.0
    ) -> None:
        self.config = config or StationConfig()
        self.link_id = link_id
        self._codec = wire.Codec(
            self.config.sysid,
            self.config.compid,
            signing_key=self.config.signing_key,
            signing_link_id=link_id & 0xFF,
            accept_unsigned=self.config.accept_unsigned,
            full_msgids=_DECODED_MSGIDS,
        )
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
        self._used_msgids = (
            _NEVER_DISABLE
            | {m for m, _ in self.config.stream_rates_hz}
            | set(self.config.stale_msgids)
            | (_BATTERY_MSGIDS if self.config.battery_telemetry else frozenset())
            | (_HEALTH_MSGIDS if self.config.health_telemetry else frozenset())
        )

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

    def _compute_next_timer_s(self) -> float:
        cfg = self.config
        t = self._next_heartbeat_s
        for cmd in self._commands.values():
            t = min(t, cmd.deadline_s)
        for req in self._params.values():
            t = min(t, req.deadline_s)
        for ps in self._param_sets.values():
            t = min(t, ps.deadline_s)
        timeout_s = cfg.vehicle_timeout_s
        stale_due_s = self._stale_due_s
        for v in self._vehicles.values():  # the same minimum, fewer calls (runs per wake-up)
            if not v.lost:
                u = v.last_heartbeat_s + timeout_s
                if u < t:
                    t = u
                u = stale_due_s(v)
                if u < t:
                    t = u
                if v.setpoint_next_s < t:
                    t = v.setpoint_next_s
                if v.home_request_s < t:
                    t = v.home_request_s
            if v.deferred:
                t = min(t, v.setpoint_since_s + v.adapter.prestream_s)
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

    # Rally points (gcs/rally.py): the vehicle's replies to an upload go to its keeper as events.
    def _on_mission_protocol(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        self._emit(mission_event(self.link_id, v.sysid, msg, now_s))

    def send_message(self, sysid: int, msg: Any, now_s: float) -> None:
        """Queue one ready-made message to a vehicle (its last address): gcs/rally.py's uploads."""
        self._send(msg, self._get(sysid).addr, now_s)

    def _info(self, v: _Vehicle) -> VehicleInfo:
        return VehicleInfo(
            self.link_id,
            v.sysid,
            v.autopilot,
            v.vehicle_type,
            v.adapter.name,
            v.custom_mode,
            v.adapter.mode_name(v.custom_mode),
            v.armed,
            v.lost,
            v.last_heartbeat_s,
            v.setpoint is not None,
            v.home.alt_amsl_m if v.home is not None else math.nan,
        )

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
                self._frames.append(
                    (now_s + self.config.unix_time_at_zero_s, False, bytes(msg.get_msgbuf()))
                )
            try:
                self._dispatch(msg, addr, now_s)
            except Exception:  # a handler bug must not take the link down
                self.stats.handler_errors += 1
                log.exception(
                    "link %d: handler error on %s from sysid %d",
                    self.link_id,
                    msg.get_type(),
                    msg.get_srcSystem(),
                )

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
                log.warning(
                    "link %d: another system sends heartbeats with our sysid %d "
                    "(compid %d, MAVProxy?): its heartbeats also feed the vehicles' GCS "
                    "failsafe; run SITL with --no-mavproxy or give one of us another "
                    "sysid",
                    self.link_id,
                    sysid,
                    msg.get_srcComponent(),
                )
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
        if msg.get_srcComponent() == _AUTOPILOT_COMPID:
            v.seq.update(msg.get_seq())  # packet loss (gcs.link_quality)
        elif kind == "RADIO_STATUS":  # a radio stamping its vehicle's sysid (gcs.link_health)
            self._on_radio_status(v, msg, now_s)
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
                log.info(
                    "link %d: ignoring %s (first seen from sysid %d)", self.link_id, kind, sysid
                )

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
                self._emit(
                    ParamSetFailed(
                        self.link_id,
                        ps.sysid,
                        now_s,
                        ps.name,
                        ps.value,
                        None,
                        "no PARAM_VALUE echo",
                        ps.attempts,
                    )
                )
        for v in self._vehicles.values():
            if not v.lost and now_s >= v.last_heartbeat_s + cfg.vehicle_timeout_s:
                v.lost = True
                self._emit(VehicleLost(self.link_id, v.sysid, now_s, v.last_heartbeat_s))
            if not v.lost and now_s >= self._stale_due_s(v):
                self.stats.stream_rerequests += 1
                log.info(
                    "link %d sysid %d: telemetry stale, re-requesting streams",
                    self.link_id,
                    v.sysid,
                )
                self._request_streams(v, now_s)
            # Batch resends: whatever is due within half a period goes now, so a fleet's
            # staggered streams coalesce into few wake-ups (each wake-up scans every vehicle).
            if (
                v.setpoint is not None
                and not v.lost
                and now_s >= v.setpoint_next_s - 0.5 * v.adapter.setpoint_period_s
            ):
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


_HANDLERS: dict[str, Callable[[StationLink, _Vehicle, Any, float], None]] = {
    "GLOBAL_POSITION_INT": StationLink._on_global_position,
    "COMMAND_ACK": StationLink._on_command_ack,
    "PARAM_VALUE": StationLink._on_param_value,
    "PARAM_ERROR": StationLink._on_param_error,
    "STATUSTEXT": StationLink._on_statustext,
    "HOME_POSITION": StationLink._on_home_position,
    "SYS_STATUS": StationLink._on_sys_status,
    "BATTERY_STATUS": StationLink._on_battery_status,
    "MISSION_REQUEST": StationLink._on_mission_protocol,  # gcs/rally.py
    "MISSION_REQUEST_INT": StationLink._on_mission_protocol,
    "MISSION_ACK": StationLink._on_mission_protocol,
    "GPS_RAW_INT": StationLink._on_health,  # gcs/link_health.py
    "EKF_STATUS_REPORT": StationLink._on_health,
    "ESTIMATOR_STATUS": StationLink._on_health,
    "RADIO_STATUS": StationLink._on_radio_status,
}

#: Battery reports: handled only with ``StationConfig.battery_telemetry``; without it they are
#: ignored (and stopped when unused) exactly as before it existed.
_BATTERY_MSGIDS = frozenset(
    (mavlink.MAVLINK_MSG_ID_SYS_STATUS, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS)
)

#: What a pilot watches (gcs/link_health.py): handled only with
#: ``StationConfig.health_telemetry``; without it ignored (and stopped when unused) as before.
#: RADIO_STATUS is never stopped (a radio's message, not a stream of the autopilot).
_HEALTH_MSGIDS = frozenset(
    getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
    for name in ("GPS_RAW_INT", "EKF_STATUS_REPORT", "ESTIMATOR_STATUS", "SYS_STATUS")
)

#: Fully decoded; every other known message stays a checked :class:`~gcs.wire.RawFrame`.
_DECODED_MSGIDS = frozenset(
    getattr(mavlink, f"MAVLINK_MSG_ID_{name}") for name in ("HEARTBEAT", *_HANDLERS)
)

#: Never asked to stop, used or not: replies to requests (ours or another GCS's), protocol
#: traffic, one-off notices; stopping them is refused at best and breaks a protocol at worst.
_NEVER_DISABLE = _DECODED_MSGIDS - _BATTERY_MSGIDS - _HEALTH_MSGIDS | frozenset(
    getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
    for name in (
        "AUTOPILOT_VERSION",
        "TIMESYNC",
        "PING",
        "SYSTEM_TIME",
        "MESSAGE_INTERVAL",
        "COMMAND_LONG",
        "COMMAND_INT",
        "PARAM_REQUEST_READ",
        "PARAM_SET",
        "PARAM_EXT_VALUE",
        "PARAM_EXT_ACK",
        "MISSION_COUNT",
        "MISSION_ITEM",
        "MISSION_ITEM_INT",
        "MISSION_REQUEST",
        "MISSION_REQUEST_INT",
        "MISSION_ACK",
        "MISSION_ITEM_REACHED",
        "MISSION_REQUEST_LIST",
        "FILE_TRANSFER_PROTOCOL",
        "LOG_ENTRY",
        "LOG_DATA",
        "FENCE_POINT",
        "RALLY_POINT",
        "MAG_CAL_PROGRESS",
        "MAG_CAL_REPORT",
        "SETUP_SIGNING",
        "RADIO_STATUS",
        "SET_POSITION_TARGET_GLOBAL_INT",
        "SET_POSITION_TARGET_LOCAL_NED",
        "SET_MODE",
        "REQUEST_DATA_STREAM",
    )
)

#: Known and deliberately ignored here (requested for display or future use; counted only).
_IGNORED = frozenset(
    {
        "EXTENDED_SYS_STATE",
        "LOCAL_POSITION_NED",
        "ATTITUDE",
        "VFR_HUD",
        "GPS_GLOBAL_ORIGIN",
        "POSITION_TARGET_GLOBAL_INT",
        "POSITION_TARGET_LOCAL_NED",
        "RADIO_STATUS",
        "TIMESYNC",
        "SYSTEM_TIME",
        "PARAM_REQUEST_READ",
        "MISSION_CURRENT",
        "NAV_CONTROLLER_OUTPUT",
        "AUTOPILOT_VERSION",
        "PING",
        "ALTITUDE",
        "VIBRATION",
        "HIGHRES_IMU",
        "SCALED_IMU",
        "RAW_IMU",
        "SCALED_PRESSURE",
        "SERVO_OUTPUT_RAW",
        "RC_CHANNELS",
        "AHRS",
        "AHRS2",
        "POWER_STATUS",
        "MEMINFO",
        "TERRAIN_REPORT",
        "SIMSTATE",
    }
)

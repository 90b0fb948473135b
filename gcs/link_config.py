"""The station link's configuration (:class:`StationConfig`) and counters (:class:`LinkStats`).

They sit below :mod:`gcs.link` and :mod:`gcs.link_state` so that both import them and neither
imports the other back: the link's state declares its ``config`` and ``stats`` attributes with
these types, and the link builds them (no circle of modules, ``tests/test_layering.py``).
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass, field

from gcs import wire
from gcs.wire import mavlink

__all__ = ["Addr", "DEFAULT_STREAM_RATES_HZ", "LinkStats", "StationConfig"]

#: A peer's address as the core sees it: opaque (a UDP ``(host, port)``, a TCP peer, a serial port,
#: a key of the in-memory ether).
Addr = Hashable

_MSG = mavlink  # message-id constants live on the dialect module
#: Telemetry we ask for (Skybrush's fleet-scale rates, docs/design/mavlink.md §2): message id -> Hz.
DEFAULT_STREAM_RATES_HZ: tuple[tuple[int, float], ...] = (
    (_MSG.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 4.0),
    (_MSG.MAVLINK_MSG_ID_SYS_STATUS, 1.0),
    (_MSG.MAVLINK_MSG_ID_GPS_RAW_INT, 1.0),
    (_MSG.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 1.0),
)


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
    unix_time_at_zero_s: float = 0.0
    """The Unix time that ``now_s == 0`` stands for (:attr:`mavedge.clock.Clock.unix_time_at_zero_s`):
    ``unix time = unix_time_at_zero_s + now_s``; only for signing timestamps and frame records."""
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
    battery_telemetry: bool = False
    """Fold SYS_STATUS / BATTERY_STATUS into :class:`gcs.events.BatteryReceived` events (the
    rotation through the base, docs/design/endurance.md §3). Off, both stay ignored exactly as
    before (counted, and BATTERY_STATUS stopped like any unused message): a mission without
    batteries keeps its event stream bit for bit."""

    health_telemetry: bool = False
    """Fold what a pilot watches into events (:mod:`gcs.link_health`): GPS_RAW_INT, SYS_STATUS's
    sensor masks and its battery (as ``battery_telemetry`` does for SYS_STATUS),
    EKF_STATUS_REPORT / ESTIMATOR_STATUS and RADIO_STATUS (the live page asks for it). Off, they
    stay ignored exactly as before."""

    def __post_init__(self) -> None:
        if not 1 <= self.sysid <= 255:
            raise ValueError(f"sysid must be in 1..255, got {self.sysid}")
        if not 1 <= self.compid <= 255:
            raise ValueError(f"compid must be in 1..255 (0 is broadcast), got {self.compid}")
        if self.sysid in self.task_sysids:
            raise ValueError(f"task_sysids must not contain our own sysid {self.sysid}")
        if any(not 1 <= t <= 255 for t in self.task_sysids):
            raise ValueError(f"task_sysids must be in 1..255, got {self.task_sysids}")
        for name in (
            "heartbeat_period_s",
            "vehicle_timeout_s",
            "command_timeout_s",
            "param_timeout_s",
            "telemetry_stale_s",
            "command_in_progress_timeout_s",
            "task_position_rate_hz",
            "home_request_period_s",
            "disable_retry_s",
        ):
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

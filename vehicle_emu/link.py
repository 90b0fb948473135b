"""Sans-I/O vehicle-side MAVLink core: one emulated autopilot (ArduPilot Copter or PX4).

Surface (aioquic style, docs/design/architecture.md §2.1)::

    core.receive_datagram(data, addr, now_s)    # bytes in
    core.handle_timer(now_s)                    # timers: failsafes, timeouts, telemetry
    core.datagrams_to_send(now_s) -> [(bytes, addr)]
    core.next_timer_s() -> float | None
    core.next_event() -> EmulatorEvent | None

The core never reads a clock, opens a socket or sleeps: every time is the ``now_s`` argument
(vehicle clock, seconds). ``addr`` is opaque; the core returns ``None`` as destination, meaning
"every peer of the link this vehicle is on" (the router / adapter owns addressing, as a serial
or UDP port in ArduPilot does: ``GCS_MAVLINK`` sends on its channel, not to a peer).

Physics is shared: a core owns a row ``index`` of a :class:`vehicle_emu.physics.Physics` (its
targets, its position). In a :class:`vehicle_emu.swarm.Swarm` the physics of all vehicles is
stepped once per tick (vectorised) and the swarm calls :meth:`VehicleCore.update_autopilot` and
:meth:`VehicleCore.emit_telemetry` around that step. A core created without a physics object
owns a one-row physics and steps it in :meth:`handle_timer` (handy for unit tests).

The core keeps the link (codec, queues, events) and the dispatch of every inbound message. Its
handlers are mixins cut along the protocol's seams, all working on one state declared once
(:class:`vehicle_emu.core_state.CoreState`):

* :mod:`vehicle_emu.core_autopilot` - timers (auto-disarm, takeoff, RTL, GCS failsafe) and
  transitions (arm, disarm, set mode) both firmwares share;
* :mod:`vehicle_emu.core_setpoints` - SET_POSITION_TARGET_*;
* :mod:`vehicle_emu.core_commands` - COMMAND_LONG / COMMAND_INT, SET_MODE;
* :mod:`vehicle_emu.core_protocols` - missions, REQUEST_DATA_STREAM, parameters, TIMESYNC, PING,
  SETUP_SIGNING.

What differs between firmwares is the personality (``core.pers``,
:mod:`vehicle_emu.personality`); the telemetry builders and the stream scheduler are in
:mod:`vehicle_emu.telemetry`.
"""

from __future__ import annotations

import logging
from collections import deque

import numpy as np

from mavedge.codec import MAX_DATAGRAM_BYTES
from mavedge.modes import px4_custom_mode

from . import telemetry as tm
from . import wire
from .core_commands import CommandHandlers
from .core_protocols import ProtocolHandlers
from .core_terrain import TerrainProtocol
from .battery import BatteryConfig
from .battery_monitor import monitor_for
from .core_state import CoreStats, RateLimitedLog
from .missions import MissionServer
from .params import ParamTable, defaults_for
from .personality import (
    ARDUPILOT_MODES,
    PERSONALITIES,
    PX4_MODES,
    ap_check_latlng_e7,
    personality_for,
    px4_map_project,
)
from .physics import Physics
from .wire import dialect as mavlink

__all__ = [
    "VehicleCore",
    "CoreStats",
    "RateLimitedLog",
    "ARDUPILOT_MODES",
    "PX4_MODES",
    "px4_custom_mode",
    "PERSONALITIES",
    "ap_check_latlng_e7",
    "px4_map_project",
]

log = logging.getLogger(__name__)

_GCS_HEARTBEAT_TYPE = mavlink.MAV_TYPE_GCS
TICK_S = 0.05


class VehicleCore(CommandHandlers, ProtocolHandlers, TerrainProtocol):
    """One emulated autopilot.

    Parameters
    ----------
    sysid : int
        MAVLink system id (1..254; 255 is the GCS by convention).
    personality : {'ardupilot', 'px4'}
    now_s : float
        Vehicle clock at boot (``time_boot_ms`` counts from here).
    physics : Physics, optional
        Shared physics; the core uses row ``index``. Without it the core owns a one-row
        physics placed at ``origin_lla`` and steps it in :meth:`handle_timer`.
    index : int
        Row in ``physics``.
    origin_lla : (lat_deg, lon_deg, alt_amsl_m)
        World origin when the core owns its physics.
    params : mapping, optional
        Parameter overrides (native units, see :mod:`vehicle_emu.params`).
    signing_key : bytes, optional
        32-byte MAVLink 2 signing key.
    trusted_addrs : collection, optional
        Source addresses from which SETUP_SIGNING is honoured ("trusted link": the analogue of
        a USB cable; ArduPilot and PX4 refuse key changes over an arbitrary radio link).
        SETUP_SIGNING is also refused while armed (PX4 behaviour, docs/design/mavlink.md §3).
    ekf_ready_after_s : float
        Arming is refused until this long after boot (SITL needs ~40 s; default 0).
    unix_time_at_zero_s : float
        Wall-clock Unix time corresponding to ``now_s == 0``; used only for MAVLink signing
        timestamps (the firmware uses GPS time there).
    log_limiter : RateLimitedLog, optional
        Rate limit for warnings caused by remote input (a Swarm shares one among its cores).
    battery : BatteryConfig, optional
        Drain a battery (docs/design/endurance.md §6) when the core owns its physics; with a
        shared physics the batteries are on when ``physics.battery`` is set. Off: endless.

    Notes
    -----
    Home and the EKF origin are the vehicle's spawn position (as SITL with per-instance
    offsets); LOCAL_NED on the wire is relative to it. Local NED is modelled as the world NED
    shifted by the origin (flat earth over the swarm area, error < 0.1 m per km).
    Yaw follows the velocity direction; yaw / yaw-rate / acceleration setpoints are parsed but
    not flown (acceleration-only targets make ArduPilot hold, like its "invalid input" path).
    """

    def __init__(
        self,
        sysid: int,
        personality: str = "ardupilot",
        *,
        now_s: float = 0.0,
        physics: Physics | None = None,
        index: int = 0,
        origin_lla: tuple[float, float, float] = (0.0, 0.0, 0.0),
        params=None,
        signing_key: bytes | None = None,
        trusted_addrs=(),
        ekf_ready_after_s: float = 0.0,
        unix_time_at_zero_s: float = 1.7e9,
        network: int = 0,
        log_limiter: RateLimitedLog | None = None,
        battery: BatteryConfig | None = None,
    ) -> None:
        if not 1 <= int(sysid) <= 254:
            raise ValueError(f"vehicle sysid must be 1..254, got {sysid}")
        self.sysid = int(sysid)
        self.network = int(network)
        self.personality = personality
        #: The firmware rules (vehicle_emu.personality); raises ValueError for unknown names.
        self.pers = personality_for(personality, self)
        self.compid = mavlink.MAV_COMP_ID_AUTOPILOT1
        self._owns_physics = physics is None
        if physics is None:
            physics = Physics(np.zeros((1, 3)), origin_lla=origin_lla)
            index = 0
            if battery is not None:
                physics.enable_battery(battery)
        self.physics = physics
        self.index = int(index)
        self.alive = True
        self._boot_s = float(now_s)
        self._physics_t_s = float(now_s)
        self._last_timer_s = float(now_s)
        self._unix_time_at_zero_s = float(unix_time_at_zero_s)
        self._ekf_ready_s = float(now_s) + float(ekf_ready_after_s)
        self.trusted_addrs = frozenset(trusted_addrs)

        pack = physics.battery
        spec = defaults_for(personality, battery=pack is not None)
        overrides = dict(params or {})
        overrides.setdefault(self.pers.sysid_param, self.sysid)
        if pack is not None:
            # The monitor configured for the pack it carries (vehicle_emu.params).
            cfg = pack.config
            if personality == "ardupilot":
                overrides.setdefault("BATT_CAPACITY", cfg.capacity_mah)
            else:
                overrides.setdefault("BAT1_CAPACITY", cfg.capacity_mah)
                overrides.setdefault("BAT1_N_CELLS", cfg.cells)
        self.params = ParamTable(spec, overrides)
        #: The firmware's battery monitor (vehicle_emu.battery_monitor); None: endless battery.
        self.batt = monitor_for(personality, self) if pack is not None else None

        allow_unsigned = frozenset(
            {mavlink.MAVLINK_MSG_ID_RADIO_STATUS, mavlink.MAVLINK_MSG_ID_SETUP_SIGNING}
        )
        self._codec = wire.Codec(
            self.sysid, self.compid, signing_key=signing_key, allow_unsigned_ids=allow_unsigned
        )
        self.stats = CoreStats()
        self._out: list[bytes] = []
        #: A swarm's set of the ``index`` of cores whose ``_out`` got frames (None: standalone).
        self._out_dirty: set[int] | None = None
        self._events: deque = deque()
        self._logged_types: set[str] = set()
        #: Warnings caused by remote input go through this (shared by a Swarm's cores).
        self.log_limiter = log_limiter if log_limiter is not None else RateLimitedLog(log)

        # Home / EKF origin = spawn point (world NED and geodetic).
        i = self.index
        self.home_ned_m = physics.pos_ned_m[i].copy()
        if self._owns_physics:
            physics.update_geodetic()
        self.home_lla = (
            float(physics.lat_deg[i]),
            float(physics.lon_deg[i]),
            float(physics.alt_amsl_m[i]),
        )

        # Autopilot state.
        self.armed = False
        self._armed_since_s: float | None = None
        self._landed_armed_since_s: float | None = None
        self._has_taken_off = False
        self._mode_key = self.pers.boot_mode
        mode_info = self.pers.mode_info(self._mode_key)
        assert mode_info is not None  # the boot mode is one of the firmware's
        self.mode_name, self._behaviour = mode_info
        self._rtl_phase = ""
        self._rtl_cruise_down_m: float | None = None
        self._rtl_dest_ned_m = self.home_ned_m.copy()  # home, or a rally point (personality)
        self._takeoff_target_down_m: float | None = None
        self._vel_target_s: float | None = None
        self._target_mask = 0b110111111000  # what POSITION_TARGET_* reports
        self._last_gcs_hb_s: float | None = None
        self._gcs_fs_config = (False, 0.0)
        self._gcs_fs_stamp = 0  # no table has stamp 0: read at the first check
        self.gcs_failsafe = False
        self.offboard_failsafe = False

        #: Streams: interval and next due time per message id (vehicle_emu.telemetry).
        rates = dict(self.pers.default_rates_hz)
        if self.batt is not None:
            rates.update(self.batt.default_rates_hz)
        self.streams = tm.StreamScheduler(rates, now_s)
        self._missions = MissionServer(
            self._send, self.pers.mission_home_items == 0, lambda: self.home_lla
        )
        nop = self._nop
        self._handlers = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_LONG": self._on_command_long,
            "COMMAND_INT": self._on_command_int,
            "SET_MODE": self._on_set_mode,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_set_position_target_local,
            "SET_POSITION_TARGET_GLOBAL_INT": self._on_set_position_target_global,
            "REQUEST_DATA_STREAM": self._on_request_data_stream,
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_SET": self._on_param_set,
            "TIMESYNC": self._on_timesync,
            "PING": self._on_ping,
            "SETUP_SIGNING": self._on_setup_signing,
            "MISSION_REQUEST_LIST": self._on_mission_request_list,
            "MISSION_REQUEST_INT": self._on_mission_request_int,
            "MISSION_REQUEST": self._on_mission_request,
            "MISSION_COUNT": self._on_mission_count,
            "MISSION_ITEM_INT": self._on_mission_item,
            "MISSION_ITEM": self._on_mission_item,
            "MISSION_CLEAR_ALL": self._on_mission_clear_all,
            "MISSION_ACK": nop,  # end of a download: nothing to do (no state kept)
            "TERRAIN_DATA": self._on_terrain_data,  # vehicle_emu.core_terrain
            "TERRAIN_CHECK": self._on_terrain_check,
            # Explicit ignores (skybrush-style nop handlers): traffic a GCS legitimately sends
            # that this emulator has no use for.
            "RADIO_STATUS": nop,
            "COMMAND_ACK": nop,
            "SYSTEM_TIME": nop,
            "PARAM_VALUE": nop,
            "MANUAL_CONTROL": nop,
            "RC_CHANNELS_OVERRIDE": nop,
            "GPS_GLOBAL_ORIGIN": nop,
            "STATUSTEXT": nop,
            "ATTITUDE": nop,
            "GLOBAL_POSITION_INT": nop,
            "LOCAL_POSITION_NED": nop,
            "SYS_STATUS": nop,
        }
        #: ArduPilot's terrain database (vehicle_emu.core_terrain), started by enable_terrain.
        self.terrain_db = None
        self._terrain_next_s = float("inf")
        self._apply_params()

    # =========================================================================================
    # Public sans-I/O surface
    # =========================================================================================

    def receive_datagram(self, data: bytes, addr, now_s: float) -> None:
        """Feed one datagram (any number of frames, possibly garbage or truncated)."""
        if not self.alive:
            self.stats.datagrams_in += 1
            self.stats.dropped_dead += 1
            return
        self.receive_decoded(self._codec.decode_datagram(data), addr, now_s)

    def receive_decoded(self, res: wire.DecodeResult, addr, now_s: float) -> None:
        """Handle one datagram already decoded (:meth:`receive_datagram`; the swarm decodes a
        broadcast frame once for every core without a signing key, whose decode depends on the
        bytes alone). ``res`` and its messages may be shared between cores: read only."""
        st = self.stats
        st.datagrams_in += 1
        if not self.alive:
            st.dropped_dead += 1
            return
        if res.n_bad or res.n_unknown or res.n_truncated_bytes or res.n_signature_rejected:
            self._count_decode_faults(res, addr, now_s)
        for msg in res.messages:
            self.receive_message(msg, addr, now_s)

    def _count_decode_faults(self, res: wire.DecodeResult, addr, now_s: float) -> None:
        """The stats and rate-limited warnings of a datagram with bad, unknown, truncated or
        unsigned frames (:meth:`receive_decoded`)."""
        st = self.stats
        st.bad_data += res.n_bad
        st.unknown_msg_ids += res.n_unknown
        st.truncated_bytes += res.n_truncated_bytes
        if res.n_signature_rejected:
            st.signing_rejected += res.n_signature_rejected
            self._warn_limited(
                now_s,
                "signing",
                "sysid %d: rejected %d frame(s) failing MAVLink signing from %s",
                self.sysid,
                res.n_signature_rejected,
                addr,
                level=logging.INFO,
            )
        if res.n_bad or res.n_unknown:
            self._warn_limited(
                now_s,
                "bad_data",
                "sysid %d: %d bad frame(s), %d unknown "
                "message id(s) from %s (totals: %d bad, %d unknown)",
                self.sysid,
                res.n_bad,
                res.n_unknown,
                addr,
                st.bad_data,
                st.unknown_msg_ids,
            )

    def receive_message(self, msg, addr, now_s: float) -> None:
        """Handle one decoded message (used by :meth:`receive_datagram`)."""
        st = self.stats
        st.messages_in += 1
        mtype = msg.get_type()
        handler = self._handlers.get(mtype)
        if handler is None:
            st.unhandled += 1
            if mtype not in self._logged_types:
                self._logged_types.add(mtype)
                log.info("sysid %d: ignoring message type %s (logged once)", self.sysid, mtype)
            return
        try:
            handler(msg, addr, now_s)
        except Exception:  # noqa: BLE001 - a handler bug must not kill the adapter loop
            st.handler_errors += 1
            self._warn_limited(
                now_s,
                f"handler:{mtype}",
                "sysid %d: handler for %s failed",
                self.sysid,
                mtype,
                level=logging.ERROR,
                exc_info=True,
            )

    def handle_timer(self, now_s: float) -> None:
        """Run timers: (own physics), autopilot rules, due telemetry."""
        if not self.alive:
            return
        if self._owns_physics:
            dt = now_s - self._physics_t_s
            if dt > 0:
                self.physics.step(dt)
                self.physics.update_geodetic()
                self._physics_t_s = now_s
        self.update_autopilot(now_s)
        self.emit_telemetry(now_s)
        self._last_timer_s = now_s

    def next_timer_s(self) -> float | None:
        if not self.alive:
            return None
        return self._last_timer_s + TICK_S

    def datagrams_to_send(self, now_s: float) -> list[tuple[bytes, object]]:
        """Frames queued since the last call, packed into datagrams of <= 1200 bytes.

        Destination ``None`` = every peer of this vehicle's link (see module docstring).
        """
        if not self._out:
            return []
        frames, self._out = self._out, []
        out: list[tuple[bytes, object]] = []
        cur: list[bytes] = []
        size = 0
        for f in frames:
            if size + len(f) > MAX_DATAGRAM_BYTES and cur:
                out.append((b"".join(cur), None))
                cur, size = [], 0
            cur.append(f)
            size += len(f)
        if cur:
            out.append((b"".join(cur), None))
        return out

    def next_event(self):
        return self._events.popleft() if self._events else None

    def kill(self) -> None:
        """The vehicle is lost: silent forever, queued output discarded."""
        self.alive = False
        self._out.clear()

    # -- convenience accessors (ground truth side, not wire) -----------------------------------

    @property
    def custom_mode(self) -> int:
        return self._mode_key

    @property
    def signing_enabled(self) -> bool:
        return self._codec.signing_enabled

    @property
    def landed(self) -> bool:
        return bool(self.physics.landed[self.index])

    @property
    def local_pos_ned_m(self) -> np.ndarray:
        """(3,) position relative to this vehicle's EKF origin (what LOCAL_POSITION_NED says)."""
        return self.physics.pos_ned_m[self.index] - self.home_ned_m

    def set_stream_rate(self, msg_id: int, rate_hz: float, now_s: float) -> None:
        """Local API: stream ``msg_id`` at ``rate_hz`` (0 stops it)."""
        self._set_interval(msg_id, 1.0 / rate_hz if rate_hz > 0 else -1.0, now_s)

    # =========================================================================================
    # Telemetry (the autopilot's timers and transitions: vehicle_emu.core_autopilot)
    # =========================================================================================

    def emit_telemetry(self, now_s: float) -> None:
        """Encode every stream that is due (after the physics step)."""
        if not self.alive:
            return
        if self._codec.signing_enabled:
            self._codec.advance_signing_timestamp(
                wire.signing_timestamp_from_s(self._unix_time_at_zero_s + now_s)
            )
        builders = tm.BUILDERS
        for msg_id in self.streams.due(now_s):
            try:
                self._send(builders[msg_id](self, now_s))
            except Exception:  # noqa: BLE001 - a bad value must not stop the other streams
                self.stats.telemetry_errors += 1
                self._warn_limited(
                    now_s,
                    f"telemetry:{msg_id}",
                    "sysid %d: building message %d failed",
                    self.sysid,
                    msg_id,
                    exc_info=True,
                )

    # =========================================================================================
    # Inbound handlers: the GCS heartbeat here; commands (core_commands), setpoints
    # (core_setpoints), missions, streams, parameters, time and signing (core_protocols)
    # =========================================================================================

    def _on_heartbeat(self, msg, addr, now_s: float) -> None:
        if msg.type != _GCS_HEARTBEAT_TYPE:
            return
        if not self.pers.accepts_gcs_heartbeat(msg.get_srcSystem()):
            return
        self.stats.gcs_heartbeats += 1
        self._last_gcs_hb_s = now_s
        self._check_gcs_link(now_s)

    # -- setpoints ----------------------------------------------------------------------------

    # -- mission protocol (vehicle_emu.missions) ---------------------------------------------

    # -- parameters ---------------------------------------------------------------------------

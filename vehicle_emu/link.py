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

The core keeps the link (codec, queues, events), the autopilot state both firmwares share and
the dispatch of every inbound message. What differs between firmwares is the personality
(``core.pers``, :mod:`vehicle_emu.personality`); the telemetry builders and the stream scheduler
are in :mod:`vehicle_emu.telemetry`. This module is longer than ~600 lines on purpose: it is one
state machine (arming, modes, takeoff, RTL, setpoints, commands, parameters, missions,
signing) whose handlers all mutate the same state, and splitting the handlers from that state
would spread each rule over two files.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, fields

import numpy as np

from mavedge.modes import px4_custom_mode
from mavedge.params import param_id_to_str as _pid_str
from mavedge.setpoints import POS_BITS as _POS_BITS
from mavedge.setpoints import VEL_BITS as _VEL_BITS
from planner.geometry import DOWN, EAST, NORTH

from . import events as ev
from . import telemetry as tm
from . import wire
from .missions import MissionServer
from .params import ParamTable, defaults_for
from .personality import (ARDUPILOT_MODES, PERSONALITIES, PX4_MODES, ap_check_latlng_e7,
                          personality_for, px4_map_project)
from .personality.base import LOCAL_FRAMES as _LOCAL_FRAMES
from .personality.base import TARGET_MASK_POSITION
from .physics import Physics
from .telemetry import (M_ATTITUDE, M_AUTOPILOT_VERSION, M_EXTENDED_SYS_STATE,  # noqa: F401
                        M_GLOBAL_POSITION_INT, M_GPS_GLOBAL_ORIGIN, M_GPS_RAW_INT, M_HEARTBEAT,
                        M_HOME_POSITION, M_LOCAL_POSITION_NED, M_MISSION_CURRENT,
                        M_POSITION_TARGET_GLOBAL_INT, M_POSITION_TARGET_LOCAL_NED, M_SYS_STATUS,
                        M_VFR_HUD)
from .wire import dialect as mavlink

__all__ = [
    "VehicleCore", "CoreStats", "RateLimitedLog", "ARDUPILOT_MODES", "PX4_MODES", "px4_custom_mode",
    "PERSONALITIES", "ap_check_latlng_e7", "px4_map_project",
]

log = logging.getLogger(__name__)

_GCS_HEARTBEAT_TYPE = mavlink.MAV_TYPE_GCS
_FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force (ArduPilot & PX4)
MAX_DATAGRAM_BYTES = 1200
TICK_S = 0.05


@dataclass
class CoreStats:
    """Counters of one core (remote bytes are counted, never raised)."""

    datagrams_in: int = 0
    messages_in: int = 0
    bad_data: int = 0
    unknown_msg_ids: int = 0
    truncated_bytes: int = 0
    signing_rejected: int = 0
    not_for_us: int = 0
    unhandled: int = 0
    handler_errors: int = 0
    telemetry_errors: int = 0
    commands: int = 0
    setpoints: int = 0
    setpoints_ignored: int = 0
    gcs_heartbeats: int = 0
    messages_out: int = 0
    bytes_out: int = 0
    dropped_dead: int = 0

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class RateLimitedLog:
    """Log at most one record per ``key`` per ``interval_s`` (explicit time, sans-I/O).

    Remote input can repeat a fault thousands of times a second (a garbage stream, a client
    speaking an unknown dialect); each is counted in the stats, but the log gets one line per
    key and interval, and the next line says how many were suppressed in between (the
    ``GCS_MAVLINK`` "N messages suppressed" idea; MAVProxy does likewise for repeated
    errors). Keys are categories, never peer addresses, so the table stays small; it is capped
    at ``max_keys`` anyway (oldest dropped).
    """

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0,
                 max_keys: int = 256) -> None:
        self.logger = logger
        self.interval_s = float(interval_s)
        self.max_keys = int(max_keys)
        self._state: dict = {}   # key -> [last_logged_s, n_suppressed]
        self.n_logged = 0
        self.n_suppressed = 0

    def log(self, now_s: float, key, level: int, msg: str, *args, **kwargs) -> bool:
        """Log ``msg % args`` unless ``key`` was logged less than ``interval_s`` ago."""
        st = self._state.get(key)
        if st is not None and now_s - st[0] < self.interval_s:
            st[1] += 1
            self.n_suppressed += 1
            return False
        if st is not None and st[1]:
            msg = msg + " (%d more suppressed in the last %.0f s)"
            args = args + (st[1], now_s - st[0])
        if st is None and len(self._state) >= self.max_keys:
            self._state.pop(next(iter(self._state)))
        self._state[key] = [now_s, 0]
        self.n_logged += 1
        self.logger.log(level, msg, *args, **kwargs)
        return True


class VehicleCore:
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

    Notes
    -----
    Home and the EKF origin are the vehicle's spawn position (as SITL with per-instance
    offsets); LOCAL_NED on the wire is relative to it. Local NED is modelled as the world NED
    shifted by the origin (flat earth over the swarm area, error < 0.1 m per km).
    Yaw follows the velocity direction; yaw / yaw-rate / acceleration setpoints are parsed but
    not flown (acceleration-only targets make ArduPilot hold, like its "invalid input" path).
    """

    # Set from the parameters by the personality (vehicle_emu/personality/*.py).
    _guided_speed_m_s: float
    _auto_speed_m_s: float
    _rtl_alt_m: float
    _rtl_hover_alt_m: float | None

    def __init__(self, sysid: int, personality: str = "ardupilot", *, now_s: float = 0.0,
                 physics: Physics | None = None, index: int = 0,
                 origin_lla: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 params=None, signing_key: bytes | None = None, trusted_addrs=(),
                 ekf_ready_after_s: float = 0.0, unix_time_at_zero_s: float = 1.7e9,
                 network: int = 0, log_limiter: RateLimitedLog | None = None) -> None:
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
        self.physics = physics
        self.index = int(index)
        self.alive = True
        self._boot_s = float(now_s)
        self._physics_t_s = float(now_s)
        self._last_timer_s = float(now_s)
        self._unix_at_zero_s = float(unix_time_at_zero_s)
        self._ekf_ready_s = float(now_s) + float(ekf_ready_after_s)
        self.trusted_addrs = frozenset(trusted_addrs)

        spec = defaults_for(personality)
        overrides = dict(params or {})
        overrides.setdefault(self.pers.sysid_param, self.sysid)
        self.params = ParamTable(spec, overrides)

        allow_unsigned = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS,
                                    mavlink.MAVLINK_MSG_ID_SETUP_SIGNING})
        self._codec = wire.Codec(self.sysid, self.compid, signing_key=signing_key,
                                 allow_unsigned_ids=allow_unsigned)
        self.stats = CoreStats()
        self._out: list[bytes] = []
        self._events: deque = deque()
        self._logged_types: set[str] = set()
        #: Warnings caused by remote input go through this (shared by a Swarm's cores).
        self.log_limiter = log_limiter if log_limiter is not None else RateLimitedLog(log)

        # Home / EKF origin = spawn point (world NED and geodetic).
        i = self.index
        self.home_ned_m = physics.pos_ned_m[i].copy()
        if self._owns_physics:
            physics.update_geodetic()
        self.home_lla = (float(physics.lat_deg[i]), float(physics.lon_deg[i]),
                         float(physics.alt_amsl_m[i]))

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
        self.gcs_failsafe = False
        self.offboard_failsafe = False

        #: Streams: interval and next due time per message id (vehicle_emu.telemetry).
        self.streams = tm.StreamScheduler(self.pers.default_rates_hz, now_s)
        self._missions = MissionServer(self._send, self.pers.mission_home_items == 0,
                                       lambda: self.home_lla)
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
            # Explicit ignores (skybrush-style nop handlers): traffic a GCS legitimately sends
            # that this emulator has no use for.
            "RADIO_STATUS": nop, "COMMAND_ACK": nop, "SYSTEM_TIME": nop, "PARAM_VALUE": nop,
            "MANUAL_CONTROL": nop, "RC_CHANNELS_OVERRIDE": nop, "GPS_GLOBAL_ORIGIN": nop,
            "STATUSTEXT": nop, "ATTITUDE": nop, "GLOBAL_POSITION_INT": nop,
            "LOCAL_POSITION_NED": nop, "SYS_STATUS": nop,
        }
        self._apply_params()

    # =========================================================================================
    # Public sans-I/O surface
    # =========================================================================================

    def receive_datagram(self, data: bytes, addr, now_s: float) -> None:
        """Feed one datagram (any number of frames, possibly garbage or truncated)."""
        st = self.stats
        st.datagrams_in += 1
        if not self.alive:
            st.dropped_dead += 1
            return
        res = self._codec.decode_datagram(data)
        st.bad_data += res.n_bad
        st.unknown_msg_ids += res.n_unknown
        st.truncated_bytes += res.n_truncated_bytes
        if res.n_signature_rejected:
            st.signing_rejected += res.n_signature_rejected
            self._warn_limited(now_s, "signing", "sysid %d: rejected %d frame(s) failing "
                               "MAVLink signing from %s", self.sysid,
                               res.n_signature_rejected, addr, level=logging.INFO)
        if res.n_bad or res.n_unknown:
            self._warn_limited(now_s, "bad_data", "sysid %d: %d bad frame(s), %d unknown "
                               "message id(s) from %s (totals: %d bad, %d unknown)", self.sysid,
                               res.n_bad, res.n_unknown, addr, st.bad_data, st.unknown_msg_ids)
        for msg in res.messages:
            self.receive_message(msg, addr, now_s)

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
            self._warn_limited(now_s, f"handler:{mtype}", "sysid %d: handler for %s failed",
                               self.sysid, mtype, level=logging.ERROR, exc_info=True)

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
    # Autopilot logic (timers)
    # =========================================================================================

    def update_autopilot(self, now_s: float) -> None:
        """Mode state machines, timeouts and failsafes, before the physics step."""
        if not self.alive:
            return
        ph, i = self.physics, self.index
        landed = bool(ph.landed[i])

        # Auto-disarm of an armed copter left on the ground. ArduCopter motors.cpp
        # auto_disarm_check (DISARM_DELAY, default 10 s); PX4 COM_DISARM_PRFLT before takeoff
        # (commander_params.yaml) and COM_DISARM_LAND (2 s) after a landing.
        if self.armed and landed and self._takeoff_target_down_m is None:
            if self._landed_armed_since_s is None:
                self._landed_armed_since_s = now_s
            delay = self.pers.auto_disarm_delay_s()
            if delay > 0 and now_s - self._landed_armed_since_s >= delay:
                self._disarm(now_s, "auto_disarm")
        else:
            self._landed_armed_since_s = None
        if self.armed and not landed:
            self._has_taken_off = True

        beh = self._behaviour
        # Takeoff progress (ArduPilot guided takeoff, PX4 AUTO.TAKEOFF).
        if self._takeoff_target_down_m is not None:
            if abs(ph.pos_ned_m[i, DOWN] - self._takeoff_target_down_m) < 0.3:
                self._takeoff_target_down_m = None
                self.pers.on_takeoff_reached(now_s, beh)
            elif not self.armed:
                self._takeoff_target_down_m = None

        if beh == "rtl":
            self._run_rtl(now_s)
        elif beh == "land":
            if landed and self.armed:
                # ArduCopter land mode disarms on touchdown; PX4 AUTO.LAND likewise.
                self._disarm(now_s, "landed")

        # ArduPilot GUID_TIMEOUT on velocity targets; PX4 offboard signal loss.
        self.pers.guided_watchdog(now_s, beh)

        self._missions.update(now_s)
        self._check_gcs_link(now_s)

    def _check_gcs_link(self, now_s: float) -> None:
        """GCS failsafe.

        ArduPilot (ArduCopter/events.cpp ``failsafe_gcs_check``): disabled when FS_GCS_ENABLE=0;
        inactive until a heartbeat from SYSID_MYGCS was seen; triggers when the last one is
        older than FS_GCS_TIMEOUT; clears when heartbeats resume, but the vehicle stays in the
        failsafe mode until a GCS changes it (measured on SITL, docs/design/mavlink.md §5.1).
        PX4: data-link loss after COM_DL_LOSS_T without a GCS heartbeat, action NAV_DLL_ACT.
        """
        last = self._last_gcs_hb_s
        if last is None:
            return
        enabled, timeout = self.pers.gcs_failsafe_config()
        if not enabled:
            self.gcs_failsafe = False
            return
        lost = now_s - last > timeout
        if lost and not self.gcs_failsafe:
            self.gcs_failsafe = True
            action = self._gcs_failsafe_action(now_s)
            log.info("sysid %d: GCS link lost at t=%.2f s -> %s", self.sysid, now_s, action)
            self._events.append(ev.FailsafeTriggered(self.sysid, now_s, "gcs", action))
        elif not lost and self.gcs_failsafe:
            self.gcs_failsafe = False
            self._events.append(ev.GcsLinkRegained(self.sysid, now_s))
            self._statustext(now_s, mavlink.MAV_SEVERITY_INFO, "GCS Failsafe Cleared")

    def _gcs_failsafe_action(self, now_s: float) -> str:
        if not self.armed:
            return "NONE"
        if self.physics.landed[self.index]:
            # ArduCopter should_disarm_on_failsafe(): landed -> disarm.
            self._disarm(now_s, "failsafe")
            return "DISARM"
        return self.pers.gcs_failsafe_action(now_s)

    def _run_rtl(self, now_s: float) -> None:
        """RTL: climb to the return altitude, fly home horizontally, then land (default) or
        hover.

        ArduCopter mode_rtl.cpp: climb to max(RTL_ALT, current altitude), return at RTL_SPEED
        (0 -> WPNAV_SPEED), final descent to RTL_ALT_FINAL; 0 (default) lands and disarms.
        PX4 navigator/rtl: climb to RTL_RETURN_ALT, return at MPC_XY_CRUISE, land unless
        RTL_LAND_DELAY < 0 (then hover at RTL_DESCEND_ALT). We land by default because both
        firmwares do; a hovering drone at home would also be a relay for the paper's base,
        which the paper's model does not assume.
        """
        ph, i = self.physics, self.index
        if not self.armed:
            return
        pos = ph.pos_ned_m[i]
        home = self._rtl_dest_ned_m  # home or the rally point chosen at RTL entry
        phase = self._rtl_phase
        if phase == "climb":
            if self._rtl_cruise_down_m is None:  # return altitude fixed at RTL entry
                self._rtl_cruise_down_m = float(min(pos[DOWN], home[DOWN] - self._rtl_alt_m))
                ph.command_position(i, (pos[NORTH], pos[EAST], self._rtl_cruise_down_m))
            if pos[DOWN] - self._rtl_cruise_down_m > 0.5:
                return
            self._rtl_phase = phase = "return"
        if phase == "return":
            dist_h = math.hypot(pos[NORTH] - home[NORTH], pos[EAST] - home[EAST])
            ph.max_speed_h_m_s[i] = self._auto_speed_m_s
            if dist_h > 1.0:
                ph.command_position(i, (home[NORTH], home[EAST], self._rtl_cruise_down_m))
                return
            self._rtl_phase = phase = "final"
        if phase == "final":
            if self._rtl_hover_alt_m is not None:
                ph.command_position(i, (home[NORTH], home[EAST],
                                        home[DOWN] - self._rtl_hover_alt_m))
                self._rtl_phase = "hover"
            else:
                ph.command_land(i)
                self._rtl_phase = "land"
        elif phase == "land" and ph.landed[i]:
            self._disarm(now_s, "landed")

    # =========================================================================================
    # Telemetry
    # =========================================================================================

    def emit_telemetry(self, now_s: float) -> None:
        """Encode every stream that is due (after the physics step)."""
        if not self.alive:
            return
        if self._codec.signing_enabled:
            self._codec.advance_signing_timestamp(
                wire.signing_timestamp_from_s(self._unix_at_zero_s + now_s))
        builders = tm.BUILDERS
        for msg_id in self.streams.due(now_s):
            try:
                self._send(builders[msg_id](self, now_s))
            except Exception:  # noqa: BLE001 - a bad value must not stop the other streams
                self.stats.telemetry_errors += 1
                self._warn_limited(now_s, f"telemetry:{msg_id}",
                                   "sysid %d: building message %d failed", self.sysid,
                                   msg_id, exc_info=True)

    def _send(self, msg) -> None:
        buf = self._codec.encode(msg)
        self._out.append(buf)
        self.stats.messages_out += 1
        self.stats.bytes_out += len(buf)

    def _set_interval(self, msg_id: int, interval_s: float, now_s: float) -> bool:
        return self.streams.set_interval(msg_id, interval_s, now_s)

    def _statustext(self, now_s: float, severity: int, text: str) -> None:
        self._send(mavlink.MAVLink_statustext_message(severity, text.encode()[:50]))

    # =========================================================================================
    # Inbound handlers
    # =========================================================================================

    def _nop(self, msg, addr, now_s: float) -> None:
        return None

    def _warn_limited(self, now_s: float, key: str, msg: str, *args,
                      level: int = logging.WARNING, **kwargs) -> bool:
        return self.log_limiter.log(now_s, key, level, msg, *args, **kwargs)

    def _for_me(self, target_system: int, target_component: int) -> bool:
        ok = target_system in (0, self.sysid) and target_component in (0, self.compid)
        if not ok:
            self.stats.not_for_us += 1
        return ok

    def _on_heartbeat(self, msg, addr, now_s: float) -> None:
        if msg.type != _GCS_HEARTBEAT_TYPE:
            return
        if not self.pers.accepts_gcs_heartbeat(msg.get_srcSystem()):
            return
        self.stats.gcs_heartbeats += 1
        self._last_gcs_hb_s = now_s
        self._check_gcs_link(now_s)

    # -- commands -----------------------------------------------------------------------------

    def _on_command_long(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        params = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
        self._command(m.command, params, None, m, now_s)

    def _on_command_int(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        # COMMAND_INT: x, y are degE7 for global frames; z is float.
        params = (m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z)
        self._command(m.command, params, m.frame, m, now_s)

    def _ack(self, command: int, result: int, m, now_s: float) -> None:
        self._send(mavlink.MAVLink_command_ack_message(command, result, 0, 0, m.get_srcSystem(),
                                                       m.get_srcComponent()))
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
            return (C.MAV_RESULT_ACCEPTED if self._set_mode(key, now_s, "command")
                    else C.MAV_RESULT_FAILED), None
        if cmd == C.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            key = self.pers.rtl_mode
            return (C.MAV_RESULT_ACCEPTED if self._set_mode(key, now_s, "command")
                    else C.MAV_RESULT_FAILED), None
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
            builder = tm.BUILDERS.get(msg_id)
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

    def _arm(self, now_s: float) -> None:
        ph, i = self.physics, self.index
        self.armed = True
        ph.armed[i] = True
        self._armed_since_s = now_s
        self._landed_armed_since_s = None
        self._has_taken_off = False
        ph.hold(i)
        self.pers.on_armed(now_s)
        self._events.append(ev.ArmingChanged(self.sysid, now_s, True, "command"))
        self._statustext(now_s, mavlink.MAV_SEVERITY_INFO, "Arming motors")

    def _disarm(self, now_s: float, reason: str, force: bool = False) -> None:
        ph, i = self.physics, self.index
        self.armed = False
        ph.armed[i] = False
        ph.hold(i)
        self._takeoff_target_down_m = None
        self._vel_target_s = None
        self._events.append(ev.ArmingChanged(self.sysid, now_s, False, reason))
        self._statustext(now_s, mavlink.MAV_SEVERITY_INFO, "Disarming motors")

    def _cmd_set_mode(self, p: tuple, now_s: float) -> int:
        return self.pers.cmd_set_mode(p, now_s)

    def _on_set_mode(self, m, addr, now_s: float) -> None:
        if m.target_system != self.sysid:
            self.stats.not_for_us += 1
            return
        self.stats.commands += 1
        self.pers.on_set_mode_message(m, now_s)

    def _set_mode(self, key: int, now_s: float, reason: str) -> bool:
        """Enter a mode (by custom_mode value); returns False for unknown modes."""
        info = self.pers.mode_info(key)
        if info is None:
            return False
        name, beh = info
        ph, i = self.physics, self.index
        changed = key != self._mode_key
        self._mode_key, self.mode_name, self._behaviour = key, name, beh
        if reason != "failsafe":
            self.offboard_failsafe = False
        self._vel_target_s = None
        if beh != "takeoff":
            self._takeoff_target_down_m = None
        ph.max_speed_h_m_s[i] = self._guided_speed_m_s if beh == "guided" else self._auto_speed_m_s
        if beh == "rtl":
            self._rtl_phase = "climb"
            self._rtl_cruise_down_m = None
            self._rtl_dest_ned_m = self.pers.rtl_destination_ned_m()
        elif beh == "land":
            ph.command_land(i)
        elif beh == "guided" and self.pers.resume_offboard(now_s):
            pass  # PX4 flies the setpoint it kept
        elif beh != "takeoff":
            ph.hold(i)
        if changed:
            self._events.append(ev.ModeChanged(self.sysid, now_s, name, key, reason))
        return True

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

    # -- setpoints ----------------------------------------------------------------------------

    def _global_to_world(self, lat_e7: int, lon_e7: int, alt_m: float, frame: int):
        """A global target -> world NED (m), or None where the firmware refuses it
        (:meth:`vehicle_emu.personality.base.Personality.global_to_world`)."""
        return self.pers.global_to_world(lat_e7, lon_e7, alt_m, frame)

    def _on_set_position_target_local(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        self.stats.setpoints += 1
        frame = m.coordinate_frame
        if frame not in _LOCAL_FRAMES:
            # PX4: "coordinate frame unsupported", returns before offboard_control_mode.
            self.stats.setpoints_ignored += 1
            return
        mask = m.type_mask
        self.pers.note_setpoint_mask(mask, now_s)  # PX4 offboard signal
        ph, i = self.physics, self.index
        pos = vel = None
        yaw = ph.yaw_rad[i]
        cy, sy = math.cos(yaw), math.sin(yaw)
        body = frame in (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED)
        if self.pers.local_target_unusable(m):
            self.stats.setpoints_ignored += 1
            return
        if not mask & _POS_BITS:
            x, y, z = m.x, m.y, m.z
            if body:  # ArduCopter rotate_body_frame_to_NE
                x, y = x * cy - y * sy, x * sy + y * cy
            if frame == mavlink.MAV_FRAME_LOCAL_NED:
                pos = self.home_ned_m + (x, y, z)   # LOCAL_NED is relative to the EKF origin
            else:
                pos = ph.pos_ned_m[i] + (x, y, z)   # offset and body frames: relative to vehicle
        if not mask & _VEL_BITS:
            vx, vy = m.vx, m.vy
            if body:
                vx, vy = vx * cy - vy * sy, vx * sy + vy * cy
            vel = np.array((vx, vy, m.vz))
        self._accept_target(pos, vel, mask, now_s)

    def _on_set_position_target_global(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        self.stats.setpoints += 1
        mask = m.type_mask
        pos = vel = None
        if not mask & _POS_BITS:
            pos = self._global_to_world(m.lat_int, m.lon_int, m.alt, m.coordinate_frame)
            if pos is None:
                self.stats.setpoints_ignored += 1
                self.pers.on_bad_global_target()
                return
        elif m.coordinate_frame not in self.pers.global_frames:
            self.stats.setpoints_ignored += 1
            return
        self.pers.note_setpoint_mask(mask, now_s)  # a dropped setpoint is no offboard signal
        if not mask & _VEL_BITS:
            vel = np.array((m.vx, m.vy, m.vz))
        self._accept_target(pos, vel, mask, now_s)

    def _accept_target(self, pos, vel, mask: int, now_s: float) -> None:
        if (pos is not None and not np.all(np.isfinite(pos))) or (
                vel is not None and not np.all(np.isfinite(vel))):
            self.stats.setpoints_ignored += 1
            return
        self.pers.accept_target((pos, vel, mask), now_s)

    def _apply_target(self, target, now_s: float) -> None:
        pos, vel, mask = target
        ph, i = self.physics, self.index
        if not self.pers.can_fly_target():
            return  # PX4 keeps it for when it is armed
        if pos is not None:
            pos = self.pers.limit_target_position(pos)
            ph.command_position(i, pos, vel)
            self._vel_target_s = None
            self._takeoff_target_down_m = None
        elif vel is not None:
            ph.command_velocity(i, vel)
            self._vel_target_s = now_s
            self._takeoff_target_down_m = None
        else:
            self.pers.on_empty_target()
        self._target_mask = mask

    # -- mission protocol (vehicle_emu.missions) ---------------------------------------------

    def _on_mission_request_list(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_request_list(m, now_s)

    def _on_mission_request_int(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_request(m, now_s, as_int=True)

    def _on_mission_request(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_request(m, now_s, as_int=False)

    def _on_mission_count(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_count(m, now_s)

    def _on_mission_clear_all(self, m, addr, now_s: float) -> None:
        if self._for_me(m.target_system, m.target_component):
            self._missions.on_clear_all(m, now_s)

    def _on_mission_item(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        if self.pers.guided_mission_items and m.current in (2, 3) and (
                getattr(m, "mission_type", 0) == mavlink.MAV_MISSION_TYPE_MISSION):
            # ArduPilot GCS_Common.cpp handle_mission_item: current = 2 is a "guided mode"
            # waypoint (MAVProxy ``guided``, Mission Planner "Fly To Here"), current = 3 an
            # altitude change; answered with MISSION_ACK, ACCEPTED or ERROR.
            ok = self._guided_mission_item(m, now_s)
            self._send(mavlink.MAVLink_mission_ack_message(
                m.get_srcSystem(), m.get_srcComponent(),
                mavlink.MAV_MISSION_ACCEPTED if ok else mavlink.MAV_MISSION_ERROR,
                mavlink.MAV_MISSION_TYPE_MISSION))
            return
        self._missions.on_item(m, now_s)

    def _guided_mission_item(self, m, now_s: float) -> bool:
        """ArduCopter ModeAuto::do_guided: "only process guided waypoint if we are in guided
        mode"; NAV_WAYPOINT -> ModeGuided::set_destination. current = 3:
        handle_change_alt_request (keep the horizontal target, change the altitude)."""
        ph, i = self.physics, self.index
        if self._behaviour != "guided" or not self.armed or (
                ph.landed[i] and self._takeoff_target_down_m is None):
            return False
        if m.get_type() == "MISSION_ITEM":
            lat_e7, lon_e7 = wire.lat_e7_from_deg(m.x), wire.lat_e7_from_deg(m.y)
        else:
            lat_e7, lon_e7 = m.x, m.y
        if m.current == 2 and m.command != mavlink.MAV_CMD_NAV_WAYPOINT:
            return False
        if m.current == 3:  # altitude only: x, y are unused (often 0)
            lat_e7, lon_e7 = (wire.lat_e7_from_deg(v) for v in self.home_lla[:2])
        if not (math.isfinite(m.z) and math.isfinite(lat_e7) and math.isfinite(lon_e7)):
            return False
        pos = self._global_to_world(int(lat_e7), int(lon_e7), float(m.z), m.frame)
        if pos is None:
            return False
        if m.current == 3:
            pos = np.array((ph.target_pos_ned_m[i, NORTH], ph.target_pos_ned_m[i, EAST], pos[DOWN]))
        self._apply_target((np.asarray(pos, dtype=float), None, TARGET_MASK_POSITION), now_s)
        return True

    # -- streams ------------------------------------------------------------------------------

    def _on_request_data_stream(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        self.pers.on_request_data_stream(m, now_s)  # PX4 does not implement it

    # -- parameters ---------------------------------------------------------------------------

    def _send_param(self, name: str) -> None:
        ptype = self.params.param_type(name)
        value = wire.param_to_wire_float(self.params[name], ptype, bytewise=self.pers.param_bytewise)
        self._send(mavlink.MAVLink_param_value_message(
            name.encode(), value, ptype, len(self.params), self.params.index_of(name)))

    def _on_param_request_list(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        for name in self.params.names():
            self._send_param(name)

    def _on_param_request_read(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        name = self.params.name_at(m.param_index) if m.param_index >= 0 else _pid_str(m.param_id)
        if name is not None and name in self.params:
            self._send_param(name)

    def _on_param_set(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        name = _pid_str(m.param_id)
        if name not in self.params:
            return  # both firmwares stay silent on unknown names
        ptype = self.params.param_type(name)
        try:
            value = wire.param_from_wire_float(m.param_value, ptype, bytewise=self.pers.param_bytewise)
        except ValueError:
            self.stats.bad_data += 1
            return
        if not math.isfinite(value):
            self.stats.bad_data += 1
            return
        stored = self.params.set(name, value)
        self._apply_params()
        self._events.append(ev.ParamChanged(self.sysid, now_s, name, stored))
        self._send_param(name)

    def _apply_params(self) -> None:
        """Derive SI limits from the parameter table (native units -> m, m/s)."""
        self.pers.apply_params()
        beh = getattr(self, "_behaviour", "hold")
        self.physics.max_speed_h_m_s[self.index] = (
            self._guided_speed_m_s if beh == "guided" else self._auto_speed_m_s)

    # -- misc ---------------------------------------------------------------------------------

    def _on_timesync(self, m, addr, now_s: float) -> None:
        # TIMESYNC: a request has tc1 == 0; reply with tc1 = our time, ts1 mirrored.
        # tc1 is never 0 in a reply (ArduPilot uses micros64() * 1000, PX4 the hrt clock in
        # ns; a reply with tc1 == 0 would read as a new request): at least 1 ns.
        if m.tc1 == 0:
            self._send(mavlink.MAVLink_timesync_message(
                max(1, wire.time_ns_from_s(now_s - self._boot_s)), m.ts1))

    def _on_ping(self, m, addr, now_s: float) -> None:
        # PING request: target_system == 0; reply targets the requester (common.xml PING).
        if m.target_system == 0:
            self._send(mavlink.MAVLink_ping_message(m.time_usec, m.seq, m.get_srcSystem(),
                                                   m.get_srcComponent()))

    def _on_setup_signing(self, m, addr, now_s: float) -> None:
        if m.target_system != self.sysid:
            self.stats.not_for_us += 1
            return
        if addr not in self.trusted_addrs or self.armed:
            self.stats.signing_rejected += 1
            self._warn_limited(now_s, "setup_signing", "sysid %d: SETUP_SIGNING from untrusted "
                               "link %s (or armed) refused", self.sysid, addr)
            return
        key = bytes(bytearray(m.secret_key)) if not isinstance(m.secret_key, bytes) else m.secret_key
        self._codec.set_signing_key(key, initial_timestamp=m.initial_timestamp)
        enabled = self._codec.signing_enabled
        log.info("sysid %d: signing %s via SETUP_SIGNING", self.sysid,
                 "enabled" if enabled else "disabled")
        self._events.append(ev.SigningChanged(self.sysid, now_s, enabled))

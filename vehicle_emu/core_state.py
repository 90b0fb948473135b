"""The state of one emulated autopilot (:class:`CoreState`), its counters and its rate-limited log.

:class:`vehicle_emu.link.VehicleCore` is cut along its seams into mixins that all work on this
state: the autopilot rules (:mod:`vehicle_emu.core_autopilot`), setpoints
(:mod:`vehicle_emu.core_setpoints`), commands (:mod:`vehicle_emu.core_commands`) and the
parameter / mission / time / signing protocols (:mod:`vehicle_emu.core_protocols`). The
attributes are declared here, once, with their types; ``VehicleCore.__init__`` sets them. The
helpers every handler uses to answer (queue a message, a STATUSTEXT, a rate-limited warning,
the target check) live here too.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from . import telemetry as tm
from . import wire
from .wire import dialect as mavlink

if TYPE_CHECKING:
    from .missions import MissionServer
    from .params import ParamTable
    from .personality.base import Personality
    from .physics import Physics

__all__ = ["CoreState", "CoreStats", "RateLimitedLog"]


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

    def __init__(
        self, logger: logging.Logger, interval_s: float = 10.0, max_keys: int = 256
    ) -> None:
        self.logger = logger
        self.interval_s = float(interval_s)
        self.max_keys = int(max_keys)
        self._state: dict = {}  # key -> [last_logged_s, n_suppressed]
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


class CoreState:
    """The attributes of a :class:`vehicle_emu.link.VehicleCore` (set by its ``__init__``) and
    the helpers every handler uses to answer."""

    # Identity and link.
    sysid: int
    network: int
    personality: str
    pers: Personality
    compid: int
    trusted_addrs: frozenset
    params: ParamTable
    _codec: wire.Codec
    stats: CoreStats
    _out: list[bytes]
    _out_dirty: set[int] | None
    _events: deque
    _logged_types: set[str]
    log_limiter: RateLimitedLog
    _handlers: dict[str, Any]
    # Time (vehicle clock, seconds).
    _boot_s: float
    _physics_t_s: float
    _last_timer_s: float
    _unix_time_at_zero_s: float
    _ekf_ready_s: float
    # Physics row and home (EKF origin).
    _owns_physics: bool
    physics: Physics
    index: int
    alive: bool
    home_ned_m: np.ndarray
    home_lla: tuple[float, float, float]
    # Autopilot state.
    armed: bool
    _armed_since_s: float | None
    _landed_armed_since_s: float | None
    _has_taken_off: bool
    _mode_key: int
    mode_name: str
    _behaviour: str
    _rtl_phase: str
    _rtl_cruise_down_m: float | None
    _rtl_dest_ned_m: np.ndarray
    """Where RTL flies: home, or the rally point the personality chose at RTL entry."""
    _takeoff_target_down_m: float | None
    _vel_target_s: float | None
    _target_mask: int
    _last_gcs_hb_s: float | None
    _gcs_fs_config: tuple[bool, float]
    """``pers.gcs_failsafe_config()`` as of the parameter table's ``_gcs_fs_stamp``."""
    _gcs_fs_stamp: int
    gcs_failsafe: bool
    offboard_failsafe: bool
    streams: tm.StreamScheduler
    batt: Any
    """The firmware's battery monitor (vehicle_emu.battery_monitor), None: endless battery."""
    _missions: MissionServer
    # Set from the parameters by the personality (vehicle_emu/personality/*.py).
    _guided_speed_m_s: float
    _auto_speed_m_s: float
    _rtl_alt_m: float
    _rtl_hover_alt_m: float | None

    def _send(self, msg) -> None:
        buf = self._codec.encode(msg)
        self._out.append(buf)
        if self._out_dirty is not None:
            self._out_dirty.add(self.index)
        self.stats.messages_out += 1
        self.stats.bytes_out += len(buf)

    def _set_interval(self, msg_id: int, interval_s: float, now_s: float) -> bool:
        if not self._can_send(msg_id):
            return False
        return self.streams.set_interval(msg_id, interval_s, now_s)

    def _can_send(self, msg_id: int) -> bool:
        """Whether this vehicle has message ``msg_id`` at all (BATTERY_STATUS: a battery; the
        filter's report: its own firmware's, ``pers.estimator_msgid``)."""
        if msg_id in (tm.M_EKF_STATUS_REPORT, tm.M_ESTIMATOR_STATUS):
            return msg_id == self.pers.estimator_msgid
        return msg_id in tm.BUILDERS and (msg_id != tm.M_BATTERY_STATUS or self.batt is not None)

    def _statustext(self, now_s: float, severity: int, text: str) -> None:
        self._send(mavlink.MAVLink_statustext_message(severity, text.encode()[:50]))

    def _nop(self, msg, addr, now_s: float) -> None:
        return None

    def _warn_limited(
        self, now_s: float, key: str, msg: str, *args, level: int = logging.WARNING, **kwargs
    ) -> bool:
        return self.log_limiter.log(now_s, key, level, msg, *args, **kwargs)

    def _for_me(self, target_system: int, target_component: int) -> bool:
        ok = target_system in (0, self.sysid) and target_component in (0, self.compid)
        if not ok:
            self.stats.not_for_us += 1
        return ok

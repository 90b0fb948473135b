"""The sub-protocols :class:`vehicle_emu.link.VehicleCore` answers: missions (with ArduPilot's
guided MISSION_ITEM), REQUEST_DATA_STREAM, parameters, TIMESYNC, PING and SETUP_SIGNING.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from mavedge.params import param_id_to_str as _pid_str
from planner.geometry import DOWN, EAST, NORTH

from . import events as ev
from . import wire
from .core_setpoints import SetpointHandlers
from .personality.base import TARGET_MASK_POSITION
from .wire import dialect as mavlink

__all__ = ["ProtocolHandlers"]

#: The core's log lines keep the logger they always had (the core was one module).
log = logging.getLogger("vehicle_emu.link")


class ProtocolHandlers(SetpointHandlers):
    """Missions, streams, parameters, time, signing (a mixin of
    :class:`vehicle_emu.link.VehicleCore`)."""

    # -- mission protocol (vehicle_emu.missions) ---------------------------------------------------

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
        if (
            self.pers.guided_mission_items
            and m.current in (2, 3)
            and (getattr(m, "mission_type", 0) == mavlink.MAV_MISSION_TYPE_MISSION)
        ):
            # ArduPilot GCS_Common.cpp handle_mission_item: current = 2 is a "guided mode"
            # waypoint (MAVProxy ``guided``, Mission Planner "Fly To Here"), current = 3 an
            # altitude change; answered with MISSION_ACK, ACCEPTED or ERROR.
            ok = self._guided_mission_item(m, now_s)
            self._send(
                mavlink.MAVLink_mission_ack_message(
                    m.get_srcSystem(),
                    m.get_srcComponent(),
                    mavlink.MAV_MISSION_ACCEPTED if ok else mavlink.MAV_MISSION_ERROR,
                    mavlink.MAV_MISSION_TYPE_MISSION,
                )
            )
            return
        self._missions.on_item(m, now_s)

    def _guided_mission_item(self, m, now_s: float) -> bool:
        """ArduCopter ModeAuto::do_guided: "only process guided waypoint if we are in guided
        mode"; NAV_WAYPOINT -> ModeGuided::set_destination. current = 3:
        handle_change_alt_request (keep the horizontal target, change the altitude)."""
        ph, i = self.physics, self.index
        if (
            self._behaviour != "guided"
            or not self.armed
            or (ph.landed[i] and self._takeoff_target_down_m is None)
        ):
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

    # -- streams -----------------------------------------------------------------------------------

    def _on_request_data_stream(self, m, addr, now_s: float) -> None:
        if not self._for_me(m.target_system, m.target_component):
            return
        self.pers.on_request_data_stream(m, now_s)  # PX4 does not implement it

    # -- parameters --------------------------------------------------------------------------------

    def _send_param(self, name: str) -> None:
        ptype = self.params.param_type(name)
        value = wire.param_to_wire_float(
            self.params[name], ptype, bytewise=self.pers.param_bytewise
        )
        self._send(
            mavlink.MAVLink_param_value_message(
                name.encode(), value, ptype, len(self.params), self.params.index_of(name)
            )
        )

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
            value = wire.param_from_wire_float(
                m.param_value, ptype, bytewise=self.pers.param_bytewise
            )
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
            self._guided_speed_m_s if beh == "guided" else self._auto_speed_m_s
        )

    # -- misc --------------------------------------------------------------------------------------

    def _on_timesync(self, m, addr, now_s: float) -> None:
        # TIMESYNC: a request has tc1 == 0; reply with tc1 = our time, ts1 mirrored.
        # tc1 is never 0 in a reply (ArduPilot uses micros64() * 1000, PX4 the hrt clock in
        # ns; a reply with tc1 == 0 would read as a new request): at least 1 ns.
        if m.tc1 == 0:
            self._send(
                mavlink.MAVLink_timesync_message(
                    max(1, wire.time_ns_from_s(now_s - self._boot_s)), m.ts1
                )
            )

    def _on_ping(self, m, addr, now_s: float) -> None:
        # PING request: target_system == 0; reply targets the requester (common.xml PING).
        if m.target_system == 0:
            self._send(
                mavlink.MAVLink_ping_message(
                    m.time_usec, m.seq, m.get_srcSystem(), m.get_srcComponent()
                )
            )

    def _on_setup_signing(self, m, addr, now_s: float) -> None:
        if m.target_system != self.sysid:
            self.stats.not_for_us += 1
            return
        if addr not in self.trusted_addrs or self.armed:
            self.stats.signing_rejected += 1
            self._warn_limited(
                now_s,
                "setup_signing",
                "sysid %d: SETUP_SIGNING from untrusted link %s (or armed) refused",
                self.sysid,
                addr,
            )
            return
        key = (
            bytes(bytearray(m.secret_key)) if not isinstance(m.secret_key, bytes) else m.secret_key
        )
        self._codec.set_signing_key(key, initial_timestamp=m.initial_timestamp)
        enabled = self._codec.signing_enabled
        log.info(
            "sysid %d: signing %s via SETUP_SIGNING",
            self.sysid,
            "enabled" if enabled else "disabled",
        )
        self._events.append(ev.SigningChanged(self.sysid, now_s, enabled))

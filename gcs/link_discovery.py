"""Who is a vehicle, and what it reports, for :class:`gcs.link.StationLink`: discovery by
HEARTBEAT (never another GCS, a companion or a gimbal, docs/design/mavlink.md §1.1), refused and
inconsistent sources, address moves, mode / arming changes, task systems, and the position, home
and STATUSTEXT a vehicle sends.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from gcs import wire
from gcs.autopilot import adapter_for
from gcs.events import (
    ArmedChanged,
    BatteryReceived,
    HomePositionReceived,
    ModeChanged,
    StatusText,
    TaskPositionReceived,
    TelemetryReceived,
    VehicleDiscovered,
    VehicleRebooted,
    VehicleRecovered,
)
from gcs.link_state import _AUTOPILOT_COMPID, Addr, _result_name, _Vehicle
from gcs.link_health import VehicleHealth
from gcs.wire import mavlink

__all__ = ["VehicleDiscovery", "NON_VEHICLE_TYPES", "sys_status_battery"]

#: The link's log lines keep the logger they always had (StationLink was one module).
log = logging.getLogger("gcs.link")

#: A vehicle clock (``time_boot_ms``) this much behind its last report means a reboot, not
#: reordered datagrams, seconds.
REBOOT_CLOCK_JUMP_S = 1.0

#: HEARTBEAT.type values that never create a vehicle (docs/design/mavlink.md §1.1): another GCS, a
#: companion computer, a gimbal, an ADS-B receiver.
NON_VEHICLE_TYPES = frozenset(
    {
        mavlink.MAV_TYPE_GCS,
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
        mavlink.MAV_TYPE_GIMBAL,
        mavlink.MAV_TYPE_ADSB,
    }
)


def sys_status_battery(link_id: int, sysid: int, t_s: float, msg: Any) -> BatteryReceived:
    """SYS_STATUS's battery fields (common.xml) as an event (the live link and the replay of a
    .tlog, mission.view.live.replay); ValueError for values no event accepts."""
    return BatteryReceived(
        link_id,
        sysid,
        t_s,
        source="SYS_STATUS",
        remaining_frac=wire.battery_remaining_to_frac(msg.battery_remaining),
        voltage_v=wire.battery_mv_to_v(msg.voltage_battery),
        current_a=wire.battery_ca_to_a(msg.current_battery),
    )


class VehicleDiscovery(VehicleHealth):
    """Discovery and vehicle reports (a mixin of :class:`gcs.link.StationLink`)."""

    # ------------------------------------------------------------------ who is a vehicle

    @staticmethod
    def _is_vehicle_heartbeat(msg: Any) -> bool:
        return (
            msg.get_srcComponent() == _AUTOPILOT_COMPID
            and msg.type not in NON_VEHICLE_TYPES
            and msg.get_srcSystem() != 0
        )

    def _may_become_vehicle(self, sysid: int) -> bool:
        cfg = self.config
        if cfg.allowed_sysids is not None and sysid not in cfg.allowed_sysids:
            return False
        return cfg.max_vehicles is None or len(self._vehicles) < cfg.max_vehicles

    def _refuse(self, sysid: int, kind: str, addr: Addr, now_s: float) -> None:
        st = self.stats
        st.refused_sysids += 1
        st.refused_by_sysid[sysid] = st.refused_by_sysid.get(sysid, 0) + 1
        self._warn(
            ("refused",),
            now_s,
            "link %d: refused %s from sysid %d at %s (not an allowed "
            "vehicle on this link; %d refused so far)",
            self.link_id,
            kind,
            sysid,
            addr,
            st.refused_sysids,
        )

    def _inconsistent(self, v: _Vehicle, now_s: float, what: str, *args: object) -> None:
        self.stats.inconsistent_frames += 1
        self._warn(
            ("inconsistent", v.sysid),
            now_s,
            "link %d sysid %d: " + what + " (%d such frames dropped on this link)",
            self.link_id,
            v.sysid,
            *args,
            self.stats.inconsistent_frames,
        )

    def _identity_changed(self, v: _Vehicle, msg: Any) -> bool:
        return msg.autopilot != v.autopilot or msg.type != v.vehicle_type

    def _moved(self, v: _Vehicle, msg: Any, kind: str, addr: Addr, now_s: float) -> bool:
        """A datagram with ``v``'s sysid from an address other than ``v.addr``: True if the
        vehicle really moved there (its old address silent, a consistent HEARTBEAT from the
        new one), after which the frame is processed; False if it is dropped."""
        if now_s - v.addr_heard_s < self.config.address_hold_s:
            # Two live sources of one sysid: a duplicate route, a misconfigured second vehicle
            # or a forger. Keep the first; never flip-flop commands between them.
            self._inconsistent(
                v, now_s, "%s from %s while %s is live; kept %s", kind, addr, v.addr, v.addr
            )
            return False
        if (
            kind != "HEARTBEAT"
            or not self._is_vehicle_heartbeat(msg)
            or (self._identity_changed(v, msg) and not v.lost)
        ):
            self._inconsistent(
                v,
                now_s,
                "%s from %s, not its address %s (silent %.1f s)",
                kind,
                addr,
                v.addr,
                now_s - v.addr_heard_s,
            )
            return False
        log.info(
            "link %d sysid %d: moved from %s to %s (old address silent %.1f s)",
            self.link_id,
            v.sysid,
            v.addr,
            addr,
            now_s - v.addr_heard_s,
        )
        v.addr, v.addr_heard_s = addr, now_s  # a reboot or a NAT rebinding
        return True

    def _discover(self, msg: Any, addr: Addr, now_s: float) -> None:
        sysid = msg.get_srcSystem()
        adapter = adapter_for(msg.autopilot)
        v = _Vehicle(
            sysid,
            addr,
            msg.autopilot,
            msg.type,
            adapter,
            msg.custom_mode,
            msg.base_mode,
            now_s,
            addr_heard_s=now_s,
        )
        v.last_msg_s[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = now_s
        self._vehicles[sysid] = v
        self._wake(now_s + self.config.vehicle_timeout_s)
        self._emit(
            VehicleDiscovered(
                self.link_id,
                sysid,
                now_s,
                msg.autopilot,
                msg.type,
                msg.custom_mode,
                adapter.mode_name(msg.custom_mode),
                v.armed,
            )
        )
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
                self._inconsistent(
                    v,
                    now_s,
                    "HEARTBEAT with autopilot %d type %d, but it is autopilot %d type %d",
                    msg.autopilot,
                    msg.type,
                    v.autopilot,
                    v.vehicle_type,
                )
                return
            # Silent for a whole timeout, then back as something else: re-flashed or replaced.
            log.warning(
                "link %d sysid %d: back as autopilot %d type %d (was %d type %d)",
                self.link_id,
                sysid,
                msg.autopilot,
                msg.type,
                v.autopilot,
                v.vehicle_type,
            )
            v.autopilot, v.adapter = msg.autopilot, adapter_for(msg.autopilot)
        v.last_msg_s[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = now_s
        was_lost, silent_s = v.lost, now_s - v.last_heartbeat_s
        v.last_heartbeat_s = now_s
        was_armed, old_mode = v.armed, v.custom_mode
        v.custom_mode, v.base_mode, v.vehicle_type = msg.custom_mode, msg.base_mode, msg.type
        if was_lost:
            v.lost = False
            self._wake(now_s + self.config.vehicle_timeout_s)
            self._emit(
                VehicleRecovered(
                    self.link_id,
                    sysid,
                    now_s,
                    silent_s,
                    v.custom_mode,
                    v.adapter.mode_name(v.custom_mode),
                )
            )
            self._send(self._heartbeat_msg(), addr, now_s)
            self._request_streams(v, now_s)  # it may have rebooted and forgotten our rates
            self._request_home(v, now_s)
            v.disable_tries.clear()  # ... and our stops: a reboot restores the default streams
            v.disable_queue.clear()
        if old_mode != v.custom_mode:
            self._emit(
                ModeChanged(
                    self.link_id,
                    sysid,
                    now_s,
                    v.custom_mode,
                    v.adapter.mode_name(v.custom_mode),
                    v.adapter.mode_name(old_mode),
                )
            )
        if was_armed != v.armed:
            self._emit(ArmedChanged(self.link_id, sysid, now_s, v.armed))
            if v.armed:
                # Both autopilots move home to where they arm (ArduCopter AP_Arming_Copter::arm
                # set_home_to_current_location; PX4 Commander::set_home_position on arming):
                # ask for the new one rather than wait for the next unsolicited message.
                self._request_home(v, now_s)

    # ------------------------------------------------------------------ task systems

    def _on_task_message(self, msg: Any, addr: Addr, now_s: float) -> None:
        """A task system: its position, and a position stream request while none arrives."""
        sysid = msg.get_srcSystem()
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            if msg.lat == 0 and msg.lon == 0:  # no fix yet
                self.stats.invalid_telemetry += 1
                return
            try:
                ev = TaskPositionReceived(
                    self.link_id,
                    sysid,
                    now_s,
                    lat_deg=wire.e7_to_deg(msg.lat),
                    lon_deg=wire.e7_to_deg(msg.lon),
                    alt_amsl_m=wire.mm_to_m(msg.alt),
                )
            except ValueError:
                self.stats.invalid_telemetry += 1
                return
            self._task_fix_s[sysid] = now_s
            self._emit(ev)
        elif kind == "HEARTBEAT":
            self.stats.task_heartbeats += 1
            last_fix = self._task_fix_s.get(sysid, -math.inf)
            last_req = self._task_request_s.get(sysid, -math.inf)
            if (
                now_s - last_fix > self.config.telemetry_stale_s
                and now_s - last_req >= self.config.telemetry_stale_s
            ):
                self._task_request_s[sysid] = now_s
                self._request_task_position(sysid, msg.get_srcComponent(), addr, now_s)
        else:
            self.stats.ignored_messages += 1

    def _request_task_position(self, sysid: int, compid: int, addr: Addr, now_s: float) -> None:
        """Fire-and-forget: trackers differ (an ArduPilot Rover streams only when asked; a plain
        tracker streams anyway and ignores both). No ACK is awaited: a task is never commanded."""
        hz = self.config.task_position_rate_hz
        self._send(
            mavlink.MAVLink_command_long_message(
                sysid,
                compid,
                mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                0,
                mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                wire.hz_to_interval_us(hz),
                0,
                0,
                0,
                0,
                0,
            ),
            addr,
            now_s,
        )
        self._send(
            mavlink.MAVLink_request_data_stream_message(
                sysid, compid, mavlink.MAV_DATA_STREAM_POSITION, max(1, int(round(hz))), 1
            ),
            addr,
            now_s,
        )

    # ------------------------------------------------------------------ what a vehicle reports

    def _on_global_position(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        if msg.lat == 0 and msg.lon == 0:  # ArduPilot before a GPS fix
            self.stats.invalid_telemetry += 1
            return
        try:
            ev = TelemetryReceived(
                self.link_id,
                v.sysid,
                now_s,
                lat_deg=wire.e7_to_deg(msg.lat),
                lon_deg=wire.e7_to_deg(msg.lon),
                alt_amsl_m=wire.mm_to_m(msg.alt),
                rel_alt_m=wire.mm_to_m(msg.relative_alt),
                vel_ned_m_s=(
                    wire.cm_s_to_m_s(msg.vx),
                    wire.cm_s_to_m_s(msg.vy),
                    wire.cm_s_to_m_s(msg.vz),
                ),
                yaw_rad=wire.hdg_cdeg_to_yaw_rad(msg.hdg),
                time_boot_s=msg.time_boot_ms / 1000.0,
            )
        except ValueError:
            self.stats.invalid_telemetry += 1
            return
        if ev.time_boot_s < v.time_boot_s - REBOOT_CLOCK_JUMP_S:
            # Its clock went back: power-cycled (a battery swap, docs/design/endurance.md §1) or
            # rebooted. The same (link, sysid) is the same vehicle: say so before the report.
            log.info(
                "link %d sysid %d: rebooted (clock %.1f s -> %.1f s)",
                self.link_id,
                v.sysid,
                v.time_boot_s,
                ev.time_boot_s,
            )
            self._emit(VehicleRebooted(self.link_id, v.sysid, now_s, v.time_boot_s, ev.time_boot_s))
            v.seq.reset()  # its sequence numbers start again too
            if not v.lost:  # a reboot faster than the loss timeout forgot our rates and home too
                self._request_streams(v, now_s)
                self._request_home(v, now_s)
                v.disable_tries.clear()
                v.disable_queue.clear()
        v.time_boot_s = ev.time_boot_s
        v.position = ev
        self._emit(ev)

    # ------------------------------------------------------------------ batteries

    def _battery_ignored(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        # Without battery telemetry: exactly what an unhandled message gets.
        self.stats.ignored_messages += 1
        if self.config.disable_unused_messages:
            self._note_unused(v, msg.get_msgId(), now_s)

    def _on_sys_status(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        """SYS_STATUS's battery fields (common.xml): the autopilot's main battery; its sensor
        masks go to :mod:`gcs.link_health`."""
        self._on_sensors(v, msg, now_s)
        if not (self.config.battery_telemetry or self.config.health_telemetry):
            self._battery_ignored(v, msg, now_s)
            return
        self._emit_converted(sys_status_battery, v, msg, now_s)

    def _on_battery_status(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        """BATTERY_STATUS of battery 0 (common.xml): consumed charge, the autopilot's own time
        remaining and charge state (other ids: a second pack, not the one the plan follows)."""
        if not self.config.battery_telemetry:
            self._battery_ignored(v, msg, now_s)
            return
        if msg.id != 0:
            self.stats.ignored_messages += 1
            return
        try:
            ev = BatteryReceived(
                self.link_id,
                v.sysid,
                now_s,
                source="BATTERY_STATUS",
                remaining_frac=wire.battery_remaining_to_frac(msg.battery_remaining),
                voltage_v=wire.battery_mv_to_v(msg.voltages[0]),
                current_a=wire.battery_ca_to_a(msg.current_battery),
                consumed_mah=wire.battery_consumed_mah(msg.current_consumed),
                time_remaining_s=wire.battery_time_remaining_s(
                    getattr(msg, "time_remaining", 0) or 0
                ),
                charge_state=int(getattr(msg, "charge_state", 0) or 0),
            )
        except ValueError:
            self.stats.invalid_telemetry += 1
            return
        self._emit(ev)

    def _on_home_position(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        if msg.latitude == 0 and msg.longitude == 0:  # no home yet
            self.stats.invalid_telemetry += 1
            return
        try:
            ev = HomePositionReceived(
                self.link_id,
                v.sysid,
                now_s,
                lat_deg=wire.e7_to_deg(msg.latitude),
                lon_deg=wire.e7_to_deg(msg.longitude),
                alt_amsl_m=wire.mm_to_m(msg.altitude),
            )
        except ValueError:
            self.stats.invalid_telemetry += 1
            return
        v.home_request_s = math.inf
        old = v.home
        v.home = ev
        if old is None or (old.lat_deg, old.lon_deg, old.alt_amsl_m) != (
            ev.lat_deg,
            ev.lon_deg,
            ev.alt_amsl_m,
        ):
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
        if any(
            c is not None and c.internal is not None
            for c in (self._commands.get(key), *self._queued.get(key, ()))
        ):
            return  # already asked and waiting
        cmd = self._new_command(v.sysid, command, params, use_int=False)
        cmd.internal = lambda result, t_s, v=v: self._on_home_request_result(v, result, t_s)
        self._submit(cmd, now_s)

    def _on_home_request_result(self, v: _Vehicle, result: int | None, now_s: float) -> None:
        if result == mavlink.MAV_RESULT_UNSUPPORTED and not v.home_by_get_home:
            v.home_by_get_home = True
        elif result not in (None, mavlink.MAV_RESULT_ACCEPTED):
            log.debug(
                "link %d sysid %d: HOME_POSITION request refused (%s)",
                self.link_id,
                v.sysid,
                _result_name(result),
            )
        if v.home is None or result != mavlink.MAV_RESULT_ACCEPTED:
            # The message follows the ACK; if it never comes, ask again later.
            v.home_request_s = now_s + self.config.home_request_period_s
            self._wake(v.home_request_s)

    def _on_statustext(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        text = msg.text
        if isinstance(text, bytes):
            text = text.decode("utf-8", errors="replace")
        self._emit(StatusText(self.link_id, v.sysid, now_s, int(msg.severity), text.rstrip("\x00")))

"""Vehicle actions for :class:`gcs.link.StationLink`: modes, arming, RTL, land, takeoff through
the autopilot adapter's commands (:mod:`gcs.autopilot`), and the position target the link keeps
re-sending (SET_POSITION_TARGET_GLOBAL_INT).
"""

from __future__ import annotations

import math
from typing import Any

from gcs import wire
from gcs.events import CommandFailed
from gcs.link_commands import CommandTracker
from gcs.link_state import LinkUsageError, _Vehicle
from gcs.wire import mavlink

__all__ = ["VehicleActions"]

#: The commands the autopilot adapters send for a flight (gcs.autopilot: modes, RTL and LAND as
#: modes, arm / disarm, take-off): what :meth:`VehicleActions.withdraw_flight_commands` stops.
_FLIGHT_COMMANDS = frozenset(
    {mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_CMD_NAV_TAKEOFF}
)


class VehicleActions(CommandTracker):
    """Actions and setpoints (a mixin of :class:`gcs.link.StationLink`)."""

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
            self.set_position_target(
                sysid, v.position.lat_deg, v.position.lon_deg, alt_above_home_m, now_s
            )
            self.engage_guided(sysid, now_s)
            return self.arm(sysid, now_s)
        spec = v.adapter.takeoff(alt_above_home_m)
        assert spec is not None
        return self._send_spec(sysid, spec, now_s)

    def set_position_target(
        self,
        sysid: int,
        lat_deg: float,
        lon_deg: float,
        alt_m: float,
        now_s: float,
        *,
        frame: int | None = None,
    ) -> None:
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
        # Validate now (a local error) rather than at the next resend: build the message.
        msg = wire.position_target_global_int(
            target_system=sysid,
            lat_deg=lat_deg,
            lon_deg=lon_deg,
            alt_m=alt_m,
            frame=fr,
            time_boot_s=now_s - self._t0_s,
        )
        if v.setpoint is None:
            v.setpoint_since_s = now_s
        v.setpoint = (float(lat_deg), float(lon_deg), float(alt_m), fr)
        if not (type(lat_deg) is float and type(lon_deg) is float and type(alt_m) is float):
            msg = None  # built from other number types: _send_setpoint's own, from v.setpoint
        self._send_setpoint(v, now_s, msg)

    def clear_position_target(self, sysid: int, now_s: float) -> None:
        """Stop re-sending the position target (commands waiting for the pre-stream fail)."""
        v = self._get(sysid)
        v.setpoint, v.setpoint_next_s, v.setpoint_since_s = None, math.inf, math.nan
        for cmd in v.deferred:
            self._emit(
                CommandFailed(
                    self.link_id,
                    sysid,
                    now_s,
                    cmd.command,
                    cmd.request_id,
                    None,
                    "setpoint stream stopped before it was long enough",
                )
            )
        v.deferred = []

    def withdraw_flight_commands(self, sysid: int, now_s: float, reason: str) -> int:
        """Stop re-sending this station's mode, arm / disarm and take-off commands to ``sysid``
        (in flight or queued): each fails now with ``reason`` (CommandFailed). Someone else took
        the vehicle (a forwarded client's override, gcs.forward): a retry of ours must not undo
        it. Returns how many were withdrawn."""
        self._get(sysid)
        n = 0
        for key in [k for k in self._commands if k[0] == sysid and k[1] in _FLIGHT_COMMANDS]:
            queued = self._queued.pop(key, None) or ()
            for cmd in (self._commands.pop(key), *queued):  # never internal (stream) ones
                n += 1
                self._emit(
                    CommandFailed(
                        self.link_id, sysid, now_s, cmd.command, cmd.request_id, None, reason
                    )
                )
        return n

    def _send_setpoint(self, v: _Vehicle, now_s: float, msg: Any = None) -> None:
        """Send ``v.setpoint`` (``msg``: that very message, already built from the same floats
        at ``now_s``) and schedule the next re-send."""
        assert v.setpoint is not None
        if msg is None:
            lat, lon, alt, frame = v.setpoint
            msg = wire.position_target_global_int(
                target_system=v.sysid,
                lat_deg=lat,
                lon_deg=lon,
                alt_m=alt,
                frame=frame,
                time_boot_s=now_s - self._t0_s,
            )
        self._send(msg, v.addr, now_s)
        v.setpoint_next_s = now_s + v.adapter.setpoint_period_s
        self._wake(v.setpoint_next_s)

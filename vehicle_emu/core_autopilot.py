"""The autopilot rules of :class:`vehicle_emu.link.VehicleCore` that both firmwares share: the
timers (auto-disarm, takeoff progress, RTL, the GCS failsafe) and the state transitions (arm,
disarm, enter a mode). What differs between firmwares is asked of the personality
(``self.pers``, :mod:`vehicle_emu.personality`).
"""

from __future__ import annotations

import logging
import math

from planner.geometry import DOWN, EAST, NORTH

from . import events as ev
from .core_state import CoreState
from .wire import dialect as mavlink

__all__ = ["AutopilotRules"]

#: The core's log lines keep the logger they always had (the core was one module).
log = logging.getLogger("vehicle_emu.link")


class AutopilotRules(CoreState):
    """Timers and state transitions (a mixin of :class:`vehicle_emu.link.VehicleCore`)."""

    # -- timers (before the physics step) ----------------------------------------------------------

    def update_autopilot(self, now_s: float) -> None:
        """Mode state machines, timeouts and failsafes, before the physics step.

        Called for every vehicle on every tick, and most ticks find nothing to do: each check
        below reads the state it needs first and writes only what changes (a write of the value
        already there is skipped), with the outcome of the straightforward sequence of checks.
        """
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
        elif self._landed_armed_since_s is not None:
            self._landed_armed_since_s = None
        if not landed and self.armed:
            self._has_taken_off = True

        beh = self._behaviour
        # Takeoff progress (ArduPilot guided takeoff, PX4 AUTO.TAKEOFF).
        if self._takeoff_target_down_m is not None:
            if abs(ph.pos_ned_m[i, DOWN] - self._takeoff_target_down_m) < 0.3:
                self._takeoff_target_down_m = None
                self.pers.on_takeoff_reached(now_s, beh)
            elif not self.armed:
                self._takeoff_target_down_m = None

        if beh == "guided":
            # ArduPilot GUID_TIMEOUT on velocity targets; PX4 offboard signal loss.
            self.pers.guided_watchdog(now_s, beh)
        elif beh == "rtl":
            self._run_rtl(now_s)
        elif beh == "land":
            if landed and self.armed:
                # ArduCopter land mode disarms on touchdown; PX4 AUTO.LAND likewise.
                self._disarm(now_s, "landed")

        self._missions.update(now_s)
        if self.terrain_db is not None:  # ArduPilot's terrain protocol (core_terrain)
            self._terrain_tick(now_s)
        self.pers.update(now_s)
        if self._last_gcs_hb_s is not None:
            self._check_gcs_link(now_s)
        if self.batt is not None:  # the firmware's battery failsafes (vehicle_emu.battery_monitor)
            self.batt.update(now_s)

    def _gcs_failsafe_config(self) -> tuple[bool, float]:
        """``pers.gcs_failsafe_config()``, kept until the parameter table changes (its stamp:
        any PARAM_SET, any ``params.set``, another table)."""
        stamp = self.params.stamp
        if self._gcs_fs_stamp != stamp:
            self._gcs_fs_config = self.pers.gcs_failsafe_config()
            self._gcs_fs_stamp = stamp
        return self._gcs_fs_config

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
        enabled, timeout = self._gcs_failsafe_config()
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
            severity, text = self.pers.gcs_regained_text  # each firmware's words
            if text:
                self._statustext(now_s, severity, text)

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
                ph.command_position(
                    i, (home[NORTH], home[EAST], home[DOWN] - self._rtl_hover_alt_m)
                )
                self._rtl_phase = "hover"
            else:
                ph.command_land(i)
                self._rtl_phase = "land"
        elif phase == "land" and ph.landed[i]:
            self._disarm(now_s, "landed")

    # -- state transitions -------------------------------------------------------------------------

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

    def _set_mode(self, key: int, now_s: float, reason: str) -> bool:
        """Enter a mode (by custom_mode value); returns False for unknown modes."""
        info = self.pers.mode_info(key)
        if info is None:
            return False
        name, beh = info
        if key == self._mode_key:
            # Re-selecting the current mode changes nothing: ArduCopter ``Copter::set_mode``
            # (ArduCopter/mode.cpp) returns true "immediately if we are already in the desired
            # mode", without re-initialising it; PX4's navigator runs a mode's on_activation only
            # when the navigation state changes (src/modules/navigator/navigator_main.cpp,
            # Navigator::run). So a GCS's retried DO_SET_MODE(GUIDED) during a take-off climb
            # does not stop the climb (docs/design/mavlink.md §3).
            return True
        ph, i = self.physics, self.index
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
            self._rtl_dest_ned_m = self.pers.rtl_destination_ned_m(now_s)
        elif beh == "land":
            ph.command_land(i)
        elif beh == "guided" and self.pers.resume_offboard(now_s):
            pass  # PX4 flies the setpoint it kept
        elif beh != "takeoff":
            ph.hold(i)
        self._events.append(ev.ModeChanged(self.sysid, now_s, name, key, reason))
        return True

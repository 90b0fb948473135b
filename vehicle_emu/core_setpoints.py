"""SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT for :class:`vehicle_emu.link.VehicleCore`: frames,
type masks, the firmware's refusals (asked of the personality) and flying an accepted target.
"""

from __future__ import annotations

import math

import numpy as np

from mavedge.setpoints import POS_BITS as _POS_BITS
from mavedge.setpoints import VEL_BITS as _VEL_BITS

from .core_autopilot import AutopilotRules
from .personality.base import LOCAL_FRAMES as _LOCAL_FRAMES
from .personality.base import TERRAIN_FRAMES
from .wire import dialect as mavlink

__all__ = ["SetpointHandlers"]


class SetpointHandlers(AutopilotRules):
    """Position / velocity targets (a mixin of :class:`vehicle_emu.link.VehicleCore`)."""

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
                pos = self.home_ned_m + (x, y, z)  # LOCAL_NED is relative to the EKF origin
            else:
                pos = ph.pos_ned_m[i] + (x, y, z)  # offset and body frames: relative to vehicle
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
            if self.pers.terrain_setpoint_needs_estimate and m.coordinate_frame in TERRAIN_FRAMES:
                self.stats.setpoints_ignored += 1
                return
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
        isfinite = math.isfinite  # on the (3,) vectors: np.all(np.isfinite(...)), per element
        if (
            pos is not None and not (isfinite(pos[0]) and isfinite(pos[1]) and isfinite(pos[2]))
        ) or (vel is not None and not (isfinite(vel[0]) and isfinite(vel[1]) and isfinite(vel[2]))):
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

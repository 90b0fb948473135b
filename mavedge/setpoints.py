"""SET_POSITION_TARGET_* type_mask constants and message builders.

Bits are *ignore* flags (pymavlink's ``POSITION_TARGET_TYPEMASK`` enum): 0-2 position, 3-5
velocity, 6-8 acceleration, 9 force, 10 yaw, 11 yaw rate. Values match ardupilot_wiki
copter-commands-in-guided-mode.rst (docs/design/mavlink.md §1.4). Never mask a single axis:
ArduCopter GCS_Mavlink.cpp tests
``type_mask & POS_IGNORE`` with POS_IGNORE = X|Y|Z, so masking only Z drops the whole position;
PX4 mavlink_receiver.cpp ignores a whole vector group if any bit in it is set (mavros#402).
"""

from __future__ import annotations

import math
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .units import deg_to_e7, s_to_time_boot_ms

__all__ = [
    "POS_BITS",
    "VEL_BITS",
    "ACC_BITS",
    "FORCE_BIT",
    "YAW_BIT",
    "YAW_RATE_BIT",
    "TYPE_MASK_POSITION",
    "TYPE_MASK_VELOCITY",
    "TYPE_MASK_POSITION_VELOCITY",
    "TYPE_MASK_ACCELERATION_LOCAL",
    "TYPE_MASK_ACCELERATION_GLOBAL",
    "TYPE_MASK_POSITION_VELOCITY_ACCELERATION",
    "TYPE_MASK_YAW",
    "TYPE_MASK_YAW_RATE",
    "TYPE_MASK_POSITION_YAW",
    "position_target_global_int",
    "position_target_local_ned",
]

_M = mavlink
POS_BITS = (
    _M.POSITION_TARGET_TYPEMASK_X_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_Z_IGNORE
)  # 0b111
VEL_BITS = (
    _M.POSITION_TARGET_TYPEMASK_VX_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_VY_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_VZ_IGNORE
)  # 0b111 << 3
ACC_BITS = (
    _M.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | _M.POSITION_TARGET_TYPEMASK_AZ_IGNORE
)  # 0b111 << 6
FORCE_BIT = _M.POSITION_TARGET_TYPEMASK_FORCE_SET  # 1 << 9
YAW_BIT = _M.POSITION_TARGET_TYPEMASK_YAW_IGNORE  # 1 << 10
YAW_RATE_BIT = _M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE  # 1 << 11

TYPE_MASK_POSITION = VEL_BITS | ACC_BITS | YAW_BIT | YAW_RATE_BIT  # 0x0DF8 = 3576
TYPE_MASK_VELOCITY = POS_BITS | ACC_BITS | YAW_BIT | YAW_RATE_BIT  # 0x0DC7 = 3527
TYPE_MASK_POSITION_VELOCITY = ACC_BITS | YAW_BIT | YAW_RATE_BIT  # 0x0DC0 = 3520
TYPE_MASK_ACCELERATION_LOCAL = POS_BITS | VEL_BITS | YAW_BIT | YAW_RATE_BIT  # 0x0C3F = 3135
TYPE_MASK_ACCELERATION_GLOBAL = 0x0C38  # 3128, as the wiki gives it (x/y/z position unmasked)
TYPE_MASK_POSITION_VELOCITY_ACCELERATION = YAW_BIT | YAW_RATE_BIT  # 0x0C00 = 3072
TYPE_MASK_YAW = POS_BITS | VEL_BITS | ACC_BITS | YAW_RATE_BIT  # 0x09FF = 2559
TYPE_MASK_YAW_RATE = POS_BITS | VEL_BITS | ACC_BITS | YAW_BIT  # 0x05FF = 1535
TYPE_MASK_POSITION_YAW = VEL_BITS | ACC_BITS | YAW_RATE_BIT  # 0x09F8 = 2552


def _mask(vel: tuple[float, float, float] | None, yaw_rad: float | None) -> int:
    mask = TYPE_MASK_POSITION if vel is None else TYPE_MASK_POSITION_VELOCITY
    if yaw_rad is not None:
        mask &= ~YAW_BIT
    return mask


def position_target_global_int(
    *,
    target_system: int,
    lat_deg: float,
    lon_deg: float,
    alt_m: float,
    frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    time_boot_s: float = 0.0,
    target_component: int = 1,
    vel_ned_m_s: tuple[float, float, float] | None = None,
    yaw_rad: float | None = None,
) -> Any:
    """A SET_POSITION_TARGET_GLOBAL_INT message with the right type_mask.

    ``alt_m`` is interpreted by ``frame``: above home for GLOBAL_RELATIVE_ALT_INT (6, default),
    AMSL for GLOBAL_INT (5). The mask is position only (3576), position + velocity (3520) when
    ``vel_ned_m_s`` is given, position + yaw (2552) when ``yaw_rad`` is given.
    """
    if not all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_m)):
        raise ValueError(f"position target must be finite: {lat_deg=}, {lon_deg=}, {alt_m=}")
    mask = _mask(vel_ned_m_s, yaw_rad)
    vx, vy, vz = vel_ned_m_s if vel_ned_m_s is not None else (0.0, 0.0, 0.0)
    return mavlink.MAVLink_set_position_target_global_int_message(
        s_to_time_boot_ms(time_boot_s),
        target_system,
        target_component,
        frame,
        mask,
        deg_to_e7(lat_deg),
        deg_to_e7(lon_deg),
        float(alt_m),
        vx,
        vy,
        vz,
        0.0,
        0.0,
        0.0,
        float(yaw_rad or 0.0),
        0.0,
    )


def position_target_local_ned(
    *,
    target_system: int,
    pos_ned_m: tuple[float, float, float],
    frame: int = mavlink.MAV_FRAME_LOCAL_NED,
    time_boot_s: float = 0.0,
    target_component: int = 1,
    vel_ned_m_s: tuple[float, float, float] | None = None,
    yaw_rad: float | None = None,
) -> Any:
    """A SET_POSITION_TARGET_LOCAL_NED message (``pos_ned_m`` in *that vehicle's* local frame)."""
    x, y, z = (float(v) for v in pos_ned_m)
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise ValueError(f"position target must be finite: {pos_ned_m=}")
    mask = _mask(vel_ned_m_s, yaw_rad)
    vx, vy, vz = vel_ned_m_s if vel_ned_m_s is not None else (0.0, 0.0, 0.0)
    return mavlink.MAVLink_set_position_target_local_ned_message(
        s_to_time_boot_ms(time_boot_s),
        target_system,
        target_component,
        frame,
        mask,
        x,
        y,
        z,
        vx,
        vy,
        vz,
        0.0,
        0.0,
        0.0,
        float(yaw_rad or 0.0),
        0.0,
    )

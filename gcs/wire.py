"""The station's view of :mod:`mavedge`, the one MAVLink edge shared with the emulator.

Kept so that ``from gcs.wire import mavlink`` and ``from gcs import wire`` keep working; the
converters, codec (with the corrected signature check), parameter encoding and type masks live
in :mod:`mavedge` (issue 13.1).
"""

from __future__ import annotations

from mavedge import mavlink
from mavedge.codec import Codec, Decoder, DecodeStats, RawFrame
from mavedge.params import (
    decode_param_value,
    encode_param_value,
    is_int_param_type,
    param_id_to_str,
    param_values_equal,
)
from mavedge.setpoints import (
    TYPE_MASK_ACCELERATION_GLOBAL,
    TYPE_MASK_ACCELERATION_LOCAL,
    TYPE_MASK_POSITION,
    TYPE_MASK_POSITION_VELOCITY,
    TYPE_MASK_POSITION_VELOCITY_ACCELERATION,
    TYPE_MASK_POSITION_YAW,
    TYPE_MASK_VELOCITY,
    TYPE_MASK_YAW,
    TYPE_MASK_YAW_RATE,
    position_target_global_int,
    position_target_local_ned,
)
from mavedge.units import (
    cm_s_to_m_s,
    deg_to_e7,
    e7_to_deg,
    hdg_cdeg_to_yaw_rad,
    hz_to_interval_us,
    m_s_to_cm_s,
    m_to_mm,
    mm_to_m,
    s_to_time_boot_ms,
    yaw_rad_to_hdg_cdeg,
)

__all__ = [
    "mavlink",
    "Codec",
    "Decoder",
    "DecodeStats",
    "RawFrame",
    "deg_to_e7",
    "e7_to_deg",
    "m_to_mm",
    "mm_to_m",
    "m_s_to_cm_s",
    "cm_s_to_m_s",
    "hdg_cdeg_to_yaw_rad",
    "yaw_rad_to_hdg_cdeg",
    "s_to_time_boot_ms",
    "hz_to_interval_us",
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
    "param_id_to_str",
    "decode_param_value",
    "encode_param_value",
    "param_values_equal",
    "is_int_param_type",
]

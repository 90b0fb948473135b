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
    "battery_remaining_to_frac",
    "battery_mv_to_v",
    "battery_ca_to_a",
    "battery_consumed_mah",
    "battery_time_remaining_s",
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
    "satellites_or_none",
    "dop_or_none",
    "rssi_or_none",
]


# Battery fields of SYS_STATUS / BATTERY_STATUS (message definitions in common.xml): each wire
# integer has an "unknown" value, returned as None so it can never pass for a measurement.


def battery_remaining_to_frac(percent: int) -> float | None:
    """``battery_remaining`` (int8 %, -1 unknown) -> fraction in [0, 1] or None."""
    if percent < 0 or percent > 100:
        return None
    return percent / 100.0


def battery_mv_to_v(mv: int) -> float | None:
    """``voltage_battery`` / ``voltages[0]`` (uint16 mV, UINT16_MAX unknown) -> volts or None."""
    if mv < 0 or mv >= 0xFFFF:
        return None
    return mv / 1000.0


def battery_ca_to_a(ca: int) -> float | None:
    """``current_battery`` (int16 cA, -1 unknown) -> amperes or None."""
    if ca == -1:
        return None
    return ca / 100.0


def battery_consumed_mah(mah: int) -> float | None:
    """``current_consumed`` (int32 mAh, -1 unknown) -> mAh or None."""
    if mah < 0:
        return None
    return float(mah)


def battery_time_remaining_s(s: int) -> float | None:
    """``time_remaining`` (int32 s, 0 not provided) -> seconds or None."""
    if s <= 0:
        return None
    return float(s)


def satellites_or_none(n: int) -> int | None:
    """GPS_RAW_INT ``satellites_visible``: UINT8_MAX (255) is "unknown" (common.xml)."""
    return None if n == 255 else int(n)


def dop_or_none(cdop: int) -> float | None:
    """GPS_RAW_INT ``eph`` / ``epv``: dilution of precision x 100; UINT16_MAX is "unknown"."""
    return None if cdop == 65535 else cdop / 100.0


def rssi_or_none(value: int) -> int | None:
    """RADIO_STATUS ``rssi`` / ``remrssi`` / ``noise``: 255 (UINT8_MAX) is "unknown"
    (common.xml, RADIO_STATUS)."""
    return None if value == 255 else int(value)

"""SI <-> MAVLink wire units: every scale factor in one screen (docs/design/architecture.md §4).

Rounding is to nearest (not truncation), so a value survives encode -> decode within half a
wire unit. Saturation rules, the same for the station and the emulator:

* ``degE7`` (lat/lon, int32): clamped to the int32 range ``[-2**31, 2**31 - 1]``; a non-finite
  angle is ``INT32_MAX``, the value MAVLink uses for "unknown / not given" in int32 lat/lon
  fields (common.xml COMMAND_INT x/y, and PX4 mavlink_receiver.cpp
  ``handle_message_command_int`` reads it as such). Real coordinates never come near the bounds
  (|lon| <= 1.8e9 < 2**31 - 1); the clamp only keeps garbage from raising in ``struct.pack``.
* velocities in cm/s (int16, GLOBAL_POSITION_INT.vx/vy/vz): saturated *symmetrically* at
  +-32767. Neither firmware saturates (ArduPilot GCS_Common.cpp
  ``GCS_MAVLINK::send_global_position_int`` and PX4 src/modules/mavlink/streams/
  GLOBAL_POSITION_INT.hpp both assign ``vel * 100`` to the int16 field, a C conversion that
  wraps), so a wrapped sign would be a firmware artefact nobody wants reproduced; we keep
  ``v -> -v`` exact on the wire, which -32768 would break.
* millimetres (int32): clamped to int32.
* headings in cdeg (uint16): 0..35999; unknown (None or non-finite) is ``UINT16_MAX``
  (common.xml GLOBAL_POSITION_INT.hdg).
"""

from __future__ import annotations

import math
from typing import SupportsFloat

__all__ = [
    "INT32_MIN",
    "INT32_MAX",
    "INT16_MAX",
    "UINT16_MAX",
    "deg_to_e7",
    "e7_to_deg",
    "m_to_mm",
    "mm_to_m",
    "m_s_to_cm_s",
    "cm_s_to_m_s",
    "hdg_cdeg_to_yaw_rad",
    "yaw_rad_to_hdg_cdeg",
    "s_to_time_boot_ms",
    "s_to_time_usec",
    "s_to_time_ns",
    "hz_to_interval_us",
    "SIGNING_EPOCH_UNIX_S",
    "signing_timestamp_from_s",
]

INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
INT16_MAX = 2**15 - 1
UINT16_MAX = 0xFFFF


def deg_to_e7(deg: SupportsFloat) -> int:
    """Degrees to ``degE7`` (int32, clamped; non-finite -> INT32_MAX). 47.5 -> 475000000."""
    deg = float(deg)
    if not math.isfinite(deg):
        return INT32_MAX
    v = int(round(deg * 1e7))
    return INT32_MIN if v < INT32_MIN else (INT32_MAX if v > INT32_MAX else v)


def e7_to_deg(e7: int) -> float:
    """``degE7`` to degrees."""
    return int(e7) / 1e7


def m_to_mm(m: float) -> int:
    """Metres to millimetres (int32, clamped). 12.34 -> 12340."""
    v = int(round(float(m) * 1000.0))
    return INT32_MIN if v < INT32_MIN else (INT32_MAX if v > INT32_MAX else v)


def mm_to_m(mm: int) -> float:
    return int(mm) / 1000.0


def m_s_to_cm_s(m_s: float) -> int:
    """m/s to cm/s (int16), saturated symmetrically at +-32767 (module docstring)."""
    v = int(round(float(m_s) * 100.0))
    return INT16_MAX if v > INT16_MAX else (-INT16_MAX if v < -INT16_MAX else v)


def cm_s_to_m_s(cm_s: int) -> float:
    return int(cm_s) / 100.0


def yaw_rad_to_hdg_cdeg(yaw_rad: float | None) -> int:
    """Yaw (rad, 0 = north, clockwise) to centidegrees 0..35999; None/non-finite -> UINT16_MAX."""
    if yaw_rad is None or not math.isfinite(yaw_rad):
        return UINT16_MAX
    return int(round(math.degrees(yaw_rad) * 100.0)) % 36000


def hdg_cdeg_to_yaw_rad(hdg_cdeg: int) -> float | None:
    """Heading (cdeg, UINT16_MAX = unknown) to yaw in (-pi, pi]; None when unknown."""
    if int(hdg_cdeg) == UINT16_MAX:
        return None
    yaw = math.radians(int(hdg_cdeg) / 100.0)
    return yaw - 2 * math.pi if yaw > math.pi else yaw


def s_to_time_boot_ms(t_s: float) -> int:
    """Seconds since boot to ``time_boot_ms`` (uint32, wraps after ~49.7 days like firmware)."""
    return int(t_s * 1000.0) & 0xFFFFFFFF


def s_to_time_usec(t_s: float) -> int:
    """Seconds to uint64 microseconds (negative -> 0)."""
    return max(0, int(t_s * 1e6))


def s_to_time_ns(t_s: float) -> int:
    """Seconds to int64 nanoseconds (TIMESYNC tc1/ts1)."""
    return int(t_s * 1e9)


def hz_to_interval_us(rate_hz: float) -> float:
    """Rate to MAV_CMD_SET_MESSAGE_INTERVAL param2: interval in us, -1 = off (rate <= 0)."""
    return -1.0 if rate_hz <= 0 else float(round(1e6 / rate_hz))


#: MAVLink signing timestamps count 10 us units since 2015-01-01T00:00:00Z
#: (mavlink.io/en/guide/message_signing.html).
SIGNING_EPOCH_UNIX_S = 1420070400


def signing_timestamp_from_s(unix_s: float) -> int:
    """Unix seconds to the 48-bit signing timestamp (10 us units since 2015-01-01)."""
    return max(0, int((unix_s - SIGNING_EPOCH_UNIX_S) * 1e5)) & 0xFFFFFFFFFFFF

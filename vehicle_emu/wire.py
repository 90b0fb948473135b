"""The emulator's view of :mod:`mavedge`, the one MAVLink edge shared with the station.

Everything inside the emulator is SI; the wire integers exist only in :mod:`mavedge`. This
module keeps the emulator's historical names (``lat_e7_from_deg`` ...) as aliases of the shared
converters so that ``from vehicle_emu import wire`` keeps working (issue 13.1).
"""

from __future__ import annotations

from mavedge import mavlink as dialect
from mavedge.codec import DecodeResult, frame_target_system, split_frames
from mavedge.codec import VehicleCodec as Codec
from mavedge.params import INT_PARAM_TYPES, param_from_wire_float, param_to_wire_float
from mavedge.units import (
    deg_to_e7,
    e7_to_deg,
    m_s_to_cm_s,
    m_to_mm,
    mm_to_m,
    s_to_time_boot_ms,
    s_to_time_ns,
    s_to_time_usec,
    signing_timestamp_from_s,
    yaw_rad_to_hdg_cdeg,
)

__all__ = [
    "dialect",
    "Codec",
    "DecodeResult",
    "lat_e7_from_deg",
    "deg_from_lat_e7",
    "alt_mm_from_m",
    "m_from_alt_mm",
    "cm_s_from_m_s",
    "hdg_cdeg_from_rad",
    "cdeg_from_rad_unsigned",
    "time_boot_ms_from_s",
    "time_usec_from_s",
    "time_ns_from_s",
    "param_to_wire_float",
    "param_from_wire_float",
    "signing_timestamp_from_s",
    "INT_PARAM_TYPES",
    "split_frames",
    "frame_target_system",
]

lat_e7_from_deg = deg_to_e7
deg_from_lat_e7 = e7_to_deg
alt_mm_from_m = m_to_mm
m_from_alt_mm = mm_to_m
cm_s_from_m_s = m_s_to_cm_s
hdg_cdeg_from_rad = yaw_rad_to_hdg_cdeg
cdeg_from_rad_unsigned = yaw_rad_to_hdg_cdeg
time_boot_ms_from_s = s_to_time_boot_ms
time_usec_from_s = s_to_time_usec
time_ns_from_s = s_to_time_ns

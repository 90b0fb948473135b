"""PARAM_VALUE / PARAM_SET value encoding (one float field for every parameter type).

Two encodings exist (mavlink.io/en/services/parameter.html#parameter-encoding), announced in
AUTOPILOT_VERSION.capabilities:

* C-cast (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST, ArduPilot): integers travel as the
  float of the same value; ArduPilot casts the float back to the parameter's own type
  (libraries/GCS_MAVLink/GCS_Param.cpp ``GCS_MAVLINK::handle_param_set`` ->
  ``AP_Param::set_float``).
* byte-wise (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE, PX4): the parameter's own bytes
  are copied into the float's four bytes, the C ``mavlink_param_union_t`` layout: an INT8 -1 is
  ``ff 00 00 00`` (its one byte in the lowest byte, the rest zero), not ``ff ff ff ff``; a
  UINT32 above 2**31 keeps its unsigned bit pattern. PX4 src/modules/mavlink/
  mavlink_parameters.cpp ``MavlinkParametersManager::send_param`` zero-initialises the message
  (``mavlink_param_value_t msg{}``) and copies ``param_size(param)`` bytes of the value into
  ``msg.param_value`` (``memcpy`` for a one-byte BOOL, ``param_get`` for its 4-byte INT32),
  and PARAM_SET is applied by copying the float's bytes back (``param_set(param,
  &(set.param_value))``) once ``param_type`` matches the parameter's own.
  Decoding reads the type's own low bytes and ignores the rest.

An earlier emulator copy packed every integer as int32 (sign-extended small types and raised on
UINT32 > 2**31); PX4 only has INT32 and FLOAT so both agree there, and per-type packing is what
the union, QGC and MAVSDK do for the other types.
"""

from __future__ import annotations

import math
import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .units import INT32_MAX, INT32_MIN

__all__ = [
    "INT_PARAM_TYPES",
    "is_int_param_type",
    "param_id_to_str",
    "encode_param_value",
    "decode_param_value",
    "param_values_equal",
    "param_to_wire_float",
    "param_from_wire_float",
]

_FMT = {
    mavlink.MAV_PARAM_TYPE_UINT8: "<B",
    mavlink.MAV_PARAM_TYPE_INT8: "<b",
    mavlink.MAV_PARAM_TYPE_UINT16: "<H",
    mavlink.MAV_PARAM_TYPE_INT16: "<h",
    mavlink.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink.MAV_PARAM_TYPE_INT32: "<i",
}
_RANGE = {
    mavlink.MAV_PARAM_TYPE_UINT8: (0, 0xFF),
    mavlink.MAV_PARAM_TYPE_INT8: (-128, 127),
    mavlink.MAV_PARAM_TYPE_UINT16: (0, 0xFFFF),
    mavlink.MAV_PARAM_TYPE_INT16: (-32768, 32767),
    mavlink.MAV_PARAM_TYPE_UINT32: (0, 0xFFFFFFFF),
    mavlink.MAV_PARAM_TYPE_INT32: (INT32_MIN, INT32_MAX),
}
INT_PARAM_TYPES = frozenset(_FMT)
"""MAV_PARAM_TYPE values that are integers of at most 32 bits."""


def is_int_param_type(param_type: int) -> bool:
    return param_type in _FMT


def param_id_to_str(param_id: bytes | str) -> str:
    """PARAM_VALUE.param_id (bytes or str, NUL padded, 16 chars max) to a clean name."""
    if isinstance(param_id, bytes):
        param_id = param_id.decode("ascii", errors="replace")
    return str(param_id).split("\x00", 1)[0]


def encode_param_value(value: float, param_type: int, *, bytewise: bool) -> float:
    """The param_value float that carries ``value`` of ``param_type``.

    Integers are rounded and must fit the type (``ValueError`` otherwise, and for non-finite
    values); REAL32 travels as itself.
    """
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"parameter value must be finite, got {value}")
    fmt = _FMT.get(param_type)
    if fmt is None:
        return value
    iv = int(round(value))
    lo, hi = _RANGE[param_type]
    if not lo <= iv <= hi:
        raise ValueError(f"{iv} does not fit MAV_PARAM_TYPE {param_type}")
    if not bytewise:
        return float(iv)
    return struct.unpack("<f", struct.pack(fmt, iv).ljust(4, b"\x00"))[0]


def decode_param_value(value: float, param_type: int, *, bytewise: bool) -> float:
    """The number a param_value float means (inverse of :func:`encode_param_value`).

    C-cast integers come back as sent (not rounded: the station compares echoes itself).
    """
    fmt = _FMT.get(param_type)
    if not bytewise or fmt is None:
        return float(value)
    raw = struct.pack("<f", value)
    return float(struct.unpack(fmt, raw[: struct.calcsize(fmt)])[0])


def param_values_equal(a: float, b: float, param_type: int) -> bool:
    """Whether a PARAM_VALUE echo ``b`` confirms a set to ``a`` (integers exactly; REAL32 to
    float32 precision, as ArduPilot and PX4 store it)."""
    if param_type in _FMT:
        return int(round(a)) == int(round(b))
    return abs(a - b) <= max(1e-6, 1e-5 * abs(a))


def param_to_wire_float(value: float, param_type: int, bytewise: bool) -> float:
    """A vehicle's stored value to PARAM_VALUE.param_value (:func:`encode_param_value`)."""
    return encode_param_value(value, param_type, bytewise=bytewise)


def param_from_wire_float(wire_value: float, param_type: int, bytewise: bool) -> float:
    """PARAM_SET.param_value to the value a vehicle stores.

    Integer types: byte-wise per type; C-cast rounded to the nearest integer (``ValueError``
    for a non-finite value, which no integer parameter can hold). REAL32 as sent.
    """
    if param_type in _FMT:
        if bytewise:
            return decode_param_value(wire_value, param_type, bytewise=True)
        if not math.isfinite(wire_value):
            raise ValueError("non-finite integer parameter")
        return float(int(round(wire_value)))
    return float(wire_value)

"""The station's MAVLink codec: pymavlink message classes, our own framing state, wire <-> SI.

Everything that knows a wire integer (``lat_e7``, ``alt_mm``, ``vx_cm_s``, ``hdg_cdeg``,
``time_boot_ms``) lives here, each behind one named converter (docs/design/architecture.md §4). The pymavlink
``MAVLink`` object (sequence counter, signing state, parser buffer) is private to this module;
``mavutil`` is never imported: it reads ``MAVLINK20``/``MAVLINK_DIALECT`` from the environment at
import time and its ``udpin`` mode sends every packet to every peer (docs/design/mavlink.md §5.3).

Decoding is robust: bad bytes on a lossy radio are *expected* (docs/design/architecture.md §7) and become
counters in :class:`DecodeStats`, never exceptions.
"""

from __future__ import annotations

import hashlib
import logging
import math
import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = [
    "mavlink", "Codec", "Decoder", "DecodeStats", "RawFrame",
    "deg_to_e7", "e7_to_deg", "m_to_mm", "mm_to_m", "m_s_to_cm_s", "cm_s_to_m_s",
    "hdg_cdeg_to_yaw_rad", "yaw_rad_to_hdg_cdeg", "s_to_time_boot_ms", "hz_to_interval_us",
    "TYPE_MASK_POSITION", "TYPE_MASK_VELOCITY", "TYPE_MASK_POSITION_VELOCITY",
    "TYPE_MASK_ACCELERATION_LOCAL", "TYPE_MASK_ACCELERATION_GLOBAL",
    "TYPE_MASK_POSITION_VELOCITY_ACCELERATION", "TYPE_MASK_YAW", "TYPE_MASK_YAW_RATE",
    "TYPE_MASK_POSITION_YAW",
    "position_target_global_int", "position_target_local_ned",
    "param_id_to_str", "decode_param_value", "encode_param_value", "param_values_equal",
    "is_int_param_type",
]

log = logging.getLogger(__name__)

# --------------------------------------------------------------------------------------------
# Wire <-> SI converters. Rounding (not truncation) keeps the round trip within half a unit.
# --------------------------------------------------------------------------------------------

_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1
_UINT16_MAX = 0xFFFF


def _clamp_int32(v: int) -> int:
    return max(_INT32_MIN, min(_INT32_MAX, v))


def deg_to_e7(deg: float) -> int:
    """Degrees to MAVLink ``degE7`` (int32). ``47.5`` -> ``475000000``."""
    return _clamp_int32(int(round(float(deg) * 1e7)))


def e7_to_deg(e7: int) -> float:
    """MAVLink ``degE7`` to degrees."""
    return int(e7) / 1e7


def m_to_mm(m: float) -> int:
    """Metres to millimetres (int32). ``12.34`` -> ``12340``."""
    return _clamp_int32(int(round(float(m) * 1000.0)))


def mm_to_m(mm: int) -> float:
    return int(mm) / 1000.0


def m_s_to_cm_s(m_s: float) -> int:
    """Metres per second to cm/s, clamped to int16 (GLOBAL_POSITION_INT.vx/vy/vz)."""
    return max(-32768, min(32767, int(round(float(m_s) * 100.0))))


def cm_s_to_m_s(cm_s: int) -> float:
    return int(cm_s) / 100.0


def hdg_cdeg_to_yaw_rad(hdg_cdeg: int) -> float | None:
    """GLOBAL_POSITION_INT.hdg (centidegrees, 0..35999, UINT16_MAX = unknown) to yaw in (-pi, pi].

    Returns None when the vehicle reports the heading as unknown.
    """
    if int(hdg_cdeg) == _UINT16_MAX:
        return None
    yaw = math.radians(int(hdg_cdeg) / 100.0)
    return yaw - 2 * math.pi if yaw > math.pi else yaw


def yaw_rad_to_hdg_cdeg(yaw_rad: float | None) -> int:
    """Yaw (rad, 0 = north, clockwise) to centidegrees 0..35999; None -> UINT16_MAX (unknown)."""
    if yaw_rad is None or not math.isfinite(yaw_rad):
        return _UINT16_MAX
    return int(round(math.degrees(yaw_rad) * 100.0)) % 36000


def s_to_time_boot_ms(t_s: float) -> int:
    """Seconds since our boot to ``time_boot_ms`` (uint32, wraps after ~49.7 days)."""
    return int(t_s * 1000.0) & 0xFFFFFFFF


def hz_to_interval_us(rate_hz: float) -> float:
    """Rate to MAV_CMD_SET_MESSAGE_INTERVAL param2: interval in us, -1 = off (rate <= 0)."""
    return -1.0 if rate_hz <= 0 else float(round(1e6 / rate_hz))


# --------------------------------------------------------------------------------------------
# SET_POSITION_TARGET_* type_mask. Bits are *ignore* flags: 0-2 position, 3-5 velocity,
# 6-8 acceleration, 9 force, 10 yaw, 11 yaw rate. Values from ardupilot_wiki
# copter-commands-in-guided-mode.rst (docs/design/mavlink.md §1.4). Never mask a single axis: ArduCopter
# drops the whole position if Z is ignored (Skybrush driver.py), PX4 ignores a whole vector group
# if any bit in it is set (mavros#402).
# --------------------------------------------------------------------------------------------

TYPE_MASK_POSITION = 0x0DF8                      # 3576: position only
TYPE_MASK_VELOCITY = 0x0DC7                      # 3527: velocity only
TYPE_MASK_POSITION_VELOCITY = 0x0DC0             # 3520: position + velocity feed-forward
TYPE_MASK_ACCELERATION_LOCAL = 0x0C3F            # 3135
TYPE_MASK_ACCELERATION_GLOBAL = 0x0C38           # 3128 (as the wiki gives it)
TYPE_MASK_POSITION_VELOCITY_ACCELERATION = 0x0C00  # 3072
TYPE_MASK_YAW = 0x09FF                           # 2559
TYPE_MASK_YAW_RATE = 0x05FF                      # 1535
TYPE_MASK_POSITION_YAW = 0x09F8                  # 2552: position + yaw (what MAVSDK sends)

_IGNORE_POS_Z = 1 << 2


def position_target_global_int(*, target_system: int, lat_deg: float, lon_deg: float, alt_m: float,
                               frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                               time_boot_s: float = 0.0, target_component: int = 1,
                               vel_ned_m_s: tuple[float, float, float] | None = None,
                               yaw_rad: float | None = None):
    """A SET_POSITION_TARGET_GLOBAL_INT message with the right type_mask.

    ``alt_m`` is interpreted by ``frame``: above home for GLOBAL_RELATIVE_ALT_INT (6, default),
    AMSL for GLOBAL_INT (5). The mask is position only (3576), position + velocity (3520) when
    ``vel_ned_m_s`` is given, position + yaw (2552) when ``yaw_rad`` is given.
    """
    if not all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_m)):
        raise ValueError(f"position target must be finite: {lat_deg=}, {lon_deg=}, {alt_m=}")
    mask = TYPE_MASK_POSITION if vel_ned_m_s is None else TYPE_MASK_POSITION_VELOCITY
    if yaw_rad is not None:
        mask &= ~(1 << 10)
    assert not mask & _IGNORE_POS_Z
    vx, vy, vz = vel_ned_m_s if vel_ned_m_s is not None else (0.0, 0.0, 0.0)
    return mavlink.MAVLink_set_position_target_global_int_message(
        s_to_time_boot_ms(time_boot_s), target_system, target_component, frame, mask,
        deg_to_e7(lat_deg), deg_to_e7(lon_deg), float(alt_m), vx, vy, vz, 0.0, 0.0, 0.0,
        float(yaw_rad or 0.0), 0.0)


def position_target_local_ned(*, target_system: int, pos_ned_m: tuple[float, float, float],
                              frame: int = mavlink.MAV_FRAME_LOCAL_NED, time_boot_s: float = 0.0,
                              target_component: int = 1,
                              vel_ned_m_s: tuple[float, float, float] | None = None,
                              yaw_rad: float | None = None):
    """A SET_POSITION_TARGET_LOCAL_NED message (``pos_ned_m`` in *that vehicle's* local frame)."""
    x, y, z = (float(v) for v in pos_ned_m)
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise ValueError(f"position target must be finite: {pos_ned_m=}")
    mask = TYPE_MASK_POSITION if vel_ned_m_s is None else TYPE_MASK_POSITION_VELOCITY
    if yaw_rad is not None:
        mask &= ~(1 << 10)
    vx, vy, vz = vel_ned_m_s if vel_ned_m_s is not None else (0.0, 0.0, 0.0)
    return mavlink.MAVLink_set_position_target_local_ned_message(
        s_to_time_boot_ms(time_boot_s), target_system, target_component, frame, mask,
        x, y, z, vx, vy, vz, 0.0, 0.0, 0.0, float(yaw_rad or 0.0), 0.0)


# --------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------

_INT_PARAM_TYPES = {
    mavlink.MAV_PARAM_TYPE_UINT8: "<B", mavlink.MAV_PARAM_TYPE_INT8: "<b",
    mavlink.MAV_PARAM_TYPE_UINT16: "<H", mavlink.MAV_PARAM_TYPE_INT16: "<h",
    mavlink.MAV_PARAM_TYPE_UINT32: "<I", mavlink.MAV_PARAM_TYPE_INT32: "<i",
}


def param_id_to_str(param_id) -> str:
    """PARAM_VALUE.param_id (bytes or str, NUL padded, 16 chars max) to a clean name."""
    if isinstance(param_id, bytes):
        param_id = param_id.decode("ascii", errors="replace")
    return param_id.split("\x00", 1)[0]


def decode_param_value(value: float, param_type: int, *, bytewise: bool) -> float:
    """PARAM_VALUE.param_value as the number the autopilot means.

    ArduPilot sends integers C-cast to float (``bytewise=False``); PX4 sends the integer's bytes
    inside the float (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE, ``bytewise=True``).
    """
    fmt = _INT_PARAM_TYPES.get(param_type)
    if not bytewise or fmt is None:
        return float(value)
    raw = struct.pack("<f", value)
    size = struct.calcsize(fmt)
    return float(struct.unpack(fmt, raw[:size])[0])


def encode_param_value(value: float, param_type: int, *, bytewise: bool) -> float:
    """The PARAM_SET.param_value float that makes the autopilot store ``value``.

    Inverse of :func:`decode_param_value`. ArduPilot casts the float to the parameter's own type
    (``AP_Param::set_float`` in libraries/GCS_MAVLink/GCS_Param.cpp ``handle_param_set``);
    PX4 copies the float's four bytes into the parameter (``param_set(param,
    &set.param_value)`` in src/modules/mavlink/mavlink_parameters.cpp), so an INT32 must travel
    as its bit pattern (``bytewise=True``). PX4 also refuses the set unless ``param_type``
    matches the parameter's own (INT32 with INT32, REAL32 with FLOAT): send the type the
    vehicle reported in PARAM_VALUE.
    """
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"parameter value must be finite, got {value}")
    fmt = _INT_PARAM_TYPES.get(param_type)
    if fmt is None:
        return value
    iv = int(round(value))
    lo, hi = _INT_RANGES[param_type]
    if not lo <= iv <= hi:
        raise ValueError(f"{iv} does not fit MAV_PARAM_TYPE {param_type}")
    if not bytewise:
        return float(iv)
    # The value in the low bytes (little-endian), the rest zero (MAVLink parameter protocol,
    # MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE; PX4 has INT32 and FLOAT only).
    return struct.unpack("<f", struct.pack(fmt, iv).ljust(4, b"\x00"))[0]


_INT_RANGES = {
    mavlink.MAV_PARAM_TYPE_UINT8: (0, 0xFF), mavlink.MAV_PARAM_TYPE_INT8: (-128, 127),
    mavlink.MAV_PARAM_TYPE_UINT16: (0, 0xFFFF), mavlink.MAV_PARAM_TYPE_INT16: (-32768, 32767),
    mavlink.MAV_PARAM_TYPE_UINT32: (0, 0xFFFFFFFF), mavlink.MAV_PARAM_TYPE_INT32: (_INT32_MIN,
                                                                                 _INT32_MAX),
}


def is_int_param_type(param_type: int) -> bool:
    return param_type in _INT_PARAM_TYPES


def param_values_equal(a: float, b: float, param_type: int) -> bool:
    """Whether a PARAM_VALUE echo ``b`` confirms a set to ``a`` (integers exactly; REAL32 to
    float32 precision, as ArduPilot and PX4 store it)."""
    if param_type in _INT_PARAM_TYPES:
        return int(round(a)) == int(round(b))
    return abs(a - b) <= max(1e-6, 1e-5 * abs(a))


# --------------------------------------------------------------------------------------------
# Codec
# --------------------------------------------------------------------------------------------

_SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01T00:00:00Z, the MAVLink signing epoch


class _NullFile:
    def write(self, _data) -> None:  # pymavlink's MAVLink wants a file; we never use it
        pass


class RawFrame:
    """A checked frame whose payload was not unpacked: the station does not use its message.

    CRC and signature are verified as for any frame; only the header is read (message id,
    sender, sequence), so it costs a fraction of a full decode. Same accessors as a pymavlink
    message for what the link layer reads (``get_type``, ``get_msgId``, ``get_srcSystem``,
    ``get_srcComponent``, ``get_seq``, ``get_msgbuf``), and no fields.
    """

    __slots__ = ("_msgid", "_name", "_sysid", "_compid", "_seq", "_buf")

    def __init__(self, msgid: int, name: str, sysid: int, compid: int, seq: int,
                 buf: bytes) -> None:
        self._msgid, self._name, self._sysid, self._compid = msgid, name, sysid, compid
        self._seq, self._buf = seq, buf

    def get_type(self) -> str:
        return self._name

    def get_msgId(self) -> int:  # noqa: N802 - pymavlink's spelling
        return self._msgid

    def get_srcSystem(self) -> int:  # noqa: N802
        return self._sysid

    def get_srcComponent(self) -> int:  # noqa: N802
        return self._compid

    def get_seq(self) -> int:
        return self._seq

    def get_msgbuf(self) -> bytes:
        return self._buf

    def __repr__(self) -> str:
        return f"RawFrame({self._name}, sysid={self._sysid}, compid={self._compid})"


class _MAVLink(mavlink.MAVLink):
    """pymavlink's parser with the signature check done in the C library's order, and frames
    of messages nobody reads left undecoded (:class:`RawFrame`).

    pymavlink 2.4.x ``MAVLink.check_signature`` stores a frame's timestamp as its stream's
    latest *before* comparing the signature, so one forged frame with a future timestamp (no key
    needed) makes every later genuine frame of that ``(link id, sysid, compid)`` stream look
    replayed: anyone on the radio can silence a vehicle. The C library (``mavlink_helpers.h``
    ``mavlink_signature_check``) updates the stream only once the signature matched, as here.
    Same logic as ``vehicle_emu/wire.py`` ``_MAVLink`` (the two packages never import each
    other; to be merged).
    """

    full_msgids: frozenset[int] | None = None
    """Message ids decoded into pymavlink objects; the others become RawFrame (None: all)."""

    def decode(self, msgbuf):
        full = self.full_msgids
        if full is not None and len(msgbuf) >= 10:
            if msgbuf[0] == mavlink.PROTOCOL_MARKER_V2:
                msgid = msgbuf[7] | (msgbuf[8] << 8) | (msgbuf[9] << 16)
            else:
                msgid = msgbuf[5]
            if msgid not in full and msgid in mavlink.mavlink_map:
                return self._decode_raw(msgbuf, msgid)
        return super().decode(msgbuf)

    def _decode_raw(self, msgbuf, msgid: int) -> RawFrame:
        """pymavlink ``MAVLink.decode`` up to and including the signature check, without the
        payload: the same frames are refused, with the same reasons."""
        if msgbuf[0] == mavlink.PROTOCOL_MARKER_V2:
            headerlen, incompat = 10, msgbuf[2]
            seq, sysid, compid = msgbuf[4], msgbuf[5], msgbuf[6]
        else:
            headerlen, incompat = 6, 0
            seq, sysid, compid = msgbuf[2], msgbuf[3], msgbuf[4]
        sig_len = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN if incompat & mavlink.MAVLINK_IFLAG_SIGNED \
            else 0
        if msgbuf[1] != len(msgbuf) - (headerlen + 2 + sig_len):
            raise mavlink.MAVError("invalid MAVLink message length")
        msgtype = mavlink.mavlink_map[msgid]
        end = len(msgbuf) - sig_len
        crc = msgbuf[end - 2] | (msgbuf[end - 1] << 8)
        crcbuf = msgbuf[1:end - 2]
        crcbuf.append(msgtype.crc_extra)
        if mavlink.x25crc(crcbuf).crc != crc:
            raise mavlink.MAVError(f"invalid MAVLink CRC in msgID {msgid}")
        signing = self.signing
        if signing.secret_key is not None:
            accept = bool(sig_len) and self.check_signature(msgbuf, sysid, compid)
            if not accept and signing.allow_unsigned_callback is not None:
                accept = signing.allow_unsigned_callback(self, msgid)
            if not accept:
                raise mavlink.MAVError("Invalid signature")
        return RawFrame(msgid, msgtype.msgname, sysid, compid, seq, bytes(msgbuf))

    def check_signature(self, msgbuf, srcSystem, srcComponent) -> bool:
        signing = self.signing
        link_id = msgbuf[-13]
        tlow, thigh = self.mav_sign_unpacker.unpack(msgbuf[-12:-6])
        timestamp = tlow + (thigh << 32)
        stream_key = (link_id, srcSystem, srcComponent)
        last = signing.stream_timestamps.get(stream_key)
        if last is not None:
            if timestamp <= last:
                return False  # replayed or out of order
        elif timestamp + 6000 * 1000 < signing.timestamp:
            return False  # a new stream more than a minute behind us
        h = hashlib.new("sha256")
        h.update(signing.secret_key)
        h.update(msgbuf[:-6])
        if h.digest()[:6] != msgbuf[-6:]:
            return False  # forged: remember nothing about it
        signing.stream_timestamps[stream_key] = timestamp
        signing.timestamp = max(signing.timestamp, timestamp)
        return True


@dataclass
class DecodeStats:
    """Counters for what came in; bad bytes become counts, never exceptions."""

    frames: int = 0
    """Frames decoded into known messages (raw frames included)."""
    raw_frames: int = 0
    """Of ``frames``: checked but not unpacked (:class:`RawFrame`), nobody reads them."""
    bad_data: int = 0
    """Bad prefixes, CRC or length errors, rejected signatures (pymavlink BAD_DATA)."""
    signature_rejected: int = 0
    """Of ``bad_data``: frames refused by MAVLink 2 signing (bad, replayed or missing)."""
    unknown_msgid: int = 0
    """Well-formed frames whose message id is not in the dialect."""
    truncated: int = 0
    """Datagrams ending in an incomplete frame (dropped)."""
    decoder_errors: int = 0
    """Unexpected exceptions inside pymavlink (parser reset)."""
    bytes_in: int = 0


class Decoder:
    """Parser state for one remote address (a stream or a sequence of datagrams)."""

    def __init__(self, stats: DecodeStats, signing_key: bytes | None = None,
                 accept_unsigned: bool = True,
                 full_msgids: frozenset[int] | None = None) -> None:
        self._stats = stats
        self._mav = _MAVLink(_NullFile(), 0, 0)
        self._mav.robust_parsing = True
        self._mav.full_msgids = full_msgids
        if signing_key is not None:
            self._mav.signing.secret_key = signing_key
            if accept_unsigned:
                self._mav.signing.allow_unsigned_callback = lambda _mav, _msgid: True

    def _reset(self) -> None:
        self._mav.buf = bytearray()
        self._mav.buf_index = 0
        self._mav.expected_length = mavlink.HEADER_LEN_V1 + 2

    def feed(self, data: bytes, *, datagram: bool = True) -> list:
        """Decode ``data``; return the good messages (pymavlink objects, or :class:`RawFrame`
        for ids outside the decoder's ``full_msgids``) in order.

        With ``datagram=True`` (UDP) an incomplete trailing frame is dropped and counted; with
        ``datagram=False`` (TCP, serial) it is kept for the next call.
        """
        self._stats.bytes_in += len(data)
        out = []
        try:
            msgs = self._mav.parse_buffer(data) or []
        except Exception:  # pymavlink bug or exotic input: count it, reset, carry on
            log.debug("decoder exception on %d bytes", len(data), exc_info=True)
            self._stats.decoder_errors += 1
            self._reset()
            return out
        for msg in msgs:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                self._stats.bad_data += 1
                if "signature" in str(getattr(msg, "reason", "")):
                    self._stats.signature_rejected += 1
            elif kind.startswith("UNKNOWN"):
                self._stats.unknown_msgid += 1
            else:
                self._stats.frames += 1
                if type(msg) is RawFrame:
                    self._stats.raw_frames += 1
                out.append(msg)
        if datagram and self._mav.buf_len() > 0:
            self._stats.truncated += 1
            self._reset()
        return out


class Codec:
    """Our side of the wire: encoder (seq, sysid/compid, optional signing) and decoder factory."""

    def __init__(self, sysid: int, compid: int, *, signing_key: bytes | None = None,
                 signing_link_id: int = 0, accept_unsigned: bool = True,
                 full_msgids: frozenset[int] | None = None) -> None:
        if signing_key is not None and len(signing_key) != 32:
            raise ValueError(f"signing_key must be 32 bytes, got {len(signing_key)}")
        self._mav = mavlink.MAVLink(_NullFile(), sysid, compid)
        self._signing_key = signing_key
        self._accept_unsigned = accept_unsigned
        self._full_msgids = full_msgids
        self.stats = DecodeStats()
        if signing_key is not None:
            self._mav.signing.secret_key = signing_key
            self._mav.signing.link_id = signing_link_id
            self._mav.signing.sign_outgoing = True

    @property
    def signing(self) -> bool:
        return self._signing_key is not None

    def set_signing_time(self, unix_time_s: float) -> None:
        """Advance the signing timestamp (10 us units since 2015-01-01); it never goes back."""
        ts = int((unix_time_s - _SIGNING_EPOCH_UNIX_S) * 1e5)
        self._mav.signing.timestamp = max(self._mav.signing.timestamp, ts)

    def encode(self, msg) -> bytes:
        """Pack one message as a MAVLink 2 frame with our ids and the next sequence number."""
        buf = msg.pack(self._mav)
        self._mav.seq = (self._mav.seq + 1) % 256
        return bytes(buf)

    def new_decoder(self) -> Decoder:
        return Decoder(self.stats, self._signing_key, self._accept_unsigned, self._full_msgids)

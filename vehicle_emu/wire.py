"""MAVLink 2 codec of the vehicle emulator: the only place that knows wire units.

Everything inside the emulator is SI (metres, seconds, radians, degrees only for geodetic
coordinates). The integer units of the wire (``lat_e7``, ``alt_mm``, ``vx_cm_s``, ``hdg_cdeg``,
``time_boot_ms`` ...) exist only here, each behind a named converter, so a reviewer can check
every scale factor in one screen (docs/design/architecture.md §4).

The pymavlink ``MAVLink`` object is private to :class:`Codec`. We import the generated dialect
module directly (``pymavlink.dialects.v20.ardupilotmega``) and never ``mavutil``: mavutil reads
``MAVLINK20``/``MAVLINK_DIALECT`` from the environment at import time and is built around files
and sockets (docs/design/mavlink.md §5.3).

Why one ``MAVLink`` instance per vehicle: pymavlink stamps ``seq``, ``srcSystem`` and the
signing state from the instance at ``pack`` time; sharing one instance between vehicles would
interleave their sequence numbers, which a GCS uses for per-vehicle loss statistics.
"""

from __future__ import annotations

import hashlib
import logging
import math
import struct
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as dialect

__all__ = [
    "dialect",
    "Codec",
    "DecodeResult",
    "lat_e7_from_deg", "deg_from_lat_e7",
    "alt_mm_from_m", "m_from_alt_mm",
    "cm_s_from_m_s", "hdg_cdeg_from_rad", "cdeg_from_rad_unsigned",
    "time_boot_ms_from_s", "time_usec_from_s", "time_ns_from_s",
    "param_to_wire_float", "param_from_wire_float",
    "signing_timestamp_from_s",
    "INT_PARAM_TYPES",
    "split_frames",
]

log = logging.getLogger(__name__)

# --------------------------------------------------------------------------------------------
# Named converters SI -> wire and back. Rounding is to nearest (not truncation) so that a value
# survives encode -> decode within half a wire unit; tests check that bound.
# --------------------------------------------------------------------------------------------

_INT32_MAX = 2**31 - 1
_INT16_MAX = 2**15 - 1


def lat_e7_from_deg(deg: float) -> int:
    """Degrees -> degE7 (int32), e.g. 47.5 -> 475000000."""
    return int(round(deg * 1e7))


def deg_from_lat_e7(lat_e7: int) -> float:
    """degE7 (int32) -> degrees."""
    return lat_e7 * 1e-7


def alt_mm_from_m(alt_m: float) -> int:
    """Metres -> millimetres (int32), e.g. 12.34 -> 12340."""
    return int(round(alt_m * 1000.0))


def m_from_alt_mm(alt_mm: int) -> float:
    """Millimetres -> metres."""
    return alt_mm * 1e-3


def cm_s_from_m_s(v_m_s: float) -> int:
    """m/s -> cm/s, saturated to int16 as GLOBAL_POSITION_INT.vx requires."""
    v = int(round(v_m_s * 100.0))
    return _INT16_MAX if v > _INT16_MAX else (-_INT16_MAX if v < -_INT16_MAX else v)


def hdg_cdeg_from_rad(yaw_rad: float) -> int:
    """Yaw (rad, 0 = north, clockwise) -> centidegrees 0..35999 (GLOBAL_POSITION_INT.hdg)."""
    if not math.isfinite(yaw_rad):
        return 65535  # UINT16_MAX: unknown, per the message definition
    return int(round(math.degrees(yaw_rad) * 100.0)) % 36000


def cdeg_from_rad_unsigned(angle_rad: float) -> int:
    """Course over ground (rad) -> centidegrees 0..35999 (GPS_RAW_INT.cog)."""
    return hdg_cdeg_from_rad(angle_rad)


def time_boot_ms_from_s(t_s: float) -> int:
    """Seconds since boot -> uint32 milliseconds (wraps after 49.7 days, like the firmware)."""
    return int(t_s * 1000.0) & 0xFFFFFFFF


def time_usec_from_s(t_s: float) -> int:
    """Seconds -> uint64 microseconds."""
    return max(0, int(t_s * 1e6))


def time_ns_from_s(t_s: float) -> int:
    """Seconds -> int64 nanoseconds (TIMESYNC tc1/ts1)."""
    return int(t_s * 1e9)


# MAVLink signing timestamps count 10 µs units since 2015-01-01 00:00:00 UTC
# (mavlink.io/en/guide/message_signing.html).
_SIGNING_EPOCH_UNIX_S = 1420070400.0


def signing_timestamp_from_s(unix_s: float) -> int:
    """Unix seconds -> 48-bit signing timestamp (10 µs units since 2015-01-01)."""
    return max(0, int((unix_s - _SIGNING_EPOCH_UNIX_S) * 1e5)) & 0xFFFFFFFFFFFF


INT_PARAM_TYPES = frozenset({
    dialect.MAV_PARAM_TYPE_UINT8, dialect.MAV_PARAM_TYPE_INT8, dialect.MAV_PARAM_TYPE_UINT16,
    dialect.MAV_PARAM_TYPE_INT16, dialect.MAV_PARAM_TYPE_UINT32, dialect.MAV_PARAM_TYPE_INT32,
})


def param_to_wire_float(value: float, param_type: int, bytewise: bool) -> float:
    """Parameter value -> PARAM_VALUE.param_value.

    ArduPilot sends every parameter C-cast to float (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST);
    PX4 copies the bytes of an int32 into the float field (PARAM_ENCODE_BYTEWISE,
    PX4 ``src/modules/mavlink/mavlink_parameters.cpp``). QGC/MAVSDK pick the decoding from the
    AUTOPILOT_VERSION capability bits, which :mod:`vehicle_emu.link` advertises accordingly.
    """
    if bytewise and param_type in INT_PARAM_TYPES:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def param_from_wire_float(wire_value: float, param_type: int, bytewise: bool) -> float:
    """PARAM_SET.param_value -> parameter value (inverse of :func:`param_to_wire_float`)."""
    if param_type in INT_PARAM_TYPES:
        if bytewise:
            return float(struct.unpack("<i", struct.pack("<f", wire_value))[0])
        if not math.isfinite(wire_value):
            raise ValueError("non-finite integer parameter")
        return float(int(round(wire_value)))
    return float(wire_value)


def split_frames(data: bytes) -> list[bytes]:
    """Split a datagram into raw MAVLink 2 / 1 frames by their headers, without CRC checks.

    Used by the multiplexing router to forward frames to the right vehicle core, which then
    decodes and verifies them. Garbage between frames is skipped; a truncated tail is dropped.
    """
    out = []
    i, n = 0, len(data)
    while i < n:
        b = data[i]
        if b == 0xFD:
            if i + 3 > n:
                break
            size = 12 + data[i + 1] + (13 if data[i + 2] & 0x01 else 0)
        elif b == 0xFE:
            if i + 2 > n:
                break
            size = 8 + data[i + 1]
        else:
            i += 1
            continue
        if i + size > n:
            break
        out.append(data[i:i + size])
        i += size
    return out


class _MAVLink(dialect.MAVLink):
    """pymavlink's MAVLink with a safer signature check.

    pymavlink 2.4.x ``check_signature`` stores the frame's timestamp as the stream's latest
    *before* verifying the signature, so one forged frame with a high timestamp makes every
    later genuine frame of that (link, sysid, compid) stream look replayed: a denial of service
    by anyone on the radio. The C library (``mavlink_helpers.h``
    ``mavlink_signature_check``) updates the stream only after the signature matched; we do the
    same.
    """

    def check_signature(self, msgbuf, srcSystem, srcComponent) -> bool:
        signing = self.signing
        link_id = msgbuf[-13]
        tlow, thigh = self.mav_sign_unpacker.unpack(msgbuf[-12:-6])
        timestamp = tlow + (thigh << 32)
        stream_key = (link_id, srcSystem, srcComponent)
        last = signing.stream_timestamps.get(stream_key)
        if last is not None:
            if timestamp <= last:
                return False
        elif timestamp + 6000 * 1000 < signing.timestamp:
            return False  # a new stream more than a minute behind us
        h = hashlib.new("sha256")
        h.update(signing.secret_key)
        h.update(msgbuf[:-6])
        if h.digest()[:6] != msgbuf[-6:]:
            return False
        signing.stream_timestamps[stream_key] = timestamp
        signing.timestamp = max(signing.timestamp, timestamp)
        return True


@dataclass
class DecodeResult:
    """What one datagram decoded to."""

    messages: list = field(default_factory=list)
    """Good messages (pymavlink message objects), in wire order."""
    n_bad: int = 0
    """Frames or byte runs that failed (bad prefix, CRC, length)."""
    n_unknown: int = 0
    """Frames with a valid header but a message id not in the dialect."""
    n_signature_rejected: int = 0
    """Frames dropped by MAVLink 2 signing (bad/missing signature, replayed timestamp)."""
    n_truncated_bytes: int = 0
    """Bytes left over at the end of the datagram (a truncated frame)."""


class Codec:
    """One vehicle's MAVLink 2 encoder/decoder (sequence numbers, signing state).

    Parameters
    ----------
    sysid, compid : int
        Our identity, stamped on every frame we send.
    signing_key : bytes, optional
        32-byte secret. With a key we sign everything we send and reject unsigned or badly signed
        input except the message ids in ``allow_unsigned_ids``.
    allow_unsigned_ids : frozenset of int
        Message ids accepted unsigned while signing is on. ArduPilot accepts only RADIO_STATUS
        and RADIO unsigned (``libraries/GCS_MAVLink/GCS_Signing.cpp``, accept_unsigned_callback);
        we also let SETUP_SIGNING through so that the link layer can decide on trust itself.
    link_id : int
        Signing link id (one per physical link).
    """

    def __init__(self, sysid: int, compid: int = 1, signing_key: bytes | None = None,
                 allow_unsigned_ids: frozenset = frozenset(), link_id: int = 0) -> None:
        if not 1 <= sysid <= 255:
            raise ValueError(f"sysid must be 1..255, got {sysid}")
        self._mav = _MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._mav.robust_parsing = True
        self._allow_unsigned_ids = frozenset(allow_unsigned_ids)
        self._mav.signing.link_id = link_id
        self.n_sent = 0
        self.set_signing_key(signing_key)

    # -- identity / signing -------------------------------------------------------------------

    @property
    def sysid(self) -> int:
        return self._mav.srcSystem

    @property
    def signing_enabled(self) -> bool:
        return self._mav.signing.secret_key is not None

    def set_signing_key(self, key: bytes | None, initial_timestamp: int = 0) -> None:
        """Install (or with ``None``/all-zero key remove) the signing secret."""
        signing = self._mav.signing
        if key is None or not any(key):
            # An all-zero key disables signing (mavlink.io message_signing, SETUP_SIGNING).
            signing.secret_key = None
            signing.sign_outgoing = False
            signing.allow_unsigned_callback = None
            return
        key = bytes(key)
        if len(key) != 32:
            raise ValueError(f"signing key must be 32 bytes, got {len(key)}")
        signing.secret_key = key
        signing.sign_outgoing = True
        allowed = self._allow_unsigned_ids
        signing.allow_unsigned_callback = lambda _mav, msg_id: msg_id in allowed
        signing.timestamp = max(signing.timestamp, int(initial_timestamp))

    def advance_signing_timestamp(self, timestamp: int) -> None:
        """Keep our signing timestamp at least ``timestamp`` (never goes backwards)."""
        if timestamp > self._mav.signing.timestamp:
            self._mav.signing.timestamp = timestamp

    # -- encode -------------------------------------------------------------------------------

    def encode(self, msg) -> bytes:
        """Pack one message with our seq and (if enabled) signature; advance seq."""
        mav = self._mav
        buf = msg.pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
        self.n_sent += 1
        return buf

    # -- decode -------------------------------------------------------------------------------

    def decode_datagram(self, data: bytes) -> DecodeResult:
        """Decode every frame in one datagram; never raises.

        A UDP datagram is a self-contained unit: bytes of a truncated frame at its end are
        counted and discarded rather than glued to the next datagram (which could fabricate a
        frame from two unrelated packets).
        """
        res = DecodeResult()
        mav = self._mav
        try:
            msgs = mav.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - remote bytes must never raise across the adapter
            log.debug("pymavlink raised on a datagram of %d bytes", len(data), exc_info=True)
            msgs = []
            res.n_bad += 1
        for m in msgs:
            t = m.get_type()
            if t == "BAD_DATA":
                reason = getattr(m, "reason", "")
                if "signature" in reason:
                    res.n_signature_rejected += 1
                else:
                    res.n_bad += 1
            elif t == "UNKNOWN" or t.startswith("UNKNOWN"):
                res.n_unknown += 1
            else:
                res.messages.append(m)
        leftover = len(mav.buf) - mav.buf_index
        if leftover > 0:
            res.n_truncated_bytes = leftover
        # Reset the parser between datagrams (see docstring).
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = dialect.HEADER_LEN_V1 + 2
        return res

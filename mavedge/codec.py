"""The MAVLink 2 codec of both sides: pymavlink's generated classes and parser, our framing state.

One ``MAVLink`` subclass (:class:`_MAVLink`) carries the two things we change in pymavlink:

* the signature check in the C library's order. pymavlink 2.4.x ``MAVLink.check_signature``
  stores a frame's timestamp as its stream's latest *before* comparing the signature, so one
  forged frame with a future timestamp (no key needed) makes every later genuine frame of that
  ``(link id, sysid, compid)`` stream look replayed: anyone on the radio can silence a link. The
  C library (``mavlink_helpers.h`` ``mavlink_signature_check``) updates the stream only once the
  signature matched, as here. (Both the station and the emulator carried a copy; this is the one.)
* frames of messages nobody reads left undecoded (:class:`RawFrame`, station only): CRC and
  signature are checked, the payload is not unpacked.

:class:`Codec` / :class:`Decoder` are the station's (a decoder per remote address, counters in
:class:`DecodeStats`); :class:`VehicleCodec` is one emulated vehicle's (one instance per vehicle:
pymavlink stamps ``seq``, ``srcSystem`` and signing from the instance, and a GCS keeps loss
statistics per sysid from ``seq``). :func:`split_frames` and :func:`frame_target_system` let a
multiplexing router send a frame to the addressed vehicle by reading its header and one payload
byte, so every frame is parsed (CRC, signature, unpack) once, by its receiver.

Bad bytes on a lossy radio are expected (docs/design/architecture.md §7) and become counters, never
exceptions.
"""

from __future__ import annotations

import hashlib
import logging
import operator
import re
import struct
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass, field
from typing import Any, NamedTuple, TypeVar

from fastcrc import crc16
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .units import signing_timestamp_from_s

__all__ = [
    "RawFrame",
    "DecodeStats",
    "Decoder",
    "Codec",
    "DecodeResult",
    "VehicleCodec",
    "split_frames",
    "frame_target_system",
    "coalesce_datagrams",
    "MAX_DATAGRAM_BYTES",
]

log = logging.getLogger(__name__)


class _NullFile:
    def write(self, _data: bytes) -> None:  # pymavlink's MAVLink wants a file; we never use it
        pass


class RawFrame:
    """A checked frame whose payload was not unpacked: the station does not use its message.

    Same accessors as a pymavlink message for what the link layer reads (``get_type``,
    ``get_msgId``, ``get_srcSystem``, ``get_srcComponent``, ``get_seq``, ``get_msgbuf``).
    """

    __slots__ = ("_msgid", "_name", "_sysid", "_compid", "_seq", "_buf")

    def __init__(
        self, msgid: int, name: str, sysid: int, compid: int, seq: int, buf: bytes
    ) -> None:
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


class _FastSpec(NamedTuple):
    """What :meth:`_MAVLink._decode_fast` needs of one message type."""

    cls: Any
    crc_extra: bytes
    size: int
    unpack: Callable[[bytes | bytearray], tuple[Any, ...]]
    order: Callable[[tuple[Any, ...]], tuple[Any, ...]]
    pack: Callable[..., bytes]
    wire_fields: Callable[[Any], tuple[Any, ...]]
    """The field values of a message in wire order (``ordered_fieldnames``), for ``pack``."""


def _fast_specs() -> dict[int, _FastSpec]:
    """The message types whose pymavlink decode is a plain unpack and reorder: no arrays and
    no strings (those need pymavlink's list building and NUL stripping; they keep its path)."""
    out = {}
    for msgid, cls in mavlink.mavlink_map.items():
        fmt = cls.unpacker.format
        if sum(cls.lengths) != len(cls.lengths) or "s" in fmt or "c" in fmt:
            continue
        orders = tuple(cls.orders)
        order = (
            operator.itemgetter(*orders) if len(orders) > 1 else (lambda t, _i=orders[0]: (t[_i],))
        )
        names = tuple(cls.ordered_fieldnames)
        wire_fields = (
            operator.attrgetter(*names)
            if len(names) > 1
            else (lambda m, _n=names[0]: (getattr(m, _n),))
        )
        out[msgid] = _FastSpec(
            cls,
            bytes((cls.crc_extra,)),
            cls.unpacker.size,
            cls.unpacker.unpack,
            order,
            cls.unpacker.pack,
            wire_fields,
        )
    return out


_FAST = _fast_specs()
_mcrf4xx = crc16.mcrf4xx  # CRC-16/MCRF4XX, the X.25 CRC pymavlink's x25crc computes with it


class _MAVLink(mavlink.MAVLink):  # type: ignore[misc]  # pymavlink is untyped
    """pymavlink's parser with the C library's signature check, optional raw frames and a
    fast path for well-formed unsigned frames (:meth:`_decode_fast`, :func:`_parse_datagram`)."""

    full_msgids: frozenset[int] | None = None
    """Message ids decoded into pymavlink objects; the others become RawFrame (None: all)."""

    def decode(self, msgbuf: bytearray) -> Any:
        full = self.full_msgids
        if len(msgbuf) >= 10:
            if msgbuf[0] == mavlink.PROTOCOL_MARKER_V2:
                msgid = msgbuf[7] | (msgbuf[8] << 8) | (msgbuf[9] << 16)
            else:
                msgid = msgbuf[5]
            if full is not None and msgid not in full and msgid in mavlink.mavlink_map:
                return self._decode_raw(msgbuf, msgid)
            if msgbuf[0] == mavlink.PROTOCOL_MARKER_V2 and not msgbuf[2]:
                m = self._decode_fast(msgbuf, msgid)
                if m is not None:
                    return m
        return super().decode(msgbuf)

    def _decode_fast(self, msgbuf: bytearray, msgid: int) -> Any:
        """pymavlink ``MAVLink.decode`` of an unsigned MAVLink 2 frame (incompat flags 0) of a
        :func:`_fast_specs` type, when its length and CRC are good and no signing key is set:
        the same message object, attribute for attribute (tests/mavedge/test_fast_decode.py),
        without the generic header, list and order handling. ``None`` for everything else
        (signing on, other types, bad length or CRC): pymavlink decodes it, or refuses it
        with its own reason."""
        spec = _FAST.get(msgid)
        if spec is None or self.signing.secret_key is not None:
            return None
        mlen = msgbuf[1]
        if mlen != len(msgbuf) - 12:
            return None
        crc = msgbuf[-2] | (msgbuf[-1] << 8)
        if _mcrf4xx(spec.crc_extra, _mcrf4xx(memoryview(msgbuf)[1:-2])) != crc:
            return None
        size = spec.size
        if mlen == size:
            payload = msgbuf[10:-2]
        elif mlen < size:  # MAVLink 2 trailing-zero truncation: pad back, as pymavlink does
            payload = msgbuf[10:-2] + bytes(size - mlen)
        else:  # longer than this dialect knows (newer extension fields): cut
            payload = msgbuf[10 : 10 + size]
        m = spec.cls(*spec.order(spec.unpack(payload)))
        m._signed = False
        m._msgbuf = msgbuf
        m._payload = msgbuf[6:-2]
        m._crc = crc
        m._header = mavlink.MAVLink_header(
            msgid, 0, msgbuf[3], mlen, msgbuf[4], msgbuf[5], msgbuf[6]
        )
        return m

    def _decode_raw(self, msgbuf: bytearray, msgid: int) -> RawFrame:
        """pymavlink ``MAVLink.decode`` up to and including the signature check, without the
        payload: the same frames are refused, with the same reasons."""
        if msgbuf[0] == mavlink.PROTOCOL_MARKER_V2:
            headerlen, incompat = 10, msgbuf[2]
            seq, sysid, compid = msgbuf[4], msgbuf[5], msgbuf[6]
        else:
            headerlen, incompat = 6, 0
            seq, sysid, compid = msgbuf[2], msgbuf[3], msgbuf[4]
        sig_len = (
            mavlink.MAVLINK_SIGNATURE_BLOCK_LEN if incompat & mavlink.MAVLINK_IFLAG_SIGNED else 0
        )
        if msgbuf[1] != len(msgbuf) - (headerlen + 2 + sig_len):
            raise mavlink.MAVError("invalid MAVLink message length")
        msgtype = mavlink.mavlink_map[msgid]
        end = len(msgbuf) - sig_len
        crc = msgbuf[end - 2] | (msgbuf[end - 1] << 8)
        crcbuf = msgbuf[1 : end - 2]
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

    def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:  # noqa: N803
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


_HEADER_V2 = struct.Struct("<BBBBBBBHB")


def _encode_fast(mav: mavlink.MAVLink, msg: Any) -> bytes | None:
    """pymavlink ``msg.pack(mav)`` (unsigned MAVLink 2) for a message of a :func:`_fast_specs`
    type: the same bytes (tests/mavedge/test_fast_decode.py), without building the header
    object and bytearrays pymavlink leaves on the message (nobody reads them on a message we
    send). ``None`` when signing or for other types: the caller packs with pymavlink."""
    spec = _FAST.get(msg.id)
    if spec is None or type(msg) is not spec.cls or mav.signing.sign_outgoing:
        return None
    payload = spec.pack(*spec.wire_fields(msg))
    # MAVLink 2 payload truncation (pymavlink MAVLink_message._pack): trailing zeros dropped,
    # at least one byte kept.
    payload = payload.rstrip(b"\0") or payload[:1]
    msgid = msg.id
    frame = (
        _HEADER_V2.pack(
            253,
            len(payload),
            0,
            0,
            mav.seq,
            mav.srcSystem,
            mav.srcComponent,
            msgid & 0xFFFF,
            msgid >> 16,
        )
        + payload
    )
    crc = _mcrf4xx(spec.crc_extra, _mcrf4xx(memoryview(frame)[1:]))
    return frame + crc.to_bytes(2, "little")


def _parse_datagram(mav: _MAVLink, data: bytes) -> list[Any] | None:
    """What ``mav.parse_buffer(data)`` returns (decoded messages and ``MAVLink_bad_data``, in
    order) for a datagram made of complete MAVLink 2 / 1 frames from its first byte to its
    last, with the parser empty; ``None`` (nothing done) for anything else: bytes before or
    between frames, a truncated tail, a parser holding bytes; the caller then runs
    ``parse_buffer``. Each frame is cut by the length the parser would read and decoded by
    ``mav.decode`` (its fast path for the common case), a refused one becoming the parser's
    BAD_DATA with the same reason. Exceptions other than ``MAVError`` propagate, as from
    ``parse_buffer``. pymavlink's own byte and packet counters are not advanced."""
    if len(mav.buf) != mav.buf_index:
        return None
    n = len(data)
    bounds = []
    i = 0
    while i < n:
        magic = data[i]
        if magic == 0xFD:
            if i + 3 > n or data[i + 2] & ~mavlink.MAVLINK_IFLAG_SIGNED:
                return None  # the parser's "invalid incompat_flags" (rare): its path
            size = 12 + data[i + 1] + (13 if data[i + 2] & mavlink.MAVLINK_IFLAG_SIGNED else 0)
        elif magic == 0xFE:
            if i + 3 > n:
                return None
            size = 8 + data[i + 1]
        else:
            return None
        if i + size > n:
            return None
        bounds.append((i, i + size))
        i += size
    out = []
    decode = mav.decode
    for a, b in bounds:
        frame = bytearray(data[a:b])
        try:
            out.append(decode(frame))
        except mavlink.MAVError as reason:
            out.append(mavlink.MAVLink_bad_data(frame, reason.message))
    return out


def _reset_parser(mav: mavlink.MAVLink) -> None:
    mav.buf = bytearray()
    mav.buf_index = 0
    mav.expected_length = mavlink.HEADER_LEN_V1 + 2


# --------------------------------------------------------------------------------------------
# Station side
# --------------------------------------------------------------------------------------------


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

    def __init__(
        self,
        stats: DecodeStats,
        signing_key: bytes | None = None,
        accept_unsigned: bool = True,
        full_msgids: frozenset[int] | None = None,
    ) -> None:
        self._stats = stats
        self._mav = _MAVLink(_NullFile(), 0, 0)
        self._mav.robust_parsing = True
        self._mav.full_msgids = full_msgids
        if signing_key is not None:
            self._mav.signing.secret_key = signing_key
            if accept_unsigned:
                self._mav.signing.allow_unsigned_callback = lambda _mav, _msgid: True

    def _reset(self) -> None:
        _reset_parser(self._mav)

    def feed(self, data: bytes, *, datagram: bool = True) -> list[Any]:
        """Decode ``data``; return the good messages (pymavlink objects, or :class:`RawFrame`
        for ids outside the decoder's ``full_msgids``) in order.

        With ``datagram=True`` (UDP) an incomplete trailing frame is dropped and counted; with
        ``datagram=False`` (TCP, serial) it is kept for the next call.
        """
        self._stats.bytes_in += len(data)
        out: list[Any] = []
        try:
            msgs = _parse_datagram(self._mav, data) if datagram else None
            if msgs is None:
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
    """The station's side of the wire: encoder (seq, sysid/compid, optional signing) and
    decoder factory."""

    def __init__(
        self,
        sysid: int,
        compid: int,
        *,
        signing_key: bytes | None = None,
        signing_link_id: int = 0,
        accept_unsigned: bool = True,
        full_msgids: frozenset[int] | None = None,
    ) -> None:
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
        ts = signing_timestamp_from_s(unix_time_s)
        self._mav.signing.timestamp = max(self._mav.signing.timestamp, ts)

    def encode(self, msg: Any) -> bytes:
        """Pack one message as a MAVLink 2 frame with our ids and the next sequence number."""
        buf = _encode_fast(self._mav, msg)
        if buf is None:
            buf = msg.pack(self._mav)
        self._mav.seq = (self._mav.seq + 1) % 256
        return bytes(buf)

    def new_decoder(self) -> Decoder:
        return Decoder(self.stats, self._signing_key, self._accept_unsigned, self._full_msgids)


# --------------------------------------------------------------------------------------------
# Vehicle side
# --------------------------------------------------------------------------------------------


@dataclass
class DecodeResult:
    """What one datagram decoded to."""

    messages: list[Any] = field(default_factory=list)
    """Good messages (pymavlink message objects), in wire order."""
    n_bad: int = 0
    """Frames or byte runs that failed (bad prefix, CRC, length)."""
    n_unknown: int = 0
    """Frames with a valid header but a message id not in the dialect."""
    n_signature_rejected: int = 0
    """Frames dropped by MAVLink 2 signing (bad/missing signature, replayed timestamp)."""
    n_truncated_bytes: int = 0
    """Bytes left over at the end of the datagram (a truncated frame)."""


class VehicleCodec:
    """One vehicle's MAVLink 2 encoder/decoder (sequence numbers, signing state).

    Parameters
    ----------
    sysid, compid : int
        Our identity, stamped on every frame we send.
    signing_key : bytes, optional
        32-byte secret. With a key we sign everything we send and reject unsigned or badly
        signed input except the message ids in ``allow_unsigned_ids``.
    allow_unsigned_ids : frozenset of int
        Message ids accepted unsigned while signing is on. ArduPilot accepts only RADIO_STATUS
        and RADIO unsigned (``libraries/GCS_MAVLink/GCS_Signing.cpp``,
        ``accept_unsigned_callback``); the emulator also lets SETUP_SIGNING through so that its
        link layer decides on trust itself.
    link_id : int
        Signing link id (one per physical link).
    """

    def __init__(
        self,
        sysid: int,
        compid: int = 1,
        signing_key: bytes | None = None,
        allow_unsigned_ids: frozenset[int] = frozenset(),
        link_id: int = 0,
    ) -> None:
        if not 1 <= sysid <= 255:
            raise ValueError(f"sysid must be 1..255, got {sysid}")
        self._mav = _MAVLink(_NullFile(), srcSystem=sysid, srcComponent=compid)
        self._mav.robust_parsing = True
        self._allow_unsigned_ids = frozenset(allow_unsigned_ids)
        self._mav.signing.link_id = link_id
        self.n_sent = 0
        #: A signing key is installed (kept by :meth:`set_signing_key`, the only way to set one;
        #: read for every vehicle on every telemetry tick, hence an attribute).
        self.signing_enabled = False
        self.set_signing_key(signing_key)

    @property
    def sysid(self) -> int:
        return self._mav.srcSystem

    @property
    def compid(self) -> int:
        return self._mav.srcComponent

    @property
    def seq(self) -> int:
        """Sequence number of the next frame we send."""
        return self._mav.seq

    def set_signing_key(self, key: bytes | None, initial_timestamp: int = 0) -> None:
        """Install (or with ``None``/all-zero key remove) the signing secret."""
        signing = self._mav.signing
        if key is None or not any(key):
            # An all-zero key disables signing (mavlink.io message_signing, SETUP_SIGNING).
            signing.secret_key = None
            signing.sign_outgoing = False
            signing.allow_unsigned_callback = None
            self.signing_enabled = False
            return
        key = bytes(key)
        if len(key) != 32:
            raise ValueError(f"signing key must be 32 bytes, got {len(key)}")
        signing.secret_key = key
        signing.sign_outgoing = True
        allowed = self._allow_unsigned_ids
        signing.allow_unsigned_callback = lambda _mav, msg_id: msg_id in allowed
        signing.timestamp = max(signing.timestamp, int(initial_timestamp))
        self.signing_enabled = True

    def advance_signing_timestamp(self, timestamp: int) -> None:
        """Keep our signing timestamp at least ``timestamp`` (never goes backwards)."""
        if timestamp > self._mav.signing.timestamp:
            self._mav.signing.timestamp = timestamp

    def encode(self, msg: Any) -> bytes:
        """Pack one message with our seq and (if enabled) signature; advance seq."""
        mav = self._mav
        buf = _encode_fast(mav, msg)
        if buf is None:
            buf = msg.pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
        self.n_sent += 1
        return buf

    def take_seq(self, n: int = 1) -> int:
        """Reserve ``n`` sequence numbers for frames packed elsewhere (a batch encoder);
        returns the first. Only valid while signing is off (signed frames go through
        :meth:`encode`)."""
        mav = self._mav
        s = mav.seq
        mav.seq = (s + n) & 0xFF
        self.n_sent += n
        return s

    def decode_datagram(self, data: bytes) -> DecodeResult:
        """Decode every frame in one datagram; never raises.

        A UDP datagram is a self-contained unit: bytes of a truncated frame at its end are
        counted and discarded rather than glued to the next datagram (which could fabricate a
        frame from two unrelated packets).
        """
        res = DecodeResult()
        mav = self._mav
        try:
            msgs = _parse_datagram(mav, data)
            if msgs is None:
                msgs = mav.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - remote bytes must never raise across the adapter
            log.debug("pymavlink raised on a datagram of %d bytes", len(data), exc_info=True)
            msgs = []
            res.n_bad += 1
        for m in msgs:
            t = m.get_type()
            if t == "BAD_DATA":
                if "signature" in getattr(m, "reason", ""):
                    res.n_signature_rejected += 1
                else:
                    res.n_bad += 1
            elif t.startswith("UNKNOWN"):
                res.n_unknown += 1
            else:
                res.messages.append(m)
        leftover = len(mav.buf) - mav.buf_index
        if leftover > 0:
            res.n_truncated_bytes = leftover
        _reset_parser(mav)
        return res


# --------------------------------------------------------------------------------------------
# Routing without parsing
# --------------------------------------------------------------------------------------------


def split_frames(data: bytes) -> list[bytes]:
    """Split a datagram into raw MAVLink 2 / 1 frames by their headers, without CRC checks.

    Garbage between frames is skipped; a truncated tail is dropped. The receiver of each frame
    decodes and verifies it.
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
        out.append(data[i : i + size])
        i += size
    return out


MAX_DATAGRAM_BYTES = 1200
"""Largest UDP datagram either side builds from several frames (below a 1,500-byte Ethernet MTU
with room for IP/UDP headers and tunnels)."""


_Dest = TypeVar("_Dest", bound=Hashable)


def coalesce_datagrams(
    datagrams: Iterable[tuple[_Dest, bytes]], max_bytes: int = MAX_DATAGRAM_BYTES
) -> list[tuple[_Dest, bytes]]:
    """``(destination, datagram)`` pairs with the datagrams of each destination joined into as
    few as fit in ``max_bytes`` (a datagram already larger goes alone).

    Every datagram holds whole MAVLink frames, so each joined one does too, and a receiver that
    splits datagrams into frames (both sides here, ArduPilot, PX4) sees the same frames in the
    same order from each destination's point of view; only the datagram boundaries change.
    Destinations come out in the order of their first datagram.
    """
    by_dest: dict[_Dest, list[bytes]] = {}
    for dest, data in datagrams:
        parts = by_dest.get(dest)
        if parts is None:
            by_dest[dest] = [data]
        else:
            parts.append(data)
    out: list[tuple[_Dest, bytes]] = []
    for dest, parts in by_dest.items():
        if len(parts) == 1:
            out.append((dest, parts[0]))
            continue
        cur: list[bytes] = []
        size = 0
        for data in parts:
            if cur and size + len(data) > max_bytes:
                out.append((dest, b"".join(cur)))
                cur, size = [], 0
            cur.append(data)
            size += len(data)
        out.append((dest, b"".join(cur)))
    return out


def _target_offsets() -> dict[int, int]:
    """msgid -> byte offset of ``target_system`` in the payload, from pymavlink's own wire
    layout (``unpacker`` format in ``ordered_fieldnames`` order)."""
    out = {}
    for msgid, cls in mavlink.mavlink_map.items():
        if "target_system" not in cls.fieldnames:
            continue
        tokens = re.findall(r"(\d*)([a-zA-Z?])", cls.unpacker.format.lstrip("<>=!@"))
        if len(tokens) != len(cls.ordered_fieldnames):
            continue
        off = 0
        for (count, code), name in zip(tokens, cls.ordered_fieldnames):
            if name == "target_system":
                out[msgid] = off
                break
            off += struct.calcsize("<" + count + code)
    return out


_TARGET_OFFSET = _target_offsets()


def frame_target_system(frame: bytes) -> int:
    """``target_system`` of one frame from :func:`split_frames` (0 = broadcast, also for
    messages without one and for unknown ids), read from the payload without unpacking or
    checking it.

    MAVLink 2 trims trailing zero bytes of a payload (mavlink.io payload truncation), so a
    target byte past the payload's end is 0.
    """
    if frame[0] == 0xFD:
        msgid, start = frame[7] | (frame[8] << 8) | (frame[9] << 16), 10
    else:
        msgid, start = frame[5], 6
    off = _TARGET_OFFSET.get(msgid)
    if off is None or off >= frame[1]:
        return 0
    return frame[start + off]

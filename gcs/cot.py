"""Cursor on Target (CoT): parse what TAK clients send, build what the station publishes.

Sans-I/O (docs/design/architecture.md §2): bytes in, :class:`CotEvent` out, and the reverse; no
sockets, no clock (every time is an argument, in Unix seconds, UTC).

Two encodings arrive (the TAK protocol as ATAK, iTAK and WinTAK speak it):

* **XML** (TAK protocol version 0): ``<event uid type time start stale how><point lat lon hae
  ce le/><detail>...</detail></event>``, one per UDP datagram, or back to back on a TCP / TLS
  stream to a TAK server;
* **TAK protocol version 1** (protobuf, ``takproto``): the mesh form on UDP (header ``bf 01 bf``
  then one ``TakMessage``) and the stream form on TCP / TLS (``bf``, a varint length, then the
  ``TakMessage``).

Remote input never raises across an adapter (docs/design/architecture.md §7): :func:`parse_cot`
raises :class:`CotError` with what is wrong, and the adapter counts and drops it.

Heights: CoT's ``hae`` is the height above the WGS 84 ellipsoid, metres; 9999999 means unknown
(the CoT schema's "no value"), read here as None.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from datetime import UTC, datetime
from xml.sax.saxutils import quoteattr

__all__ = [
    "CotEvent",
    "CotError",
    "CotStream",
    "parse_cot",
    "cot_xml",
    "cot_time",
    "UNKNOWN_HAE",
    "MAX_EVENT_BYTES",
]

#: CoT's "no value" for hae / ce / le.
UNKNOWN_HAE = 9999999.0

#: A larger event is refused (a stream that never closes an event must not grow without bound).
MAX_EVENT_BYTES = 64 * 1024

_MESH_HEADER = b"\xbf\x01\xbf"


class CotError(ValueError):
    """Bytes that are not a usable CoT event (the message says why)."""


@dataclass(frozen=True)
class CotEvent:
    """One CoT event as the station uses it."""

    uid: str
    type: str
    lat_deg: float
    lon_deg: float
    hae_m: float | None
    """Height above the WGS 84 ellipsoid, metres; None: unknown (9999999 on the wire)."""
    time_unix_s: float
    start_unix_s: float
    stale_unix_s: float
    how: str = ""
    callsign: str | None = None
    course_deg: float | None = None
    speed_m_s: float | None = None

    def __post_init__(self) -> None:
        if not self.uid:
            raise CotError("event has no uid")
        if not (math.isfinite(self.lat_deg) and -90.0 <= self.lat_deg <= 90.0):
            raise CotError(f"event {self.uid!r}: lat must be in [-90, 90], got {self.lat_deg}")
        if not (math.isfinite(self.lon_deg) and -180.0 <= self.lon_deg <= 180.0):
            raise CotError(f"event {self.uid!r}: lon must be in [-180, 180], got {self.lon_deg}")
        for name in ("time_unix_s", "start_unix_s", "stale_unix_s"):
            if not math.isfinite(getattr(self, name)):
                raise CotError(f"event {self.uid!r}: {name} is not a time")

    @property
    def lifetime_s(self) -> float:
        """How long the sender says the event holds: ``stale - time``, seconds (clock-skew free:
        both come from the sender's clock)."""
        return self.stale_unix_s - self.time_unix_s


def cot_time(unix_s: float) -> str:
    """CoT's time format (W3C XML Schema dateTime, UTC, milliseconds): 2026-12-02T10:00:00.000Z."""
    dt = datetime.fromtimestamp(unix_s, UTC)
    return dt.strftime("%Y-%m-%dT%H:%M:%S.") + f"{dt.microsecond // 1000:03d}Z"


def _parse_time(text: str | None, what: str, uid: str) -> float:
    if not text:
        raise CotError(f"event {uid!r}: no {what} time")
    try:
        dt = datetime.fromisoformat(text.strip())
    except ValueError:
        raise CotError(f"event {uid!r}: {what} time {text!r} is not an ISO 8601 time") from None
    if dt.tzinfo is None:  # CoT times are UTC ("Z"); a bare time is read as UTC too
        dt = dt.replace(tzinfo=UTC)
    return dt.timestamp()


def _float(text: str | None, what: str, uid: str) -> float:
    if text is None:
        raise CotError(f"event {uid!r}: point has no {what}")
    try:
        return float(text)
    except ValueError:
        raise CotError(f"event {uid!r}: point {what} {text!r} is not a number") from None


def _opt_float(text: str | None) -> float | None:
    try:
        x = float(text) if text is not None else None
    except ValueError:
        return None
    return x if x is not None and math.isfinite(x) and abs(x) < UNKNOWN_HAE else None


def _parse_xml(data: bytes) -> CotEvent:
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        # no DTDs: entity expansion is a denial of service and CoT never uses one
        raise CotError("XML with a DOCTYPE / ENTITY declaration is refused")
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise CotError(f"not well-formed XML: {exc}") from None
    if root.tag != "event":
        raise CotError(f"root element is <{root.tag}>, not <event>")
    uid = root.get("uid") or ""
    if not uid:
        raise CotError("event has no uid")
    point = root.find("point")
    if point is None:
        raise CotError(f"event {uid!r} has no <point>")
    detail = root.find("detail")
    contact = detail.find("contact") if detail is not None else None
    track = detail.find("track") if detail is not None else None
    return CotEvent(
        uid=uid,
        type=root.get("type") or "",
        lat_deg=_float(point.get("lat"), "lat", uid),
        lon_deg=_float(point.get("lon"), "lon", uid),
        hae_m=_opt_float(point.get("hae")),
        time_unix_s=_parse_time(root.get("time"), "time", uid),
        start_unix_s=_parse_time(root.get("start") or root.get("time"), "start", uid),
        stale_unix_s=_parse_time(root.get("stale"), "stale", uid),
        how=root.get("how") or "",
        callsign=(contact.get("callsign") or None) if contact is not None else None,
        course_deg=_opt_float(track.get("course")) if track is not None else None,
        speed_m_s=_opt_float(track.get("speed")) if track is not None else None,
    )


def _from_proto(msg: object) -> CotEvent:
    ev = msg.cotEvent  # type: ignore[attr-defined]  # takproto's generated TakMessage
    uid = str(ev.uid)
    if not uid:
        raise CotError("TAK protocol message has no cotEvent (or its uid is empty)")
    callsign = str(ev.detail.contact.callsign) or None
    has_track = ev.detail.HasField("track")
    return CotEvent(
        uid=uid,
        type=str(ev.type),
        lat_deg=float(ev.lat),
        lon_deg=float(ev.lon),
        hae_m=_opt_float(str(ev.hae)),
        time_unix_s=ev.sendTime / 1000.0,
        start_unix_s=ev.startTime / 1000.0,
        stale_unix_s=ev.staleTime / 1000.0,
        how=str(ev.how),
        callsign=callsign,
        course_deg=float(ev.detail.track.course) if has_track else None,
        speed_m_s=float(ev.detail.track.speed) if has_track else None,
    )


def _parse_proto(payload: bytes) -> CotEvent:
    from takproto.proto import TakMessage  # protobuf: imported only when a v1 message comes

    msg = TakMessage()
    try:
        msg.ParseFromString(payload)
    except Exception as exc:  # protobuf's DecodeError (and friends): remote garbage
        raise CotError(f"not a TAK protocol v1 message: {exc}") from None
    return _from_proto(msg)


def _varint(data: bytes, i: int) -> tuple[int, int] | None:
    """(value, next index) of the varint at ``data[i]``; None if it is not complete yet."""
    value = shift = 0
    while i < len(data):
        b = data[i]
        value |= (b & 0x7F) << shift
        i += 1
        if not b & 0x80:
            return value, i
        shift += 7
        if shift > 63:
            raise CotError("TAK protocol v1 length varint is too long")
    return None


def parse_cot(data: bytes) -> CotEvent:
    """One CoT event from one datagram or one framed stream message.

    XML, TAK protocol v1 mesh (``bf 01 bf`` + protobuf) or stream (``bf`` + varint length +
    protobuf). Raises :class:`CotError` saying what is wrong.
    """
    data = bytes(data)
    if not data.strip():
        raise CotError("empty message")
    if len(data) > MAX_EVENT_BYTES:
        raise CotError(f"message of {len(data)} bytes is over {MAX_EVENT_BYTES}")
    if data.startswith(_MESH_HEADER):
        return _parse_proto(data[3:])
    if data[0] == 0xBF:
        got = _varint(data, 1)
        if got is None:
            raise CotError("TAK protocol v1 stream message is truncated (in its length)")
        n, i = got
        if len(data) - i != n:
            raise CotError(f"TAK protocol v1 stream message says {n} bytes, has {len(data) - i}")
        return _parse_proto(data[i:])
    return _parse_xml(data.lstrip())


class CotStream:
    """Frames a TCP / TLS byte stream into CoT messages (XML events back to back, or TAK
    protocol v1 stream messages), for :func:`parse_cot`. ``dropped`` counts bytes thrown away
    (garbage between events, an oversized event)."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.dropped = 0

    def feed(self, data: bytes) -> list[bytes]:
        """Append ``data``; return every complete message now in the buffer."""
        self._buf += data
        out: list[bytes] = []
        while self._buf:
            if self._buf[0] == 0xBF:
                got = _varint(bytes(self._buf[:11]), 1)
                if got is None:
                    break
                n, i = got
                if n > MAX_EVENT_BYTES:
                    self.dropped += len(self._buf)
                    self._buf.clear()
                    break
                if len(self._buf) < i + n:
                    break
                out.append(bytes(self._buf[: i + n]))
                del self._buf[: i + n]
                continue
            start = self._buf.find(b"<")
            if start < 0:
                self.dropped += len(self._buf)
                self._buf.clear()
                break
            if start:
                self.dropped += start
                del self._buf[:start]
            end = self._buf.find(b"</event>")
            if end < 0:
                if len(self._buf) > MAX_EVENT_BYTES:
                    self.dropped += len(self._buf)
                    self._buf.clear()
                break
            end += len(b"</event>")
            out.append(bytes(self._buf[:end]))
            del self._buf[:end]
        return out


def _attr(value: float, digits: int) -> str:
    return f"{value:.{digits}f}"


def cot_xml(
    *,
    uid: str,
    type: str,
    lat_deg: float,
    lon_deg: float,
    now_unix_s: float,
    stale_after_s: float,
    hae_m: float | None = None,
    how: str = "m-g",
    callsign: str | None = None,
    course_deg: float | None = None,
    speed_m_s: float | None = None,
    remarks: str | None = None,
    detail_xml: str = "",
) -> bytes:
    """One CoT event as XML bytes (TAK protocol version 0, what every TAK client reads).

    ``hae_m`` None is sent as 9999999 (unknown). ``detail_xml`` is inserted as is inside
    ``<detail>`` (the caller builds it from trusted values: shapes, links, colours).
    """
    t = cot_time(now_unix_s)
    stale = cot_time(now_unix_s + stale_after_s)
    hae = UNKNOWN_HAE if hae_m is None or not math.isfinite(hae_m) else hae_m
    parts = [
        f"<event version={quoteattr('2.0')} uid={quoteattr(uid)} type={quoteattr(type)} "
        f"how={quoteattr(how)} time={quoteattr(t)} start={quoteattr(t)} "
        f"stale={quoteattr(stale)}>",
        f'<point lat="{_attr(lat_deg, 7)}" lon="{_attr(lon_deg, 7)}" hae="{_attr(hae, 1)}" '
        f'ce="{UNKNOWN_HAE:.1f}" le="{UNKNOWN_HAE:.1f}"/>',
        "<detail>",
    ]
    if callsign is not None:
        parts.append(f"<contact callsign={quoteattr(callsign)}/>")
    if course_deg is not None or speed_m_s is not None:
        c = course_deg if course_deg is not None and math.isfinite(course_deg) else 0.0
        s = speed_m_s if speed_m_s is not None and math.isfinite(speed_m_s) else 0.0
        parts.append(f'<track course="{_attr(c % 360.0, 1)}" speed="{_attr(s, 2)}"/>')
    if remarks is not None:
        text = remarks.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
        parts.append(f"<remarks>{text}</remarks>")
    parts.append(detail_xml)
    parts.append("</detail></event>")
    return "".join(parts).encode()

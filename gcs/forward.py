"""MAVLink forwarding to other ground stations, as MAVProxy's ``--out``.

Every frame a vehicle sends on any of the station's links goes out, unchanged, to every output
(QGroundControl, MAVProxy, a logger); what those send back is relayed to the link of the vehicle
it is addressed to (``target_system``; a broadcast target 0, a message without a target, or a
system never heard, goes to every link). With ``readonly`` nothing they send reaches a vehicle.

Outputs (connection strings as :mod:`gcs.connection`):

* ``udpout:HOST:PORT`` - send to HOST:PORT (QGC listens on 14550); replies come back to our socket.
* ``udpin:HOST:PORT`` - listen; send to every peer that has sent us something.
* ``tcpin:HOST:PORT`` - listen for TCP clients; send to all of them.

System ids. The station is sysid 255 (``StationConfig.sysid``), the one ArduPilot's GCS failsafe
counts (SYSID_MYGCS / MAV_GCS_SYSID), and QGroundControl's default is 255 too. Frames whose
source is the station's sysid are never forwarded (our heartbeats, or another 255 GCS on a
vehicle link, must not look like a vehicle to the outputs); and frames *from* an output with the
station's sysid are dropped (a warning once): they would feed the vehicles' GCS failsafe for us,
and their COMMAND_ACKs (addressed to 255) would be taken by the station as answers to its own
commands. Set QGC's "MAVLink system ID" (Application Settings -> MAVLink) to another value,
e.g. 254, for it to command vehicles through the forwarder.

Sans-clock: the forwarder keeps no timers; it needs the links' raw taps
(:meth:`gcs.aio.StationAdapter.add_tap` / :meth:`~gcs.aio.StationAdapter.send_raw`), and runs
on the station's event loop.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any, Protocol
from collections.abc import Callable, Sequence

from gcs.connection import ConnectionSpec, parse_connection
from gcs.wire import mavlink

__all__ = ["Forwarder", "split_frames", "OUTPUT_KINDS"]

log = logging.getLogger(__name__)

OUTPUT_KINDS = ("udpout", "udpin", "tcpin")

_V1, _V2 = 0xFE, 0xFD
_MAX_TCP_CLIENTS = 16
_MAX_UDP_PEERS = 16


class RawLink(Protocol):
    """What the forwarder needs of a station link (:class:`gcs.aio.StationAdapter`)."""

    link_id: int

    def add_tap(self, tap: Callable[[bytes, object], None]) -> None: ...

    def send_raw(self, frame: bytes) -> None: ...


def split_frames(buf: bytes | bytearray) -> tuple[list[bytes], int]:
    """Whole MAVLink v1/v2 frames at the start of ``buf`` (by header length; no CRC check: the
    receiving GCS checks). Returns ``(frames, consumed)``; bytes before a start marker are
    skipped, an incomplete frame at the end is left (``consumed`` stops before it)."""
    out, i, n = [], 0, len(buf)
    while i < n:
        b = buf[i]
        if b not in (_V1, _V2):
            i += 1
            continue
        if i + 2 > n:
            break
        ln = buf[i + 1]
        if b == _V1:
            total = ln + 8
        else:
            if i + 3 > n:
                break
            total = ln + 12 + (13 if buf[i + 2] & 0x01 else 0)
        if i + total > n:
            break
        out.append(bytes(buf[i : i + total]))
        i += total
    return out, i


def _src_sysid(frame: bytes) -> int:
    return frame[3] if frame[0] == _V1 else frame[5]


class Forwarder:
    """Forward vehicle traffic to ``outputs`` and route their messages back (module docstring).

    Parameters
    ----------
    outputs : connection strings (``udpout:``, ``udpin:``, ``tcpin:``)
    readonly : drop everything the outputs send
    gcs_sysid : the station's own MAVLink system id (never forwarded; dropped from outputs)
    """

    def __init__(
        self, outputs: Sequence[str], *, readonly: bool = False, gcs_sysid: int = 255
    ) -> None:
        self.specs: list[ConnectionSpec] = []
        for text in outputs:
            spec = parse_connection(text)
            if spec.kind not in OUTPUT_KINDS:
                raise ValueError(
                    f"forwarding output {text!r}: use udpout:H:P, udpin:H:P or "
                    f"tcpin:H:P (got a {spec.kind} connection)"
                )
            self.specs.append(spec)
        self.readonly = bool(readonly)
        self.gcs_sysid = int(gcs_sysid)
        self.links: list[RawLink] = []
        self._links_of_sysid: dict[int, set[int]] = {}
        self._stream_bufs: dict[tuple[int, object], bytearray] = {}
        self._parsers: dict[object, Any] = {}  # pymavlink MAVLink parsers
        self._outputs: list[_Output] = []
        self.addresses: list[tuple[str, int]] = []
        """Local address of each output (udpin/tcpin: the bound port; udpout: our socket)."""
        self.stats = {
            "frames_out": 0,
            "frames_in": 0,
            "routed": 0,
            "dropped_readonly": 0,
            "dropped_own_sysid": 0,
            "dropped_undecodable": 0,
        }
        self._warned_sysid = False

    # ------------------------------------------------------------------ set-up

    def attach(self, link: RawLink, *, datagram: bool = True) -> None:
        """Tap one station link (``datagram``: UDP, each chunk holds whole frames)."""
        self.links.append(link)
        lid = link.link_id
        link.add_tap(lambda data, addr: self.from_vehicle(lid, data, addr, datagram=datagram))

    async def start(self) -> Forwarder:
        loop = asyncio.get_running_loop()
        for spec in self.specs:
            out = _Output(self, spec)
            await out.start(loop)
            self._outputs.append(out)
            assert out.local_address is not None  # set by start()
            self.addresses.append(out.local_address)
        return self

    def close(self) -> None:
        for out in self._outputs:
            out.close()
        self._outputs.clear()

    # ------------------------------------------------------------------ vehicles -> outputs

    def from_vehicle(self, link_id: int, data: bytes, addr: Any, *, datagram: bool = True) -> None:
        """Bytes heard on link ``link_id``: forward every frame not from the station's sysid."""
        if datagram:
            frames, _ = split_frames(data)
        else:  # a byte stream: keep the tail of a frame cut by the read
            key = (link_id, addr)
            buf = self._stream_bufs.setdefault(key, bytearray())
            buf += data
            frames, used = split_frames(buf)
            del buf[:used]
            if len(buf) > 4096:  # garbage without a frame start: do not grow forever
                buf.clear()
        keep = []
        for f in frames:
            sysid = _src_sysid(f)
            if sysid == self.gcs_sysid:
                continue
            self._links_of_sysid.setdefault(sysid, set()).add(link_id)
            keep.append(f)
        if not keep or not self._outputs:
            return
        payload = b"".join(keep)
        self.stats["frames_out"] += len(keep)
        for out in self._outputs:
            out.send(payload)

    # ------------------------------------------------------------------ outputs -> vehicles

    def from_output(self, data: bytes, source: object) -> None:
        """Bytes from an output peer ``source``: decode, filter, route by ``target_system``."""
        parser = self._parsers.get(source)
        if parser is None:
            parser = mavlink.MAVLink(None)
            parser.robust_parsing = True
            self._parsers[source] = parser
        try:
            msgs = parser.parse_buffer(bytes(data)) or []
        except Exception:  # noqa: BLE001 - garbage from a peer never takes the station down
            self.stats["dropped_undecodable"] += 1
            return
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self.stats["dropped_undecodable"] += 1
                continue
            self.stats["frames_in"] += 1
            if self.readonly:
                self.stats["dropped_readonly"] += 1
                continue
            if msg.get_srcSystem() == self.gcs_sysid:
                self.stats["dropped_own_sysid"] += 1
                if not self._warned_sysid:
                    self._warned_sysid = True
                    log.warning(
                        "forwarding: a ground station on %s uses sysid %d, the station's "
                        "own: its messages are dropped. Give it another MAVLink system "
                        "ID (QGroundControl: Application Settings -> MAVLink, e.g. 254)",
                        source,
                        self.gcs_sysid,
                    )
                continue
            frame = bytes(msg.get_msgbuf())
            target = int(getattr(msg, "target_system", 0) or 0)
            ids = self._links_of_sysid.get(target) if target else None
            for link in self.links:
                if ids is None or link.link_id in ids:
                    link.send_raw(frame)
                    self.stats["routed"] += 1


class _Output:
    """One forwarding output's sockets."""

    def __init__(self, owner: Forwarder, spec: ConnectionSpec) -> None:
        self.owner = owner
        self.spec = spec
        self.local_address: tuple[str, int] | None = None
        self._udp: asyncio.DatagramTransport | None = None
        self._peers: dict[Any, None] = {}
        self._writers: list[asyncio.StreamWriter] = []
        self._server: asyncio.Server | None = None
        self._tasks: list[asyncio.Task[Any]] = []

    async def start(self, loop: asyncio.AbstractEventLoop) -> None:
        spec = self.spec
        if spec.kind in ("udpout", "udpin"):
            out = self

            class _P(asyncio.DatagramProtocol):
                def datagram_received(self, data: bytes, addr: Any) -> None:
                    if spec.kind == "udpin":
                        if addr not in out._peers and len(out._peers) >= _MAX_UDP_PEERS:
                            out._peers.pop(next(iter(out._peers)))
                        out._peers[addr] = None
                    out.owner.from_output(data, (spec.text, addr))

                def error_received(
                    self, exc: Exception
                ) -> None:  # nobody listening yet (ICMP): keep sending
                    log.debug("forward %s: %s", spec.text, exc)

            kw: dict[str, Any] = (
                {"remote_addr": spec.address}
                if spec.kind == "udpout"
                else {"local_addr": spec.address}
            )
            self._udp, _ = await loop.create_datagram_endpoint(_P, **kw)
            self.local_address = self._udp.get_extra_info("sockname")[:2]
        else:

            async def on_client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
                if len(self._writers) >= _MAX_TCP_CLIENTS:
                    writer.close()
                    return
                peer = writer.get_extra_info("peername")
                self._writers.append(writer)
                try:
                    while data := await reader.read(65536):
                        self.owner.from_output(data, (spec.text, peer))
                except (ConnectionError, OSError):
                    pass
                finally:
                    if writer in self._writers:
                        self._writers.remove(writer)
                    self.owner._parsers.pop((spec.text, peer), None)
                    writer.close()

            self._server = await asyncio.start_server(on_client, *spec.address)
            self.local_address = self._server.sockets[0].getsockname()[:2]

    def send(self, payload: bytes) -> None:
        try:
            if self.spec.kind == "udpout":
                assert self._udp is not None  # started
                self._udp.sendto(payload)
            elif self.spec.kind == "udpin":
                assert self._udp is not None  # started
                for peer in self._peers:
                    self._udp.sendto(payload, peer)
            else:
                for w in list(self._writers):
                    # A stalled client must not grow our memory: drop what it cannot take.
                    if w.transport.get_write_buffer_size() < (1 << 20):
                        w.write(payload)
        except OSError as exc:
            log.debug("forward %s: %s", self.spec.text, exc)

    def close(self) -> None:
        if self._udp is not None:
            self._udp.close()
        if self._server is not None:
            self._server.close()
        for w in self._writers:
            w.close()
        self._writers.clear()

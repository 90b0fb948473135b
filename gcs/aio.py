"""A thin asyncio adapter: runs a :class:`~gcs.link.StationLink` over UDP, TCP or serial.

The cycle, after aioquic's ``transmit()`` (ARCHITECTURE §4.3): receive -> ``core.receive_datagram(
data, addr, now)`` -> drain events -> send everything from ``datagrams_to_send`` -> re-arm one
timer at ``next_timer_s()``. Local calls follow the same path: call the core, then
:meth:`StationAdapter.transmit`. The clock is injectable (default: the loop's monotonic clock);
with a simulation speed-up, pass the simulated clock and ``time_scale`` = the speed-up so timers
are re-armed in wall seconds.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import socket
import time
from typing import Callable

from gcs.connection import ConnectionSpec, parse_connection
from gcs.events import Event
from gcs.link import StationConfig, StationLink
from gcs.records import TlogWriter

__all__ = ["StationAdapter", "open_links"]

log = logging.getLogger(__name__)

_UDP_RCVBUF_BYTES = 4 << 20


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, owner: "StationAdapter") -> None:
        self.owner = owner

    def datagram_received(self, data: bytes, addr) -> None:
        self.owner.receive(data, addr)

    def error_received(self, exc: Exception) -> None:  # ICMP unreachable etc.: keep going
        log.debug("link %d: %s", self.owner.link_id, exc)


class StationAdapter:
    """One link: a transport from a connection string plus its station core."""

    def __init__(self, connection: str | ConnectionSpec, config: StationConfig | None = None, *,
                 link_id: int = 0, clock: Callable[[], float] | None = None,
                 wall_clock: Callable[[], float] = time.time, tlog: TlogWriter | None = None,
                 on_event: Callable[[Event], None] | None = None,
                 time_scale: float = 1.0) -> None:
        self.spec = parse_connection(connection) if isinstance(connection, str) else connection
        self.link_id = link_id
        self._config = config or StationConfig()
        if not time_scale > 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        self._clock = clock
        self.time_scale = float(time_scale)
        self._wall_clock = wall_clock
        self._tlog = tlog
        self._on_event = on_event
        self.events: asyncio.Queue[Event] = asyncio.Queue()
        self.core: StationLink | None = None
        self._send: Callable[[bytes, object], None] = lambda data, addr: None
        self._timer: asyncio.TimerHandle | None = None
        self._closers: list[Callable[[], None]] = []
        self.local_address = None

    def now(self) -> float:
        return self._clock() if self._clock else asyncio.get_running_loop().time()

    async def start(self) -> "StationAdapter":
        loop = asyncio.get_running_loop()
        if self._clock is None:
            self._clock = loop.time
        spec, cfg = self.spec, self._config
        static: tuple = ()
        if spec.kind in ("udpin", "udpout"):
            remote = spec.address if spec.kind == "udpout" else None
            local = spec.address if spec.kind == "udpin" else None
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Udp(self), local_addr=local, remote_addr=remote)
            self.local_address = transport.get_extra_info("sockname")
            sock = transport.get_extra_info("socket")
            if sock is not None:  # bursts from hundreds of vehicles: a deeper receive queue
                try:
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _UDP_RCVBUF_BYTES)
                except OSError:
                    pass
            if remote is not None:  # connected socket: one peer, whatever addr the core names
                static = (remote,)
                self._send = lambda data, addr: transport.sendto(data)
            else:
                self._send = transport.sendto
            self._closers.append(transport.close)
        elif spec.kind == "tcp":
            reader, writer = await asyncio.open_connection(*spec.address)
            static = (spec.address,)
            self._send = lambda data, addr: writer.write(data)
            self._start_reader(reader, spec.address)
            self._closers.append(writer.close)
        elif spec.kind == "tcpin":
            async def on_client(reader, writer):
                peer = writer.get_extra_info("peername")
                self._send = lambda data, addr: writer.write(data)  # the latest client wins
                await self._read_stream(reader, peer)
            server = await asyncio.start_server(on_client, *spec.address)
            self.local_address = server.sockets[0].getsockname()
            self._closers.append(server.close)
        else:
            self._open_serial(spec, loop)
            static = (spec.device,)
        cfg = dataclasses.replace(
            cfg, static_peers=tuple(cfg.static_peers) + static,
            datagram=spec.kind in ("udpin", "udpout"), record_frames=self._tlog is not None,
            unix_time_offset_s=self._wall_clock() - self.now())
        self.core = StationLink(cfg, link_id=self.link_id, now_s=self.now())
        self.transmit()
        return self

    def _open_serial(self, spec: ConnectionSpec, loop: asyncio.AbstractEventLoop) -> None:
        try:
            import serial  # pyserial: optional, not a project dependency
        except ImportError:
            raise RuntimeError(f"{spec.text!r}: serial links need pyserial "
                               "(pip install pyserial)") from None
        port = serial.Serial(spec.device, spec.baud, timeout=0)

        def readable() -> None:
            data = port.read(port.in_waiting or 1)
            if data:
                self.receive(data, spec.device)
        loop.add_reader(port.fileno(), readable)
        self._send = lambda data, addr: port.write(data)
        self._closers += [lambda: loop.remove_reader(port.fileno()), port.close]

    def _start_reader(self, reader: asyncio.StreamReader, peer) -> None:
        task = asyncio.get_running_loop().create_task(self._read_stream(reader, peer))
        self._closers.append(task.cancel)

    async def _read_stream(self, reader: asyncio.StreamReader, peer) -> None:
        while data := await reader.read(65536):
            self.receive(data, peer)
        log.info("link %d: %s closed the connection", self.link_id, peer)

    def receive(self, data: bytes, addr) -> None:
        if self.core is not None:
            self.core.receive_datagram(data, addr, self.now())
            self.transmit()

    def _on_timer(self) -> None:
        self._timer = None
        if self.core is not None:
            self.core.handle_timer(self.now())
            self.transmit()

    def transmit(self) -> None:
        """Drain events, send what the core queued, write the tlog, re-arm the timer."""
        core = self.core
        assert core is not None, "start() first"
        while (event := core.next_event()) is not None:
            if self._on_event is None:
                self.events.put_nowait(event)
                continue
            try:
                self._on_event(event)
            except Exception:
                log.exception("link %d: event handler failed on %r", self.link_id, event)
        for data, addr in core.datagrams_to_send(self.now()):
            try:
                self._send(data, addr)
            except OSError as exc:  # unreachable peer: the link layer copes with loss
                log.debug("link %d: send to %s failed: %s", self.link_id, addr, exc)
        if self._tlog is not None:
            self._tlog.write_frames(core.take_frames())
        if self._timer is not None:
            self._timer.cancel()
        t = core.next_timer_s()
        if t is not None:
            # Core seconds -> wall seconds: under a speed-up every station timer (the 1 Hz GCS
            # heartbeat included) must follow the vehicles' clock (MAVLINK_NOTES §5).
            delay = max(0.0, t - self.now()) / self.time_scale
            self._timer = asyncio.get_running_loop().call_later(delay, self._on_timer)

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        for close in reversed(self._closers):
            close()
        self._closers.clear()


async def open_links(connections: list[str], config: StationConfig | None = None,
                     **kwargs) -> list[StationAdapter]:
    """Start one adapter per connection string, with link ids 0, 1, ..."""
    return [await StationAdapter(c, config, link_id=i, **kwargs).start()
            for i, c in enumerate(connections)]

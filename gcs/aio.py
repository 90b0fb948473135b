"""A thin asyncio adapter: runs a :class:`~gcs.link.StationLink` over UDP, TCP or serial.

The cycle, after aioquic's ``transmit()`` (docs/design/architecture.md §2.1): receive -> ``core.receive_datagram(
data, addr, now)`` -> drain events -> send everything from ``datagrams_to_send`` -> re-arm one
timer at ``next_timer_s()``. Local calls follow the same path: call the core, then
:meth:`StationAdapter.transmit`. The clock is injectable: a :class:`mavedge.clock.Clock` (its
``now`` is the core's time, its ``wall_delay_s`` re-arms timers in wall seconds, its
``unix_time_at_zero_s`` stamps signatures and the .tlog), or a bare ``now()`` callable with
``time_scale`` = the speed-up; default: the loop's monotonic clock at 1x.

Links that are down are the normal case, not an error: a ``tcp:`` server (SITL, a companion
computer) not yet up, a USB radio not yet plugged in, a ``udpout:`` network not yet routable.
:meth:`StationAdapter.start` then succeeds anyway and keeps trying in the background with a
doubling wait (``reconnect_s``), as it does when such a link drops later; the state is
:attr:`StationAdapter.connected` and the :class:`~gcs.events.LinkDown` /
:class:`~gcs.events.LinkUp` events, each logged once per change. Only a mistake that waiting
cannot fix raises, in one line: a ``udpin:`` / ``tcpin:`` address that cannot be bound (in use,
not ours), a host name that does not resolve, a file that is not a serial port, a serial device
we may not open, pyserial missing (:class:`LinkOpenError`, :class:`SerialLinkError`).
The serial port on the event loop is :mod:`gcs.serial_port`.
"""

from __future__ import annotations

import asyncio
import dataclasses
import errno
import logging
import os
import socket
import time
from collections.abc import Callable
from typing import Any

from gcs.connection import ConnectionSpec, parse_connection
from gcs.events import Event, LinkDown, LinkEvent, LinkUp
from gcs.link import StationConfig, StationLink
from gcs.records import TlogWriter
from gcs.serial_port import SerialLinkError, _serial_open_reason, _SerialPort
from mavedge.clock import Clock
from mavedge.codec import coalesce_datagrams

__all__ = ["StationAdapter", "SerialLinkError", "LinkOpenError", "open_links"]

log = logging.getLogger(__name__)

_UDP_RCVBUF_BYTES = 4 << 20


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, owner: StationAdapter) -> None:
        self.owner = owner

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.owner.receive(data, addr)

    def error_received(self, exc: Exception) -> None:  # ICMP unreachable etc.: keep going
        log.debug("link %d: %s", self.owner.link_id, exc)


class LinkOpenError(OSError):
    """A link that cannot be opened and that waiting will not fix (one line: which, why)."""


def _open_reason(spec: ConnectionSpec, exc: BaseException) -> str:
    """One line: what was tried, why it failed, the likely cause (the caller names the link,
    as the runner's "cannot open link 'udpin:...': ..." does)."""
    if spec.kind == "serial":
        return _serial_open_reason(spec, exc)
    host, port = spec.address
    if isinstance(exc, socket.gaierror):
        return f"cannot resolve host {host!r} ({exc.strerror or exc})"
    code = getattr(exc, "errno", None)
    if isinstance(code, int) and code > 0:
        reason = os.strerror(code)
    else:
        reason = str(exc) or type(exc).__name__
    if spec.kind in ("udpin", "tcpin"):
        hint = {
            errno.EADDRINUSE: " (another station, MAVProxy or QGroundControl on this port?)",
            errno.EADDRNOTAVAIL: " (not an address of this computer)",
            errno.EACCES: " (ports below 1024 need privileges)",
        }.get(code or 0, "")
        return f"cannot listen on {host}:{port}: {reason}{hint}"
    return f"cannot connect to {host}:{port}: {reason}"


class _NowFnClock:
    """A bare ``now()`` callable, a speed-up and a Unix clock as a :class:`Clock` (the form
    ``mission.flight.station_loop`` passes; the default is the loop's own clock). The Unix anchor is
    read when asked: the core is built at :meth:`StationAdapter.start`."""

    def __init__(
        self, now_fn: Callable[[], float], time_scale: float, wall_clock: Callable[[], float]
    ) -> None:
        self.now = now_fn
        self.time_scale = time_scale
        self._wall_clock = wall_clock

    def wall_delay_s(self, dt_s: float) -> float:
        return max(0.0, dt_s) / self.time_scale

    @property
    def unix_time_at_zero_s(self) -> float:
        return self._wall_clock() - self.now()


class StationAdapter:
    """One link: a transport from a connection string plus its station core.

    ``clock``: a :class:`~mavedge.clock.Clock`, or a bare ``now()`` callable whose wall speed
    is ``time_scale`` and whose Unix anchor is read from ``wall_clock`` (a Clock carries both:
    leave ``time_scale`` and ``wall_clock`` alone). Default: the running loop's clock.

    ``coalesce``: what one :meth:`transmit` sends to one address goes in datagrams of up to
    :data:`mavedge.codec.MAX_DATAGRAM_BYTES` (:func:`mavedge.codec.coalesce_datagrams`) rather
    than one per frame (the core queues one frame per datagram): the same frames in the same
    order per address, fewer datagrams (a control tick's setpoints to a network of vehicles
    behind one address). ``False``: one frame per datagram, as the core queues them."""

    def __init__(
        self,
        connection: str | ConnectionSpec,
        config: StationConfig | None = None,
        *,
        link_id: int = 0,
        clock: Clock | Callable[[], float] | None = None,
        wall_clock: Callable[[], float] = time.time,
        tlog: TlogWriter | None = None,
        on_event: Callable[[Event], None] | None = None,
        time_scale: float = 1.0,
        reconnect_s: tuple[float, float] = (1.0, 8.0),
        on_link_event: Callable[[LinkEvent], None] | None = None,
        coalesce: bool = True,
    ) -> None:
        self.spec = parse_connection(connection) if isinstance(connection, str) else connection
        self.coalesce = bool(coalesce)
        self.link_id = link_id
        self._config = config or StationConfig()
        if not time_scale > 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        if isinstance(clock, Clock) and time_scale != 1.0:
            raise ValueError("a Clock brings its own speed-up: leave time_scale at 1")
        self.time_scale = float(time_scale)
        self._wall_clock = wall_clock
        self._clock: Clock | None = (
            clock
            if isinstance(clock, Clock) or clock is None
            else _NowFnClock(clock, self.time_scale, wall_clock)
        )
        self._tlog = tlog
        self._on_event = on_event
        self.events: asyncio.Queue[Event | LinkEvent] = asyncio.Queue()
        self.core: StationLink | None = None
        self._send: Callable[[bytes, Any], None] = lambda data, addr: None
        self._timer: asyncio.TimerHandle | None = None
        self._closers: list[Callable[[], object]] = []
        self.local_address = None
        self.reconnect_s = reconnect_s
        """tcp, udpout, serial: first and longest wait (wall seconds) between connection
        attempts while the link is down."""
        self.reconnects = 0
        """Connections made after the first attempt at start (reconnections, late links)."""
        self._writer: asyncio.StreamWriter | None = None
        self._on_link_event = on_link_event
        self._connected: bool | None = None
        self.down_reason = ""
        """Why the link is down (empty while it is up)."""
        self._port: _SerialPort | None = None
        self._port_lost: asyncio.Event | None = None
        self._taps: list[Callable[[bytes, object], None]] = []
        self.early_wakeups = 0
        """Timer wake-ups before the core's next deadline (skipped without a scan)."""
        self._tap_peers: dict[Any, Any] = {}
        self._reader: socket.socket | None = None
        self.drained = 0
        """Datagrams read by :meth:`drain` (not by the event loop's one-per-iteration reads)."""
        self.drained_max = 0
        """The most :meth:`drain` found queued at once: how far the station's reading fell
        behind what the vehicles had sent."""

    def now(self) -> float:
        clock = self._clock
        return clock.now() if clock is not None else asyncio.get_running_loop().time()

    @property
    def connected(self) -> bool:
        """The transport is up: bound (udpin, tcpin), connected (tcp, udpout) or open (serial).
        Says nothing about the vehicles behind it (they have their own timeouts)."""
        return bool(self._connected)

    def _set_connected(self, up: bool, reason: str = "") -> None:
        """Record a state change: logged once, and a LinkUp / LinkDown event."""
        if up:
            self.down_reason = ""
        elif reason:
            self.down_reason = reason
        if self._connected is up:
            return
        first = self._connected is None
        self._connected = up
        now = self.now()
        if up:
            log.log(
                logging.DEBUG if first else logging.WARNING,
                "link %d: %s is up",
                self.link_id,
                self.spec.text,
            )
            self._emit_link_event(LinkUp(self.link_id, now, connection=self.spec.text))
        else:
            log.warning(
                "link %d: %s is down (%s); retrying in the background",
                self.link_id,
                self.spec.text,
                self.down_reason,
            )
            self._emit_link_event(
                LinkDown(self.link_id, now, connection=self.spec.text, reason=self.down_reason)
            )

    def _emit_link_event(self, event: LinkEvent) -> None:
        # To on_link_event, or to the events queue when there is no on_event; never to on_event
        # itself: its consumers take vehicle events (Event, with a sysid).
        if self._on_link_event is not None:
            try:
                self._on_link_event(event)
            except Exception:
                log.exception("link %d: link event handler failed on %r", self.link_id, event)
        elif self._on_event is None:
            self.events.put_nowait(event)

    async def start(self) -> StationAdapter:
        """Open the link. A link that is down is retried in the background (see the module
        docstring); a mistake raises :class:`LinkOpenError` or :class:`SerialLinkError` (both
        OSError), in one line."""
        loop = asyncio.get_running_loop()
        if self._clock is None:
            self._clock = _NowFnClock(loop.time, self.time_scale, self._wall_clock)
        spec, cfg = self.spec, self._config
        static: tuple[Any, ...] = ()
        if spec.kind in ("udpout", "tcp"):
            static = (spec.address,)  # heartbeat it before hearing anything
        elif spec.kind == "serial":
            static = (spec.device,)
        cfg = dataclasses.replace(
            cfg,
            static_peers=tuple(cfg.static_peers) + static,
            datagram=spec.kind in ("udpin", "udpout"),
            record_frames=self._tlog is not None,
            unix_time_at_zero_s=self._clock.unix_time_at_zero_s,
        )
        self.core = StationLink(cfg, link_id=self.link_id, now_s=self.now())
        try:
            if spec.kind == "udpin":
                await self._open_udp(loop)
            elif spec.kind == "tcpin":
                await self._open_tcpin()
            else:
                await self._open_client(loop)
        except BaseException:
            self.close()
            raise
        self.transmit()
        return self

    async def _open_udp(self, loop: asyncio.AbstractEventLoop) -> None:
        spec = self.spec
        remote = spec.address if spec.kind == "udpout" else None
        local = spec.address if spec.kind == "udpin" else None
        try:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Udp(self), local_addr=local, remote_addr=remote
            )
        except OSError as exc:
            if spec.kind == "udpin" or isinstance(exc, socket.gaierror):
                raise LinkOpenError(_open_reason(spec, exc)) from exc
            raise
        self.local_address = transport.get_extra_info("sockname")
        sock = transport.get_extra_info("socket")
        if sock is not None:  # bursts from hundreds of vehicles: a deeper receive queue
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _UDP_RCVBUF_BYTES)
            except OSError:
                pass
        if sock is not None:  # a plain socket on the same descriptor, for drain()
            reader = socket.fromfd(sock.fileno(), sock.family, sock.type)
            reader.setblocking(False)
            self._reader = reader
            self._closers.append(reader.close)
        if remote is not None:  # connected socket: one peer, whatever addr the core names
            self._send = lambda data, addr: transport.sendto(data)
        else:
            self._send = transport.sendto
        self._closers.append(transport.close)
        self._set_connected(True)

    async def _open_tcpin(self) -> None:
        spec = self.spec

        async def on_client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            peer = writer.get_extra_info("peername")
            self._send = lambda data, addr: writer.write(data)  # the latest client wins
            await self._read_stream(reader, peer)

        try:
            server = await asyncio.start_server(on_client, *spec.address)
        except OSError as exc:
            raise LinkOpenError(_open_reason(spec, exc)) from exc
        self.local_address = server.sockets[0].getsockname()
        self._closers.append(server.close)
        self._set_connected(True)

    async def _open_client(self, loop: asyncio.AbstractEventLoop) -> None:
        """tcp, udpout, serial: one attempt now; while the link is down a background task keeps
        trying, and afterwards keeps it up (TCP reconnection, serial re-plug)."""
        reader = None
        if self.spec.kind == "tcp":
            self._closers.append(self._close_writer)
        try:
            reader = await self._connect_once(loop)
        except LinkOpenError:
            raise
        except socket.gaierror as exc:  # a typo in the host name: waiting will not fix it
            raise LinkOpenError(_open_reason(self.spec, exc)) from exc
        except SerialLinkError as exc:
            if not exc.retryable:
                raise
            self._set_connected(False, str(exc))
        except OSError as exc:
            self._set_connected(False, _open_reason(self.spec, exc))
        else:
            self._set_connected(True)
        if self.spec.kind == "udpout" and self.connected:
            return  # a UDP socket, once connected, does not go down
        task = loop.create_task(self._keep_up(reader))
        self._closers.append(task.cancel)

    async def _connect_once(self, loop: asyncio.AbstractEventLoop) -> asyncio.StreamReader | None:
        """One connection attempt; returns the TCP reader (None for udpout, serial)."""
        spec = self.spec
        if spec.kind == "tcp":
            reader, self._writer = await asyncio.open_connection(*spec.address)
            self._send = lambda data, addr: self._tcp_write(data)
            return reader
        if spec.kind == "udpout":
            await self._open_udp(loop)
            return None
        self._open_serial(spec, loop)
        return None

    async def _keep_up(self, reader: asyncio.StreamReader | None) -> None:
        """For the adapter's life: wait for the link to drop (TCP end of stream, serial hang-up),
        then reconnect with a doubling wait, as MAVProxy's ``autoreconnect`` does, with a fresh
        decoder. Vehicles time out meanwhile and are recovered when heard again."""
        loop = asyncio.get_running_loop()
        first, longest = self.reconnect_s
        spec = self.spec
        peer = spec.device if spec.kind == "serial" else spec.address
        while True:
            if self.connected:
                if spec.kind == "tcp":
                    assert reader is not None  # a connected TCP link has its reader
                    await self._read_stream(reader, peer)
                    self._close_writer()
                    self._set_connected(False, "connection closed")
                elif spec.kind == "serial":
                    assert self._port_lost is not None
                    await self._port_lost.wait()
                    self._set_connected(False, f"serial port lost ({self.down_reason})")
                else:
                    return
                if self.core is not None:
                    self.core.reset_stream(peer)
            delay = first
            while True:
                await asyncio.sleep(delay)
                try:
                    reader = await self._connect_once(loop)
                except OSError as exc:
                    reason = (
                        str(exc) if isinstance(exc, SerialLinkError) else _open_reason(spec, exc)
                    )
                    self.down_reason = reason
                    log.debug("link %d: %s still down: %s", self.link_id, spec.text, reason)
                    delay = min(2 * delay, longest)
                    continue
                break
            self.reconnects += 1
            self._set_connected(True)
            if self.core is not None:
                self.core.handle_timer(self.now())  # whatever fell due while it was down
                self.transmit()

    def _open_serial(self, spec: ConnectionSpec, loop: asyncio.AbstractEventLoop) -> None:
        if self._port_lost is None:
            self._port_lost = asyncio.Event()
            self._closers.append(self._close_port)
        lost = self._port_lost

        def on_lost(why: str) -> None:
            self.down_reason = why
            lost.set()

        port = _SerialPort.open(
            spec,
            loop,
            lambda data: self.receive(data, spec.device),
            link_id=self.link_id,
            on_lost=on_lost,
        )
        lost.clear()
        self._port = port
        self._send = lambda data, addr: port.write(data)

    def _close_port(self) -> None:
        if self._port is not None:
            self._port.close()

    async def _read_stream(self, reader: asyncio.StreamReader, peer: Any) -> None:
        try:
            while data := await reader.read(65536):
                self.receive(data, peer)
        except (ConnectionError, OSError) as exc:  # reset by peer, ...
            log.info("link %d: %s: %s", self.link_id, peer, exc)
            return
        log.info("link %d: %s closed the connection", self.link_id, peer)

    def _tcp_write(self, data: bytes) -> None:
        w = self._writer
        if w is None or w.is_closing():
            return  # reconnecting: the frame is lost, as on a radio link
        w.write(data)

    def _close_writer(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def receive(self, data: bytes, addr: Any) -> None:
        if self._taps:
            self._tap_raw(data, addr)
        if self.core is not None:
            self.core.receive_datagram(data, addr, self.now())
            self.transmit()

    def drain(self, limit: int = 4096) -> int:
        """Read every datagram already queued on this link's UDP socket (at most ``limit``),
        then send what the core queued once; returns how many were read (0 for TCP and
        serial links, whose streams the loop reads whole).

        asyncio's datagram transport reads one datagram per socket per loop iteration. Under
        lock-step pacing (:class:`mavedge.clock.PacedReader`) the station says "everything up to
        now is done" once per iteration; with 50 vehicles' telemetry arriving faster than one
        datagram an iteration, the backlog grew on the socket while simulated time moved on,
        and at 50x the station read COMMAND_ACKs and positions tens of simulated seconds late
        (docs/results/endurance.md). The station's loop drains in every iteration, right after
        its first acknowledgement, so it reads at most about the lock-step's slack late
        (docs/design/mavlink.md §4.3); the emulator drains before it moves time
        (vehicle_emu/udp.py ``EmulatorServer._drain``)."""
        reader = self._reader
        if reader is None:
            return 0
        core = self.core
        n = 0
        for _ in range(limit):
            try:
                data, addr = reader.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:  # ICMP unreachable and the like: the link copes with loss
                log.debug("link %d: drain: %s", self.link_id, exc)
                break
            n += 1
            if self._taps:
                self._tap_raw(data, addr)
            if core is not None:
                core.receive_datagram(data, addr, self.now())
        if n:
            self.drained += n
            self.drained_max = max(self.drained_max, n)
            if core is not None:
                self.transmit()
        return n

    # Raw tap (MAVLink forwarding, gcs.forward): the bytes as they arrive, and frames injected
    # as they are, beside the station core (which neither sees nor answers them).

    def add_tap(self, tap: Callable[[bytes, object], None]) -> None:
        """Call ``tap(data, addr)`` with every chunk of bytes received on this link, before the
        station core decodes it (UDP: one datagram; TCP/serial: whatever the read returned)."""
        self._taps.append(tap)

    def _tap_raw(self, data: bytes, addr: Any) -> None:
        self._tap_peers[addr] = None
        for tap in self._taps:
            try:
                tap(data, addr)
            except Exception:
                log.exception("link %d: tap failed", self.link_id)

    def send_raw(self, frame: bytes) -> None:
        """Send one MAVLink frame as is to this link's peers (the static ones and every address
        heard since the first tap), and write it to the .tlog as an outgoing frame."""
        if self.core is None:
            return
        peers = list(dict.fromkeys((*self.core.config.static_peers, *self._tap_peers))) or [None]
        for addr in peers:
            try:
                self._send(frame, addr)
            except (OSError, TypeError) as exc:  # unreachable / not yet connected
                log.debug("link %d: raw send to %s failed: %s", self.link_id, addr, exc)
            if self.spec.kind not in ("udpin",):
                break  # connected socket, TCP or serial: one peer whatever addr says
        if self._tlog is not None:
            self._tlog.write(self.now() + self.core.config.unix_time_at_zero_s, frame)

    def _on_timer(self) -> None:
        self._timer = None
        core = self.core
        if core is not None:
            due = core.next_timer_s()
            if due is None or self.now() >= due:
                core.handle_timer(self.now())
            else:
                # Early: the wall-time estimate ran ahead of the core's clock (a paced clock held
                # back by lock-step). By next_timer_s's contract nothing is due before it, and
                # handle_timer scans every vehicle: skip it and re-arm (transmit).
                self.early_wakeups += 1
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
        out = core.datagrams_to_send(self.now())
        if self.coalesce and len(out) > 1:
            out = [(data, addr) for addr, data in coalesce_datagrams((a, d) for d, a in out)]
        for data, addr in out:
            try:
                self._send(data, addr)
            except OSError as exc:  # unreachable peer: the link layer copes with loss
                log.debug("link %d: send to %s failed: %s", self.link_id, addr, exc)
        if self._tlog is not None:
            self._tlog.write_frames(core.take_frames())
        t = core.next_timer_s()
        if t is not None:
            # Core seconds -> wall seconds: under a speed-up every station timer (the 1 Hz GCS
            # heartbeat included) must follow the vehicles' clock (docs/design/mavlink.md §4.2).
            loop = asyncio.get_running_loop()
            assert self._clock is not None  # set by start()
            when = loop.time() + self._clock.wall_delay_s(t - self.now())
            # Keep a pending timer that is due no later: cancelling and re-arming it on every
            # received datagram starved it under steady traffic (asyncio runs the I/O callbacks
            # of an iteration before the timers that fell due, so a due timer was cancelled
            # before it could run, and heartbeats and setpoints stopped). An early wake-up is
            # harmless: handle_timer recomputes the next deadline and transmit re-arms.
            if self._timer is None or self._timer.cancelled() or when < self._timer.when():
                if self._timer is not None:
                    self._timer.cancel()
                self._timer = loop.call_at(when, self._on_timer)

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        for close in reversed(self._closers):
            close()
        self._closers.clear()


async def open_links(
    connections: list[str], config: StationConfig | None = None, **kwargs: Any
) -> list[StationAdapter]:
    """Start one adapter per connection string, with link ids 0, 1, ..."""
    return [
        await StationAdapter(c, config, link_id=i, **kwargs).start()
        for i, c in enumerate(connections)
    ]

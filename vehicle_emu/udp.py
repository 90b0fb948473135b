"""Thin asyncio UDP adapter for :class:`vehicle_emu.swarm.Swarm` (docs/design/architecture.md §2.1).

Cycle (after aioquic ``transmit()``): receive -> ``swarm.receive_datagram(endpoint, data, addr,
clock.now())`` -> send everything from ``datagrams_to_send`` -> re-arm one timer at
``next_timer_s()`` (converted to wall time through the clock's speed-up).

Endpoint layout: SITL style, endpoint ``e`` bound at ``base_port + e`` (one socket per vehicle,
or per network with ``Swarm(mux=True)``), or every endpoint on an ephemeral port when
``base_port == 0`` (tests). Binds 127.0.0.1 by default.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import socket
import threading
import time

from mavedge.clock import Clock, PacedClock, RealClock
from mavedge.codec import coalesce_datagrams

from .link import RateLimitedLog
from .swarm import Swarm

__all__ = ["EmulatorServer", "run_in_thread", "ThreadedEmulator"]

log = logging.getLogger(__name__)


class _EndpointProtocol(asyncio.DatagramProtocol):
    def __init__(self, server: EmulatorServer, endpoint: int) -> None:
        self.server = server
        self.endpoint = endpoint

    def datagram_received(self, data: bytes, addr) -> None:
        self.server._on_datagram(self.endpoint, data, addr)

    def error_received(self, exc: Exception) -> None:  # e.g. ICMP port unreachable
        self.server.n_socket_errors += 1
        log.debug("endpoint %d: socket error %s", self.endpoint, exc)


class EmulatorServer:
    """Runs a swarm on real sockets and a clock.

    Parameters
    ----------
    swarm : Swarm
    clock : Clock
        Vehicle clock (a :class:`~mavedge.clock.RealClock` with its speed-up); a
        :class:`~mavedge.clock.PacedClock` is advanced once per timer iteration (lock-step with
        a station in another process).
    host : str
        Bind address (loopback by default).
    base_port : int
        Endpoint ``e`` binds ``base_port + e``; 0 = ephemeral ports.
    coalesce : bool
        Join what one flush sends to one address from one endpoint into datagrams of up to
        :data:`mavedge.codec.MAX_DATAGRAM_BYTES` (:func:`mavedge.codec.coalesce_datagrams`),
        as a radio modem or router packs frames: the receiver gets the same frames in the same
        order, in fewer datagrams (with ``Swarm(mux=True)`` a network's vehicles share an
        endpoint: a burst of telemetry from hundreds of them is a few datagrams, not one each).
        The radio model has already decided each vehicle datagram's fate (``Swarm.datagrams_to_send``).
    """

    def __init__(
        self,
        swarm: Swarm,
        clock: Clock,
        host: str = "127.0.0.1",
        base_port: int = 0,
        *,
        coalesce: bool = True,
    ) -> None:
        self.swarm = swarm
        self.coalesce = bool(coalesce)
        self.clock = clock
        self.host = host
        self.base_port = int(base_port)
        self.transports: list[asyncio.DatagramTransport] = []
        self.addresses: list[tuple[str, int]] = []
        self.n_socket_errors = 0
        self.n_events = 0
        self._timer: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._closed = False
        self._readers: list | None = None
        #: Errors caused by what arrives on the sockets are logged at most once per interval.
        self.log_limiter = RateLimitedLog(log)

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self._loop = loop
        for e in range(self.swarm.n_endpoints):
            port = self.base_port + e if self.base_port else 0
            transport, _ = await loop.create_datagram_endpoint(
                functools.partial(_EndpointProtocol, self, e), local_addr=(self.host, port)
            )
            self.transports.append(transport)
            self.addresses.append(transport.get_extra_info("sockname")[:2])
        log.info(
            "emulating %d vehicles on %d endpoint(s) %s:%d..%d",
            self.swarm.n,
            len(self.addresses),
            self.host,
            self.addresses[0][1],
            self.addresses[-1][1],
        )
        self._on_timer()

    def _on_datagram(self, endpoint: int, data: bytes, addr) -> None:
        now = self.clock.now()
        self._receive(endpoint, data, addr, now)
        self._flush(now)

    def _receive(self, endpoint: int, data: bytes, addr, now: float) -> None:
        try:
            self.swarm.receive_datagram(endpoint, data, addr, now)
        except Exception:  # noqa: BLE001 - never let one packet kill the loop
            self.log_limiter.log(
                now,
                "receive",
                logging.ERROR,
                "endpoint %d: error handling a datagram from %s",
                endpoint,
                addr,
                exc_info=True,
            )

    def _drain(self, now: float, limit: int = 4096) -> None:
        """Read every datagram already queued on the sockets before time moves on.

        asyncio's datagram transport reads one datagram per socket per loop iteration; when a
        station streams to a fleet (PX4: 10 Hz setpoints per vehicle) faster than that, the
        backlog would grow while simulated time advances, and the vehicles would see their
        streams stall (PX4 leaves OFFBOARD when the last setpoint is older than COM_OF_LOSS_T).
        Under lock-step pacing, simulated time must not move on until what the station has
        already sent is delivered."""
        if self._readers is None:
            self._readers = []
            for transport in self.transports:
                ts = transport.get_extra_info("socket")  # asyncio's wrapper: no recvfrom
                sock = socket.fromfd(ts.fileno(), ts.family, ts.type) if ts is not None else None
                if sock is not None:
                    sock.setblocking(False)
                self._readers.append(sock)
        for endpoint, sock in enumerate(self._readers):
            if sock is None:
                continue
            for _ in range(limit):
                try:
                    data, addr = sock.recvfrom(65536)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    self.n_socket_errors += 1
                    break
                self._receive(endpoint, data, addr, now)
        self._flush(now)

    def _flush(self, now: float) -> None:
        transports = self.transports
        out = self.swarm.datagrams_to_send(now)
        if self.coalesce and len(out) > 1:
            out = [
                (endpoint, data, addr)
                for (endpoint, addr), data in coalesce_datagrams(
                    ((endpoint, addr), data) for endpoint, data, addr in out
                )
            ]
        for endpoint, data, addr in out:
            try:
                transports[endpoint].sendto(data, addr)  # type: ignore[arg-type]  # (host, port) or None
            except (OSError, ValueError, TypeError) as exc:
                self.n_socket_errors += 1
                self.log_limiter.log(
                    now, "sendto", logging.DEBUG, "sendto %s failed: %s", addr, exc
                )
        ev = self.swarm.next_event()
        while ev is not None:
            self.n_events += 1
            log.info("%s", ev)
            ev = self.swarm.next_event()

    def _on_timer(self) -> None:
        if self._closed:
            return
        paced = self.clock if isinstance(self.clock, PacedClock) else None
        assert self._loop is not None  # set by start()
        woke_wall_s = self._loop.time()
        if paced is not None:  # lock-step: deliver what the station sent, then move time
            self._drain(paced.now())
        now = paced.advance() if paced is not None else self.clock.now()
        try:
            self.swarm.handle_timer(now)
        except Exception:  # noqa: BLE001
            self.log_limiter.log(
                now, "tick", logging.ERROR, "swarm tick failed at t=%.3f", now, exc_info=True
            )
        self._flush(now)
        if paced is None:
            delay = self.clock.wall_delay_s(self.swarm.next_timer_s() - self.clock.now())
            self._timer = self._loop.call_later(delay, self._on_timer)
            return
        # A paced clock stands still while this iteration works, so the next wake-up is timed
        # from when this one woke, not from now: timed from now, every period was the tick plus
        # the iteration's own work, and at 10x with 500 vehicles the iterations that came more
        # than max_step_s apart lost simulated time (PacedClock.stats "held_by_step_s",
        # docs/results/scale.md). A paced clock may also be held back by the station: look
        # again within one tick.
        delay = self.clock.wall_delay_s(min(self.swarm.next_timer_s() - now, self.swarm.tick_s))
        self._timer = self._loop.call_at(woke_wall_s + delay, self._on_timer)

    def close(self) -> None:
        self._closed = True
        if self._timer is not None:
            self._timer.cancel()
        for sock in self._readers or ():
            if sock is not None:
                sock.close()
        self._readers = None
        for t in self.transports:
            t.close()
        self.transports = []


class ThreadedEmulator:
    """An :class:`EmulatorServer` on its own event loop in a background thread (tests, demos).

    ``addresses`` is valid after construction returns; :meth:`call` runs a function on the
    emulator thread (the swarm must only be touched there) and returns its result.
    """

    def __init__(
        self,
        swarm: Swarm,
        speedup: float = 1.0,
        host: str = "127.0.0.1",
        base_port: int = 0,
        start_timeout_s: float = 10.0,
    ) -> None:
        self.swarm = swarm
        self.loop = asyncio.new_event_loop()
        self.clock = RealClock(speedup, time_fn=time.monotonic)
        self.server = EmulatorServer(swarm, self.clock, host, base_port)
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, name="vehicle-emu", daemon=True)
        self.thread.start()
        if not self._ready.wait(start_timeout_s):
            raise TimeoutError("emulator did not start")
        if self._error is not None:
            raise self._error

    @property
    def addresses(self) -> list[tuple[str, int]]:
        return self.server.addresses

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self.server.start())
        except BaseException as exc:  # noqa: BLE001 - reported to the constructor
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        self.loop.run_forever()
        self.server.close()
        self.loop.close()

    def call(self, fn, timeout_s: float = 5.0):
        """Run ``fn()`` on the emulator thread and return its result."""
        fut = asyncio.run_coroutine_threadsafe(self._acall(fn), self.loop)
        return fut.result(timeout_s)

    @staticmethod
    async def _acall(fn):
        return fn()

    def stop(self, timeout_s: float = 5.0) -> None:
        if self.loop.is_running():
            self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout_s)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def run_in_thread(swarm: Swarm, speedup: float = 1.0, **kwargs) -> ThreadedEmulator:
    """Start ``swarm`` on loopback UDP in a background thread."""
    return ThreadedEmulator(swarm, speedup=speedup, **kwargs)

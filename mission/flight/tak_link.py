"""The station's TAK connections: crews' Cursor-on-Target reports in, the mesh's picture out.

One :class:`TakLink` holds every TAK connection of a flight (``phireman fly --tak URL``, and the
``url`` of the mission's ``tak`` crews), opened with pytak's transports (``pytak.protocol_factory``:
UDP unicast / multicast / broadcast, TCP, TLS with client certificates, its COT_URL spelling and
its ``PYTAK_TLS_*`` configuration names). It runs on the station's asyncio loop:

* **in**: every datagram (UDP) or framed message (TCP / TLS, :class:`gcs.cot.CotStream`) is
  parsed (:func:`gcs.cot.parse_cot`: XML or TAK protocol v1); a position report of a contact
  (type ``a-*``) becomes a :class:`gcs.tak.TakContactReported` on the station's clock, its
  stale time the event's own lifetime (``stale - time``, so a phone's clock offset does not
  matter) scaled by the flight's speed-up. Bad input is counted and dropped, never raised
  (docs/design/architecture.md §7); the station's own events (uid prefix :data:`OWN_UID_PREFIX`,
  heard back on a multicast group) are ignored.
* **out**: :meth:`TakLink.send` never blocks the control tick: a bounded queue per connection,
  the oldest message dropped (and counted) when it is full, a writer task draining it.
"""

from __future__ import annotations

import asyncio
import collections
import configparser
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from gcs.cot import CotError, CotStream, parse_cot
from gcs.tak import TakContactReported

__all__ = [
    "TakLink",
    "TakConnection",
    "OWN_UID_PREFIX",
    "MESH_SA_URL",
    "TX_QUEUE_MAX",
    "MAX_RATE_MSGS_S",
]

log = logging.getLogger(__name__)

#: Every uid the station publishes starts with this (its own events heard back are ignored).
OWN_UID_PREFIX = "phireman-"

#: ATAK's mesh situational awareness: the default when a crew names no TAK connection.
MESH_SA_URL = "udp://239.2.3.1:6969"

#: Messages per second per TAK connection, at most (``--tak-max-rate``). A TAK server relays
#: every message to every client: FreeTAKServer 2.2.1 on the project's 2-core machine relayed 25
#: messages a second from one client with up to 2.7 s of delay under load, and fell behind
#: (dropping crews' own reports) at the 50 a second a 6-drone picture took every half second.
MAX_RATE_MSGS_S = 20.0

#: Messages waiting per connection before the oldest is dropped.
TX_QUEUE_MAX = 512


@dataclass
class TakConnection:
    """One open TAK connection (its pytak reader / writer and counters)."""

    url: str
    reader: Any = None
    writer: Any = None
    queue: collections.deque[bytes] = field(
        default_factory=lambda: collections.deque(maxlen=TX_QUEUE_MAX)
    )
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    counters: dict[str, int] = field(
        default_factory=lambda: {
            "received": 0,
            "reports": 0,
            "bad": 0,
            "own": 0,
            "not_position": 0,
            "sent": 0,
            "dropped": 0,
            "send_errors": 0,
        }
    )

    @property
    def datagram(self) -> bool:
        return self.url.lower().startswith("udp")


class TakLink:
    """Every TAK connection of a flight.

    Parameters
    ----------
    urls : pytak COT_URLs (``udp://239.2.3.1:6969``, ``tcp://H:P``, ``tls://H:P``; ``+ro`` /
        ``+wo`` for read / write only)
    on_event : called with every :class:`TakContactReported`
    clock : the station's clock (seconds)
    speedup : the flight's speed-up (a CoT lifetime is wall seconds)
    tls : pytak's TLS settings (``PYTAK_TLS_CLIENT_CERT``, ``PYTAK_TLS_CLIENT_KEY``,
        ``PYTAK_TLS_CLIENT_CAFILE``, ``PYTAK_TLS_CLIENT_PASSWORD``, ``PYTAK_TLS_DONT_VERIFY``,
        ``PYTAK_TLS_DONT_CHECK_HOSTNAME``)
    unix_time : wall clock, Unix seconds (tests)
    """

    def __init__(
        self,
        urls: list[str],
        on_event: Callable[[TakContactReported], None],
        *,
        clock: Callable[[], float],
        speedup: float = 1.0,
        tls: Mapping[str, str] | None = None,
        unix_time: Callable[[], float] = time.time,
    ) -> None:
        self.urls = list(dict.fromkeys(urls))
        self.on_event = on_event
        self.clock = clock
        self.speedup = speedup
        self.tls = dict(tls or {})
        self.unix_time = unix_time
        self.connections: list[TakConnection] = []
        self._tasks: list[asyncio.Task[None]] = []

    async def start(self) -> TakLink:
        import pytak  # the transports (imported here: only flights with TAK pay for it)

        for url in self.urls:
            cfg = configparser.ConfigParser()
            cfg["tak"] = {"COT_URL": url, **self.tls}
            reader, writer = await pytak.protocol_factory(cfg["tak"])
            conn = TakConnection(url, reader, writer)
            self.connections.append(conn)
            if reader is not None:
                self._tasks.append(asyncio.create_task(self._rx(conn)))
            if writer is not None:
                self._tasks.append(asyncio.create_task(self._tx(conn)))
            log.info("TAK connection %s open (%s)", url, _direction(reader, writer))
        return self

    # ------------------------------------------------------------------ in

    def receive(self, conn: TakConnection, message: bytes) -> TakContactReported | None:
        """One message off ``conn``: the report it carries (also given to ``on_event``), or
        None (counted: bad, own, not a position)."""
        conn.counters["received"] += 1
        try:
            ev = parse_cot(message)
        except CotError as exc:
            conn.counters["bad"] += 1
            log.debug("TAK %s: dropped a message: %s", conn.url, exc)
            return None
        if ev.uid.startswith(OWN_UID_PREFIX):
            conn.counters["own"] += 1
            return None
        if not ev.type.startswith("a-"):  # atoms are contacts; b-/u-/t- are not positions
            conn.counters["not_position"] += 1
            return None
        now = self.clock()
        try:
            rep = TakContactReported(
                t_s=now,
                uid=ev.uid,
                callsign=ev.callsign,
                lat_deg=ev.lat_deg,
                lon_deg=ev.lon_deg,
                hae_m=ev.hae_m,
                stale_s=now + ev.lifetime_s * self.speedup,
                cot_type=ev.type,
            )
        except ValueError:
            conn.counters["bad"] += 1
            return None
        conn.counters["reports"] += 1
        self.on_event(rep)
        return rep

    async def _rx(self, conn: TakConnection) -> None:
        stream = CotStream()
        try:
            while True:
                if conn.datagram:
                    data, _addr = await conn.reader.recv()
                    messages = [bytes(data)]
                else:
                    data = await conn.reader.read(65536)
                    if not data:
                        log.warning("TAK %s: the server closed the connection", conn.url)
                        return
                    messages = stream.feed(data)
                for m in messages:
                    self.receive(conn, m)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # a transport failure must not take the station down
            log.warning("TAK %s: receiving stopped: %s", conn.url, exc)

    # ------------------------------------------------------------------ out

    def send(self, messages: list[bytes]) -> None:
        """Queue ``messages`` on every writable connection; never blocks (drop oldest)."""
        for conn in self.connections:
            if conn.writer is None:
                continue
            for m in messages:
                if len(conn.queue) == conn.queue.maxlen:
                    conn.counters["dropped"] += 1
                conn.queue.append(m)
            conn.wake.set()

    async def _tx(self, conn: TakConnection) -> None:
        while True:
            await conn.wake.wait()
            conn.wake.clear()
            while conn.queue:
                m = conn.queue.popleft()
                try:
                    if conn.datagram:
                        await conn.writer.send(m)
                    else:
                        conn.writer.write(m)
                        await conn.writer.drain()
                    conn.counters["sent"] += 1
                except asyncio.CancelledError:
                    raise
                except Exception as exc:
                    conn.counters["send_errors"] += 1
                    log.debug("TAK %s: send failed: %s", conn.url, exc)

    def counters(self) -> dict[str, int]:
        """Every connection's counters added up."""
        total: dict[str, int] = collections.Counter()
        for c in self.connections:
            total.update(c.counters)
        return dict(total)

    async def aclose(self) -> None:
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            try:
                await t
            except (asyncio.CancelledError, Exception):
                pass
        for c in self.connections:
            for end in (c.reader, c.writer):
                close = getattr(end, "close", None)
                if close is not None:
                    try:
                        close()
                    except Exception:
                        pass


def _direction(reader: object, writer: object) -> str:
    if reader is not None and writer is not None:
        return "in and out"
    return "in only" if reader is not None else "out only"

"""A crew's TAK phone for the TAK integration tests: a pytak client that reports a position track
as Cursor on Target and counts what it receives (by CoT type, and the crew connectivity markers
by label), recording when each marker was seen where. Used over loopback UDP
(tests/integration/test_tak_udp.py) and through a TAK server (tests/integration/test_tak_server.py).
"""

from __future__ import annotations

import asyncio
import collections
import configparser
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gcs.cot import CotError, CotStream, cot_xml, parse_cot
from planner.geometry import geodetic_to_ned_m, ned_to_geodetic

__all__ = ["CrewPhone", "ORIGIN", "tak_mission"]

#: The small test missions' origin (tests/small_mission.py: the schema's default origin).
ORIGIN = (-35.36326, 149.16523, 584.0)


def tak_mission(path: Path, *, duration_s: float, speedup: float, seed: int = 3) -> Path:
    """Write the TAK tests' mission to ``path``: six emulated vehicles, the crew ``Alpha`` (TAK
    callsign ``ALPHA``) and one slot ``Engine`` for any ``ENGINE-*`` contact."""
    from mission.format.load import dump_mission
    from mission.format.schema import RunSpec, TakSource, Task
    from small_mission import small_mission

    m = small_mission(
        "tak",
        RunSpec(duration_s=duration_s, seed=seed, speedup=speedup),
        count=6,
        tasks=(
            Task(name="Alpha", tak=TakSource(callsign="ALPHA")),
            Task(name="Engine", tak=TakSource(callsign_pattern="ENGINE-*")),
        ),
    )
    path.write_text(dump_mission(m))
    return path


@dataclass
class CrewPhone:
    """One crew's phone: ``track(t)`` gives (north, east) metres from the base ``t`` wall seconds
    after the phone first heard the station (0 until then: a loaded machine may take many
    seconds to start ``phireman fly``); reports every ``period_s`` until ``stop_after_s`` on that
    clock (then silent)."""

    uid: str
    callsign: str
    track: Callable[[float], tuple[float, float]]
    stop_after_s: float = 1e9
    period_s: float = 0.25
    stale_after_s: float = 2.0
    got: collections.Counter[str] = field(default_factory=collections.Counter)
    markers: collections.Counter[str] = field(default_factory=collections.Counter)
    """Crew connectivity markers (``b-m-p-s-m``) received, by label (``Alpha: mesh OK``)."""
    marker_log: list[tuple[float, str, float, float]] = field(default_factory=list)
    """(wall time, label, north, east) of every crew marker received."""
    sent_log: list[tuple[float, float, float]] = field(default_factory=list)
    """(wall time, north, east) of every report sent."""
    heard_s: float | None = None
    """Wall time (monotonic) of the first message from the station."""

    def _event(self, n: float, e: float) -> bytes:
        lat, lon, _ = ned_to_geodetic(np.array([n, e, 0.0]), *ORIGIN)
        return cot_xml(
            uid=self.uid,
            type="a-f-G-U-C",
            lat_deg=float(lat),
            lon_deg=float(lon),
            hae_m=600.0,
            now_unix_s=time.time(),
            stale_after_s=self.stale_after_s,
            callsign=self.callsign,
        )

    def _received(self, data: bytes) -> None:
        try:
            ev = parse_cot(data)
        except CotError:
            self.got["bad"] += 1
            return
        self.got[ev.type] += 1
        if self.heard_s is None and ev.uid.startswith("phireman-"):
            self.heard_s = time.monotonic()
        if ev.type == "b-m-p-s-m" and ev.callsign:
            self.markers[ev.callsign] += 1
            ned = geodetic_to_ned_m(ev.lat_deg, ev.lon_deg, ORIGIN[2], *ORIGIN)
            self.marker_log.append((time.monotonic(), ev.callsign, float(ned[0]), float(ned[1])))

    async def run(self, url_in: str, url_out: str, done: asyncio.Event) -> None:
        """Report and receive until ``done``: ``url_in`` / ``url_out`` are pytak COT_URLs (the
        same ``tcp://`` URL for a TAK server: one connection both ways)."""
        import pytak

        def cfg(url: str) -> configparser.SectionProxy:
            c = configparser.ConfigParser()
            c["c"] = {"COT_URL": url}
            return c["c"]

        if url_in == url_out:  # a stream to a TAK server
            reader, writer = await pytak.protocol_factory(cfg(url_in))
            stream = CotStream()

            async def recv_all() -> None:
                while data := await reader.read(65536):
                    for m in stream.feed(data):
                        self._received(m)

            async def send(msg: bytes) -> None:
                writer.write(msg)
                await writer.drain()

            closers = [writer.close]
        else:  # datagrams: one socket to listen, one to send
            _, out = await pytak.protocol_factory(cfg(url_out))
            inp, _ = await pytak.protocol_factory(cfg(url_in))

            async def recv_all() -> None:
                while True:
                    data, _ = await inp.recv()
                    self._received(data)

            async def send(msg: bytes) -> None:
                await out.send(msg)

            closers = [out.close, inp.close]

        rx = asyncio.create_task(recv_all())
        while not done.is_set():
            t = 0.0 if self.heard_s is None else time.monotonic() - self.heard_s
            if t < self.stop_after_s:
                n, e = self.track(t)
                try:
                    await send(self._event(n, e))
                    self.sent_log.append((time.monotonic(), n, e))
                except OSError:  # the station is not listening yet (ICMP port unreachable)
                    self.got["refused"] += 1
            await asyncio.sleep(self.period_s)
        rx.cancel()
        for close in closers:
            close()

    def marker_latency_s(self, label_prefix: str, ne_m: tuple[float, float], tol_m: float) -> float:
        """Wall seconds from the first report sent at ``ne_m`` to the first crew marker whose
        label starts with ``label_prefix`` received within ``tol_m`` of it (NaN: never)."""
        sent = [t for t, n, e in self.sent_log if np.hypot(n - ne_m[0], e - ne_m[1]) < 1e-6]
        if not sent:
            return float("nan")
        seen = [
            t
            for t, label, n, e in self.marker_log
            if label.startswith(label_prefix)
            and t >= sent[0]
            and np.hypot(n - ne_m[0], e - ne_m[1]) < tol_m
        ]
        return seen[0] - sent[0] if seen else float("nan")

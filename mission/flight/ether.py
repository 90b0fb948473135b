"""The in-memory MAVLink ether: the station's links and an emulated swarm exchanging datagrams
on a virtual clock, with seeded loss - the full protocol path with no sockets and no
nondeterminism (docs/design/architecture.md §3.1, driver 2). Most integration tests fly through it.

* :class:`LockstepEther` - moves datagrams both ways and advances both sides' timers;
* :func:`station_for_swarm` - a station with one in-memory link per network of a swarm.

Typical use (``tests/integration/test_pair.py``)::

    swarm = build_swarm(mission, scenario, seed=seed)       # mission.flight.mission_world
    station = station_for_swarm(swarm)
    ether = LockstepEther(swarm, station, np.random.default_rng(seed), loss=0.05)
    ether.advance_to(t_s, poll=operator.poll)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from gcs.link import StationConfig, StationLink
from gcs.station import Station
from vehicle_emu.swarm import Swarm

__all__ = ["LockstepEther", "station_for_swarm"]


class LockstepEther:
    """The station's links and a swarm exchanging datagrams in memory on a virtual clock.

    Station link ``k`` talks to the swarm's endpoint ``k`` (the swarm must be ``mux=True``).
    ``loss`` drops each datagram (either direction) with that probability, from ``rng``;
    ``cut(link)`` / ``restore(link)`` sever a whole link (a dead station, a cable pulled).
    """

    def __init__(
        self,
        swarm: Swarm,
        station: Station,
        rng: np.random.Generator,
        loss: float = 0.0,
        now_s: float = 0.0,
    ) -> None:
        if not swarm.mux:
            raise ValueError("LockstepEther needs Swarm(mux=True): one endpoint per network")
        self.swarm = swarm
        self.station = station
        self.rng = rng
        self.loss = float(loss)
        self.now_s = float(now_s)
        self.cut_links: set[int] = set()
        self.on_event: Callable | None = None
        self.frames_to_vehicles = 0
        self.frames_to_station = 0

    def _drop(self) -> bool:
        return self.loss > 0 and self.rng.random() < self.loss

    def pump(self) -> None:
        """Move everything queued on both sides (repeat until quiet)."""
        for _ in range(4):
            moved = 0
            for lid, data, _addr in self.station.datagrams_to_send(self.now_s):
                if lid in self.cut_links or self._drop():
                    continue
                self.swarm.receive_datagram(lid, data, ("gcs", lid), self.now_s)
                self.frames_to_vehicles += 1
                moved += 1
            for endpoint, data, addr in self.swarm.datagrams_to_send(self.now_s):
                if addr != ("gcs", endpoint) or endpoint in self.cut_links or self._drop():
                    continue
                self.station.link(endpoint).receive_datagram(data, ("emu", endpoint), self.now_s)
                self.frames_to_station += 1
                moved += 1
            for ev in self.station.events():
                if self.on_event is not None:
                    self.on_event(ev)
            if not moved:
                break

    def advance_to(
        self,
        t_s: float,
        *,
        poll: Callable[[float], None] | None = None,
        poll_period_s: float | None = None,
    ) -> None:
        """Run both sides up to ``t_s``: swarm ticks, station timers, optional poll callback."""
        next_poll = self.now_s if poll is not None else math.inf
        while True:
            t_swarm = self.swarm.next_timer_s()
            t_station = self.station.next_timer_s()
            t_next = min(t_swarm, t_station if t_station is not None else math.inf, next_poll)
            if t_next > t_s:
                break
            self.now_s = max(self.now_s, t_next)
            if self.now_s >= t_swarm - 1e-12:
                self.swarm.handle_timer(self.now_s)
            if t_station is not None and self.now_s >= t_station:
                self.station.handle_timer(self.now_s)
            if poll is not None and self.now_s >= next_poll:
                poll(self.now_s)
                next_poll = self.now_s + (poll_period_s or 0.25)
            self.pump()
        self.now_s = t_s


def station_for_swarm(swarm: Swarm, now_s: float = 0.0, **config) -> Station:
    """A station with one in-memory link per MAVLink network of ``swarm`` (for the ether)."""
    cfg = StationConfig(static_peers=(), **config)
    links = [
        StationLink(dataclasses.replace(cfg, static_peers=(("emu", k),)), link_id=k, now_s=now_s)
        for k in range(swarm.n_networks)
    ]
    return Station(links)

"""Several links as one sans-I/O station: vehicles addressed by ``(link_id, sysid)``.

Sysids are 8-bit, so more than ~250 vehicles need several MAVLink networks (docs/design/mavlink.md §5.4);
each network is one :class:`~gcs.link.StationLink`. This object only routes: per-vehicle calls go
to the right link, timers and events are merged. It owns no sockets and reads no clock.
"""

from __future__ import annotations

from collections.abc import Sequence

from gcs.events import Event
from gcs.link import StationLink, UnknownVehicle, VehicleInfo

__all__ = ["Station", "VehicleId"]

VehicleId = tuple[int, int]
"""``(link_id, sysid)``: a vehicle's identity across links."""


class Station:
    def __init__(self, links: Sequence[StationLink]) -> None:
        self._links = {link.link_id: link for link in links}
        if len(self._links) != len(links):
            raise ValueError("link ids must be unique")

    @property
    def links(self) -> list[StationLink]:
        return list(self._links.values())

    def link(self, link_id: int) -> StationLink:
        try:
            return self._links[link_id]
        except KeyError:
            raise UnknownVehicle(f"no link {link_id}") from None

    # ---------------------------------------------------------------- sans-I/O surface

    def next_timer_s(self) -> float | None:
        times = [t for link in self._links.values() if (t := link.next_timer_s()) is not None]
        return min(times) if times else None

    def handle_timer(self, now_s: float) -> None:
        for link in self._links.values():
            t = link.next_timer_s()
            if t is not None and t <= now_s:
                link.handle_timer(now_s)

    def next_event(self) -> Event | None:
        for link in self._links.values():
            if (ev := link.next_event()) is not None:
                return ev
        return None

    def events(self) -> list[Event]:
        """Drain every pending event, link by link, each link's in order."""
        out: list[Event] = []
        for link in self._links.values():
            while (ev := link.next_event()) is not None:
                out.append(ev)
        return out

    def datagrams_to_send(self, now_s: float) -> list[tuple[int, bytes, object]]:
        """``(link_id, data, addr)`` for every link."""
        return [
            (lid, data, addr)
            for lid, link in self._links.items()
            for data, addr in link.datagrams_to_send(now_s)
        ]

    # ---------------------------------------------------------------- vehicles

    def vehicles(self) -> list[VehicleInfo]:
        return [v for link in self._links.values() for v in link.vehicles()]

    def networked(self) -> list[VehicleId]:
        return [(lid, s) for lid, link in self._links.items() for s in link.networked_sysids()]

    def set_position_target(
        self, vid: VehicleId, lat_deg: float, lon_deg: float, alt_above_home_m: float, now_s: float
    ) -> None:
        self.link(vid[0]).set_position_target(vid[1], lat_deg, lon_deg, alt_above_home_m, now_s)

    def clear_position_target(self, vid: VehicleId, now_s: float) -> None:
        self.link(vid[0]).clear_position_target(vid[1], now_s)

    def withdraw_flight_commands(self, vid: VehicleId, now_s: float, reason: str) -> int:
        return self.link(vid[0]).withdraw_flight_commands(vid[1], now_s, reason)

    def set_mode(self, vid: VehicleId, mode: str, now_s: float) -> int:
        return self.link(vid[0]).set_mode(vid[1], mode, now_s)

    def engage_guided(self, vid: VehicleId, now_s: float) -> int:
        return self.link(vid[0]).engage_guided(vid[1], now_s)

    def arm(self, vid: VehicleId, now_s: float) -> int:
        return self.link(vid[0]).arm(vid[1], now_s)

    def takeoff(self, vid: VehicleId, alt_above_home_m: float, now_s: float) -> int | None:
        return self.link(vid[0]).takeoff(vid[1], alt_above_home_m, now_s)

    def rtl(self, vid: VehicleId, now_s: float) -> int:
        return self.link(vid[0]).rtl(vid[1], now_s)

    def land(self, vid: VehicleId, now_s: float) -> int:
        return self.link(vid[0]).land(vid[1], now_s)

    def send_message(self, vid: VehicleId, msg: object, now_s: float) -> None:
        self.link(vid[0]).send_message(vid[1], msg, now_s)

    def request_param(self, vid: VehicleId, name: str, now_s: float) -> None:
        self.link(vid[0]).request_param(vid[1], name, now_s)

    def set_param(
        self,
        vid: VehicleId,
        name: str,
        value: float,
        param_type: int,
        now_s: float,
        *,
        previous: float | None = None,
    ) -> None:
        self.link(vid[0]).set_param(vid[1], name, value, param_type, now_s, previous=previous)

"""The mesh on TAK: the station's picture as Cursor-on-Target events (``phireman fly --tak``).

:func:`picture_cot` builds one batch (pure: the operator's state and explicit times in, CoT XML
out); :func:`attach` publishes a batch every ``FlyOptions.tak_period_s`` wall seconds on the
station's loop through :class:`mission.flight.tak_link.TakLink` (bounded queue, drop oldest), so
each uid is sent at most once a period. What is sent (docs/tak.md):

* every vehicle heard: ``a-f-A-M-H-Q`` (friendly, air, military, rotary wing, drone: MIL-STD-2525
  "UAV rotary wing", the icon ATAK draws for a friendly multicopter UAV), callsign ``UAV 7``
  (``UAV 1:7`` on a second MAVLink link), course and speed from its velocity, its state and
  altitudes in ``remarks``. ``hae`` carries the altitude above mean sea level the autopilot
  reports (GLOBAL_POSITION_INT.alt): the station has no geoid model, so it is off from the true
  height above the ellipsoid by the local geoid undulation (about -107..+85 m worldwide);
* the base: ``a-f-G-I`` (friendly ground installation), callsign ``BASE``;
* radio links (vehicle-vehicle, vehicle-crew, vehicle-base, within the mission's radio range)
  and the task tree's edges: ``u-d-f`` drawing shapes (a polyline of two ``<link point>``s, what
  ATAK itself sends for a drawn line; ``b-m-r`` is a route, which ATAK offers to navigate);
  radio links green, tree edges orange;
* each crew's connectivity: a spot marker ``b-m-p-s-m`` at the crew, green "mesh OK" /
  red "NO MESH" / grey "UNKNOWN" (stale TAK report), with since when in ``remarks``.

Every event is ``stale`` after :data:`STALE_PERIODS` periods (at least :data:`MIN_STALE_S`):
if the station dies its picture disappears from every TAK client within seconds.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np

from gcs.cot import cot_time, cot_xml
from mission.flight.tak_link import MAX_RATE_MSGS_S, OWN_UID_PREFIX
from mission.view.live.state import classify, crew_names, mst_tree, radio_links, tree_from_planner
from planner.geometry import ned_to_geodetic, tasks_connected

__all__ = [
    "attach",
    "picture_cot",
    "CotItem",
    "Throttle",
    "MAX_RATE_MSGS_S",
    "MOVE_M",
    "CrewLinkTracker",
    "UAV_TYPE",
    "BASE_TYPE",
    "LINE_TYPE",
    "CREW_STATUS_TYPE",
    "STALE_PERIODS",
    "MIN_STALE_S",
]

log = logging.getLogger(__name__)

UAV_TYPE = "a-f-A-M-H-Q"
BASE_TYPE = "a-f-G-I"
LINE_TYPE = "u-d-f"
CREW_STATUS_TYPE = "b-m-p-s-m"
#: A published event holds this many publishing periods ...
STALE_PERIODS = 5.0
#: ... and at least this long, wall seconds.
MIN_STALE_S = 5.0
#: Links published at most (shortest first): a TAK server must not be flooded.
MAX_TAK_LINKS = 200

#: An item is sent again before its refresh only when it moved this far (metres, on a grid) or
#: its text changed.
MOVE_M = 5.0

# When a picture exceeds the budget: a crew's marker or the base that changed goes first; then
# everything else by how long it has waited, a crew's marker counted as 3 s older, the base 2 s,
# a drone 1 s (seconds of head start over the lines).
_HEAD_START_S = {"crew": 3.0, "base": 2.0, "uav": 1.0, "tree": 0.0, "radio": 0.0}
_URGENT = ("crew", "base")

_GREEN, _RED, _GREY, _ORANGE = -16711936, -65536, -8355712, -23296


@dataclass(frozen=True)
class CotItem:
    """One event of a picture: its CoT ``type``, ``uid``, ``kind`` (crew, base, uav, tree,
    radio: the priority), ``key`` (what it shows: positions on a :data:`MOVE_M` grid, labels;
    an unchanged key need not be sent again before the refresh) and how to ``render`` its XML."""

    type: str
    uid: str
    kind: str
    key: tuple[object, ...]
    render: Callable[[], bytes]
    """Builds the XML: only for the items the throttle sends (most of a big picture waits)."""

    @property
    def xml(self) -> bytes:
        return self.render()


def _grid(*ne_m: float) -> tuple[int, ...]:
    return tuple(int(math.floor(v / MOVE_M)) if math.isfinite(v) else 0 for v in ne_m)


class Throttle:
    """Which items of a picture to send (sans-I/O, explicit time).

    An item is due when it is new, when its key changed (it moved a grid cell, its text
    changed) or when it was last sent ``refresh_s`` ago (so clients do not see it go stale while
    the station lives). At most ``budget`` due items go per picture: first a crew's marker or the
    base that changed, then the rest by how long each has waited (a never-sent item as if sent
    ``refresh_s`` ago), with a head start for crews, the base and the drones over the lines.
    Nothing starves: what waits grows older. What is over budget waits for the next picture."""

    def __init__(self, budget: int, refresh_s: float) -> None:
        if budget < 1:
            raise ValueError(f"budget must be >= 1, got {budget}")
        self.budget = budget
        self.refresh_s = refresh_s
        self._sent: dict[str, tuple[float, tuple[object, ...]]] = {}
        self.deferred = 0
        """Items that were due but waited for a later picture (over budget)."""

    def select(self, items: list[CotItem], now_s: float) -> list[CotItem]:
        ranked = []
        for it in items:
            last = self._sent.get(it.uid)
            changed = last is None or last[1] != it.key
            if not changed and now_s - last[0] < self.refresh_s:  # type: ignore[index]
                continue
            sent_s = now_s - self.refresh_s if last is None else last[0]
            urgent = changed and it.kind in _URGENT
            ranked.append(((not urgent, sent_s - _HEAD_START_S.get(it.kind, 0.0)), it))
        ranked.sort(key=lambda r: r[0])
        out = [it for _, it in ranked[: self.budget]]
        self.deferred += len(ranked) - len(out)
        for it in out:
            self._sent[it.uid] = (now_s, it.key)
        return out


class CrewLinkTracker:
    """Since when each crew has been in its connectivity state ('connected', 'not connected',
    'unknown'), in Unix seconds."""

    def __init__(self) -> None:
        self._state: dict[int, tuple[str, float]] = {}

    def update(self, column: int, state: str, now_unix_s: float) -> float:
        old = self._state.get(column)
        if old is None or old[0] != state:
            self._state[column] = (state, now_unix_s)
            return now_unix_s
        return old[1]


def _line(
    uid: str,
    a: tuple[float, float],
    b: tuple[float, float],
    colour: int,
    label: str,
    now_unix_s: float,
    stale_s: float,
) -> bytes:
    detail = (
        f'<link point="{a[0]:.7f},{a[1]:.7f}"/><link point="{b[0]:.7f},{b[1]:.7f}"/>'
        f'<strokeColor value="{colour}"/><strokeWeight value="2.0"/>'
        '<labels_on value="false"/>'
    )
    return cot_xml(
        uid=uid,
        type=LINE_TYPE,
        how="h-e",
        lat_deg=a[0],
        lon_deg=a[1],
        now_unix_s=now_unix_s,
        stale_after_s=stale_s,
        callsign=label,
        detail_xml=detail,
    )


def picture_cot(
    op,
    mission,
    now_s: float,
    now_unix_s: float,
    *,
    stale_s: float = MIN_STALE_S,
    crews: CrewLinkTracker | None = None,
) -> list[CotItem]:
    """One batch: a :class:`CotItem` for the base, every vehicle heard, the radio links, the
    task tree and every crew's connectivity. ``now_s``: station time; ``now_unix_s``: the
    events' time; ``stale_s``: their lifetime."""
    o = op.fleet.origin
    snap = op.fleet.snapshot(now_s)
    out: list[CotItem] = []
    geo = lambda ne: ned_to_geodetic(  # noqa: E731
        np.column_stack([ne, np.zeros(len(ne))]), o.lat_deg, o.lon_deg, o.alt_amsl_m
    )
    out.append(
        CotItem(
            BASE_TYPE,
            f"{OWN_UID_PREFIX}base",
            "base",
            (op.phase,),
            partial(
                cot_xml,
                uid=f"{OWN_UID_PREFIX}base",
                type=BASE_TYPE,
                lat_deg=o.lat_deg,
                lon_deg=o.lon_deg,
                hae_m=o.alt_amsl_m,
                now_unix_s=now_unix_s,
                stale_after_s=stale_s,
                callsign="BASE",
                remarks=f"phireman base station; phase {op.phase}",
            ),
        )
    )
    n = snap.n_vehicles
    states: list[str] = (
        list(classify(snap, op.released, {(l, s) for _, l, s in op.reclaimed})) if n else []
    )
    heard = ~snap.lost & snap.has_position
    batt = snap.battery_frac  # None: no battery reported by any vehicle
    if heard.any():
        rows = np.flatnonzero(heard)
        lat, lon, alt = ned_to_geodetic(snap.pos_ned_m[rows], o.lat_deg, o.lon_deg, o.alt_amsl_m)
        lat, lon, alt = np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(alt)
        vel = np.nan_to_num(snap.vel_ned_m_s[rows])
        course = np.degrees(np.arctan2(vel[:, 1], vel[:, 0])) % 360.0
        speed = np.hypot(vel[:, 0], vel[:, 1])
        for j, i in enumerate(rows.tolist()):  # one event per vehicle: the codec edge
            link, sysid = int(snap.link_id[i]), int(snap.sysid_of_index[i])
            name = f"UAV {sysid}" if link == 0 else f"UAV {link}:{sysid}"
            above_base = -float(snap.pos_ned_m[i, 2])
            pct = None if batt is None or not np.isfinite(batt[i]) else round(100 * batt[i])
            uid = f"{OWN_UID_PREFIX}uav-{link}-{sysid}"
            key = (*_grid(*snap.pos_ned_m[i]), states[i], snap.mode[i], pct)
            out.append(
                CotItem(
                    UAV_TYPE,
                    uid,
                    "uav",
                    key,
                    partial(
                        cot_xml,
                        uid=uid,
                        type=UAV_TYPE,
                        lat_deg=float(lat[j]),
                        lon_deg=float(lon[j]),
                        hae_m=float(alt[j]),
                        now_unix_s=now_unix_s,
                        stale_after_s=stale_s,
                        callsign=name,
                        course_deg=float(course[j]),
                        speed_m_s=float(speed[j]),
                        remarks=(
                            f"{states[i]}, mode {snap.mode[i] or '?'}; "
                            f"{alt[j]:.0f} m AMSL, {above_base:.0f} m above base"
                            + ("" if pct is None else f"; battery {pct} %")
                        ),
                        detail_xml="" if pct is None else f'<status battery="{pct}"/>',
                    ),
                )
            )
    # Radio links: vehicle-vehicle, vehicle-crew, vehicle-base (the live page's rule).
    r = mission.radio.range_m
    ne = np.where(heard[:, None], snap.pos_ned_m[:, :2], 0.0) if n else np.empty((0, 2))
    t_m = op.t_mission_s(now_s) if op.mission_t0_s is not None else 0.0
    crews_ne = np.asarray(op.task_pos_fn(t_m), dtype=float).reshape(-1, 2)
    crew_ok = np.isfinite(crews_ne).all(axis=1)
    segs: list[tuple[str, np.ndarray, np.ndarray, str]] = []
    vv, _ = radio_links(ne, heard, r, max_links=MAX_TAK_LINKS) if n else (np.empty((0, 2)), 0)
    for a, b in np.asarray(vv, dtype=int).tolist():
        segs.append((f"v{a}-v{b}", ne[int(a)], ne[int(b)], "radio"))
    for k in np.flatnonzero(crew_ok).tolist():
        d = np.linalg.norm(ne - crews_ne[k], axis=1) if n else np.empty(0)
        for i in np.flatnonzero(heard & (d < r)).tolist():
            segs.append((f"v{i}-c{k}", ne[i], crews_ne[k], "radio"))
    base_r = min(r, mission.radio.base_range_m)
    for i in np.flatnonzero(heard & (np.linalg.norm(ne, axis=1) < base_r)).tolist() if n else []:
        segs.append((f"v{i}-base", ne[i], np.zeros(2), "radio"))
    # The task tree: the planner's, else the MST of base, crews and networked vehicles.
    tree = tree_from_planner(op.planner)
    if tree is None and n:
        relay = snap.networked & snap.has_position
        tree = mst_tree(np.zeros(2), crews_ne, snap.pos_ned_m[relay, :2])
    if tree is not None:
        nodes = np.asarray(tree["nodes"], dtype=float).reshape(-1, 2)
        for v, p in enumerate(tree["parent"]):
            if p >= 0 and np.isfinite(nodes[[v, p]]).all():
                segs.append((f"t{v}-{p}", nodes[v], nodes[p], "tree"))
    segs = segs[:MAX_TAK_LINKS]
    if segs:
        pts = np.array([[s[1], s[2]] for s in segs]).reshape(-1, 2)
        lat, lon, _ = geo(pts)
        lat, lon = np.atleast_1d(lat).reshape(-1, 2), np.atleast_1d(lon).reshape(-1, 2)
        for j, (name, a, b, kind) in enumerate(segs):
            out.append(
                CotItem(
                    LINE_TYPE,
                    f"{OWN_UID_PREFIX}{kind}-{name}",
                    kind,
                    _grid(*a, *b),
                    partial(
                        _line,
                        f"{OWN_UID_PREFIX}{kind}-{name}",
                        (float(lat[j, 0]), float(lon[j, 0])),
                        (float(lat[j, 1]), float(lon[j, 1])),
                        _GREEN if kind == "radio" else _ORANGE,
                        f"{kind} {name}",
                        now_unix_s,
                        stale_s,
                    ),
                )
            )
    out += _crew_markers(op, mission, snap, crews_ne, crew_ok, now_unix_s, stale_s, crews)
    return out


def _crew_markers(op, mission, snap, crews_ne, crew_ok, now_unix_s, stale_s, tracker):
    o = op.fleet.origin
    names = crew_names(mission)
    tak_states = {s.column: s for s in op.tak.states()} if op.tak is not None else {}
    connected = op.crews_connected
    if connected is None or len(connected) != len(crews_ne):
        heard = ~snap.lost & snap.has_position
        ne = np.where(heard[:, None], snap.pos_ned_m[:, :2], np.inf)
        connected = (
            tasks_connected(
                np.where(crew_ok[:, None], crews_ne, np.inf), ne, heard, mission.radio.range_m
            )
            if snap.n_vehicles
            else np.zeros(len(crews_ne), bool)
        )
    out = []
    for k in range(len(crews_ne)):
        st = tak_states.get(k)
        pos = crews_ne[k] if crew_ok[k] else (st.last_ne_m if st is not None else None)
        if pos is None or not np.isfinite(pos).all():
            continue  # never had a position: nothing to place
        state = "unknown" if not crew_ok[k] else ("connected" if connected[k] else "not connected")
        since = tracker.update(k, state, now_unix_s) if tracker is not None else now_unix_s
        label, colour = {
            "connected": ("mesh OK", _GREEN),
            "not connected": ("NO MESH", _RED),
            "unknown": ("UNKNOWN", _GREY),
        }[state]
        name = names[k] if k < len(names) else f"crew {k}"
        who = f" ({st.callsign or st.uid})" if st is not None and st.uid else ""
        lat, lon, _ = ned_to_geodetic(
            np.array([pos[0], pos[1], 0.0]), o.lat_deg, o.lon_deg, o.alt_amsl_m
        )
        detail = (
            f'<usericon iconsetpath="COT_MAPPING_SPOTMAP/b-m-p-s-m/{colour}"/>'
            f'<color argb="{colour}"/><status readiness="{str(state == "connected").lower()}"/>'
        )
        out.append(
            CotItem(
                CREW_STATUS_TYPE,
                f"{OWN_UID_PREFIX}crew-{k}",
                "crew",
                (state, since, who, *_grid(*pos)),
                partial(
                    cot_xml,
                    uid=f"{OWN_UID_PREFIX}crew-{k}",
                    type=CREW_STATUS_TYPE,
                    how="h-g-i-g-o",
                    lat_deg=float(lat),
                    lon_deg=float(lon),
                    now_unix_s=now_unix_s,
                    stale_after_s=stale_s,
                    callsign=f"{name}: {label}",
                    remarks=f"{name}{who}: {state} through the drone mesh since "
                    f"{cot_time(since)}"
                    + (" (TAK report stale: position unknown)" if state == "unknown" else ""),
                    detail_xml=detail,
                ),
            )
        )
    return out


class _Publisher:
    def __init__(
        self,
        op,
        link,
        mission,
        clock: Callable[[], float],
        period_s: float,
        on_tak: Callable[[dict], None] | None,
        max_rate_msgs_s: float = MAX_RATE_MSGS_S,
    ) -> None:
        self.op, self.link, self.mission, self.clock = op, link, mission, clock
        self.period_s = period_s
        self.min_stale_s = max(MIN_STALE_S, STALE_PERIODS * period_s)
        self.stale_s = self.min_stale_s
        self.rate_msgs_s = max_rate_msgs_s
        self.throttle = Throttle(max(1, int(max_rate_msgs_s * period_s)), self.stale_s / 2.0)
        self.tracker = CrewLinkTracker()
        self.published: collections.Counter[str] = collections.Counter()
        self.batches = 0
        self.on_tak = on_tak
        self._task = asyncio.create_task(self._run())

    def publish_once(self) -> int:
        now_unix_s = time.time()
        batch = picture_cot(
            self.op,
            self.mission,
            self.clock(),
            now_unix_s,
            stale_s=self.stale_s,
            crews=self.tracker,
        )
        # Under the rate limit every item is sent at least once per cycle of len(batch) / rate
        # seconds: the stale time (hence the refresh, at half of it) grows with the picture, so
        # a client never sees a live item go stale (used from the next picture on).
        cycle_s = len(batch) / self.rate_msgs_s
        self.stale_s = max(self.min_stale_s, 2.0 * cycle_s + 2.0 * self.period_s)
        self.throttle.refresh_s = self.stale_s / 2.0
        batch = self.throttle.select(batch, now_unix_s)
        self.link.send([it.xml for it in batch])
        self.published.update(it.type for it in batch)
        self.batches += 1
        return len(batch)

    async def _run(self) -> None:
        while True:
            try:
                self.publish_once()
            except Exception:  # a picture that cannot be drawn must not stop the flight
                log.exception("TAK picture failed")
            await asyncio.sleep(self.period_s)

    async def aclose(self) -> None:
        self._task.cancel()
        try:
            await self._task
        except asyncio.CancelledError:
            pass
        if self.on_tak is not None:
            self.on_tak(
                {
                    "counters": self.link.counters(),
                    "published": dict(self.published),
                    "batches": self.batches,
                    "deferred": self.throttle.deferred,
                    "crews": self.op.tak.counters if self.op.tak is not None else {},
                }
            )


async def attach(op, link, *, mission, opts, clock: Callable[[], float], speedup: float = 1.0):
    """Publish the mesh on ``link`` every ``opts.tak_period_s`` wall seconds; returns objects
    with ``async aclose()`` (``opts.on_tak`` gets the counters when it closes)."""
    pub = _Publisher(
        op, link, mission, clock, opts.tak_period_s, opts.on_tak, opts.tak_max_rate_msgs_s
    )
    log.info("publishing the mesh on TAK (%s) every %.1f s", ", ".join(link.urls), pub.period_s)
    return [pub]

"""Rally points kept on every vehicle: the MAVLink mission protocol for ``MAV_MISSION_TYPE_RALLY``.

Why (issue 15, "recovery toward the network"): ``phireman-resilient`` with ``rally`` on publishes
one rally point per branch of its task tree, near the base (:func:`planner.resilient.rally_points`).
Uploaded to the vehicles, the firmware's own lost-link RTL flies a cut-off drone to the nearest
of them instead of all the way home: ArduCopter ``ModeRTL::compute_return_target`` ->
``AP_Rally::calc_best_rally_or_home_location`` (libraries/AP_Rally/AP_Rally.cpp), PX4 Return ->
``RTL::findRtlDestination`` / ``findClosestSafePoint`` (src/modules/navigator/rtl.cpp, per
``RTL_TYPE``). Sans-I/O, like the rest of :mod:`gcs`: messages and ``now_s`` in, messages out.

* :class:`RallyUpload` - one upload to one vehicle (mavlink.io/en/services/mission.html, "Upload
  a Mission to the Vehicle"), timing as QGroundControl's ``PlanManager``
  (src/MissionManager/PlanManager.cc, .h): MISSION_COUNT(n, RALLY) -> the vehicle asks for each
  item (MISSION_REQUEST_INT; ArduPilot asks with the legacy MISSION_REQUEST,
  ``MissionItemProtocol::queued_request_send``) -> MISSION_ITEM_INT(seq, frame
  :data:`RALLY_ITEM_FRAME`, MAV_CMD_NAV_RALLY_POINT) -> ... -> MISSION_ACK(ACCEPTED). The vehicle
  drives the item retries (it asks again, ArduPilot after 1 s); a repeated request gets the
  item again. Without a first request within ``ack_timeout_s`` (QGC ``_ackTimeoutMilliseconds``
  1500) the count is sent again, at most ``retries`` times (QGC ``_maxRetryCount`` 5); silence
  after an item, a request outside the list or an ACK other than ACCEPTED fail the upload
  (``PlanManager::_ackTimeout`` "Vehicle did not request all items", ``_handleMissionAck``),
  except INVALID_SEQUENCE while items flow: ArduPilot (GCS_MAVLink/MissionItemProtocol.cpp
  ``handle_mission_item``) answers a duplicate item so and goes on with the upload.
  A count of 0 clears the vehicle's rally points (answered by an ACK at once).
* :class:`RallyKeeper` - the fleet's rally set: the station publishes the planner's points every
  control tick; the set is re-uploaded only when a point moved more than
  ``move_threshold_m`` (or the number changed), at most every ``min_period_s``; every vehicle
  heard gets the same set (a failed upload is tried again after ``retry_after_s``). A failure is
  loud: an error in the log and a :class:`RallyUploadFailed` event (``on_failure``); so is a
  firmware that accepted the items but says it cannot use them (:data:`REFUSAL_TEXTS`: PX4's
  "RTL: unsupported MAV_FRAME"), which is why a read-back alone proves nothing.
* :data:`RALLY_PARAMS` / :func:`rally_param_writes` - the firmware settings that make RTL use the
  points (ArduPilot ``RALLY_LIMIT_KM``, PX4 ``RTL_TYPE``), written with the mission's limits.
* :class:`MissionProtocolReceived` - the event :class:`gcs.link.StationLink` emits for the
  mission-protocol replies it does not handle itself.

The frame of the items (:data:`RALLY_ITEM_FRAME`) is one both firmwares' RTL uses. PX4 stores the
frame number of an item as sent (src/modules/mavlink/mavlink_mission.cpp
``MavlinkMissionManager::parse_mavlink_mission_item``: ``mission_item->frame =
mavlink_mission_item->frame``) and its RTL read only frames 0 and 3 of a rally point until main of
2026-03-30 (src/modules/navigator/rtl.cpp ``RTL::setSafepointAsDestination``; any other frame:
"RTL: unsupported MAV_FRAME", severity CRITICAL, every 2 s from ``RTL::on_inactive``, while
``RTL::findClosestSafePoint`` still chose the point, so RTL had no destination). A frame-6 upload
was accepted and read back as 6 (``format_mavlink_mission_item`` writes 6 for any relative
item in int mode, 3 in float mode), indistinguishable from a working one. QGroundControl sends
rally points to every autopilot in frame 3 (src/MissionManager/RallyPointManager.cc
``RallyPointManager::sendToVehicle``). ArduPilot takes 3 and 6 alike as above home
(libraries/GCS_MAVLink/MissionItemProtocol_Rally.cpp
``MissionItemProtocol_Rally::convert_MISSION_ITEM_INT_to_RallyLocation``; others ->
MAV_MISSION_UNSUPPORTED_FRAME), and reads them back as 3.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from gcs.autopilot import ARDUPILOT, PX4
from gcs.events import Event
from gcs.wire import deg_to_e7, mavlink

__all__ = [
    "MissionProtocolReceived",
    "RallyUploadFailed",
    "RALLY_ITEM_FRAME",
    "REFUSAL_TEXTS",
    "is_refusal_text",
    "mission_event",
    "RallyPoint",
    "UploadState",
    "RallyUpload",
    "RallyConfig",
    "RallyKeeper",
    "RALLY_PARAMS",
    "rally_param_writes",
    "planner_rally_points_m",
    "MISSION_PROTOCOL_MESSAGES",
]

log = logging.getLogger(__name__)

T_RALLY = mavlink.MAV_MISSION_TYPE_RALLY
#: Replies of a vehicle during an upload, routed to the keeper (gcs/link.py hook).
MISSION_PROTOCOL_MESSAGES = ("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK")
#: The frame of every rally item: MAV_FRAME_GLOBAL_RELATIVE_ALT (3), altitude above home, the
#: one frame both firmwares' RTL reads in every version (module docstring: PX4 rtl.cpp
#: ``RTL::setSafepointAsDestination`` 0 and 3 only until 2026-03-30, ArduPilot
#: ``MissionItemProtocol_Rally::convert_MISSION_ITEM_INT_to_RallyLocation`` 3 or 6). In a
#: MISSION_ITEM_INT x / y stay degE7 whatever the frame (common.xml MISSION_ITEM_INT).
RALLY_ITEM_FRAME = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
#: STATUSTEXT beginnings by which a firmware says it cannot use the rally points it accepted:
#: PX4 src/modules/navigator/rtl.cpp ``RTL::setSafepointAsDestination``, ``mavlink_log_critical(
#: ..., "RTL: unsupported MAV_FRAME\t")`` (severity 2, repeated every 2 s by ``RTL::on_inactive``).
REFUSAL_TEXTS = ("RTL: unsupported MAV_FRAME",)


def is_refusal_text(text: str) -> bool:
    """Whether a vehicle's STATUSTEXT says it cannot use its rally points (:data:`REFUSAL_TEXTS`)."""
    return text.strip().startswith(REFUSAL_TEXTS)


@dataclass(frozen=True)
class MissionProtocolReceived(Event):
    """A vehicle's MISSION_REQUEST(_INT) or MISSION_ACK (plain fields: recordable as JSON)."""

    kind: str = ""
    """'MISSION_REQUEST', 'MISSION_REQUEST_INT' or 'MISSION_ACK'."""
    mission_type: int = 0
    seq: int = -1
    """Requested item (requests only)."""
    result: int = -1
    """MAV_MISSION_RESULT (acks only)."""
    target_system: int = 0
    target_component: int = 0


def mission_event(link_id: int, sysid: int, msg: Any, now_s: float) -> MissionProtocolReceived:
    """The event for one decoded MISSION_REQUEST / MISSION_REQUEST_INT / MISSION_ACK."""
    kind = msg.get_type()
    return MissionProtocolReceived(
        link_id,
        sysid,
        now_s,
        kind=kind,
        mission_type=int(getattr(msg, "mission_type", 0)),
        seq=int(msg.seq) if kind != "MISSION_ACK" else -1,
        result=int(msg.type) if kind == "MISSION_ACK" else -1,
        target_system=int(msg.target_system),
        target_component=int(msg.target_component),
    )


@dataclass(frozen=True)
class RallyUploadFailed(Event):
    """The vehicle does not hold the station's rally set: the upload failed, was refused, or the
    firmware said it cannot use the points (plain fields: recordable as JSON)."""

    version: int = 0
    """The keeper's set that failed (:attr:`RallyKeeper.version`)."""
    reason: str = ""
    result: int = -1
    """The vehicle's MAV_MISSION_RESULT when it answered with an error ACK, else -1."""
    refused: bool = False
    """True when the firmware refused the points (an error ACK or a :data:`REFUSAL_TEXTS`
    STATUSTEXT), False when it did not answer."""


@dataclass(frozen=True)
class RallyPoint:
    """One rally point as it goes on the wire (MISSION_ITEM_INT x / y / z)."""

    lat_e7: int
    lon_e7: int
    alt_above_home_m: float


class UploadState(StrEnum):
    COUNT_SENT = "count sent"
    """Waiting for the vehicle's first request (or the ACK of a count of 0)."""
    SENDING = "sending"
    """Items requested and sent; waiting for the next request or the final ACK."""
    DONE = "done"
    FAILED = "failed"


class RallyUpload:
    """One rally upload to one vehicle (see the module docstring). Outgoing messages are taken
    with :meth:`take_messages`; :meth:`handle_timer` runs the timeouts."""

    def __init__(
        self,
        target_system: int,
        points: Sequence[RallyPoint],
        now_s: float,
        *,
        gcs_sysid: int = 255,
        gcs_compid: int = mavlink.MAV_COMP_ID_MISSIONPLANNER,
        target_component: int = mavlink.MAV_COMP_ID_AUTOPILOT1,
        ack_timeout_s: float = 1.5,
        retries: int = 5,
    ) -> None:
        self.target_system = int(target_system)
        self.target_component = int(target_component)
        self.points = tuple(points)
        self.gcs_sysid, self.gcs_compid = gcs_sysid, gcs_compid
        self.ack_timeout_s = float(ack_timeout_s)
        self.retries = int(retries)
        self.state = UploadState.COUNT_SENT
        self.result: int | None = None
        """The vehicle's MAV_MISSION_RESULT when it acked, else None."""
        self.reason = ""
        """Why the upload failed (for people and logs)."""
        self.count_retries = 0
        self.items_sent = 0
        self.duplicates = 0
        """INVALID_SEQUENCE acks of a duplicate item (the upload went on)."""
        self._out: list[Any] = []
        self._deadline_s = math.inf
        self._send_count(now_s)

    # -- outputs ------------------------------------------------------------------------------

    @property
    def finished(self) -> bool:
        return self.state in (UploadState.DONE, UploadState.FAILED)

    def take_messages(self) -> list[Any]:
        out, self._out = self._out, []
        return out

    def next_timer_s(self) -> float | None:
        return None if self.finished else self._deadline_s

    # -- inputs -------------------------------------------------------------------------------

    def _for_us(self, ev: MissionProtocolReceived) -> bool:
        # Replies to another GCS's transfer, or of another mission type, are not ours (QGC
        # drops them: "Incorrect mission_type received").
        return (
            ev.sysid == self.target_system
            and ev.mission_type == T_RALLY
            and ev.target_system in (0, self.gcs_sysid)
            and ev.target_component in (0, self.gcs_compid)
        )

    def on_event(self, ev: MissionProtocolReceived, now_s: float) -> None:
        """A MISSION_REQUEST(_INT) or MISSION_ACK from the vehicle."""
        if self.finished or not self._for_us(ev):
            return
        if ev.kind == "MISSION_ACK":
            if (
                ev.result == mavlink.MAV_MISSION_INVALID_SEQUENCE
                and self.state == UploadState.SENDING
            ):
                # ArduPilot MissionItemProtocol::handle_mission_item acks an item it did not ask
                # for (a duplicate) with INVALID_SEQUENCE and carries on: not the end.
                self.duplicates += 1
                return
            if ev.result == mavlink.MAV_MISSION_ACCEPTED and (
                not self.points or self.items_sent >= len(self.points)
            ):
                self._finish(UploadState.DONE, ev.result, "")
            elif ev.result == mavlink.MAV_MISSION_ACCEPTED:
                self._finish(UploadState.FAILED, ev.result, "accepted before every item was sent")
            else:
                self._finish(
                    UploadState.FAILED, ev.result, f"vehicle refused: {_result_name(ev.result)}"
                )
            return
        if not 0 <= ev.seq < len(self.points):
            self._finish(
                UploadState.FAILED, None, f"vehicle requested item {ev.seq} of {len(self.points)}"
            )
            return
        self.state = UploadState.SENDING
        self._send_item(ev.seq)
        self.items_sent = max(self.items_sent, ev.seq + 1)
        self._deadline_s = now_s + self.ack_timeout_s

    def handle_timer(self, now_s: float) -> None:
        if self.finished or now_s < self._deadline_s:
            return
        if self.state == UploadState.COUNT_SENT and self.count_retries < self.retries:
            self.count_retries += 1
            self._send_count(now_s)
        elif self.state == UploadState.COUNT_SENT:
            self._finish(UploadState.FAILED, None, "no answer to MISSION_COUNT, retries exhausted")
        elif self.items_sent < len(self.points):
            self._finish(UploadState.FAILED, None, "vehicle did not request every item")
        else:
            self._finish(UploadState.FAILED, None, "no final MISSION_ACK")

    # -- internals ------------------------------------------------------------------------------

    def _finish(self, state: UploadState, result: int | None, reason: str) -> None:
        self.state, self.result, self.reason = state, result, reason
        self._deadline_s = math.inf

    def _send_count(self, now_s: float) -> None:
        self._out.append(
            mavlink.MAVLink_mission_count_message(
                self.target_system, self.target_component, len(self.points), T_RALLY
            )
        )
        self._deadline_s = now_s + self.ack_timeout_s

    def _send_item(self, seq: int) -> None:
        p = self.points[seq]
        self._out.append(
            mavlink.MAVLink_mission_item_int_message(
                self.target_system,
                self.target_component,
                seq,
                RALLY_ITEM_FRAME,
                mavlink.MAV_CMD_NAV_RALLY_POINT,
                0,
                1,
                0.0,
                0.0,
                0.0,
                0.0,
                p.lat_e7,
                p.lon_e7,
                float(p.alt_above_home_m),
                T_RALLY,
            )
        )


def _result_name(result: int) -> str:
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(result)
    return entry.name if entry is not None else f"MAV_MISSION_RESULT({result})"


# ------------------------------------------------------------------------------------------------
# The fleet's rally set
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RallyConfig:
    """When to re-upload, and the protocol timing. Units in the names."""

    move_threshold_m: float = 15.0
    """Re-upload when some point moved more than this (nearest-point distance), or the number
    of points changed."""
    min_period_s: float = 10.0
    """At most one new set every this long (each set costs every vehicle 2 + 2 n messages)."""
    alt_above_home_m: float = 40.0
    """Rally point altitude (RALLY_POINT z, above home). ArduCopter returns at the higher of it
    and its RTL altitude; the emulator returns at the RTL altitude."""
    inward_m: float = 10.0
    """Each point is uploaded this much nearer the base (along the line to it; on the tree's
    first edge, where the planner's points lie). The planner puts them at ``rally_dist`` = r from
    the base, exactly at the edge of the base's reach (min(R, r)); a firmware stops within its
    acceptance radius of a point (ArduCopter WPNAV_RADIUS 2 m, PX4 NAV_ACC_RAD 10 m), so a drone
    returning from beyond stopped 0.5-1 m outside the base's reach, was never heard again and
    landed there (tests/integration/test_rally_flight.py found it)."""
    max_points: int = 10
    """Points kept (the nearest the base first): ArduPilot stores 10+ (``AP_Rally::get_rally_max``
    from the storage size, 15 bytes per point)."""
    retry_after_s: float = 5.0
    """A failed upload to a vehicle is started again after this long."""
    ack_timeout_s: float = 1.5
    retries: int = 5

    def __post_init__(self) -> None:
        if not (
            self.move_threshold_m >= 0
            and self.min_period_s >= 0
            and self.inward_m >= 0
            and self.retry_after_s >= 0
            and self.ack_timeout_s > 0
            and self.retries >= 0
            and self.max_points >= 0
        ):
            raise ValueError(f"invalid rally configuration {self}")
        if not -32768 <= self.alt_above_home_m <= 32767:
            # ArduPilot MissionItemProtocol_Rally::convert_MISSION_ITEM_INT_to_RallyLocation:
            # z outside int16 -> MAV_MISSION_INVALID_PARAM7.
            raise ValueError(f"alt_above_home_m must fit an int16, got {self.alt_above_home_m}")


def set_moved(old_ne_m: np.ndarray | None, new_ne_m: np.ndarray, threshold_m: float) -> bool:
    """Whether ``new`` differs from ``old`` (both (K, 2)): another count, or a new point farther
    than ``threshold_m`` from every old one (or an old one from every new one)."""
    if old_ne_m is None or len(old_ne_m) != len(new_ne_m):
        return True
    if len(new_ne_m) == 0:
        return False
    d = np.linalg.norm(new_ne_m[:, None, :] - old_ne_m[None, :, :], axis=2)
    return bool(d.min(axis=1).max() > threshold_m or d.min(axis=0).max() > threshold_m)


VehicleId = tuple[int, int]


class RallyKeeper:
    """Keeps every vehicle's rally points equal to the latest published set (module docstring).

    Parameters
    ----------
    origin_lat_deg, origin_lon_deg : the mission frame's origin (north / east metres around it)
    config : thresholds and timing
    gcs_sysid, gcs_compid : our identity (replies addressed elsewhere are not ours)
    """

    def __init__(
        self,
        origin_lat_deg: float,
        origin_lon_deg: float,
        config: RallyConfig = RallyConfig(),
        *,
        gcs_sysid: int = 255,
        gcs_compid: int = mavlink.MAV_COMP_ID_MISSIONPLANNER,
    ) -> None:
        self.origin = (float(origin_lat_deg), float(origin_lon_deg))
        self.config = config
        self.gcs_sysid, self.gcs_compid = gcs_sysid, gcs_compid
        self.points_ne_m: np.ndarray | None = None
        """The set being kept (None: nothing published yet)."""
        self.version = 0
        """Bumped for every new set; a vehicle is up to date when it accepted this version."""
        self._points: tuple[RallyPoint, ...] = ()
        self._published_s = -math.inf
        self._accepted: dict[VehicleId, int] = {}
        self._uploads: dict[VehicleId, tuple[int, RallyUpload]] = {}
        self._retry_s: dict[VehicleId, float] = {}
        self._refused: dict[VehicleId, int] = {}
        """Vehicle -> the set version its firmware refused (not uploaded again: the same items
        would be refused again; a new set is)."""
        self.stats = {"sets": 0, "uploads": 0, "accepted": 0, "failed": 0}
        self.failures: list[tuple[float, VehicleId, str]] = []
        self.on_failure: Callable[[RallyUploadFailed], None] | None = None
        """Called with every :class:`RallyUploadFailed` (the runner records it and shows it)."""

    # -- the set -----------------------------------------------------------------------------

    def publish(self, points_ne_m: np.ndarray | None, now_s: float, *, force: bool = False) -> bool:
        """The planner's rally points (K, 2) north / east metres (None: none published). Adopted
        as the new set when it moved enough and ``min_period_s`` passed (``force``: at once, e.g.
        an empty set at the end of the flight). Returns True if adopted."""
        if points_ne_m is None:
            return False
        pts = np.asarray(points_ne_m, dtype=float).reshape(-1, 2)
        pts = pts[np.isfinite(pts).all(axis=1)]
        r = np.hypot(*pts.T)
        pts = pts * (np.maximum(r - self.config.inward_m, 0.0) / np.where(r > 0, r, 1.0))[:, None]
        if len(pts) > self.config.max_points:  # the nearest the base first (stable order)
            pts = pts[np.argsort(np.hypot(*pts.T), kind="stable")[: self.config.max_points]]
        if not force and (
            now_s - self._published_s < self.config.min_period_s
            or not set_moved(self.points_ne_m, pts, self.config.move_threshold_m)
        ):
            return False
        if force and self.points_ne_m is not None and not set_moved(self.points_ne_m, pts, 0.0):
            return False
        self.points_ne_m = pts
        self._points = tuple(self._to_wire(pts))
        self.version += 1
        self._published_s = now_s
        self._retry_s.clear()
        self.stats["sets"] += 1
        log.info("rally set %d: %d point(s)", self.version, len(pts))
        return True

    def _to_wire(self, pts: np.ndarray) -> Iterable[RallyPoint]:
        from planner.geometry import ned_to_geodetic

        if len(pts) == 0:
            return ()
        ned = np.column_stack([pts, np.zeros(len(pts))])
        lat, lon, _ = ned_to_geodetic(ned, self.origin[0], self.origin[1], 0.0)
        return (
            RallyPoint(deg_to_e7(float(a)), deg_to_e7(float(b)), self.config.alt_above_home_m)
            for a, b in zip(np.atleast_1d(lat), np.atleast_1d(lon))
        )

    def up_to_date(self, vid: VehicleId) -> bool:
        return self._accepted.get(vid) == self.version

    # -- per vehicle --------------------------------------------------------------------------

    def poll(self, reachable: Iterable[VehicleId], now_s: float) -> list[tuple[VehicleId, Any]]:
        """Timers of the running uploads, and a new upload for every ``reachable`` vehicle not up
        to date; returns the ``(vehicle, message)`` pairs to send, in order."""
        out: list[tuple[VehicleId, Any]] = []
        for vid, (_, up) in list(self._uploads.items()):
            up.handle_timer(now_s)
            out += [(vid, m) for m in up.take_messages()]
            self._settle(vid, now_s)
        if self.version == 0:
            return out
        for vid in reachable:
            if (
                vid in self._uploads
                or self.up_to_date(vid)
                or self._refused.get(vid) == self.version
                or now_s < self._retry_s.get(vid, -math.inf)
            ):
                continue
            up = RallyUpload(
                vid[1],
                self._points,
                now_s,
                gcs_sysid=self.gcs_sysid,
                gcs_compid=self.gcs_compid,
                ack_timeout_s=self.config.ack_timeout_s,
                retries=self.config.retries,
            )
            self._uploads[vid] = (self.version, up)
            self.stats["uploads"] += 1
            out += [(vid, m) for m in up.take_messages()]
        return out

    def on_event(self, ev: MissionProtocolReceived, now_s: float) -> list[tuple[VehicleId, Any]]:
        """A vehicle's mission-protocol reply; returns the messages to send at once."""
        vid = (ev.link_id, ev.sysid)
        entry = self._uploads.get(vid)
        if entry is None:
            return []
        up = entry[1]
        up.on_event(ev, now_s)
        out = [(vid, m) for m in up.take_messages()]
        self._settle(vid, now_s)
        return out

    def next_timer_s(self) -> float | None:
        times = [t for _, up in self._uploads.values() if (t := up.next_timer_s()) is not None]
        return min(times) if times else None

    def _settle(self, vid: VehicleId, now_s: float) -> None:
        version, up = self._uploads[vid]
        if not up.finished:
            return
        del self._uploads[vid]
        if up.state == UploadState.DONE:
            self._accepted[vid] = version
            self.stats["accepted"] += 1
            log.debug("link %d sysid %d: rally set %d accepted", *vid, version)
        else:
            self._retry_s[vid] = now_s + self.config.retry_after_s
            self._fail(
                vid,
                version,
                now_s,
                f"rally upload failed: {up.reason}",
                -1 if up.result is None else up.result,
                refused=up.result is not None,
            )

    def on_status_text(self, vid: VehicleId, text: str, now_s: float) -> None:
        """A vehicle's STATUSTEXT. One of :data:`REFUSAL_TEXTS` means the firmware holds rally
        points it cannot fly to (PX4 repeats it every 2 s): reported once per set and vehicle,
        and a vehicle that had accepted the set no longer counts as holding it (it is not sent
        the same set again; the next set is uploaded as usual)."""
        if not is_refusal_text(text) or self._refused.get(vid) == self.version:
            return
        self._refused[vid] = self.version
        self._accepted.pop(vid, None)
        self._fail(
            vid,
            self.version,
            now_s,
            f"the firmware cannot use its rally points: {text.strip()!r}",
            -1,
            refused=True,
        )

    def _fail(
        self, vid: VehicleId, version: int, now_s: float, reason: str, result: int, *, refused: bool
    ) -> None:
        """Count, log (an error: RTL would not go where the station believes) and announce."""
        self.stats["failed"] += 1
        self.failures.append((now_s, vid, reason))
        log.error("link %d sysid %d: rally set %d: %s", *vid, version, reason)
        if self.on_failure is not None:
            self.on_failure(
                RallyUploadFailed(
                    vid[0],
                    vid[1],
                    now_s,
                    version=version,
                    reason=reason,
                    result=result,
                    refused=refused,
                )
            )


# ------------------------------------------------------------------------------------------------
# Firmware settings and the planner's points
# ------------------------------------------------------------------------------------------------

#: Parameters that decide whether RTL uses the rally points, per HEARTBEAT.autopilot.
#: ArduPilot ``RALLY_LIMIT_KM`` (AP_Rally.cpp ``find_nearest_rally_point``): a nearest point
#: farther than this sends the copter home; Copter's default 0.3 km is less than a mission field's
#: size, so the station sets 0 (no limit). ``RALLY_INCL_HOME`` (Copter default 1: home competes
#: with the points, ``calc_best_rally_or_home_location``) is read and left as it is.
#: PX4 ``RTL_TYPE`` (rtl_params.c): 0 (default) and 3 return to the closest of home and the rally
#: points, 1 to the closest rally point; 2 and 4 ignore rally points (``RTL::findRtlDestination``),
#: so those are set to 0.
RALLY_PARAMS: dict[int, tuple[str, ...]] = {
    ARDUPILOT: ("RALLY_LIMIT_KM", "RALLY_INCL_HOME"),
    PX4: ("RTL_TYPE",),
}


def rally_param_writes(autopilot: int, current: Mapping[str, float]) -> list[tuple[str, float]]:
    """``(name, value)`` writes that make the firmware's RTL use rally points, given the values
    read (names not read are skipped)."""
    out: list[tuple[str, float]] = []
    if (
        autopilot == ARDUPILOT
        and "RALLY_LIMIT_KM" in current
        and float(current["RALLY_LIMIT_KM"]) != 0.0
    ):
        out.append(("RALLY_LIMIT_KM", 0.0))
    if autopilot == PX4 and "RTL_TYPE" in current and int(current["RTL_TYPE"]) in (2, 4):
        out.append(("RTL_TYPE", 0.0))
    return out


def planner_rally_points_m(planner: Any) -> np.ndarray | None:
    """(B, 2) north / east metres: the rally points the planner publishes with its tree
    (``phireman-resilient`` with ``rally`` on: :func:`planner.resilient.rally_points` of its
    current tree at ``rally_dist``, what its own world model uses), None for any other planner."""
    from planner.resilient import ResilientPlanner, rally_points

    if (
        not isinstance(planner, ResilientPlanner)
        or not planner.params.rally
        or planner.tree is None
    ):
        return None
    return planner.units.to_m(rally_points(planner.tree, planner.params.rally_dist))

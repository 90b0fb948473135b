"""Sans-I/O MAVLink mission protocol server (missions, fences, rally points) for one vehicle.

What a ground station sees when it downloads or uploads plans (mavlink.io/en/services/
mission.html), following the firmware code:

* ArduPilot ``libraries/GCS_MAVLink/MissionItemProtocol.cpp`` (one instance per mission type):
  MISSION_REQUEST_LIST -> MISSION_COUNT; MISSION_REQUEST_INT -> MISSION_ITEM_INT and
  MISSION_REQUEST -> MISSION_ITEM (converted from the int item); a request outside the list ->
  MISSION_ACK(INVALID_SEQUENCE). Upload: MISSION_COUNT -> MISSION_REQUEST for item 0 (ArduPilot
  sends the legacy MISSION_REQUEST in ``queued_request_send``; GCSes answer with
  MISSION_ITEM_INT), each item -> next request, the last -> MISSION_ACK(ACCEPTED); count 0 ->
  ACK at once; a wrong seq -> ACK(INVALID_SEQUENCE) and the upload continues; an upload from
  a second GCS while one is running -> ACK(DENIED); requests are resent after 1 s without an
  item and the upload is cancelled (ACK OPERATION_CANCELLED) after 8 s (``upload_timeout_ms``).
  Mission item 0 is always home (``AP_Mission::read_cmd_from_storage``: index 0 is home), so
  an "empty" ArduPilot mission has count 1.
* PX4 ``src/modules/mavlink/mavlink_mission.cpp``: same exchange, no home item (an empty plan
  has count 0); requests are MISSION_REQUEST_INT (``_int_mode``) unless the GCS used the
  legacy float messages, in which case MISSION_REQUEST.

Items are stored, never flown: the vehicle core refuses AUTO / AUTO.MISSION with a STATUSTEXT.
Fence items must be MAV_CMD_NAV_FENCE_* and rally items MAV_CMD_NAV_RALLY_POINT, else the
upload is refused with ACK(UNSUPPORTED) (ArduPilot ``MissionItemProtocol_Fence`` /
``MissionItemProtocol_Rally``).

Frames, as each firmware stores and reports them:

* PX4 ``MavlinkMissionManager::parse_mavlink_mission_item`` takes global items in frames 0 / 3
  (5 / 6 in int mode) and MAV_FRAME_MISSION (2), anything else -> ACK(UNSUPPORTED_FRAME); it
  stores the frame number as sent (``mission_item->frame = mavlink_mission_item->frame``), which
  is what the navigator later reads (the rally frames its RTL can use:
  vehicle_emu/personality/px4.py), and ``format_mavlink_mission_item`` reports a global item by
  its altitude reference only: relative -> 6 (int mode) or 3, absolute -> 5 or 0. A frame-3
  upload reads back as 6: a read-back cannot tell a frame the navigator uses from one it cannot.
* ArduPilot rally points (libraries/GCS_MAVLink/MissionItemProtocol_Rally.cpp
  ``convert_MISSION_ITEM_INT_to_RallyLocation``): 0 / 5 absolute, 3 / 6 above home, 10 / 11
  above terrain, anything else -> ACK(UNSUPPORTED_FRAME); ``get_item_as_mission_item`` reports
  them as 0, 3 and 10 (the non-int frame numbers, even in a MISSION_ITEM_INT).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from . import wire
from .wire import dialect as mavlink

__all__ = ["MissionServer", "MissionItem"]

T_MISSION = mavlink.MAV_MISSION_TYPE_MISSION
T_FENCE = mavlink.MAV_MISSION_TYPE_FENCE
T_RALLY = mavlink.MAV_MISSION_TYPE_RALLY
T_ALL = mavlink.MAV_MISSION_TYPE_ALL
_TYPES = (T_MISSION, T_FENCE, T_RALLY)
_FENCE_CMDS = frozenset(range(5000, 5005))  # MAV_CMD_NAV_FENCE_RETURN_POINT .. CIRCLE_EXCLUSION
_RALLY_CMDS = frozenset({mavlink.MAV_CMD_NAV_RALLY_POINT})
#: Frames whose x / y are latitude / longitude (degE7 in *_INT messages, degrees in MISSION_ITEM).
_GLOBAL_FRAMES = frozenset(
    {
        mavlink.MAV_FRAME_GLOBAL,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        mavlink.MAV_FRAME_GLOBAL_INT,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
        mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
    }
)

_F = mavlink
#: PX4 parse_mavlink_mission_item: the frames it takes (module docstring); 5 / 6 in int mode only.
_PX4_FRAMES = frozenset(
    {_F.MAV_FRAME_GLOBAL, _F.MAV_FRAME_GLOBAL_RELATIVE_ALT, _F.MAV_FRAME_MISSION}
)
_PX4_INT_FRAMES = frozenset({_F.MAV_FRAME_GLOBAL_INT, _F.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})
_PX4_RELATIVE = frozenset({_F.MAV_FRAME_GLOBAL_RELATIVE_ALT, _F.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})
#: ArduPilot convert_MISSION_ITEM_INT_to_RallyLocation: frame -> the frame it reports it in.
_AP_RALLY_FRAMES = {
    _F.MAV_FRAME_GLOBAL: _F.MAV_FRAME_GLOBAL,
    _F.MAV_FRAME_GLOBAL_INT: _F.MAV_FRAME_GLOBAL,
    _F.MAV_FRAME_GLOBAL_RELATIVE_ALT: _F.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    _F.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: _F.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    _F.MAV_FRAME_GLOBAL_TERRAIN_ALT: _F.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    _F.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: _F.MAV_FRAME_GLOBAL_TERRAIN_ALT,
}

RESEND_S = 1.0  # ArduPilot MissionItemProtocol::update: 1000 ms + stream slowdown
UPLOAD_TIMEOUT_S = 8.0  # ArduPilot MissionItemProtocol.h upload_timeout_ms = 8000


@dataclass(frozen=True)
class MissionItem:
    """One stored item, in MISSION_ITEM_INT units (x, y degE7 for global frames)."""

    frame: int
    command: int
    current: int
    autocontinue: int
    params: tuple
    x: int
    y: int
    z: float

    @classmethod
    def from_msg(cls, m) -> MissionItem:
        x, y = m.x, m.y
        if m.get_type() == "MISSION_ITEM":
            # Legacy float item: lat/lon in degrees for global frames (common.xml MISSION_ITEM).
            if m.frame in _GLOBAL_FRAMES:
                x, y = wire.lat_e7_from_deg(x), wire.lat_e7_from_deg(y)
            else:
                x, y = int(round(x * 1e4)), int(round(y * 1e4))  # local: metres * 1e4
        return cls(
            int(m.frame),
            int(m.command),
            int(m.current),
            int(m.autocontinue),
            (float(m.param1), float(m.param2), float(m.param3), float(m.param4)),
            int(x),
            int(y),
            float(m.z),
        )


@dataclass
class _Upload:
    mission_type: int
    count: int
    sysid: int
    compid: int
    items: list
    next_seq: int
    last_rx_s: float
    last_request_s: float


class MissionServer:
    """Mission, fence and rally stores plus the transfer state machine of one vehicle.

    Parameters
    ----------
    send : callable(message)
        Queues a pymavlink message for the link (the vehicle core's ``_send``).
    px4 : bool
        PX4 conventions instead of ArduPilot's (see module docstring).
    home_fn : callable() -> (lat_deg, lon_deg, alt_amsl_m)
        ArduPilot's item 0.
    """

    def __init__(self, send, px4: bool, home_fn) -> None:
        self._send = send
        self.px4 = px4
        self._home_fn = home_fn
        self.items: dict[int, list[MissionItem]] = {t: [] for t in _TYPES}
        self._upload: _Upload | None = None
        self._int_mode = True  # PX4 mavlink_mission.h: accurate int32 messages by default
        self.uploads_completed = 0

    # -- queries --------------------------------------------------------------------------

    def count(self, mission_type: int) -> int:
        n = len(self.items.get(mission_type, ()))
        if mission_type == T_MISSION and not self.px4:
            # ArduPilot: index 0 is home; an uploaded list includes it at seq 0.
            return max(n, 1)
        return n

    def has_mission(self) -> bool:
        """True if a mission with at least one navigation item beyond home is stored."""
        return self.count(T_MISSION) > (0 if self.px4 else 1)

    def item(self, mission_type: int, seq: int) -> MissionItem | None:
        if not 0 <= seq < self.count(mission_type):
            return None
        if mission_type == T_MISSION and not self.px4 and seq == 0:
            lat, lon, alt = self._home_fn()
            return MissionItem(
                mavlink.MAV_FRAME_GLOBAL,
                mavlink.MAV_CMD_NAV_WAYPOINT,
                0,
                1,
                (0.0, 0.0, 0.0, 0.0),
                wire.lat_e7_from_deg(lat),
                wire.lat_e7_from_deg(lon),
                float(alt),
            )
        return self.items[mission_type][seq]

    # -- inbound --------------------------------------------------------------------------

    def _ack(self, sysid: int, compid: int, result: int, mission_type: int) -> None:
        self._send(mavlink.MAVLink_mission_ack_message(sysid, compid, result, mission_type))

    def _type_ok(self, m) -> bool:
        t = getattr(m, "mission_type", T_MISSION)
        if t in _TYPES:
            return True
        self._ack(m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_UNSUPPORTED, t)
        return False

    def _download_from(self, m) -> tuple[int, int, int] | None:
        """(sysid, compid, mission type) of a download request we can serve, else None (acked)."""
        if not self._type_ok(m):
            return None
        src, comp, t = m.get_srcSystem(), m.get_srcComponent(), m.mission_type
        if self._upload is not None:
            # "someone is uploading a mission; reject fetching of points until done or timeout"
            self._ack(src, comp, mavlink.MAV_MISSION_DENIED, t)
            return None
        return src, comp, t

    def on_request_list(self, m, now_s: float) -> None:
        who = self._download_from(m)
        if who is not None:
            src, comp, t = who
            self._send(mavlink.MAVLink_mission_count_message(src, comp, self.count(t), t))

    def on_request(self, m, now_s: float, as_int: bool) -> None:
        who = self._download_from(m)
        if who is None:
            return
        src, comp, t = who
        if self.px4:
            self._int_mode = as_int
        it = self.item(t, m.seq)
        if it is None:
            self._ack(src, comp, mavlink.MAV_MISSION_INVALID_SEQUENCE, t)
            return
        it = self._as_reported(it, t, as_int)
        if as_int:
            self._send(
                mavlink.MAVLink_mission_item_int_message(
                    src,
                    comp,
                    m.seq,
                    it.frame,
                    it.command,
                    it.current,
                    it.autocontinue,
                    *it.params,
                    it.x,
                    it.y,
                    it.z,
                    t,
                )
            )
        else:
            if it.frame in _GLOBAL_FRAMES:
                x, y = wire.deg_from_lat_e7(it.x), wire.deg_from_lat_e7(it.y)
            else:
                x, y = it.x * 1e-4, it.y * 1e-4
            self._send(
                mavlink.MAVLink_mission_item_message(
                    src,
                    comp,
                    m.seq,
                    it.frame,
                    it.command,
                    it.current,
                    it.autocontinue,
                    *it.params,
                    x,
                    y,
                    it.z,
                    t,
                )
            )

    def on_count(self, m, now_s: float) -> None:
        if not self._type_ok(m):
            return
        src, comp, t = m.get_srcSystem(), m.get_srcComponent(), m.mission_type
        up = self._upload
        if up is not None and (src, comp) != (up.sysid, up.compid):
            self._ack(src, comp, mavlink.MAV_MISSION_DENIED, t)
            return
        if m.count == 0:
            self._upload = None
            self.items[t] = []
            self.uploads_completed += 1
            self._ack(src, comp, mavlink.MAV_MISSION_ACCEPTED, t)
            return
        self._upload = _Upload(t, int(m.count), src, comp, [], 0, now_s, now_s)
        self._request(now_s)

    def on_item(self, m, now_s: float) -> None:
        src, comp = m.get_srcSystem(), m.get_srcComponent()
        t = getattr(m, "mission_type", T_MISSION)
        up = self._upload
        if up is None or up.mission_type != t:
            self._ack(src, comp, mavlink.MAV_MISSION_ERROR, t)
            return
        if (src, comp) != (up.sysid, up.compid):
            self._ack(src, comp, mavlink.MAV_MISSION_DENIED, t)
            return
        if m.seq != up.next_seq:
            self._ack(src, comp, mavlink.MAV_MISSION_INVALID_SEQUENCE, t)
            return
        if self.px4 and m.get_type() == "MISSION_ITEM":
            self._int_mode = False
        it = MissionItem.from_msg(m)
        if not self._frame_ok(it.frame, t, m.get_type() == "MISSION_ITEM_INT"):
            self._upload = None
            self._ack(src, comp, mavlink.MAV_MISSION_UNSUPPORTED_FRAME, t)
            return
        allowed = {T_FENCE: _FENCE_CMDS, T_RALLY: _RALLY_CMDS}.get(t)
        if allowed is not None and it.command not in allowed:
            self._upload = None
            self._ack(src, comp, mavlink.MAV_MISSION_UNSUPPORTED, t)
            return
        up.items.append(it)
        up.next_seq += 1
        up.last_rx_s = now_s
        if up.next_seq >= up.count:
            self.items[t] = up.items
            self._upload = None
            self.uploads_completed += 1
            self._ack(src, comp, mavlink.MAV_MISSION_ACCEPTED, t)
            return
        self._request(now_s)

    def _frame_ok(self, frame: int, mission_type: int, as_int: bool) -> bool:
        """Whether the firmware takes an item in ``frame`` (module docstring)."""
        if self.px4:
            return frame in _PX4_FRAMES or (as_int and frame in _PX4_INT_FRAMES)
        if mission_type == T_RALLY:
            return frame in _AP_RALLY_FRAMES
        return True

    def _as_reported(self, it: MissionItem, mission_type: int, as_int: bool) -> MissionItem:
        """The stored item with the frame the firmware reports (module docstring)."""
        frame = it.frame
        if self.px4 and frame != mavlink.MAV_FRAME_MISSION:
            rel = frame in _PX4_RELATIVE
            if as_int:
                frame = _F.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT if rel else _F.MAV_FRAME_GLOBAL_INT
            else:
                frame = _F.MAV_FRAME_GLOBAL_RELATIVE_ALT if rel else _F.MAV_FRAME_GLOBAL
        elif not self.px4 and mission_type == T_RALLY:
            frame = _AP_RALLY_FRAMES.get(frame, frame)
        return it if frame == it.frame else dataclasses.replace(it, frame=frame)

    def on_clear_all(self, m, now_s: float) -> None:
        t = getattr(m, "mission_type", T_MISSION)
        src, comp = m.get_srcSystem(), m.get_srcComponent()
        if self._upload is not None:
            self._ack(src, comp, mavlink.MAV_MISSION_ERROR, t)  # "success && !receiving"
            return
        if t == T_ALL:
            for k in _TYPES:
                self.items[k] = []
        elif t in _TYPES:
            self.items[t] = []
        else:
            self._ack(src, comp, mavlink.MAV_MISSION_UNSUPPORTED, t)
            return
        self._ack(src, comp, mavlink.MAV_MISSION_ACCEPTED, t)

    # -- timers ---------------------------------------------------------------------------

    def _request(self, now_s: float) -> None:
        up = self._upload
        assert up is not None  # requests are sent during an upload only
        up.last_request_s = now_s
        cls = (
            mavlink.MAVLink_mission_request_int_message
            if self.px4 and self._int_mode
            else mavlink.MAVLink_mission_request_message
        )
        self._send(cls(up.sysid, up.compid, up.next_seq, up.mission_type))

    def update(self, now_s: float) -> None:
        up = self._upload
        if up is None:
            return
        if now_s - up.last_rx_s > UPLOAD_TIMEOUT_S:
            self._upload = None
            self._ack(up.sysid, up.compid, mavlink.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)
        elif now_s - up.last_request_s > RESEND_S:
            self._request(now_s)

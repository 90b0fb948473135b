"""gcs/rally.py: the rally upload state machine and the fleet keeper, against the emulator's mission
server (vehicle_emu/missions.py) in memory, on an explicit clock."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from gcs.autopilot import ARDUPILOT, PX4
from gcs.rally import (
    MISSION_PROTOCOL_MESSAGES,
    RALLY_ITEM_FRAME,
    RallyUploadFailed,
    RallyConfig,
    RallyKeeper,
    RallyPoint,
    RallyUpload,
    UploadState,
    mission_event,
    planner_rally_points_m,
    rally_param_writes,
    set_moved,
)
from vehicle_emu.link import VehicleCore


GCS_ADDR = ("10.0.0.1", 14550)


class FakeGcs:
    """Encodes as a GCS (sysid, component 190) and decodes what a vehicle core sends."""

    def __init__(self, sysid: int = 255) -> None:
        self.mav = mavlink.MAVLink(None, sysid, 190)
        self.rx = mavlink.MAVLink(None, sysid, 190)
        self.rx.robust_parsing = True

    def frame(self, msg) -> bytes:
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return buf

    def decode(self, datagrams) -> list:
        out = []
        for data, _ in datagrams:
            out += [m for m in (self.rx.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]
        return out


T_RALLY = mavlink.MAV_MISSION_TYPE_RALLY
ORIGIN = (39.7596, -121.6219, 540.0)
POINTS = (
    RallyPoint(397605000, -1216210000, 40.0),
    RallyPoint(397590000, -1216230000, 40.0),
    RallyPoint(397600000, -1216200000, 45.0),
)


class Vehicles:
    """Emulated vehicles (sysid 1..n) behind an in-memory wire; the station side is ``sink``.

    ``drop_up(msg)`` / ``drop_down(msg)`` decide which station -> vehicle / vehicle -> station
    mission messages are lost.
    """

    def __init__(self, personality: str, n: int = 1) -> None:
        self.cores = {s: VehicleCore(s, personality, origin_lla=ORIGIN) for s in range(1, n + 1)}
        self.gcs = FakeGcs()
        self.t = 0.0
        self.seen: list[tuple[float, int, str, int]] = []  # (t, sysid, kind, seq or result)
        self.sent: list[tuple[float, int, str, int]] = []
        self.drop_up = lambda m: False
        self.drop_down = lambda m: False

    def send(self, sysid: int, msg) -> None:
        seq = getattr(msg, "seq", getattr(msg, "count", -1))
        self.sent.append((self.t, sysid, msg.get_type(), seq))
        if not self.drop_up(msg):
            self.cores[sysid].receive_datagram(self.gcs.frame(msg), GCS_ADDR, self.t)

    def replies(self) -> list:
        out = []
        for sysid, core in self.cores.items():
            for m in self.gcs.decode(core.datagrams_to_send(self.t)):
                if m.get_type() in MISSION_PROTOCOL_MESSAGES and not self.drop_down(m):
                    self.seen.append(
                        (
                            self.t,
                            sysid,
                            m.get_type(),
                            m.type if m.get_type() == "MISSION_ACK" else m.seq,
                        )
                    )
                    out.append(mission_event(0, sysid, m, self.t))
        return out

    def tick(self, dt: float = 0.05) -> None:
        self.t = round(self.t + dt, 6)
        for core in self.cores.values():
            core.handle_timer(self.t)

    def rally(self, sysid: int = 1):
        return self.cores[sysid]._missions.items[T_RALLY]


def run_upload(v: Vehicles, up: RallyUpload, until_s: float = 20.0) -> None:
    """Exchange messages, advancing the clock by 50 ms steps, until the upload ends."""
    while not up.finished and v.t < until_s:
        for m in up.take_messages():
            v.send(up.target_system, m)
        for ev in v.replies():
            up.on_event(ev, v.t)
        for m in up.take_messages():
            v.send(up.target_system, m)
        v.tick()
        up.handle_timer(v.t)


@pytest.mark.parametrize(
    "personality, request_kind", [("ardupilot", "MISSION_REQUEST"), ("px4", "MISSION_REQUEST_INT")]
)
def test_upload_happy_path(personality, request_kind):
    v = Vehicles(personality)
    up = RallyUpload(1, POINTS, v.t)
    run_upload(v, up)
    assert up.state == UploadState.DONE and up.result == mavlink.MAV_MISSION_ACCEPTED
    stored = v.rally()
    assert [(it.x, it.y, it.z) for it in stored] == [
        (p.lat_e7, p.lon_e7, p.alt_above_home_m) for p in POINTS
    ]
    assert {it.command for it in stored} == {mavlink.MAV_CMD_NAV_RALLY_POINT}
    # Frame 3: the one PX4's RTL reads (rtl.cpp RTL::setSafepointAsDestination), ArduPilot too.
    assert {it.frame for it in stored} == {mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT}
    # ArduPilot asks with the legacy MISSION_REQUEST (queued_request_send), PX4 with _INT.
    assert [k for _, _, k, _ in v.seen] == [request_kind] * 3 + ["MISSION_ACK"]
    assert [k for _, _, k, _ in v.sent] == ["MISSION_COUNT"] + ["MISSION_ITEM_INT"] * 3
    # Emptying: a count of 0 is acknowledged at once.
    clear = RallyUpload(1, (), v.t)
    run_upload(v, clear)
    assert clear.state == UploadState.DONE and v.rally() == []


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_lost_item_is_requested_again_and_resent(personality):
    v = Vehicles(personality)
    lost = []

    def drop_first_item_1(m):
        if m.get_type() == "MISSION_ITEM_INT" and m.seq == 1 and not lost:
            lost.append(m)
            return True
        return False

    v.drop_up = drop_first_item_1
    up = RallyUpload(1, POINTS, v.t)
    run_upload(v, up)
    assert lost and up.state == UploadState.DONE
    requests_1 = [t for t, _, k, s in v.seen if k != "MISSION_ACK" and s == 1]
    assert len(requests_1) == 2
    # The vehicle asks again after its own resend period (vehicle_emu/missions.py RESEND_S, 1 s).
    assert requests_1[1] - requests_1[0] == pytest.approx(1.0, abs=0.11)
    assert len(v.rally()) == 3


def test_silent_vehicle_count_is_resent_then_upload_fails():
    v = Vehicles("ardupilot")
    v.drop_up = lambda m: True  # nothing reaches the vehicle
    up = RallyUpload(1, POINTS, v.t, ack_timeout_s=1.5, retries=5)
    run_upload(v, up, until_s=30.0)
    counts = [t for t, _, k, _ in v.sent if k == "MISSION_COUNT"]
    assert counts == pytest.approx([0.0, 1.5, 3.0, 4.5, 6.0, 7.5], abs=0.051)
    assert up.state == UploadState.FAILED and "MISSION_COUNT" in up.reason
    assert v.t == pytest.approx(9.0, abs=0.051)  # the last count's timeout


def test_vehicle_gone_silent_mid_upload_fails_after_the_timeout():
    v = Vehicles("px4")
    v.drop_down = lambda m: m.get_type() != "MISSION_REQUEST_INT" or m.seq > 0
    up = RallyUpload(1, POINTS, v.t, ack_timeout_s=1.5)
    run_upload(v, up)
    assert up.state == UploadState.FAILED and up.items_sent == 1
    assert "did not request every item" in up.reason
    first_item = [t for t, _, k, _ in v.sent if k == "MISSION_ITEM_INT"][0]
    assert v.t - first_item == pytest.approx(1.5, abs=0.051)


def test_error_ack_fails_the_upload():
    """Another GCS is uploading: ArduPilot / PX4 answer DENIED (vehicle_emu/missions.py)."""
    v = Vehicles("ardupilot")
    other = FakeGcs(sysid=254)
    v.cores[1].receive_datagram(
        other.frame(mavlink.MAVLink_mission_count_message(1, 1, 2, T_RALLY)), GCS_ADDR, v.t
    )
    v.cores[1].datagrams_to_send(v.t)
    up = RallyUpload(1, POINTS, v.t)
    run_upload(v, up)
    assert up.state == UploadState.FAILED and up.result == mavlink.MAV_MISSION_DENIED
    assert "MAV_MISSION_DENIED" in up.reason


def test_duplicate_item_invalid_sequence_ack_does_not_end_the_upload():
    """ArduPilot MissionItemProtocol::handle_mission_item acks a duplicate with INVALID_SEQUENCE
    and goes on; the upload still ends ACCEPTED."""
    v = Vehicles("ardupilot")
    up = RallyUpload(1, POINTS, v.t)
    dup = []

    def send_twice(sysid, msg, send=v.send):
        send(sysid, msg)
        if msg.get_type() == "MISSION_ITEM_INT" and msg.seq == 0 and not dup:
            dup.append(msg)
            send(sysid, msg)

    v.send = send_twice
    run_upload(v, up)
    assert dup and up.state == UploadState.DONE and up.duplicates == 1
    assert ("MISSION_ACK", mavlink.MAV_MISSION_INVALID_SEQUENCE) in [
        (k, s) for _, _, k, s in v.seen
    ]


def test_replies_for_another_gcs_or_mission_type_are_ignored():
    up = RallyUpload(1, POINTS, 0.0)
    up.take_messages()
    other_gcs = mavlink.MAVLink_mission_request_message(254, 190, 0, T_RALLY)
    other_type = mavlink.MAVLink_mission_request_message(
        255, 190, 0, mavlink.MAV_MISSION_TYPE_MISSION
    )
    for m in (other_gcs, other_type):
        up.on_event(mission_event(0, 1, m, 0.1), 0.1)
    assert up.state == UploadState.COUNT_SENT and up.take_messages() == []
    up.on_event(
        mission_event(0, 1, mavlink.MAVLink_mission_request_message(255, 190, 7, T_RALLY), 0.2), 0.2
    )
    assert up.state == UploadState.FAILED  # a request outside the list


# ------------------------------------------------------------------------------------------------
# The keeper
# ------------------------------------------------------------------------------------------------


def pump(v: Vehicles, keeper: RallyKeeper, reachable, seconds: float) -> None:
    end = v.t + seconds
    while v.t < end - 1e-9:
        for vid, m in keeper.poll(reachable, v.t):
            v.send(vid[1], m)
        for ev in v.replies():
            for vid, m in keeper.on_event(ev, v.t):
                v.send(vid[1], m)
        v.tick()


def test_keeper_same_set_for_every_vehicle_threshold_and_rate_limit():
    v = Vehicles("px4", n=3)
    cfg = RallyConfig(move_threshold_m=15.0, min_period_s=10.0, inward_m=0.0)
    keeper = RallyKeeper(*ORIGIN[:2], cfg)
    vids = [(0, s) for s in v.cores]
    pts = np.array([[80.0, 0.0], [0.0, -90.0]])
    assert keeper.publish(pts, v.t)
    pump(v, keeper, vids, 2.0)
    assert all(keeper.up_to_date(vid) for vid in vids)
    for s in v.cores:  # the same set everywhere, where it was published (mission frame)
        np.testing.assert_allclose(v.cores[s].pers.rally_ne_m(), pts, atol=0.05)
    uploads = keeper.stats["uploads"]
    assert not keeper.publish(pts + [[10.0, 0.0], [0.0, 0.0]], v.t)  # moved 10 m < 15 m
    assert not keeper.publish(pts + [[20.0, 0.0], [0.0, 0.0]], v.t)  # 20 m, but 2 s after
    v.t = 10.0
    assert not keeper.publish(pts + [[10.0, 5.0], [0.0, 0.0]], v.t)  # 11.2 m
    assert keeper.publish(pts + [[20.0, 0.0], [0.0, 0.0]], v.t)  # 20 m, 10 s after
    pump(v, keeper, vids, 2.0)
    assert keeper.stats["uploads"] == uploads + 3 and keeper.version == 2
    for s in v.cores:
        np.testing.assert_allclose(
            v.cores[s].pers.rally_ne_m(), pts + [[20.0, 0.0], [0.0, 0.0]], atol=0.05
        )
    pump(v, keeper, vids, 5.0)  # nothing new: no traffic
    assert keeper.stats["uploads"] == uploads + 3


def test_keeper_retries_a_failed_vehicle_later_and_skips_unreachable_ones():
    v = Vehicles("ardupilot", n=2)
    keeper = RallyKeeper(
        *ORIGIN[:2], RallyConfig(retry_after_s=5.0, retries=0, ack_timeout_s=1.0, inward_m=0.0)
    )
    keeper.publish(np.array([[60.0, 60.0]]), v.t)
    v.drop_up = lambda m: v.t < 3.0  # vehicle 2's link is down at first
    pump(v, keeper, [(0, 2)], 8.0)
    assert keeper.stats["failed"] == 1 and keeper.failures[0][1] == (0, 2)
    assert keeper.failures[0][0] == pytest.approx(1.0, abs=0.051)
    assert keeper.up_to_date((0, 2))  # retried at ~6 s, accepted
    assert v.cores[1].pers.rally_ne_m().shape == (0, 2)  # not reachable: never sent to


def test_keeper_keeps_the_points_nearest_the_base_and_forced_empty_set():
    keeper = RallyKeeper(*ORIGIN[:2], RallyConfig(max_points=2, inward_m=0.0))
    assert keeper.publish(np.array([[300.0, 0.0], [50.0, 0.0], [0.0, 100.0]]), 0.0)
    np.testing.assert_allclose(keeper.points_ne_m, [[50.0, 0.0], [0.0, 100.0]])
    assert not keeper.publish(np.zeros((0, 2)), 1.0)  # rate limit
    assert keeper.publish(np.zeros((0, 2)), 1.0, force=True)  # the end: cleared at once
    assert keeper.version == 2 and len(keeper.points_ne_m) == 0
    assert not keeper.publish(np.zeros((0, 2)), 1.0, force=True)  # already empty


def test_keeper_moves_points_inward_toward_the_base():
    keeper = RallyKeeper(*ORIGIN[:2], RallyConfig(inward_m=10.0))
    keeper.publish(np.array([[100.0, 0.0], [-30.0, 40.0], [6.0, 0.0]]), 0.0)
    np.testing.assert_allclose(keeper.points_ne_m, [[90.0, 0.0], [-24.0, 32.0], [0.0, 0.0]])


def test_set_moved():
    a = np.array([[0.0, 0.0], [10.0, 0.0]])
    assert set_moved(None, a, 5.0) and set_moved(a, a[:1], 5.0)
    assert not set_moved(a, a[::-1] + 1.0, 5.0)  # order does not matter
    assert set_moved(a, a + [[0.0, 0.0], [6.0, 0.0]], 5.0)


def test_rally_param_writes():
    assert rally_param_writes(ARDUPILOT, {"RALLY_LIMIT_KM": 0.3, "RALLY_INCL_HOME": 1}) == [
        ("RALLY_LIMIT_KM", 0.0)
    ]
    assert rally_param_writes(ARDUPILOT, {"RALLY_LIMIT_KM": 0.0}) == []
    assert rally_param_writes(ARDUPILOT, {}) == []
    assert rally_param_writes(PX4, {"RTL_TYPE": 2}) == [("RTL_TYPE", 0.0)]
    assert (
        rally_param_writes(PX4, {"RTL_TYPE": 0}) == [] == rally_param_writes(PX4, {"RTL_TYPE": 1})
    )


def test_planner_rally_points_are_the_resilient_planners():
    from planner.methods import TickInput, make_planner
    from planner.problem import ProblemConfig
    from planner.resilient import rally_points

    problem = ProblemConfig(
        n_drones=6,
        n_tasks=3,
        length_unit_m=50.0,
        radio_range_m=100.0,
        base_range_m=100.0,
        max_speed_m_s=7.5,
        field_half_width_m=250.0,
    )
    tasks = np.array([[200.0, 0.0], [0.0, -180.0], [150.0, 150.0]])
    pos = np.array([[10.0, 0.0], [0.0, 10.0], [-10.0, 0.0], [0.0, -10.0], [5.0, 5.0], [-5, -5.0]])
    tick = TickInput(0, pos, np.ones(6, bool), np.ones(6, bool), tasks)
    res = make_planner(
        "phireman-resilient", problem, {"rally": True, "info": "central"}, np.random.default_rng(0)
    )
    res.plan(tick)
    pts = planner_rally_points_m(res)
    assert pts is not None and pts.shape[1] == 2 and len(pts) >= 1
    np.testing.assert_allclose(pts, rally_points(res.tree, res.params.rally_dist) * 50.0)
    assert np.all(np.hypot(*pts.T) <= 100.0 + 1e-6)  # rally_dist = 2 units = r from the base
    off = make_planner("phireman-resilient", problem, {"info": "central"}, np.random.default_rng(0))
    off.plan(tick)
    assert planner_rally_points_m(off) is None
    phi = make_planner("phireman", problem, {"info": "central"}, np.random.default_rng(0))
    phi.plan(tick)
    assert planner_rally_points_m(phi) is None


# ------------------------------------------------------------------------------------------------
# Frames the firmware can fly to, and loud failures (issue 28, point 5)
# ------------------------------------------------------------------------------------------------


def statustexts(v: Vehicles, seconds: float) -> list[tuple[float, int, int, str]]:
    """Tick ``seconds`` and return every STATUSTEXT as (t, sysid, severity, text)."""
    out = []
    end = v.t + seconds
    while v.t < end - 1e-9:
        v.tick()
        for sysid, core in v.cores.items():
            for m in v.gcs.decode(core.datagrams_to_send(v.t)):
                if m.get_type() == "STATUSTEXT":
                    out.append((v.t, sysid, m.severity, m.text))
    return out


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_station_points_are_ones_the_firmware_rtl_uses(personality):
    """The station's items (frame 3) are taken by both firmwares, and PX4's RTL has no complaint
    about them (with frame 6 it says "RTL: unsupported MAV_FRAME" every 2 s: next test)."""
    v = Vehicles(personality)
    keeper = RallyKeeper(*ORIGIN[:2], RallyConfig(inward_m=0.0))
    keeper.publish(np.array([[120.0, 0.0]]), v.t)
    pump(v, keeper, [(0, 1)], 2.0)
    assert keeper.up_to_date((0, 1)) and keeper.stats["failed"] == 0
    assert (
        [it.frame for it in v.rally()]
        == [RALLY_ITEM_FRAME]
        == [mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT]
    )
    assert not [t for t in statustexts(v, 6.0) if "MAV_FRAME" in t[3]]
    # RTL from 200 m north goes to the point (120 m), not home.
    core = v.cores[1]
    core.physics.pos_ned_m[0] = (200.0, 0.0, -20.0)
    np.testing.assert_allclose(core.pers.rtl_destination_ned_m(v.t)[:2], (120.0, 0.0), atol=0.1)


def test_keeper_reports_a_firmware_that_cannot_use_its_points_loudly(caplog):
    """PX4 up to main of 2026-03-29 accepts frame-6 rally points, reads them back as 6 and then
    says "RTL: unsupported MAV_FRAME" (severity 2) every 2 s: the keeper takes that as a failed
    upload, once per set, with an error in the log and a RallyUploadFailed event, and does not
    send the same set again (it would be refused again); the next set goes out as usual."""
    v = Vehicles("px4")
    events: list[RallyUploadFailed] = []
    keeper = RallyKeeper(*ORIGIN[:2], RallyConfig(inward_m=0.0, min_period_s=0.0))
    keeper.on_failure = events.append
    keeper.publish(np.array([[120.0, 0.0]]), v.t)
    pump(v, keeper, [(0, 1)], 2.0)
    assert keeper.up_to_date((0, 1))
    # What the station sent before the fix: the same point in frame 6 (GLOBAL_RELATIVE_ALT_INT).
    core = v.cores[1]
    core._missions.items[T_RALLY] = [
        dataclasses.replace(it, frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT) for it in v.rally()
    ]
    texts = statustexts(v, 6.0)
    bad = [(t, sev) for t, _, sev, text in texts if text == "RTL: unsupported MAV_FRAME"]
    assert len(bad) >= 2 and {sev for _, sev in bad} == {mavlink.MAV_SEVERITY_CRITICAL}
    assert bad[1][0] - bad[0][0] == pytest.approx(2.0, abs=0.051)
    uploads = keeper.stats["uploads"]
    with caplog.at_level(logging.ERROR, logger="gcs.rally"):
        for t, sysid, _, text in texts:
            keeper.on_status_text((0, sysid), text, t)
    assert not keeper.up_to_date((0, 1)) and keeper.stats["failed"] == 1
    assert len(events) == 1 and events[0].refused and events[0].version == keeper.version
    assert (events[0].link_id, events[0].sysid) == (0, 1)
    assert "unsupported MAV_FRAME" in events[0].reason
    assert [r.levelno for r in caplog.records] == [logging.ERROR]
    pump(v, keeper, [(0, 1)], 10.0)  # refused: the same set is not sent again
    assert keeper.stats["uploads"] == uploads
    assert keeper.publish(np.array([[150.0, 0.0]]), v.t)  # a new set is
    pump(v, keeper, [(0, 1)], 2.0)
    assert keeper.up_to_date((0, 1)) and keeper.stats["uploads"] == uploads + 1


def test_keeper_refused_upload_is_an_error_and_an_event(caplog):
    """A MISSION_ACK error (another GCS uploading: DENIED) is logged as an error and announced."""
    v = Vehicles("ardupilot")
    other = FakeGcs(sysid=254)
    v.cores[1].receive_datagram(
        other.frame(mavlink.MAVLink_mission_count_message(1, 1, 2, T_RALLY)), GCS_ADDR, v.t
    )
    v.cores[1].datagrams_to_send(v.t)
    events: list[RallyUploadFailed] = []
    keeper = RallyKeeper(*ORIGIN[:2], RallyConfig(inward_m=0.0))
    keeper.on_failure = events.append
    keeper.publish(np.array([[60.0, 0.0]]), v.t)
    with caplog.at_level(logging.ERROR, logger="gcs.rally"):
        pump(v, keeper, [(0, 1)], 1.0)
    assert [(e.result, e.refused) for e in events] == [(mavlink.MAV_MISSION_DENIED, True)]
    assert "MAV_MISSION_DENIED" in events[0].reason
    assert [r.levelno for r in caplog.records] == [logging.ERROR]

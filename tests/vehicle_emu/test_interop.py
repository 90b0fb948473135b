"""What third-party ground stations (QGC, Mission Planner, MAVProxy) send on connect and while
planning, and what the emulator answers: in memory, explicit time, both personalities.

Firmware references: ArduPilot libraries/GCS_MAVLink/GCS_Common.cpp, MissionItemProtocol.cpp,
ArduCopter/GCS_Mavlink.cpp; PX4 src/modules/mavlink/mavlink_receiver.cpp, mavlink_mission.cpp,
mavlink_main.cpp (see vehicle_emu/missions.py and vehicle_emu/link.py).
"""

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from vehicle_emu.link import VehicleCore

from emu_helpers import GCS_ADDR, acks, of_type

HOME = (47.5, 8.5, 400.0)
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
M_ACCEPTED = mavlink.MAV_MISSION_ACCEPTED
T_MISSION, T_FENCE, T_RALLY = 0, 1, 2


class Rig:
    def __init__(self, gcs, personality):
        self.gcs = gcs
        self.t = 0.0
        self.px4 = personality == "px4"
        self.core = VehicleCore(1, personality, origin_lla=HOME)

    def send(self, data):
        self.core.receive_datagram(data, GCS_ADDR, self.t)
        return self.gcs.decode(self.core.datagrams_to_send(self.t))

    def msg(self, m):
        return self.send(self.gcs.frame(m))

    def run(self, until_s):
        out = []
        while self.t < until_s - 1e-9:
            self.t = round(self.t + 0.05, 6)
            self.core.receive_datagram(self.gcs.heartbeat(), GCS_ADDR, self.t)
            self.core.handle_timer(self.t)
            out += self.gcs.decode(self.core.datagrams_to_send(self.t))
        return out

    def download(self, mission_type, as_int=True):
        out = self.msg(mavlink.MAVLink_mission_request_list_message(1, 1, mission_type))
        counts = of_type(out, "MISSION_COUNT")
        assert len(counts) == 1 and counts[0].mission_type == mission_type
        assert counts[0].target_system == 255  # answered to the requester
        items = []
        for seq in range(counts[0].count):
            req = (
                mavlink.MAVLink_mission_request_int_message
                if as_int
                else mavlink.MAVLink_mission_request_message
            )
            out = self.msg(req(1, 1, seq, mission_type))
            got = of_type(out, "MISSION_ITEM_INT" if as_int else "MISSION_ITEM")
            assert len(got) == 1 and got[0].seq == seq and got[0].mission_type == mission_type
            items.append(got[0])
        self.msg(mavlink.MAVLink_mission_ack_message(1, 1, M_ACCEPTED, mission_type))
        return items

    def upload(self, mission_type, items):
        """Answer every request like QGC (MISSION_ITEM_INT); return (request types, acks)."""
        out = self.msg(mavlink.MAVLink_mission_count_message(1, 1, len(items), mission_type))
        req_types, mission_acks = [], []
        for _ in range(len(items) + 1):
            mission_acks += of_type(out, "MISSION_ACK")
            reqs = [m for m in out if m.get_type() in ("MISSION_REQUEST", "MISSION_REQUEST_INT")]
            if not reqs:
                break
            assert len(reqs) == 1
            r = reqs[0]
            req_types.append(r.get_type())
            assert r.mission_type == mission_type and r.target_system == 255
            frame, cmd, x, y, z = items[r.seq]
            out = self.msg(
                mavlink.MAVLink_mission_item_int_message(
                    1, 1, r.seq, frame, cmd, 0, 1, 0, 0, 0, 0, x, y, z, mission_type
                )
            )
        return req_types, mission_acks


def _wp(lat, lon, alt, cmd=mavlink.MAV_CMD_NAV_WAYPOINT, frame=6):
    return frame, cmd, int(lat * 1e7), int(lon * 1e7), alt


@pytest.fixture(params=["ardupilot", "px4"])
def rig(request, gcs):
    return Rig(gcs, request.param)


# ---------------------------------------------------------------------------------------------
# QGroundControl / Mission Planner connect sequence
# ---------------------------------------------------------------------------------------------


def test_qgc_connect_handshake(rig, gcs):
    core = rig.core
    rig.send(gcs.heartbeat())
    # 1. REQUEST_MESSAGE(AUTOPILOT_VERSION): ACK first, then the message.
    out = rig.send(gcs.command(512, 148))
    assert [m.get_type() for m in out] == ["COMMAND_ACK", "AUTOPILOT_VERSION"]
    assert out[0].result == ACCEPTED and out[0].target_system == 255
    caps = out[1].capabilities
    for bit in (
        "MAVLINK2",
        "MISSION_INT",
        "COMMAND_INT",
        "SET_POSITION_TARGET_GLOBAL_INT",
        "SET_POSITION_TARGET_LOCAL_NED",
        "MISSION_FENCE",
        "MISSION_RALLY",
    ):
        assert caps & getattr(mavlink, "MAV_PROTOCOL_CAPABILITY_" + bit), bit
    bytewise = bool(caps & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
    c_cast = bool(caps & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
    assert (bytewise, c_cast) == ((True, False) if rig.px4 else (False, True))
    assert not caps & mavlink.MAV_PROTOCOL_CAPABILITY_FTP  # not implemented: not advertised
    assert out[1].flight_sw_version >> 24 == (1 if rig.px4 else 4)
    # 2. PROTOCOL_VERSION (300): not in this emulator; the firmware rule for an unknown id
    #    (ArduPilot FAILED, PX4 DENIED) - an ACK either way, never silence.
    assert acks(rig.send(gcs.command(512, 300)), 512) == [
        mavlink.MAV_RESULT_DENIED if rig.px4 else mavlink.MAV_RESULT_FAILED
    ]
    # 3. Legacy REQUEST_AUTOPILOT_CAPABILITIES.
    out = rig.send(gcs.command(520, 1))
    assert acks(out, 520) == [ACCEPTED] and len(of_type(out, "AUTOPILOT_VERSION")) == 1
    # 4. Parameters.
    out = rig.msg(mavlink.MAVLink_param_request_list_message(1, 1))
    pv = of_type(out, "PARAM_VALUE")
    n = len(core.params)
    assert {p.param_count for p in pv} == {n}
    assert sorted(p.param_index for p in pv) == list(range(n))
    # 5. Mission, fence, rally: each answered with its own MISSION_COUNT.
    expected = {T_MISSION: 0 if rig.px4 else 1, T_FENCE: 0, T_RALLY: 0}
    for t, count in expected.items():
        out = rig.msg(mavlink.MAVLink_mission_request_list_message(1, 1, t))
        mc = of_type(out, "MISSION_COUNT")
        assert [(m.count, m.mission_type) for m in mc] == [(count, t)]
    # 6. Streams: SET_MESSAGE_INTERVAL acked; REQUEST_DATA_STREAM (Mission Planner) honoured
    #    by ArduPilot.
    assert acks(rig.send(gcs.command(511, 33, 500_000)), 511) == [ACCEPTED]
    rig.msg(mavlink.MAVLink_request_data_stream_message(1, 1, mavlink.MAV_DATA_STREAM_ALL, 2, 1))
    # 7. TIMESYNC and SYSTEM_TIME.
    out = rig.msg(mavlink.MAVLink_timesync_message(0, 123456789))
    ts = of_type(out, "TIMESYNC")
    assert len(ts) == 1 and ts[0].ts1 == 123456789 and ts[0].tc1 > 0
    assert rig.msg(mavlink.MAVLink_system_time_message(1_700_000_000_000_000, 0)) == []
    # 8. Home: MAV_CMD_GET_HOME_POSITION and REQUEST_MESSAGE(HOME_POSITION).
    out = rig.send(gcs.command(410))
    assert acks(out, 410) == [ACCEPTED]
    home = of_type(out, "HOME_POSITION")
    assert len(home) == 1 and home[0].latitude == 475000000 and home[0].altitude == 400000
    out = rig.send(gcs.command(512, 242))
    assert acks(out, 512) == [ACCEPTED] and len(of_type(out, "HOME_POSITION")) == 1
    # 9. Unknown commands: COMMAND_ACK UNSUPPORTED, long and int.
    assert acks(rig.send(gcs.command(31010)), 31010) == [mavlink.MAV_RESULT_UNSUPPORTED]
    out = rig.msg(mavlink.MAVLink_command_int_message(1, 1, 0, 31011, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert acks(out, 31011) == [mavlink.MAV_RESULT_UNSUPPORTED]
    # 10. PING.
    out = rig.msg(mavlink.MAVLink_ping_message(42, 7, 0, 0))
    ping = of_type(out, "PING")
    assert len(ping) == 1 and ping[0].seq == 7 and ping[0].target_system == 255
    assert core.stats.unhandled == 0 and core.stats.handler_errors == 0
    # The requested streams flow afterwards.
    types = {m.get_type() for m in rig.run(2.0)}
    assert {"HEARTBEAT", "GLOBAL_POSITION_INT"} <= types
    if not rig.px4:
        assert {"SYS_STATUS", "GPS_RAW_INT", "MISSION_CURRENT"} <= types


def test_param_value_consistent_by_index_and_name(rig, gcs):
    names = rig.core.params.names()
    for i, name in enumerate(names):
        by_idx = of_type(
            rig.msg(mavlink.MAVLink_param_request_read_message(1, 1, b"", i)), "PARAM_VALUE"
        )
        by_name = of_type(
            rig.msg(mavlink.MAVLink_param_request_read_message(1, 1, name.encode(), -1)),
            "PARAM_VALUE",
        )
        assert len(by_idx) == len(by_name) == 1
        for pv in (by_idx[0], by_name[0]):
            assert pv.param_id == name and pv.param_index == i
            assert pv.param_count == len(names)


def test_ardupilot_sys_status_reports_geofence_healthy(gcs):
    rig = Rig(gcs, "ardupilot")
    rig.send(gcs.command(511, 1, 1_000_000))
    ss = of_type(rig.run(1.5), "SYS_STATUS")
    assert ss and ss[0].onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_GEOFENCE
    assert not ss[0].onboard_control_sensors_present & mavlink.MAV_SYS_STATUS_GEOFENCE


# ---------------------------------------------------------------------------------------------
# Mission protocol
# ---------------------------------------------------------------------------------------------


def test_ardupilot_empty_mission_is_home_only(gcs):
    rig = Rig(gcs, "ardupilot")
    items = rig.download(T_MISSION)
    assert len(items) == 1
    home = items[0]
    assert home.command == mavlink.MAV_CMD_NAV_WAYPOINT and home.frame == mavlink.MAV_FRAME_GLOBAL
    assert (home.x, home.y, home.z) == (475000000, 85000000, pytest.approx(400.0))
    # Legacy MISSION_REQUEST -> MISSION_ITEM in degrees (MissionItemProtocol handle_mission_request)
    legacy = rig.download(T_MISSION, as_int=False)
    assert legacy[0].x == pytest.approx(47.5) and legacy[0].y == pytest.approx(8.5)
    out = rig.msg(mavlink.MAVLink_mission_request_int_message(1, 1, 1, T_MISSION))
    assert [a.type for a in of_type(out, "MISSION_ACK")] == [mavlink.MAV_MISSION_INVALID_SEQUENCE]


def test_px4_empty_mission_has_no_items(gcs):
    rig = Rig(gcs, "px4")
    assert rig.download(T_MISSION) == []


def test_mission_upload_then_download(rig, gcs):
    items = [_wp(47.5001, 8.5001, 20.0), _wp(47.5002, 8.5002, 25.0), _wp(47.5003, 8.5, 30.0)]
    if not rig.px4:
        items = [_wp(*HOME, frame=0)] + items  # ArduPilot GCSes upload home as item 0
    req_types, mission_acks = rig.upload(T_MISSION, items)
    # ArduPilot queued_request_send sends MISSION_REQUEST; PX4 (_int_mode) MISSION_REQUEST_INT.
    want = "MISSION_REQUEST_INT" if rig.px4 else "MISSION_REQUEST"
    assert req_types == [want] * len(items)
    assert [(a.type, a.mission_type) for a in mission_acks] == [(M_ACCEPTED, T_MISSION)]
    got = rig.download(T_MISSION)
    assert len(got) == len(items)
    for it, (frame, cmd, x, y, z) in list(zip(got, items))[(0 if rig.px4 else 1) :]:
        assert (it.frame, it.command, it.x, it.y) == (frame, cmd, x, y)
        assert it.z == pytest.approx(z)
    # MISSION_CURRENT.total counts the plan without ArduPilot's home.
    rig.send(gcs.command(511, mavlink.MAVLINK_MSG_ID_MISSION_CURRENT, 1_000_000))
    mc = of_type(rig.run(1.5), "MISSION_CURRENT")
    assert mc and mc[0].total == 3 and mc[0].mission_state == mavlink.MISSION_STATE_NOT_STARTED


def test_empty_upload_is_acked_at_once(rig, gcs):
    rig.upload(T_MISSION, [_wp(47.5001, 8.5001, 20.0)] * 2)
    req_types, mission_acks = rig.upload(T_MISSION, [])
    assert req_types == [] and [a.type for a in mission_acks] == [M_ACCEPTED]
    assert len(rig.download(T_MISSION)) == (0 if rig.px4 else 1)


def test_upload_request_resent_then_cancelled(rig, gcs):
    out = rig.msg(mavlink.MAVLink_mission_count_message(1, 1, 2, T_MISSION))
    first = [m for m in out if m.get_type().startswith("MISSION_REQUEST")]
    assert len(first) == 1 and first[0].seq == 0
    out = rig.run(1.5)
    resent = [m for m in out if m.get_type().startswith("MISSION_REQUEST")]
    assert [m.seq for m in resent] == [0]
    # A download while the upload is pending is denied (MissionItemProtocol: "someone is
    # uploading a mission; reject fetching of points").
    out = rig.msg(mavlink.MAVLink_mission_request_list_message(1, 1, T_MISSION))
    assert [a.type for a in of_type(out, "MISSION_ACK")] == [mavlink.MAV_MISSION_DENIED]
    out = rig.run(9.0)
    assert [a.type for a in of_type(out, "MISSION_ACK")] == [
        mavlink.MAV_MISSION_OPERATION_CANCELLED
    ]
    assert of_type(rig.run(12.0), "MISSION_ACK") == []
    assert len(rig.download(T_MISSION)) == (0 if rig.px4 else 1)  # nothing was stored


def test_upload_wrong_seq_and_second_gcs(rig, gcs):
    from emu_helpers import FakeGcs

    rig.msg(mavlink.MAVLink_mission_count_message(1, 1, 1, T_MISSION))
    out = rig.msg(
        mavlink.MAVLink_mission_item_int_message(
            1, 1, 5, 6, 16, 0, 1, 0, 0, 0, 0, 475001000, 85001000, 10.0, T_MISSION
        )
    )
    assert [a.type for a in of_type(out, "MISSION_ACK")] == [mavlink.MAV_MISSION_INVALID_SEQUENCE]
    other = FakeGcs(sysid=254)
    rig.core.receive_datagram(
        other.frame(mavlink.MAVLink_mission_count_message(1, 1, 3, T_MISSION)), GCS_ADDR, rig.t
    )
    out = gcs.decode(rig.core.datagrams_to_send(rig.t))
    assert [(a.type, a.target_system) for a in of_type(out, "MISSION_ACK")] == [
        (mavlink.MAV_MISSION_DENIED, 254)
    ]
    out = rig.msg(
        mavlink.MAVLink_mission_item_int_message(
            1, 1, 0, 6, 16, 0, 1, 0, 0, 0, 0, 475001000, 85001000, 10.0, T_MISSION
        )
    )
    assert [a.type for a in of_type(out, "MISSION_ACK")] == [M_ACCEPTED]
    # An item outside any upload is an error, not silence.
    out = rig.msg(
        mavlink.MAVLink_mission_item_int_message(
            1, 1, 0, 6, 16, 0, 1, 0, 0, 0, 0, 475001000, 85001000, 10.0, T_MISSION
        )
    )
    assert [a.type for a in of_type(out, "MISSION_ACK")] == [mavlink.MAV_MISSION_ERROR]


def test_fence_and_rally_upload_download_clear(rig, gcs):
    poly = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
    fence = [
        _wp(47.49, 8.49, 0, cmd=poly, frame=5),
        _wp(47.51, 8.49, 0, cmd=poly, frame=5),
        _wp(47.51, 8.51, 0, cmd=poly, frame=5),
    ]
    _, mission_acks = rig.upload(T_FENCE, fence)
    assert [(a.type, a.mission_type) for a in mission_acks] == [(M_ACCEPTED, T_FENCE)]
    rally = [_wp(47.5005, 8.5005, 15.0, cmd=mavlink.MAV_CMD_NAV_RALLY_POINT)]
    _, mission_acks = rig.upload(T_RALLY, rally)
    assert [(a.type, a.mission_type) for a in mission_acks] == [(M_ACCEPTED, T_RALLY)]
    assert [it.command for it in rig.download(T_FENCE)] == [poly] * 3
    assert [it.x for it in rig.download(T_RALLY)] == [rally[0][2]]
    # A waypoint is not a fence item.
    _, mission_acks = rig.upload(T_FENCE, [_wp(47.5, 8.5, 10.0)])
    assert [a.type for a in mission_acks] == [mavlink.MAV_MISSION_UNSUPPORTED]
    assert len(rig.download(T_FENCE)) == 3  # the refused upload left the old fence
    out = rig.msg(mavlink.MAVLink_mission_clear_all_message(1, 1, mavlink.MAV_MISSION_TYPE_ALL))
    assert [a.type for a in of_type(out, "MISSION_ACK")] == [M_ACCEPTED]
    assert rig.download(T_FENCE) == [] and rig.download(T_RALLY) == []


# ---------------------------------------------------------------------------------------------
# AUTO is refused, loudly; ArduPilot guided waypoints via MISSION_ITEM current=2
# ---------------------------------------------------------------------------------------------


def _texts(msgs):
    return [m.text for m in of_type(msgs, "STATUSTEXT")]


def test_auto_mode_refused_with_statustext(rig, gcs):
    mode0 = rig.core.custom_mode
    set_auto = gcs.command(176, 1, 4, 4) if rig.px4 else gcs.command(176, 1, 3)
    out = rig.send(set_auto)
    assert acks(out, 176) == [
        mavlink.MAV_RESULT_TEMPORARILY_REJECTED if rig.px4 else mavlink.MAV_RESULT_FAILED
    ]
    assert _texts(out) and rig.core.custom_mode == mode0
    home = [_wp(*HOME, frame=0)] if not rig.px4 else []
    rig.upload(T_MISSION, home + [_wp(47.5001, 8.5001, 20.0)])
    out = rig.send(set_auto)
    assert acks(out, 176)[0] != ACCEPTED
    assert any("not flown" in t for t in _texts(out)) and rig.core.custom_mode == mode0
    # SET_MODE (MAVProxy ``mode AUTO``) takes the same path.
    custom = (4 << 16) | (4 << 24) if rig.px4 else 3
    out = rig.msg(mavlink.MAVLink_set_mode_message(1, 1, custom))
    assert rig.core.custom_mode == mode0 and acks(out)[0] != ACCEPTED


def test_ardupilot_guided_mission_item_current2(gcs):
    rig = Rig(gcs, "ardupilot")
    item = mavlink.MAVLink_mission_item_int_message(
        1, 1, 0, 3, 16, 2, 0, 0, 0, 0, 0, 475004500, 85000000, 20.0, T_MISSION
    )
    out = rig.msg(item)  # STABILIZE, disarmed: refused
    assert [a.type for a in of_type(out, "MISSION_ACK")] == [mavlink.MAV_MISSION_ERROR]
    assert acks(rig.send(gcs.command(176, 1, 4)), 176) == [ACCEPTED]
    assert acks(rig.send(gcs.command(400, 1)), 400) == [ACCEPTED]
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, 10)), 22) == [ACCEPTED]
    rig.run(6.0)
    out = rig.msg(item)
    assert [a.type for a in of_type(out, "MISSION_ACK")] == [M_ACCEPTED]
    rig.run(25.0)
    north, east, down = rig.core.local_pos_ned_m
    assert north == pytest.approx(50.0, abs=1.0) and east == pytest.approx(0.0, abs=1.0)
    assert down == pytest.approx(-20.0, abs=0.5)
    # current = 3: altitude change only.
    alt = mavlink.MAVLink_mission_item_int_message(
        1, 1, 0, 3, 16, 3, 0, 0, 0, 0, 0, 0, 0, 12.0, T_MISSION
    )
    assert [a.type for a in of_type(rig.msg(alt), "MISSION_ACK")] == [M_ACCEPTED]
    rig.run(35.0)
    assert rig.core.local_pos_ned_m == pytest.approx([50.0, 0.0, -12.0], abs=1.0)


def test_ardupilot_request_data_stream_all_includes_attitude_and_vfr_hud(gcs):
    # MAVProxy and Mission Planner ask for MAV_DATA_STREAM_ALL; ArduCopter GCS_Mavlink.cpp
    # puts ATTITUDE in EXTRA1 and VFR_HUD in EXTRA2.
    rig = Rig(gcs, "ardupilot")
    rig.msg(mavlink.MAVLink_request_data_stream_message(1, 1, mavlink.MAV_DATA_STREAM_ALL, 4, 1))
    assert acks(rig.send(gcs.command(176, 1, 4)), 176) == [ACCEPTED]
    assert acks(rig.send(gcs.command(400, 1)), 400) == [ACCEPTED]
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, 10)), 22) == [ACCEPTED]
    out = rig.run(2.0)
    att, hud = of_type(out, "ATTITUDE"), of_type(out, "VFR_HUD")
    assert 6 <= len(att) <= 10 and 6 <= len(hud) <= 10
    assert hud[-1].climb > 0.5 and hud[-1].alt > HOME[2] + 1.0  # climbing, AMSL altitude
    assert all(-3.1416 <= a.yaw <= 3.1416 for a in att)

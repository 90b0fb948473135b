"""The emulator's RTL goes to a rally point as each firmware chooses it (vehicle_emu/personality:
ArduPilot AP_Rally, PX4 RTL_TYPE), in memory on an explicit clock."""

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavedge.units import deg_to_e7
from planner.geometry import ned_to_geodetic
from vehicle_emu.link import VehicleCore
from vehicle_emu.missions import MissionItem

from emu_helpers import GCS_ADDR, acks, of_type

ORIGIN = (47.5, 8.5, 400.0)
T_RALLY = mavlink.MAV_MISSION_TYPE_RALLY
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED


def rally_item(
    north_m: float, east_m: float, frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
) -> MissionItem:
    lat, lon, _ = ned_to_geodetic(np.array([[north_m, east_m, 0.0]]), *ORIGIN)
    return MissionItem(
        frame,
        mavlink.MAV_CMD_NAV_RALLY_POINT,
        0,
        1,
        (0.0, 0.0, 0.0, 0.0),
        deg_to_e7(float(lat[0])),
        deg_to_e7(float(lon[0])),
        40.0,
    )


def destination(personality: str, at_ne_m, rally_ne_m, **params) -> np.ndarray:
    """Where RTL would fly from ``at_ne_m`` with these rally points and parameters (N, E)."""
    core = VehicleCore(1, personality, origin_lla=ORIGIN, params=params)
    core._missions.items[T_RALLY] = [rally_item(*p) for p in rally_ne_m]
    core.physics.pos_ned_m[0] = (at_ne_m[0], at_ne_m[1], -20.0)
    dest = core.pers.rtl_destination_ned_m(0.0)
    assert dest[2] == core.home_ned_m[2]  # the return altitude stays the core's
    return np.round(dest[:2], 1)


HOME = [0.0, 0.0]


@pytest.mark.parametrize(
    "at, points, params, expect",
    [
        ((200, 0), [], {}, HOME),  # no rally point: home
        ((200, 0), [(100, 0), (0, 100)], {}, [100, 0]),  # the nearest point
        ((10, 0), [(100, 0)], {}, HOME),  # RALLY_INCL_HOME 1: home nearer
        ((10, 0), [(100, 0)], {"RALLY_INCL_HOME": 0}, [100, 0]),  # ... not considered
        ((500, 0), [(150, 0)], {}, HOME),  # 350 m > RALLY_LIMIT_KM 0.3
        ((500, 0), [(150, 0)], {"RALLY_LIMIT_KM": 0.0}, [150, 0]),  # no limit
        ((51, 0), [(101, 0)], {}, [101, 0]),  # 50 m < 51 m: strict, no margin
        ((0, 200), [(0, 100), (0, 100)], {}, [0, 100]),  # equal points: the first
    ],
)
def test_ardupilot_rtl_destination(at, points, params, expect):
    """AP_Rally::calc_best_rally_or_home_location / find_nearest_rally_point (Copter defaults
    RALLY_LIMIT_KM 0.3, RALLY_INCL_HOME 1)."""
    np.testing.assert_allclose(destination("ardupilot", at, points, **params), expect, atol=0.2)


@pytest.mark.parametrize(
    "at, points, params, expect",
    [
        ((200, 0), [], {}, HOME),
        ((200, 0), [(100, 0), (0, 100)], {}, [100, 0]),  # RTL_TYPE 0: closest safe point
        ((10, 0), [(100, 0)], {}, HOME),  # home is closer
        ((10, 0), [(100, 0)], {"RTL_TYPE": 1}, [100, 0]),  # 1: rally before home
        ((200, 0), [(100, 0)], {"RTL_TYPE": 2}, HOME),  # 2: rally points not considered
        ((200, 0), [(100, 0)], {"RTL_TYPE": 3}, [100, 0]),
        ((51, 0), [(101, 0)], {}, HOME),  # 50 + 2 m margin is not < 51
        ((200, 0), [(8, 0)], {"RTL_TYPE": 1}, HOME),  # within 10 m of home: ignored
        ((200, 0), [(8, 0)], {"RTL_TYPE": 5}, [8, 0]),  # ... except RTL_TYPE 5
        ((200, 30), [], {"RTL_TYPE": 5}, [200, 30]),  # 5, none: where it is
        ((500, 0), [(150, 0)], {}, [150, 0]),  # no distance limit in PX4
    ],
)
def test_px4_rtl_destination(at, points, params, expect):
    """RTL::findRtlDestination / findClosestSafePoint (src/modules/navigator/rtl.cpp)."""
    np.testing.assert_allclose(destination("px4", at, points, **params), expect, atol=0.2)


class Rig:
    """One vehicle, a fake GCS and an explicit clock (as tests/vehicle_emu/test_link_*.py)."""

    def __init__(self, gcs, personality):
        self.gcs = gcs
        self.t = 0.0
        self.core = VehicleCore(1, personality, origin_lla=ORIGIN)

    def send(self, data):
        self.core.receive_datagram(data, GCS_ADDR, self.t)
        return self.gcs.decode(self.core.datagrams_to_send(self.t))

    def run(self, until_s, sp=None):
        out = []
        while self.t < until_s - 1e-9:
            self.t = round(self.t + 0.05, 6)
            self.core.receive_datagram(self.gcs.heartbeat(), GCS_ADDR, self.t)
            if sp is not None:
                self.core.receive_datagram(self.gcs.local_target(*sp), GCS_ADDR, self.t)
            self.core.handle_timer(self.t)
            out += self.gcs.decode(self.core.datagrams_to_send(self.t))
        return out

    def upload_rally(self, points_ne_m, frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT):
        """The MAVLink mission protocol, as a GCS runs it (count, requested items, ack)."""
        items = [rally_item(*p, frame=frame) for p in points_ne_m]
        out = self.send(
            self.gcs.frame(mavlink.MAVLink_mission_count_message(1, 1, len(items), T_RALLY))
        )
        while True:
            reqs = of_type(out, "MISSION_REQUEST") + of_type(out, "MISSION_REQUEST_INT")
            if not reqs:
                return of_type(out, "MISSION_ACK")
            it = items[reqs[0].seq]
            out = self.send(
                self.gcs.frame(
                    mavlink.MAVLink_mission_item_int_message(
                        1,
                        1,
                        reqs[0].seq,
                        it.frame,
                        it.command,
                        0,
                        1,
                        0,
                        0,
                        0,
                        0,
                        it.x,
                        it.y,
                        it.z,
                        T_RALLY,
                    )
                )
            )


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_rtl_flies_to_the_rally_point_and_lands_there(gcs, personality):
    rig = Rig(gcs, personality)
    acks_ = rig.upload_rally([(100.0, 0.0), (0.0, -120.0)])
    assert [a.type for a in acks_] == [mavlink.MAV_MISSION_ACCEPTED]
    out_at = (200.0, 20.0, -15.0)
    if personality == "ardupilot":
        assert acks(rig.send(gcs.command(176, 1, 4)), 176) == [ACCEPTED]  # GUIDED
        assert acks(rig.send(gcs.command(400, 1)), 400) == [ACCEPTED]
        assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, 15.0)), 22) == [ACCEPTED]
        rig.run(8.0)
    else:
        rig.run(1.0, sp=out_at)
        assert acks(rig.send(gcs.command(176, 1, 6)), 176) == [ACCEPTED]  # OFFBOARD
        assert acks(rig.send(gcs.command(400, 1)), 400) == [ACCEPTED]
    rig.run(rig.t + 40.0, sp=out_at)
    np.testing.assert_allclose(rig.core.local_pos_ned_m, out_at, atol=1.0)
    assert acks(rig.send(gcs.command(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)), 20) == [ACCEPTED]
    rig.run(rig.t + 200.0)  # PX4: climb to RTL_RETURN_ALT 60 m, land at 0.7 m/s
    assert rig.core.landed and not rig.core.armed
    # Landed at the nearest rally point (about 102 m away), not at home (about 201 m away).
    np.testing.assert_allclose(rig.core.local_pos_ned_m[:2], (100.0, 0.0), atol=1.5)


def _read_back(rig, as_int: bool) -> list[int]:
    """The stored rally items' frames as the vehicle reports them (the download half)."""
    out = rig.send(rig.gcs.frame(mavlink.MAVLink_mission_request_list_message(1, 1, T_RALLY)))
    (count,) = of_type(out, "MISSION_COUNT")
    frames = []
    for seq in range(count.count):
        cls = (
            mavlink.MAVLink_mission_request_int_message
            if as_int
            else mavlink.MAVLink_mission_request_message
        )
        out = rig.send(rig.gcs.frame(cls(1, 1, seq, T_RALLY)))
        (item,) = of_type(out, "MISSION_ITEM_INT" if as_int else "MISSION_ITEM")
        frames.append(item.frame)
    return frames


@pytest.mark.parametrize(
    "personality, frame, int_back, float_back",
    [
        # PX4 mavlink_mission.cpp format_mavlink_mission_item: by altitude reference only.
        ("px4", mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, 6, 3),
        ("px4", mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 6, 3),
        ("px4", mavlink.MAV_FRAME_GLOBAL, 5, 0),
        # ArduPilot MissionItemProtocol_Rally::get_item_as_mission_item: non-int numbers.
        ("ardupilot", mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 3, 3),
        ("ardupilot", mavlink.MAV_FRAME_GLOBAL_INT, 0, 0),
    ],
)
def test_rally_frames_read_back_as_the_firmware_reports_them(
    gcs, personality, frame, int_back, float_back
):
    rig = Rig(gcs, personality)
    assert [a.type for a in rig.upload_rally([(100.0, 0.0)], frame=frame)] == [
        mavlink.MAV_MISSION_ACCEPTED
    ]
    assert rig.core._missions.items[T_RALLY][0].frame == frame  # stored as sent
    assert _read_back(rig, as_int=True) == [int_back]
    assert _read_back(rig, as_int=False) == [float_back]


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_rally_item_in_a_frame_the_firmware_does_not_take_is_refused(gcs, personality):
    """PX4 parse_mavlink_mission_item / ArduPilot convert_MISSION_ITEM_INT_to_RallyLocation:
    a local frame -> MISSION_ACK(UNSUPPORTED_FRAME), nothing stored."""
    rig = Rig(gcs, personality)
    acks_ = rig.upload_rally([(100.0, 0.0)], frame=mavlink.MAV_FRAME_LOCAL_NED)
    assert [a.type for a in acks_] == [mavlink.MAV_MISSION_UNSUPPORTED_FRAME]
    assert rig.core._missions.items[T_RALLY] == []


def test_px4_rally_point_in_frame_6_is_complained_about_and_rtl_stays_put(gcs):
    """PX4 up to main of 2026-03-29: a frame-6 rally point is accepted and stored as 6;
    RTL::on_inactive re-chooses the destination every 2 s and RTL::setSafepointAsDestination
    says "RTL: unsupported MAV_FRAME" (severity 2) each time; RTL::findClosestSafePoint still
    picks the point, whose destination stays unset: the vehicle stays where it is, neither at
    the rally point nor at home."""
    rig = Rig(gcs, "px4")
    acks_ = rig.upload_rally([(100.0, 0.0)], frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
    assert [a.type for a in acks_] == [mavlink.MAV_MISSION_ACCEPTED]
    out_at = (200.0, 20.0, -15.0)
    rig.run(1.0, sp=out_at)
    assert acks(rig.send(gcs.command(176, 1, 6)), 176) == [ACCEPTED]  # OFFBOARD
    assert acks(rig.send(gcs.command(400, 1)), 400) == [ACCEPTED]
    out = rig.run(rig.t + 40.0, sp=out_at)
    texts = [m for m in of_type(out, "STATUSTEXT") if m.text == "RTL: unsupported MAV_FRAME"]
    assert len(texts) >= 15 and {m.severity for m in texts} == {mavlink.MAV_SEVERITY_CRITICAL}
    np.testing.assert_allclose(rig.core.local_pos_ned_m, out_at, atol=1.0)
    out = rig.send(gcs.command(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH))
    assert acks(out, 20) == [ACCEPTED]
    assert [m.text for m in of_type(out, "STATUSTEXT")] == ["RTL: unsupported MAV_FRAME"]
    rig.run(rig.t + 60.0)
    assert rig.core.mode_name == "AUTO.RTL" and rig.core.armed
    np.testing.assert_allclose(rig.core.local_pos_ned_m, out_at, atol=1.0)


@pytest.mark.parametrize("frame", [mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT])
def test_px4_rally_point_in_frame_0_or_3_is_flown_to_without_complaint(gcs, frame):
    rig = Rig(gcs, "px4")
    assert [a.type for a in rig.upload_rally([(100.0, 0.0)], frame=frame)] == [
        mavlink.MAV_MISSION_ACCEPTED
    ]
    out = rig.run(6.0)
    assert not [m for m in of_type(out, "STATUSTEXT") if "MAV_FRAME" in m.text]
    rig.core.physics.pos_ned_m[0] = (200.0, 0.0, -20.0)
    np.testing.assert_allclose(
        rig.core.pers.rtl_destination_ned_m(rig.t)[:2], (100.0, 0.0), atol=0.2
    )

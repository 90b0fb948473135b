"""Out-of-range remote input: coordinates outside the globe, finite but absurd local targets.

Each test names the firmware line it follows (ArduPilot: AP_Math/location.cpp, ArduCopter/
GCS_Mavlink.cpp; PX4: src/modules/mavlink/mavlink_receiver.cpp, src/lib/geo/geo.cpp,
src/modules/navigator/navigator_main.cpp, src/modules/mc_pos_control). In memory, explicit time.
"""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from vehicle_emu.link import VehicleCore, ap_check_latlng_e7, px4_map_project

from emu_helpers import GCS_ADDR, acks, of_type

HOME = (47.5, 8.5, 400.0)
ACCEPTED, DENIED = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
REPOSITION = mavlink.MAV_CMD_DO_REPOSITION
REL_INT = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


class Flying:
    """A vehicle hovering 10 m above home, taking targets from a fake GCS."""

    def __init__(self, gcs, personality):
        self.gcs, self.t = gcs, 0.0
        self.px4 = personality == "px4"
        self.core = VehicleCore(1, personality, origin_lla=HOME)
        # Every stream on, so every telemetry builder sees whatever the target became.
        for msg_id in (85, 87, 32, 33, 24, 1, 30, 74, 245):
            self.core.set_stream_rate(msg_id, 10.0, 0.0)
        if self.px4:
            self.send(gcs.local_target(0, 0, -10))
            assert acks(self.send(gcs.command(176, 1, 6)), 176) == [ACCEPTED]
            assert acks(self.send(gcs.command(400, 1)), 400) == [ACCEPTED]
            self.hold_sp = (0, 0, -10)
        else:
            assert acks(self.send(gcs.command(176, 1, 4)), 176) == [ACCEPTED]
            assert acks(self.send(gcs.command(400, 1)), 400) == [ACCEPTED]
            assert acks(self.send(gcs.command(22, 0, 0, 0, 0, 0, 0, 10.0)), 22) == [ACCEPTED]
            self.hold_sp = None
        self.run(8.0)
        assert self.core.local_pos_ned_m == pytest.approx((0, 0, -10), abs=0.3)

    def send(self, data):
        self.core.receive_datagram(data, GCS_ADDR, self.t)
        return self.gcs.decode(self.core.datagrams_to_send(self.t))

    def run(self, until_s, sp_msg=None):
        """Tick to ``until_s`` with a GCS heartbeat; PX4 gets a 10 Hz setpoint stream (the
        hold setpoint, or ``sp_msg`` when given) so that it stays in OFFBOARD."""
        out = []
        while self.t < until_s - 1e-9:
            self.t = round(self.t + 0.05, 6)
            self.core.receive_datagram(self.gcs.heartbeat(), GCS_ADDR, self.t)
            if sp_msg is not None:
                self.core.receive_datagram(self.gcs.frame(sp_msg), GCS_ADDR, self.t)
            elif self.hold_sp is not None and round(self.t * 20) % 2 == 0:
                self.core.receive_datagram(self.gcs.local_target(*self.hold_sp), GCS_ADDR, self.t)
            self.core.handle_timer(self.t)
            out += self.gcs.decode(self.core.datagrams_to_send(self.t))
        return out

    def reposition(self, lat_e7, lon_e7, alt_m=10.0, frame=None):
        """DO_REPOSITION to ``alt_m`` above home, in the frame the station uses: ArduPilot 6;
        PX4 5 with the AMSL altitude (PX4 reads z as AMSL whatever the frame, gcs/link_commands.py
        send_command_int). ``frame`` given: sent as is."""
        if frame is None and self.px4:
            frame, alt_m = mavlink.MAV_FRAME_GLOBAL_INT, alt_m + self.core.home_lla[2]
        msg = mavlink.MAVLink_command_int_message(
            1, 1, frame or REL_INT, REPOSITION, 0, 0, -1, 1, 0, float("nan"), lat_e7, lon_e7, alt_m
        )
        return acks(self.send(self.gcs.frame(msg)), REPOSITION)


def _global_sp(lat_e7, lon_e7, alt_m=10.0):
    return mavlink.MAVLink_set_position_target_global_int_message(
        0, 1, 1, REL_INT, 3576, lat_e7, lon_e7, alt_m, 0, 0, 0, 0, 0, 0, 0, 0
    )


@pytest.fixture(params=["ardupilot", "px4"])
def flying(request, gcs):
    return Flying(gcs, request.param)


# ---------------------------------------------------------------------------------------------
# Latitude / longitude outside the globe
# ---------------------------------------------------------------------------------------------


def test_ardupilot_check_latlng_bounds_are_inclusive():
    """AP_Math/location.cpp: ``labs(lat) <= 90*1e7``, ``labs(lng) <= 180*1e7``."""
    assert ap_check_latlng_e7(900_000_000, -1_800_000_000)
    assert not ap_check_latlng_e7(900_000_001, 0)
    assert not ap_check_latlng_e7(0, -1_800_000_001)
    assert not ap_check_latlng_e7(-(2**31), 0)


@pytest.mark.parametrize(
    "lat_e7, lon_e7",
    [
        (1_000_000_000, 85_000_000),  # lat 100 deg
        (475_000_000, 1_810_000_000),  # lon 181 deg
        (-(2**31), -(2**31)),
    ],
)
def test_ardupilot_refuses_reposition_and_setpoints_off_the_globe(gcs, lat_e7, lon_e7):
    """ArduCopter/GCS_Mavlink.cpp handle_command_int_do_reposition: ``if (!check_latlng(
    packet.x, packet.y)) return MAV_RESULT_DENIED``; handle_message_set_position_target_global_int:
    ``if (!check_latlng(...)) { copter.mode_guided.init(true); return; }`` (stop and hold)."""
    rig = Flying(gcs, "ardupilot")
    assert rig.reposition(lat_e7, lon_e7) == [DENIED]
    ignored = rig.core.stats.setpoints_ignored
    # first a valid far target so that "hold" is distinguishable from "keep flying"
    lat_ok = int(round((HOME[0] + 200 / 111_200) * 1e7))
    rig.send(rig.gcs.frame(_global_sp(lat_ok, 85_000_000)))
    rig.run(rig.t + 3.0)
    north_before = rig.core.local_pos_ned_m[0]
    assert north_before > 5.0
    rig.send(rig.gcs.frame(_global_sp(lat_e7, lon_e7)))
    assert rig.core.stats.setpoints_ignored == ignored + 1
    rig.run(rig.t + 5.0)
    assert abs(rig.core.local_pos_ned_m[0] - north_before) < 8.0  # braked, not off to 200 m
    assert np.linalg.norm(rig.core.physics.vel_ned_m_s[0]) < 0.2  # and holding
    assert rig.core.stats.handler_errors == 0


def test_px4_projects_an_out_of_range_latitude_as_the_firmware_does(gcs):
    """PX4 does not range-check: mavlink_receiver.cpp handle_message_command_int copies
    ``x / 1e7`` into param5, navigator_main.cpp DO_REPOSITION only checks the geofence (none
    here), commander acks ACCEPTED; the target is then projected by lib/geo
    MapProjection::project, where latitude 100 deg is latitude 80 deg on the far meridian:
    52.5 deg of arc north of home, over the pole."""
    rig = Flying(gcs, "px4")
    assert rig.reposition(1_000_000_000, 85_000_000) == [ACCEPTED]
    assert rig.core.mode_name == "AUTO.LOITER"
    expected_north_m = math.radians(52.5) * 6371000.0
    target = rig.core.physics.target_pos_ned_m[0] - rig.core.home_ned_m
    assert target[0] == pytest.approx(expected_north_m, rel=1e-6)
    assert target[1] == pytest.approx(0.0, abs=1.0)
    assert target[2] == pytest.approx(-10.0, abs=1e-6)  # z = ref_alt - alt: flat frame
    out = rig.run(rig.t + 2.0)
    assert rig.core.local_pos_ned_m[0] > 5.0  # heading north, as PX4 would
    assert rig.core.stats.handler_errors == 0 and of_type(out, "GLOBAL_POSITION_INT")


def test_px4_global_setpoint_off_the_globe_is_projected_too(gcs):
    """The same for SET_POSITION_TARGET_GLOBAL_INT (mavlink_receiver.cpp
    ``global_local_proj_ref.project(lat, lon, ...)``): it is a valid offboard setpoint."""
    # the folding is the firmware's: lat 100 deg IS lat 80 deg on the far meridian for sin/cos
    assert px4_map_project(100.0, 8.5, *HOME[:2]) == pytest.approx(
        px4_map_project(80.0, 8.5 - 180.0, *HOME[:2]), rel=1e-6, abs=1e-3
    )
    rig = Flying(gcs, "px4")
    rig.run(rig.t + 0.5, sp_msg=_global_sp(1_000_000_000, 85_000_000))
    assert rig.core.mode_name == "OFFBOARD"
    target = rig.core.physics.target_pos_ned_m[0] - rig.core.home_ned_m
    assert target[0] == pytest.approx(math.radians(52.5) * 6371000.0, rel=1e-6)
    # back in range: the emulator's ellipsoid geodesy, as before (consistent with telemetry)
    from planner.geometry import ned_to_geodetic

    lat, lon, _ = ned_to_geodetic(np.array([800.0, -600.0, 0.0]), *HOME)
    sp = _global_sp(int(round(float(lat) * 1e7)), int(round(float(lon) * 1e7)))
    rig.run(rig.t + 0.2, sp_msg=sp)
    target = rig.core.physics.target_pos_ned_m[0] - rig.core.home_ned_m
    assert target[:2] == pytest.approx((800.0, -600.0), abs=0.05)


def test_px4_reposition_int32_max_keeps_the_horizontal_target(gcs):
    """mavlink_receiver.cpp handle_message_command_int: ``x == INT32_MAX && y == INT32_MAX``
    means "ignore" (NaN); 0x7ff80000 twice is "NAN was by accident sent as int" -> DENIED."""
    rig = Flying(gcs, "px4")
    before = rig.core.physics.target_pos_ned_m[0].copy()
    assert rig.reposition(2**31 - 1, 2**31 - 1, alt_m=20.0) == [ACCEPTED]
    after = rig.core.physics.target_pos_ned_m[0]
    assert after[:2] == pytest.approx(before[:2], abs=1e-9)
    assert after[2] - rig.core.home_ned_m[2] == pytest.approx(-20.0)
    assert rig.reposition(0x7FF80000, 0x7FF80000) == [DENIED]


@pytest.mark.parametrize(
    "frame", [REL_INT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_MISSION]
)
def test_px4_reads_command_int_z_as_amsl_whatever_the_frame(gcs, frame):
    """mavlink_receiver.cpp handle_message_command_int copies z to param7 without looking at the
    frame; navigator_main.cpp DO_REPOSITION takes param7 as AMSL. A frame-6 "10 m above home"
    is a target 10 m above sea level: 390 m below home here."""
    rig = Flying(gcs, "px4")
    home_amsl = rig.core.home_lla[2]
    assert home_amsl > 100.0  # so that 10 m AMSL is far below home
    assert rig.reposition(*rig.core.pers.home_e7(), alt_m=10.0, frame=frame) == [ACCEPTED]
    target_down = rig.core.physics.target_pos_ned_m[0, 2] - rig.core.home_ned_m[2]
    assert target_down == pytest.approx(home_amsl - 10.0, abs=1e-6)


def test_px4_command_int_in_frame_5_is_above_home_as_meant(gcs):
    rig = Flying(gcs, "px4")
    assert rig.reposition(*rig.core.pers.home_e7(), alt_m=25.0) == [ACCEPTED]
    target_down = rig.core.physics.target_pos_ned_m[0, 2] - rig.core.home_ned_m[2]
    assert target_down == pytest.approx(-25.0, abs=1e-6)


# ---------------------------------------------------------------------------------------------
# Finite but absurd local targets (float32 max is 3.4e38)
# ---------------------------------------------------------------------------------------------

HUGE_TARGETS = [
    (3e38, 0.0, -10.0),
    (3e38, 3e38, -10.0),
    (-3e38, 3e38, -3e38),
    (3.4e38, 0, 0),
    (0.0, 0.0, -3e38),
]


@pytest.mark.parametrize("target", HUGE_TARGETS)
def test_huge_local_target_never_raises(flying, target):
    """No exception from remote input, ever: every stream keeps flowing with finite (float32-
    saturated) values and the vehicle state stays finite."""
    rig = flying
    sp = mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 3576, *target, 0, 0, 0, 0, 0, 0, 0, 0
    )
    out = rig.run(rig.t + 3.0, sp_msg=sp)
    st = rig.core.stats
    assert st.handler_errors == 0 and st.telemetry_errors == 0
    for mtype in (
        "POSITION_TARGET_LOCAL_NED",
        "POSITION_TARGET_GLOBAL_INT",
        "LOCAL_POSITION_NED",
        "GLOBAL_POSITION_INT",
    ):
        assert len(of_type(out, mtype)) >= 25, mtype  # 10 Hz for 3 s
    assert len(of_type(out, "HEARTBEAT")) >= 3  # 1 Hz
    assert np.all(np.isfinite(rig.core.physics.pos_ned_m))
    assert np.all(np.isfinite(rig.core.physics.vel_ned_m_s))


def test_ardupilot_ignores_targets_whose_cm_value_overflows(gcs):
    """ArduCopter/GCS_Mavlink.cpp handle_message_set_position_target_local_ned converts to cm
    in float: ``packet.x * 100.0f`` is inf beyond FLT_MAX / 100; such a setpoint is no usable
    target and the vehicle keeps holding where it is."""
    rig = Flying(gcs, "ardupilot")
    ignored = rig.core.stats.setpoints_ignored
    rig.send(gcs.local_target(3e38, 0, -10))
    assert rig.core.stats.setpoints_ignored == ignored + 1
    rig.run(rig.t + 3.0)
    assert rig.core.local_pos_ned_m == pytest.approx((0, 0, -10), abs=0.3)
    rig.send(gcs.local_target(3e30, 0, -10))  # fits in cm: accepted and flown
    assert rig.core.stats.setpoints_ignored == ignored + 1
    rig.run(rig.t + 2.0)
    assert rig.core.local_pos_ned_m[0] > 3.0


def test_px4_holds_north_east_when_the_float32_error_norm_overflows(gcs):
    """PX4 PositionControl::_positionControl -> ControlMath::constrainXY: an error vector with an
    infinite float32 length is ``normalized() * max`` = 0, no horizontal motion; the vertical
    channel is constrained separately and still flies (here: the 20 m altitude)."""
    rig = Flying(gcs, "px4")
    sp = mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 3576, 3e38, 3e38, -20.0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    rig.run(rig.t + 10.0, sp_msg=sp)
    assert rig.core.mode_name == "OFFBOARD"
    assert rig.core.local_pos_ned_m == pytest.approx((0, 0, -20), abs=0.3)
    # 1e19 m: the float32 squared norm (2e38) is still finite -> PX4 flies towards it
    sp = mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 3576, 1e19, 0.0, -20.0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    rig.run(rig.t + 2.0, sp_msg=sp)
    assert rig.core.local_pos_ned_m[0] > 3.0

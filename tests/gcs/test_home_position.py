"""Home altitude from HOME_POSITION (issue 12 E): asked for, followed, preferred over the
GLOBAL_POSITION_INT estimate by the link (PX4 setpoints) and the fleet view."""

import numpy as np
import pytest
from gcs_fakes import FakeAutopilot, drain, sent
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.events import HomePositionReceived, TelemetryReceived
from gcs.fleet import FleetView, MissionOrigin

A1 = ("10.0.0.1", 14550)
GUIDED = 4
OFFBOARD = 393216
REQ, GET_HOME = mav.MAV_CMD_REQUEST_MESSAGE, mav.MAV_CMD_GET_HOME_POSITION


def _home_requests(link, now_s):
    return [
        m
        for m, _ in sent(link, now_s, "COMMAND_LONG")
        if (m.command == REQ and m.param1 == mav.MAVLINK_MSG_ID_HOME_POSITION)
        or m.command == GET_HOME
    ]


def _tick(link, t0_s, t_end_s, step_s=0.1, ap=None):
    """Run the timer (and the vehicle's 1 Hz heartbeat); return [(t, home request)]."""
    out = []
    t = t0_s
    while t <= t_end_s + 1e-9:
        if ap is not None and abs(t - round(t)) < 1e-6:
            link.receive_datagram(ap.heartbeat(GUIDED), A1, t)
        link.handle_timer(t)
        out += [(t, m) for m in _home_requests(link, t)]
        t = round(t + step_s, 6)
    return out


def test_requested_on_discovery_until_it_arrives(station):
    link = station(
        request_home_position=True,
        stream_rates_hz=(),
        command_timeout_s=0.5,
        command_retries=1,
        home_request_period_s=5.0,
    )
    ap = FakeAutopilot(sysid=1)
    link.receive_datagram(ap.heartbeat(GUIDED), A1, 0.0)
    (first,) = _home_requests(link, 0.0)
    assert first.command == REQ and first.target_system == 1
    link.receive_datagram(ap.ack(REQ), A1, 0.05)  # accepted, but no home yet (no GPS fix)
    later = _tick(link, 0.1, 11.9, ap=ap)
    # Asked again 5 s after the ACK (re-sent once without an ACK), then 5 s after that gave up.
    assert [round(t, 1) for t, _ in later] == [5.1, 5.6, 11.1, 11.6]
    assert [m.param2 for _, m in later] == [0, 0, 0, 0]
    link.receive_datagram(ap.home_position(47.5, 8.25, 432.1), A1, 12.0)
    (ev,) = [e for e in drain(link) if isinstance(e, HomePositionReceived)]
    assert (ev.lat_deg, ev.lon_deg, ev.alt_amsl_m) == (47.5, 8.25, 432.1)
    assert link.vehicle(1).home_alt_amsl_m == 432.1
    assert _tick(link, 12.0, 30.0, ap=ap) == []  # known: no more requests
    # The same home again (PX4 streams it) is no news; a new one is.
    link.receive_datagram(ap.home_position(47.5, 8.25, 432.1), A1, 31.0)
    assert drain(link) == []
    link.receive_datagram(ap.home_position(47.5, 8.25, 433.0), A1, 32.0)
    assert [e.alt_amsl_m for e in drain(link)] == [433.0]


def test_unsupported_request_message_falls_back_to_get_home_position(station):
    link = station(request_home_position=True, stream_rates_hz=(), home_request_period_s=2.0)
    ap = FakeAutopilot(sysid=1)
    link.receive_datagram(ap.heartbeat(GUIDED), A1, 0.0)
    assert [m.command for m in _home_requests(link, 0.0)] == [REQ]
    link.receive_datagram(ap.ack(REQ, mav.MAV_RESULT_UNSUPPORTED), A1, 0.1)
    assert [m.command for _, m in _tick(link, 0.1, 2.2)] == [GET_HOME]


def test_arming_asks_again(station):
    link = station(request_home_position=True, stream_rates_hz=())
    ap = FakeAutopilot(sysid=1)
    link.receive_datagram(ap.heartbeat(GUIDED), A1, 0.0)
    sent(link, 0.0)
    link.receive_datagram(ap.ack(REQ) + ap.home_position(47.5, 8.25, 432.1), A1, 0.1)
    link.receive_datagram(ap.heartbeat(GUIDED, armed=True), A1, 1.0)
    assert len(_home_requests(link, 1.0)) == 1


def test_px4_setpoint_altitude_uses_home_position(station):
    link = station(request_home_position=True, stream_rates_hz=())
    ap = FakeAutopilot(sysid=1, autopilot=mav.MAV_AUTOPILOT_PX4)
    link.receive_datagram(ap.heartbeat(OFFBOARD), A1, 0.0)
    # Before HOME_POSITION: the estimate alt - relative_alt (here 500 - 20 = 480).
    link.receive_datagram(ap.global_position(47.5, 8.25, 500.0, 20.0), A1, 0.1)
    sent(link, 0.1)
    link.set_position_target(1, 47.5, 8.25, 10.0, 0.2)
    ((sp, _),) = sent(link, 0.2, "SET_POSITION_TARGET_GLOBAL_INT")
    assert sp.coordinate_frame == mav.MAV_FRAME_GLOBAL_INT and sp.alt == pytest.approx(490.0)
    link.receive_datagram(ap.home_position(47.5, 8.25, 478.0), A1, 0.3)
    # In flight PX4's alt - relative_alt wanders; home does not, nor do the targets.
    link.receive_datagram(ap.global_position(47.5, 8.25, 502.5, 20.0), A1, 0.4)
    link.set_position_target(1, 47.5, 8.25, 10.0, 0.5)
    ((sp, _),) = sent(link, 0.5, "SET_POSITION_TARGET_GLOBAL_INT")
    assert sp.alt == pytest.approx(488.0)


def test_px4_command_int_goes_in_frame_5_with_the_amsl_altitude(station):
    """PX4 reads COMMAND_INT z as AMSL whatever the frame (mavlink_receiver.cpp
    handle_message_command_int; main of 2026-02-25 to 2026-03-03 even refused frames but 5): a
    frame-6 request leaves as frame 5, home + alt; ArduPilot gets the frame as asked."""
    from gcs.link import LinkUsageError

    link = station(request_home_position=True, stream_rates_hz=())
    px4 = FakeAutopilot(sysid=1, autopilot=mav.MAV_AUTOPILOT_PX4)
    ardu = FakeAutopilot(sysid=2, autopilot=mav.MAV_AUTOPILOT_ARDUPILOTMEGA)
    link.receive_datagram(px4.heartbeat(OFFBOARD), A1, 0.0)
    link.receive_datagram(ardu.heartbeat(GUIDED), A1, 0.0)
    link.receive_datagram(px4.home_position(47.5, 8.25, 478.0), A1, 0.1)
    sent(link, 0.1)
    rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    for sysid in (1, 2):
        link.send_command_int(
            sysid,
            mav.MAV_CMD_DO_REPOSITION,
            frame=rel,
            params=(-1, 1, 0, float("nan")),
            lat_deg=47.501,
            lon_deg=8.25,
            alt_m=20.0,
            now_s=0.2,
        )
    cmds = {m.target_system: m for m, _ in sent(link, 0.2, "COMMAND_INT")}
    assert (cmds[1].frame, cmds[1].z) == (mav.MAV_FRAME_GLOBAL_INT, pytest.approx(498.0))
    assert (cmds[2].frame, cmds[2].z) == (rel, pytest.approx(20.0))
    assert cmds[1].x == cmds[2].x == 475010000
    # (another command id: one DO_REPOSITION per vehicle is in flight until it is acked)
    link.send_command_int(
        1, mav.MAV_CMD_DO_SET_ROI_LOCATION, frame=mav.MAV_FRAME_GLOBAL, alt_m=500.0, now_s=0.3
    )
    ((m, _),) = sent(link, 0.3, "COMMAND_INT")
    assert (m.frame, m.z) == (mav.MAV_FRAME_GLOBAL_INT, pytest.approx(500.0))
    with pytest.raises(LinkUsageError):
        link.send_command_int(
            1, mav.MAV_CMD_DO_REPOSITION, frame=mav.MAV_FRAME_LOCAL_NED, now_s=0.4
        )


def test_fleet_view_prefers_home_position_and_never_drifts_once_known():
    fleet = FleetView(MissionOrigin(47.5, 8.25, 400.0))

    def tel(t, alt, rel):
        return TelemetryReceived(0, 1, t, lat_deg=47.5, lon_deg=8.25, alt_amsl_m=alt, rel_alt_m=rel)

    fleet.apply(tel(0.0, 500.0, 20.0))
    snap = fleet.snapshot(0.0)
    assert snap.home_amsl_m[0] == 480.0 and not snap.home_reported[0]  # the estimate
    fleet.apply(HomePositionReceived(0, 1, 0.5, lat_deg=47.5, lon_deg=8.25, alt_amsl_m=478.0))
    for t, alt in ((1.0, 502.5), (1.5, 497.5), (2.0, 501.0)):
        fleet.apply(tel(t, alt, 20.0))
        snap = fleet.snapshot(t)
        assert snap.home_amsl_m[0] == 478.0 and snap.home_reported[0]
    _, _, rel = fleet.targets_to_global([0], np.array([[0.0, 0.0, -100.0]]))
    assert rel[0] == pytest.approx(400.0 + 100.0 - 478.0)

"""The station core: bytes and now_s in, bytes and events out. No sockets, no sleeps."""

import math

import pytest
from gcs_fakes import FakeAutopilot, drain, sent
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.events import (
    ArmedChanged,
    CommandAcked,
    CommandFailed,
    CommandInProgress,
    CommandTimedOut,
    ModeChanged,
    ParamReceived,
    ParamTimedOut,
    StatusText,
    TelemetryReceived,
    VehicleDiscovered,
    VehicleLost,
    VehicleRecovered,
)
from gcs.link import LinkUsageError, StationConfig, StationLink, UnknownVehicle

A1, A2 = ("10.0.0.1", 14550), ("10.0.0.2", 14550)
GUIDED = 4


def run_until(link: StationLink, t_end_s: float) -> list:
    """Drive the timer exactly as an adapter would; return [(t, msg, addr)] sent on the way."""
    out = []
    while (t := link.next_timer_s()) is not None and t <= t_end_s:
        link.handle_timer(t)
        out += [(t, m, a) for m, a in sent(link, t)]
    return out


def discovered(station, fake_ap: FakeAutopilot, addr=A1, now_s=0.0, **cfg) -> StationLink:
    link = station(**cfg)
    link.receive_datagram(fake_ap.heartbeat(GUIDED), addr, now_s)
    return link


def commands(frames, command):
    return [(t, m) for t, m, _ in frames if m.get_type() == "COMMAND_LONG" and m.command == command]


# ---------------------------------------------------------------------------- heartbeat


def test_heartbeat_every_second_from_the_timer(station):
    link = station(static_peers=(A1,))
    assert link.next_timer_s() == 0.0
    frames = run_until(link, 3.5)
    hb = [(t, m, a) for t, m, a in frames if m.get_type() == "HEARTBEAT"]
    assert [t for t, _, _ in hb] == [0.0, 1.0, 2.0, 3.0]
    m = hb[0][1]
    assert (m.type, m.autopilot) == (mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID)
    assert (m.get_srcSystem(), m.get_srcComponent()) == (255, mav.MAV_COMP_ID_MISSIONPLANNER)
    assert all(a == A1 for _, _, a in hb)


def test_late_timer_does_not_burst(station):
    link = station(static_peers=(A1,))
    link.handle_timer(0.0)
    sent(link, 0.0)
    link.handle_timer(10.3)  # the loop stalled for 10 s
    assert len(sent(link, 10.3, "HEARTBEAT")) == 1
    assert link.next_timer_s() == pytest.approx(11.3)


# ---------------------------------------------------------------------------- discovery


def test_discovery_only_from_autopilot_heartbeats(station):
    link = station()
    other_gcs = FakeAutopilot(
        sysid=250, compid=190, vehicle_type=mav.MAV_TYPE_GCS, autopilot=mav.MAV_AUTOPILOT_INVALID
    )
    gimbal = FakeAutopilot(sysid=1, compid=mav.MAV_COMP_ID_GIMBAL, vehicle_type=mav.MAV_TYPE_GIMBAL)
    companion = FakeAutopilot(sysid=1, compid=1, vehicle_type=mav.MAV_TYPE_ONBOARD_CONTROLLER)
    for i, f in enumerate((other_gcs, gimbal, companion)):
        link.receive_datagram(f.heartbeat(), A1, float(i))
    assert drain(link) == [] and link.vehicles() == []
    assert link.stats.non_vehicle_heartbeats == 3

    ap = FakeAutopilot(sysid=1)
    link.receive_datagram(ap.heartbeat(GUIDED, armed=True), A1, 5.0)
    (ev,) = drain(link)
    assert isinstance(ev, VehicleDiscovered)
    assert (ev.link_id, ev.sysid, ev.autopilot, ev.mode, ev.armed) == (0, 1, 3, "GUIDED", True)
    out = sent(link, 5.0)
    # One GCS heartbeat at once to the new vehicle, then the stream requests, all to its address.
    assert out[0][0].get_type() == "HEARTBEAT" and all(a == A1 for _, a in out)
    intervals = [m for m, _ in out if m.get_type() == "COMMAND_LONG"]
    assert intervals and intervals[0].command == mav.MAV_CMD_SET_MESSAGE_INTERVAL
    assert intervals[0].param1 == mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    assert intervals[0].param2 == 250000  # 4 Hz


def test_messages_from_undiscovered_or_own_sysid_are_counted_and_dropped(station):
    link = station()
    stranger = FakeAutopilot(sysid=9)
    link.receive_datagram(stranger.global_position(47, 8, 500, 10), A1, 0.0)
    twin = FakeAutopilot(sysid=255)
    link.receive_datagram(twin.heartbeat(), A1, 0.0)
    assert drain(link) == []
    assert link.stats.from_unknown_sysid == 1 and link.stats.own_sysid == 1


def test_targeted_messages_go_only_to_that_vehicle(station):
    link = station()
    v1, v2 = FakeAutopilot(sysid=1), FakeAutopilot(sysid=2)
    link.receive_datagram(v1.heartbeat(GUIDED), A1, 0.0)
    link.receive_datagram(v2.heartbeat(GUIDED), A2, 0.0)
    sent(link, 0.0)
    link.arm(2, 0.1)
    link.set_position_target(1, 47.0, 8.0, 20.0, 0.1)
    out = sent(link, 0.1)
    arm = [a for m, a in out if m.get_type() == "COMMAND_LONG"]
    sp = [a for m, a in out if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]
    assert arm == [A2] and sp == [A1]
    # A broadcast (our heartbeat) goes to every peer.
    link.handle_timer(1.0)
    assert sorted(a for _, a in sent(link, 1.0, "HEARTBEAT")) == [A1, A2]


def test_unknown_sysid_is_a_local_error(station):
    link = station()
    with pytest.raises(UnknownVehicle):
        link.arm(7, 0.0)


# ---------------------------------------------------------------------------- loss


def test_lost_within_timeout_plus_one_tick_then_recovered(station):
    ap = FakeAutopilot(sysid=3)
    link = station(static_peers=(A1,))
    tick_s = 0.1
    t, lost_at = 0.0, None
    while t < 12.0:
        if t <= 3.0 + 1e-9 and abs(t - round(t)) < 1e-9:
            link.receive_datagram(ap.heartbeat(GUIDED), A1, t)  # heartbeats at 0..3 s
        if (due := link.next_timer_s()) is not None and due <= t:
            link.handle_timer(t)
        link.datagrams_to_send(t)
        for ev in drain(link):
            if isinstance(ev, VehicleLost):
                lost_at = ev.t_s
                assert ev.last_heartbeat_s == pytest.approx(3.0)
        if lost_at is not None:
            break
        t = round(t + tick_s, 10)
    assert lost_at is not None and 3.0 + 5.0 <= lost_at <= 3.0 + 5.0 + tick_s
    assert link.vehicle(3).lost and link.networked_sysids() == []

    link.receive_datagram(ap.heartbeat(6, armed=True), A2, 20.0)  # back, in RTL, new address
    evs = drain(link)
    assert [type(e) for e in evs] == [VehicleRecovered, ModeChanged, ArmedChanged]
    assert evs[0].silent_s == pytest.approx(17.0) and evs[1].mode == "RTL"
    assert link.address_of(3) == A2 and link.networked_sysids() == [3]
    out = sent(link, 20.0)
    assert out[0][0].get_type() == "HEARTBEAT" and {a for _, a in out} == {A2}


# ---------------------------------------------------------------------------- commands


def test_command_retried_then_timed_out_with_confirmation_incremented(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap, stream_rates_hz=())
    sent(link, 0.0)
    rid = link.arm(1, 0.0)
    frames = [(0.0, m, a) for m, a in sent(link, 0.0)] + run_until(link, 3.0)
    arms = commands(frames, mav.MAV_CMD_COMPONENT_ARM_DISARM)
    assert [t for t, _ in arms] == pytest.approx([0.0, 0.5, 1.0, 1.5])
    assert [m.confirmation for _, m in arms] == [0, 1, 2, 3]
    assert all(m.param1 == 1 and m.param2 == 0 for _, m in arms)  # never forced (21196)
    timed_out = [e for e in drain(link) if isinstance(e, CommandTimedOut)]
    assert len(timed_out) == 1
    ev = timed_out[0]
    assert (ev.command, ev.request_id, ev.attempts, ev.t_s) == (400, rid, 4, pytest.approx(2.0))


def test_ack_stops_retries(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap, stream_rates_hz=())
    rid = link.set_mode(1, "GUIDED", 0.0)
    ((m, _),) = sent(link, 0.0, "COMMAND_LONG")
    assert (m.command, m.param1, m.param2) == (mav.MAV_CMD_DO_SET_MODE, 1, 4)
    link.handle_timer(0.5)  # one retry
    assert len(sent(link, 0.5, "COMMAND_LONG")) == 1
    link.receive_datagram(ap.ack(mav.MAV_CMD_DO_SET_MODE), A1, 0.7)
    evs = [e for e in drain(link) if not isinstance(e, VehicleDiscovered)]
    assert evs == [CommandAcked(0, 1, 0.7, mav.MAV_CMD_DO_SET_MODE, rid, 2)]
    assert not commands(run_until(link, 5.0), mav.MAV_CMD_DO_SET_MODE)


def test_withdrawn_flight_commands_are_never_sent_again(station):
    """A forwarded client took the vehicle (gcs.forward): our pending GUIDED, queued and
    in-flight, must not reach it after the client's mode change."""
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap, stream_rates_hz=())
    rid1 = link.set_mode(1, "GUIDED", 0.0)
    rid2 = link.set_mode(1, "GUIDED", 0.1)  # queued behind the first (one per command id)
    rid3 = link.arm(1, 0.1)
    sent(link, 0.1)
    assert link.withdraw_flight_commands(1, 0.2, "withdrawn: taken") == 3
    evs = [e for e in drain(link) if isinstance(e, CommandFailed)]
    assert sorted(e.request_id for e in evs) == sorted([rid1, rid2, rid3])
    assert all(e.reason == "withdrawn: taken" and e.result is None for e in evs)
    frames = run_until(link, 5.0)
    assert not commands(frames, mav.MAV_CMD_DO_SET_MODE)
    assert not commands(frames, mav.MAV_CMD_COMPONENT_ARM_DISARM)
    assert not [e for e in drain(link) if isinstance(e, (CommandFailed, CommandTimedOut))]
    # The link still commands it when asked again (an operator's rejoin).
    link.set_mode(1, "GUIDED", 5.0)
    assert len(sent(link, 5.0, "COMMAND_LONG")) == 1


def test_in_progress_keeps_waiting_without_resending(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap, stream_rates_hz=())
    rid = link.takeoff(1, 10.0, 0.0)
    ((m, _),) = sent(link, 0.0, "COMMAND_LONG")
    assert (m.command, m.param7) == (mav.MAV_CMD_NAV_TAKEOFF, 10.0)
    link.receive_datagram(ap.ack(mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_RESULT_IN_PROGRESS, 40), A1, 0.2)
    assert not commands(run_until(link, 4.0), mav.MAV_CMD_NAV_TAKEOFF)
    link.receive_datagram(ap.ack(mav.MAV_CMD_NAV_TAKEOFF), A1, 4.0)
    evs = [e for e in drain(link) if not isinstance(e, VehicleDiscovered)]
    assert [type(e) for e in evs] == [CommandInProgress, CommandAcked]
    assert evs[0].progress == 40 and evs[1].request_id == rid


def test_denied_command_fails_and_ack_for_another_station_is_ignored(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap, stream_rates_hz=())
    link.arm(1, 0.0)
    link.receive_datagram(ap.ack(400, mav.MAV_RESULT_ACCEPTED, target_system=254), A1, 0.1)
    link.receive_datagram(ap.ack(400, mav.MAV_RESULT_DENIED), A1, 0.2)
    evs = [e for e in drain(link) if not isinstance(e, VehicleDiscovered)]
    assert len(evs) == 1 and isinstance(evs[0], CommandFailed)
    assert (evs[0].result, evs[0].reason) == (mav.MAV_RESULT_DENIED, "MAV_RESULT_DENIED")


def test_same_command_is_queued_behind_the_one_in_flight(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap, stream_rates_hz=())
    link.set_mode(1, "GUIDED", 0.0)
    link.set_mode(1, "RTL", 0.0)
    assert [m.param2 for m, _ in sent(link, 0.0, "COMMAND_LONG")] == [4]
    link.receive_datagram(ap.ack(mav.MAV_CMD_DO_SET_MODE), A1, 0.1)
    assert [m.param2 for m, _ in sent(link, 0.1, "COMMAND_LONG")] == [6]


# ---------------------------------------------------------------------------- streams


def test_set_message_interval_unsupported_falls_back_to_request_data_stream(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap)
    ((first, _),) = sent(link, 0.0, "COMMAND_LONG")  # one SET_MESSAGE_INTERVAL in flight
    assert first.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL
    link.receive_datagram(
        ap.ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_UNSUPPORTED), A1, 0.1
    )
    out = sent(link, 0.1)
    streams = {m.req_stream_id: m for m, _ in out if m.get_type() == "REQUEST_DATA_STREAM"}
    assert set(streams) == {mav.MAV_DATA_STREAM_POSITION, mav.MAV_DATA_STREAM_EXTENDED_STATUS}
    assert streams[mav.MAV_DATA_STREAM_POSITION].req_message_rate == 4
    assert all(m.start_stop == 1 and m.target_system == 1 for m in streams.values())
    assert not [m for m, _ in out if m.get_type() == "COMMAND_LONG"]  # queue dropped
    assert drain(link)[1:] == []  # internal: no command events for the stream machinery
    assert link.stats.data_stream_fallbacks == 1


def test_set_message_interval_accepted_in_turn_then_timeout_falls_back(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap)
    ((m, _),) = sent(link, 0.0, "COMMAND_LONG")
    link.receive_datagram(ap.ack(511), A1, 0.05)
    ((m2, _),) = sent(link, 0.05, "COMMAND_LONG")
    assert m2.command == 511 and m2.param1 == mav.MAVLINK_MSG_ID_SYS_STATUS
    frames = run_until(link, 2.2)  # no more ACKs: 4 attempts, then fall back
    assert len(commands(frames, 511)) == 3
    assert [m for _, m, _ in frames if m.get_type() == "REQUEST_DATA_STREAM"]


def test_stale_telemetry_is_re_requested(station):
    ap = FakeAutopilot(sysid=1)
    link = station(static_peers=(A1,))
    t = 0.0
    re_requests = []
    while t <= 12.0:
        if abs(t - round(t)) < 1e-9:
            link.receive_datagram(ap.heartbeat(GUIDED), A1, t)
            if t < 4:  # telemetry stops after 3 s while heartbeats go on
                link.receive_datagram(ap.global_position(47, 8, 500, 10), A1, t)
        while (due := link.next_timer_s()) is not None and due <= t:
            link.handle_timer(due)
        for _ in range(10):  # the vehicle ACKs every SET_MESSAGE_INTERVAL at once
            cmds = sent(link, t, "COMMAND_LONG")
            if not cmds:
                break
            for m, _ in cmds:
                if m.command == 511 and m.param1 == mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
                    re_requests.append(t)
                link.receive_datagram(ap.ack(m.command), A1, t)
        t = round(t + 0.1, 10)
    assert re_requests[0] == 0.0 and link.stats.data_stream_fallbacks == 0
    re_requests = re_requests[1:]
    assert re_requests and 6.0 <= re_requests[0] <= 6.2  # 3 s after the last position (3.0)
    assert link.stats.stream_rerequests >= 1


# ---------------------------------------------------------------------------- telemetry etc.


def test_a_report_no_event_accepts_is_counted_not_emitted(station):
    """The codec-edge converters (health, SYS_STATUS's battery) go through one door: a
    ValueError is invalid telemetry (counted), anything else an event."""
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap, stream_rates_hz=())
    drain(link)
    v, before = link._get(1), link.stats.invalid_telemetry

    def refused(link_id, sysid, t_s, msg):
        raise ValueError("no event accepts it")

    link._emit_converted(refused, v, "x", 2.0)
    assert drain(link) == [] and link.stats.invalid_telemetry == before + 1
    link._emit_converted(lambda li, s, t, m: StatusText(li, s, t, 6, m), v, "hi", 2.5)
    assert drain(link) == [StatusText(0, 1, 2.5, 6, "hi")]
    assert link.stats.invalid_telemetry == before + 1


def test_telemetry_params_and_statustext_become_events(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap, stream_rates_hz=())
    drain(link)
    link.receive_datagram(
        ap.global_position(47.5, 8.25, 512.34, 12.34, (1.5, -2.0, 0.25), 9000), A1, 1.0
    )
    link.receive_datagram(ap.statustext("EKF3 IMU0 is using GPS"), A1, 1.0)
    tel, txt = drain(link)
    assert isinstance(tel, TelemetryReceived)
    assert (tel.lat_deg, tel.lon_deg, tel.alt_amsl_m, tel.rel_alt_m) == (47.5, 8.25, 512.34, 12.34)
    assert tel.vel_ned_m_s == (1.5, -2.0, 0.25) and tel.yaw_rad == pytest.approx(math.pi / 2)
    assert txt == StatusText(0, 1, 1.0, mav.MAV_SEVERITY_INFO, "EKF3 IMU0 is using GPS")
    link.receive_datagram(ap.global_position(0, 0, 0, 0), A1, 1.1)  # no fix yet
    assert drain(link) == [] and link.stats.invalid_telemetry == 1

    link.request_param(1, "FS_GCS_ENABLE", 2.0)
    ((m, a),) = sent(link, 2.0, "PARAM_REQUEST_READ")
    assert (m.param_id, m.param_index, m.target_system, a) == ("FS_GCS_ENABLE", -1, 1, A1)
    link.handle_timer(3.0)
    assert len(sent(link, 3.0, "PARAM_REQUEST_READ")) == 1  # retried
    link.receive_datagram(ap.param_value("FS_GCS_ENABLE", 1.0), A1, 3.2)
    assert drain(link) == [
        ParamReceived(0, 1, 3.2, "FS_GCS_ENABLE", 1.0, mav.MAV_PARAM_TYPE_REAL32)
    ]
    link.request_param(1, "GUID_TIMEOUT", 4.0)
    run_until(link, 10.0)
    assert [e for e in drain(link) if isinstance(e, ParamTimedOut)] == [
        ParamTimedOut(0, 1, 8.0, "GUID_TIMEOUT", 4)
    ]


def test_px4_integer_params_are_bytewise(station):
    import struct

    ap = FakeAutopilot(sysid=1, autopilot=mav.MAV_AUTOPILOT_PX4)
    link = discovered(station, ap, stream_rates_hz=())
    drain(link)
    as_float = struct.unpack("<f", struct.pack("<i", 2))[0]
    link.receive_datagram(ap.param_value("NAV_DLL_ACT", as_float, mav.MAV_PARAM_TYPE_INT32), A1, 1)
    (ev,) = drain(link)
    assert ev.value == 2.0


# ---------------------------------------------------------------------------- autopilots


def test_px4_offboard_and_arm_only_after_prestreaming_setpoints(station):
    ap = FakeAutopilot(sysid=1, autopilot=mav.MAV_AUTOPILOT_PX4)
    link = station(stream_rates_hz=())
    link.receive_datagram(ap.heartbeat(3 << 16), A1, 0.0)  # POSCTL
    assert drain(link)[0].mode == "POSCTL"
    with pytest.raises(LinkUsageError):
        link.set_mode(1, "OFFBOARD", 0.0)  # no setpoint stream yet
    # Home 3 m below the vehicle (alt - relative_alt = 497 m AMSL).
    link.receive_datagram(ap.global_position(47.0, 8.0, 500.0, 3.0), A1, 0.0)
    link.takeoff(1, 15.0, 0.0)  # PX4: climb in offboard
    frames = [(0.0, m, a) for m, a in sent(link, 0.0)] + run_until(link, 2.0)
    sp_times = [t for t, m, _ in frames if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]
    mode_cmds = commands(frames, mav.MAV_CMD_DO_SET_MODE)
    arm_cmds = commands(frames, mav.MAV_CMD_COMPONENT_ARM_DISARM)
    assert mode_cmds and arm_cmds
    t_mode, m = mode_cmds[0]
    assert (m.param1, m.param2, m.param3) == (1, 6, 0)  # unpacked main/sub, not 393216
    assert t_mode > 1.0 and arm_cmds[0][0] > 1.0
    before = [t for t in sp_times if t < t_mode]
    assert len(before) >= 10 and max(b - a for a, b in zip(before, before[1:])) <= 0.1 + 1e-9
    sp = [m for _, m, _ in frames if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"][0]
    # PX4: GLOBAL_INT (AMSL) = home + 15 m (its frame-6 conversion is off when home != origin).
    assert (sp.coordinate_frame, sp.type_mask, sp.alt) == (5, 3576, 497.0 + 15.0)
    assert (sp.lat_int, sp.lon_int) == (470000000, 80000000)


def test_px4_rtl_is_unpacked_and_modes_decode(station):
    ap = FakeAutopilot(sysid=1, autopilot=mav.MAV_AUTOPILOT_PX4)
    link = station(stream_rates_hz=())
    link.receive_datagram(ap.heartbeat(393216, armed=True), A1, 0.0)
    assert link.vehicle(1).mode == "OFFBOARD"
    link.rtl(1, 0.0)
    ((m, _),) = sent(link, 0.0, "COMMAND_LONG")
    assert (m.command, m.param1, m.param2, m.param3) == (176, 1, 4, 5)
    link.receive_datagram(ap.heartbeat(84148224, armed=True), A1, 1.0)
    assert [e.mode for e in drain(link) if isinstance(e, ModeChanged)] == ["AUTO.RTL"]


def test_ardupilot_setpoints_resent_every_second_even_if_unchanged(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap, stream_rates_hz=())
    link.set_position_target(1, 47.0, 8.0, 30.0, 0.0)
    frames = [(0.0, m, a) for m, a in sent(link, 0.0)] + run_until(link, 3.5)
    sp = [(t, m) for t, m, _ in frames if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"]
    assert [t for t, _ in sp] == [0.0, 1.0, 2.0, 3.0]
    assert all((m.coordinate_frame, m.type_mask, m.alt) == (6, 3576, 30.0) for _, m in sp)
    link.clear_position_target(1, 3.5)
    assert not [f for f in run_until(link, 6.0) if f[1].get_type().startswith("SET_POSITION")]


# ---------------------------------------------------------------------------- robustness


@given(st.lists(st.binary(max_size=300), max_size=8))
def test_arbitrary_bytes_never_raise_and_only_bump_counters(chunks):
    link = StationLink(StationConfig(datagram=True))
    for i, data in enumerate(chunks):
        link.receive_datagram(data, A1, float(i))
    assert link.next_event() is None
    assert link.vehicles() == []
    d = link.stats.decode
    assert d.bytes_in == sum(map(len, chunks))


def test_garbage_around_frames_three_ways(station):
    ap = FakeAutopilot(sysid=1)
    hb, pos = ap.heartbeat(GUIDED), ap.global_position(47, 8, 500, 10)

    def events_for(datagrams):
        link = station(stream_rates_hz=())
        for d in datagrams:
            link.receive_datagram(d, A1, 0.0)
        return [type(e) for e in drain(link)], link.stats.decode

    one, s1 = events_for([hb, pos])
    both, s2 = events_for([hb + pos])
    noisy, s3 = events_for([b"\x00\x01junk" + hb + b"\xff" * 3, pos + pos[:7]])
    assert one == both == noisy == [VehicleDiscovered, TelemetryReceived]
    assert s1.bad_data == s2.bad_data == 0
    assert s3.bad_data >= 2 and s3.truncated == 1


def test_signing_signs_outgoing_frames(station):
    key = bytes(range(32))
    link = station(signing_key=key, static_peers=(A1,), unix_time_at_zero_s=1.7e9)
    link.handle_timer(0.0)
    ((data, _),) = link.datagrams_to_send(0.0)
    assert data[0] == 0xFD and data[2] & mav.MAVLINK_IFLAG_SIGNED
    ap = FakeAutopilot(sysid=1, signing_key=key)
    ap.parser.signing.timestamp = int((1.7e9 - 1420070400) * 1e5)
    (m,) = ap.decode(data)
    assert m.get_type() == "HEARTBEAT" and m._signed
    with pytest.raises(ValueError):
        StationConfig(sysid=0)


def test_one_refused_message_interval_does_not_force_the_fallback(station):
    ap = FakeAutopilot(sysid=1)
    link = discovered(station, ap)
    for result in (
        mav.MAV_RESULT_ACCEPTED,
        mav.MAV_RESULT_FAILED,
        mav.MAV_RESULT_ACCEPTED,
        mav.MAV_RESULT_ACCEPTED,
    ):
        ((m, _),) = sent(link, 0.0, "COMMAND_LONG")
        link.receive_datagram(ap.ack(511, result), A1, 0.0)
    assert link.stats.data_stream_fallbacks == 0 and sent(link, 0.0) == []

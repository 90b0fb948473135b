"""Keeping real time under load (issue 12 D1, D2): the station turns off the messages it does not
use, and does not unpack them while they still come."""

import pytest
from gcs_fakes import FakeAutopilot, drain, sent
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs import wire
from gcs.link import StationConfig, StationLink

A1 = ("10.0.0.1", 14550)
PX4 = mav.MAV_AUTOPILOT_PX4
OFFBOARD = 393216
SMI = mav.MAV_CMD_SET_MESSAGE_INTERVAL
ATT, LPOS = mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED
GPI, SYS = mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mav.MAVLINK_MSG_ID_SYS_STATUS


def _stops(link, now_s):
    return [
        int(m.param1)
        for m, _ in sent(link, now_s, "COMMAND_LONG")
        if m.command == SMI and m.param2 == -1
    ]


def _px4(station, **cfg):
    cfg.setdefault("stream_rates_hz", ((GPI, 2.0),))
    link = station(**cfg)
    ap = FakeAutopilot(sysid=1, autopilot=PX4)
    link.receive_datagram(ap.heartbeat(OFFBOARD), A1, 0.0)
    out = sent(link, 0.0, "COMMAND_LONG")
    assert [(m.command, m.param1) for m, _ in out] == [(SMI, GPI)]  # what we use, at our rate
    link.receive_datagram(ap.ack(SMI), A1, 0.01)
    return link, ap


def _sys_status(ap):
    return ap.pack(mav.MAVLink_sys_status_message(0, 0, 0, 500, 12000, -1, 80, 0, 0, 0, 0, 0, 0))


def test_unused_messages_are_stopped_one_at_a_time(station):
    link, ap = _px4(station)
    link.receive_datagram(ap.attitude() + ap.local_position(), A1, 0.1)
    assert _stops(link, 0.1) == [ATT]  # one in flight: an ACK names only the command id
    link.receive_datagram(ap.attitude() + ap.local_position(), A1, 0.15)  # already asked
    assert _stops(link, 0.15) == []
    link.receive_datagram(ap.ack(SMI), A1, 0.2)
    assert _stops(link, 0.2) == [LPOS]
    link.receive_datagram(ap.ack(SMI), A1, 0.3)
    assert (link.stats.disable_requests, link.stats.messages_disabled) == (2, 2)
    # What the station reads, or its protocols need, is never stopped.
    never = [
        ap.heartbeat(OFFBOARD),
        ap.global_position(47, 8, 500, 10),
        ap.statustext("hi"),
        ap.home_position(47, 8, 490),
        ap.ack(400),
        ap.param_value("X", 1.0),
        ap.pack(
            mav.MAVLink_autopilot_version_message(
                0, 0, 0, 0, 0, b"\0" * 8, b"\0" * 8, b"\0" * 8, 0, 0, 0
            )
        ),
        ap.pack(mav.MAVLink_timesync_message(0, 1)),
    ]
    for i, frame in enumerate(never):
        link.receive_datagram(frame, A1, 0.4 + i * 0.01)
    link.handle_timer(0.5)
    assert _stops(link, 0.5) == [] and link.stats.disable_requests == 2
    assert link.stats.handler_errors == 0


def test_requested_streams_are_kept(station):
    link, ap = _px4(station, stream_rates_hz=((GPI, 2.0), (SYS, 0.2)))
    link.receive_datagram(ap.ack(SMI), A1, 0.02)
    link.receive_datagram(_sys_status(ap), A1, 0.1)
    assert _stops(link, 0.1) == []


def test_still_coming_is_asked_again_up_to_the_cap_and_refusals_are_final(station):
    link, ap = _px4(station, disable_retry_s=10.0, disable_attempts=2, command_timeout_s=0.5)
    asked = []
    t = 0.1
    while t < 40.0:  # the vehicle ACKs but keeps streaming ATTITUDE at 10 Hz
        if abs(t - round(t)) < 1e-6:
            link.receive_datagram(ap.heartbeat(OFFBOARD), A1, t)
        link.receive_datagram(ap.attitude(), A1, t)
        link.handle_timer(t)
        for m, _ in sent(link, t, "COMMAND_LONG"):  # ACK everything (stale stream re-requests)
            if m.param2 == -1:
                asked.append(round(t, 1))
            link.receive_datagram(ap.ack(m.command), A1, t + 0.01)
        t = round(t + 0.1, 6)
    assert len(asked) == 2 and asked[0] == 0.1 and 10.1 <= asked[1] <= 10.2
    assert link.stats.disable_requests == 2 and link.stats.messages_disabled == 2

    link.receive_datagram(ap.local_position(), A1, 40.0)
    assert _stops(link, 40.0) == [LPOS]
    link.receive_datagram(ap.ack(SMI, mav.MAV_RESULT_DENIED), A1, 40.01)
    link.receive_datagram(ap.local_position(), A1, 60.0)
    assert _stops(link, 60.0) == []  # not a stream it can stop: never again


def test_no_ack_gives_up_quickly_and_stream_requests_go_first(station):
    link, ap = _px4(station, command_timeout_s=0.5, command_retries=3)
    link.receive_datagram(ap.attitude() + ap.local_position(), A1, 0.1)
    assert _stops(link, 0.1) == [ATT]
    link.request_streams(1, 0.2)  # e.g. telemetry went stale: queued behind the stop in flight
    link.handle_timer(0.6)  # stop not ACKed: sent once more (best effort), not four times
    assert _stops(link, 0.6) == [ATT]
    link.handle_timer(1.1)
    out = sent(link, 1.1, "COMMAND_LONG")
    assert [(m.command, m.param1) for m, _ in out] == [(SMI, GPI)]  # the stream request first
    link.receive_datagram(ap.ack(SMI), A1, 1.2)
    assert _stops(link, 1.2) == [LPOS]  # then the next stop
    assert link.stats.data_stream_fallbacks == 0  # a lost stop is no reason to fall back


def test_switch_off(station):
    link, ap = _px4(station, disable_unused_messages=False)
    link.receive_datagram(ap.attitude(), A1, 0.1)
    assert _stops(link, 0.1) == [] and link.stats.disable_requests == 0


def test_reboot_resets_the_cap(station):
    link, ap = _px4(station, disable_attempts=1)
    link.receive_datagram(ap.attitude(), A1, 0.1)
    assert _stops(link, 0.1) == [ATT]
    link.receive_datagram(ap.ack(SMI), A1, 0.2)
    link.receive_datagram(ap.attitude(), A1, 20.0)
    assert _stops(link, 20.0) == []  # capped
    link.handle_timer(30.0)  # lost, then back (a reboot restores the default streams)
    link.receive_datagram(ap.heartbeat(OFFBOARD), A1, 31.0)
    sent(link, 31.0)
    link.receive_datagram(ap.ack(SMI), A1, 31.1)  # the stream re-request
    link.receive_datagram(ap.attitude(), A1, 31.2)
    assert _stops(link, 31.2) == [ATT]


def test_unused_frames_are_checked_but_not_unpacked():
    link = StationLink(StationConfig(record_frames=True, disable_unused_messages=False))
    ap = FakeAutopilot(sysid=1)
    frames = [
        ap.heartbeat(4),
        ap.attitude(),
        ap.local_position(),
        ap.global_position(47, 8, 500, 10),
    ]
    bad = bytearray(ap.attitude())
    bad[-1] ^= 0xFF  # CRC broken
    for f in frames + [bytes(bad)]:
        link.receive_datagram(f, A1, 0.0)
    d = link.stats.decode
    assert (d.frames, d.raw_frames, d.bad_data) == (4, 2, 1)
    assert [f for _, out, f in link.take_frames() if not out] == frames  # the tlog keeps all
    assert link.stats.ignored_messages == 2 and link.stats.handler_errors == 0
    assert [type(e).__name__ for e in drain(link)] == ["VehicleDiscovered", "TelemetryReceived"]


def test_raw_frames_obey_signing():
    key = bytes(range(32))
    link = StationLink(
        StationConfig(signing_key=key, accept_unsigned=False, unix_time_at_zero_s=1.7e9)
    )
    signed, plain = FakeAutopilot(sysid=1), FakeAutopilot(sysid=1)
    signed.sign_outgoing(key, 1.7e9)
    link.receive_datagram(signed.heartbeat(4), A1, 0.0)
    link.receive_datagram(plain.attitude(), A1, 0.1)
    signed.mav.signing.timestamp += 10
    link.receive_datagram(signed.attitude(), A1, 0.2)
    d = link.stats.decode
    assert (d.raw_frames, d.signature_rejected) == (1, 1)


@pytest.mark.parametrize(
    "msg",
    [
        mav.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6),
        mav.MAVLink_vfr_hud_message(1.0, 2.0, 90, 50, 3.0, 4.0),
        mav.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3),
    ],
)
def test_raw_frame_header_matches_full_decode(msg):
    ap = FakeAutopilot(sysid=42, compid=7)
    data = ap.pack(msg)
    stats = wire.DecodeStats()
    (raw,) = wire.Decoder(stats, full_msgids=frozenset()).feed(data)
    (full,) = wire.Decoder(stats).feed(data)
    assert isinstance(raw, wire.RawFrame) and not isinstance(full, wire.RawFrame)
    for get in ("get_type", "get_msgId", "get_srcSystem", "get_srcComponent", "get_seq"):
        assert getattr(raw, get)() == getattr(full, get)()
    assert bytes(raw.get_msgbuf()) == bytes(full.get_msgbuf()) == data

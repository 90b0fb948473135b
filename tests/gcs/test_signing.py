"""MAVLink 2 signing on the station side: a forged frame must not lock out the real sender."""

from gcs_fakes import FakeAutopilot, drain

from gcs.events import TelemetryReceived, VehicleDiscovered

KEY = bytes(range(32))
OFFSET_S = 1.7e9  # core time 0 = this Unix time
A1 = ("10.0.0.1", 14550)


def _signed_vehicle(sysid: int = 1, t_s: float = 0.0) -> FakeAutopilot:
    ap = FakeAutopilot(sysid=sysid)
    ap.sign_outgoing(KEY, OFFSET_S + t_s)
    return ap


def test_forged_future_timestamp_does_not_lock_out_the_real_vehicle(station):
    link = station(signing_key=KEY, accept_unsigned=False, unix_time_at_zero_s=OFFSET_S)
    real = _signed_vehicle()
    link.receive_datagram(real.heartbeat(4), A1, 0.0)
    assert [type(e) for e in drain(link)] == [VehicleDiscovered]

    # The attacker knows the vehicle's ids and signing link id, not the key: a frame "signed"
    # with another key and a timestamp a day ahead, from the vehicle's own address (spoofed UDP
    # source, or the same radio channel).
    forger = FakeAutopilot(sysid=1)
    forger.sign_outgoing(bytes(32 * [7]), OFFSET_S + 86400.0)
    rejected_before = link.stats.decode.signature_rejected
    link.receive_datagram(forger.global_position(10.0, 10.0, 100.0, 50.0), A1, 0.5)
    assert link.stats.decode.signature_rejected == rejected_before + 1
    assert drain(link) == []

    # The real vehicle, a second later (its timestamps far below the forged one), is still heard.
    real.mav.signing.timestamp += 100_000
    link.receive_datagram(real.global_position(47.5, 8.25, 500.0, 10.0), A1, 1.0)
    (tel,) = drain(link)
    assert isinstance(tel, TelemetryReceived) and tel.lat_deg == 47.5
    assert link.stats.decode.signature_rejected == rejected_before + 1


def test_replayed_and_unsigned_frames_are_rejected(station):
    link = station(signing_key=KEY, accept_unsigned=False, unix_time_at_zero_s=OFFSET_S)
    real = _signed_vehicle()
    hb = real.heartbeat(4)
    link.receive_datagram(hb, A1, 0.0)
    drain(link)
    link.receive_datagram(hb, A1, 0.1)  # the same frame again: a replay (timestamp not newer)
    link.receive_datagram(FakeAutopilot(sysid=1).global_position(1.0, 1.0, 1.0, 1.0), A1, 0.2)
    assert drain(link) == []
    assert link.stats.decode.signature_rejected == 2

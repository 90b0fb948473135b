"""Byte-stream framing in the station core (TCP, serial: ``datagram=False``), in memory with
explicit time: frames cut anywhere across reads still decode; UDP datagrams are not re-joined."""

from __future__ import annotations

import pytest
from gcs_fakes import drain

from gcs.events import TelemetryReceived, VehicleDiscovered

DEV = "/dev/ttyUSB0"


def _stream(fake):
    ap = fake(sysid=3)
    return ap.heartbeat(custom_mode=4) + ap.global_position(47.5, 8.25, 512.5, 12.34)


@pytest.mark.parametrize("cut", [1, 5, 9, 10, 11, 20, 30, 40])
def test_a_frame_cut_across_two_reads_still_parses(station, fake, cut):
    link = station(datagram=False, stream_rates_hz=())
    data = _stream(fake)
    link.receive_datagram(data[:cut], DEV, 0.0)
    link.receive_datagram(data[cut:], DEV, 0.01)
    kinds = [type(e) for e in drain(link)]
    assert VehicleDiscovered in kinds and TelemetryReceived in kinds
    assert link.stats.decode.truncated == 0 and link.stats.decode.frames == 2


def test_one_byte_at_a_time(station, fake):
    link = station(datagram=False, stream_rates_hz=())
    data = _stream(fake)
    for i in range(len(data)):
        link.receive_datagram(data[i : i + 1], DEV, i * 1e-4)
    tel = [e for e in drain(link) if isinstance(e, TelemetryReceived)]
    assert len(tel) == 1 and tel[0].sysid == 3
    assert tel[0].rel_alt_m == pytest.approx(12.34, abs=1e-3)
    assert link.stats.decode.frames == 2


def test_line_noise_between_frames_resyncs(station, fake):
    link = station(datagram=False, stream_rates_hz=())
    ap = fake(sysid=3)
    hb, pos = ap.heartbeat(custom_mode=4), ap.global_position(47.5, 8.25, 512.5, 12.34)
    noisy = b"\x00\x11garbage" + hb + b"\x55junk\xaa" + pos  # noise without a start byte
    for i in range(0, len(noisy), 7):  # 7-byte reads, as a slow UART might deliver
        link.receive_datagram(noisy[i : i + 7], DEV, 0.0)
    kinds = [type(e) for e in drain(link)]
    assert VehicleDiscovered in kinds and TelemetryReceived in kinds


def test_datagrams_are_not_rejoined(station, fake):
    """The contrast: UDP (datagram=True) drops a cut frame instead of waiting for the rest."""
    link = station(stream_rates_hz=())
    data = _stream(fake)
    link.receive_datagram(data[:9], ("127.0.0.1", 14550), 0.0)
    link.receive_datagram(data[9:], ("127.0.0.1", 14550), 0.01)
    assert not any(isinstance(e, VehicleDiscovered) for e in drain(link))
    assert link.stats.decode.truncated >= 1

"""Packet loss from MAVLink sequence numbers (gcs.link_quality): gaps, the wrap at 255,
duplicates and reordered frames, windows; and the station link counting it per vehicle."""

from __future__ import annotations

import pytest

from gcs.link_quality import DUPLICATE_WINDOW, SeqCounter


def feed(seqs):
    c = SeqCounter()
    for s in seqs:
        c.update(s)
    return c


def test_no_gap_no_loss():
    c = feed(range(0, 200))
    assert (c.received, c.lost, c.duplicates) == (200, 0, 0)
    assert c.total_loss_frac() == 0.0


def test_gap_counts_missing_frames():
    c = feed([10, 11, 15, 16, 20])  # 12-14 and 17-19 missing
    assert c.lost == 6 and c.duplicates == 0
    assert c.total_loss_frac() == pytest.approx(6 / 11)


def test_wrap_at_255_is_not_a_gap():
    c = feed([253, 254, 255, 0, 1, 2])
    assert c.lost == 0 and c.duplicates == 0


def test_gap_across_the_wrap():
    c = feed([254, 255, 2])  # 0 and 1 missing
    assert c.lost == 2


def test_duplicate_and_reordered_frames_are_not_losses():
    c = feed([5, 6, 6, 7, 5, 8])
    assert c.lost == 0
    assert c.duplicates == 2
    assert c.received == 6
    assert c.total_loss_frac() == 0.0


def test_reordered_across_the_wrap_is_a_duplicate():
    c = feed([0, 1, 255])  # 255 arrives late, after the wrap
    assert c.duplicates == 1 and c.lost == 0


def test_largest_gap_below_the_window_is_a_loss():
    c = feed([0, DUPLICATE_WINDOW])  # DUPLICATE_WINDOW - 1 frames missing
    assert c.lost == DUPLICATE_WINDOW - 1 and c.duplicates == 0
    c = feed([0, (DUPLICATE_WINDOW + 1) & 0xFF])  # read as behind
    assert c.lost == 0 and c.duplicates == 1


def test_windows():
    c = feed(range(0, 10))
    assert c.take_window() == 0.0
    assert c.loss_frac() is None  # nothing in the new window yet
    for s in (12, 13):  # 10, 11 lost
        c.update(s)
    assert c.take_window() == pytest.approx(2 / 4)
    assert c.total_loss_frac() == pytest.approx(2 / 14)


def test_reset_after_reboot():
    c = feed([100, 101])
    c.reset()
    c.update(0)  # a new reference, not 154 lost
    c.update(1)
    assert c.lost == 0


def test_station_link_counts_per_vehicle():
    """Frames of one vehicle through the station core with a gap: counted by the link."""
    from gcs.link import StationLink
    from mavedge import mavlink

    link = StationLink()
    mav = mavlink.MAVLink(None, 7, 1)
    addr = ("10.0.0.7", 14550)

    def frame(seq, msg):
        mav.seq = seq
        return bytes(msg.pack(mav))

    hb = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
    )
    for k, seq in enumerate([250, 251, 252, 255, 0, 0, 3]):  # lost 253, 254, 1, 2; one repeat
        link.receive_datagram(frame(seq, hb), addr, float(k))
    c = link.seq_counter(7)
    # The first heartbeat discovers the vehicle (counting starts with its next frame).
    assert (c.received, c.lost, c.duplicates) == (6, 4, 1)

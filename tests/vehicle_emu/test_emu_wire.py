import math

import pytest
from hypothesis import given, strategies as st

from vehicle_emu import wire


def test_golden_wire_units():
    assert wire.lat_e7_from_deg(47.5) == 475000000
    assert wire.alt_mm_from_m(12.34) == 12340
    assert wire.cm_s_from_m_s(-1.234) == -123
    assert wire.cm_s_from_m_s(1e6) == 32767
    assert wire.hdg_cdeg_from_rad(math.pi / 2) == 9000
    assert wire.hdg_cdeg_from_rad(-math.pi / 2) == 27000
    assert wire.hdg_cdeg_from_rad(float("nan")) == 65535
    assert wire.time_boot_ms_from_s(1.2345) == 1234
    assert wire.signing_timestamp_from_s(1420070400.0 + 1.0) == 100000


@given(st.floats(-90, 90))
def test_lat_roundtrip_within_half_unit(lat):
    assert abs(wire.deg_from_lat_e7(wire.lat_e7_from_deg(lat)) - lat) <= 0.5e-7 + 1e-12


@given(st.floats(-1000, 10000))
def test_alt_roundtrip(alt):
    assert abs(wire.m_from_alt_mm(wire.alt_mm_from_m(alt)) - alt) <= 0.5e-3 + 1e-9


@pytest.mark.parametrize(
    "value,ptype",
    [
        (7, wire.dialect.MAV_PARAM_TYPE_INT32),
        (-3, wire.dialect.MAV_PARAM_TYPE_INT32),
        (2.5, wire.dialect.MAV_PARAM_TYPE_REAL32),
    ],
)
@pytest.mark.parametrize("bytewise", [False, True])
def test_param_encoding_roundtrip(value, ptype, bytewise):
    w = wire.param_to_wire_float(value, ptype, bytewise)
    assert wire.param_from_wire_float(w, ptype, bytewise) == value


def test_split_frames_and_decode_three_ways():
    tx = wire.Codec(7)
    frames = [tx.encode(wire.dialect.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)) for _ in range(3)]
    rx = wire.Codec(1)
    # one frame per datagram
    assert sum(len(rx.decode_datagram(f).messages) for f in frames) == 3
    # several frames in one datagram
    assert wire.split_frames(b"".join(frames)) == frames
    assert len(rx.decode_datagram(b"".join(frames)).messages) == 3
    # garbage around and a truncated tail
    res = rx.decode_datagram(b"\x01\x02" + frames[0] + b"zz" + frames[1][:-3])
    assert len(res.messages) == 1 and res.n_bad >= 1 and res.n_truncated_bytes > 0
    # the parser was reset: the next datagram decodes cleanly
    assert len(rx.decode_datagram(frames[2]).messages) == 1

"""Codec golden values, type masks, round trips."""

import math

import pytest
from gcs_fakes import FakeAutopilot
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs import wire
from gcs.autopilot import (
    PX4_MODES,
    ArduCopterAdapter,
    PX4Adapter,
    UnsupportedCommand,
    adapter_for,
    mode_name,
    px4_custom_mode,
    px4_main_sub,
)


def test_golden_wire_units():
    assert wire.deg_to_e7(47.5) == 475000000
    assert wire.m_to_mm(12.34) == 12340
    assert wire.deg_to_e7(-122.4194155) == -1224194155
    assert wire.m_s_to_cm_s(-1.005) in (-100, -101) and wire.m_s_to_cm_s(1e6) == 32767
    assert wire.hdg_cdeg_to_yaw_rad(65535) is None
    assert wire.hdg_cdeg_to_yaw_rad(27000) == pytest.approx(-math.pi / 2)
    assert wire.yaw_rad_to_hdg_cdeg(-math.pi / 2) == 27000
    assert wire.hz_to_interval_us(4.0) == 250000 and wire.hz_to_interval_us(0) == -1


def test_type_mask_constants():
    assert wire.TYPE_MASK_POSITION == 3576 == 0x0DF8
    assert wire.TYPE_MASK_VELOCITY == 3527
    assert wire.TYPE_MASK_POSITION_VELOCITY == 3520
    assert wire.TYPE_MASK_ACCELERATION_LOCAL == 3135
    assert wire.TYPE_MASK_ACCELERATION_GLOBAL == 3128
    assert wire.TYPE_MASK_POSITION_VELOCITY_ACCELERATION == 3072
    assert wire.TYPE_MASK_YAW == 2559 and wire.TYPE_MASK_YAW_RATE == 1535
    for mask in (
        wire.TYPE_MASK_POSITION,
        wire.TYPE_MASK_POSITION_VELOCITY,
        wire.TYPE_MASK_POSITION_YAW,
    ):
        assert mask & 0b111 == 0  # never mask Z (or X, Y) on a position target


def test_position_target_global_int_bytes():
    codec = wire.Codec(255, 190)
    msg = wire.position_target_global_int(
        target_system=7, lat_deg=47.5, lon_deg=8.25, alt_m=12.34, time_boot_s=1.5
    )
    frame = codec.encode(msg)
    (m,) = FakeAutopilot().decode(frame)
    assert (m.target_system, m.target_component, m.coordinate_frame, m.type_mask) == (7, 1, 6, 3576)
    assert (m.lat_int, m.lon_int, m.time_boot_ms) == (475000000, 82500000, 1500)
    assert m.alt == pytest.approx(12.34, abs=1e-5)
    with_vel = wire.position_target_global_int(
        target_system=7, lat_deg=1, lon_deg=2, alt_m=3, vel_ned_m_s=(1, 2, 3)
    )
    assert with_vel.type_mask == 3520 and with_vel.vz == 3
    assert wire.position_target_local_ned(target_system=1, pos_ned_m=(1, 2, -3)).type_mask == 3576
    with pytest.raises(ValueError):
        wire.position_target_global_int(target_system=1, lat_deg=math.nan, lon_deg=0, alt_m=0)


def test_codec_sequence_and_decode_stats():
    codec = wire.Codec(255, 190)
    hb = mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)
    a, b = codec.encode(hb), codec.encode(hb)
    assert a[4] == 0 and b[4] == 1  # seq increments
    dec = codec.new_decoder()
    msgs = dec.feed(a + b"garbage" + b)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "HEARTBEAT"]
    assert codec.stats.frames == 2 and codec.stats.bad_data == 1
    assert dec.feed(a[:5]) == [] and codec.stats.truncated == 1
    stream = codec.new_decoder()
    assert stream.feed(a[:5], datagram=False) == []
    assert [m.get_type() for m in stream.feed(a[5:], datagram=False)] == ["HEARTBEAT"]


@given(st.floats(-90, 90), st.floats(-180, 180), st.floats(-1000, 9000))
def test_round_trip_within_quantisation(lat, lon, alt):
    assert abs(wire.e7_to_deg(wire.deg_to_e7(lat)) - lat) <= 0.5e-7 + 1e-12
    assert abs(wire.e7_to_deg(wire.deg_to_e7(lon)) - lon) <= 0.5e-7 + 1e-12
    assert abs(wire.mm_to_m(wire.m_to_mm(alt)) - alt) <= 0.5e-3 + 1e-9


def test_param_value_decoding():
    import struct

    as_float = struct.unpack("<f", struct.pack("<i", 300))[0]
    assert wire.decode_param_value(as_float, mav.MAV_PARAM_TYPE_INT32, bytewise=True) == 300
    assert wire.decode_param_value(3.0, mav.MAV_PARAM_TYPE_INT8, bytewise=False) == 3.0
    assert wire.decode_param_value(0.5, mav.MAV_PARAM_TYPE_REAL32, bytewise=True) == 0.5
    assert wire.param_id_to_str(b"FS_GCS_ENABLE\x00\x00\x00") == "FS_GCS_ENABLE"


def test_mode_tables():
    assert mode_name(3, 4) == "GUIDED" and mode_name(3, 6) == "RTL" and mode_name(3, 9) == "LAND"
    assert mode_name(12, 393216) == "OFFBOARD"
    assert px4_custom_mode(*PX4_MODES["AUTO.TAKEOFF"]) == 33816576
    assert px4_custom_mode(*PX4_MODES["AUTO.LOITER"]) == 50593792
    assert px4_custom_mode(*PX4_MODES["AUTO.RTL"]) == 84148224
    assert px4_custom_mode(*PX4_MODES["AUTO.LAND"]) == 100925440
    assert px4_custom_mode(*PX4_MODES["POSCTL"]) == 196608
    assert px4_main_sub(84148224) == (4, 5)
    for name in PX4_MODES:
        assert mode_name(12, px4_custom_mode(*PX4_MODES[name])) == name
    assert mode_name(99, 5) == "MODE(5)"
    ap, px4 = ArduCopterAdapter(), PX4Adapter()
    assert ap.set_mode("guided").params[:2] == (1.0, 4.0)
    assert px4.set_mode("OFFBOARD").params[:3] == (1.0, 6.0, 0.0)
    assert px4.set_mode("OFFBOARD").after_prestream and not ap.set_mode("GUIDED").after_prestream
    assert ap.takeoff(10).params[6] == 10.0 and px4.takeoff(10) is None
    assert ap.arm().params[:2] == (1.0, 0.0)
    assert ap.is_failsafe_mode(6) and not ap.is_failsafe_mode(4)
    assert isinstance(adapter_for(12), PX4Adapter)
    with pytest.raises(UnsupportedCommand):
        ap.set_mode("OFFBOARD")
    with pytest.raises(UnsupportedCommand):
        adapter_for(0).set_mode("GUIDED")

"""mavedge: the one MAVLink edge of the station and the emulator (issue 13.1)."""

import hashlib
import math
import struct

import pytest
from hypothesis import given, strategies as st

from mavedge import codec, modes, params, setpoints, units
from mavedge import mavlink as mav

KEY = bytes(range(32))


class _F:
    def write(self, _d):
        pass


def _pymavlink(sysid=7, compid=1, key=None, ts=0):
    m = mav.MAVLink(_F(), sysid, compid)
    if key is not None:
        m.signing.secret_key = key
        m.signing.sign_outgoing = True
        m.signing.timestamp = ts
    return m


# ------------------------------------------------------------------ units


def test_units_golden_and_saturation():
    assert units.deg_to_e7(47.5) == 475_000_000
    assert units.deg_to_e7(-180.0) == -1_800_000_000
    # int32 clamp both ways, non-finite is INT32_MAX ("unknown")
    assert units.deg_to_e7(1e9) == 2**31 - 1 and units.deg_to_e7(-1e9) == -(2**31)
    assert units.deg_to_e7(float("nan")) == 2**31 - 1
    assert units.deg_to_e7(float("-inf")) == 2**31 - 1
    # symmetric int16 velocity saturation
    assert units.m_s_to_cm_s(1e6) == 32767 and units.m_s_to_cm_s(-1e6) == -32767
    assert units.m_s_to_cm_s(-327.67) == -32767 and units.m_s_to_cm_s(-1.234) == -123
    assert units.m_to_mm(12.34) == 12340 and units.m_to_mm(1e12) == 2**31 - 1
    assert units.yaw_rad_to_hdg_cdeg(-math.pi / 2) == 27000
    assert units.yaw_rad_to_hdg_cdeg(None) == units.yaw_rad_to_hdg_cdeg(math.nan) == 65535
    assert units.hdg_cdeg_to_yaw_rad(65535) is None
    assert units.signing_timestamp_from_s(units.SIGNING_EPOCH_UNIX_S + 1.0) == 100_000


@given(st.floats(-400.0, 400.0))
def test_velocity_is_sign_symmetric_on_the_wire(v):
    assert units.m_s_to_cm_s(-v) == -units.m_s_to_cm_s(v)


@given(st.floats(-180, 180))
def test_e7_round_trip_within_half_unit(deg):
    assert abs(units.e7_to_deg(units.deg_to_e7(deg)) - deg) <= 0.5e-7 + 1e-12


def test_converters_fit_the_pymavlink_fields():
    # Saturated values must pack without struct.error in the int16 / int32 fields.
    m = mav.MAVLink_global_position_int_message(
        0,
        units.deg_to_e7(1e12),
        units.deg_to_e7(-1e12),
        units.m_to_mm(1e12),
        units.m_to_mm(-1e12),
        units.m_s_to_cm_s(1e9),
        units.m_s_to_cm_s(-1e9),
        units.m_s_to_cm_s(float("1e300")),
        units.yaw_rad_to_hdg_cdeg(math.inf),
    )
    _pymavlink().decode(bytearray(m.pack(_pymavlink())))


# ------------------------------------------------------------------ parameters

I8, U8, I16, U16, I32, U32, R32 = (
    mav.MAV_PARAM_TYPE_INT8,
    mav.MAV_PARAM_TYPE_UINT8,
    mav.MAV_PARAM_TYPE_INT16,
    mav.MAV_PARAM_TYPE_UINT16,
    mav.MAV_PARAM_TYPE_INT32,
    mav.MAV_PARAM_TYPE_UINT32,
    mav.MAV_PARAM_TYPE_REAL32,
)


def _bytes(f):
    return struct.pack("<f", f)


def test_bytewise_is_the_c_union_per_type():
    # mavlink_param_union_t: the type's own bytes, little-endian, in the low bytes; rest zero.
    assert _bytes(params.encode_param_value(-1, I8, bytewise=True)) == b"\xff\x00\x00\x00"
    assert _bytes(params.encode_param_value(200, U8, bytewise=True)) == b"\xc8\x00\x00\x00"
    assert _bytes(params.encode_param_value(-2, I16, bytewise=True)) == b"\xfe\xff\x00\x00"
    assert _bytes(params.encode_param_value(300, I32, bytewise=True)) == struct.pack("<i", 300)
    assert _bytes(params.encode_param_value(-3, I32, bytewise=True)) == struct.pack("<i", -3)
    # UINT32 above 2**31 keeps its unsigned pattern (int32 packing raised here)
    assert _bytes(params.encode_param_value(3_000_000_000, U32, bytewise=True)) == struct.pack(
        "<I", 3_000_000_000
    )
    # C-cast: the value as a float; REAL32 untouched either way
    assert params.encode_param_value(-1, I8, bytewise=False) == -1.0
    assert params.encode_param_value(2.5, R32, bytewise=True) == 2.5
    with pytest.raises(ValueError):
        params.encode_param_value(128, I8, bytewise=True)
    with pytest.raises(ValueError):
        params.encode_param_value(math.nan, I32, bytewise=False)


@pytest.mark.parametrize(
    "ptype,lo,hi",
    [
        (I8, -128, 127),
        (U8, 0, 255),
        (I16, -32768, 32767),
        (U16, 0, 65535),
        (I32, -(2**31), 2**31 - 1),
        (U32, 0, 2**32 - 1),
    ],
)
@pytest.mark.parametrize("bytewise", [False, True])
def test_param_round_trip_every_type(ptype, lo, hi, bytewise):
    for v in {lo, hi, 0, 1, (lo + hi) // 2}:
        w = params.encode_param_value(v, ptype, bytewise=bytewise)
        # what travels is a float32 (the wire field): pass it through one
        w32 = struct.unpack("<f", struct.pack("<f", w))[0]
        if bytewise:
            assert params.decode_param_value(w32, ptype, bytewise=True) == v
            assert params.param_from_wire_float(w32, ptype, True) == v
        elif abs(v) < 2**24:  # C-cast is exact only within float32's integer range
            assert params.param_from_wire_float(w32, ptype, False) == v


def test_vehicle_and_station_param_paths_agree():
    # the emulator's send path and the station's read path are one implementation now
    for ptype, v in [(I32, 7), (I32, -3), (I8, -1), (U16, 65535), (R32, 2.5)]:
        w = params.param_to_wire_float(v, ptype, True)
        assert params.decode_param_value(w, ptype, bytewise=True) == v


def test_pymavlink_param_value_carries_the_bytes():
    # Golden bytes: a PARAM_VALUE from pymavlink holds exactly the union bytes at offset 0.
    f = params.encode_param_value(-1, I8, bytewise=True)
    buf = mav.MAVLink_param_value_message(b"X", f, 1, 0, I8).pack(_pymavlink())
    assert buf[10:14] == b"\xff\x00\x00\x00"


# ------------------------------------------------------------------ modes and type masks


def test_mode_tables():
    assert modes.ARDUCOPTER_MODES["GUIDED"] == mav.COPTER_MODE_GUIDED == 4
    assert modes.ARDUCOPTER_MODES["AUTO_RTL"] == 27 and "ENUM_END" not in modes.ARDUCOPTER_MODES
    assert modes.px4_custom_mode(*modes.PX4_MODES["OFFBOARD"]) == 393216
    assert modes.px4_custom_mode(*modes.PX4_MODES["AUTO.LOITER"]) == (4 << 16) | (3 << 24)
    for name, pair in modes.PX4_MODES.items():
        assert modes.px4_main_sub(modes.px4_custom_mode(*pair)) == pair
        assert modes.PX4_NAMES[pair] == name


def test_type_masks_from_pymavlink_enum():
    assert (
        setpoints.TYPE_MASK_POSITION,
        setpoints.TYPE_MASK_VELOCITY,
        setpoints.TYPE_MASK_POSITION_VELOCITY,
        setpoints.TYPE_MASK_ACCELERATION_LOCAL,
        setpoints.TYPE_MASK_POSITION_VELOCITY_ACCELERATION,
        setpoints.TYPE_MASK_YAW,
        setpoints.TYPE_MASK_YAW_RATE,
        setpoints.TYPE_MASK_POSITION_YAW,
    ) == (3576, 3527, 3520, 3135, 3072, 2559, 1535, 2552)
    assert setpoints.POS_BITS == 0b111 and setpoints.VEL_BITS == 0b111 << 3
    assert setpoints.ACC_BITS == 0b111 << 6


# ------------------------------------------------------------------ codec: golden bytes


def _hb():
    return mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, 81, 393216, mav.MAV_STATE_ACTIVE, 3
    )


def test_golden_frames_match_pymavlink():
    """Our encoders produce pymavlink's bytes, sequence for sequence, signed and unsigned."""
    ours = codec.VehicleCodec(7, 1)
    ref = _pymavlink(7, 1)
    for _ in range(300):  # wraps the sequence number
        assert ours.encode(_hb()) == bytes(_hb().pack(ref))
        ref.seq = (ref.seq + 1) % 256
    station = codec.Codec(255, 190)
    ref = _pymavlink(255, 190)
    sp = setpoints.position_target_global_int(
        target_system=3, lat_deg=47.5, lon_deg=8.25, alt_m=20.0
    )
    assert station.encode(sp) == bytes(sp.pack(ref))
    signed = codec.VehicleCodec(7, 1, signing_key=KEY)
    signed.advance_signing_timestamp(1000)
    ref = _pymavlink(7, 1, KEY, 1000)
    assert signed.encode(_hb()) == bytes(_hb().pack(ref))


def test_golden_bytes_heartbeat_literal():
    frame = codec.VehicleCodec(1, 1).encode(mav.MAVLink_heartbeat_message(2, 3, 81, 4, 4, 3))
    # fd len incompat compat seq sys comp msgid(3) | payload | crc
    assert frame[:10] == bytes([0xFD, 9, 0, 0, 0, 1, 1, 0, 0, 0])
    assert frame[10:19] == struct.pack("<IBBBBB", 4, 2, 3, 81, 4, 3)
    assert len(frame) == 21


# ------------------------------------------------------------------ codec: signing


def _signed_frame(ts, key=KEY, sysid=255):
    m = _pymavlink(sysid, 190, key, ts)
    return bytes(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(m))


def _forge(ts):
    """A frame whose timestamp is ``ts`` but whose signature is garbage (no key needed)."""
    f = bytearray(_signed_frame(ts, key=bytes(32 * [7])))
    return bytes(f)


@pytest.mark.parametrize("side", ["vehicle", "station"])
def test_forged_future_timestamp_does_not_silence_the_stream(side):
    """pymavlink's own check_signature would record the forged timestamp; ours does not."""
    if side == "vehicle":
        c = codec.VehicleCodec(1, 1, signing_key=KEY)
        accepted = lambda data: len(c.decode_datagram(data).messages)  # noqa: E731
    else:
        dec = codec.Codec(255, 190, signing_key=KEY, accept_unsigned=False).new_decoder()
        accepted = lambda data: len(dec.feed(data))  # noqa: E731
    assert accepted(_signed_frame(1000)) == 1
    assert accepted(_forge(10**12)) == 0
    assert accepted(_signed_frame(2000)) == 1  # the genuine stream carries on
    assert accepted(_signed_frame(2000)) == 0  # a replay is still refused


def test_pymavlink_stock_check_would_be_poisoned():
    """The reason for the override: stock pymavlink refuses the genuine frame after a forgery."""
    stock = mav.MAVLink(_F(), 1, 1)
    stock.robust_parsing = True
    stock.signing.secret_key = KEY
    ok = [m.get_type() for m in stock.parse_buffer(_signed_frame(1000)) or []]
    stock.parse_buffer(_forge(10**12))
    after = [m.get_type() for m in stock.parse_buffer(_signed_frame(2000)) or []]
    assert ok == ["HEARTBEAT"] and after != ["HEARTBEAT"]


def test_one_signature_check():
    assert (
        codec.Decoder(codec.DecodeStats())._mav.check_signature.__func__
        is codec.VehicleCodec(1)._mav.check_signature.__func__
    )
    assert hashlib.sha256  # the check is sha256 over key + frame (mavlink.io message_signing)


# ------------------------------------------------------------------ routing without parsing


def _messages_with_target():
    return [
        mav.MAVLink_command_long_message(42, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        mav.MAVLink_command_long_message(0, 0, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        mav.MAVLink_param_set_message(17, 1, b"FS_GCS_ENABLE", 1.0, 9),
        mav.MAVLink_set_mode_message(200, 1, 4),
        mav.MAVLink_mission_request_int_message(9, 1, 3, 0),
        setpoints.position_target_local_ned(target_system=254, pos_ned_m=(1.0, 2.0, -3.0)),
        setpoints.position_target_global_int(target_system=5, lat_deg=1.0, lon_deg=2.0, alt_m=3.0),
        mav.MAVLink_request_data_stream_message(77, 0, 6, 4, 1),
        mav.MAVLink_setup_signing_message(3, 1, KEY, 5),
    ]


@pytest.mark.parametrize("key", [None, KEY])
def test_frame_target_system_matches_a_full_parse(key):
    tx = _pymavlink(255, 190, key, 10)
    msgs = _messages_with_target() + [_hb(), mav.MAVLink_timesync_message(1, 2)]
    data = b"".join(bytes(m.pack(tx)) for m in msgs)
    frames = codec.split_frames(b"\x00junk" + data + b"\xfd\x10")
    assert len(frames) == len(msgs)
    rx = _pymavlink(1, 1)
    for f, m in zip(frames, msgs):
        parsed = rx.decode(bytearray(f))
        assert (
            codec.frame_target_system(f)
            == getattr(parsed, "target_system", 0)
            == getattr(m, "target_system", 0)
        )


def test_frame_target_system_truncated_payload_is_zero():
    # MAVLink 2 trims trailing zeros: a broadcast COMMAND_LONG ends before target_system.
    f = bytes(mav.MAVLink_command_long_message(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0).pack(_pymavlink()))
    assert f[1] < 30 and codec.frame_target_system(f) == 0

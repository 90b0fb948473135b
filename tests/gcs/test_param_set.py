"""PARAM_SET in the station core: encoding per autopilot, echo confirmation, retry, refusal."""

import struct

import pytest
from gcs_fakes import FakeAutopilot, drain, sent
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs import audit, wire
from gcs.events import ParamReceived, ParamSetConfirmed, ParamSetFailed

A1 = ("10.0.0.1", 14550)
INT8, INT32, REAL32 = mav.MAV_PARAM_TYPE_INT8, mav.MAV_PARAM_TYPE_INT32, mav.MAV_PARAM_TYPE_REAL32


def _link(station, autopilot=mav.MAV_AUTOPILOT_ARDUPILOTMEGA, **cfg):
    link = station(**cfg)
    ap = FakeAutopilot(sysid=1, autopilot=autopilot)
    link.receive_datagram(ap.heartbeat(4), A1, 0.0)
    drain(link)
    link.datagrams_to_send(0.0)
    return link, ap


def _run(link, t_end):
    out = []
    while (t := link.next_timer_s()) is not None and t <= t_end:
        link.handle_timer(t)
        out += [(t, m) for m, _ in sent(link, t, "PARAM_SET")]
    return out


def test_ardupilot_set_is_c_cast_and_confirmed_by_the_echo(station):
    link, ap = _link(station)
    link.set_param(1, "FS_GCS_ENABLE", 1, INT8, 1.0, previous=0.0)
    ((msg, to),) = sent(link, 1.0, "PARAM_SET")
    assert to == A1 and (msg.target_system, msg.target_component) == (1, 1)
    assert msg.param_id == "FS_GCS_ENABLE" and msg.param_type == INT8
    assert msg.param_value == 1.0  # ArduPilot casts the float (GCS_Param.cpp)
    link.receive_datagram(ap.param_value("FS_GCS_ENABLE", 1.0, INT8), A1, 1.2)
    evs = drain(link)
    assert [type(e) for e in evs] == [ParamReceived, ParamSetConfirmed]
    ok = evs[1]
    assert (ok.name, ok.value, ok.previous, ok.attempts) == ("FS_GCS_ENABLE", 1.0, 0.0, 1)
    assert _run(link, 10.0) == []  # confirmed: never re-sent


def test_px4_int32_set_is_bytewise(station):
    link, ap = _link(station, autopilot=mav.MAV_AUTOPILOT_PX4)
    link.set_param(1, "NAV_DLL_ACT", 2, INT32, 0.0)
    ((msg, _),) = sent(link, 0.0, "PARAM_SET")
    assert msg.param_type == INT32
    assert struct.pack("<f", msg.param_value) == struct.pack("<i", 2)
    echo = struct.unpack("<f", struct.pack("<i", 2))[0]
    link.receive_datagram(ap.param_value("NAV_DLL_ACT", echo, INT32), A1, 0.1)
    (got, ok) = drain(link)
    assert got.value == 2.0 and isinstance(ok, ParamSetConfirmed) and ok.value == 2.0


def test_px4_float_param_is_sent_as_the_float(station):
    link, _ = _link(station, autopilot=mav.MAV_AUTOPILOT_PX4)
    link.set_param(1, "COM_OF_LOSS_T", 1.5, REAL32, 0.0)
    ((msg, _),) = sent(link, 0.0, "PARAM_SET")
    assert (msg.param_type, msg.param_value) == (REAL32, 1.5)


def test_no_echo_is_retried_then_fails(station):
    link, _ = _link(station, param_timeout_s=1.0, param_retries=2)
    link.set_param(1, "FS_GCS_ENABLE", 1, INT8, 0.0)
    first = sent(link, 0.0, "PARAM_SET")
    resends = _run(link, 10.0)
    assert len(first) == 1 and [t for t, _ in resends] == [1.0, 2.0]
    (fail,) = [e for e in drain(link) if isinstance(e, ParamSetFailed)]
    assert fail.t_s == 3.0 and fail.attempts == 3 and fail.value is None
    assert "no PARAM_VALUE" in fail.reason and fail.requested == 1.0


def test_stale_echo_is_resent_and_a_kept_value_fails(station):
    # ArduPilot echoes the old value of a write-protected parameter ("Param write denied").
    link, ap = _link(station, param_retries=1)
    link.set_param(1, "SYSID_MYGCS", 255, mav.MAV_PARAM_TYPE_INT16, 0.0)
    sent(link, 0.0)
    link.receive_datagram(ap.param_value("SYSID_MYGCS", 200.0, mav.MAV_PARAM_TYPE_INT16), A1, 0.1)
    assert len(sent(link, 0.1, "PARAM_SET")) == 1  # maybe a crossing read reply: ask again
    assert not [e for e in drain(link) if isinstance(e, (ParamSetFailed, ParamSetConfirmed))]
    link.receive_datagram(ap.param_value("SYSID_MYGCS", 200.0, mav.MAV_PARAM_TYPE_INT16), A1, 0.2)
    (fail,) = [e for e in drain(link) if isinstance(e, ParamSetFailed)]
    assert fail.value == 200.0 and "kept 200" in fail.reason
    assert _run(link, 10.0) == []


def test_param_error_fails_at_once(station):
    link, ap = _link(station)
    link.set_param(1, "FS_GCS_ENABLE", 1, INT8, 0.0)
    assert len(sent(link, 0.0, "PARAM_SET")) == 1
    err = mav.MAVLink_param_error_message(
        255, 190, b"FS_GCS_ENABLE", -1, mav.MAV_PARAM_ERROR_PERMISSION_DENIED
    )
    link.receive_datagram(ap._pack(err), A1, 0.1)
    (fail,) = drain(link)
    assert isinstance(fail, ParamSetFailed) and fail.reason == "MAV_PARAM_ERROR_PERMISSION_DENIED"
    assert _run(link, 10.0) == []


def test_set_param_validates_locally(station):
    link, _ = _link(station)
    with pytest.raises(ValueError):
        link.set_param(1, "FS_GCS_ENABLE", 300, INT8, 0.0)  # does not fit INT8
    with pytest.raises(ValueError):
        link.set_param(1, "X" * 17, 1, INT8, 0.0)
    with pytest.raises(KeyError):
        link.set_param(7, "FS_GCS_ENABLE", 1, INT8, 0.0)
    assert sent(link, 0.0, "PARAM_SET") == []


@given(st.integers(0, 0x7F7FFFFF))
def test_bytewise_int32_round_trip(v):
    # Non-negative INT32s below the float NaN/inf patterns: everything we ever write.
    f = wire.encode_param_value(v, INT32, bytewise=True)
    f32 = struct.unpack("<f", struct.pack("<f", f))[0]  # through the wire's float32 field
    assert wire.decode_param_value(f32, INT32, bytewise=True) == v


@given(st.integers(-128, 127))
def test_c_cast_round_trip(v):
    f = wire.encode_param_value(v, INT8, bytewise=False)
    assert f == float(v) and wire.decode_param_value(f, INT8, bytewise=False) == v


# ---------------------------------------------------------------------------- audit fixes

AP, PX4 = audit.ARDUPILOT, audit.PX4


def test_failsafe_fixes_ardupilot():
    assert audit.failsafe_fixes(AP, {"FS_GCS_ENABLE": 0, "SYSID_MYGCS": 255}) == (
        ("FS_GCS_ENABLE", 1.0),
    )
    assert audit.failsafe_fixes(AP, {"FS_GCS_ENABLE": 3, "MAV_GCS_SYSID": 250}, 254) == (
        ("MAV_GCS_SYSID", 254.0),
    )
    # A range that already includes us, and a safe vehicle: nothing to write.
    assert (
        audit.failsafe_fixes(
            AP, {"FS_GCS_ENABLE": 1, "MAV_GCS_SYSID": 250, "MAV_GCS_SYSID_HI": 255}
        )
        == ()
    )
    # Unread parameters are never written (the vehicle may not have them).
    assert audit.failsafe_fixes(AP, {}) == ()


def test_failsafe_fixes_px4():
    for bad in (0, 1, 3, 5, 6, 7):
        assert audit.failsafe_fixes(PX4, {"NAV_DLL_ACT": bad}) == (("NAV_DLL_ACT", 2.0),)
    assert audit.failsafe_fixes(PX4, {"NAV_DLL_ACT": 3, "COM_OBL_RC_ACT": 6}) == (
        ("NAV_DLL_ACT", 2.0),
        ("COM_OBL_RC_ACT", 3.0),
    )
    # Offboard loss falling back to NAV_RCL_ACT (no RC): Return written there.
    assert audit.failsafe_fixes(PX4, {"NAV_DLL_ACT": 2, "COM_OBL_RC_ACT": 0, "NAV_RCL_ACT": 6}) == (
        ("NAV_RCL_ACT", 2.0),
    )


def test_fixed_params_pass_the_audit():
    for ap, params in (
        (AP, {"FS_GCS_ENABLE": 0, "SYSID_MYGCS": 7}),
        (AP, {"FS_GCS_ENABLE": 7, "MAV_GCS_SYSID": 7, "FS_OPTIONS": 18}),
        (PX4, {"NAV_DLL_ACT": 0, "COM_OBL_RC_ACT": 0, "NAV_RCL_ACT": 3}),
        (PX4, {"NAV_DLL_ACT": 6, "COM_OBL_RC_ACT": 7, "NAV_RCL_ACT": 0, "COM_DLL_EXCEPT": 6}),
        (PX4, {"NAV_DLL_ACT": 2, "COM_OBL_RC_ACT": 0, "NAV_RCL_ACT": 2, "COM_OBL_ACT": 0}),
    ):
        assert not audit.audit_vehicle(0, 1, ap, params).safe
        fixed = dict(params, **dict(audit.failsafe_fixes(ap, params)))
        assert audit.audit_vehicle(0, 1, ap, fixed).safe


def test_heartbeat_with_our_sysid_is_never_a_vehicle_and_warns_once(station, caplog):
    # MAVProxy's own heartbeat (sysid 255, compid 230, MAV_TYPE_GCS), as sim_vehicle.py runs it.
    link = station()
    mavproxy = FakeAutopilot(
        sysid=255, compid=230, vehicle_type=mav.MAV_TYPE_GCS, autopilot=mav.MAV_AUTOPILOT_INVALID
    )
    with caplog.at_level("WARNING", logger="gcs.link"):
        for t in (0.0, 1.0, 2.0):
            link.receive_datagram(mavproxy.heartbeat(), A1, t)
    assert link.vehicles() == [] and drain(link) == []
    assert link.stats.own_sysid == 3
    assert sum("our sysid 255" in r.getMessage() for r in caplog.records) == 1

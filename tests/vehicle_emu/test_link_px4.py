"""PX4 personality: packed custom_mode, unpacked DO_SET_MODE, offboard engage/loss, data link."""

import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from vehicle_emu import events as ev
from vehicle_emu.link import VehicleCore, px4_custom_mode

from emu_helpers import GCS_ADDR, acks, of_type

ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
REJECTED = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
OFFBOARD = 393216


class Rig:
    def __init__(self, gcs, **kw):
        self.gcs = gcs
        self.t = 0.0
        self.core = VehicleCore(1, "px4", origin_lla=(47.5, 8.5, 400.0), **kw)

    def send(self, data):
        self.core.receive_datagram(data, GCS_ADDR, self.t)
        return self.gcs.decode(self.core.datagrams_to_send(self.t))

    def run(self, until_s, sp=None, sp_period_s=0.05, hb=True):
        """Advance to until_s; optionally stream setpoint ``sp`` every ``sp_period_s``."""
        out = []
        next_sp = next_hb = self.t
        while self.t < until_s - 1e-9:
            self.t = round(self.t + 0.05, 6)
            if hb and self.t >= next_hb:
                self.core.receive_datagram(self.gcs.heartbeat(), GCS_ADDR, self.t)
                next_hb = self.t + 1.0
            if sp is not None and self.t >= next_sp - 1e-9:
                self.core.receive_datagram(self.gcs.local_target(*sp), GCS_ADDR, self.t)
                next_sp = self.t + sp_period_s
            self.core.handle_timer(self.t)
            out += self.gcs.decode(self.core.datagrams_to_send(self.t))
        return out


def test_px4_heartbeat_and_default_streams(gcs):
    rig = Rig(gcs)
    msgs = rig.run(2.0)
    hb = of_type(msgs, "HEARTBEAT")[0]
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert hb.custom_mode == px4_custom_mode(4, 3) == 50593792  # AUTO.LOITER
    types = {m.get_type() for m in msgs}
    # PX4's mavlink module streams without being asked
    assert {"GLOBAL_POSITION_INT", "SYS_STATUS", "EXTENDED_SYS_STATE"} <= types
    assert of_type(msgs, "EXTENDED_SYS_STATE")[0].landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND


def test_do_set_mode_uses_unpacked_main_sub(gcs):
    rig = Rig(gcs)
    assert acks(rig.send(gcs.command(176, 1, 3, 0)), 176) == [ACCEPTED]  # POSCTL
    assert rig.core.custom_mode == 196608
    assert acks(rig.send(gcs.command(176, 1, 4, 5)), 176) == [ACCEPTED]  # AUTO.RTL
    assert rig.core.custom_mode == 84148224
    # the packed word in param2 is not a main mode: nothing changes
    assert acks(rig.send(gcs.command(176, 1, 196608, 0)), 176) == [REJECTED]
    assert rig.core.custom_mode == 84148224
    # SET_MODE with packed custom_mode is unpacked by the vehicle
    out = rig.send(gcs.frame(mavlink.MAVLink_set_mode_message(1, 1, 196608)))
    assert acks(out, 176) == [ACCEPTED] and rig.core.mode_name == "POSCTL"


def test_offboard_needs_a_recent_setpoint_not_a_long_stream(gcs):
    """PX4 commander offboardCheck.cpp OffboardChecks::checkAndReport: the offboard signal is
    valid while ``now < offboard_control_mode.timestamp + COM_OF_LOSS_T``; mavlink_receiver.cpp
    handle_message_set_position_target_local_ned publishes that topic on every valid setpoint.
    So one setpoint is enough (MAVSDK's Offboard::start() sends one, then switches)."""
    rig = Rig(gcs)
    assert acks(rig.send(gcs.command(176, 1, 6)), 176) == [REJECTED]  # no setpoint yet
    rig.run(0.5)
    rig.send(gcs.local_target(0, 0, -5))  # exactly one
    rig.run(rig.t + 0.9)  # 0.9 s < 1.0 s
    assert acks(rig.send(gcs.command(176, 1, 6)), 176) == [ACCEPTED]
    assert rig.core.custom_mode == OFFBOARD
    # arm in offboard while streaming: climbs to the setpoint
    assert acks(rig.send(gcs.command(400, 1)), 400) == [ACCEPTED]
    rig.run(rig.t + 6, sp=(10, 5, -5))
    assert np.allclose(rig.core.local_pos_ned_m, (10, 5, -5), atol=0.2)


def test_offboard_refused_when_the_last_setpoint_is_older_than_com_of_loss_t(gcs):
    rig = Rig(gcs, params={"COM_OF_LOSS_T": 1.0})
    rig.send(gcs.local_target(0, 0, -5))
    rig.run(1.1)  # 1.1 s > 1.0 s
    assert acks(rig.send(gcs.command(176, 1, 6)), 176) == [REJECTED]
    assert rig.core.mode_name == "AUTO.LOITER"
    # A slow stream (0.6 s period, < 2 Hz) keeps the signal: only its age counts.
    rig.run(rig.t + 3.0, sp=(0, 0, -5), sp_period_s=0.6)
    assert acks(rig.send(gcs.command(176, 1, 6)), 176) == [ACCEPTED]


@pytest.mark.parametrize(
    "frame, mask",
    [
        (6, 3576),  # GLOBAL_RELATIVE_ALT: not a local frame
        (1, 0b111111111),
    ],
)  # pos, vel, acc all ignored
def test_px4_setpoints_that_publish_no_offboard_control_mode_do_not_count(gcs, frame, mask):
    """mavlink_receiver.cpp: an unsupported frame returns before publishing; a setpoint with no
    position, velocity or acceleration is "invalid" and publishes nothing."""
    rig = Rig(gcs)
    rig.send(gcs.local_target(0, 0, -5, mask=mask, frame=frame))
    assert acks(rig.send(gcs.command(176, 1, 6)), 176) == [REJECTED]
    rig.send(gcs.local_target(0, 0, -5))
    assert acks(rig.send(gcs.command(176, 1, 6)), 176) == [ACCEPTED]


def test_offboard_loss_falls_back_after_com_of_loss_t(gcs):
    rig = Rig(gcs)
    rig.run(1.5, sp=(0, 0, -5))
    rig.send(gcs.command(176, 1, 6))
    rig.send(gcs.command(400, 1))
    rig.run(5.0, sp=(0, 0, -5))
    t_stop = rig.t
    rig.run(t_stop + 0.9)
    assert rig.core.mode_name == "OFFBOARD"
    rig.run(t_stop + 1.2)
    # COM_OBL_RC_ACT = 0 (Position) needs a manual control signal; with none, PX4's
    # failsafe.cpp Failsafe::checkModeFallback takes NAV_RCL_ACT's action (PR #26289), which
    # is 2 (Return) in the emulator's defaults.
    assert rig.core.params["COM_OBL_RC_ACT"] == 0 and rig.core.params["NAV_RCL_ACT"] == 2
    assert rig.core.mode_name == "AUTO.RTL"
    fs = [e for e in iter(rig.core.next_event, None) if isinstance(e, ev.FailsafeTriggered)]
    assert (fs[0].kind, fs[0].action) == ("offboard", "AUTO.RTL")


def _flying_offboard(gcs, sp=(0, 0, -5), **params) -> Rig:
    """A PX4 rig armed in OFFBOARD at 5 m, its setpoint stream just stopped."""
    rig = Rig(gcs, params=params)
    rig.run(1.5, sp=sp)
    rig.send(gcs.command(176, 1, 6))
    rig.send(gcs.command(400, 1))
    rig.run(5.0, sp=sp)
    assert rig.core.armed and rig.core.mode_name == "OFFBOARD"
    return rig


def _offboard_failsafes(rig) -> list:
    return [
        (e.kind, e.action)
        for e in iter(rig.core.next_event, None)
        if isinstance(e, ev.FailsafeTriggered)
    ]


# failsafe.cpp Failsafe::fromOffboardLossActParam: 3 Return, 4 Land, 5 Hold act directly,
# whatever NAV_RCL_ACT says (0 here: it would be "no action" for the manual fallbacks).
@pytest.mark.parametrize("act, mode", [(3, "AUTO.RTL"), (4, "AUTO.LAND"), (5, "AUTO.LOITER")])
def test_offboard_loss_direct_action(gcs, act, mode):
    rig = _flying_offboard(gcs, COM_OBL_RC_ACT=act, NAV_RCL_ACT=0)
    rig.run(rig.t + 1.2)
    assert rig.core.mode_name == mode
    assert ("offboard", mode) in _offboard_failsafes(rig)


# 0 Position, 1 Altitude, 2 Stabilized need manual control; without it checkModeFallback
# replaces them by NAV_RCL_ACT's action (failsafe.cpp fromNavDllOrRclActParam: 1 Hold,
# 2 Return, 3 Land), so a manual mode is never entered.
@pytest.mark.parametrize("obl", [0, 1, 2])
@pytest.mark.parametrize("rcl, mode", [(1, "AUTO.LOITER"), (2, "AUTO.RTL"), (3, "AUTO.LAND")])
def test_offboard_loss_manual_fallback_without_rc_takes_nav_rcl_act(gcs, obl, rcl, mode):
    rig = _flying_offboard(gcs, COM_OBL_RC_ACT=obl, NAV_RCL_ACT=rcl)
    rig.run(rig.t + 1.2)
    assert rig.core.mode_name == mode and rig.core.armed
    assert _offboard_failsafes(rig) == [("offboard", mode)]


@pytest.mark.parametrize("rcl", [0, 7])
def test_offboard_loss_manual_fallback_with_nav_rcl_act_none_keeps_last_setpoint(gcs, rcl):
    """NAV_RCL_ACT 0 (Disabled) and 7 (Hold mode, no failsafe) are Action::None in
    fromNavDllOrRclActParam: the vehicle stays in OFFBOARD on its last setpoint, here a
    velocity setpoint it keeps flying."""
    rig = Rig(gcs, params={"COM_OBL_RC_ACT": 0, "NAV_RCL_ACT": rcl})
    rig.run(1.5, sp=(0, 0, -5))
    rig.send(gcs.command(176, 1, 6))
    rig.send(gcs.command(400, 1))
    rig.run(8.0, sp=(0, 0, -5))
    rig.send(gcs.local_target(0, 0, 0, mask=0b110111000111, vx=2.0))  # velocity only
    t_stop = rig.t
    north0 = rig.core.local_pos_ned_m[0]
    rig.run(t_stop + 4.0)
    assert rig.core.mode_name == "OFFBOARD" and rig.core.armed
    assert rig.core.local_pos_ned_m[0] - north0 > 4.0  # still flying north
    assert _offboard_failsafes(rig) == [("offboard", "NONE")]  # reported once per loss
    # A setpoint ends the loss; the next loss is a new one.
    rig.run(rig.t + 0.5, sp=(rig.core.local_pos_ned_m[0], 0, -5))
    rig.run(rig.t + 1.2)
    assert _offboard_failsafes(rig) == [("offboard", "NONE")]


@pytest.mark.parametrize(
    "params",
    [
        {"COM_OBL_RC_ACT": 6},
        {"COM_OBL_RC_ACT": 7},
        {"COM_OBL_RC_ACT": 0, "NAV_RCL_ACT": 5},
        {"COM_OBL_RC_ACT": 1, "NAV_RCL_ACT": 6},
    ],
)
def test_offboard_loss_terminate_or_disarm_stops_the_motors_and_falls(gcs, params):
    """COM_OBL_RC_ACT 6 Terminate / 7 Disarm, or a manual fallback without RC whose NAV_RCL_ACT
    is 5 Terminate / 6 Disarm: motors off in the air, the vehicle falls."""
    rig = _flying_offboard(gcs, **params)
    assert rig.core.local_pos_ned_m[2] < -4.5
    rig.run(rig.t + 1.2)
    assert not rig.core.armed
    assert _offboard_failsafes(rig) == [("offboard", "DISARM")]
    rig.run(rig.t + 3.0)
    assert rig.core.landed and rig.core.local_pos_ned_m[2] > -0.5


def test_datalink_loss_returns_home_with_emulator_default(gcs):
    rig = Rig(gcs, params={"COM_DL_LOSS_T": 5})
    rig.run(1.5, sp=(0, 0, -10))
    rig.send(gcs.command(176, 1, 6))
    rig.send(gcs.command(400, 1))
    rig.run(8.0, sp=(40, 0, -10))
    rig.send(gcs.command(176, 1, 4, 3))  # Hold, no more offboard
    t0 = rig.t
    rig.run(t0 + 4.0, hb=False)
    assert rig.core.mode_name == "AUTO.LOITER"
    out = rig.run(t0 + 6.0, hb=False)
    assert rig.core.mode_name == "AUTO.RTL"  # NAV_DLL_ACT = 2
    # PX4's words: Commander.cpp dataLinkCheck, then failsafe/framework.cpp notifyUser.
    assert [(m.severity, m.text) for m in of_type(out, "STATUSTEXT")] == [
        (mavlink.MAV_SEVERITY_INFO, "Connection to ground station lost"),
        (mavlink.MAV_SEVERITY_CRITICAL, "Failsafe activated"),
    ]
    # The GCS comes back: PX4's own words (Commander.cpp Commander::dataLinkCheck), at INFO;
    # never ArduPilot's "GCS Failsafe Cleared".
    out = rig.run(rig.t + 2.0)
    texts = [(m.severity, m.text) for m in of_type(out, "STATUSTEXT")]
    assert texts == [(mavlink.MAV_SEVERITY_INFO, "GCS connection regained")]
    assert not rig.core.gcs_failsafe


def test_px4_takeoff_and_param_bytewise(gcs):
    rig = Rig(gcs)
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, float("nan"))), 22) == [REJECTED]
    rig.send(gcs.command(400, 1))
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, float("nan"))), 22) == [ACCEPTED]
    assert rig.core.mode_name == "AUTO.TAKEOFF"
    rig.run(5.0)
    assert rig.core.local_pos_ned_m[2] == pytest.approx(-2.5, abs=0.3)  # MIS_TAKEOFF_ALT
    assert rig.core.mode_name == "AUTO.LOITER"
    out = rig.send(gcs.frame(mavlink.MAVLink_param_request_read_message(1, 1, b"NAV_DLL_ACT", -1)))
    pv = of_type(out, "PARAM_VALUE")[0]
    import struct

    assert struct.unpack("<i", struct.pack("<f", pv.param_value))[0] == 2


@pytest.mark.parametrize(
    "frame, flown", [(5, True), (6, True), (0, False), (3, False), (10, False)]
)
def test_px4_global_targets_only_in_int_frames(gcs, frame, flown):
    """PX4 mavlink_receiver.cpp takes SET_POSITION_TARGET_GLOBAL_INT in frames 5, 6, 11 only."""
    rig = _flying_offboard(gcs)
    alt = 410.0 if frame in (0, 5) else 10.0  # AMSL (origin at 400 m) or above home
    lat, lon = 47.5 + 20 / 111_200, 8.5
    msg = mavlink.MAVLink_set_position_target_global_int_message(
        0, 1, 1, frame, 3576, round(lat * 1e7), round(lon * 1e7), alt, 0, 0, 0, 0, 0, 0, 0, 0
    )
    ignored = rig.core.stats.setpoints_ignored
    for _ in range(60):  # 3 s of a 20 Hz stream of that one target
        rig.t = round(rig.t + 0.05, 6)
        rig.core.receive_datagram(gcs.frame(msg), GCS_ADDR, rig.t)
        rig.core.handle_timer(rig.t)
    if flown:
        assert rig.core.stats.setpoints_ignored == ignored
        assert rig.core.local_pos_ned_m[0] > 10.0  # on its way 20 m north
    else:
        assert rig.core.stats.setpoints_ignored == ignored + 60
        assert abs(rig.core.local_pos_ned_m[0]) < 1.0  # holding; the stream then counts as lost


def test_param_set_of_com_dl_loss_t_takes_effect_at_once(gcs):
    """The core keeps ``gcs_failsafe_config`` between parameter changes: PARAM_SET of
    COM_DL_LOSS_T / NAV_DLL_ACT is seen at the next check."""
    rig = Rig(gcs)
    rig.run(2.0)
    t0 = rig.t
    rig.run(t0 + 6.0, hb=False)  # 6 s of silence: within the default 10 s
    assert not rig.core.gcs_failsafe
    i32 = mavlink.MAV_PARAM_TYPE_INT32
    as_f = lambda v: struct.unpack("<f", struct.pack("<i", v))[0]  # noqa: E731 (bytewise)
    rig.send(gcs.frame(mavlink.MAVLink_param_set_message(1, 1, b"NAV_DLL_ACT", as_f(0), i32)))
    rig.send(gcs.frame(mavlink.MAVLink_param_set_message(1, 1, b"COM_DL_LOSS_T", as_f(5), i32)))
    rig.run(rig.t + 0.05, hb=False)
    assert not rig.core.gcs_failsafe  # NAV_DLL_ACT = 0: disabled
    rig.send(gcs.frame(mavlink.MAVLink_param_set_message(1, 1, b"NAV_DLL_ACT", as_f(2), i32)))
    rig.run(rig.t + 0.05, hb=False)
    assert rig.core.gcs_failsafe


def test_f32_norm_overflow_fast_check_matches_the_float32_reference():
    """personality.px4._f32_norm_overflows (Python floats below 1e18) against the float32
    arithmetic it stands for, on magnitudes from metres to beyond FLT_MAX, NaN and inf."""
    from vehicle_emu.personality.px4 import _f32_norm_overflows, _f32_norm_overflows_ref

    rng = np.random.default_rng(3)
    exps = rng.uniform(-3, 40, (4000, 2))
    vals = np.sign(rng.uniform(-1, 1, (4000, 2))) * 10.0**exps
    vals[::97, 0] = np.nan
    vals[::89, 1] = np.inf
    edge = [(1e18, 1e18), (1.3e19, 1.3e19), (1.9e19, 0.0), (-1.8e19, 1e3), (3.5e38, 0.0)]
    cases = [tuple(v) for v in vals.tolist()] + edge
    got = [_f32_norm_overflows(v) for v in cases]
    assert got == [_f32_norm_overflows_ref(v) for v in cases]
    assert any(got) and not all(got)

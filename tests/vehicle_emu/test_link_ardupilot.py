"""ArduPilot Copter personality: modes, arming, takeoff, setpoints, timeouts, failsafe."""

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from vehicle_emu import events as ev
from vehicle_emu.link import VehicleCore

from emu_helpers import GCS_ADDR, acks, of_type

ACCEPTED, FAILED = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_FAILED


class Rig:
    """A core with its own physics, a fake GCS and an explicit clock."""

    def __init__(self, gcs, **kw):
        self.gcs = gcs
        self.t = 0.0
        self.core = VehicleCore(1, "ardupilot", origin_lla=(47.5, 8.5, 400.0), **kw)

    def send(self, data):
        self.core.receive_datagram(data, GCS_ADDR, self.t)
        return self.gcs.decode(self.core.datagrams_to_send(self.t))

    def run(self, until_s, hb_period_s=None, on_msg=None):
        out = []
        next_hb = self.t
        while self.t < until_s - 1e-9:
            self.t = round(self.t + 0.05, 6)
            if hb_period_s is not None and self.t >= next_hb:
                self.core.receive_datagram(self.gcs.heartbeat(), GCS_ADDR, self.t)
                self.last_hb_t = self.t
                next_hb = self.t + hb_period_s
            self.core.handle_timer(self.t)
            msgs = self.gcs.decode(self.core.datagrams_to_send(self.t))
            if on_msg:
                for m in msgs:
                    on_msg(m)
            out += msgs
        return out

    def events(self):
        out = []
        while (e := self.core.next_event()) is not None:
            out.append(e)
        return out

    def guided_armed_at(self, alt_m=10.0):
        assert acks(self.send(self.gcs.command(176, 1, 4)), 176) == [ACCEPTED]
        assert acks(self.send(self.gcs.command(400, 1)), 400) == [ACCEPTED]
        assert acks(self.send(self.gcs.command(22, 0, 0, 0, 0, 0, 0, alt_m)), 22) == [ACCEPTED]
        self.run(self.t + alt_m / 2.5 + 4, hb_period_s=1.0)
        assert self.core.local_pos_ned_m[2] == pytest.approx(-alt_m, abs=0.2)


def test_only_heartbeat_until_streams_requested(gcs):
    rig = Rig(gcs)
    msgs = rig.run(5.0)
    assert {m.get_type() for m in msgs} == {"HEARTBEAT"}
    assert 4 <= len(msgs) <= 6  # 1 Hz
    hb = msgs[0]
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR and hb.custom_mode == 0  # STABILIZE
    assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def test_set_message_interval_and_request_data_stream(gcs):
    rig = Rig(gcs)
    assert acks(rig.send(gcs.command(511, 33, 200_000)), 511) == [ACCEPTED]  # 5 Hz
    msgs = rig.run(2.0)
    assert 9 <= len(of_type(msgs, "GLOBAL_POSITION_INT")) <= 11
    rig.send(
        gcs.frame(
            mavlink.MAVLink_request_data_stream_message(
                1, 1, mavlink.MAV_DATA_STREAM_EXTENDED_STATUS, 2, 1
            )
        )
    )
    msgs = rig.run(4.0)
    assert 3 <= len(of_type(msgs, "SYS_STATUS")) <= 5
    assert 3 <= len(of_type(msgs, "GPS_RAW_INT")) <= 5
    assert acks(rig.send(gcs.command(511, 33, -1)), 511) == [ACCEPTED]
    assert not of_type(rig.run(5.0), "GLOBAL_POSITION_INT")
    # one-shot REQUEST_MESSAGE: ACK first, then the message
    out = rig.send(gcs.command(512, 242))
    assert [m.get_type() for m in out] == ["COMMAND_ACK", "HOME_POSITION"]
    assert out[1].latitude == 475000000 and out[1].altitude == 400000
    out = rig.send(gcs.command(520, 1))
    av = of_type(out, "AUTOPILOT_VERSION")[0]
    assert av.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    # ArduPilot handle_command_request_message: unknown message id -> MAV_RESULT_FAILED
    assert acks(rig.send(gcs.command(512, 9999)), 512) == [mavlink.MAV_RESULT_FAILED]


def test_mode_arm_takeoff_rules(gcs):
    rig = Rig(gcs)
    # takeoff refused while disarmed
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, 10)), 22) == [FAILED]
    # RTL / LAND are not armable modes (ArduCopter Mode::allows_arming)
    assert acks(rig.send(gcs.command(176, 1, 6)), 176) == [ACCEPTED]
    assert acks(rig.send(gcs.command(400, 1)), 400) == [FAILED]
    # unknown mode number
    assert acks(rig.send(gcs.command(176, 1, 42)), 176) == [FAILED]
    # SET_MODE message is acked with command = 11 (ArduPilot quirk)
    out = rig.send(gcs.frame(mavlink.MAVLink_set_mode_message(1, 1, 5)))
    assert acks(out, 11) == [ACCEPTED] and rig.core.mode_name == "LOITER"
    # takeoff refused outside GUIDED even when armed
    assert acks(rig.send(gcs.command(400, 1)), 400) == [ACCEPTED]
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, 10)), 22) == [FAILED]
    assert acks(rig.send(gcs.command(176, 1, 4)), 176) == [ACCEPTED]
    # takeoff downwards refused
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, -1)), 22) == [FAILED]
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, 10)), 22) == [ACCEPTED]
    climb = []
    rig.run(
        2.0,
        hb_period_s=1.0,
        on_msg=lambda m: climb.append(m) if m.get_type() == "HEARTBEAT" else None,
    )
    assert climb[-1].base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED and climb[-1].custom_mode == 4
    assert not rig.core.landed
    # a second takeoff while flying is refused ("can't takeoff again")
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, 20)), 22) == [FAILED]
    # disarm in flight refused without force
    assert acks(rig.send(gcs.command(400, 0)), 400) == [FAILED]
    names = [type(e).__name__ for e in rig.events()]
    assert "ModeChanged" in names and "ArmingChanged" in names and "TakeoffStarted" in names


def test_auto_disarm_without_takeoff(gcs):
    rig = Rig(gcs)
    rig.send(gcs.command(176, 1, 4))
    assert acks(rig.send(gcs.command(400, 1)), 400) == [ACCEPTED]
    rig.run(9.5, hb_period_s=1.0)
    assert rig.core.armed
    rig.run(10.6, hb_period_s=1.0)
    assert not rig.core.armed
    assert any(isinstance(e, ev.ArmingChanged) and e.reason == "auto_disarm" for e in rig.events())


def test_setpoint_rules_local_frames_and_masks(gcs):
    rig = Rig(gcs)
    # setpoints ignored outside GUIDED
    rig.send(gcs.local_target(10, 0, -10))
    assert rig.core.stats.setpoints_ignored == 1
    rig.guided_armed_at(10.0)
    # Z masked -> whole position ignored (ArduCopter POS_IGNORE semantics): vehicle holds
    rig.send(gcs.local_target(30, 0, 0, mask=3576 | 0b100))
    rig.run(rig.t + 3, hb_period_s=1.0)
    assert np.allclose(rig.core.local_pos_ned_m, (0, 0, -10), atol=0.3)
    # LOCAL_NED position target: relative to the EKF origin
    rig.send(gcs.local_target(20, -10, -15))
    rig.run(rig.t + 10, hb_period_s=1.0)
    assert np.allclose(rig.core.local_pos_ned_m, (20, -10, -15), atol=0.2)
    # LOCAL_OFFSET_NED: relative to the current position
    rig.send(gcs.local_target(5, 5, 0, frame=mavlink.MAV_FRAME_LOCAL_OFFSET_NED))
    rig.run(rig.t + 6, hb_period_s=1.0)
    assert np.allclose(rig.core.local_pos_ned_m, (25, -5, -15), atol=0.2)
    # POSITION_TARGET_LOCAL_NED reports the target
    rig.send(gcs.command(511, 85, 500_000))
    pt = of_type(rig.run(rig.t + 1, hb_period_s=1.0), "POSITION_TARGET_LOCAL_NED")[-1]
    assert (pt.x, pt.y, pt.z) == pytest.approx((25, -5, -15), abs=0.2)
    # position targets persist (no GUID_TIMEOUT for them)
    rig.run(rig.t + 20, hb_period_s=1.0)
    assert np.allclose(rig.core.local_pos_ned_m, (25, -5, -15), atol=0.2)


def test_global_int_frames(gcs):
    rig = Rig(gcs)
    rig.guided_armed_at(10.0)
    from planner.geometry import ned_to_geodetic

    lat, lon, _ = ned_to_geodetic(np.array([30.0, 20.0, 0.0]), 47.5, 8.5, 400.0)
    msg = mavlink.MAVLink_set_position_target_global_int_message(
        0,
        1,
        1,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        3576,
        int(round(float(lat) * 1e7)),
        int(round(float(lon) * 1e7)),
        12.0,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
    )
    rig.send(gcs.frame(msg))
    rig.run(rig.t + 10, hb_period_s=1.0)
    assert np.allclose(rig.core.local_pos_ned_m, (30, 20, -12), atol=0.2)
    msg = mavlink.MAVLink_set_position_target_global_int_message(
        0,
        1,
        1,
        mavlink.MAV_FRAME_GLOBAL_INT,
        3576,
        int(round(float(lat) * 1e7)),
        int(round(float(lon) * 1e7)),
        420.0,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
    )  # AMSL
    rig.send(gcs.frame(msg))
    rig.run(rig.t + 6, hb_period_s=1.0)
    assert rig.core.local_pos_ned_m[2] == pytest.approx(-20, abs=0.2)


def test_velocity_target_stops_after_guid_timeout(gcs):
    rig = Rig(gcs)
    rig.guided_armed_at(10.0)
    start = rig.core.local_pos_ned_m.copy()
    rig.send(gcs.local_target(0, 0, 0, mask=3527, vx=2.0))
    t_cmd = rig.t
    speeds = []
    rig.run(t_cmd + 2.9, hb_period_s=1.0)
    moving = rig.core.physics.vel_ned_m_s[0, 0]
    assert moving == pytest.approx(2.0, abs=0.05)
    rig.run(t_cmd + 5.0, hb_period_s=1.0)  # GUID_TIMEOUT = 3 s
    assert abs(rig.core.physics.vel_ned_m_s[0, 0]) < 0.05
    moved = rig.core.local_pos_ned_m[0] - start[0]
    assert 5.5 < moved < 7.0  # ~3 s at 2 m/s, then stopped
    pos = rig.core.local_pos_ned_m.copy()
    rig.run(rig.t + 5, hb_period_s=1.0)
    assert np.allclose(rig.core.local_pos_ned_m, pos, atol=0.05)
    del speeds


def test_gcs_failsafe_rtl_home_and_stays_in_rtl(gcs):
    rig = Rig(gcs)
    # Not active before the first GCS heartbeat: no failsafe even after a long time.
    rig.run(10.0)
    assert not rig.core.gcs_failsafe
    rig.guided_armed_at(10.0)
    rig.send(gcs.local_target(60, 0, -10))
    rig.run(rig.t + 10, hb_period_s=1.0)
    t_last_hb = rig.last_hb_t
    rig.run(t_last_hb + 4.9)  # heartbeats stop
    assert rig.core.mode_name == "GUIDED"
    rig.run(t_last_hb + 5.2)
    assert rig.core.mode_name == "RTL" and rig.core.gcs_failsafe
    fs = [e for e in rig.events() if isinstance(e, ev.FailsafeTriggered)]
    assert fs and fs[0].action == "RTL" and 5.0 < fs[0].t_s - t_last_hb <= 5.1
    d0 = np.hypot(*rig.core.local_pos_ned_m[:2])
    rig.run(rig.t + 6)  # climbs to RTL_ALT (15 m) first, then flies home at WPNAV_SPEED
    assert rig.core.local_pos_ned_m[2] == pytest.approx(-15, abs=0.3)
    d1 = np.hypot(*rig.core.local_pos_ned_m[:2])
    assert d1 < d0 - 10  # heading home
    # GCS comes back: failsafe clears but the vehicle stays in RTL; ArduCopter says so at
    # WARNING (ArduCopter/events.cpp Copter::failsafe_gcs_off_event).
    out = rig.run(rig.t + 2, hb_period_s=1.0)
    assert not rig.core.gcs_failsafe and rig.core.mode_name == "RTL"
    texts = [(m.severity, m.text) for m in of_type(out, "STATUSTEXT")]
    assert texts == [(mavlink.MAV_SEVERITY_WARNING, "GCS Failsafe Cleared")]
    rig.run(rig.t + 40, hb_period_s=1.0)
    assert np.hypot(*rig.core.local_pos_ned_m[:2]) < 1.0
    assert rig.core.landed and not rig.core.armed  # RTL_ALT_FINAL = 0: land and disarm
    # and a GCS can take it back
    assert acks(rig.send(gcs.command(176, 1, 4)), 176) == [ACCEPTED]


def _gcs_lost_in(gcs, mode: int, fs_options: int) -> Rig:
    """A copter flying at 10 m in ``mode`` whose GCS heartbeats stop for 6 s (> 5 s)."""
    rig = Rig(gcs, params={"FS_OPTIONS": fs_options})
    rig.run(1.0, hb_period_s=1.0)
    rig.guided_armed_at(10.0)
    if mode == 3:
        # The emulator refuses AUTO on the wire (it flies no missions): entered directly to
        # check the failsafe rule for it.
        rig.core._set_mode(mode, rig.t, "test")
    elif mode != 4:
        assert acks(rig.send(gcs.command(176, 1, mode)), 176) == [ACCEPTED]
    rig.run(rig.t + 1.0, hb_period_s=1.0)
    rig.events()
    rig.run(rig.last_hb_t + 6.0)
    assert rig.core.gcs_failsafe and rig.core.armed
    return rig


# ArduCopter/events.cpp Copter::failsafe_gcs_on_event: FS_OPTIONS bit 1 (2) continues AUTO,
# bit 4 (16) continues modes that are not ``is_autopilot()`` (mode.h: LOITER, ALT_HOLD, ...).
# Bit 2 (4) is RC_CONTINUE_IF_GUIDED, the RC failsafe only: GUIDED gets the FS_GCS_ENABLE action
# (1, RTL) whatever FS_OPTIONS says.
@pytest.mark.parametrize(
    "mode, fs_options, after",
    [
        (4, 4, "RTL"),
        (4, 2 | 4 | 16, "RTL"),  # GUIDED: no bit keeps it
        (5, 16, "LOITER"),
        (5, 0, "RTL"),
        (5, 4, "RTL"),  # LOITER: pilot-controlled, bit 4 only
        (3, 2, "AUTO"),
        (3, 16, "RTL"),  # AUTO: bit 1 only (is_autopilot)
    ],
)
def test_gcs_failsafe_fs_options(gcs, mode, fs_options, after):
    rig = _gcs_lost_in(gcs, mode, fs_options)
    assert rig.core.mode_name == after
    fs = [e for e in rig.events() if isinstance(e, ev.FailsafeTriggered)]
    assert [(e.kind, e.action) for e in fs] == [("gcs", "NONE" if after != "RTL" else "RTL")]


def test_failsafe_ignores_heartbeats_from_other_sysids():
    from emu_helpers import FakeGcs

    rig = Rig(FakeGcs(sysid=254))
    rig.run(2.0, hb_period_s=1.0)
    assert rig.core.stats.gcs_heartbeats == 0  # only SYSID_MYGCS (255) counts


def test_param_protocol(gcs):
    rig = Rig(gcs)
    out = rig.send(gcs.frame(mavlink.MAVLink_param_request_list_message(1, 1)))
    pv = of_type(out, "PARAM_VALUE")
    names = [p.param_id for p in pv]
    assert {
        "SYSID_THISMAV",
        "FS_GCS_ENABLE",
        "FS_GCS_TIMEOUT",
        "GUID_TIMEOUT",
        "WPNAV_SPEED",
    } <= set(names)
    assert all(p.param_count == len(pv) for p in pv)
    out = rig.send(
        gcs.frame(
            mavlink.MAVLink_param_set_message(
                1, 1, b"WPNAV_SPEED", 300.0, mavlink.MAV_PARAM_TYPE_REAL32
            )
        )
    )
    assert of_type(out, "PARAM_VALUE")[0].param_value == 300.0
    out = rig.send(gcs.frame(mavlink.MAVLink_param_request_read_message(1, 1, b"GUID_TIMEOUT", -1)))
    assert of_type(out, "PARAM_VALUE")[0].param_value == pytest.approx(3.0)
    # the new speed limit is flown
    rig.guided_armed_at(10.0)
    rig.send(gcs.local_target(50, 0, -10))
    top = []
    rig.run(rig.t + 5, hb_period_s=1.0, on_msg=lambda m: None)
    top.append(np.hypot(*rig.core.physics.vel_ned_m_s[0, :2]))
    assert max(top) <= 3.0 + 1e-9


def test_timesync_and_ping(gcs):
    rig = Rig(gcs)
    rig.t = 2.0
    out = rig.send(gcs.frame(mavlink.MAVLink_timesync_message(0, 123456)))
    ts = of_type(out, "TIMESYNC")[0]
    assert ts.ts1 == 123456 and ts.tc1 == 2_000_000_000
    out = rig.send(gcs.frame(mavlink.MAVLink_ping_message(77, 5, 0, 0)))
    p = of_type(out, "PING")[0]
    assert (p.time_usec, p.seq, p.target_system) == (77, 5, 255)


def test_commands_for_other_sysids_are_ignored(gcs):
    rig = Rig(gcs)
    out = rig.send(gcs.command(400, 1, target=7))
    assert out == [] and rig.core.stats.not_for_us == 1 and not rig.core.armed


def test_guided_again_during_the_takeoff_climb_changes_nothing(gcs):
    # A GCS that retries its DO_SET_MODE(GUIDED) while the take-off climbs (its first ACK came
    # late) must not stop the climb: ArduCopter Copter::set_mode returns at once for the current
    # mode. The emulator once re-entered GUIDED, held at 1.4 m, and refused every later take-off.
    rig = Rig(gcs)
    assert acks(rig.send(gcs.command(176, 1, 4)), 176) == [ACCEPTED]
    assert acks(rig.send(gcs.command(400, 1)), 400) == [ACCEPTED]
    assert acks(rig.send(gcs.command(22, 0, 0, 0, 0, 0, 0, 10)), 22) == [ACCEPTED]
    rig.run(0.6, hb_period_s=1.0)
    assert 0.0 < -rig.core.local_pos_ned_m[2] < 5.0
    rig.events()
    assert acks(rig.send(gcs.command(176, 1, 4)), 176) == [ACCEPTED]
    assert not any(type(e).__name__ == "ModeChanged" for e in rig.events())
    rig.run(rig.t + 10.0 / 2.5 + 4, hb_period_s=1.0)
    assert rig.core.local_pos_ned_m[2] == pytest.approx(-10.0, abs=0.2)


def _param_set(gcs, name: bytes, value: float, ptype: int) -> bytes:
    return gcs.frame(mavlink.MAVLink_param_set_message(1, 1, name, value, ptype))


def test_param_set_of_the_gcs_failsafe_takes_effect_at_once(gcs):
    """The core keeps ``gcs_failsafe_config`` between parameter changes: a PARAM_SET of
    FS_GCS_TIMEOUT / FS_GCS_ENABLE (or a local ``params.set``) must be seen on the next check."""
    rig = Rig(gcs)
    rig.run(1.0, hb_period_s=1.0)
    rig.guided_armed_at(10.0)
    rig.run(rig.t + 1.0, hb_period_s=1.0)
    rig.events()
    t_hb = rig.last_hb_t
    rig.run(t_hb + 3.0)  # 3 s of silence: within the default 5 s
    assert not rig.core.gcs_failsafe
    rig.send(_param_set(gcs, b"FS_GCS_TIMEOUT", 2.0, mavlink.MAV_PARAM_TYPE_REAL32))
    rig.run(rig.t + 0.05)  # the next tick sees the 2 s timeout
    assert rig.core.gcs_failsafe and rig.core.mode_name == "RTL"
    # disabled: the failsafe flag drops at the next check (the mode stays)
    rig.send(_param_set(gcs, b"FS_GCS_ENABLE", 0, mavlink.MAV_PARAM_TYPE_INT8))
    rig.run(rig.t + 0.05)
    assert not rig.core.gcs_failsafe
    # a local change of the table counts as well
    rig.core.params.set("FS_GCS_ENABLE", 1)
    rig.run(rig.t + 0.05)
    assert rig.core.gcs_failsafe
    rig.core.params.set("FS_GCS_TIMEOUT", 100.0)
    rig.run(rig.t + 0.05)
    assert not rig.core.gcs_failsafe  # not lost any more under a 100 s timeout
    kinds = [type(e).__name__ for e in rig.events()]
    assert kinds.count("FailsafeTriggered") == 2 and kinds.count("GcsLinkRegained") == 1

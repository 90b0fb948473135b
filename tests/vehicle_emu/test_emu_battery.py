"""Batteries in the emulator (docs/design/endurance.md §6): the drain and voltage model, each
firmware's telemetry and failsafes, and the battery swap's power cycle. In memory, explicit time."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from vehicle_emu import events as ev
from vehicle_emu.battery import (
    BatteryConfig,
    SwapConfig,
    battery_step,
    battery_step_reference,
    ocv_cell_v,
)
from vehicle_emu.link import VehicleCore, px4_custom_mode
from vehicle_emu.physics import Physics
from vehicle_emu.swarm import Swarm

from emu_helpers import GCS_ADDR, FakeGcs, of_type

CFG = BatteryConfig(capacity_mah=3000.0, cells=4, hover_endurance_s=1200.0, ref_speed_m_s=10.0)


# -- the model ---------------------------------------------------------------------------------


def test_battery_step_matches_its_reference(rng):
    n = 64
    consumed = rng.uniform(0, 3500, n)
    energy = rng.uniform(0, 40, n)
    vel = rng.normal(0, 6, (n, 3))
    drawing = rng.random(n) < 0.7
    fast = battery_step(CFG, consumed, energy, vel, drawing, 0.05)
    slow = battery_step_reference(CFG, consumed, energy, vel, drawing, 0.05)
    for a, b in zip(fast, slow):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_hover_drains_capacity_over_endurance_and_voltage_sags_by_ir():
    ph = Physics(np.zeros((2, 3)))
    batt = ph.enable_battery(CFG)
    ph.armed[0] = True  # row 1 disarmed on the ground: no drain
    ph.step(600.0)  # hovering on the ground counts as hover (armed, motors running)
    i_hover = CFG.capacity_mah * 3.6 / CFG.hover_endurance_s
    assert batt.current_a[0] == pytest.approx(i_hover)
    assert batt.consumed_mah[0] == pytest.approx(CFG.capacity_mah * 600.0 / 1200.0)
    assert ph.battery_frac[0] == pytest.approx(0.5)
    expect_v = CFG.cells * float(ocv_cell_v(0.5)) - i_hover * CFG.internal_resistance_ohm
    assert batt.voltage_v[0] == pytest.approx(expect_v)
    assert batt.consumed_mah[1] == 0.0 and batt.current_a[1] == 0.0
    assert batt.voltage_v[1] == pytest.approx(CFG.cells * 4.2)
    assert batt.energy_wh[0] == pytest.approx(expect_v * i_hover * 600 / 3600, rel=0.05)


def test_speed_and_climb_raise_the_current():
    ph = Physics(np.zeros((3, 3)), max_speed_h_m_s=10.0)
    batt = ph.enable_battery(CFG)
    ph.armed[:] = True
    ph.command_velocity(0, (0.0, 0.0, -2.0))  # off the ground first (landed ones do not slide)
    ph.command_velocity(1, (0.0, 0.0, -2.5))  # climbing at the reference rate
    ph.command_position(2, (0.0, 0.0, -5.0))
    ph.step(1.0)
    ph.command_velocity(0, (10.0, 0.0, 0.0))
    ph.step(5.0)
    i_hover = CFG.hover_current_a
    v = ph.vel_ned_m_s
    speed0 = math.hypot(v[0, 0], v[0, 1])
    assert speed0 == pytest.approx(10.0, rel=1e-3)
    assert batt.current_a[0] == pytest.approx(i_hover * (1 + 0.3 * (speed0 / 10.0) ** 2), rel=1e-3)
    assert batt.current_a[1] == pytest.approx(i_hover * (1 + 0.5 * (-v[1, 2]) / 2.5), rel=1e-3)
    assert batt.current_a[1] > i_hover * 1.4


def test_batteries_off_physics_is_unchanged():
    a, b = Physics(np.zeros((2, 3))), Physics(np.zeros((2, 3)))
    b.enable_battery(CFG)
    for ph in (a, b):
        ph.armed[:] = True
        ph.command_position(0, (30.0, 5.0, -10.0))
        ph.step(7.3)
    np.testing.assert_array_equal(a.pos_ned_m, b.pos_ned_m)
    np.testing.assert_array_equal(a.battery_frac, np.ones(2))
    assert a.battery is None and (b.battery_frac < 1).all()


# -- a vehicle with a battery ------------------------------------------------------------------


class Rig:
    """One core on its own physics with a battery, a GCS heartbeating at 1 Hz."""

    def __init__(self, personality, battery=CFG, **kw):
        self.gcs = FakeGcs()
        self.t = 0.0
        self.core = VehicleCore(
            1, personality, origin_lla=(47.5, 8.5, 400.0), battery=battery, **kw
        )
        self.msgs: list = []

    def send(self, data):
        self.core.receive_datagram(data, GCS_ADDR, self.t)

    def run(self, until_s, step_s=0.1):
        while self.t < until_s - 1e-9:
            self.t = round(self.t + step_s, 6)
            if abs(self.t - round(self.t)) < 1e-9:
                self.send(self.gcs.heartbeat())
            self.core.handle_timer(self.t)
            self.msgs += self.gcs.decode(self.core.datagrams_to_send(self.t))

    def fly(self, alt_m=10.0):
        """Arm in the guided mode and climb (ArduPilot GUIDED + takeoff; PX4 takeoff)."""
        if self.core.personality == "ardupilot":
            self.send(self.gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 4))
            self.send(self.gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
            self.send(self.gcs.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_m))
        else:
            self.send(self.gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
            self.send(
                self.gcs.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 400.0 + alt_m)
            )
        self.run(self.t + 8.0)
        assert self.core.armed and not self.core.landed

    def drain_to(self, consumed_mah):
        """Jump the pack's consumed charge (the truth) to ``consumed_mah``."""
        self.core.physics.battery.consumed_mah[0] = consumed_mah

    def texts(self):
        return [m.text for m in of_type(self.msgs, "STATUSTEXT")]


def _request(rig, msg_id):
    rig.send(rig.gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, msg_id))
    return [m for m in rig.gcs.decode(rig.core.datagrams_to_send(rig.t))]


def test_ardupilot_sys_status_and_battery_status_fields():
    rig = Rig("ardupilot")
    rig.fly()
    rig.drain_to(1000.0)
    rig.run(rig.t + 0.2)
    batt = rig.core.physics.battery
    v, i = float(batt.voltage_v[0]), float(batt.current_a[0])
    used = float(batt.consumed_mah[0])
    ss = of_type(_request(rig, mavlink.MAVLINK_MSG_ID_SYS_STATUS), "SYS_STATUS")[0]
    assert ss.voltage_battery == int(v * 1000)
    assert ss.current_battery == int(i * 100) and ss.current_battery > 0
    # AP capacity_remaining_pct: 100 (capacity - used) / capacity, truncated (BATT_CAPACITY).
    assert ss.battery_remaining == int(100 * (3000 - used) / 3000) == 66
    bit = mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
    assert ss.onboard_control_sensors_present & bit and ss.onboard_control_sensors_health & bit
    bs = of_type(_request(rig, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS), "BATTERY_STATUS")[0]
    assert bs.voltages[0] == int(v * 1000) and set(bs.voltages[1:]) == {65535}
    assert list(bs.voltages_ext) == [0, 0, 0, 0]
    assert bs.current_consumed == int(used)
    assert bs.energy_consumed == int(float(batt.energy_wh[0]) * 36)
    assert bs.battery_remaining == 66 and bs.time_remaining == 0
    assert bs.charge_state == mavlink.MAV_BATTERY_CHARGE_STATE_OK
    assert bs.battery_function == mavlink.MAV_BATTERY_FUNCTION_UNKNOWN
    assert bs.temperature == 32767


def test_ardupilot_battery_status_streams_only_when_asked_in_extra3():
    rig = Rig("ardupilot")
    rig.run(3.0)
    assert not of_type(rig.msgs, "BATTERY_STATUS")
    rig.send(
        rig.gcs.frame(
            mavlink.MAVLink_request_data_stream_message(1, 1, mavlink.MAV_DATA_STREAM_EXTRA3, 2, 1)
        )
    )
    rig.run(6.0)
    assert 5 <= len(of_type(rig.msgs, "BATTERY_STATUS")) <= 7


def test_px4_fields_and_default_streams():
    rig = Rig("px4")
    rig.fly()
    rig.drain_to(1000.0)
    rig.msgs.clear()
    rig.run(rig.t + 10.0)
    bs = of_type(rig.msgs, "BATTERY_STATUS")
    ss = of_type(rig.msgs, "SYS_STATUS")
    assert len(bs) == 5 and 9 <= len(ss) <= 11  # 0.5 Hz and 1 Hz unasked
    batt = rig.core.physics.battery
    used = float(batt.consumed_mah[0])
    last = bs[-1]
    assert last.battery_remaining == math.ceil(100 * (1 - used / 3000))
    assert last.battery_function == mavlink.MAV_BATTERY_FUNCTION_ALL
    assert last.type == mavlink.MAV_BATTERY_TYPE_LIPO
    assert last.energy_consumed == -1
    assert set(last.voltages[1:]) == {65535} and list(last.voltages_ext) == [65535] * 4
    t_rem = (1 - used / 3000) * 3000 * 3.6 / float(batt.current_a[0])
    assert abs(last.time_remaining - t_rem) <= 2
    assert ss[-1].battery_remaining == last.battery_remaining


def test_batteries_off_keep_the_old_sys_status_and_have_no_battery_status():
    rig = Rig("ardupilot", battery=None)
    assert rig.core.batt is None and "BATT_CAPACITY" not in rig.core.params
    out = _request(rig, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS)
    acks = [m.result for m in of_type(out, "COMMAND_ACK")]
    assert acks == [mavlink.MAV_RESULT_FAILED] and not of_type(out, "BATTERY_STATUS")
    ss = of_type(_request(rig, mavlink.MAVLINK_MSG_ID_SYS_STATUS), "SYS_STATUS")[0]
    assert (ss.voltage_battery, ss.current_battery, ss.battery_remaining) == (12600, -1, 100)


# -- the failsafes -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "action, mode",
    [(0, "GUIDED"), (1, "LAND"), (2, "RTL"), (3, "SMART_RTL"), (7, "BRAKE")],
)
def test_ardupilot_low_mah_failsafe_action(action, mode):
    rig = Rig("ardupilot", params={"BATT_LOW_MAH": 600, "BATT_FS_LOW_ACT": action})
    rig.fly()
    rig.drain_to(2390.0)  # 610 mAh left: not yet (strict <)
    rig.run(rig.t + 1.0)
    assert rig.core.batt.failsafe == 0 and rig.core.mode_name == "GUIDED"
    rig.drain_to(2410.0)
    rig.run(rig.t + 0.3)
    texts = rig.texts()
    assert any(t.startswith("Battery 1 is low ") and t.endswith("used 2410 mAh") for t in texts)
    assert "Battery Failsafe" in texts
    assert rig.core.mode_name == mode
    evs = []
    while (e := rig.core.next_event()) is not None:
        evs.append(e)
    fs = [e for e in evs if isinstance(e, ev.FailsafeTriggered)]
    assert [(e.kind, e.action) for e in fs] == [("battery_low", mode if action else "NONE")]
    bs = of_type(_request(rig, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS), "BATTERY_STATUS")[0]
    assert bs.charge_state == mavlink.MAV_BATTERY_CHARGE_STATE_LOW
    ss = of_type(_request(rig, mavlink.MAVLINK_MSG_ID_SYS_STATUS), "SYS_STATUS")[0]
    assert not ss.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_BATTERY


def test_ardupilot_low_voltage_needs_batt_low_timer_and_critical_escalates():
    rig = Rig(
        "ardupilot",
        battery=BatteryConfig(capacity_mah=3000.0, cells=3, hover_endurance_s=1200.0),
        params={"BATT_FS_LOW_ACT": 2, "BATT_CRT_MAH": 300, "BATT_FS_CRT_ACT": 1},
    )
    rig.fly()
    rig.drain_to(2930.0)  # OCV ~3.6 V a cell, under load below BATT_LOW_VOLT 10.5 V
    rig.run(rig.t + 0.2)
    assert rig.core.physics.battery.voltage_v[0] < 10.5
    t_below = rig.t
    rig.drain_to(2600.0)  # voltage back up: the timer restarts
    rig.run(rig.t + 5.0)
    rig.drain_to(2930.0)
    t_below = rig.t
    rig.run(t_below + 9.5)
    # the crit mAh failsafe (300 left) fires at once; it outranks the pending low voltage
    assert rig.core.batt.failsafe == 2 and rig.core.mode_name == "LAND"
    assert any(t.startswith("Battery 1 is critical ") for t in rig.texts())


def test_ardupilot_low_voltage_timer():
    rig = Rig(
        "ardupilot",
        battery=BatteryConfig(capacity_mah=3000.0, cells=3, hover_endurance_s=1200.0),
        params={"BATT_FS_LOW_ACT": 2},
    )
    rig.fly()
    rig.drain_to(2930.0)
    rig.run(rig.t + 0.1)
    t0 = rig.t
    rig.run(t0 + 9.9)
    assert rig.core.batt.failsafe == 0
    rig.run(t0 + 10.3)
    assert rig.core.batt.failsafe == 1 and rig.core.mode_name == "RTL"


def test_ardupilot_failsafe_disarmed_does_nothing():
    rig = Rig("ardupilot", params={"BATT_LOW_MAH": 600, "BATT_FS_LOW_ACT": 2})
    rig.drain_to(2900.0)
    rig.run(3.0)
    assert rig.core.batt.failsafe == 0 and not rig.texts()


@pytest.mark.parametrize(
    "act, crit_mode, emerg_mode",
    [(0, None, None), (2, (4, 6), (4, 6)), (3, (4, 5), (4, 6))],
)
def test_px4_warning_levels_and_com_low_bat_act(act, crit_mode, emerg_mode):
    rig = Rig("px4", params={"COM_LOW_BAT_ACT": act})
    rig.fly()
    start = rig.core.custom_mode
    rig.drain_to(3000 * (1 - 0.14))  # below BAT_LOW_THR 0.15: warn only
    rig.run(rig.t + 0.3)
    assert rig.core.batt.warning == 1 and rig.core.custom_mode == start
    assert "Low battery level, return advised" in rig.texts()
    rig.drain_to(3000 * (1 - 0.06))  # below BAT_CRIT_THR 0.07
    rig.run(rig.t + 0.3)
    expect = start if crit_mode is None else px4_custom_mode(*crit_mode)
    assert rig.core.custom_mode == expect
    if act == 0:
        assert "Critical battery level, land now" in rig.texts()
    bs = of_type(_request(rig, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS), "BATTERY_STATUS")[0]
    assert bs.charge_state == mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL
    if rig.core.landed:
        return
    rig.drain_to(3000 * (1 - 0.04))  # below BAT_EMERGEN_THR 0.05
    rig.run(rig.t + 0.3)
    expect = start if emerg_mode is None else px4_custom_mode(*emerg_mode)
    assert rig.core.custom_mode == expect
    bs = of_type(_request(rig, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS), "BATTERY_STATUS")[0]
    assert bs.charge_state == mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY


def test_px4_armed_with_a_low_battery_does_not_fail_safe_for_that_level():
    rig = Rig("px4", params={"COM_LOW_BAT_ACT": 3})
    rig.drain_to(3000 * (1 - 0.06))  # already critical on the ground
    rig.run(0.5)
    assert rig.core.batt.warning == 2
    rig.fly()
    assert rig.core.mode_name != "AUTO_RTL"
    rig.drain_to(3000 * (1 - 0.04))
    rig.run(rig.t + 0.3)
    assert rig.core.custom_mode == px4_custom_mode(4, 6)  # emergency is worse: land


# -- the swap's power cycle ---------------------------------------------------------------------


def test_swap_power_cycles_the_vehicle():
    gcs = FakeGcs()
    sw = Swarm(
        1,
        personality="ardupilot",
        battery=CFG,
        battery_swap=SwapConfig(swap_time_s=30.0),
        params={"BATT_LOW_MAH": 123},
        stream_rates_hz={mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 2.0},
        gcs_addrs=[GCS_ADDR],
    )
    t = 0.0
    beats: list = []
    positions: list = []

    def run(until):
        nonlocal t
        while t < until - 1e-9:
            t = round(t + 0.05, 6)
            sw.handle_timer(t)
            for m in gcs.decode(sw.datagrams_to_send(t)):
                if m.get_type() == "HEARTBEAT":
                    beats.append(t)
                elif m.get_type() == "GLOBAL_POSITION_INT":
                    positions.append((t, m.time_boot_ms))

    run(5.0)
    assert sw.physics.battery.soc[0] == 1.0 and sw.powered[0]  # a full pack is not swapped
    sw.physics.battery.consumed_mah[0] = 1500.0  # flown and landed at home, disarmed
    n_beats = len(beats)
    run(6.0)
    assert not sw.powered[0]
    t_off = 5.05  # the first tick with a used pack, landed at home
    assert sw.boot_at_s[0] == pytest.approx(t_off + 30.0)
    assert len(beats) == n_beats
    run(t_off + 29.0)
    assert len(beats) == n_beats  # silent through the swap
    assert not sw.radio.active[0]
    run(t_off + 31.0)
    assert sw.powered[0] and len(beats) > n_beats
    t_boot = beats[n_beats]
    assert t_off + 30.0 - 0.05 <= t_boot <= t_off + 30.1
    core = sw.cores[0]
    assert core.params["BATT_LOW_MAH"] == 123  # parameters kept
    assert core.mode_name == "STABILIZE" and not core.armed  # ArduCopter boots in STABILIZE
    assert sw.physics.battery.soc[0] == 1.0
    after = [ms for (tt, ms) in positions if tt > t_boot]
    assert after and after[0] < 2000  # time_boot_ms from 0 again
    out = []
    while (e := sw.next_event()) is not None:
        out.append(type(e).__name__)
    assert out.index("VehiclePoweredOff") < out.index("VehicleBooted")


def test_swap_off_and_batteries_off_never_power_cycle():
    sw = Swarm(1, battery=CFG, battery_swap=None)
    sw.physics.battery.consumed_mah[0] = 1500.0
    t = 0.0
    for _ in range(100):
        t = round(t + 0.05, 6)
        sw.handle_timer(t)
    assert sw.powered[0]
    plain = Swarm(1)
    assert plain.physics.battery is None and plain.battery_swap is None


def test_pack_run_empty_in_the_air_loses_the_vehicle():
    sw = Swarm(1, battery=CFG)
    sw.physics.armed[0] = sw.cores[0].armed = True
    sw.physics.battery.consumed_mah[0] = CFG.capacity_mah - 0.001
    t = 0.0
    for _ in range(5):
        t = round(t + 0.05, 6)
        sw.handle_timer(t)
    assert not sw.alive[0]
    kinds = []
    while (e := sw.next_event()) is not None:
        if isinstance(e, ev.VehicleKilled):
            kinds.append(e.cause)
    assert kinds == ["battery_empty"]

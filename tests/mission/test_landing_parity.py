"""The emulator lands as the station expects it to (docs/design/endurance.md §6.5, §7): each
personality serves the landing parameters at the firmware's defaults and flies its two-stage
descent from them, at the speeds and in the time :mod:`gcs.landing` computes from the same
parameters. In memory, explicit time."""

from __future__ import annotations

import numpy as np
import pytest

from gcs.autopilot import ARDUPILOT, PX4
from gcs.landing import (
    FIRMWARE_DEFAULTS,
    LANDING_PARAMS,
    RTL_ALT_DEFAULTS,
    RTL_ALT_PARAMS,
    landing_descent,
)
from vehicle_emu.link import VehicleCore
from vehicle_emu.physics import CTRL_LAND

CASES = [
    ("ardupilot", ARDUPILOT, {}),
    ("ardupilot", ARDUPILOT, {"LAND_SPEED": 30.0}),
    ("ardupilot", ARDUPILOT, {"LAND_SPEED_HIGH": 250.0, "LAND_ALT_LOW": 500.0}),
    ("ardupilot", ARDUPILOT, {"WPNAV_SPEED_DN": 100.0}),
    ("px4", PX4, {}),
    ("px4", PX4, {"MPC_LAND_SPEED": 0.6}),
    ("px4", PX4, {"MPC_Z_V_AUTO_DN": 1.0}),
    ("px4", PX4, {"MPC_LAND_ALT1": 20.0, "MPC_LAND_ALT2": 2.0}),
]


@pytest.mark.parametrize("name,autopilot", [("ardupilot", ARDUPILOT), ("px4", PX4)])
def test_each_personality_serves_the_landing_parameters_at_the_firmware_defaults(name, autopilot):
    core = VehicleCore(1, name)
    for p in LANDING_PARAMS[autopilot]:
        assert core.params[p] == pytest.approx(FIRMWARE_DEFAULTS[autopilot][p]), p
    # The return altitude a relay sent home by RTL lands from when it is above its layer.
    name_rtl = RTL_ALT_PARAMS[autopilot][0]
    assert core.params[name_rtl] == pytest.approx(RTL_ALT_DEFAULTS[autopilot])


@pytest.mark.parametrize("name,autopilot,params", CASES)
def test_the_emulated_landing_is_the_one_the_station_plans(name, autopilot, params):
    core = VehicleCore(1, name)
    for k, v in params.items():
        core.params.set(k, v)
    core.pers.apply_params()
    ph = core.physics
    expect = landing_descent(autopilot, params)
    for h in np.linspace(0.0, 40.0, 81):
        ph.pos_ned_m[0, 2] = -h
        assert ph.land_descent_m_s()[0] == pytest.approx(expect.speed_m_s(float(h))), h
    # Flown from 50 m: the time the station counts, within the emulator's velocity lag.
    ph.armed[:] = True
    ph.pos_ned_m[0] = [0.0, 0.0, -50.0]
    ph.vel_ned_m_s[0] = 0.0
    ph.target_pos_ned_m[0] = ph.pos_ned_m[0]
    ph.command_land(0)
    assert ph.ctrl[0] == CTRL_LAND
    t = 0.0
    while ph.pos_ned_m[0, 2] < -1e-6 and t < 300.0:
        ph.step(0.1)
        t += 0.1
    assert t == pytest.approx(expect.time_s(50.0), abs=2.0)

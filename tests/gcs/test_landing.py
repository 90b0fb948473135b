"""The firmware's landing descent from the vehicle's own parameters (gcs/landing.py): the
two-stage profiles of ArduCopter and PX4 at their defaults and with other settings, the time
checked against a step-by-step descent."""

from __future__ import annotations

import numpy as np
import pytest

from gcs.autopilot import ARDUPILOT, PX4
from gcs.landing import FIRMWARE_DEFAULTS, LANDING_PARAMS, LandingDescent, landing_descent


def _time_reference(d: LandingDescent, alt_m: float, dh_m: float = 1e-3) -> float:
    """Seconds to descend ``alt_m``, one millimetre at a time at the speed of its height."""
    h = np.arange(0.0, alt_m, dh_m) + 0.5 * dh_m
    return float(sum(dh_m / d.speed_m_s(x) for x in h))


def test_every_landing_parameter_has_its_firmware_default():
    for ap, names in LANDING_PARAMS.items():
        assert set(names) == set(FIRMWARE_DEFAULTS[ap])


def test_ardupilot_defaults_descend_fast_to_land_alt_low_then_at_land_speed():
    d = landing_descent(ARDUPILOT)
    assert (d.fast_m_s, d.slow_alt_m, d.land_alt_m, d.land_m_s) == (1.5, 10.0, 10.0, 0.5)
    assert d.time_s(50.0) == pytest.approx(40.0 / 1.5 + 10.0 / 0.5)
    assert d.time_s(6.0) == pytest.approx(6.0 / 0.5)
    assert d.time_s(0.0) == 0.0


def test_ardupilot_land_speed_high_replaces_wpnav_speed_dn_and_alt_low_is_at_least_1_m():
    d = landing_descent(ARDUPILOT, {"LAND_SPEED_HIGH": 250.0, "WPNAV_SPEED_DN": 100.0})
    assert d.fast_m_s == 2.5
    assert landing_descent(ARDUPILOT, {"WPNAV_SPEED_DN": 100.0}).fast_m_s == 1.0
    # Never slower above LAND_ALT_LOW than below it (mode.cpp: "Don't speed up for landing").
    assert landing_descent(ARDUPILOT, {"WPNAV_SPEED_DN": 30.0, "LAND_SPEED": 60.0}).fast_m_s == 0.6
    assert landing_descent(ARDUPILOT, {"LAND_ALT_LOW": 20.0}).slow_alt_m == 1.0


def test_a_slower_land_speed_takes_longer():
    base = landing_descent(ARDUPILOT).time_s(50.0)
    slow = landing_descent(ARDUPILOT, {"LAND_SPEED": 30.0}).time_s(50.0)
    assert slow == pytest.approx(base + 10.0 / 0.3 - 10.0 / 0.5)
    assert landing_descent(PX4, {"MPC_LAND_SPEED": 0.6}).time_s(50.0) > landing_descent(PX4).time_s(
        50.0
    )


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"MPC_Z_V_AUTO_DN": 1.0},  # the ramp meets the auto-mode limit below MPC_LAND_ALT1
        {"MPC_Z_V_AUTO_DN": 0.5},  # under the landing speed: the limit the whole way
        {"MPC_LAND_ALT1": 3.0},  # ALT1 under ALT2: raised to it (FlightTaskAuto::updateParams)
        {"MPC_LAND_ALT1": 20.0, "MPC_LAND_ALT2": 2.0, "MPC_Z_VEL_MAX_DN": 3.0},
    ],
)
def test_px4_profile_and_time_match_the_firmware_ramp(params):
    d = landing_descent(PX4, params)
    p = {**FIRMWARE_DEFAULTS[PX4], **params}
    lo, hi = p["MPC_LAND_ALT2"], max(p["MPC_LAND_ALT1"], p["MPC_LAND_ALT2"])

    def firmware(h: float) -> float:  # math::interpolate, then the MPC_Z_V_AUTO_DN limit
        k = 1.0 if h >= hi else 0.0 if h <= lo else (h - lo) / (hi - lo)
        v = p["MPC_LAND_SPEED"] + k * (p["MPC_Z_VEL_MAX_DN"] - p["MPC_LAND_SPEED"])
        return min(v, p["MPC_Z_V_AUTO_DN"])

    for h in np.linspace(0.0, 30.0, 301):
        assert d.speed_m_s(float(h)) == pytest.approx(firmware(float(h)))
    for alt in (0.5, 4.0, 7.5, 50.0):
        assert d.time_s(alt) == pytest.approx(_time_reference(d, alt), rel=1e-4)


def test_px4_defaults_from_50_m():
    d = landing_descent(PX4)
    ramp = 5.0 / 0.8 * np.log(1.5 / 0.7)  # 10 m -> 5 m, 1.5 -> 0.7 m/s linear in the height
    assert d.time_s(50.0) == pytest.approx(40.0 / 1.5 + ramp + 5.0 / 0.7)


def test_an_unknown_autopilot_lands_as_ardupilot_defaults_and_bad_profiles_are_refused():
    assert landing_descent(99) == landing_descent(ARDUPILOT)
    with pytest.raises(ValueError):
        LandingDescent(1.5, 5.0, 10.0, 0.5)
    with pytest.raises(ValueError):
        LandingDescent(1.5, 10.0, 5.0, 0.0)

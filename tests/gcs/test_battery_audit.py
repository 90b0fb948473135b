"""The battery-failsafe audit per firmware: what lands a drone where it is at the low level or
does nothing is refused (``require``), only warned about (``warn``), and fixed to a return."""

from __future__ import annotations

import pytest

from gcs import audit
from gcs.autopilot import ARDUPILOT, PX4

AP_OK = {
    "BATT_FS_LOW_ACT": 2.0,
    "BATT_FS_CRT_ACT": 1.0,
    "BATT_LOW_MAH": 1000.0,
    "BATT_LOW_VOLT": 0.0,
    "BATT_CRT_MAH": 500.0,
    "BATT_CRT_VOLT": 0.0,
    "BATT_CAPACITY": 5000.0,
}
PX4_OK = {
    "COM_LOW_BAT_ACT": 3.0,
    "BAT_LOW_THR": 0.25,
    "BAT_CRIT_THR": 0.15,
    "BAT_EMERGEN_THR": 0.07,
}


def _blocking(findings) -> set[str]:
    return {f.param for f in findings if f.severity == "blocking"}


def test_ardupilot_rtl_at_low_is_cleared():
    assert not _blocking(audit.audit_battery(ARDUPILOT, AP_OK, low_frac=0.2))


@pytest.mark.parametrize("act", [0, 1, 4, 5, 7])
def test_ardupilot_low_action_that_lands_or_does_nothing_is_refused(act):
    params = {**AP_OK, "BATT_FS_LOW_ACT": float(act)}
    assert _blocking(audit.audit_battery(ARDUPILOT, params)) == {"BATT_FS_LOW_ACT"}
    assert audit.battery_fixes(ARDUPILOT, params) == (("BATT_FS_LOW_ACT", 2.0),)


def test_ardupilot_low_failsafe_without_threshold_is_refused_and_fixed_from_capacity():
    params = {**AP_OK, "BATT_LOW_MAH": 0.0, "BATT_CRT_MAH": 0.0}
    assert _blocking(audit.audit_battery(ARDUPILOT, params)) == {"BATT_LOW_MAH"}
    assert audit.battery_fixes(ARDUPILOT, params, low_frac=0.2) == (("BATT_LOW_MAH", 1000.0),)


def test_ardupilot_critical_above_low_is_refused():
    params = {**AP_OK, "BATT_CRT_MAH": 1200.0}
    assert "BATT_CRT_MAH" in _blocking(audit.audit_battery(ARDUPILOT, params))


def test_ardupilot_firmware_low_above_mission_low_is_a_warning():
    found = audit.audit_battery(ARDUPILOT, {**AP_OK, "BATT_LOW_MAH": 1500.0}, low_frac=0.2)
    assert any(f.param == "BATT_LOW_MAH" and f.severity == "warning" for f in found)
    assert not _blocking(found)


@pytest.mark.parametrize("act,blocks", [(0, True), (1, False), (2, True), (3, False)])
def test_px4_low_battery_action(act, blocks):
    params = {**PX4_OK, "COM_LOW_BAT_ACT": float(act)}
    assert bool(_blocking(audit.audit_battery(PX4, params))) == blocks
    assert audit.battery_fixes(PX4, params) == ((("COM_LOW_BAT_ACT", 3.0),) if blocks else ())


def test_unread_parameters_block_only_when_batteries_are_required():
    assert _blocking(audit.audit_battery(PX4, {}, battery="require")) == {
        "COM_LOW_BAT_ACT",
        "BAT_CRIT_THR",
    }
    warn = audit.audit_battery(PX4, {}, battery="warn")
    assert warn and not _blocking(warn)
    assert audit.audit_battery(PX4, {}, battery="off") == ()


def test_fleet_verdict_with_battery_modes():
    lost_link_ok = {"FS_GCS_ENABLE": 1.0, "SYSID_MYGCS": 255.0}
    params = {**lost_link_ok, **AP_OK, "BATT_FS_LOW_ACT": 1.0}
    vehicles = {(0, 1): (ARDUPILOT, params)}
    assert not audit.audit_fleet(vehicles, battery="require").cleared_to_fly
    assert audit.audit_fleet(vehicles, battery="warn").cleared_to_fly
    assert audit.audit_fleet(vehicles).cleared_to_fly  # off: lost-link audit only, as before
    over = audit.audit_fleet(vehicles, battery="require", override=True)
    assert over.cleared_to_fly and over.overridden

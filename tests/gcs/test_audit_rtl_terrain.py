"""Over terrain the firmware's own return must clear the ground (gcs/audit.py
``audit_rtl_altitude``, docs/terrain.md §6.2): RTL climbs to its return altitude above home and
flies a straight line home, so that altitude must clear the highest ground of the operating area.
Pure functions over parameter dicts and a synthetic DEM."""

from __future__ import annotations

import pytest

from gcs.audit import (
    BLOCKING,
    INFO,
    audit_fleet,
    audit_rtl_altitude,
    rtl_altitude_fixes,
)
from gcs.autopilot import ARDUPILOT, PX4
from gcs.control import Geofence, TerrainAltitude
from planner.terrain import Hill, synthetic_terrain

BASE_AMSL_M = 500.0
# A 70 m hill 250 m east of the base, on the plane of the base's ground.
HILL = synthetic_terrain([Hill((0.0, 250.0), 70.0, 90.0)], 800.0, 10.0, BASE_AMSL_M)


def test_the_least_return_altitude_clears_the_highest_ground_inside_the_fence():
    ta = TerrainAltitude(HILL, BASE_AMSL_M, clearance_m=15.0)
    assert ta.rtl_min_alt_m(Geofence()) == pytest.approx(70.0 + 15.0, abs=0.5)
    box = dict(north_min_m=-700.0, north_max_m=700.0)
    assert ta.rtl_min_alt_m(Geofence(**box, east_min_m=-700.0, east_max_m=700.0)) == (
        pytest.approx(85.0, abs=0.5)
    )
    # a fence west of the hill: only its foot (2.7 sigma out, about 1 m) counts
    west = ta.rtl_min_alt_m(Geofence(**box, east_min_m=-700.0, east_max_m=-20.0))
    assert 15.0 <= west < 17.0


@pytest.mark.parametrize(
    ("autopilot", "name", "default", "per_m"),
    [(ARDUPILOT, "RTL_ALT", 1500.0, 100.0), (PX4, "RTL_RETURN_ALT", 60.0, 1.0)],
)
def test_a_return_altitude_below_the_ground_blocks_and_is_fixed(autopilot, name, default, per_m):
    (f,) = audit_rtl_altitude(autopilot, {name: default}, 85.0)
    assert f.severity == BLOCKING and f.param == name and "85 m" in f.message
    assert rtl_altitude_fixes(autopilot, {name: default}, 84.2) == ((name, 85.0 * per_m),)
    (ok,) = audit_rtl_altitude(autopilot, {name: 85.0 * per_m}, 85.0)
    assert ok.severity == INFO
    assert rtl_altitude_fixes(autopilot, {name: 85.0 * per_m}, 85.0) == ()
    (missing,) = audit_rtl_altitude(autopilot, {}, 85.0)
    assert missing.severity == BLOCKING and "could not be read" in missing.message
    assert rtl_altitude_fixes(autopilot, {}, 85.0) == ()  # never written unread


def test_the_fleet_audit_checks_the_return_altitude_only_over_terrain():
    params = {
        "FS_GCS_ENABLE": 1,
        "FS_GCS_TIMEOUT": 5,
        "FS_OPTIONS": 0,
        "GUID_TIMEOUT": 3,
        "SYSID_MYGCS": 255,
        "RTL_ALT": 1500,
    }
    flat = audit_fleet({(0, 1): (ARDUPILOT, params)})
    assert flat.cleared_to_fly
    assert not any(f.param == "RTL_ALT" for a in flat.vehicles for f in a.findings)
    hill = audit_fleet({(0, 1): (ARDUPILOT, params)}, rtl_min_alt_m=85.0)
    assert not hill.cleared_to_fly
    assert [f.param for f in hill.vehicles[0].blocking] == ["RTL_ALT"]

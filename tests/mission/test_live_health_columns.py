"""The live page's per-vehicle health columns (mission.view.live.health) from a fleet fed with
the station's own events, in memory; and the station link's health handlers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs.events import (
    BatteryReceived,
    EstimatorReceived,
    GpsReceived,
    SensorsReceived,
    TelemetryReceived,
    VehicleDiscovered,
)
from gcs.fleet import FleetView, MissionOrigin
from mavedge import mavlink
from mission.view.live.health import (
    estimator_problems,
    health_columns,
    minutes_to_reserve,
    unhealthy_sensors,
)

GPS = mavlink.MAV_SYS_STATUS_SENSOR_GPS
MAG = mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
GYRO = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO


def test_unhealthy_sensors_are_present_enabled_and_not_healthy():
    assert unhealthy_sensors(GPS | MAG | GYRO, GPS | MAG | GYRO, GPS | GYRO) == ("3D_MAG",)
    # Present but disabled: not reported as a problem.
    assert unhealthy_sensors(GPS | MAG, GPS, GPS) == ()
    assert unhealthy_sensors(-1, -1, -1) == ()


def test_estimator_problems():
    ok = 1 | 2 | 4 | 8 | 16 | 32 | 256 | 512
    assert estimator_problems(ok, 1, 10) == "ok"
    assert estimator_problems(-1, 0, -1) is None
    assert estimator_problems(ok & ~16, 1, 10) == "no abs. position"
    assert estimator_problems(ok | 32768, 1, 10) == "GPS glitch"  # EKF_GPS_GLITCHING
    assert estimator_problems(ok | 1024, 2, 10) == "GPS glitch"  # ESTIMATOR_GPS_GLITCH
    assert estimator_problems(ok | 1024, 1, 10) == "uninitialised"  # EKF_UNINITIALIZED
    assert estimator_problems(ok | 128, 1, 90) == "constant-position mode; test ratio 0.90"


def test_minutes_to_reserve():
    got = minutes_to_reserve(
        np.array([0.85, 0.5, 0.2, 0.9]), np.array([0.01 / 60, np.nan, 0.001, 0.0]), 0.25
    )
    assert got[0] == pytest.approx(60.0)  # 60 % above the reserve at 1 %/min
    assert math.isnan(got[1]) and got[2] == 0.0 and math.isnan(got[3])


def test_health_columns_from_fleet_events():
    origin = MissionOrigin(47.0, 8.0, 500.0)
    fleet = FleetView(origin)
    for s in (1, 2):
        fleet.apply(VehicleDiscovered(0, s, 0.0, autopilot=3, custom_mode=4, armed=True))
    fleet.apply(
        TelemetryReceived(
            0,
            1,
            1.0,
            lat_deg=47.001,
            lon_deg=8.002,
            alt_amsl_m=530.0,
            rel_alt_m=30.0,
            vel_ned_m_s=(3.0, 4.0, 0.0),
            yaw_rad=None,
            time_boot_s=1.0,
        )
    )
    fleet.apply(GpsReceived(0, 1, 1.0, fix_type=3, satellites=14, hdop=0.8))
    fleet.apply(SensorsReceived(0, 1, 1.0, present=GPS | MAG, enabled=GPS | MAG, health=GPS))
    fleet.apply(EstimatorReceived(0, 1, 1.0, source="EKF_STATUS_REPORT", flags=831, variance=0.2))
    fleet.apply(BatteryReceived(0, 1, 1.0, remaining_frac=0.87, voltage_v=15.8))
    snap = fleet.snapshot(3.0)
    cols = health_columns(snap, origin, 3.0, loss_frac=[0.02, None])
    assert cols["sats"] == [14, None] and cols["gps"] == [3, None] and cols["hdop"] == [0.8, None]
    assert cols["bat"] == [87, None] and cols["volt"] == [15.8, None]
    assert cols["sensors_bad"] == ["3D_MAG", None]
    assert cols["ekf"] == ["ok", None]
    assert cols["gs"][0] == 5.0
    assert cols["lat"][0] == pytest.approx(47.001, abs=1e-6)
    assert cols["lon"][0] == pytest.approx(8.002, abs=1e-6)
    assert cols["amsl"][0] == pytest.approx(530.0, abs=0.1)
    assert cols["ahome"][0] == pytest.approx(30.0, abs=0.1)
    assert cols["loss"] == [2.0, None]
    assert cols["since"][0] == 2.0
    assert cols["rssi"] == [None, None]


def _link_with_vehicle(health: bool):
    from gcs.link import StationLink, StationConfig

    link = StationLink(StationConfig(health_telemetry=health))
    mav = mavlink.MAVLink(None, 7, 1)
    addr = ("10.0.0.7", 14550)
    hb = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
    )
    link.receive_datagram(bytes(hb.pack(mav)), addr, 0.0)
    while link.next_event() is not None:
        pass
    return link, mav, addr


def _events(link):
    out = []
    while (ev := link.next_event()) is not None:
        out.append(ev)
    return out


def test_station_link_folds_health_reports_only_when_asked():
    gps = mavlink.MAVLink_gps_raw_int_message(0, 3, 1, 1, 1, 90, 65535, 0, 65535, 11)
    ekf = mavlink.MAVLink_ekf_status_report_message(831, 0.1, 0.3, 0.2, 0.1, 0.0)
    radio = mavlink.MAVLink_radio_status_message(200, 190, 255, 40, 42, 3, 1)
    for health in (True, False):
        link, mav, addr = _link_with_vehicle(health)
        before = link.stats.ignored_messages
        for msg in (gps, ekf, radio):
            link.receive_datagram(bytes(msg.pack(mav)), addr, 1.0)
        evs = _events(link)
        if not health:
            assert evs == [] and link.stats.ignored_messages == before + 3
            continue
        g, e, r = evs
        assert isinstance(g, GpsReceived) and (g.fix_type, g.satellites, g.hdop) == (3, 11, 0.9)
        assert isinstance(e, EstimatorReceived) and e.flags == 831
        assert e.variance == pytest.approx(0.3)
        assert (r.rssi, r.remrssi) == (200, 190)
        assert r.noise == 40 and r.rxerrors == 3

"""The station's battery view: SYS_STATUS / BATTERY_STATUS in, events, the fleet's arrays and the
drain estimate from quantized reports; a power-cycled vehicle re-identified (VehicleRebooted)."""

from __future__ import annotations

import math

from gcs_fakes import drain
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.battery import DrainEstimator
from gcs.events import BatteryReceived, VehicleRebooted, VehicleRecovered
from gcs.fleet import FleetView, MissionOrigin

ORIGIN = MissionOrigin(47.0, 8.0, 500.0)


def _sys_status(fake, percent: int, mv: int = 15800, ca: int = 1200) -> bytes:
    return fake.pack(
        mav.MAVLink_sys_status_message(0, 0, 0, 500, mv, ca, percent, 0, 0, 0, 0, 0, 0)
    )


def _battery_status(fake, percent: int, consumed_mah: int, t_rem_s: int, state: int) -> bytes:
    volts = [15800] + [0xFFFF] * 9
    return fake.pack(
        mav.MAVLink_battery_status_message(
            0, 0, 0, 2500, volts, 1200, consumed_mah, -1, percent, t_rem_s, state
        )
    )


def _discovered(station, fake, **cfg):
    link = station(**cfg)
    ap = fake(sysid=3)
    link.receive_datagram(ap.heartbeat(), "a", 0.0)
    drain(link)
    return link, ap


def test_battery_reports_become_events_in_si(station, fake):
    link, ap = _discovered(station, fake, battery_telemetry=True)
    link.receive_datagram(_sys_status(ap, 87), "a", 1.0)
    link.receive_datagram(
        _battery_status(ap, 87, 640, 900, mav.MAV_BATTERY_CHARGE_STATE_OK), "a", 1.1
    )
    evs = [e for e in drain(link) if isinstance(e, BatteryReceived)]
    assert [e.source for e in evs] == ["SYS_STATUS", "BATTERY_STATUS"]
    s, b = evs
    assert s.remaining_frac == 0.87 and s.voltage_v == 15.8 and s.current_a == 12.0
    assert s.consumed_mah is None and s.time_remaining_s is None
    assert b.consumed_mah == 640.0 and b.time_remaining_s == 900.0
    assert b.charge_state == mav.MAV_BATTERY_CHARGE_STATE_OK


def test_unknown_battery_fields_are_none_not_numbers(station, fake):
    link, ap = _discovered(station, fake, battery_telemetry=True)
    link.receive_datagram(_sys_status(ap, -1, mv=0xFFFF, ca=-1), "a", 1.0)
    (ev,) = [e for e in drain(link) if isinstance(e, BatteryReceived)]
    assert ev.remaining_frac is None and ev.voltage_v is None and ev.current_a is None


def test_without_battery_telemetry_nothing_changes(station, fake):
    link, ap = _discovered(station, fake)
    before = link.stats.ignored_messages
    link.receive_datagram(_sys_status(ap, 87), "a", 1.0)
    assert not [e for e in drain(link) if isinstance(e, BatteryReceived)]
    assert link.stats.ignored_messages == before + 1


def test_drain_estimate_is_exact_through_whole_percent_reports():
    # A true drain of 1/1500 per s reported in whole percent at 0.2 Hz: each reading is off by up
    # to a percent, the edge-to-edge slope is not.
    true_rate = 1.0 / 1500.0
    est = DrainEstimator()
    for k in range(0, 120):
        t = 5.0 * k
        est.update(t, math.floor((0.995 - true_rate * t) * 100.0) / 100.0)
    rate = est.drain_per_s(5.0 * 119)
    assert abs(rate - true_rate) / true_rate < 0.05
    # Landed: the level holds; the bound brings the drain down within a few steps' time.
    assert est.drain_per_s(5.0 * 119 + 600.0) < 0.25 * true_rate
    # A full battery (swap) forgets the old slope.
    est.update(1000.0, 1.0)
    assert math.isnan(est.drain_per_s(1000.0))


def test_fleet_folds_batteries_and_estimates_drain():
    fleet = FleetView(ORIGIN)
    rate = 1.0 / 1200.0
    for k in range(60):
        t = 5.0 * k
        pct = math.floor((0.999 - rate * t) * 100.0)
        fleet.apply(BatteryReceived(0, 1, t, "SYS_STATUS", pct / 100.0, 15.5, 20.0))
    fleet.apply(BatteryReceived(0, 1, 295.0, "BATTERY_STATUS", 0.7, 15.4, 20.0, 1500.0, 800.0, 1))
    snap = fleet.snapshot(296.0)
    assert snap.battery_frac is not None and snap.drain_per_s is not None
    assert snap.battery_frac[0] == math.floor((0.999 - rate * 295.0) * 100.0) / 100.0
    assert snap.battery_consumed_mah is not None and snap.battery_consumed_mah[0] == 1500.0
    assert snap.battery_charge_state is not None and snap.battery_charge_state[0] == 1
    assert abs(snap.drain_per_s[0] - rate) / rate < 0.05


def test_power_cycled_vehicle_comes_back_as_the_same_vehicle(station, fake):
    link, ap = _discovered(station, fake, battery_telemetry=True)
    link.receive_datagram(ap.global_position(47.0, 8.0, 500.0, 0.0, time_boot_ms=900_000), "a", 1.0)
    link.receive_datagram(_sys_status(ap, 18), "a", 1.5)
    fleet = FleetView(ORIGIN)
    for e in drain(link):
        fleet.apply(e)
    # Swapped on the ground: silent (lost), then it boots again with a full battery.
    link.handle_timer(20.0)
    t = 40.0
    link.receive_datagram(ap.heartbeat(), "a", t)
    link.receive_datagram(ap.global_position(47.0, 8.0, 500.0, 0.0, time_boot_ms=3_000), "a", t)
    link.receive_datagram(_sys_status(ap, 100), "a", t + 0.5)
    evs = drain(link)
    kinds = [type(e) for e in evs]
    assert VehicleRecovered in kinds and VehicleRebooted in kinds
    (rb,) = [e for e in evs if isinstance(e, VehicleRebooted)]
    assert (rb.sysid, rb.previous_boot_s, rb.time_boot_s) == (3, 900.0, 3.0)
    assert len(link.vehicles()) == 1  # not a new vehicle
    for e in evs:
        fleet.apply(e)
    snap = fleet.snapshot(t + 1.0)
    assert snap.n_vehicles == 1 and not snap.lost[0]
    assert snap.rebooted_s is not None and snap.rebooted_s[0] == t
    assert snap.battery_frac is not None and snap.battery_frac[0] == 1.0
    assert [type(e) for e in evs].index(VehicleRecovered) < kinds.index(VehicleRebooted)


def test_datagrams_slightly_out_of_order_are_not_a_reboot(station, fake):
    link, ap = _discovered(station, fake)
    link.receive_datagram(ap.global_position(47.0, 8.0, 500.0, 0.0, time_boot_ms=10_500), "a", 1.0)
    link.receive_datagram(ap.global_position(47.0, 8.0, 500.0, 0.0, time_boot_ms=10_000), "a", 1.1)
    assert not [e for e in drain(link) if isinstance(e, VehicleRebooted)]

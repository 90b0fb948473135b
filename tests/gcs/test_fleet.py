"""Fleet view: GLOBAL_POSITION_INT -> mission NED, stable rows, networked / lost / returning."""

import numpy as np
import pytest
from gcs_fakes import FakeAutopilot, drain
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.events import ModeChanged, TelemetryReceived, VehicleDiscovered, VehicleLost
from gcs.fleet import FleetView, MissionOrigin
from gcs.link import StationConfig, StationLink
from planner.geometry import ned_to_geodetic

ORIGIN = MissionOrigin(47.3977, 8.5456, 488.0)
A1, A2 = ("10.0.0.1", 1), ("10.0.0.2", 2)


def fly(link, fleet, data, addr, t):
    link.receive_datagram(data, addr, t)
    for ev in drain(link):
        fleet.apply(ev)


def test_two_vehicles_with_different_origins_land_in_one_mission_frame():
    """Vehicle 1 took off 200 m north-east of the mission origin, vehicle 2 300 m south-west and
    20 m higher; their local frames differ, the mission frame must not."""
    link = StationLink(StationConfig(stream_rates_hz=()))
    fleet = FleetView(ORIGIN)
    truth = np.array([[150.0, 130.0, -30.0], [-210.0, -220.0, -45.0]])  # mission NED, metres
    homes_amsl = [488.0, 508.0]
    lat, lon, alt = ned_to_geodetic(truth, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_amsl_m)
    aps = [FakeAutopilot(sysid=5), FakeAutopilot(sysid=9, autopilot=mav.MAV_AUTOPILOT_PX4)]
    for i, (ap, addr) in enumerate(zip(aps, (A1, A2))):
        fly(link, fleet, ap.heartbeat(4 if i == 0 else 393216), addr, 0.0)
        fly(
            link,
            fleet,
            ap.global_position(lat[i], lon[i], alt[i], alt[i] - homes_amsl[i], (1.0, -0.5, 0.2)),
            addr,
            0.5,
        )
    snap = fleet.snapshot(1.0)
    assert list(snap.sysid_of_index) == [5, 9] and list(snap.link_id) == [0, 0]
    # Within the wire quantisation (1e-7 deg ~ 1.1 cm, 1 mm).
    np.testing.assert_allclose(snap.pos_ned_m, truth, atol=0.02)
    np.testing.assert_allclose(snap.vel_ned_m_s, [[1.0, -0.5, 0.2]] * 2)
    np.testing.assert_allclose(snap.home_amsl_m, homes_amsl, atol=2e-3)
    assert snap.networked.all() and not snap.lost.any() and snap.mode == ("GUIDED", "OFFBOARD")

    # Targets back to the wire: same target for both -> same lat/lon, different rel. altitude.
    tgt = np.array([[100.0, 50.0, -40.0], [100.0, 50.0, -40.0]])
    t_lat, t_lon, rel = fleet.targets_to_global([0, 1], tgt)
    assert t_lat[0] == t_lat[1] and t_lon[0] == t_lon[1]
    np.testing.assert_allclose(rel, [40.0, 20.0], atol=2e-3)


def test_rows_are_stable_and_states_classified():
    fleet = FleetView(ORIGIN, timeout_s=5.0)
    assert fleet.register(1, 7) == 0 and fleet.register(0, 7) == 1  # same sysid, other link
    assert fleet.index_of(1, 7) == 0
    with pytest.raises(KeyError):
        fleet.index_of(2, 7)
    tel = dict(lat_deg=47.3977, lon_deg=8.5456, alt_amsl_m=520.0, rel_alt_m=32.0)
    fleet.apply(VehicleDiscovered(1, 7, 0.0, autopilot=3, custom_mode=4, mode="GUIDED"))
    fleet.apply(TelemetryReceived(1, 7, 0.5, **tel))
    fleet.apply(VehicleDiscovered(0, 7, 0.0, autopilot=3, custom_mode=4, mode="GUIDED"))
    fleet.apply(TelemetryReceived(0, 7, 0.5, **tel))

    snap = fleet.snapshot(3.0)
    assert snap.networked.tolist() == [True, True]
    snap = fleet.snapshot(5.6)  # row 0 silent for 5.1 s
    assert snap.lost.tolist() == [True, True] and not snap.networked.any()

    # Row 0 heard again in RTL (its GCS failsafe fired): returning, not networked.
    fleet.apply(VehicleLost(1, 7, 5.5, 0.5))
    fleet.apply(ModeChanged(1, 7, 20.0, custom_mode=6, mode="RTL", previous_mode="GUIDED"))
    fleet.apply(TelemetryReceived(1, 7, 20.0, **tel))
    snap = fleet.snapshot(20.5)
    assert snap.returning.tolist() == [False, False]  # link still says lost: no recovery yet
    from gcs.events import VehicleRecovered

    fleet.apply(VehicleRecovered(1, 7, 20.0, silent_s=19.5, custom_mode=6, mode="RTL"))
    snap = fleet.snapshot(20.5)
    assert snap.returning.tolist() == [True, False] and snap.networked.tolist() == [False, False]
    assert snap.lost.tolist() == [False, True]
    # Reclaimed to GUIDED: networked again.
    fleet.apply(ModeChanged(1, 7, 21.0, custom_mode=4, mode="GUIDED", previous_mode="RTL"))
    snap = fleet.snapshot(21.0)
    assert snap.networked.tolist() == [True, False] and not snap.returning.any()
    assert snap.pos_ned_m.shape == (2, 3)


def test_vehicle_without_position_has_nan_rows():
    fleet = FleetView(ORIGIN)
    fleet.apply(VehicleDiscovered(0, 1, 0.0, autopilot=12, custom_mode=0))
    snap = fleet.snapshot(0.1)
    assert not snap.has_position[0] and np.isnan(snap.pos_ned_m).all()
    assert snap.n_vehicles == 1


def test_link_state_events_make_no_rows():
    from gcs.events import LinkDown, LinkUp

    fleet = FleetView(ORIGIN)
    fleet.apply(LinkDown(0, 1.0, connection="tcp:127.0.0.1:5760", reason="refused"))
    fleet.apply(LinkUp(0, 2.0, connection="tcp:127.0.0.1:5760"))
    assert len(fleet) == 0 and fleet.snapshot(2.0).n_vehicles == 0


def test_rows_survive_growth_and_snapshots_are_copies():
    # Rows live in arrays that grow by doubling: values written before a growth are kept, and
    # a snapshot does not change when the fleet does afterwards.
    fleet = FleetView(ORIGIN, timeout_s=5.0)
    for k in range(40):
        fleet.apply(VehicleDiscovered(0, k + 1, 0.0, autopilot=3, custom_mode=4, mode="GUIDED"))
        fleet.apply(
            TelemetryReceived(
                0, k + 1, 0.5, lat_deg=47.3977, lon_deg=8.5456, alt_amsl_m=500.0 + k, rel_alt_m=k
            )
        )
    snap = fleet.snapshot(1.0)
    assert snap.n_vehicles == 40 and snap.mode == ("GUIDED",) * 40
    assert np.allclose(snap.home_amsl_m, 500.0) and snap.networked.all()
    fleet.apply(ModeChanged(0, 1, 2.0, custom_mode=6, mode="RTL", previous_mode="GUIDED"))
    fleet.apply(VehicleLost(0, 2, 2.0, 0.5))
    assert snap.mode[0] == "GUIDED" and snap.networked[1]
    later = fleet.snapshot(2.0)
    assert later.mode[0] == "RTL" and later.lost[1] and not later.returning.any()


def test_cached_positions_and_modes_match_a_fresh_computation():
    """snapshot() keeps positions and mode facts between polls (converting only changed rows);
    after random events (rows added past a growth, positions, modes, a vehicle without a fix,
    an origin replaced) every snapshot equals a full recomputation, to the bit."""
    from gcs.events import VehicleRecovered

    rng = np.random.default_rng(4)
    fleet = FleetView(ORIGIN)
    n_checked = 0
    for step in range(300):
        t = step * 0.1
        link, sysid = int(rng.integers(0, 2)), int(rng.integers(1, 40))
        kind = rng.random()
        if kind < 0.6:
            fleet.apply(
                TelemetryReceived(
                    link,
                    sysid,
                    t,
                    lat_deg=ORIGIN.lat_deg + rng.normal() * 1e-3,
                    lon_deg=ORIGIN.lon_deg + rng.normal() * 1e-3,
                    alt_amsl_m=500.0 + rng.normal(),
                    rel_alt_m=12.0,
                )
            )
        elif kind < 0.7:
            fleet.apply(
                VehicleDiscovered(
                    link, sysid, t, autopilot=int(rng.choice([3, 12])), custom_mode=4, armed=True
                )
            )
        elif kind < 0.8:
            fleet.apply(ModeChanged(link, sysid, t, custom_mode=int(rng.choice([4, 6, 9]))))
        elif kind < 0.85:
            fleet.apply(VehicleRecovered(link, sysid, t, custom_mode=6))
        elif kind < 0.9:
            fleet.apply(VehicleLost(link, sysid, t))
        if step == 150:
            fleet.origin = MissionOrigin(47.0, 8.0, 400.0)
        if step % 3 == 0:
            snap = fleet.snapshot(t)
            n = snap.n_vehicles
            ref = fleet._positions_reference(n)
            assert snap.pos_ned_m.tobytes() == ref.tobytes()
            infos = [fleet._new_mode_info(k) for k in zip(fleet._autopilot, fleet._custom_mode)]
            assert snap.mode == tuple(name for name, _ in infos)
            assert snap.autopilot.tolist() == fleet._autopilot
            assert snap.custom_mode.tolist() == fleet._custom_mode
            failsafe = np.array([f for _, f in infos], dtype=bool)
            assert np.array_equal(
                snap.returning, snap.lost.__invert__() & fleet._was_lost[:n] & failsafe
            )
            n_checked += n
    assert n_checked > 1000


def test_a_reboot_keeps_the_battery_the_new_boot_reported_before_it_was_noticed():
    """The reboot is noticed at the new boot's first position report; the battery reports of the
    new boot that came before it describe the new battery (kept), the old boot's do not."""
    from gcs.events import BatteryReceived, VehicleRebooted

    fleet = FleetView(ORIGIN)
    fleet.apply(VehicleDiscovered(0, 1, 0.0))
    fleet.apply(BatteryReceived(0, 1, 100.0, remaining_frac=0.45))
    # Power cut at 101 s, boot at 102 s, full battery reported at 104 s, first position at 110 s
    # (its clock at 8 s): the level of 104 s is the new battery's.
    fleet.apply(BatteryReceived(0, 1, 104.0, remaining_frac=1.0))
    fleet.apply(VehicleRebooted(0, 1, 110.0, 3000.0, 8.0))
    snap = fleet.snapshot(110.0)
    assert snap.battery_frac[0] == 1.0 and snap.rebooted_s[0] == 110.0
    # Its last level came before this boot (clock at 8 s: booted at 112 s): unknown, not 45 %.
    fleet.apply(BatteryReceived(0, 1, 111.0, remaining_frac=0.45))
    fleet.apply(VehicleRebooted(0, 1, 120.0, 3000.0, 8.0))
    assert np.isnan(fleet.snapshot(120.0).battery_frac[0])
    # A level reported within the boot's clock but before the last position of the old boot
    # is the old battery's (no silence between them: the fake feeds of the operator's tests).
    fleet.apply(BatteryReceived(0, 1, 125.0, remaining_frac=0.45))
    fleet.apply(
        TelemetryReceived(
            0, 1, 125.5, lat_deg=ORIGIN.lat_deg, lon_deg=ORIGIN.lon_deg, alt_amsl_m=500.0
        )
    )
    fleet.apply(VehicleRebooted(0, 1, 126.0, 3000.0, 8.0))
    assert np.isnan(fleet.snapshot(126.0).battery_frac[0])

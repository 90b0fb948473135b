"""The rotation in the station's tick (gcs/operations/rotation.py), against the fake station of
test_operations.py, in memory with explicit time: a relay's battery falls (fake telemetry), a
spare is launched, takes the post, the relay is sent home, lands, is power-cycled full and is a
spare again; the firmware's own low-battery RTL is the policy's failsafe."""

from __future__ import annotations

import numpy as np
import pytest
from test_operations import CONTROL, ORIGIN, RTL, STABILIZE, FakePlanner, FakeStation, Feed

from gcs.autopilot import ARDUPILOT
from gcs.events import (
    ArmedChanged,
    BatteryReceived,
    ModeChanged,
    VehicleLost,
    VehicleRebooted,
    VehicleRecovered,
)
from gcs.fleet import FleetView
from gcs.operations import OperationsConfig, Operator
from gcs.operations.rotation import RotationSetup
from planner.endurance import (
    AIR,
    INBOUND,
    LOST,
    READY,
    RETURNING,
    SWAPPING,
    BaseResources,
    EnduranceParams,
    RotationPolicy,
)

POST_N_M = 100.0


def _make(
    n: int = 2,
    flying: int = 1,
    swap_confirm: str = "auto",
    refill: bool = False,
    duration_s: float = 10_000.0,
):
    # Without the refill unless asked (on by default): these follow one relay and its spare.
    policy = RotationPolicy(
        n,
        flying,
        BaseResources(pads=1, swap_time_s=60.0, spare_batteries=4),
        EnduranceParams(critical_frac=0.2, return_speed_m_s=5.0, refill_lost=refill),
    )
    rot = RotationSetup(policy, hover_drain_per_s=1.0 / 1500.0, swap_confirm=swap_confirm)
    station = FakeStation()
    planner = FakePlanner()
    op = Operator(
        station,
        FleetView(ORIGIN, timeout_s=5.0),
        planner,
        lambda t: np.array([[POST_N_M + 50.0, 0.0]]),
        CONTROL,
        OperationsConfig(audit=False, expected_vehicles=n, duration_s=duration_s),
        rotation=rot,
    )
    feed = Feed(op)
    vids = [feed.add(k + 1, 0.0) for k in range(n)]
    return op, station, planner, feed, vids, rot


def _audited(rot: RotationSetup, n: int, autopilot: int = ARDUPILOT):
    """An operator with the pre-flight audit on, ``n`` vehicles of ``autopilot`` heard and
    ``rot`` (the landing tests); returns (op, feed, vids)."""
    op = Operator(
        FakeStation(),
        FleetView(ORIGIN, timeout_s=5.0),
        FakePlanner(),
        lambda t: np.array([[POST_N_M, 0.0]]),
        CONTROL,
        OperationsConfig(audit=True, expected_vehicles=n, duration_s=10_000.0),
        rotation=rot,
    )
    feed = Feed(op)
    return op, feed, [feed.add(k + 1, 0.0, autopilot=autopilot) for k in range(n)]


def _battery(feed: Feed, vid, t_s: float, frac: float) -> None:
    feed.emit(BatteryReceived(vid[0], vid[1], t_s, "SYS_STATUS", frac, 15.0, 20.0))


def _run(feed: Feed, t0: float, t1: float, batt: dict) -> float:
    t = t0
    while t <= t1 + 1e-9:
        for vid, frac in batt.items():
            if vid not in feed.silent:
                _battery(feed, vid, t, frac)
        feed.poll(t)
        t = round(t + 0.5, 9)
    return t


def _relay_at_post(feed: Feed, relay, spare) -> dict:
    """The relay airborne at its post on 90 % from t = 1 s, the spare full on the ground.
    Returns the batteries (fed on by ``_run``)."""
    feed.poll(0.0)
    _battery(feed, relay, 0.5, 0.9)
    feed.fly(relay, 1.0)
    feed.v[relay]["north_m"] = POST_N_M
    return {relay: 0.9, spare: 1.0}


def _relay_low(feed: Feed, relay, spare, spare_north_m: float | None = None):
    """The relay at its post on 90 % for 20 s, then its battery at the launch lead (30 %) for
    5 s: the spare is launched. Returns the time and the batteries (fed on by ``_run``)."""
    batt = _relay_at_post(feed, relay, spare)
    if spare_north_m is not None:
        feed.v[spare]["north_m"] = spare_north_m
    t = _run(feed, 1.0, 20.0, batt)
    batt[relay] = 0.30
    return _run(feed, t, t + 5.0, batt), batt


def _spare_at_post(feed: Feed, spare, t: float, batt: dict, east_m: float | None = None) -> float:
    """The spare in the air at the relay's post for 3 s: the relay is sent home."""
    feed.fly(spare, t)
    feed.v[spare]["north_m"] = POST_N_M
    if east_m is not None:
        feed.v[spare]["east_m"] = east_m
    return _run(feed, t, t + 3.0, batt)


def _lands(feed: Feed, relay, t: float, batt: dict, north_m: float) -> float:
    """The relay in RTL lands ``north_m`` from the base's centre and disarms; 2 s pass."""
    feed.mode(relay, t, RTL)
    feed.v[relay]["north_m"] = north_m
    feed.alt(relay, t, 0.0)
    feed.armed(relay, t, False)
    return _run(feed, t, t + 2.0, batt)


def _powered_off_unheard_and_back(feed: Feed, rot, relay, t: float, batt: dict) -> float:
    """The relay sent home: in RTL it lands on its pad, still armed in the last heartbeat heard;
    the crew pulls the pack before the disarm is heard, the link declares it lost, and 60 s later
    it boots with a full pack in the one burst the link reports at its first heartbeat
    (VehicleRecovered, ModeChanged RTL -> STABILIZE, ArmedChanged False, VehicleRebooted). It is
    never lost to the rotation. Returns the time 3 s after the boot."""
    feed.mode(relay, t, RTL)
    t = _run(feed, t, t + 3.0, batt)
    # Home in RTL, on the ground, still armed in the last heartbeat the station hears ...
    feed.v[relay]["north_m"] = 1.0
    feed.alt(relay, t, 0.0)
    t = _run(feed, t, t + 1.0, batt)
    last_heard = t - 0.5
    # ... then the crew pulls the pack: silent, never heard disarmed.
    feed.silent.add(relay)
    t = _run(feed, t, t + 5.0, batt)
    feed.emit(VehicleLost(relay[0], relay[1], t, last_heard))
    t = _run(feed, t, last_heard + 60.5, batt)
    assert rot.policy.phase[0] != LOST  # powered off at the base, not lost
    # The boot, as the link reports it (one burst at the first heartbeat).
    feed.silent.discard(relay)
    feed.emit(VehicleRecovered(relay[0], relay[1], t, t - last_heard, STABILIZE, "STABILIZE"))
    feed.v[relay]["mode"] = STABILIZE
    feed.emit(ModeChanged(relay[0], relay[1], t, STABILIZE, "STABILIZE", "RTL"))
    feed.v[relay]["armed"] = False
    feed.emit(ArmedChanged(relay[0], relay[1], t, False))
    feed.emit(VehicleRebooted(relay[0], relay[1], t, last_heard, 0.5))
    batt[relay] = 1.0
    return _run(feed, t, t + 3.0, batt)


def test_only_the_planned_k_take_off_and_the_spares_stay_home():
    op, station, planner, feed, (relay, spare), rot = _make()
    feed.poll(0.0)
    assert op.phase == "launch"
    # (A charge never reported counts as due now, docs/design/endurance.md §3: SYS_STATUS
    # arrives during the launch.)
    _battery(feed, relay, 0.5, 0.9)
    feed.fly(relay, 1.0)
    feed.poll(1.0)
    assert op.phase == "run"
    _run(feed, 1.5, 3.0, {relay: 0.9, spare: 1.0})
    assert station.of("takeoff", relay) and not station.of("takeoff", spare)
    assert not station.of("arm", spare)
    tick = planner.ticks[-1]
    assert tick.alive.tolist() == [True, False]  # the spare is not in the planner's fleet


def test_relay_relieved_by_a_spare_sent_home_landed_rebooted_and_ready_again():
    op, station, planner, feed, (relay, spare), rot = _make()
    batt = _relay_at_post(feed, relay, spare)
    feed.v[spare]["north_m"] = 0.0
    t = _run(feed, 1.0, 20.0, batt)
    assert rot.policy.phase.tolist() == [AIR, READY]
    assert np.isfinite(rot.time_to_reserve_s[0]) and rot.time_to_reserve_s[0] > 0
    # The relay's battery falls to its launch lead: the spare is launched.
    batt[relay] = 0.30
    t = _run(feed, t, t + 3.0, batt)
    assert rot.policy.phase.tolist() == [AIR, INBOUND]
    t_launch = t
    t = _run(feed, t, t + 2.0, batt)
    assert station.of("takeoff", spare, since_s=t_launch - 3.0)  # armed and taken off
    feed.fly(spare, t)
    t = _run(feed, t, t + 3.0, batt)
    # In the air, it is sent to the relay's post.
    (call,) = station.of("set_position_target", spare, since_s=t - 1.0)[-1:]
    assert call[2] > ORIGIN.lat_deg + 0.0008  # ~100 m north of the origin
    # It holds the post, networked: the handover, and the relay is sent home (RTL).
    feed.v[spare]["north_m"] = POST_N_M
    t = _run(feed, t, t + 2.0, batt)
    assert rot.policy.phase.tolist() == [RETURNING, AIR]
    assert station.of("rtl", relay)
    assert planner.ticks[-1].alive.tolist() == [False, True]
    # It flies home in RTL and lands: disarmed at the base -> on a pad.
    t = _lands(feed, relay, t, batt, north_m=2.0)
    assert rot.policy.phase[0] == SWAPPING
    n_takeoffs = len(station.of("takeoff", relay))
    # The crew pulls its battery: silent for 20 s (lost to the link, not to the rotation) ...
    feed.silent.add(relay)
    t = _run(feed, t, t + 20.0, batt)
    assert rot.policy.phase[0] == SWAPPING
    # ... and it boots again, full: the same vehicle, a spare again.
    feed.silent.discard(relay)
    feed.emit(VehicleRebooted(relay[0], relay[1], t, 1500.0, 2.0))
    batt[relay] = 1.0
    t = _run(feed, t, t + 2.0, batt)
    assert rot.policy.phase.tolist() == [READY, AIR]
    assert op.fleet.snapshot(t).n_vehicles == 2
    s = op.rotation_summary()
    assert s is not None
    assert (s["rotations"], s["swaps"], s["reboots"]) == (1, 1, 1)
    assert 0.29 <= s["min_battery_in_air"] <= 0.31
    # A spare on the ground is not launched again until the policy sends it.
    t = _run(feed, t, t + 5.0, batt)
    assert len(station.of("takeoff", relay)) == n_takeoffs


@pytest.mark.parametrize("duration_s", [40.0, 10_000.0])
def test_a_relay_due_after_the_mission_end_is_not_relieved(duration_s):
    # The run starts at 1 s. At 30 % the relay is ~55 s from its reserve, within the launch lead:
    # relieved in a long mission; in one that ends at 41 s (more than the 30-s slack before that
    # reserve) it holds its post to the end and no spare is spent.
    op, station, planner, feed, (relay, spare), rot = _make(duration_s=duration_s)
    t, batt = _relay_low(feed, relay, spare, spare_north_m=0.0)
    assert op.mission_t0_s == 1.0
    assert 50.0 < rot.time_to_reserve_s[0] < 60.0
    if duration_s < 100.0:
        assert rot.policy.phase.tolist() == [AIR, READY]
        assert not station.of("takeoff", spare)
    else:
        assert rot.policy.phase.tolist() == [AIR, INBOUND]


def test_swap_confirmed_when_the_crew_powers_off_before_the_disarm_is_heard():
    """The emulator's sequence (/work/flyruns/a, sysid 40): the relay lands in RTL at the base
    and is powered off by the ground crew in the very step it disarms, so the station never
    hears it disarmed; the link declares it lost ~5 s later, and after the swap (60 s of silence,
    longer than ``lost_after_s``) it comes back in one burst: VehicleRecovered, ModeChanged
    RTL -> STABILIZE, ArmedChanged False, VehicleRebooted, a full SYS_STATUS. The station must
    neither drop it as lost nor miss the swap: it is a spare again."""
    op, station, planner, feed, (relay, spare), rot = _make()
    t, batt = _relay_low(feed, relay, spare, spare_north_m=0.0)
    t = _spare_at_post(feed, spare, t, batt)
    assert rot.policy.phase.tolist() == [RETURNING, AIR]
    t = _powered_off_unheard_and_back(feed, rot, relay, t, batt)
    assert rot.policy.phase.tolist() == [READY, AIR]
    s = op.rotation_summary()
    assert s is not None
    assert (s["rotations"], s["swaps"], s["reboots"], s["landed_away"]) == (1, 1, 1, 0)
    assert (s["ready"], s["in_air"]) == (1, 1)


def test_pads_away_from_the_base_centre_are_home_not_landed_away():
    """The emulator's vehicles stand on pads spread tens of metres around the base's centre and
    RTL lands each on its own: a spare on its pad while being launched, and a relay back on its
    pad, are at home (not ``landed_away``), and the relay's swap is confirmed there."""
    op, station, planner, feed, (relay, spare), rot = _make()
    for vid, east in ((relay, 60.0), (spare, 66.0)):
        feed.v[vid]["east_m"] = east
    t, batt = _relay_low(feed, relay, spare)  # launched, still disarmed on its pad
    assert rot.policy.phase.tolist() == [AIR, INBOUND]
    assert rot.counters["landed_away"] == 0 and not rot.gone
    t = _spare_at_post(feed, spare, t, batt, east_m=60.0)
    assert rot.policy.phase.tolist() == [RETURNING, AIR]
    t = _lands(feed, relay, t, batt, north_m=0.5)
    assert rot.policy.phase[0] == SWAPPING
    feed.emit(VehicleRebooted(relay[0], relay[1], t, 1500.0, 2.0))
    batt[relay] = 1.0
    t = _run(feed, t, t + 2.0, batt)
    assert rot.policy.phase.tolist() == [READY, AIR]
    assert rot.counters["landed_away"] == 0


def test_firmware_low_battery_rtl_is_a_failsafe_not_a_reclaim():
    op, station, planner, feed, (relay, spare), rot = _make()
    batt = _relay_at_post(feed, relay, spare)
    t = _run(feed, 1.0, 5.0, batt)
    # No spare launched yet; the firmware's own low-battery RTL (the station sent none).
    batt[relay] = 0.21
    _battery(feed, relay, t, 0.21)
    feed.mode(relay, t, RTL)
    t0 = t
    t = _run(feed, t, t + 5.0, batt)
    assert rot.policy.phase[0] == RETURNING
    assert rot.counters["battery_failsafes"] == 1
    assert not station.of("engage_guided", relay, since_s=t0)  # not reclaimed from its RTL


def test_an_rtl_with_a_full_battery_is_reclaimed_as_before():
    op, station, planner, feed, (relay, spare), rot = _make()
    feed.poll(0.0)
    _battery(feed, relay, 0.5, 0.9)
    feed.fly(relay, 1.0)
    batt = {relay: 0.9, spare: 1.0}
    t = _run(feed, 1.0, 5.0, batt)
    feed.mode(relay, t, RTL)  # e.g. its GCS failsafe: not a battery one
    t = _run(feed, t, t + 5.0, batt)
    assert rot.counters["battery_failsafes"] == 0
    assert rot.policy.phase[0] == AIR
    assert station.of("engage_guided", relay, since_s=t - 5.0)


def test_relay_on_a_pad_off_the_base_centre_powered_off_unheard_is_a_spare_again():
    """The emulator's sequence of wildfire_2h: the relay took off from its pad 60 m from the
    base's centre before the rotation's first tick (never heard disarmed in the run), RTL brings
    it back to that pad, the crew pulls the pack before the disarm is heard, and it reboots 60 s
    later. Its pad is known from HOME_POSITION: it is down at home, not lost, and a spare again."""
    from gcs.events import HomePositionReceived
    from planner.geometry import ned_to_geodetic

    op, station, planner, feed, (relay, spare), rot = _make()
    lat, lon, _ = ned_to_geodetic(
        np.array([0.0, 60.0, 0.0]), ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_amsl_m
    )
    feed.emit(
        HomePositionReceived(
            relay[0],
            relay[1],
            0.0,
            float(np.ravel(lat)[0]),
            float(np.ravel(lon)[0]),
            ORIGIN.alt_amsl_m,
        )
    )
    feed.v[relay]["east_m"] = 60.0
    feed.fly(relay, 0.0)
    _battery(feed, relay, 0.0, 0.9)
    feed.poll(0.0)
    feed.v[relay]["north_m"] = POST_N_M
    batt = {relay: 0.9, spare: 1.0}
    t = _run(feed, 0.5, 20.0, batt)
    batt[relay] = 0.30
    t = _run(feed, t, t + 5.0, batt)
    t = _spare_at_post(feed, spare, t, batt, east_m=60.0)
    assert rot.policy.phase.tolist() == [RETURNING, AIR]
    t = _powered_off_unheard_and_back(feed, rot, relay, t, batt)
    assert rot.policy.phase.tolist() == [READY, AIR]


def _relieve_and_land(feed, rot, relay, spare):
    """The relay relieved by the spare, home in RTL and disarmed on its pad: swapping."""
    t, batt = _relay_low(feed, relay, spare)
    t = _spare_at_post(feed, spare, t, batt)
    t = _lands(feed, relay, t, batt, north_m=1.0)
    assert rot.policy.phase.tolist() == [SWAPPING, AIR]
    return t, batt


def test_manual_swap_waits_for_the_crew_then_for_a_charged_battery():
    """``swap_confirm='manual'``: the power cycle with a full battery does not end the swap; the
    crew's ``confirm_swap`` does, once the vehicle is heard with a charged battery. The action is
    recorded like every operator action, and the state names the vehicle on its pad."""
    op, station, planner, feed, (relay, spare), rot = _make(swap_confirm="manual")
    seen = []
    op.on_action = seen.append
    t, batt = _relieve_and_land(feed, rot, relay, spare)
    ids = [f"{relay[0]}:{relay[1]}", f"{spare[0]}:{spare[1]}"]
    st = rot.state(ids)
    assert st["pads"] == [
        {"vehicle": ids[0], "since_s": st["pads"][0]["since_s"], "confirmed_s": None}
    ]
    assert st["pads"][0]["since_s"] <= t and st["swap_confirm"] == "manual"
    assert st["phase"] == ["swapping", "air"] and st["batteries"]["charged"] == 3
    # A spare on the ground may not be confirmed (no swap requested), nor "all" at once.
    (rec,) = op.operator_command("confirm_swap", spare, t, source="test")
    assert rec.result.startswith("not confirmed: no swap requested")
    with pytest.raises(ValueError):
        op.operator_command("confirm_swap", None, t, source="test")
    # Powered off and back, full: the station alone does not end a manual swap.
    feed.silent.add(relay)
    t = _run(feed, t, t + 10.0, batt)
    # The crew confirms while it is still off: confirmed, not yet ready.
    (rec,) = op.operator_command("confirm_swap", relay, t, source="web 127.0.0.1")
    assert rec.result.startswith("swap confirmed") and seen[-1] is rec
    assert rot.state(ids)["pads"][0]["confirmed_s"] == pytest.approx(t, abs=0.1)
    (again,) = op.operator_command("confirm_swap", relay, t, source="test")
    assert again.result == "already confirmed"
    t = _run(feed, t, t + 5.0, batt)
    assert rot.policy.phase[0] == SWAPPING
    feed.silent.discard(relay)
    feed.emit(VehicleRebooted(relay[0], relay[1], t, 1500.0, 2.0))
    # Heard again, the old pack's charge still in the last report: not yet.
    t = _run(feed, t, t + 1.0, batt)
    assert rot.policy.phase[0] == SWAPPING
    batt[relay] = 1.0
    t = _run(feed, t, t + 2.0, batt)
    assert rot.policy.phase.tolist() == [READY, AIR]
    assert rot.confirmed_s == {} and relay not in op.released
    s = op.rotation_summary()
    assert s is not None
    assert (s["swaps"], s["swaps_confirmed_by_crew"], s["swap_confirm"]) == (1, 1, "manual")
    kinds = [e["kind"] for e in rot.event_dicts(0, ids)]
    assert kinds.index("crew_confirmed") < kinds.index("swap_done")
    assert rot.state(ids)["pads"] == [{"vehicle": None}]


def test_manual_swap_without_the_crew_stays_on_the_pad():
    op, station, planner, feed, (relay, spare), rot = _make(swap_confirm="manual")
    t, batt = _relieve_and_land(feed, rot, relay, spare)
    feed.emit(VehicleRebooted(relay[0], relay[1], t, 1500.0, 2.0))
    batt[relay] = 1.0
    t = _run(feed, t, t + 120.0, batt)
    assert rot.policy.phase[0] == SWAPPING and rot.policy.summary()["swaps"] == 0


def test_auto_swap_the_crew_may_confirm_first():
    """``auto``: a vehicle whose battery the station never reads back full (an unknown charge)
    is never confirmed by the station; the crew's confirmation ends its swap."""
    op, station, planner, feed, (relay, spare), rot = _make()
    t, batt = _relieve_and_land(feed, rot, relay, spare)
    # Power-cycled, but its battery is never reported again (the charge is unknown).
    feed.emit(VehicleRebooted(relay[0], relay[1], t, 1500.0, 2.0))
    del batt[relay]
    t = _run(feed, t, t + 100.0, batt)
    assert rot.policy.phase[0] == SWAPPING
    (rec,) = op.operator_command("confirm_swap", relay, t, source="test")
    assert rec.result.startswith("swap confirmed")
    t = _run(feed, t, t + 2.0, batt)
    assert rot.policy.phase[0] == READY


def test_firmware_low_battery_smart_rtl_is_a_failsafe_left_to_fly_home():
    """ArduCopter's BATT_FS_LOW_ACT 3 (SmartRTL, accepted by the audit) is a battery failsafe too:
    the station neither reclaims the drone nor overrides its way home with RTL. (PX4 begins its
    battery failsafe with a Hold, another failsafe mode: the same path sends it home.)"""
    smart_rtl = 21  # ArduCopter mode.h Mode::Number::SMART_RTL
    op, station, planner, feed, (relay, spare), rot = _make()
    batt = _relay_at_post(feed, relay, spare)
    t = _run(feed, 1.0, 5.0, batt)
    batt[relay] = 0.21
    _battery(feed, relay, t, 0.21)
    feed.mode(relay, t, smart_rtl)
    t0 = t
    t = _run(feed, t, t + 5.0, batt)
    assert rot.counters["battery_failsafes"] == 1
    assert rot.policy.phase[0] == RETURNING
    assert not station.of("engage_guided", relay, since_s=t0)  # not reclaimed
    assert not station.of("rtl", relay, since_s=t0)  # left on its own way home


def _lose_relay_in_flight(op, feed, relay, spare, rot):
    """The relay flies its post and falls silent out there: lost to the rotation."""
    batt = _relay_at_post(feed, relay, spare)
    t = _run(feed, 1.0, 10.0, batt)
    assert rot.policy.phase[0] == AIR
    last_heard = t - 0.5
    feed.silent.add(relay)
    t = _run(feed, t, t + rot.lost_after_s + 5.0, batt)
    feed.emit(VehicleLost(relay[0], relay[1], t, last_heard))
    t = _run(feed, t, t + 2.0, batt)
    assert rot.policy.phase[0] == LOST
    return t, batt, last_heard


def _heard_on_its_pad(feed, relay, t: float, last_heard: float) -> None:
    """The crew brought it back: powered up on its pad, disarmed."""
    feed.silent.discard(relay)
    feed.v[relay]["north_m"] = 0.5
    feed.emit(VehicleRecovered(relay[0], relay[1], t, t - last_heard, STABILIZE, "STABILIZE"))
    feed.v[relay]["mode"] = STABILIZE
    feed.emit(ModeChanged(relay[0], relay[1], t, STABILIZE, "STABILIZE", "GUIDED"))
    feed.alt(relay, t, 0.0)
    feed.armed(relay, t, False)
    feed.emit(VehicleRebooted(relay[0], relay[1], t, last_heard, 0.5))


@pytest.mark.parametrize("refill", [False, True])
def test_a_lost_vehicle_heard_again_on_its_pad_full_is_a_spare_again(refill):
    op, station, planner, feed, (relay, spare), rot = _make(refill=refill)
    t, batt, last_heard = _lose_relay_in_flight(op, feed, relay, spare, rot)
    t = _run(feed, t, t + 100.0, batt)
    assert rot.policy.phase[0] == LOST  # silent: still lost
    _heard_on_its_pad(feed, relay, t, last_heard)
    batt[relay] = 1.0
    t = _run(feed, t, t + 3.0, batt)
    assert op.rotation_summary()["recovered"] == 1
    kinds = [e.kind for e in rot.events]
    assert "recovered" in kinds
    if not refill:
        assert rot.policy.phase[0] == READY
    else:
        # A spare again, and the post lost in the air is short of one: it flies into it.
        assert rot.policy.phase[0] == AIR and "refill" in kinds[kinds.index("recovered") :]


def test_a_lost_vehicle_heard_again_but_not_full_stays_lost():
    op, station, planner, feed, (relay, spare), rot = _make()
    t, batt, last_heard = _lose_relay_in_flight(op, feed, relay, spare, rot)
    _heard_on_its_pad(feed, relay, t, last_heard)
    batt[relay] = 0.4  # the same pack: not a charged vehicle
    t = _run(feed, t, t + 3.0, batt)
    assert rot.policy.phase[0] == LOST
    assert op.rotation_summary()["recovered"] == 0


@pytest.mark.parametrize("land_speed_cm_s", [50.0, 30.0])
def test_the_audit_reads_each_vehicles_landing_and_the_plan_counts_the_slowest(land_speed_cm_s):
    """With a rotation the audit reads the landing parameters (gcs/landing.py); once cleared,
    the policy is planned again with the slowest vehicle's descent from the top layer: one
    vehicle reporting LAND_SPEED 30 cm/s lands 13 s later from 50 m than the defaults."""
    from test_operations import AP_SAFE, answer_audit

    from gcs.landing import LANDING_PARAMS, landing_descent

    built: list[float] = []

    def replan(land_s: float) -> RotationPolicy:
        built.append(land_s)
        return RotationPolicy(
            3, 2, BaseResources(pads=1), EnduranceParams(critical_frac=0.2, land_s=land_s)
        )

    default_s = landing_descent(ARDUPILOT).time_s(50.0)
    rot = RotationSetup(
        replan(default_s), hover_drain_per_s=1.0 / 1500.0, land_from_m=50.0, replan=replan
    )
    op, feed, vids = _audited(rot, 3)
    station = op.station
    feed.poll(0.0)
    assert op.phase == "audit"
    for v in vids:
        asked = {c[2] for c in station.of("request_param", v)}
        assert set(LANDING_PARAMS[ARDUPILOT]) <= asked
    # Vehicles 1 and 2 answer the firmware's defaults; vehicle 3 lands at land_speed_cm_s.
    # RTL_ALT 15 m is below the 50-m layer: they land from the layer.
    landing = {"LAND_SPEED": 50.0, "LAND_SPEED_HIGH": 0.0, "LAND_ALT_LOW": 1000.0, "RTL_ALT": 1500}
    for v in vids:
        own = {**landing, "LAND_SPEED": land_speed_cm_s} if v == vids[2] else landing
        answer_audit(feed, station, 0.5, {**AP_SAFE, "WPNAV_SPEED_DN": 150.0, **own}, vid=v)
    feed.poll(0.75)
    assert op.phase == "launch"
    expect = landing_descent(ARDUPILOT, {"LAND_SPEED": land_speed_cm_s}).time_s(50.0)
    assert rot.policy.params.land_s == pytest.approx(expect)
    assert op.rotation_summary()["land_s"] == round(expect, 1)  # summary.json says it
    if land_speed_cm_s == 50.0:
        assert built == [default_s]  # the same landing: the plan is not built again
    else:
        assert expect == pytest.approx(default_s + 10.0 / 0.3 - 10.0 / 0.5)
        assert built == [default_s, pytest.approx(expect)]


def test_a_relay_sent_home_lands_from_its_return_altitude_when_that_is_higher():
    """A relay sent home by RTL climbs to its return altitude first (gcs/landing.py: PX4
    RTL::computeReturnAltitude, ArduCopter compute_return_target) and lands from there: the
    audit reads RTL_RETURN_ALT / RTL_ALT with the landing, and the plan counts the descent from
    the higher of the layer and it. PX4's default 60 m is above the 50-m layer; an ArduCopter
    whose RTL_ALT was raised (over terrain, 90 m) lands from 90 m; the firmware's 15 m does not
    count."""
    from test_operations import AP_SAFE, PX4_SAFE_WITHOUT_COM_OBL_ACT, answer_audit

    from gcs.autopilot import PX4
    from gcs.landing import landing_descent, return_alt_m

    px4_safe = {**PX4_SAFE_WITHOUT_COM_OBL_ACT, "MPC_Z_VEL_MAX_DN": 1.5}
    assert return_alt_m(PX4) == 60.0 and return_alt_m(ARDUPILOT) == 15.0
    assert return_alt_m(ARDUPILOT, {"RTL_ALT": 9000.0}) == 90.0
    cases = [
        (PX4, {**px4_safe, "RTL_RETURN_ALT": 60.0}, landing_descent(PX4).time_s(60.0)),
        (PX4, {**px4_safe, "RTL_RETURN_ALT": 30.0}, landing_descent(PX4).time_s(50.0)),
        (
            ARDUPILOT,
            {**AP_SAFE, "WPNAV_SPEED_DN": 150.0, "RTL_ALT": 9000.0},
            landing_descent(ARDUPILOT).time_s(90.0),
        ),
        (
            ARDUPILOT,
            {**AP_SAFE, "WPNAV_SPEED_DN": 150.0, "RTL_ALT": 1500.0},
            landing_descent(ARDUPILOT).time_s(50.0),
        ),
    ]
    for autopilot, answers, expect in cases:
        rot = RotationSetup(
            RotationPolicy(2, 1, BaseResources(pads=1), EnduranceParams(land_s=1.0)),
            hover_drain_per_s=1.0 / 1500.0,
            land_from_m=50.0,
            replan=lambda land_s: RotationPolicy(
                2, 1, BaseResources(pads=1), EnduranceParams(land_s=land_s)
            ),
        )
        op, feed, (v,) = _audited(rot, 1, autopilot)
        feed.poll(0.0)
        asked = {c[2] for c in op.station.of("request_param", v)}
        assert ("RTL_RETURN_ALT" if autopilot == PX4 else "RTL_ALT") in asked
        answer_audit(feed, op.station, 0.5, answers, vid=v)
        feed.run(0.75, 10.0, 0.25, until=lambda op: op.phase != "audit")
        assert op.phase == "launch", (autopilot, answers)
        assert rot.policy.params.land_s == pytest.approx(expect), (autopilot, answers)


def test_a_vehicle_without_the_landing_parameters_is_not_held_and_lands_at_the_defaults():
    """The landing's own parameters are optional reads (a firmware may spell them otherwise):
    unanswered, the audit goes on after its grace and the plan keeps the firmware's default."""
    from test_operations import AP_SAFE, answer_audit

    from gcs.landing import landing_descent
    from gcs.operations.audit import OPTIONAL_GRACE_S

    default_s = landing_descent(ARDUPILOT).time_s(50.0)
    rot = RotationSetup(
        RotationPolicy(2, 1, BaseResources(pads=1), EnduranceParams(land_s=default_s)),
        hover_drain_per_s=1.0 / 1500.0,
        land_from_m=50.0,
        replan=lambda land_s: RotationPolicy(
            2, 1, BaseResources(pads=1), EnduranceParams(land_s=land_s)
        ),
    )
    op, feed, vids = _audited(rot, 2)
    feed.poll(0.0)
    for v in vids:  # no LAND_* answered (WPNAV_SPEED_DN, a limit too, is)
        answer_audit(feed, op.station, 0.5, {**AP_SAFE, "WPNAV_SPEED_DN": 150.0}, vid=v)
    t = feed.run(0.75, 10.0, 0.25, until=lambda op: op.phase != "audit")
    assert op.phase == "launch" and t <= 0.5 + OPTIONAL_GRACE_S + 1.0  # a poll per round
    assert rot.policy.params.land_s == pytest.approx(default_s)

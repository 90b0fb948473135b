"""A vehicle discovered after the fleet's pre-flight audit is audited on its own before it may fly
(gcs/operations/late_audit.py): in memory, explicit time, the fakes of test_operations."""

from __future__ import annotations

import logging

import numpy as np
from test_operations import (
    AP_SAFE,
    CONTROL,
    ORIGIN,
    REAL32,
    FakePlanner,
    FakeStation,
    Feed,
    answer_audit,
    make,
)

from gcs import audit as audit_mod
from gcs.autopilot import ARDUPILOT
from gcs.events import BatteryReceived, ParamSetConfirmed, ParamTimedOut, VehicleRebooted
from gcs.fleet import FleetView
from gcs.landing import FIRMWARE_DEFAULTS
from gcs.operations import OperationsConfig, Operator
from gcs.operations.rotation import RotationSetup
from gcs.wire import mavlink
from planner.endurance import LOST, READY, BaseResources, EnduranceParams, RotationPolicy

INT8 = mavlink.MAV_PARAM_TYPE_INT8
#: What launches or steers a vehicle (a late vehicle gets none of these before it is cleared).
FLIGHT_COMMANDS = ("engage_guided", "arm", "takeoff", "set_position_target")
UNSAFE = {**AP_SAFE, "FS_GCS_ENABLE": 0.0}  # no lost-link failsafe: the audit blocks
#: ArduCopter limits already at the mission's 10 m/s (cm/s; no climb rate: the climb is kept).
LIMITS_OK = {"WPNAV_SPEED": 1000.0, "WPNAV_SPEED_UP": 250.0}


def _flying_fleet(**cfg) -> tuple[Operator, FakeStation, Feed, list, tuple[int, int]]:
    """Vehicle 1 audited (safe), launched and flying: the run at t=1. Returns with its vid."""
    op, station, feed, (v,) = make(1, audit=True, **cfg)
    feed.poll(0.0)
    assert op.phase == "audit"
    answer_audit(feed, station, 0.5, {**AP_SAFE, **LIMITS_OK}, vid=v)
    feed.poll(0.75)
    assert op.phase == "launch"
    feed.fly(v, 1.0)
    feed.poll(1.0)
    assert op.phase == "run"
    seen: list = []
    op.on_action = seen.append
    return op, station, feed, seen, v


def _commanded(station: FakeStation, vid) -> list[str]:
    return [c[0] for c in station.calls if c[0] in FLIGHT_COMMANDS and c[1] == vid]


def _row_alive(op: Operator, vid) -> bool:
    """Whether the planner's last tick counted the vehicle (in the plan)."""
    return bool(op.planner.ticks[-1].alive[op.fleet.index_of(*vid)])


def test_a_late_unsafe_vehicle_is_fixed_with_apply_failsafes_and_then_launched():
    op, station, feed, seen, _ = _flying_fleet(apply_failsafes=True)
    late = feed.add(2, 2.0)
    feed.poll(2.0)
    asked = [c[2] for c in station.of("request_param", late)]
    assert asked == list(audit_mod.params_still_needed(ARDUPILOT, {}))
    feed.run(2.25, 5.0)
    # Reads pending: on the ground, neither armed nor commanded, nor in the plan.
    assert _commanded(station, late) == []
    assert not _row_alive(op, late)
    answer_audit(feed, station, 5.1, UNSAFE, vid=late, ptype=INT8)
    feed.poll(5.25)
    sets = station.of("set_param", late)
    assert [(c[2], c[3], c[6]) for c in sets] == [("FS_GCS_ENABLE", 1.0, 0.0)]
    assert op.late_audits[late].initial_report is not None
    assert not op.late_audits[late].initial_report.cleared_to_fly
    feed.run(5.5, 8.0)
    assert _commanded(station, late) == []  # the fix is not confirmed yet
    assert op.late_audits[late].verdict == "pending" and seen == []
    feed.param(late, "FS_GCS_ENABLE", 1.0, 8.1, INT8)
    feed.emit(ParamSetConfirmed(*late, 8.1, "FS_GCS_ENABLE", 1.0, 0.0, INT8))
    feed.poll(8.25)
    assert op.late_audits[late].verdict == "cleared"
    assert op.late_audits[late].report is not None and op.late_audits[late].report.cleared_to_fly
    assert _commanded(station, late) == ["engage_guided", "arm", "takeoff"]
    assert [(a.action, a.link_id, a.sysid, a.result) for a in seen] == [("audit", *late, "cleared")]
    (change,) = [c for c in op.param_changes if c["sysid"] == late[1]]
    assert (change["name"], change["ok"], change["purpose"]) == ("FS_GCS_ENABLE", True, "failsafe")
    feed.fly(late, 9.0)
    feed.run(9.0, 11.0)
    assert _row_alive(op, late)  # now planned with the fleet
    assert op.late_audit_summary() == [
        {"link_id": 0, "sysid": 2, "verdict": "cleared", "started_s": 2.0, "blocking": []}
    ]


def test_a_late_unsafe_vehicle_without_apply_failsafes_stays_on_the_ground_and_is_reported(
    caplog,
):
    op, station, feed, seen, v = _flying_fleet()
    late = feed.add(2, 2.0)
    feed.poll(2.0)
    answer_audit(feed, station, 2.5, UNSAFE, vid=late)
    with caplog.at_level(logging.WARNING, logger="gcs.operations.late_audit"):
        feed.run(2.75, 60.0)
    assert op.phase == "run"  # the fleet flies on
    assert station.of("set_param", late) == []  # nothing is written without the flag
    assert _commanded(station, late) == []
    assert not _row_alive(op, late)
    assert _commanded(station, v)  # the audited vehicle is flown as before
    assert op.late_audits[late].verdict == "refused"
    ((rec,),) = [[a for a in seen if a.sysid == 2]]
    assert rec.action == "audit" and rec.result.startswith("refused (FS_GCS_ENABLE")
    (summary,) = op.late_audit_summary()
    assert summary["verdict"] == "refused" and summary["blocking"][0].startswith("FS_GCS_ENABLE")
    assert any(
        "failed it" in r.getMessage() and "sysid 2" in r.getMessage() for r in caplog.records
    )
    # an operator's rejoin does not put it back in the plan
    op.operator_command("rejoin", late, 61.0)
    feed.run(61.0, 70.0)
    assert _commanded(station, late) == []


def test_a_late_safe_vehicle_gets_the_limits_and_is_launched_after_its_audit():
    op, station, feed, seen, _ = _flying_fleet(max_speed_m_s=10.0)
    late = feed.add(2, 2.0)
    feed.poll(2.0)
    asked = [c[2] for c in station.of("request_param", late)]
    assert "WPNAV_SPEED" in asked
    feed.run(2.25, 4.0)
    assert _commanded(station, late) == []
    answer_audit(feed, station, 4.1, {**AP_SAFE, **LIMITS_OK, "WPNAV_SPEED": 500.0}, vid=late)
    feed.poll(4.25)
    assert [(c[2], c[3]) for c in station.of("set_param", late)] == [("WPNAV_SPEED", 1000.0)]
    feed.run(4.5, 6.0)
    assert _commanded(station, late) == []  # the limit is not confirmed yet
    feed.emit(ParamSetConfirmed(*late, 6.1, "WPNAV_SPEED", 1000.0, 500.0, REAL32))
    feed.poll(6.25)
    assert op.late_audits[late].verdict == "cleared"
    assert _commanded(station, late) == ["engage_guided", "arm", "takeoff"]
    assert [a.result for a in seen] == ["cleared"]


def test_a_late_vehicle_whose_reads_time_out_is_asked_again_then_refused():
    op, station, feed, seen, _ = _flying_fleet(audit_rounds=2)
    late = feed.add(2, 2.0)
    feed.run(2.0, 4.0)
    first = [c[2] for c in station.of("request_param", late)]
    for name in first:  # the link gave up on every read (its own retries spent)
        feed.emit(ParamTimedOut(*late, 4.1, name, 3))
    feed.poll(4.25)
    assert op.late_audits[late].round == 2
    again = [c[2] for c in station.of("request_param", late, since_s=4.25)]
    assert again == [n for n in first if n not in audit_mod.OPTIONAL_PARAMS]
    assert op.late_audits[late].verdict == "pending"
    for name in again:
        feed.emit(ParamTimedOut(*late, 6.1, name, 3))
    feed.run(6.25, 40.0)
    assert op.late_audits[late].verdict == "refused"  # unread: unknown lost-link behaviour
    assert len(station.of("request_param", late)) == len(first) + len(again)  # two rounds
    assert _commanded(station, late) == []


def test_a_rebooted_vehicle_is_not_audited_again():
    op, station, feed, seen, v = _flying_fleet()
    late = feed.add(2, 2.0)
    feed.poll(2.0)
    answer_audit(feed, station, 2.5, vid=late)
    feed.poll(2.75)
    assert op.late_audits[late].cleared
    reads = len(station.of("request_param"))
    # A power cycle of each (a battery swap): the same link and sysid, parameters kept.
    feed.emit(VehicleRebooted(*v, 20.0, 18.0, 0.5))
    feed.emit(VehicleRebooted(*late, 20.0, 17.0, 0.5))
    feed.run(20.0, 40.0)
    assert len(station.of("request_param")) == reads
    assert list(op.late_audits) == [late] and op.late_audits[late].cleared
    assert v not in op.late_audits


def test_a_vehicle_heard_after_the_last_read_round_does_not_refuse_the_fleet():
    op, station, feed, (v,) = make(1, audit=True, audit_rounds=1)
    feed.poll(0.0)
    late = feed.add(2, 0.3)  # during the audit, after its (only) round of reads was asked
    feed.poll(0.3)
    answer_audit(feed, station, 0.5, vid=v)
    feed.poll(0.75)
    assert op.phase == "launch"  # the fleet's verdict is on what it read: vehicle 1
    assert [(a.link_id, a.sysid) for a in op.audit_report.vehicles] == [v]
    assert _commanded(station, v) == ["engage_guided", "arm", "takeoff"]
    feed.poll(1.0)
    assert station.of("request_param", late)  # audited on its own
    assert _commanded(station, late) == []
    answer_audit(feed, station, 1.1, vid=late)
    feed.fly(v, 1.25)
    feed.run(1.25, 3.0)
    assert op.phase == "run" and op.late_audits[late].cleared
    assert _commanded(station, late) == ["engage_guided", "arm", "takeoff"]


def test_no_late_audit_with_the_audit_off():
    op, station, feed, vids = make(1)  # audit off
    feed.poll(0.0)
    feed.fly(vids[0], 1.0)
    feed.poll(1.0)
    assert op.phase == "run"
    late = feed.add(2, 2.0)
    feed.poll(2.0)
    assert station.of("request_param") == [] and op.late_audits == {}
    assert _commanded(station, late) == ["engage_guided", "arm", "takeoff"]


def test_with_a_rotation_a_late_vehicle_is_lost_to_it_until_cleared_then_a_spare():
    # Three drones, two flown: row 0 audited with the fleet; rows 1 (a relay's slot) and 2 (the
    # spare) heard after the audit. Row 2 passes its own audit; row 1 never answers: it is never
    # a vehicle of the rotation (the policy does not count on a drone the audit refused).
    policy = RotationPolicy(
        3,
        2,
        BaseResources(pads=1, swap_time_s=60.0, spare_batteries=4),
        EnduranceParams(critical_frac=0.2, return_speed_m_s=5.0),
    )
    rot = RotationSetup(policy, hover_drain_per_s=1.0 / 1500.0)
    station = FakeStation()
    op = Operator(
        station,
        FleetView(ORIGIN, timeout_s=5.0),
        FakePlanner(),
        lambda t: np.array([[150.0, 0.0]]),
        CONTROL,
        OperationsConfig(
            audit=True, expected_vehicles=1, duration_s=10_000.0, audit_timeout_s=20.0
        ),
        rotation=rot,
    )
    feed = Feed(op)
    v = feed.add(1, 0.0)
    feed.poll(0.0)
    # With a rotation the audit reads the landing too (gcs/landing.py): the firmware's defaults.
    # and the return altitude a relay sent home lands from (RTL_ALT).
    landing = {**AP_SAFE, **FIRMWARE_DEFAULTS[ARDUPILOT], "RTL_ALT": 1500.0}
    answer_audit(feed, station, 0.5, landing, vid=v)
    feed.poll(0.75)
    assert op.phase == "launch"
    silent_late = feed.add(2, 0.8)
    spare = feed.add(3, 0.8)
    feed.fly(v, 1.0)

    def run(t0: float, t1: float) -> None:
        t = t0
        while t <= t1 + 1e-9:
            for vid in (v, silent_late, spare):
                feed.emit(BatteryReceived(*vid, t, "SYS_STATUS", 1.0, 15.0, 20.0))
            feed.poll(t)
            t = round(t + 0.5, 9)

    run(1.0, 2.0)
    answer_audit(feed, station, 2.1, landing, vid=spare)
    run(2.5, 45.0)  # the launch's wave timeout (40 s), then the run
    assert op.phase == "run"
    assert op.late_audits[spare].cleared and op.late_audits[silent_late].verdict == "refused"
    assert policy.phase[1] == LOST  # never a vehicle of the rotation
    assert policy.phase[2] == READY  # lost to the rotation until cleared, then a spare
    assert [(e.kind, e.drone) for e in rot.events if e.drone == 2] == [
        ("lost", 2),
        ("recovered", 2),
    ]
    assert _commanded(station, silent_late) == [] and _commanded(station, spare) == []

"""Station core <-> emulated vehicles in memory: virtual clock, seeded lossy ether, no sockets.

The ether (:class:`mission.flight.runners.LockstepEther`) moves datagrams between the station's links
and a :class:`vehicle_emu.swarm.Swarm` (its vehicle cores); time moves only when told to.
"""

from __future__ import annotations

import dataclasses
import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from gcs.events import (
    ArmedChanged,
    CommandTimedOut,
    ParamSetConfirmed,
    VehicleDiscovered,
    VehicleLost,
)
from gcs.control import layer_alt_m
from inmemory_flight import InMemoryFlight as _InMemoryFlight
from mission.flight.station_loop import make_operator
from small_mission import crew, small_mission
from mission.flight.ether import LockstepEther, station_for_swarm
from mission.flight.fly_options import FlyOptions
from mission.flight.mission_world import mission_scenario
from mission.format.schema import (
    Attrition,
    RunSpec,
    ScriptedLoss,
    Task,
    TrackPoint,
)
from vehicle_emu.swarm import Swarm


def _pair(n=3, personality="ardupilot", loss=0.0, seed=0, **station_cfg):
    swarm = Swarm(n, personality=personality, mux=True, rng=np.random.default_rng(seed))
    station = station_for_swarm(swarm, **station_cfg)
    ether = LockstepEther(swarm, station, np.random.default_rng(seed + 1), loss=loss)
    events = []
    ether.on_event = events.append
    return swarm, station, ether, events


def test_discovery_over_a_lossy_ether():
    swarm, station, ether, events = _pair(n=5, loss=0.2)
    ether.advance_to(3.0)
    found = {e.sysid for e in events if isinstance(e, VehicleDiscovered)}
    assert found == {1, 2, 3, 4, 5}
    assert all(e.t_s <= 3.0 for e in events if isinstance(e, VehicleDiscovered))


def test_heartbeat_loss_is_lost_within_the_timeout():
    swarm, station, ether, events = _pair(n=2)
    ether.advance_to(2.0)
    ether.cut_links.add(0)
    t_cut = ether.now_s
    ether.advance_to(10.0)
    lost = [e for e in events if isinstance(e, VehicleLost)]
    assert {e.sysid for e in lost} == {1, 2}
    timeout = station.links[0].config.vehicle_timeout_s
    for e in lost:
        # Last heartbeat at most 1 s before the cut; lost within the timeout plus one tick.
        assert e.t_s - e.last_heartbeat_s <= timeout + 0.1
        assert e.t_s <= t_cut + timeout + 0.1


def test_command_retries_then_times_out():
    swarm, station, ether, events = _pair(n=1)
    ether.advance_to(1.5)
    ether.cut_links.add(0)
    rid = station.arm((0, 1), ether.now_s)
    ether.advance_to(ether.now_s + 5.0)
    cfg = station.links[0].config
    out = [e for e in events if isinstance(e, CommandTimedOut) and e.request_id == rid]
    assert len(out) == 1 and out[0].attempts == cfg.command_retries + 1
    assert out[0].command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM


def _frames_out(station, kinds):
    out = []
    for t, outgoing, frame in station.links[0].take_frames():
        if not outgoing:
            continue
        m = mavlink.MAVLink(None)
        m.robust_parsing = True
        for msg in m.parse_buffer(frame) or []:
            if msg.get_type() in kinds:
                out.append((t, msg))
    return out


def test_px4_offboard_engaged_only_after_prestreaming():
    swarm, station, ether, events = _pair(n=1, personality="px4", record_frames=True)
    ether.advance_to(2.0)
    station.links[0].take_frames()
    station.takeoff((0, 1), 10.0, ether.now_s)
    ether.pump()
    ether.advance_to(ether.now_s + 6.0)
    frames = _frames_out(station, {"SET_POSITION_TARGET_GLOBAL_INT", "COMMAND_LONG"})
    first_sp = min(t for t, m in frames if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT")
    mode_cmds = [
        (t, m)
        for t, m in frames
        if m.get_type() == "COMMAND_LONG"
        and m.command in (mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_CMD_COMPONENT_ARM_DISARM)
    ]
    assert mode_cmds, "OFFBOARD / arm never sent"
    assert min(t for t, _ in mode_cmds) >= first_sp + 1.0  # PX4: > 1 s of setpoints first
    sp_times = sorted(t for t, m in frames if m.get_type() == "SET_POSITION_TARGET_GLOBAL_INT")
    assert np.max(np.diff(sp_times)) < 0.5  # streamed at > 2 Hz
    info = station.links[0].vehicle(1)
    assert info.mode == "OFFBOARD" and info.armed


# ------------------------------------------------------------------ the operator, in memory


def _mission(n=6, personality="ardupilot", duration_s=60.0, kills=(), tasks=None, radio=100.0):
    return small_mission(
        "pair",
        RunSpec(duration_s=duration_s, control_period_s=1.0, seed=3),
        count=n,
        personality=personality,
        tasks=tasks or (crew(60.0, 40.0), crew(-50.0, -60.0)),
        radio_m=radio,
        attrition=Attrition(scripted=tuple(ScriptedLoss(vehicle=i, t_s=t) for t, i in kills)),
    )


def test_launch_run_end_in_memory():
    f = _InMemoryFlight(_mission(duration_s=30.0))
    f.run_until_phase("run")
    assert f.op.audit_report.cleared_to_fly and not f.op.audit_report.overridden
    f.run_until_phase("done")
    recs = f.op.records
    assert len(recs) >= 29 and recs[-1].planned == 6
    tu1, _ = f.op.station_tu()
    truth = f.world.truth_tu(30.0)
    assert tu1 > 0.9 and truth["tu1"] > 0.9


def test_audit_refuses_unsafe_vehicles_unless_overridden():
    f = _InMemoryFlight(_mission(n=2), params={"FS_GCS_ENABLE": 0})
    f.run_until_phase("refused", limit_s=80.0)
    assert {(a.link_id, a.sysid) for a in f.op.audit_report.unsafe} == {(0, 1), (0, 2)}


def test_audit_refusal_writes_no_parameter_without_the_flag():
    f = _InMemoryFlight(_mission(n=2), params={"FS_GCS_ENABLE": 0}, record=True)
    f.run_until_phase("refused", limit_s=80.0)
    assert [c.params["FS_GCS_ENABLE"] for c in f.swarm.cores] == [0, 0]
    assert f.op.param_changes == []
    assert not any(m.get_type() == "PARAM_SET" for m in _sent_messages(f))


def _sent_messages(f):
    out = []
    for _t, outgoing, frame in f.station.links[0].take_frames():
        if outgoing:
            m = mavlink.MAVLink(None)
            m.robust_parsing = True
            out += m.parse_buffer(frame) or []
    return out


def test_apply_failsafes_fixes_ardupilot_and_launches():
    f = _InMemoryFlight(
        _mission(n=2, duration_s=10.0), params={"FS_GCS_ENABLE": 0}, apply_failsafes=True
    )
    f.run_until_phase("run", limit_s=150.0)
    assert [c.params["FS_GCS_ENABLE"] for c in f.swarm.cores] == [1, 1]
    assert f.op.initial_audit_report is not None and not f.op.initial_audit_report.cleared_to_fly
    assert f.op.audit_report.cleared_to_fly and not f.op.audit_report.overridden
    ok = sorted(
        (c["sysid"], c["name"], c["previous"], c["value"], c["ok"]) for c in f.op.param_changes
    )
    assert ok == [(1, "FS_GCS_ENABLE", 0, 1, True), (2, "FS_GCS_ENABLE", 0, 1, True)]
    assert {e.sysid for e in f.events if isinstance(e, ParamSetConfirmed)} == {1, 2}


def test_apply_failsafes_sets_the_gcs_sysid_the_vehicle_has():
    f = _InMemoryFlight(
        _mission(n=1, duration_s=10.0),
        params={"FS_GCS_ENABLE": 0, "SYSID_MYGCS": 200},
        apply_failsafes=True,
    )
    f.run_until_phase("run", limit_s=150.0)
    core = f.swarm.cores[0]
    assert (core.params["FS_GCS_ENABLE"], core.params["SYSID_MYGCS"]) == (1, 255)
    assert {c["name"] for c in f.op.param_changes if c["ok"]} == {"FS_GCS_ENABLE", "SYSID_MYGCS"}


def test_apply_failsafes_fixes_px4_nav_dll_act_bytewise():
    f = _InMemoryFlight(
        _mission(n=2, personality="px4", duration_s=10.0),
        params={"NAV_DLL_ACT": 0},
        apply_failsafes=True,
        record=True,
    )
    f.run_until_phase("run", limit_s=150.0)
    assert [c.params["NAV_DLL_ACT"] for c in f.swarm.cores] == [2, 2]
    sets = [m for m in _sent_messages(f) if m.get_type() == "PARAM_SET"]
    assert sets and all(m.param_type == mavlink.MAV_PARAM_TYPE_INT32 for m in sets)
    # PX4 copies the float's bytes into the INT32 (mavlink_parameters.cpp): 2 as a bit pattern.
    assert {struct.pack("<f", m.param_value) for m in sets} == {struct.pack("<i", 2)}
    assert all(c["ok"] for c in f.op.param_changes) and len(f.op.param_changes) == 2
    assert f.op.audit_report.cleared_to_fly and not f.op.audit_report.overridden


def test_apply_failsafes_fixes_a_disarming_offboard_loss_action():
    # COM_OBL_RC_ACT 6 (terminate on offboard loss) and NAV_DLL_ACT 0 are both written to
    # Return (gcs/audit.py failsafe_fixes), confirmed by the echo, and the flight is cleared.
    f = _InMemoryFlight(
        _mission(n=1, personality="px4"),
        params={"NAV_DLL_ACT": 0, "COM_OBL_RC_ACT": 6},
        apply_failsafes=True,
    )
    f.run_until_phase("launch", limit_s=120.0)
    core = f.swarm.cores[0]
    assert core.params["NAV_DLL_ACT"] == 2 and core.params["COM_OBL_RC_ACT"] == 3
    assert f.op.audit_report.cleared_to_fly and not f.op.audit_report.overridden
    written = {c["name"] for c in f.op.param_changes if c["ok"]}
    assert {"NAV_DLL_ACT", "COM_OBL_RC_ACT"} <= written


@pytest.mark.parametrize(
    "personality,ready_s", [("ardupilot", 40.0), ("ardupilot", 70.0), ("px4", 70.0)]
)
def test_launch_waits_for_vehicles_that_are_not_ready_to_arm(personality, ready_s):
    # Every vehicle refuses to arm until its EKF is ready (SITL: ~40 s after boot). The launch
    # keeps asking at a steady pace (no runaway back-off), reports the PreArm text, and starts
    # the run only once the fleet has climbed.
    f = _InMemoryFlight(
        _mission(n=4, personality=personality, duration_s=10.0), ekf_ready_s=ready_s
    )
    f.run_until_phase("run", limit_s=ready_s + 120.0)
    armed = {}
    for e in f.events:
        if isinstance(e, ArmedChanged) and e.armed:
            armed.setdefault(e.sysid, e.t_s)
    assert set(armed) == {1, 2, 3, 4}
    cfg = f.op.config
    assert min(armed.values()) >= ready_s
    assert max(armed.values()) <= ready_s + cfg.prearm_retry_s + 2.0
    assert set(f.op.prearm) == {(0, 1), (0, 2), (0, 3), (0, 4)}
    assert all("not ready" in text or "denied" in text for _, text in f.op.prearm.values())
    # The run started with the fleet up, not on a timeout with vehicles on the ground.
    snap = f.op.fleet.snapshot(f.ether.now_s)
    alt = f.op._height_m(snap)
    target = layer_alt_m(np.arange(snap.n_vehicles), f.op.control)
    assert (alt >= cfg.climbed_alt_frac * target).mean() >= cfg.wave_climbed_frac
    assert f.op.mission_t0_s > max(armed.values())


def test_reclaim_after_gcs_failsafe():
    f = _InMemoryFlight(_mission(n=3, duration_s=120.0))
    f.run_until_phase("run")
    f.run_until(f.ether.now_s + 5.0)
    f.ether.cut_links.add(0)  # the station goes deaf and mute
    f.run_until(f.ether.now_s + 8.0)  # FS_GCS_TIMEOUT 5 s: every vehicle in RTL
    assert all(c.custom_mode == 6 for c in f.swarm.cores)  # ArduCopter RTL
    f.ether.cut_links.clear()
    t_back = f.ether.now_s
    f.run_until(t_back + 10.0)
    assert {s for _, _, s in f.op.reclaimed} == {1, 2, 3}
    assert all(c.custom_mode == 4 for c in f.swarm.cores)  # GUIDED again
    assert f.op.records[-1].planned == 3


def test_killed_vehicle_is_detected_and_the_plan_closes_the_gap():
    mission = _mission(n=8, duration_s=90.0, kills=[(30.0, 0)])
    f = _InMemoryFlight(mission)
    f.run_until_phase("run")
    t0 = f.op.mission_t0_s
    f.run_until(t0 + 29.0)
    before = f.op.records[-1]
    f.run_until(t0 + 90.0)
    lost = [e for e in f.events if isinstance(e, VehicleLost) and e.sysid == 1]
    assert lost and lost[0].t_s <= t0 + 30.0 + 5.0 + 0.5
    after = f.op.records[-1]
    assert after.planned == before.planned - 1
    assert after.tasks_covered == after.n_tasks  # the others closed the gap
    assert f.world.truth_tu(90.0)["tu1"] > 0.9


def test_relay_loss_cuts_a_branch_whose_vehicles_return_and_are_reclaimed():
    # One far task (180 m, radio 100 m): a chain base -> relay -> far drone(s). Kill the relays
    # next to the base: the far branch loses the station, fails safe (RTL), flies home, comes
    # back into range and is reclaimed.
    tasks = (Task(track=(TrackPoint(t_s=0.0, north_m=180.0, east_m=0.0),)),)
    f = _InMemoryFlight(_mission(n=4, duration_s=200.0, tasks=tasks))
    f.run_until_phase("run")
    t0 = f.op.mission_t0_s
    f.run_until(t0 + 60.0)
    pos = f.swarm.physics.pos_ned_m[:, :2]
    dist = np.linalg.norm(pos, axis=1)
    far = np.flatnonzero(dist > 100.0)
    assert len(far), "no drone beyond direct base range"
    relays = [i for i in np.argsort(dist) if dist[i] <= 100.0]
    for i in relays:
        f.swarm.kill(int(i), f.ether.now_s, "test")
    f.run_until(t0 + 150.0)
    far_sysids = {int(f.swarm.sysid_of_index[i]) for i in far}
    lost = {e.sysid for e in f.events if isinstance(e, VehicleLost)}
    assert far_sysids <= lost
    assert far_sysids <= {s for _, _, s in f.op.reclaimed}


# ------------------------------------------------------------------ limits, operator, restart


def _with_speed(mission, max_speed_m_s):
    emu = dataclasses.replace(mission.vehicles.emulated, max_speed_m_s=max_speed_m_s)
    return dataclasses.replace(
        mission, vehicles=dataclasses.replace(mission.vehicles, emulated=emu)
    )


@pytest.mark.parametrize(
    "personality,firmware_defaults,expect",
    [
        (
            "ardupilot",
            {"WPNAV_SPEED": 1000.0, "WPNAV_SPEED_UP": 250.0},
            {"WPNAV_SPEED": 400.0, "WPNAV_SPEED_UP": 500.0},
        ),
        (
            "px4",
            {"MPC_XY_VEL_MAX": 12.0, "MPC_XY_CRUISE": 5.0, "MPC_Z_VEL_MAX_UP": 3.0},
            {"MPC_XY_VEL_MAX": 4.0, "MPC_XY_CRUISE": 4.0, "MPC_Z_VEL_MAX_UP": 5.0},
        ),
    ],
)
def test_the_missions_limits_are_written_into_the_firmware_and_restored(
    personality, firmware_defaults, expect
):
    # The firmware's own defaults (faster than the mission) are replaced by the mission's limits
    # at launch (gcs/limits.py), each confirmed by its echo, and written back after landing.
    f = _InMemoryFlight(
        _with_speed(_mission(n=2, personality=personality, duration_s=5.0), 4.0),
        params=firmware_defaults,
        restore_params=True,
    )
    f.run_until_phase("run", limit_s=120.0)
    for core in f.swarm.cores:
        assert {k: core.params[k] for k in expect} == pytest.approx(expect)
    limits = [c for c in f.op.param_changes if c.get("purpose") == "limit"]
    assert {c["name"] for c in limits} == set(expect) and all(c["ok"] for c in limits)
    f.run_until_phase("done", limit_s=400.0)
    assert f.op.end_status["in_air"] == 0  # done = landed, not merely "in RTL"
    for core in f.swarm.cores:
        assert {k: core.params[k] for k in expect} == pytest.approx(firmware_defaults)


def test_keep_firmware_limits_writes_nothing():
    f = _InMemoryFlight(
        _with_speed(_mission(n=2), 4.0), params={"WPNAV_SPEED": 1000.0}, set_limits=False
    )
    f.run_until_phase("run", limit_s=120.0)
    assert f.op.param_changes == []
    assert all(core.params["WPNAV_SPEED"] == 1000.0 for core in f.swarm.cores)


def test_a_restarted_station_counts_its_reclaims():
    # The first station flies, goes silent (killed): every vehicle fails safe to RTL. A new
    # station (new Operator, nothing remembered) finds them airborne in RTL and reclaims them:
    # counted exactly as reclaims after a failsafe on the first run.
    f = _InMemoryFlight(_mission(n=3, duration_s=120.0))
    f.run_until_phase("run")
    f.run_until(f.ether.now_s + 5.0)
    f.ether.cut_links.add(0)
    f.run_until(f.ether.now_s + 8.0)
    assert all(c.custom_mode == 6 for c in f.swarm.cores)  # ArduCopter RTL
    mission = _mission(n=3, duration_s=120.0)
    now = f.ether.now_s
    scenario = mission_scenario(mission, 3)
    station = station_for_swarm(f.swarm, now_s=now)
    op = make_operator(mission, scenario, station, FlyOptions(wave_size=10), 3, now, 3)
    ether = LockstepEther(f.swarm, station, np.random.default_rng(4), now_s=now)
    ether.on_event = op.handle_event
    ether.advance_to(now + 40.0, poll=op.poll, poll_period_s=0.5)
    assert op.phase == "run"
    assert {s for _, _, s in op.reclaimed} == {1, 2, 3}
    assert all(c.custom_mode == 4 for c in f.swarm.cores)  # GUIDED again


def test_operator_actions_release_rtl_and_rejoin():
    f = _InMemoryFlight(_mission(n=4, duration_s=200.0))
    f.run_until_phase("run")
    f.run_until(f.ether.now_s + 3.0)
    now = f.ether.now_s
    (rec,) = f.op.operator_command("rtl", (0, 2), now, source="test")
    assert rec.result == "sent" and (0, 2) in f.op.released
    f.run_until(now + 3.0)
    core = f.swarm.cores[1]
    assert core.custom_mode == 6  # RTL: not reclaimed, not planned
    assert f.op.records[-1].planned == 3
    assert not any(s == 2 for _, _, s in f.op.reclaimed)
    f.op.operator_command("rejoin", (0, 2), f.ether.now_s, source="test")
    f.run_until(f.ether.now_s + 6.0)
    assert core.custom_mode == 4 and f.op.records[-1].planned == 4
    with pytest.raises(ValueError):
        f.op.operator_command("explode", None, f.ether.now_s)


@pytest.mark.parametrize("action,mode", [("end", 6), ("hold", 4), ("land", 9)])
def test_interrupt_tells_every_vehicle_and_reports_it(action, mode):
    f = _InMemoryFlight(_mission(n=3, duration_s=200.0))
    f.run_until_phase("run")
    f.run_until(f.ether.now_s + 3.0)
    f.op.interrupt(action, f.ether.now_s)
    f.run_until(f.ether.now_s + 3.0)
    assert all(c.custom_mode == mode for c in f.swarm.cores)  # ArduCopter RTL 6 GUIDED 4 LAND 9
    report = f.op.interrupt_report(f.ether.now_s)
    assert len(report) == 3 and all(ok for _, _, ok in report), report

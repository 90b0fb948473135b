"""The relay rotation for the operator, in memory with explicit time: the frame's ``rotation`` key
(mission/view/live/rotation.py) from the station's rotation state, ``rotation.jsonl`` written only
when the state changes and read back by the replay, the status line's rotation field and the
closing summary's line (mission/commands/fly.py)."""

from __future__ import annotations

import io
import json
from types import SimpleNamespace

import numpy as np
import pytest
from status_rows import status_row

from gcs.events import TelemetryReceived, VehicleDiscovered
from gcs.fleet import FleetView, MissionOrigin
from gcs.operations.rotation_setup import RotationSetup
from mission.commands.fly import _Status, format_rotation, format_status, planned_drop
from mission.flight.run_dir import ROTATION_FILE, ROTATION_SNAPSHOT_S, Records, read_rotation
from mission.view.live.rotation import MAX_EVENTS, event_text, rotation_frame
from mission.view.live.replay import ReplaySource
from planner.endurance import (
    AIR,
    INBOUND,
    READY,
    RETURNING,
    BaseResources,
    EnduranceParams,
    RotationEvent,
    RotationPolicy,
)
from planner.geometry import ned_to_geodetic

ORIGIN = MissionOrigin(39.76, -121.62, 540.0)
#: north, east of each vehicle (sysids 1..4): two relays out, one spare on its way, one home.
POS = {1: (100.0, 0.0), 2: (0.0, 150.0), 3: (40.0, 120.0), 4: (0.0, 0.0)}


def _fleet(t_s: float) -> FleetView:
    fleet = FleetView(ORIGIN, timeout_s=5.0)
    for sysid, (n, e) in POS.items():
        lat, lon, alt = ned_to_geodetic(
            np.array([n, e, -20.0]), ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_amsl_m
        )
        fleet.apply(VehicleDiscovered(0, sysid, 0.0, autopilot=3, mode="GUIDED"))
        fleet.apply(
            TelemetryReceived(
                0,
                sysid,
                t_s,
                lat_deg=float(np.ravel(lat)[0]),
                lon_deg=float(np.ravel(lon)[0]),
                alt_amsl_m=float(np.ravel(alt)[0]),
                rel_alt_m=20.0,
            )
        )
    return fleet


def _rotation() -> RotationSetup:
    """Relays 1 and 2 in the plan, spare 3 inbound to relay 2, vehicle 4 home at t = 100 s: it
    lands and takes pad 1 (a 60-s swap); its battery goes to one of two chargers (600 s)."""
    policy = RotationPolicy(
        4,
        2,
        BaseResources(pads=2, swap_time_s=60.0, spare_batteries=5, chargers=2, charge_time_s=600.0),
        EnduranceParams(return_speed_m_s=5.0),
    )
    policy.phase[2], policy.phase[3] = INBOUND, RETURNING
    policy.replaces[2], policy.replaced_by[1] = 1, 2
    rot = RotationSetup(policy, hover_drain_per_s=1.0 / 1500.0, swap_confirm="manual")
    pos = np.array([v for _, v in sorted(POS.items())])
    alive = np.ones(4, bool)
    out = policy.step(
        100.0,
        pos,
        alive,
        np.array([0.6, 0.5, 0.95, 0.3]),
        np.full(4, 1e-3),
        networked=np.array([True, True, False, False]),
        landed_at_base=np.array([False, False, False, True]),
        swap_done=np.zeros(4, bool),
    )
    rot.events.extend(out.events)
    rot.time_to_reserve_s = np.array([300.0, 240.0, np.inf, np.inf])
    rot.tick_s = 100.0
    return rot


IDS = [f"0:{s}" for s in sorted(POS)]


def test_the_frame_names_pads_queue_batteries_and_phases():
    rot = _rotation()
    state = rot.state(IDS)
    t = 120.0
    f = rotation_frame(state, rot.event_dicts(0, IDS), _fleet(t).snapshot(t), t, 90.0)
    json.dumps(f, allow_nan=False)  # what the server sends
    assert f["swap_confirm"] == "manual"
    assert f["phase"] == ["air", "air", "inbound", "swapping"]
    assert f["pads"] == [
        {"pad": 1, "vehicle": "0:4", "elapsed_s": 20, "left_s": 40, "confirmed": False},
        {"pad": 2, "vehicle": None},
    ]
    # Spare 3 is 50 m from relay 2's post (30 north, 40 east): 10 s at 5 m/s.
    assert f["queue"] == [{"spare": "0:3", "relay": "0:2", "dist_m": 50, "eta_s": 10}]
    # Relay 1 (no spare yet) reaches its reserve 300 s after the tick at 100 s: 280 s from now.
    assert f["due"] == [{"relay": "0:1", "reserve_in_s": 280}]
    assert f["batteries"] == {
        "charged": 4,
        "charging_left_s": [580],
        "queued": 0,
        "chargers": 2,
    }
    texts = [e["text"] for e in f["events"]]
    assert "swap requested: vehicle 4 on a pad" in texts
    assert f["events"][-1]["t_mission_s"] == pytest.approx(10.0)


def test_a_crews_confirmation_shows_on_its_pad_and_in_words():
    rot = _rotation()
    rot.confirmed_s[3] = 110.0
    state = rot.state(IDS)
    assert state["pads"][0]["confirmed_s"] == 110.0
    f = rotation_frame(state, [], _fleet(130.0).snapshot(130.0), 130.0, None)
    assert f["pads"][0]["confirmed"] and f["pads"][0]["left_s"] == 30
    assert event_text({"kind": "crew_confirmed", "vehicle": "1:4", "other": None}) == (
        "the ground crew confirmed vehicle 1:4's swap"
    )


def test_rotation_jsonl_records_changes_only_and_the_replay_reads_it(tmp_path):
    """Records.rotation writes a line when the state changed or events came; the replay picks the
    last line at or before a frame and the events up to it."""
    rot = _rotation()
    op = SimpleNamespace(
        rotation_state=lambda: rot.state(IDS),
        rotation_events=lambda start=0: rot.event_dicts(start, IDS),
    )
    from mission.format.schema import RunSpec
    from small_mission import small_mission

    rec = Records(tmp_path, small_mission("records", RunSpec()), {})
    rec.rotation(op, 100.0)
    rec.rotation(op, 101.0)  # nothing changed: no line
    rot.confirmed_s[3] = 102.0
    rot.events.append(rot.events[-1].__class__(102.0, "crew_confirmed", 3))
    rec.rotation(op, 102.0)
    rec.close()
    lines = [json.loads(x) for x in (tmp_path / ROTATION_FILE).read_text().splitlines()]
    assert [x["t_s"] for x in lines] == [100.0, 102.0]
    assert [e["kind"] for e in lines[1]["events"]] == ["crew_confirmed"]
    got = ReplaySource._read_rotation(tmp_path / ROTATION_FILE)
    assert got is not None and [g["n_events"] for g in got] == [
        len(lines[0]["events"]),
        len(lines[0]["events"]) + 1,
    ]
    src = SimpleNamespace(rotation=got, t0_s=90.0)
    snap = _fleet(101.5).snapshot(101.5)
    before = ReplaySource._rotation_at(src, snap, 101.5)
    after = ReplaySource._rotation_at(src, snap, 102.0)
    assert before is not None and not before["pads"][0]["confirmed"]
    assert after is not None and after["pads"][0]["confirmed"]
    assert after["events"][-1]["kind"] == "crew_confirmed"
    assert ReplaySource._rotation_at(src, snap, 99.0) is None


def _status(**kw):
    """A two-hour mission's status row: 20 relays networked, none lost, TU near 1."""
    return status_row(
        **{
            "duration_s": 7200.0,
            "networked": 20,
            "lost": 0,
            "returning": 1,
            "tu1": 0.95,
            "tu2": 0.97,
            "modes": {"GUIDED": 21},
            "reclaims": 0,
            **kw,
        }
    )


ROT = dict(rotations=12, min_battery_in_air=0.314, battery_failsafes_in_air=0, landed_away=0)


def test_the_status_line_counts_rotations_and_says_failsafes_and_landings_away():
    line = format_status(_status(rotation=ROT), width=200)
    assert "rot 12 min 31%" in line and "batt fs" not in line and "away" not in line
    bad = dict(ROT, battery_failsafes_in_air=2, landed_away=1)
    assert "rot 12 min 31% 2 batt fs 1 away" in format_status(_status(rotation=bad), width=200)
    # On 80 columns the rotation stays (the drones lost and home leave first), planned for the
    # whole run: hundreds of rotations.
    d = _status(rotation=ROT, t_mission_s=7199.0)
    dropped = planned_drop(d, 80)
    narrow = format_status(d, 80, dropped)
    assert narrow == "flying 7199/7200s | 20/50 net | crews 9/10 | TU1 95% TU2 97% rot 12 min 31%"
    late = format_status(_status(rotation=dict(ROT, rotations=480)), 80, dropped)
    assert "rot 480 min 31%" in late and len(late) <= 79
    err = io.StringIO()
    st = _Status(err)
    st(_status(rotation=ROT))
    st(_status(rotation=bad))
    st(_status(rotation=bad))
    warnings = [x for x in err.getvalue().splitlines() if x.startswith("warning:")]
    assert len(warnings) == 2  # each once
    assert "battery failsafe in the air (2 so far)" in warnings[0]
    assert "1 vehicle(s) landed away from the base" in warnings[1]


def test_the_closing_summary_line():
    e = dict(
        ROT, swaps=11, swap_confirm="manual", swaps_confirmed_by_crew=11, battery_failsafes_in_air=1
    )
    assert format_rotation(e) == (
        "relay rotation: 12 rotations, 1 battery failsafes in the air, 0 landed away from the "
        "base, min battery in the air 31 %; 11 battery swaps (manual confirmation, 11 confirmed "
        "by the ground crew)"
    )


def _two_hours_of_ticks(tmp_path, n_ticks: int = 7200, quiet_ticks: int = 0):
    """A two-hour flight's rotation, one control tick a second: 34 of 50 vehicles in the plan,
    each relay's reserve estimated from whole percents at its own drain as the station does (its
    time jumps when the percent drops, and moves on with the clock in between), a rotation every 40 s (a spare
    in, a relay out, an event), each tick recorded by ``Records.rotation``; then
    ``quiet_ticks`` ticks where nothing changes. Returns the run directory's ``rotation.jsonl``
    and the state and events the station had after each tick."""
    from mission.format.schema import RunSpec
    from small_mission import small_mission

    n, k = 50, 34
    policy = RotationPolicy(n, k, BaseResources(pads=4), EnduranceParams())
    rot = RotationSetup(policy, hover_drain_per_s=1.0 / 1500.0, swap_confirm="auto")
    ids = [f"0:{i + 1}" for i in range(n)]
    rng = np.random.default_rng(7)
    launched = rng.uniform(0.0, 300.0, n)
    endurance_s = rng.uniform(1350.0, 1650.0, n)  # each its own drain
    op = SimpleNamespace(
        rotation_state=lambda: rot.state(ids),
        rotation_events=lambda start=0: rot.event_dicts(start, ids),
    )
    rec = Records(tmp_path, small_mission("records", RunSpec()), {})
    truth = []
    for step in range(n_ticks + quiet_ticks):
        t = 10.0 + step
        if step < n_ticks:
            if step % 40 == 39:  # the first spare relieves the relay in the plan the longest
                air = np.flatnonzero(policy.phase == AIR)
                spare = int(np.flatnonzero(policy.phase == READY)[0])
                relay = int(air[np.argmin(launched[air])])
                policy.phase[spare], policy.phase[relay] = AIR, READY
                launched[spare] = t
                policy.counters["rotations"] += 1
                rot.events.append(RotationEvent(t, "handover", spare, relay))
            charge = np.floor(100.0 * (1.0 - (t - launched) / endurance_s)) / 100.0
            rot.time_to_reserve_s = np.maximum(0.0, (charge - 0.2) * endurance_s)
            rot.tick_s = t
        rec.rotation(op, t)
        truth.append((t, rot.state(ids), rot.event_dicts(0, ids)))
    rec.close()
    return tmp_path / ROTATION_FILE, truth


def test_rotation_jsonl_of_two_hours_is_small_and_the_replay_draws_the_same_panel(tmp_path):
    """The lines between whole states carry only what changed: two hours of ticks write at least
    ten times less than a whole state at every tick that changed it, and the replay rebuilds, at
    any instant, the state the station had and the same panel."""
    path, truth = _two_hours_of_ticks(tmp_path)
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    # The whole state on the first line, then once per ROTATION_SNAPSHOT_S.
    span = truth[-1][0] - truth[0][0]
    assert "state" in lines[0]
    assert sum("state" in x for x in lines) == 1 + int(span // ROTATION_SNAPSHOT_S)
    # What the records were before the patches: the whole state at every tick it changed.
    before, last = 0, None
    for t, state, _ in truth:
        if state != last:
            before += len(json.dumps({"t_s": t, "state": state, "events": []})) + 1
        last = state
    size = path.stat().st_size
    assert len(lines) > 3000  # the reserves move nearly every tick: a line nearly every tick
    assert size * 10 <= before, (size, before)
    got = ReplaySource._read_rotation(path)
    assert got is not None and len(got) == len(lines)
    src = SimpleNamespace(rotation=got, t0_s=0.0)
    snap = _fleet(0.0).snapshot(0.0)
    picks = np.random.default_rng(3).integers(0, len(truth), 80).tolist() + [0, len(truth) - 1]
    for j in picks:
        t, state, events = truth[j]
        at = t + 0.5  # a frame between two ticks shows the first
        frame = ReplaySource._rotation_at(src, snap, at)
        assert frame == rotation_frame(state, events[-MAX_EVENTS:], snap, at, 0.0)
        k = max(i for i, g in enumerate(got) if g["t_s"] <= at)
        assert got[k]["state"] == state and got[k]["n_events"] == len(events)


def test_quiet_ticks_write_nothing_and_a_lost_line_costs_only_until_the_next_whole_state(
    tmp_path,
):
    path, truth = _two_hours_of_ticks(tmp_path, n_ticks=900, quiet_ticks=3600)
    text = path.read_text().splitlines()
    # The quiet hour wrote no line.
    assert json.loads(text[-1])["t_s"] <= truth[900 - 1][0]
    # A line cut short early on: the replay skips the lines after it until the next whole
    # state; every state it gives is the station's at that tick.
    whole = [i for i, x in enumerate(text) if '"state"' in x]
    assert len(whole) >= 3
    cut = whole[0] + 5
    broken = tmp_path / "broken.jsonl"
    broken.write_text("\n".join(text[:cut] + [text[cut][:20]] + text[cut + 1 :]) + "\n")
    got = read_rotation(broken)
    stamps = [json.loads(x)["t_s"] for x in text]
    assert [t for t, _, _ in got] == stamps[:cut] + stamps[whole[1] :]
    by_t = {t: s for t, s, _ in truth}
    assert all(s == by_t[t] for t, s, _ in got)


def test_events_jsonl_keeps_a_battery_report_when_it_changes_or_every_period(tmp_path):
    """A battery report a second per vehicle was 98 % of events.jsonl: one is written when the
    whole percent, the charge state or what the autopilot knows changes, or
    BATTERY_RECORD_PERIOD_S after the last one of that vehicle and message (the .tlog has
    them all). Each vehicle and message has its own."""
    from gcs.events import BatteryReceived
    from mission.flight.run_dir import BATTERY_RECORD_PERIOD_S, Records
    from mission.format.schema import RunSpec
    from small_mission import small_mission

    rec = Records(tmp_path, small_mission("records", RunSpec()), {})
    sent = []
    for k in range(61):  # 60 s at 1 Hz, draining 1 % every 15 s; voltage sags each second
        t = float(k)
        frac = 0.9 - 0.01 * (k // 15)
        for sysid in (1, 2):
            ev = BatteryReceived(0, sysid, t, "SYS_STATUS", frac, 15.0 - 0.001 * k, 20.0)
            sent.append(ev)
            rec.event(ev)
        if k == 33:  # a BATTERY_STATUS, once: its own stream
            rec.event(BatteryReceived(0, 1, t, "BATTERY_STATUS", frac, None, None, 500.0))
    rec.event(BatteryReceived(0, 1, 60.5, "SYS_STATUS", 0.86, 15.0, 20.0, charge_state=2))
    rec.close()
    lines = [json.loads(x) for x in (tmp_path / "events.jsonl").read_text().splitlines()]
    mine = [x for x in lines if x["type"] == "BatteryReceived" and x["sysid"] == 1]
    sys_status = [x["t_s"] for x in mine if x["source"] == "SYS_STATUS"]
    # The changes (0, 15, 30, 45, 60 s), the 10-s refreshes between them, the charge state.
    assert BATTERY_RECORD_PERIOD_S == 10.0
    assert sys_status == [0.0, 10.0, 15.0, 25.0, 30.0, 40.0, 45.0, 55.0, 60.0, 60.5]
    assert [x["t_s"] for x in mine if x["source"] == "BATTERY_STATUS"] == [33.0]
    assert [x["t_s"] for x in lines if x.get("sysid") == 2] == sys_status[:-1]
    # Every percent the vehicle reported is in the file, at the second it was first reported.
    firsts = {}
    for ev in sent:
        if ev.sysid == 1:
            firsts.setdefault(round(ev.remaining_frac * 100), ev.t_s)
    written = {round(x["remaining_frac"] * 100): x["t_s"] for x in reversed(mine)}
    assert {p: written[p] for p in firsts} == firsts

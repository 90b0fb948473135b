"""Unit tests of :class:`gcs.operations.Operator` against a fake station, in memory, explicit time.

No emulator and no link core: a :class:`FakeStation` records every call the operator makes, and
a :class:`Feed` emits the :mod:`gcs.events` a station link would (HEARTBEAT -> VehicleDiscovered /
ModeChanged / ArmedChanged, GLOBAL_POSITION_INT -> TelemetryReceived, PARAM_VALUE ->
ParamReceived / ParamSetConfirmed, COMMAND_ACK -> CommandFailed, ...). The fleet view is the real
:class:`gcs.fleet.FleetView` (a pure fold of those events). The end-to-end behaviour against the
emulator is in ``tests/integration/test_pair.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs import audit as audit_mod
from gcs import limits as limits_mod
from gcs.autopilot import ARDUPILOT, PX4, adapter_for, px4_custom_mode
from gcs.control import ControlConfig, TerrainAltitude
from gcs.events import (
    ArmedChanged,
    CommandFailed,
    CommandTimedOut,
    HomePositionReceived,
    ModeChanged,
    ParamReceived,
    ParamSetConfirmed,
    ParamSetFailed,
    ParamTimedOut,
    StatusText,
    TaskPositionReceived,
    TelemetryReceived,
    VehicleDiscovered,
    VehicleLost,
    VehicleRecovered,
)
from gcs.fleet import FleetView, MissionOrigin
from gcs.link import LinkUsageError, UnknownVehicle
from gcs.operations import (
    OPERATOR_ACTIONS,
    PHASES,
    OperationsConfig,
    Operator,
    OperatorAction,
    TickRecord,
)
from gcs.tasks import LiveTasks
from gcs.wire import mavlink
from planner.geometry import ned_to_geodetic
from planner.methods import PlanOutput
from planner.terrain import Canyon, synthetic_terrain

ORIGIN = MissionOrigin(45.0, 7.0, 100.0)
STABILIZE, GUIDED, RTL, LAND = 0, 4, 6, 9
OFFBOARD = px4_custom_mode(6, 0)
PX4_POSCTL = px4_custom_mode(3, 0)
ARM, TAKEOFF, SET_MODE = (
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
    mavlink.MAV_CMD_NAV_TAKEOFF,
    mavlink.MAV_CMD_DO_SET_MODE,
)
FAILED, TEMP_REJECTED = mavlink.MAV_RESULT_FAILED, mavlink.MAV_RESULT_TEMPORARILY_REJECTED
REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
CONTROL = ControlConfig(cruise_alt_m=20.0, layer_spacing_m=5.0, n_layers=3)

#: Safe ArduCopter lost-link parameters (gcs.audit: FS_GCS_ENABLE 1 = RTL, our GCS sysid).
#: A PX4 vehicle's safe lost-link settings, without COM_OBL_ACT (absent on PX4 >= 1.14).
PX4_SAFE_WITHOUT_COM_OBL_ACT = {
    "COM_OF_LOSS_T": 1.0,
    "COM_OBL_RC_ACT": 3.0,
    "NAV_RCL_ACT": 2.0,
    "NAV_DLL_ACT": 2.0,
    "COM_DL_LOSS_T": 10.0,
    "COM_RC_IN_MODE": 4.0,
    "COM_RCL_EXCEPT": 0.0,
    "COM_DLL_EXCEPT": 0.0,
    "COM_FAIL_ACT_T": 0.0,
}

AP_SAFE = {
    "FS_GCS_ENABLE": 1.0,
    "FS_GCS_TIMEOUT": 5.0,
    "FS_OPTIONS": 0.0,
    "GUID_TIMEOUT": 3.0,
    "SYSID_MYGCS": 255.0,
}


# ------------------------------------------------------------------------------------ fakes


class FakeLink:
    def __init__(self, station: FakeStation, link_id: int) -> None:
        self.station, self.link_id = station, link_id

    def cancel_param(self, sysid: int, name: str, now_s: float) -> bool:
        self.station.calls.append(("cancel_param", (self.link_id, sysid), name, now_s))
        return True


class FakeStation:
    """The :class:`gcs.station.Station` surface the operator uses; records every call.

    ``raises[name] = exc`` makes that method raise ``exc`` (a refused local call)."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []
        self.raises: dict[str, Exception] = {}
        self._rid = 0

    def _record(self, name: str, vid, *args) -> int:
        if name in self.raises:
            raise self.raises[name]
        self.calls.append((name, tuple(vid), *args))
        self._rid += 1
        return self._rid

    def link(self, link_id: int) -> FakeLink:
        return FakeLink(self, link_id)

    def engage_guided(self, vid, now_s):
        return self._record("engage_guided", vid, now_s)

    def arm(self, vid, now_s):
        return self._record("arm", vid, now_s)

    def takeoff(self, vid, alt_above_home_m, now_s):
        return self._record("takeoff", vid, alt_above_home_m, now_s)

    def rtl(self, vid, now_s):
        return self._record("rtl", vid, now_s)

    def land(self, vid, now_s):
        return self._record("land", vid, now_s)

    def set_position_target(self, vid, lat_deg, lon_deg, alt_above_home_m, now_s):
        return self._record("set_position_target", vid, lat_deg, lon_deg, alt_above_home_m, now_s)

    def clear_position_target(self, vid, now_s):
        return self._record("clear_position_target", vid, now_s)

    def withdraw_flight_commands(self, vid, now_s, reason):
        return self._record("withdraw_flight_commands", vid, reason, now_s)

    def request_param(self, vid, name, now_s):
        return self._record("request_param", vid, name, now_s)

    def set_param(self, vid, name, value, param_type, now_s, *, previous=None):
        return self._record("set_param", vid, name, value, param_type, now_s, previous)

    # ---------------------------------------------------------------- reading the record

    @staticmethod
    def t_of(call: tuple) -> float:
        """When a recorded call was made (set_param ends with ``previous``)."""
        return call[-2] if call[0] == "set_param" else call[-1]

    def of(self, name: str, vid=None, since_s: float = -math.inf) -> list[tuple]:
        """Calls of one kind (for one vehicle), made at or after ``since_s``."""
        return [
            c
            for c in self.calls
            if c[0] == name
            and (vid is None or c[1] == tuple(vid))
            and self.t_of(c) >= since_s - 1e-12
        ]

    def names(self, since_s: float = -math.inf) -> list[str]:
        return [c[0] for c in self.calls if self.t_of(c) >= since_s - 1e-12]


class FakePlanner:
    """Plans nothing: every planned vehicle is told to stay (zero displacement)."""

    def __init__(self) -> None:
        self.ticks = []

    def plan(self, tick):
        self.ticks.append(tick)
        return PlanOutput(np.zeros((len(tick.pos_m), 2)), info={"iterations": 7})


class Feed:
    """A fleet of fake vehicles: emits the events a station link would, into the operator.

    Vehicle state (mode, armed, altitude above home, position) is set by the test; every
    :meth:`poll` first sends a GLOBAL_POSITION_INT (TelemetryReceived) of every vehicle that is
    not ``silent``, so the fleet view keeps hearing them, then polls the operator."""

    def __init__(self, op: Operator) -> None:
        self.op = op
        self.v: dict[tuple[int, int], dict] = {}
        self.silent: set[tuple[int, int]] = set()

    def emit(self, event) -> None:
        self.op.handle_event(event)

    def add(
        self,
        sysid: int,
        t_s: float,
        *,
        autopilot: int = ARDUPILOT,
        mode: int | None = None,
        armed: bool = False,
        alt_m: float = 0.0,
        north_m: float | None = None,
        link: int = 0,
    ) -> tuple[int, int]:
        vid = (link, sysid)
        if mode is None:
            mode = STABILIZE if autopilot == ARDUPILOT else PX4_POSCTL
        self.v[vid] = {
            "autopilot": autopilot,
            "mode": mode,
            "armed": armed,
            "alt_m": alt_m,
            "north_m": 10.0 * len(self.v) if north_m is None else north_m,
            "east_m": 0.0,
        }
        self.emit(
            VehicleDiscovered(
                link, sysid, t_s, autopilot, 2, mode, adapter_for(autopilot).mode_name(mode), armed
            )
        )
        self.telemetry(vid, t_s)
        return vid

    def telemetry(self, vid, t_s: float) -> None:
        s = self.v[vid]
        lat, lon, alt = ned_to_geodetic(
            np.array([[s["north_m"], s["east_m"], -s["alt_m"]]]),
            ORIGIN.lat_deg,
            ORIGIN.lon_deg,
            ORIGIN.alt_amsl_m,
        )
        self.emit(
            TelemetryReceived(
                vid[0], vid[1], t_s, float(lat[0]), float(lon[0]), float(alt[0]), s["alt_m"]
            )
        )

    def mode(self, vid, t_s: float, custom_mode: int) -> None:
        s = self.v[vid]
        old = s["mode"]
        s["mode"] = custom_mode
        ad = adapter_for(s["autopilot"])
        self.emit(
            ModeChanged(
                vid[0], vid[1], t_s, custom_mode, ad.mode_name(custom_mode), ad.mode_name(old)
            )
        )

    def armed(self, vid, t_s: float, armed: bool) -> None:
        self.v[vid]["armed"] = armed
        self.emit(ArmedChanged(vid[0], vid[1], t_s, armed))

    def alt(self, vid, t_s: float, alt_m: float) -> None:
        self.v[vid]["alt_m"] = alt_m
        self.telemetry(vid, t_s)

    def fly(self, vid, t_s: float, alt_m: float | None = None) -> None:
        """Guided, armed and at ``alt_m`` (default: its layer's altitude)."""
        row = self.op.fleet.index_of(*vid)
        guided = GUIDED if self.v[vid]["autopilot"] == ARDUPILOT else OFFBOARD
        if self.v[vid]["mode"] != guided:
            self.mode(vid, t_s, guided)
        if not self.v[vid]["armed"]:
            self.armed(vid, t_s, True)
        self.alt(vid, t_s, 20.0 + 5.0 * (row % 3) if alt_m is None else alt_m)

    def param(self, vid, name: str, value: float, t_s: float, param_type: int = REAL32) -> None:
        self.emit(ParamReceived(vid[0], vid[1], t_s, name, value, param_type))

    def poll(self, t_s: float):
        for vid in self.v:
            if vid not in self.silent:
                self.telemetry(vid, t_s)
        return self.op.poll(t_s)

    def run(self, t0_s: float, t1_s: float, dt_s: float = 0.25, until=None) -> float:
        """Poll from t0 to t1 (inclusive) every dt; stop early once ``until(op)``. Returns the
        last time polled."""
        t = t0_s
        while t <= t1_s + 1e-9:
            self.poll(t)
            if until is not None and until(self.op):
                return t
            t = round(t + dt_s, 9)
        return t - dt_s


def make(
    n: int = 0,
    *,
    t_s: float = 0.0,
    autopilot: int = ARDUPILOT,
    live_tasks=None,
    tasks=((1000.0, 0.0),),
    **cfg,
) -> tuple[Operator, FakeStation, Feed, list]:
    """An operator (discover phase) and ``n`` vehicles discovered at ``t_s``."""
    cfg.setdefault("audit", False)
    if n:
        cfg.setdefault("expected_vehicles", n)
    station = FakeStation()
    op = Operator(
        station,
        FleetView(ORIGIN, timeout_s=5.0),
        FakePlanner(),
        lambda t: np.array(tasks, dtype=float),
        CONTROL,
        OperationsConfig(**cfg),
        now_s=0.0,
        live_tasks=live_tasks,
    )
    feed = Feed(op)
    vids = [feed.add(k + 1, t_s, autopilot=autopilot) for k in range(n)]
    return op, station, feed, vids


def to_run(n: int = 2, **cfg):
    """Discover -> launch at t=0 (audit off), every vehicle up at t=1 -> run at t=1."""
    op, station, feed, vids = make(n, **cfg)
    feed.poll(0.0)
    assert op.phase == "launch"
    for v in vids:
        feed.fly(v, 1.0)
    rec = feed.poll(1.0)
    assert op.phase == "run" and rec is not None
    return op, station, feed, vids


def answer_audit(
    feed: Feed, station: FakeStation, t_s: float, values=None, vid=None, ptype: int = REAL32
) -> None:
    """Answer every parameter read requested so far with ``values`` (names absent: no answer)."""
    values = AP_SAFE if values is None else values
    for c in list(station.of("request_param", vid)):
        name = c[2]
        if name in values:
            feed.param(c[1], name, values[name], t_s, ptype)


# ------------------------------------------------------------------------- the public surface


def test_public_names_and_phase_strings():
    assert PHASES == ("discover", "audit", "launch", "run", "end", "done", "refused")
    assert OPERATOR_ACTIONS == ("hold", "rtl", "land", "release", "rejoin", "confirm_swap")
    op, *_ = make()
    assert op.phase == "discover" and isinstance(op.phase, str) and not op.finished
    assert f"{op.phase}" == "discover" and str(op.phase) == "discover"
    assert op.next_poll_s(3.0) == pytest.approx(3.25)
    assert op.t_mission_s(10.0) == 0.0 and op.mission_t0_s is None
    assert op.station_tu() == (0.0, 0.0)


def test_config_validation():
    with pytest.raises(ValueError):
        OperationsConfig(end="hover")
    with pytest.raises(ValueError):
        OperationsConfig(wave_size=0)
    with pytest.raises(ValueError):
        OperationsConfig(control_period_s=0.0)


# ------------------------------------------------------------------------------- discover


def test_discover_waits_for_the_expected_count():
    op, station, feed, _ = make(expected_vehicles=2, audit=True)
    v1 = feed.add(1, 0.5)
    feed.poll(1.0)
    assert op.phase == "discover" and station.calls == []
    feed.add(2, 1.2)
    feed.poll(1.5)
    assert op.phase == "audit"
    asked = {(c[1], c[2]) for c in station.of("request_param")}
    for vid in (v1, (0, 2)):
        for name in audit_mod.params_still_needed(ARDUPILOT, {}):
            assert (vid, name) in asked
    assert all(c[-1] == 1.5 for c in station.calls)


def test_discover_settles_without_an_expected_count():
    op, station, feed, _ = make(discover_settle_s=3.0)
    feed.add(1, 0.5)
    feed.add(2, 1.0)
    feed.run(1.0, 3.75)
    assert op.phase == "discover"
    feed.poll(4.0)  # 3 s after the last discovery
    assert op.phase == "launch"


def test_discover_timeout_starts_with_the_vehicles_heard():
    op, station, feed, _ = make(expected_vehicles=3, discover_timeout_s=30.0)
    feed.add(1, 0.0)
    t = feed.run(0.0, 40.0, 0.5, until=lambda op: op.phase != "discover")
    assert t == pytest.approx(30.0) and op.phase == "launch"


def test_discover_without_any_vehicle_refuses_at_the_timeout():
    """Issue 28: nothing heard is refused at discover_timeout_s (it used to wait for ever)."""
    op, station, feed, _ = make(expected_vehicles=2, discover_timeout_s=30.0)
    op.poll(0.0)
    op.poll(29.5)
    assert op.phase == "discover" and op.refusal is None
    op.poll(30.0)
    assert op.phase == "refused" and op.finished
    assert op.refusal == "no vehicle heard within 30 s"
    assert station.calls == []


def test_discover_without_any_vehicle_can_wait_forever():
    op, station, feed, _ = make(expected_vehicles=2, discover_timeout_s=math.inf)
    for t in (0.0, 30.0, 1000.0):
        op.poll(t)
    assert op.phase == "discover" and not op.finished


def test_no_audit_goes_straight_to_launch_and_reads_nothing():
    op, station, feed, vids = make(2)
    feed.poll(0.0)
    assert op.phase == "launch"
    assert station.of("request_param") == [] and station.of("set_param") == []


def test_a_live_task_never_heard_refuses_after_the_task_wait():
    tasks = LiveTasks(ORIGIN, {0: 50})
    op, station, feed, _ = make(
        2, live_tasks=tasks, discover_timeout_s=10.0, task_wait_timeout_s=20.0
    )
    t = feed.run(0.0, 60.0, 0.5, until=lambda op: op.phase != "discover")
    assert op.phase == "refused" and op.finished and t == pytest.approx(30.0)
    assert "50" in op.refusal
    assert station.calls == []


def test_a_live_task_position_is_no_fleet_row_and_lets_the_flight_start():
    tasks = LiveTasks(ORIGIN, {0: 50})
    op, station, feed, _ = make(2, live_tasks=tasks, tasks=((0.0, 0.0),))
    feed.poll(1.0)
    assert op.phase == "discover"
    feed.emit(TaskPositionReceived(0, 50, 1.2, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_amsl_m))
    assert len(op.fleet) == 2
    feed.poll(1.5)
    assert op.phase == "launch"
    assert np.allclose(op.task_pos_fn(0.0), [[0.0, 0.0]], atol=1e-6)


# ---------------------------------------------------------------------------------- audit


def test_audit_reads_cancels_the_other_spelling_and_launches_when_safe():
    op, station, feed, (v,) = make(1, audit=True)
    feed.poll(0.0)
    assert op.phase == "audit"
    asked = [c[2] for c in station.of("request_param", v)]
    assert asked == list(audit_mod.params_still_needed(ARDUPILOT, {}))
    assert "MAV_GCS_SYSID" in asked
    feed.run(0.25, 2.0)
    assert op.phase == "audit"  # still waiting for the answers
    answer_audit(feed, station, 2.1)
    # SYSID_MYGCS read: the firmware has that spelling, the other read is cancelled.
    assert ("cancel_param", v, "MAV_GCS_SYSID", 2.1) in station.calls
    feed.poll(2.25)
    assert op.phase == "launch"
    assert op.audit_report is not None and op.audit_report.cleared_to_fly
    assert not op.audit_report.overridden and op.initial_audit_report is None
    assert station.of("set_param") == [] and op.param_changes == []


def test_audit_follow_up_parameter_is_read_after_its_key():
    op, station, feed, (v,) = make(1, audit=True)
    feed.poll(0.0)
    assert not any(c[2] == "MAV_GCS_SYSID_HI" for c in station.of("request_param"))
    feed.param(v, "MAV_GCS_SYSID", 255.0, 0.5)
    assert ("request_param", v, "MAV_GCS_SYSID_HI", 0.5) in station.calls
    assert ("cancel_param", v, "SYSID_MYGCS", 0.5) in station.calls
    answer_audit(feed, station, 0.6, {k: v_ for k, v_ in AP_SAFE.items() if k != "SYSID_MYGCS"})
    feed.poll(0.75)
    assert op.phase == "audit"  # MAV_GCS_SYSID_HI still pending
    feed.param(v, "MAV_GCS_SYSID_HI", 0.0, 0.8)
    feed.poll(1.0)
    assert op.phase == "launch"


def test_audit_refuses_unsafe_vehicles_and_writes_nothing_without_the_flag():
    op, station, feed, (v,) = make(1, audit=True)
    feed.poll(0.0)
    answer_audit(feed, station, 0.5, {**AP_SAFE, "FS_GCS_ENABLE": 0.0})
    feed.poll(0.75)
    assert op.phase == "refused" and op.finished
    assert op.refusal and "audit" in op.refusal
    assert not op.audit_report.cleared_to_fly
    assert station.of("set_param") == [] and op.param_changes == []
    feed.run(1.0, 5.0)
    assert op.phase == "refused" and station.names(1.0) == []


def test_audit_override_launches_unsafe_vehicles():
    op, station, feed, (v,) = make(1, audit=True, override_audit=True)
    feed.poll(0.0)
    answer_audit(feed, station, 0.5, {**AP_SAFE, "FS_GCS_ENABLE": 0.0})
    feed.poll(0.75)
    assert op.phase == "launch"
    assert op.audit_report.overridden and op.audit_report.cleared_to_fly
    assert station.of("set_param") == []


def test_audit_rounds_ask_again_for_what_timed_out():
    op, station, feed, (v,) = make(1, audit=True, audit_rounds=3)
    feed.poll(0.0)
    answer_audit(
        feed,
        station,
        0.5,
        {k: x for k, x in AP_SAFE.items() if k not in ("FS_GCS_ENABLE", "FS_OPTIONS")},
    )
    feed.emit(ParamTimedOut(0, 1, 1.0, "FS_GCS_ENABLE", 3))
    feed.emit(ParamTimedOut(0, 1, 1.0, "FS_OPTIONS", 3))
    feed.poll(1.0)
    assert op.phase == "audit"
    names = [c[2] for c in station.of("request_param", v, since_s=1.0)]
    assert names == ["FS_GCS_ENABLE"]  # optional FS_OPTIONS is not asked for again
    feed.emit(ParamTimedOut(0, 1, 2.0, "FS_GCS_ENABLE", 3))
    feed.poll(2.0)
    assert [c[2] for c in station.of("request_param", v, since_s=2.0)] == ["FS_GCS_ENABLE"]
    feed.emit(ParamTimedOut(0, 1, 3.0, "FS_GCS_ENABLE", 3))
    feed.poll(3.0)  # third round timed out: audited as is, unreadable = blocking
    assert station.of("request_param", v, since_s=3.0) == []
    assert op.phase == "refused"
    assert sum(c[2] == "FS_GCS_ENABLE" for c in station.of("request_param")) == 3


def test_audit_round_answered_launches():
    op, station, feed, (v,) = make(1, audit=True, audit_rounds=3)
    feed.poll(0.0)
    answer_audit(feed, station, 0.5, {k: x for k, x in AP_SAFE.items() if k != "FS_GCS_ENABLE"})
    feed.emit(ParamTimedOut(0, 1, 1.0, "FS_GCS_ENABLE", 3))
    feed.poll(1.0)
    feed.param(v, "FS_GCS_ENABLE", 1.0, 1.5)
    feed.poll(1.75)
    assert op.phase == "launch"


def test_audit_timeout_audits_what_was_read():
    op, station, feed, (v,) = make(1, audit=True, audit_timeout_s=20.0)
    t = feed.run(0.0, 40.0, 0.5, until=lambda op: op.phase != "audit")
    assert t == pytest.approx(20.0) and op.phase == "refused"
    assert any(f.param == "FS_GCS_ENABLE" for f in op.audit_report.vehicles[0].blocking)


def test_audit_reads_still_answered_past_the_timeout_are_waited_for():
    """A large fleet's reads take longer than the timeout while every read is answered: the
    deadline runs from the last answer, and the audit ends when the last one comes."""
    op, station, feed, (v,) = make(1, audit=True, audit_timeout_s=20.0)
    feed.poll(0.0)
    names = list(AP_SAFE)
    t = 0.0
    for k, name in enumerate(names):  # one answer every 15 s: 60 s for the five
        t = 15.0 * (k + 1)
        feed.run(t - 14.5, t - 0.5, 0.5)
        assert op.phase == "audit", name
        feed.param(v, name, AP_SAFE[name], t)
    feed.run(t, t + 2.0, 0.5, until=lambda op: op.phase != "audit")
    assert op.phase == "launch" and op.audit_report.cleared_to_fly


def test_apply_failsafes_writes_confirms_by_echo_and_reaudits():
    op, station, feed, (v,) = make(1, audit=True, apply_failsafes=True)
    feed.poll(0.0)
    answer_audit(
        feed,
        station,
        0.5,
        {**AP_SAFE, "FS_GCS_ENABLE": 0.0, "SYSID_MYGCS": 254.0},
        ptype=mavlink.MAV_PARAM_TYPE_INT8,
    )
    feed.poll(0.75)
    assert op.phase == "audit"
    sets = station.of("set_param", v)
    assert [(c[2], c[3], c[4], c[6]) for c in sets] == [
        ("FS_GCS_ENABLE", 1.0, mavlink.MAV_PARAM_TYPE_INT8, 0.0),
        ("SYSID_MYGCS", 255.0, mavlink.MAV_PARAM_TYPE_INT8, 254.0),
    ]
    assert [c["ok"] for c in op.param_changes] == [None, None]
    assert [c["purpose"] for c in op.param_changes] == ["failsafe", "failsafe"]
    assert not op.initial_audit_report.cleared_to_fly
    feed.run(1.0, 3.0)
    assert op.phase == "audit"  # waits for the echoes
    for name, value, prev in (("FS_GCS_ENABLE", 1.0, 0.0), ("SYSID_MYGCS", 255.0, 254.0)):
        feed.param(v, name, value, 3.1, mavlink.MAV_PARAM_TYPE_INT8)
        feed.emit(ParamSetConfirmed(0, 1, 3.1, name, value, prev, mavlink.MAV_PARAM_TYPE_INT8))
        feed.poll(3.25) if name == "FS_GCS_ENABLE" else None
        if name == "FS_GCS_ENABLE":
            assert op.phase == "audit"  # one echo still awaited
    feed.poll(3.5)
    assert op.phase == "launch" and op.audit_report.cleared_to_fly
    assert [(c["name"], c["previous"], c["value"], c["ok"]) for c in op.param_changes] == [
        ("FS_GCS_ENABLE", 0.0, 1.0, True),
        ("SYSID_MYGCS", 254.0, 255.0, True),
    ]
    assert len(station.of("set_param")) == 2  # no second write


def test_apply_failsafes_a_refused_write_refuses_the_flight():
    op, station, feed, (v,) = make(1, audit=True, apply_failsafes=True)
    feed.poll(0.0)
    answer_audit(feed, station, 0.5, {**AP_SAFE, "FS_GCS_ENABLE": 0.0})
    feed.poll(0.75)
    feed.param(v, "FS_GCS_ENABLE", 0.0, 1.0)
    feed.emit(ParamSetFailed(0, 1, 1.0, "FS_GCS_ENABLE", 1.0, 0.0, "the vehicle kept 0", 4))
    feed.poll(1.25)
    assert op.phase == "refused"
    (c,) = op.param_changes
    assert c["ok"] is False and c["reason"] == "the vehicle kept 0" and c["requested"] == 1.0
    assert c["previous"] == 0.0


def test_apply_failsafes_gives_up_waiting_for_echoes_after_the_audit_timeout():
    op, station, feed, (v,) = make(1, audit=True, apply_failsafes=True, audit_timeout_s=20.0)
    feed.poll(0.0)
    answer_audit(feed, station, 0.5, {**AP_SAFE, "FS_GCS_ENABLE": 0.0})
    feed.poll(1.0)  # fixes sent at t=1
    t = feed.run(1.25, 40.0, 0.25, until=lambda op: op.phase != "audit")
    assert t == pytest.approx(21.0) and op.phase == "refused"


def test_the_missions_limits_are_read_written_and_confirmed_before_launch():
    op, station, feed, (v,) = make(1, audit=True, max_speed_m_s=10.0, climb_rate_m_s=5.0)
    feed.poll(0.0)
    asked = [c[2] for c in station.of("request_param", v)]
    assert asked[-2:] == ["WPNAV_SPEED", "WPNAV_SPEED_UP"]
    answer_audit(feed, station, 0.5, {**AP_SAFE, "WPNAV_SPEED": 500.0, "WPNAV_SPEED_UP": 250.0})
    feed.poll(0.75)
    assert op.phase == "audit"
    assert [(c[2], c[3], c[6]) for c in station.of("set_param", v)] == [
        ("WPNAV_SPEED", 1000.0, 500.0),
        ("WPNAV_SPEED_UP", 500.0, 250.0),
    ]
    assert {c["purpose"] for c in op.param_changes} == {"limit"}
    feed.emit(ParamSetConfirmed(0, 1, 1.0, "WPNAV_SPEED", 1000.0, 500.0, REAL32))
    feed.poll(1.0)
    assert op.phase == "audit"
    feed.emit(ParamSetConfirmed(0, 1, 1.1, "WPNAV_SPEED_UP", 500.0, 250.0, REAL32))
    feed.poll(1.25)
    assert op.phase == "launch"
    assert all(c["ok"] for c in op.param_changes) and op.limit_warnings == []


def test_limits_already_right_write_nothing_and_unreadable_ones_warn():
    op, station, feed, vids = make(2, audit=True, max_speed_m_s=10.0)
    feed.poll(0.0)
    answer_audit(
        feed, station, 0.5, {**AP_SAFE, "WPNAV_SPEED": 1000.0, "WPNAV_SPEED_UP": 250.0}, vid=vids[0]
    )
    answer_audit(feed, station, 0.5, AP_SAFE, vid=vids[1])
    # Unreadable limits are asked again in each audit round (a vehicle booting, a lost read),
    # then reported.
    for k in range(3):
        for name in ("WPNAV_SPEED", "WPNAV_SPEED_UP"):
            feed.emit(ParamTimedOut(0, 2, 0.6 + k, name, 3))
        feed.poll(0.75 + k)
    asked = [c for c in station.of("request_param") if c[2] == "WPNAV_SPEED"]
    assert len(asked) == 1 + 3  # vehicle 1 once, vehicle 2 in each of the 3 rounds
    # Without a climb rate only the speed is written; vehicle 1 already has it; vehicle 2's
    # could not be read.
    assert station.of("set_param") == []
    assert op.phase == "launch"
    assert len(op.limit_warnings) == 1 and "sysid 2" in op.limit_warnings[0]


def test_set_limits_off_neither_reads_nor_writes_them():
    op, station, feed, (v,) = make(1, audit=True, max_speed_m_s=10.0, set_limits=False)
    feed.poll(0.0)
    assert not any(c[2].startswith("WPNAV") for c in station.of("request_param"))
    answer_audit(feed, station, 0.5)
    feed.poll(0.75)
    assert op.phase == "launch" and station.of("set_param") == []


# --------------------------------------------------------------------------------- launch


def test_launch_ardupilot_guided_arm_takeoff_to_the_layer():
    op, station, feed, vids = make(3)
    feed.poll(0.0)
    assert op.phase == "launch"
    for row, v in enumerate(vids):
        assert [c[0] for c in station.calls if c[1] == v] == ["engage_guided", "arm", "takeoff"]
        assert station.of("takeoff", v)[0][2] == pytest.approx(20.0 + 5.0 * row)


def test_px4_takes_off_by_the_offboard_climb_only():
    op, station, feed, (v,) = make(1, autopilot=PX4)
    feed.poll(0.0)
    assert [c[0] for c in station.calls] == ["takeoff"]
    assert station.calls[0][2] == pytest.approx(20.0)


def test_px4_without_a_position_is_not_sent_a_takeoff():
    op, station, feed, _ = make(0, expected_vehicles=1)
    feed.emit(VehicleDiscovered(0, 1, 0.0, PX4, 2, PX4_POSCTL, "POSCTL", False))
    op.poll(0.0)
    assert op.phase == "launch" and station.calls == []


def test_no_second_takeoff_while_climbing():
    op, station, feed, (v,) = make(
        1, wave_timeout_s=1000.0, takeoff_grace_s=6.0, action_retry_s=3.0
    )
    feed.poll(0.0)
    feed.mode(v, 0.5, GUIDED)
    feed.armed(v, 0.5, True)
    feed.alt(v, 0.5, 0.5)  # armed, still on the ground (below liftoff_alt_m, 1 m)
    feed.run(0.5, 6.25)
    assert len(station.of("takeoff")) == 1 and len(station.of("arm")) == 1
    # 6 s after it was first seen armed, still on the ground: the take-off alone again.
    feed.poll(6.5)
    assert station.names(6.5) == ["takeoff"]


def test_a_vehicle_off_the_ground_is_left_alone():
    op, station, feed, (v,) = make(1, wave_timeout_s=1000.0)
    feed.poll(0.0)
    feed.mode(v, 0.5, GUIDED)
    feed.armed(v, 0.5, True)
    feed.alt(v, 2.0, 5.0)  # airborne, climbing to 20 m
    feed.run(2.0, 30.0)
    assert station.names(0.25) == []
    assert op.phase == "launch"  # 5 m < 0.7 x 20 m: not climbed


def test_a_takeoff_stopped_short_is_climbed_by_a_position_target_not_a_second_takeoff():
    # ArduCopter refuses NAV_TAKEOFF off the ground (Mode::do_user_takeoff); a vehicle hovering
    # at 1.4 m after an interrupted take-off must be climbed by a target, alternating with a
    # take-off in case its altitude reads high on the ground.
    op, station, feed, (v,) = make(
        1, wave_timeout_s=1000.0, takeoff_grace_s=6.0, action_retry_s=3.0
    )
    feed.poll(0.0)
    assert station.names(0.0) == ["engage_guided", "arm", "takeoff"]
    feed.mode(v, 0.5, GUIDED)
    feed.armed(v, 0.5, True)
    feed.alt(v, 0.5, 1.4)
    feed.run(0.5, 6.25)
    assert station.names(0.25) == []
    feed.poll(6.5)
    assert station.names(6.5) == ["set_position_target"]
    assert station.of("set_position_target", v)[0][4] == pytest.approx(20.0)  # its layer
    assert op.counters["takeoff_climbs"] == 1
    feed.run(6.75, 9.5)
    assert station.names(9.5) == ["takeoff"]  # the climb did not help: a take-off again
    # after the take-off's grace (counted from the command and from when it was seen armed)
    t = feed.run(9.75, 30.0, until=lambda op: bool(station.names(9.75)))
    assert t > 15.0 and station.names(9.75) == ["set_position_target"]
    feed.alt(v, t + 0.5, 19.0)  # it climbs: airborne, no take-off any more; the run starts
    feed.run(t + 0.5, 60.0)
    assert "takeoff" not in station.names(t + 0.5) and op.phase == "run"


def test_an_unarmed_vehicle_is_sent_the_takeoff_again_after_the_grace():
    op, station, feed, (v,) = make(1, wave_timeout_s=1000.0, takeoff_grace_s=6.0)
    feed.poll(0.0)
    feed.run(0.25, 5.75)
    assert station.names(0.25) == []
    feed.poll(6.0)
    assert station.names(6.0) == ["engage_guided", "arm", "takeoff"]


def test_waves_start_when_most_of_the_previous_one_is_airborne():
    op, station, feed, vids = make(4, wave_size=2, wave_airborne_frac=0.8, wave_timeout_s=1000.0)
    feed.poll(0.0)
    assert {c[1] for c in station.calls} == {vids[0], vids[1]}
    feed.fly(vids[0], 1.0, alt_m=3.0)
    feed.run(1.0, 2.0)
    assert {c[1] for c in station.calls} == {vids[0], vids[1]}  # 1 of 2 < 0.8 x 2
    feed.fly(vids[1], 2.1, alt_m=3.0)
    feed.poll(2.25)
    assert {c[1] for c in station.of("takeoff", since_s=2.25)} == {vids[2], vids[3]}
    assert station.of("takeoff", vids[3])[0][2] == pytest.approx(20.0)  # row 3: layer 0


def test_a_wave_counts_only_the_vehicles_heard():
    op, station, feed, vids = make(4, wave_size=2, wave_timeout_s=1000.0)
    feed.poll(0.0)
    feed.silent.add(vids[1])
    feed.fly(vids[0], 1.0, alt_m=3.0)
    feed.run(1.0, 5.0)
    assert not station.of("takeoff", vids[2])
    feed.poll(5.25)  # vehicle 2 silent since t=0, past the fleet's 5 s: 1 of 1 heard is up
    assert station.of("takeoff", vids[2]) and station.of("takeoff", vids[3])


def test_a_wave_times_out():
    op, station, feed, vids = make(3, wave_size=2, wave_timeout_s=10.0)
    feed.run(0.0, 9.75)
    assert not station.of("takeoff", vids[2])
    feed.poll(10.0)
    assert station.of("takeoff", vids[2])


def test_the_run_starts_when_most_of_the_fleet_has_climbed():
    op, station, feed, vids = make(
        2, wave_climbed_frac=0.8, climbed_alt_frac=0.7, wave_timeout_s=1000.0
    )
    feed.poll(0.0)
    for v in vids:
        feed.fly(v, 1.0, alt_m=15.0)  # row 0 needs 14 m, row 1 needs 17.5 m
    feed.run(1.0, 3.0)
    assert op.phase == "launch" and op.mission_t0_s is None
    feed.alt(vids[1], 3.1, 18.0)
    rec = feed.poll(3.25)
    assert op.phase == "run" and op.mission_t0_s == 3.25
    assert isinstance(rec, TickRecord) and rec.t_step == 0 and rec.t_mission_s == 0.0


def test_the_final_climb_times_out_into_the_run():
    op, station, feed, vids = make(2, wave_timeout_s=10.0)
    feed.poll(0.0)
    for v in vids:
        feed.fly(v, 1.0, alt_m=5.0)
    feed.poll(1.0)  # wave 1 airborne at t=1: the climb waits from here
    t = feed.run(1.25, 30.0, until=lambda op: op.phase != "launch")
    assert t == pytest.approx(11.0) and op.phase == "run"


def test_command_failures_back_off_exponentially():
    op, station, feed, (v,) = make(
        1, wave_timeout_s=1000.0, action_retry_s=3.0, max_backoff_s=24.0, takeoff_grace_s=6.0
    )
    t_fail, attempts = 0.0, [0.0]
    feed.poll(0.0)
    for _ in range(6):
        t_fail = attempts[-1] + 0.5
        # The whole attempt fails (GUIDED, arm, take-off): counted once.
        for cmd in (SET_MODE, ARM, TAKEOFF):
            feed.emit(
                CommandTimedOut(0, 1, t_fail, cmd, 0, 3)
                if cmd == SET_MODE
                else CommandFailed(
                    0,
                    1,
                    t_fail,
                    cmd,
                    0,
                    mavlink.MAV_RESULT_DENIED if cmd == TAKEOFF else mavlink.MAV_RESULT_UNSUPPORTED,
                )
            )
        t = feed.run(
            t_fail,
            t_fail + 100.0,
            0.25,
            until=lambda op, t_fail=t_fail: bool(station.of("takeoff", since_s=t_fail)),
        )
        attempts.append(t)
    gaps = [b - a for a, b in zip(attempts, attempts[1:])]
    # First retry after the 3 s minimum (the failure came 0.5 s in: 0.5 + 3), then doubling,
    # capped at 24 s.
    assert gaps == pytest.approx([3.5, 6.5, 12.5, 24.5, 24.5, 24.5])
    assert op.counters["command_failures"] == 18


def test_success_resets_the_back_off():
    op, station, feed, (v,) = make(1, wave_timeout_s=1000.0)
    feed.poll(0.0)
    feed.emit(CommandFailed(0, 1, 0.5, TAKEOFF, 0, mavlink.MAV_RESULT_DENIED))
    feed.run(0.5, 3.5, until=lambda op: bool(station.of("takeoff", since_s=0.5)))
    feed.emit(CommandFailed(0, 1, 4.0, TAKEOFF, 0, mavlink.MAV_RESULT_DENIED))  # backoff 6
    feed.fly(v, 5.0, alt_m=10.0)
    feed.poll(5.0)  # guided and airborne: failures forgotten
    feed.mode(v, 5.5, STABILIZE)
    feed.alt(v, 5.5, 10.0)
    t = feed.run(5.5, 30.0, until=lambda op: bool(station.of("engage_guided", since_s=5.5)))
    assert t == pytest.approx(10.0)  # the back-off (until 10) still applies to the next attempt
    feed.emit(CommandFailed(0, 1, 10.5, SET_MODE, 0, mavlink.MAV_RESULT_DENIED))
    t = feed.run(10.5, 40.0, until=lambda op: bool(station.of("engage_guided", since_s=10.5)))
    assert t == pytest.approx(13.5)  # failures were reset: 3 s, not 12 s


def test_prearm_refusals_are_retried_at_a_steady_pace_and_the_launch_waits():
    op, station, feed, (v,) = make(
        1, wave_timeout_s=10.0, launch_timeout_s=60.0, prearm_retry_s=5.0, action_retry_s=3.0
    )
    arms: list[float] = []

    def refuse(op):
        for c in station.of("arm"):
            if c[-1] not in arms:
                arms.append(c[-1])
                t = c[-1]
                feed.emit(StatusText(0, 1, t, 4, "PreArm: EKF not ready"))
                # ArduPilot answers the take-off first (not armed), then refuses the arm.
                feed.emit(CommandFailed(0, 1, t, TAKEOFF, 0, FAILED))
                feed.emit(CommandFailed(0, 1, t, ARM, 0, FAILED))
        return op.phase != "launch"

    t = feed.run(0.0, 120.0, 0.25, until=refuse)
    gaps = np.diff(arms[:8])
    assert gaps == pytest.approx([5.0] * 7)  # steady, no back-off
    assert op.prearm[v][1] == "PreArm: EKF not ready"
    # The launch waited while the vehicle was refusing: until launch_timeout_s, then the climb
    # timeout counted from the last wait.
    assert op.phase == "run" and t == pytest.approx(69.75)
    assert op._launch_gave_up


def test_not_ready_lists_recent_refusals_and_px4_temporarily_rejected_counts():
    op, station, feed, vids = make(2, autopilot=PX4, wave_timeout_s=1000.0)
    feed.poll(0.0)
    feed.emit(CommandFailed(0, 1, 0.5, ARM, 0, TEMP_REJECTED))
    snap = op.fleet.snapshot(1.0)
    assert op.not_ready(snap, 1.0) == [(0, 1)]
    assert op.not_ready(op.fleet.snapshot(0.5 + 12.0 + 0.25), 0.5 + 12.25) == []
    # Asked again prearm_retry_s after the refusal (the failed command ended the take-off
    # grace), not after action_retry_s x 2^n.
    t = feed.run(0.5, 20.0, until=lambda op: len(station.of("takeoff", vids[0])) > 1)
    assert t == pytest.approx(5.5)
    feed.run(5.75, 6.0)
    assert len(station.of("takeoff", vids[1])) == 2  # never refused: after the 6 s grace
    assert station.of("takeoff", vids[1])[1][-1] == pytest.approx(6.0)


def test_a_takeoff_failure_then_an_arm_refusal_is_not_a_failure():
    op, station, feed, (v,) = make(
        1, wave_timeout_s=1000.0, takeoff_grace_s=1.0, prearm_retry_s=5.0
    )
    feed.poll(0.0)
    feed.emit(CommandFailed(0, 1, 0.5, TAKEOFF, 0, FAILED))
    feed.emit(CommandFailed(0, 1, 0.6, ARM, 0, FAILED))
    t = feed.run(0.75, 30.0, until=lambda op: len(station.of("takeoff")) > 1)
    assert t == pytest.approx(5.75)  # 0.6 + 5 (prearm pace), not a back-off
    feed.emit(CommandFailed(0, 1, t, TAKEOFF, 0, mavlink.MAV_RESULT_DENIED))
    t2 = feed.run(t + 0.25, 60.0, until=lambda op: len(station.of("takeoff")) > 2)
    assert t2 - t == pytest.approx(3.0)  # the first counted failure: 3 s


def test_link_usage_errors_are_logged_and_retried():
    op, station, feed, (v,) = make(1, wave_timeout_s=1000.0, takeoff_grace_s=1.0)
    station.raises["arm"] = LinkUsageError("vehicle busy")
    feed.poll(0.0)
    assert station.names() == ["engage_guided"]
    del station.raises["arm"]
    t = feed.run(0.25, 10.0, until=lambda op: bool(station.of("arm")))
    assert t == pytest.approx(3.0)


def test_a_command_failure_for_an_unknown_vehicle_is_only_counted():
    op, station, feed, vids = make(1)
    feed.poll(0.0)
    feed.emit(CommandFailed(0, 9, 0.5, ARM, 0, FAILED))
    assert op.counters["command_failures"] == 1
    feed.poll(0.75)


# ------------------------------------------------------------------------------------ run


def test_run_ticks_every_control_period_with_one_target_each():
    op, station, feed, vids = to_run(
        2, control_period_s=1.0, radio_range_m=50.0, tasks=((5.0, 0.0), (1000.0, 0.0))
    )
    rec = op.records[-1]
    assert (rec.t_s, rec.t_step, rec.fleet, rec.planned, rec.guided, rec.lost) == (
        1.0,
        0,
        2,
        2,
        2,
        0,
    )
    assert (rec.n_tasks, rec.tasks_covered, rec.plan_iterations) == (2, 1, 7)
    targets = station.of("set_position_target", since_s=1.0)
    assert [c[1] for c in targets] == vids
    assert [c[4] for c in targets] == pytest.approx([20.0, 25.0], abs=0.01)
    assert op.next_poll_s(1.0) == pytest.approx(1.25)
    assert op.next_poll_s(1.9) == pytest.approx(2.0)
    assert feed.poll(1.5) is None
    rec2 = feed.poll(2.0)
    assert rec2.t_step == 1 and rec2.t_mission_s == pytest.approx(1.0)
    assert len(op.planner.ticks) == 2
    # A poll less than a period late keeps the schedule; more than one re-bases it.
    rec3 = feed.poll(3.7)
    assert rec3.t_step == 2 and op.next_poll_s(3.7) == pytest.approx(3.95)
    assert feed.poll(4.0).t_step == 3
    rec5 = feed.poll(6.2)
    assert rec5.t_step == 4 and op.next_poll_s(6.9) == pytest.approx(7.15)
    assert feed.poll(7.0) is None and feed.poll(7.2) is not None
    tu1, tu2 = op.station_tu()
    assert 0.0 < tu1 <= 1.0 and 0.0 <= tu2 <= 1.0
    assert op.t_mission_s(7.2) == pytest.approx(6.2)


def test_run_lasts_duration_then_ends_with_rtl():
    op, station, feed, vids = to_run(2, duration_s=5.0)
    feed.run(1.25, 5.75)
    assert op.phase == "run"
    feed.poll(6.0)
    assert op.phase == "end" and op.end_t0_s == 6.0
    assert [c[0] for c in station.calls if c[-1] == 6.0 and c[0] != "set_position_target"] == [
        "clear_position_target",
        "rtl",
        "clear_position_target",
        "rtl",
    ]
    assert op.records[-1].t_step == 5


def test_end_land_sends_land():
    op, station, feed, vids = to_run(1, duration_s=2.0, end="land")
    feed.run(1.25, 3.0)
    assert op.phase == "end"
    assert station.of("land") and not station.of("rtl")


# -------------------------------------------------------------------------------- reclaim


def test_reclaim_in_flight_is_counted_when_seen_back_in_guided():
    op, station, feed, (v, w) = to_run(2)
    feed.mode(v, 2.0, RTL)  # e.g. the GCS failsafe fired
    feed.run(2.0, 2.75)
    assert not station.of("engage_guided", v, since_s=2.0)  # the launch's attempt: 3 s minimum
    feed.poll(3.0)
    assert [c[0] for c in station.calls if c[1] == v and c[-1] == 3.0] == [
        "set_position_target",
        "set_position_target",
        "engage_guided",
    ]  # tick, hold, GUIDED
    hold = station.of("set_position_target", v, since_s=3.0)[-1]
    assert hold[4] == pytest.approx(20.0, abs=0.01)
    assert op.counters["reclaim_attempts"] == 1 and op.reclaimed == []
    feed.run(3.25, 5.75)
    assert op.counters["reclaim_attempts"] == 1
    feed.poll(6.0)  # still in RTL: asked again
    assert op.counters["reclaim_attempts"] == 2
    feed.mode(v, 6.5, GUIDED)
    feed.run(6.5, 8.0)
    assert op.reclaimed == [(6.5, 0, 1)]
    assert op.counters["reclaim_attempts"] == 2 and op.counters["relaunches"] == 0
    assert not station.of("arm", since_s=1.0) and not station.of("takeoff", since_s=1.0)


def test_a_restarted_station_reclaims_vehicles_found_flying():
    op, station, feed, _ = make(0, expected_vehicles=2)
    v = feed.add(1, 0.0, mode=RTL, armed=True, alt_m=22.0)
    w = feed.add(2, 0.0, mode=GUIDED, armed=True, alt_m=25.0)
    feed.poll(0.0)
    # Both are up: the launch is over at once, and the run's first tick targets both.
    assert op.phase == "run" and op.mission_t0_s == 0.0
    assert [c[0] for c in station.calls if c[1] == v] == [
        "set_position_target",
        "engage_guided",
        "set_position_target",
    ]  # hold, GUIDED, tick
    assert [c[0] for c in station.calls if c[1] == w] == ["set_position_target"]  # the tick
    assert not station.of("arm") and not station.of("takeoff")
    assert op.counters["reclaim_attempts"] == 1 and op.reclaimed == []
    feed.mode(v, 0.5, GUIDED)
    feed.poll(0.5)
    assert op.reclaimed == [(0.5, 0, 1)] and op.counters["reclaim_attempts"] == 1
    assert op.counters["relaunches"] == 0


def test_a_landed_vehicle_is_launched_again():
    op, station, feed, (v, w) = to_run(2)
    feed.mode(v, 3.0, LAND)
    feed.alt(v, 4.0, 0.0)
    feed.armed(v, 4.0, False)
    feed.run(3.0, 5.75)
    assert not station.of("takeoff", v, since_s=1.0)  # the launch's take-off grace (6 s)
    feed.poll(6.0)
    assert [c[0] for c in station.calls if c[1] == v and c[-1] == 6.0] == [
        "engage_guided",
        "arm",
        "takeoff",
    ]
    assert op.counters["relaunches"] == 1 and op.counters["reclaim_attempts"] == 0
    feed.run(6.25, 11.75)
    assert len(station.of("takeoff", v)) == 2
    feed.poll(12.0)  # still on the ground after the grace: the take-off again, not a relaunch
    assert len(station.of("takeoff", v)) == 3 and op.counters["relaunches"] == 1


def test_lost_and_recovered_are_counted_and_a_recovered_vehicle_is_acted_on_at_once():
    op, station, feed, (v, w) = to_run(2)
    feed.mode(v, 2.0, RTL)
    feed.run(2.0, 3.0)
    assert op.counters["reclaim_attempts"] == 1  # at t=3, next one not before 6
    feed.emit(VehicleLost(0, 1, 3.5, 3.0))
    assert op.counters["lost"] == 1
    assert op.fleet.snapshot(3.5).lost[0]
    feed.emit(VehicleRecovered(0, 1, 4.0, 1.0, RTL, "RTL"))
    assert op.counters["recovered"] == 1
    feed.poll(4.0)
    assert op.counters["reclaim_attempts"] == 2
    assert station.of("engage_guided", v, since_s=4.0)


def test_released_vehicles_are_not_planned_or_reclaimed():
    op, station, feed, (v, w) = to_run(2)
    op.operator_command("release", v, 1.5, source="cli")
    feed.mode(v, 2.0, RTL)
    feed.run(2.0, 10.0)
    assert not station.of("engage_guided", v, since_s=1.5)
    assert not station.of("set_position_target", v, since_s=1.5)
    assert op.records[-1].planned == 1
    assert len(op.planner.ticks[-1].networked) == 2 and op.planner.ticks[-1].networked.sum() == 1


# ------------------------------------------------------------------------------------ end


def test_end_is_done_when_every_vehicle_heard_has_landed():
    op, station, feed, (v, w) = to_run(2, duration_s=2.0, action_retry_s=3.0)
    feed.run(1.25, 3.0)
    assert op.phase == "end" and op.end_t0_s == 3.0
    assert op.end_status == {"on_ground": 0, "in_air": 2, "not_heard": 0}
    feed.mode(v, 3.5, RTL)  # v obeys, w does not
    feed.run(3.5, 5.75)
    assert station.names(3.25) == []
    feed.poll(6.0)
    assert [c[0] for c in station.calls if c[-1] == 6.0] == ["clear_position_target", "rtl"]
    assert station.calls[-1][1] == w
    feed.mode(w, 6.5, RTL)
    feed.armed(v, 7.0, False)
    feed.alt(v, 7.0, 0.0)
    feed.poll(7.0)
    assert op.phase == "end" and op.end_status == {"on_ground": 1, "in_air": 1, "not_heard": 0}
    feed.armed(w, 8.0, False)
    feed.poll(8.0)
    assert op.phase == "done" and op.finished
    assert op.end_status == {"on_ground": 2, "in_air": 0, "not_heard": 0}
    n = len(station.calls)
    feed.run(8.25, 10.0)
    assert len(station.calls) == n and op.phase == "done"


def test_end_does_not_wait_for_vehicles_not_heard():
    op, station, feed, (v, w) = to_run(2, duration_s=2.0)
    feed.run(1.25, 3.0)
    feed.armed(v, 3.5, False)
    feed.silent.add(w)
    t = feed.run(3.5, 20.0, until=lambda op: op.phase == "done")
    assert t > 3.0 + 5.0 and op.end_status == {"on_ground": 1, "in_air": 0, "not_heard": 1}


def test_end_times_out_with_vehicles_in_the_air():
    op, station, feed, vids = to_run(2, duration_s=2.0, end_timeout_s=30.0)
    feed.run(1.25, 3.0)
    for v in vids:
        feed.mode(v, 3.5, RTL)
    t = feed.run(3.5, 60.0, until=lambda op: op.phase == "done")
    assert t == pytest.approx(33.0)
    assert op.end_status == {"on_ground": 0, "in_air": 2, "not_heard": 0}


def test_begin_end_is_ignored_once_ending_or_finished():
    op, station, feed, vids = to_run(1)
    op.begin_end(2.0)
    assert op.phase == "end" and op.end_t0_s == 2.0
    op.begin_end(3.0)
    assert op.end_t0_s == 2.0
    op2, *_ = make(1, audit=True)
    op2.poll(0.0)
    assert op2.phase == "audit"
    op2.begin_end(1.0)
    assert op2.phase == "end"


def test_restore_params_after_landing():
    op, station, feed, (v,) = make(
        1, audit=True, max_speed_m_s=10.0, climb_rate_m_s=5.0, restore_params=True, duration_s=2.0
    )
    feed.poll(0.0)
    answer_audit(feed, station, 0.5, {**AP_SAFE, "WPNAV_SPEED": 500.0, "WPNAV_SPEED_UP": 500.0})
    feed.poll(0.75)
    feed.param(v, "WPNAV_SPEED", 1000.0, 1.0)
    feed.emit(ParamSetConfirmed(0, 1, 1.0, "WPNAV_SPEED", 1000.0, 500.0, REAL32))
    feed.poll(1.0)
    assert op.phase == "launch"
    feed.fly(v, 1.5)
    feed.poll(1.5)
    assert op.phase == "run"
    feed.run(1.75, 3.5)
    assert op.phase == "end"
    assert not any(c["purpose"] == "restore" for c in op.param_changes)
    feed.mode(v, 4.0, RTL)
    feed.armed(v, 4.0, False)
    feed.poll(4.0)
    assert op.phase == "end"  # restoring
    (s,) = station.of("set_param", since_s=4.0)
    assert (s[2], s[3], s[6]) == ("WPNAV_SPEED", 500.0, 1000.0)
    assert op.param_changes[-1]["purpose"] == "restore"
    feed.run(4.25, 6.0)
    assert op.phase == "end" and len(station.of("set_param", since_s=4.0)) == 1
    feed.emit(ParamSetConfirmed(0, 1, 6.1, "WPNAV_SPEED", 500.0, 1000.0, REAL32))
    feed.poll(6.25)
    assert op.phase == "done"
    assert op.param_changes[-1]["ok"] is True


def test_restore_gives_up_after_ten_seconds():
    op, station, feed, (v,) = make(
        1, audit=True, max_speed_m_s=10.0, restore_params=True, duration_s=2.0
    )
    feed.poll(0.0)
    answer_audit(feed, station, 0.5, {**AP_SAFE, "WPNAV_SPEED": 500.0, "WPNAV_SPEED_UP": 100.0})
    feed.poll(0.75)
    feed.emit(ParamSetConfirmed(0, 1, 1.0, "WPNAV_SPEED", 1000.0, 500.0, REAL32))
    feed.poll(1.0)
    feed.fly(v, 1.5)
    feed.run(1.5, 3.5)
    feed.armed(v, 4.0, False)
    t = feed.run(4.0, 30.0, until=lambda op: op.phase == "done")
    assert t == pytest.approx(14.0)


# ------------------------------------------------------------------------------- events


def test_status_texts_failsafes_and_prearm():
    op, station, feed, (v,) = make(1)
    feed.emit(StatusText(0, 1, 1.0, 2, "GCS Failsafe"))
    feed.emit(StatusText(0, 1, 1.1, 2, "Failsafe activated: Return"))
    feed.emit(StatusText(0, 1, 1.2, 6, "  Arming denied: not ready  "))
    feed.emit(StatusText(0, 1, 1.3, 6, "Flight mode change"))
    assert [(t, vid, s) for t, vid, s in op.failsafe_texts] == [
        (1.0, v, "GCS Failsafe"),
        (1.1, v, "Failsafe activated: Return"),
    ]
    assert op.prearm[v] == (1.2, "Arming denied: not ready")


def test_a_failsafe_that_ended_is_good_news_not_a_failsafe_warning():
    """ArduCopter says "GCS Failsafe Cleared" at WARNING (events.cpp failsafe_gcs_off_event),
    PX4 "GCS connection regained" at INFO (Commander.cpp dataLinkCheck): neither is a failsafe
    for the operator (fly's "warning: ... reports", the live view's red line)."""
    op, station, feed, (v,) = make(1)
    feed.emit(StatusText(0, 1, 1.0, 4, "GCS Failsafe"))
    feed.emit(StatusText(0, 1, 2.0, 4, "GCS Failsafe Cleared"))
    feed.emit(StatusText(0, 1, 3.0, 6, "GCS connection regained"))
    feed.emit(StatusText(0, 1, 4.0, 2, "EKF Failsafe Cleared"))
    assert op.failsafe_texts == [(1.0, v, "GCS Failsafe")]
    kinds = [
        StatusText(0, 1, 0.0, sev, text).kind
        for sev, text in (
            (4, "GCS Failsafe"),
            (4, "GCS Failsafe Cleared"),
            (6, "GCS connection regained"),
            (2, "RTL: unsupported MAV_FRAME"),
            (6, "Takeoff detected"),
        )
    ]
    assert kinds == ["failsafe", "recovered", "recovered", "failsafe", "status"]


def test_home_position_moves_the_altitude_above_home():
    op, station, feed, (v,) = make(1, wave_timeout_s=1000.0, takeoff_grace_s=1.0)
    feed.poll(0.0)
    feed.mode(v, 0.1, GUIDED)
    feed.armed(v, 0.1, True)
    feed.alt(v, 0.1, 0.5)  # 0.5 m above the estimated home: on the ground
    feed.run(0.25, 2.75)
    assert len(station.of("takeoff")) == 1
    feed.poll(3.0)  # grace over, action_retry_s since the last attempt: sent again
    assert len(station.of("takeoff")) == 2
    # HOME_POSITION says home is 5 m lower: 5.5 m above it, airborne.
    feed.emit(
        HomePositionReceived(0, 1, 3.1, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_amsl_m - 5.0)
    )
    feed.run(3.25, 12.0)
    assert len(station.of("takeoff")) == 2


def test_mode_and_armed_changes_are_folded_into_the_fleet():
    op, station, feed, (v,) = make(1)
    feed.mode(v, 1.0, GUIDED)
    feed.armed(v, 1.0, True)
    snap = op.fleet.snapshot(1.0)
    assert snap.mode[0] == "GUIDED" and snap.armed[0]


# -------------------------------------------------------------------------- operator actions


def test_operator_actions_hold_rtl_land_release_rejoin():
    op, station, feed, (v, w) = to_run(2)
    seen: list[OperatorAction] = []
    op.on_action = seen.append
    (a,) = op.operator_command("hold", v, 1.5, source="web 127.0.0.1")
    assert (a.action, a.link_id, a.sysid, a.source, a.result) == (
        "hold",
        0,
        1,
        "web 127.0.0.1",
        "sent",
    )
    hold = station.calls[-1]
    assert hold[0] == "set_position_target" and hold[1] == v
    assert hold[4] == pytest.approx(20.0, abs=0.01)
    assert op.released == {v: "hold"}
    (b,) = op.operator_command("rtl", w, 1.6)
    assert b.result == "sent"
    assert [c[0] for c in station.calls[-2:]] == ["clear_position_target", "rtl"]
    (c,) = op.operator_command("land", w, 1.7)
    assert [c_[0] for c_ in station.calls[-2:]] == ["clear_position_target", "land"]
    assert op.released == {v: "hold", w: "land"}
    (d,) = op.operator_command("rejoin", v, 1.8)
    assert d.result == "rejoined" and v not in op.released
    (e,) = op.operator_command("rejoin", v, 1.9)
    assert e.result == "was not released"
    (f,) = op.operator_command("release", v, 2.0)
    assert f.result == "released" and op.released[v] == "release"
    assert seen == op.actions and [x.action for x in seen] == [
        "hold",
        "rtl",
        "land",
        "rejoin",
        "rejoin",
        "release",
    ]
    with pytest.raises(ValueError):
        op.operator_command("fly away", v, 2.0)
    with pytest.raises(UnknownVehicle):
        op.operator_command("hold", (0, 42), 2.0)


def test_rejoin_reclaims_at_the_next_poll():
    op, station, feed, (v, w) = to_run(2)
    op.operator_command("rtl", v, 1.5)
    feed.mode(v, 1.6, RTL)
    feed.run(1.75, 10.0)
    assert not station.of("engage_guided", v, since_s=1.5)
    op.operator_command("rejoin", v, 10.1)
    feed.poll(10.25)
    assert station.of("engage_guided", v, since_s=10.25)
    assert op.counters["reclaim_attempts"] == 1


def test_operator_command_for_all_heard_and_link_errors():
    op, station, feed, (v, w) = to_run(2)
    feed.silent.add(w)
    feed.run(1.25, 7.0)
    station.raises["rtl"] = LinkUsageError("no route")
    recs = op.operator_command("rtl", None, 7.1, source="cli")
    assert [(r.sysid, r.result) for r in recs] == [(1, "not sent: no route")]
    assert op.released == {v: "rtl"}


def test_hold_without_a_position_releases_only():
    op, station, feed, _ = make(0)
    feed.emit(VehicleDiscovered(0, 1, 0.0, ARDUPILOT, 2, STABILIZE, "STABILIZE", False))
    (a,) = op.operator_command("hold", (0, 1), 0.5)
    assert a.result.startswith("released") and station.calls == []


def test_an_operator_rtl_vehicle_is_left_alone_at_the_end():
    op, station, feed, (v, w) = to_run(2, duration_s=2.0)
    op.operator_command("rtl", v, 1.5)  # told RTL, not yet in RTL
    feed.run(1.75, 3.0)
    assert op.phase == "end"
    assert len(station.of("rtl", v)) == 1 and len(station.of("rtl", w)) == 1


# ------------------------------------------------------------------------------ interrupt


@pytest.mark.parametrize("phase", ["discover", "audit", "refused"])
def test_interrupt_end_before_launch_is_done(phase):
    op, station, feed, (v,) = make(1, audit=True, expected_vehicles=1 if phase != "discover" else 2)
    feed.poll(0.0)
    if phase == "refused":
        answer_audit(feed, station, 0.5, {**AP_SAFE, "FS_GCS_ENABLE": 0.0})
        feed.poll(0.75)
    assert op.phase == phase
    n = len(station.calls)
    op.interrupt("end", 1.0)
    assert op.phase == "done" and op.interrupted == "end" and len(station.calls) == n


def test_interrupt_end_in_flight_ends_the_mission():
    op, station, feed, vids = to_run(2)
    op.interrupt("end", 2.0)
    assert op.phase == "end" and op.end_t0_s == 2.0 and op.interrupted == "end"
    feed.poll(2.0)
    assert len(station.of("rtl", since_s=2.0)) == 2


@pytest.mark.parametrize("action", ["rtl", "land", "hold"])
def test_interrupt_tells_every_vehicle_and_reports(action):
    op, station, feed, (v, w, x) = to_run(3, end="land")
    feed.silent.add(x)
    feed.run(1.25, 7.0)
    op.interrupt(action, 7.1)
    assert op.phase == "done" and op.interrupted == action
    assert [(a.sysid, a.action, a.source) for a in op.actions] == [
        (1, action, "interrupt"),
        (2, action, "interrupt"),
    ]
    if action in ("rtl", "land"):
        assert len(station.of(action, since_s=7.1)) == 2
    else:
        assert len(station.of("set_position_target", since_s=7.1)) == 2
    # v obeys (and lands), w does not answer yet; x is not heard.
    if action != "hold":
        feed.mode(v, 7.5, RTL if action == "rtl" else LAND)
        feed.mode(w, 7.5, STABILIZE)
    else:
        feed.mode(w, 7.5, LAND)
    rep = op.interrupt_report(7.5)
    assert [r[0] for r in rep] == [v, w, x]
    assert rep[0][2] is True and rep[1][2] is False and rep[2][2] is False
    assert "not heard" in rep[2][1]
    feed.armed(v, 8.0, False)
    assert op.interrupt_report(8.0)[0] == (
        v,
        f"on the ground ({op.fleet.snapshot(8).mode[0]})",
        True,
    )


def test_interrupt_report_end_uses_the_missions_end_action():
    op, station, feed, (v,) = to_run(1, end="land")
    op.interrupt("end", 2.0)
    feed.mode(v, 2.5, RTL)
    (rep,) = op.interrupt_report(2.5)
    assert rep[2] is False and "LAND" in rep[1]
    feed.mode(v, 3.0, LAND)
    assert op.interrupt_report(3.0)[0][2] is True


def test_a_second_interrupt_after_done_stays_done():
    op, station, feed, vids = to_run(1)
    op.interrupt("rtl", 2.0)
    op.interrupt("land", 2.5)
    assert op.phase == "done" and op.interrupted == "land"
    assert len(station.of("land")) == 1


# --------------------------------------------------------------------- the transition table


def test_every_phase_has_a_table_row_and_a_poll_handler():
    from gcs.operations import TRANSITIONS, Phase

    assert tuple(p.value for p in Phase) == PHASES
    assert set(TRANSITIONS) == set(Phase) == set(Operator._POLL)
    # Every phase is reachable from discover, and every phase can reach done.
    seen, todo = {Phase.DISCOVER}, [Phase.DISCOVER]
    while todo:
        for nxt in TRANSITIONS[todo.pop()].values():
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    assert seen == set(Phase)
    for phase in Phase:
        reach, todo = {phase}, [phase]
        while todo:
            for nxt in TRANSITIONS[todo.pop()].values():
                if nxt not in reach:
                    reach.add(nxt)
                    todo.append(nxt)
        assert Phase.DONE in reach, phase


def test_an_illegal_transition_raises():
    from gcs.operations import IllegalTransition, Trigger

    op, station, feed, vids = make(1)
    with pytest.raises(IllegalTransition):
        op._enter(Trigger.LAUNCHED, 0.0)  # discover -> run: no such move
    assert op.phase == "discover"
    feed.poll(0.0)
    assert op.phase == "launch"
    for trigger in (Trigger.FOUND, Trigger.CLEARED, Trigger.UNSAFE, Trigger.LANDED):
        with pytest.raises(IllegalTransition):
            op._enter(trigger, 0.5)
    assert op.phase == "launch"
    op.interrupt("rtl", 1.0)
    assert op.phase == "done"
    for trigger in Trigger:
        if trigger is not Trigger.INTERRUPT:
            with pytest.raises(IllegalTransition):
                op._enter(trigger, 2.0)


def test_the_phase_is_a_string_enum_a_driver_may_set():
    import json

    from gcs.operations import Phase

    op, station, feed, vids = to_run(1)
    assert op.phase is Phase.RUN and op.phase == "run" and hash(op.phase) == hash("run")
    assert json.dumps({"phase": op.phase}) == '{"phase": "run"}'
    assert op.phase in ("launch", "run") and f"phase {op.phase}" == "phase run"
    op.phase = "done"  # what a runner's stop hook does
    assert op.phase is Phase.DONE and op.finished
    with pytest.raises(ValueError):
        op.phase = "hovering"


def test_a_subclass_of_a_handled_event_gets_its_handler():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class LoudStatusText(StatusText):
        pass

    op, station, feed, (v,) = make(1)
    feed.emit(LoudStatusText(0, 1, 1.0, 2, "GCS Failsafe"))
    assert op.failsafe_texts == [(1.0, v, "GCS Failsafe")]


def test_optional_parameters_a_firmware_lacks_do_not_hold_the_audit():
    # PX4 1.18 has no COM_OBL_ACT (PX4 <= 1.13 only) and no answer comes for it: once every
    # required read is answered the audit waits OPTIONAL_GRACE_S, not a read timeout with
    # retries (a restarted station reclaimed its PX4 vehicles ~10 s late).
    from gcs.operations.audit import OPTIONAL_GRACE_S

    safe = PX4_SAFE_WITHOUT_COM_OBL_ACT
    op, station, feed, (v,) = make(1, audit=True, autopilot=PX4)
    feed.poll(0.0)
    assert ("request_param", v, "COM_OBL_ACT") in [c[:3] for c in station.calls]
    answer_audit(feed, station, 0.5, safe)
    feed.poll(0.5 + OPTIONAL_GRACE_S / 2)
    assert op.phase == "audit"  # a late optional answer is still welcome
    feed.poll(0.5 + OPTIONAL_GRACE_S + 0.1)
    assert op.phase == "launch"
    assert ("cancel_param", v, "COM_OBL_ACT") in [c[:3] for c in station.calls]


# ------------------------------------------------------------ a forwarded client's override


class _Override:
    """What the operator reads of a gcs.forward.Override (a forwarded client's mode change)."""

    def __init__(self, vids, what="SET_MODE RTL", client="127.0.0.1:14550 sysid 254"):
        self.vids, self._what, self.client = tuple(vids), what, client

    def what(self, autopilot=None):
        return self._what


def test_an_honoured_override_takes_the_vehicle_out_of_the_plan_until_rejoined():
    op, station, feed, (v, w) = to_run(2)
    seen: list[OperatorAction] = []
    op.on_action = seen.append
    feed.run(1.25, 5.0)
    assert op.forwarded_override(_Override([v]), 5.1, refuse=False) is None  # passed on
    assert op.released == {v: "override"}
    (rec,) = seen
    assert (rec.action, rec.link_id, rec.sysid) == ("override", 0, 1)
    assert rec.source == "127.0.0.1:14550 sysid 254" and rec.result == "SET_MODE RTL (t+4 s)"
    assert op.overrides[v] is rec
    # Its setpoint stream and any command retry of ours stop at once ...
    assert [c[0] for c in station.calls[-2:]] == [
        "clear_position_target",
        "withdraw_flight_commands",
    ]
    feed.mode(v, 5.2, RTL)  # the client's RTL reaches the vehicle
    feed.run(5.25, 30.0)
    # ... and it is never switched back, re-targeted or planned while the other one flies on.
    assert not station.of("engage_guided", v, since_s=5.1)
    assert not station.of("set_position_target", v, since_s=5.1)
    assert station.of("set_position_target", w, since_s=25.0)
    assert op.records[-1].planned == 1  # only w is given a target
    # A client's retry of the same command is recorded once.
    op.forwarded_override(_Override([v]), 30.1, refuse=False)
    assert len(seen) == 1
    # The operator gives it back: reclaimed like a vehicle back from a failsafe.
    op.operator_command("rejoin", v, 30.2, source="web 127.0.0.1")
    assert v not in op.released and v not in op.overrides
    feed.poll(30.25)
    assert station.of("engage_guided", v, since_s=30.25)


def test_an_honoured_override_is_not_end_commanded():
    op, station, feed, (v, w) = to_run(2, duration_s=10.0)
    op.forwarded_override(_Override([v], "DO_REPOSITION"), 2.0, refuse=False)
    feed.run(1.25, 20.0)
    assert op.phase == "end"
    assert station.of("rtl", w) and not station.of("rtl", v)
    op.interrupt("end", 20.1)  # Ctrl-C: the report says whose it is
    rep = dict((vid, (text, ok)) for vid, text, ok in op.interrupt_report(20.2))
    assert rep[v] == (
        "127.0.0.1:14550 sysid 254 flies it (DO_REPOSITION (t+1 s)); now GUIDED: not told",
        True,
    )
    assert "told RTL" in rep[w][0]


def test_a_refused_override_leaves_the_vehicle_in_the_plan_and_says_why():
    op, station, feed, (v, w) = to_run(2)
    seen: list[OperatorAction] = []
    op.on_action = seen.append
    why = op.forwarded_override(_Override([v]), 2.0, refuse=True)
    assert why == "phireman: vehicle 1 is flown by the relay plan; hold it on the station first"
    assert op.released == {} and not station.of("clear_position_target")
    (rec,) = seen
    assert (rec.action, rec.sysid, rec.result) == ("override-refused", 1, "SET_MODE RTL (t+1 s)")
    # A client's retries are each refused, recorded once (again after a while).
    assert op.forwarded_override(_Override([v]), 3.0, refuse=True) == why
    assert len(seen) == 1
    op.forwarded_override(_Override([v]), 14.0, refuse=True)
    assert len(seen) == 2
    # Held on the station first: the client may fly it, and the record says it took it.
    op.operator_command("hold", v, 15.0, source="web 127.0.0.1")
    assert op.forwarded_override(_Override([v]), 15.5, refuse=True) is None
    assert op.released[v] == "override" and seen[-1].action == "override"


def test_override_of_vehicles_the_station_does_not_fly_passes():
    op, station, feed, (v,) = to_run(1)
    assert op.forwarded_override(_Override([(0, 42)]), 2.0, refuse=True) is None
    assert op.forwarded_override(_Override([]), 2.0, refuse=True) is None
    assert op.released == {} and not op.actions


def test_over_terrain_a_vehicle_in_a_canyon_below_its_home_is_airborne():
    # docs/terrain.md §6.2: under the ceiling a vehicle flies down into a canyon, below its home
    # on the rim. Its height is read above the DEM's ground, so it stays planned and is never
    # sent a take-off (read above home, it was "on the ground" and sent NAV_TAKEOFF each retry).
    dem = synthetic_terrain(
        [Canyon([(-1500.0, 300.0), (1500.0, 300.0)], 250.0, 40.0, 150.0)],
        1500.0,
        10.0,
        ORIGIN.alt_amsl_m,
    )
    ta = TerrainAltitude(dem, ORIGIN.alt_amsl_m, clearance_m=15.0, ceiling_agl_m=120.0)
    control = ControlConfig(cruise_alt_m=100.0, n_layers=1, terrain=ta)
    station, planner = FakeStation(), FakePlanner()
    op = Operator(
        station,
        FleetView(ORIGIN, timeout_s=5.0),
        planner,
        lambda t: np.array([[1000.0, 0.0]]),
        control,
        OperationsConfig(audit=False, expected_vehicles=1),
        now_s=0.0,
    )
    feed = Feed(op)
    v = feed.add(1, 0.0, north_m=0.0)
    feed.poll(0.0)
    feed.fly(v, 1.0, alt_m=100.0)
    assert feed.poll(1.0) is not None and op.phase == "run"
    takeoffs = len(station.of("takeoff", v))
    feed.v[v]["east_m"] = 300.0  # over the canyon's floor, 250 m down
    feed.alt(v, 2.0, -150.0)  # 150 m below its home, 100 m above the floor
    feed.run(2.0, 20.0)
    assert planner.ticks[-1].networked.tolist() == [True]
    assert len(station.of("takeoff", v)) == takeoffs
    assert op.counters["relaunches"] == 0 and op.phase == "run"


def test_a_missions_descent_rate_is_read_and_written_with_the_limits():
    op, station, feed, (v,) = make(
        1, audit=True, max_speed_m_s=10.0, climb_rate_m_s=5.0, descent_rate_m_s=4.0
    )
    feed.poll(0.0)
    asked = [c[2] for c in station.of("request_param", v)]
    assert asked[-3:] == ["WPNAV_SPEED", "WPNAV_SPEED_UP", "WPNAV_SPEED_DN"]
    answer_audit(
        feed,
        station,
        0.5,
        {**AP_SAFE, "WPNAV_SPEED": 1000.0, "WPNAV_SPEED_UP": 500.0, "WPNAV_SPEED_DN": 150.0},
    )
    feed.poll(0.75)
    assert [(c[2], c[3], c[6]) for c in station.of("set_param", v)] == [
        ("WPNAV_SPEED_DN", 400.0, 150.0)
    ]
    feed.emit(ParamSetConfirmed(0, 1, 1.0, "WPNAV_SPEED_DN", 400.0, 150.0, REAL32))
    feed.poll(1.25)
    assert op.phase == "launch" and op.limit_warnings == []


def test_px4_descent_rate_parameter():
    assert limits_mod.limit_params(PX4, 10.0, 5.0, 4.0)["MPC_Z_VEL_MAX_DN"] == 4.0
    assert "MPC_Z_VEL_MAX_DN" not in limits_mod.limit_params(PX4, 10.0, 5.0)
    assert limits_mod.limit_writes(PX4, {"MPC_Z_VEL_MAX_DN": 1.5}, 10.0, 5.0, 4.0) == [
        ("MPC_Z_VEL_MAX_DN", 4.0)
    ]

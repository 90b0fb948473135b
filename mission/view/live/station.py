"""The live view's source: the operator's picture read from the running station.

Everything runs on the station's event loop: :meth:`LiveStation.on_event` is called by the
runner for every link event, the sampler task builds frames between two polls of the station,
and :meth:`LiveStation.act` (a web request handler on the same loop) calls
:meth:`gcs.operations.Operator.operator_command`, then flushes the links at once.
"""

from __future__ import annotations

import asyncio
import collections
import json
import logging
import math
import time
from collections.abc import Callable

import numpy as np

from gcs.control import layer_alt_m
from gcs.events import (
    CommandFailed,
    CommandTimedOut,
    ModeChanged,
    StatusText,
    TelemetryReceived,
    VehicleDiscovered,
    VehicleLost,
    VehicleRecovered,
)
from gcs.operations import OPERATOR_ACTIONS
from gcs.operations.config import override_label
from gcs.rally import RallyUploadFailed
from gcs.wire import mavlink
from mission.view.live.alerts import AlertBook, AlertConfig
from mission.view.live.health import LOSS_WINDOW_S, health_columns, minutes_to_reserve
from mission.view.live.rotation import MAX_EVENTS, rotation_frame
from mission.view.live.server import TruthUnavailable
from mission.view.live.state import (
    Picture,
    classify,
    decimate,
    frame_dict,
    mission_meta,
    mst_tree,
    tree_from_planner,
)
from planner.geometry import geodetic_to_ned_m

__all__ = ["LiveStation", "event_entry"]

log = logging.getLogger(__name__)

#: Frames cost at most this fraction of the station's wall time (the sampler slows down).
CPU_BUDGET = 0.015
MIN_PERIOD_S = 0.25


def _cmd_name(cmd: int) -> str:
    e = mavlink.enums.get("MAV_CMD", {}).get(cmd)
    return e.name.replace("MAV_CMD_", "") if e is not None else f"command {cmd}"


def event_entry(ev) -> tuple[str, str] | None:
    """(kind, text) of a link event worth showing the operator, or None."""
    if isinstance(ev, VehicleLost):
        return "lost", "lost (not heard)"
    if isinstance(ev, VehicleRecovered):
        return "recovered", f"heard again after {ev.silent_s:.0f} s, in {ev.mode or '?'}"
    if isinstance(ev, StatusText):  # "GCS Failsafe Cleared" is good news (gcs.events)
        return ev.kind, f"says: {ev.text.strip()}"
    if isinstance(ev, RallyUploadFailed):
        return "failsafe", ev.reason
    if isinstance(ev, CommandFailed):
        why = ev.reason or (f"result {ev.result}" if ev.result is not None else "failed")
        return "command", f"{_cmd_name(ev.command)} failed: {why}"
    if isinstance(ev, CommandTimedOut):
        return "command", f"{_cmd_name(ev.command)} not acknowledged ({ev.attempts} tries)"
    if isinstance(ev, ModeChanged) and ev.mode in ("RTL", "LAND", "AUTO.RTL", "AUTO.LAND"):
        return "mode", f"mode {ev.previous_mode or '?'} -> {ev.mode}"
    return None


def held_by(released: dict, overrides: dict) -> dict:
    """The page's word per released vehicle: the operator's action, or who took it for one a
    forwarded client took (``overrides``: vid -> its :class:`~gcs.operations.OperatorAction`)."""
    if not overrides:
        return released
    return {
        v: override_label(overrides[v].source, overrides[v].result) if v in overrides else a
        for v, a in released.items()
    }


class LiveStation:
    """Reads the :class:`gcs.operations.Operator` (see the module docstring).

    Parameters
    ----------
    op : the operator
    mission : the mission flown
    clock : the station's clock (core seconds)
    adapters : the station's links (flushed after an action)
    actions : whether actions may be enabled (the server also needs a key)
    tiles : what the page needs for background imagery (``server.tiles_meta``)
    alert_config : thresholds of the alerts (:mod:`mission.view.live.alerts`)
    log_event : where alerts and their acknowledgements are logged (the run directory's
        ``events.jsonl`` writer), or None
    """

    def __init__(
        self,
        op,
        mission,
        clock: Callable[[], float],
        adapters=(),
        *,
        actions: bool = True,
        tiles: dict | None = None,
        alert_config: AlertConfig | None = None,
        log_event: Callable[[object], None] | None = None,
    ) -> None:
        self.op = op
        self.alerts = AlertBook(alert_config or AlertConfig())
        self.log_event = log_event
        self._commanded: set[tuple[int, int]] = set()
        """Vehicles the station itself sent to RTL / LAND (no failsafe alert for them)."""
        self._loss: dict[tuple[int, int], float | None] = {}
        self._loss_t = -math.inf
        self.mission = mission
        self.clock = clock
        self.adapters = list(adapters)
        self.actions_enabled = actions
        self.tiles = tiles
        self.events: collections.deque = collections.deque(maxlen=300)
        self._seq = 0
        self._yaw_deg: dict[tuple[int, int], float] = {}
        self._targets: dict[tuple[int, int], tuple[float, float, float]] = {}
        self._phase = op.phase
        self._crew_tracks: list[list] = []
        self._crew_track_t = -math.inf
        self.frames_built = 0
        self.frame_cpu_s = 0.0
        self._task: asyncio.Task | None = None
        self._wrap_station()
        prev = op.on_action

        def on_action(rec) -> None:
            if prev is not None:
                prev(rec)
            self._add(
                rec.t_s,
                "action",
                (rec.link_id, rec.sysid),
                f"operator {rec.action.upper()} from {rec.source}: {rec.result}",
            )

        op.on_action = on_action

    # ------------------------------------------------------------------ inputs

    def _wrap_station(self) -> None:
        """Record the position target each vehicle is sent (the planned target), on the way to
        the station's normal command path (nothing else changes)."""
        st = self.op.station
        set_target, clear_target = st.set_position_target, st.clear_position_target

        def set_position_target(vid, lat_deg, lon_deg, alt_above_home_m, now_s, *a, **kw):
            out = set_target(vid, lat_deg, lon_deg, alt_above_home_m, now_s, *a, **kw)
            self._targets[tuple(vid)] = (float(lat_deg), float(lon_deg), float(alt_above_home_m))
            return out

        def clear_position_target(vid, now_s, *a, **kw):
            self._targets.pop(tuple(vid), None)
            return clear_target(vid, now_s, *a, **kw)

        st.set_position_target = set_position_target
        st.clear_position_target = clear_position_target
        # Who sent a vehicle home: the station (an operator action, the end, a rotation) or not
        # (the autopilot's failsafe, another GCS) - the failsafe alert's question.
        commanded = self._commanded

        def wrap(name: str, home: bool | None):
            orig = getattr(st, name)

            def call(vid, *a, **kw):
                if home is None:  # set_mode(vid, mode, ...)
                    mode = str(a[0]).upper() if a else ""
                    on = any(w in mode for w in ("RTL", "LAND", "RETURN"))
                else:
                    on = home
                (commanded.add if on else commanded.discard)(tuple(vid))
                return orig(vid, *a, **kw)

            setattr(st, name, call)

        wrap("rtl", True)
        wrap("land", True)
        wrap("set_mode", None)
        wrap("engage_guided", False)

    def on_event(self, ev) -> None:
        """Every link event (called by the runner before the operator folds it)."""
        if isinstance(ev, TelemetryReceived):
            if ev.yaw_rad is not None:
                self._yaw_deg[(ev.link_id, ev.sysid)] = math.degrees(ev.yaw_rad) % 360.0
            return
        if isinstance(ev, VehicleDiscovered):
            return
        entry = event_entry(ev)
        if entry is not None:
            self._add(ev.t_s, entry[0], (ev.link_id, ev.sysid), entry[1])

    def _add(self, t_s: float, kind: str, vid, text: str) -> None:
        self._seq += 1
        op = self.op
        tm = None if op.mission_t0_s is None else t_s - op.mission_t0_s
        who = (
            ""
            if vid is None
            else (f"vehicle {vid[1]}" if vid[0] == 0 else f"vehicle {vid[0]}:{vid[1]}")
        )
        self.events.append(
            {
                "seq": self._seq,
                "t_s": round(t_s, 1),
                "t_mission_s": None if tm is None else round(tm, 1),
                "kind": kind,
                "vehicle": None if vid is None else f"{vid[0]}:{vid[1]}",
                "text": f"{who} {text}".strip(),
            }
        )

    # ------------------------------------------------------------------ output

    def meta(self) -> dict:
        return mission_meta(
            self.mission,
            self.op.control.geofence,
            mode="live",
            actions=self.actions_enabled,
            tiles=self.tiles,
            duration_s=self.op.config.duration_s,
            end_action=self.op.config.end,
        )

    def frame(self, index: int | None = None, truth: bool = False) -> dict:
        """The current frame (``index`` is ignored: a live station has only now).

        Raises
        ------
        TruthUnavailable
            ``truth``: the station never sees the emulator's truth (docs/live_view.md).
        """
        if truth:
            raise TruthUnavailable(
                "no emulator truth on the live view: the station never sees it; replay the run "
                "directory afterwards (phireman replay RUN_DIR --serve) for the truth layer"
            )
        op = self.op
        now = self.clock()
        snap = op.fleet.snapshot(now)
        n = snap.n_vehicles
        vids = list(zip(snap.link_id.tolist(), snap.sysid_of_index.tolist()))
        reclaimed = {(l, s) for _, l, s in op.reclaimed}
        states = classify(snap, op.released, reclaimed)
        hdg = np.array([self._yaw_deg.get(v, math.nan) for v in vids], dtype=float)
        vel = snap.vel_ned_m_s
        moving = np.isnan(hdg) & (np.hypot(vel[:, 0], vel[:, 1]) > 0.5) if n else np.zeros(0, bool)
        hdg[moving] = np.degrees(np.arctan2(vel[moving, 1], vel[moving, 0])) % 360.0
        target = np.full((n, 3), np.nan)
        rows = [i for i, v in enumerate(vids) if v in self._targets]
        if rows:
            t = np.array([self._targets[vids[i]] for i in rows])
            o = op.fleet.origin
            ned = np.atleast_2d(
                geodetic_to_ned_m(
                    t[:, 0],
                    t[:, 1],
                    np.full(len(rows), o.alt_amsl_m),
                    o.lat_deg,
                    o.lon_deg,
                    o.alt_amsl_m,
                )
            )
            home_above_base = snap.home_amsl_m[rows] - o.alt_amsl_m
            ned[:, 2] = -(t[:, 2] + np.nan_to_num(home_above_base))
            target[rows] = ned
        t_m = op.t_mission_s(now) if op.mission_t0_s is not None else None
        crews = np.asarray(op.task_pos_fn(t_m or 0.0), dtype=float).reshape(-1, 2)
        self._track_crews(t_m, crews)
        tree = tree_from_planner(op.planner)
        if tree is None:
            relay = snap.networked & snap.has_position & (states == "networked")
            tree = mst_tree(np.zeros(2), crews, snap.pos_ned_m[relay, :2])
        recs = op.records
        series = decimate(
            [(round(r.t_mission_s, 1), r.tasks_covered, r.networked, r.lost) for r in recs]
        )
        last = recs[-1] if recs else None
        pic = Picture(
            t_s=now,
            t_mission_s=t_m,
            phase=op.phase,
            snap=snap,
            states=states,
            heading_deg=hdg,
            target_ned_m=target,
            layer_alt_m=layer_alt_m(np.arange(n), op.control) if n else np.zeros(0),
            n_layers=op.control.n_layers,
            crews_ne_m=crews,
            tree=tree,
            tu1=None if last is None else last.tu1_so_far,
            tu2=None if last is None else last.tu2_so_far,
            series={
                "t": [s[0] for s in series],
                "crews": [s[1] for s in series],
                "networked": [s[2] for s in series],
                "lost": [s[3] for s in series],
            },
            events=list(self.events)[-60:],
            crew_tracks=self._crew_tracks,
            released=held_by(op.released, op.overrides),
            rotation=self._rotation(snap, now),
        )
        pic.health = health_columns(
            snap,
            op.fleet.origin,
            now,
            loss_frac=self._loss_windows(now, vids),
            reserve_min=self._reserve_min(snap),
        )
        mission = self.mission
        frame = frame_dict(pic, mission.radio.range_m, mission.radio.base_range_m)
        self._update_alerts(now, frame, snap)
        frame["alerts"] = {
            "open": self.alerts.unacknowledged(),
            "recent": self.alerts.recent(),
            "crew_cut_off_s": self.alerts.config.crew_cut_off_s,
            "battery_low_pct": round(100 * self.alerts.config.battery_low_frac),
        }
        return frame

    # ------------------------------------------------------------------ health and alerts

    def _loss_windows(self, now_s: float, vids: list) -> list[float | None]:
        """Per row, the packet loss of the last closed window (:data:`LOSS_WINDOW_S`)."""
        if now_s >= self._loss_t + LOSS_WINDOW_S:
            self._loss_t = now_s
            st = self.op.station
            for vid in vids:
                try:
                    self._loss[vid] = st.link(vid[0]).seq_counter(vid[1]).take_window()
                except (KeyError, LookupError):
                    self._loss[vid] = None
        return [self._loss.get(v) for v in vids]

    def _reserve_min(self, snap) -> np.ndarray:
        """Minutes to the battery reserve: the rotation's own figure where it runs (its reserve
        is the way home plus a margin, planner.endurance.time_to_reserve_s), else the drain
        estimate (gcs.battery) down to the alert's low level."""
        n = snap.n_vehicles
        out = minutes_to_reserve(
            snap.battery_frac if snap.battery_frac is not None else np.full(n, np.nan),
            snap.drain_per_s if snap.drain_per_s is not None else np.full(n, np.nan),
            self.alerts.config.battery_low_frac,
        )
        rot = getattr(self.op, "rotation", None)
        t = getattr(rot, "time_to_reserve_s", None)
        if t is not None and len(t):
            k = min(n, len(t))
            t = np.asarray(t[:k], dtype=float)
            out[:k] = np.where(np.isfinite(t), t / 60.0, np.nan)
        return out

    def _update_alerts(self, now_s: float, frame: dict, snap) -> None:
        op = self.op
        v = frame["v"]
        ending = op.phase in ("end", "done")
        commanded = v["id"] if ending else [f"{l}:{s}" for l, s in self._commanded]
        raised = self.alerts.update(
            now_s,
            vehicles=v["id"],
            states=v["state"],
            modes=v["mode"],
            commanded=commanded,
            battery_frac=snap.battery_frac,
            charge_state=snap.battery_charge_state,
            crews=self._crew_names(len(frame["crews"]["connected"])),
            crews_connected=frame["crews"]["connected"],
            mission_running=op.phase == "run" and op.mission_t0_s is not None,
        )
        for rec in raised:
            self._add(rec.t_s, "alert", None, f"ALERT {rec.kind}: {rec.text}")
            if self.log_event is not None:
                self.log_event(rec)
        if raised:
            log.warning("live view: %s", "; ".join(f"{r.kind}: {r.text}" for r in raised))

    def _crew_names(self, k: int) -> list[str]:
        names = getattr(self, "_names", None)
        if names is None or len(names) != k:
            from mission.view.live.state import crew_names

            names = crew_names(self.mission)
            names = (names + [f"crew {i + 1}" for i in range(len(names), k)])[:k]
            self._names = names
        return names

    def acknowledge(self, alert: str, source: str) -> list[dict]:
        """An operator acknowledged alert ``alert`` (its id, or ``"all"``) from the page."""
        try:
            which: int | str = "all" if alert == "all" else int(alert)
        except ValueError:
            raise ValueError(f"alert must be an id or 'all', got {alert!r}") from None
        done = self.alerts.acknowledge(which, self.clock(), source)
        for rec in done:
            self._add(
                rec.t_s,
                "ack",
                None,
                f"alert {rec.alert_id} ({rec.kind}: {rec.subject}) acknowledged by {source}",
            )
            if self.log_event is not None:
                self.log_event(rec)
        return [{"id": r.alert_id, "kind": r.kind, "subject": r.subject} for r in done]

    def _rotation(self, snap, now_s: float) -> dict | None:
        """The frame's ``rotation`` key (None without batteries)."""
        state = self.op.rotation_state()
        if state is None:
            return None
        start = max(0, len(self.op.rotation.events) - MAX_EVENTS)
        return rotation_frame(
            state, self.op.rotation_events(start), snap, now_s, self.op.mission_t0_s
        )

    def _track_crews(self, t_m: float | None, crews: np.ndarray) -> None:
        if t_m is None or t_m < self._crew_track_t + 1.0:
            return
        self._crew_track_t = t_m
        if len(self._crew_tracks) != len(crews):
            self._crew_tracks = [[] for _ in range(len(crews))]
        for k, (n, e) in enumerate(crews.tolist()):
            if math.isfinite(n) and math.isfinite(e):
                tr = self._crew_tracks[k]
                tr.append([round(n, 1), round(e, 1)])
                if len(tr) > 400:
                    del tr[::2]  # keep the whole track, coarser

    # ------------------------------------------------------------------ actions

    def act(self, action: str, vehicle: str, source: str) -> list[dict]:
        """An operator action from the page: ``vehicle`` is ``"LINK:SYSID"`` or ``"all"``."""
        if action not in OPERATOR_ACTIONS:
            raise ValueError(f"unknown action {action!r}; valid: {', '.join(OPERATOR_ACTIONS)}")
        if not self.actions_enabled:
            raise ValueError("actions are off")
        vid = None
        if vehicle != "all":
            try:
                link, sysid = (int(x) for x in vehicle.split(":"))
            except ValueError:
                raise ValueError(
                    f"vehicle must be 'LINK:SYSID' or 'all', got {vehicle!r}"
                ) from None
            vid = (link, sysid)
        done = self.op.operator_command(action, vid, self.clock(), source=source)
        for a in self.adapters:  # out now, not at the next poll
            a.transmit()
        return [
            {"vehicle": f"{r.link_id}:{r.sysid}", "action": r.action, "result": r.result}
            for r in done
        ]

    # ------------------------------------------------------------------ the sampler

    def start(self, server) -> None:
        self._task = asyncio.get_running_loop().create_task(self._sample(server))

    async def _sample(self, server) -> None:
        period = MIN_PERIOD_S
        while True:
            if self.op.phase != self._phase:
                self._add(self.clock(), "phase", None, f"phase {self._phase} -> {self.op.phase}")
                self._phase = self.op.phase
            # Frames are built with or without a page open: the alerts they feed are logged
            # either way (docs/live_view.md, "Alerts"); the CPU budget holds for both.
            t0 = time.process_time()
            try:
                frame = self.frame()
                if server.clients:
                    server.publish(
                        json.dumps(frame, allow_nan=False, separators=(",", ":")).encode()
                    )
            except Exception:  # noqa: BLE001 - the view must never stop the flight
                log.exception("live view: building a frame failed")
            cost = time.process_time() - t0
            self.frames_built += 1
            self.frame_cpu_s += cost
            period = max(MIN_PERIOD_S, cost / CPU_BUDGET)
            await asyncio.sleep(period)

    async def aclose(self) -> None:
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except (asyncio.CancelledError, Exception):  # noqa: BLE001
                pass

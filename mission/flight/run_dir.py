"""A flight's run directory: where it goes, what is written at start, the summary at the end.

A run directory holds: ``mission.yaml`` (resolved), ``run.json`` (seed, code version, options),
``flight.tlog`` (every frame both ways), ``events.jsonl``, ``metrics.csv`` (one row per control
tick), ``summary.json``, with batteries ``rotation.jsonl`` (the relay rotation, when it changes)
and, when emulated, ``truth.npz``. Records are written by a background
thread every half second (:mod:`gcs.records`), off the control path; ``close()`` writes the rest.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from gcs.events import HEALTH_EVENTS, BatteryReceived, TelemetryReceived
from gcs.operations import Operator
from gcs.records import EventLog, MetricsWriter, TlogWriter
from mission.flight.fly_options import FlyOptions
from mission.format.schema import Mission
from mission.format.version import code_version

__all__ = [
    "new_run_dir",
    "Records",
    "run_meta",
    "summary",
    "stopped_summary",
    "FlightTimes",
    "flown_span_s",
    "ROTATION_FILE",
    "ROTATION_SNAPSHOT_S",
    "BATTERY_RECORD_PERIOD_S",
    "rotation_patch",
    "apply_rotation_patch",
    "read_rotation",
]

#: The rotation's record in a run directory (:meth:`Records.rotation`, :func:`read_rotation`).
ROTATION_FILE = "rotation.jsonl"

#: ``rotation.jsonl`` writes the whole state at least this often (station seconds); the lines
#: between carry only what changed (:func:`rotation_patch`), so a reader that starts at any
#: whole-state line, or lost a line, is right again at the next one.
ROTATION_SNAPSHOT_S = 300.0

#: A vehicle's battery report is written to events.jsonl at least this often (simulated s) while
#: nothing in it changes (:meth:`Records._battery_news`); the .tlog has every one.
BATTERY_RECORD_PERIOD_S = 10.0


def rotation_patch(old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any] | None:
    """What changed from ``old`` to ``new``, for :func:`apply_rotation_patch`: the keys whose
    value changed; a dict that changed as its own patch; a list as long as before as the
    entries that changed (``{"index": value}``); a removed key as None (a JSON merge patch,
    RFC 7396, with the lists of vehicles patched entry by entry). None when the patch would
    not give ``new`` back (a value that is None itself, which reads as a removal): the caller
    writes the whole state instead.

    The rotation's state (:meth:`gcs.operations.rotation_setup.RotationSetup.state`) changes a
    few entries at a tick (relays' reserve times, a vehicle's phase, a counter): its line
    shrinks from the whole state, about 2 kB with 50 vehicles, to those entries."""
    patch = _patch(old, new)
    return patch if apply_rotation_patch(old, patch) == new else None


def _patch(old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    patch: dict[str, Any] = {}
    for k, v in new.items():
        was = old.get(k)
        if k in old and was == v:
            continue
        if isinstance(v, dict) and isinstance(was, dict):
            patch[k] = _patch(was, v)
        elif isinstance(v, list) and isinstance(was, list) and len(v) == len(was):
            patch[k] = {str(i): x for i, (w, x) in enumerate(zip(was, v)) if w != x}
        else:
            patch[k] = v
    for k in old.keys() - new.keys():
        patch[k] = None
    return patch


def apply_rotation_patch(old: dict[str, Any], patch: dict[str, Any]) -> dict[str, Any]:
    """``old`` with ``patch`` (:func:`rotation_patch`) applied, as a new dict; ``old`` and the
    values the patch leaves alone are shared, not copied."""
    out = dict(old)
    for k, v in patch.items():
        was = old.get(k)
        if v is None:
            out.pop(k, None)
        elif isinstance(v, dict) and isinstance(was, dict):
            out[k] = apply_rotation_patch(was, v)
        elif isinstance(v, dict) and isinstance(was, list):
            entries = list(was)
            for i, x in v.items():
                entries[int(i)] = x
            out[k] = entries
        else:
            out[k] = v
    return out


def read_rotation(path: Path) -> list[tuple[float, dict[str, Any], list[dict[str, Any]]]]:
    """``rotation.jsonl``'s lines in order as ``(t_s, state, events)``, each state whole.

    A line is ``{"t_s", "state"}`` (the whole state) or ``{"t_s", "changed"}`` (a patch of the
    line before, :func:`rotation_patch`), with ``"events"`` when rotation events came. Files
    written before the patches have whole states only. A line that cannot be read (cut short by
    a crash) is skipped, and so are the patches after it until the next whole state."""
    out: list[tuple[float, dict[str, Any], list[dict[str, Any]]]] = []
    state: dict[str, Any] | None = None
    for text in path.read_text().splitlines():
        try:
            rec = json.loads(text)
            t_s = float(rec["t_s"])
            if "state" in rec:
                state = rec["state"]
            elif state is not None:
                state = apply_rotation_patch(state, rec["changed"])
            events = list(rec.get("events", ()))
        except (ValueError, KeyError, TypeError, AttributeError, IndexError):
            state = None  # a line lost: the patches after it wait for a whole state
            continue
        if state is not None:
            out.append((t_s, state, events))
    return out


#: Under this share of the requested speed-up the pace is reported as too slow (on screen and
#: ``summary.json``'s ``speedup_slow``): results such as reclaims and TU move with the pace.
SLOW_PACE_FRACTION = 0.5


@dataclasses.dataclass
class FlightTimes:
    """When the mission phase began and ended on both clocks (simulated, wall), and when Ctrl-C
    came, noted by the station's loop: the pace the mission was flown at (``summary.json``'s
    ``speedup_achieved``) and the replay's interrupt marker (``interrupted_at_s``)."""

    mission_start: tuple[float, float] | None = None
    """(simulated s, wall s) when the run phase began."""
    mission_end: tuple[float, float] | None = None
    """(simulated s, wall s) when it ended: its duration, Ctrl-C, or the operator ending it."""
    interrupt_s: float | None = None
    """Simulated time of Ctrl-C, if any."""

    def note(self, op: Operator, now_s: float, wall_s: float) -> None:
        if self.mission_start is None and op.mission_t0_s is not None:
            self.mission_start = (op.mission_t0_s, wall_s)
        if (
            self.mission_start is not None
            and self.mission_end is None
            and op.phase not in ("launch", "run")
        ):
            self.mission_end = (now_s, wall_s)

    def pace(self) -> float | None:
        """Simulated seconds per wall second while the mission ran (None before it ran)."""
        if self.mission_start is None or self.mission_end is None:
            return None
        wall = self.mission_end[1] - self.mission_start[1]
        return (self.mission_end[0] - self.mission_start[0]) / wall if wall > 0 else None


def flown_span_s(op: Operator) -> float:
    """The mission seconds flown, [0, span): the control steps the station ran (step k covers
    [k, k + 1) control periods, the truth's sample grid t0 + k dt), up to the mission's
    duration: all of it, or up to Ctrl-C. The span of both TU figures in ``summary.json``."""
    if op.mission_t0_s is None or not op.records:
        return 0.0
    period = op.config.control_period_s
    return min(op.config.duration_s, (op.records[-1].t_step + 1) * period)


def _station_tu(op: Operator, span_s: float) -> dict:
    """The station's TU1/TU2 over its control steps in [0, span_s) of mission time (each
    tick's record carries the TU of the ticks up to it)."""
    period = op.config.control_period_s
    inside = [r for r in op.records if r.t_step * period < span_s - 1e-9]
    if not inside:
        return {"tu1": None, "tu2": None, "ticks": 0, "span_s": span_s}
    last = inside[-1]
    return {"tu1": last.tu1_so_far, "tu2": last.tu2_so_far, "ticks": len(inside), "span_s": span_s}


def new_run_dir(mission: Mission, opts: FlyOptions, seed: int, kind: str) -> Path:
    """A new, empty run directory under ``--out`` or the mission's ``output.dir``."""
    base = Path(opts.out_dir) if opts.out_dir else Path(mission.output.dir)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    name = f"{stamp}-fly-{mission.name}-{kind}-s{seed}"
    path = base / name
    k = 1
    while path.exists():
        k += 1
        path = base / f"{name}-{k}"
    path.mkdir(parents=True)
    return path


class Records:
    """The run directory's writers (buffered, written every 0.5 s by a background thread)."""

    def __init__(self, run_dir: Path, mission: Mission, meta: dict) -> None:
        from mission.format.load import dump_mission

        self.dir = run_dir
        (run_dir / "mission.yaml").write_text(
            dump_mission(mission, "resolved mission of this run"), encoding="utf-8"
        )
        (run_dir / "run.json").write_text(
            json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8"
        )
        self.tlog = TlogWriter(run_dir / "flight.tlog")
        self.events = EventLog(run_dir / "events.jsonl")
        self.metrics = MetricsWriter(run_dir / "metrics.csv")
        self._rotation: MetricsWriter | None = None
        self._rotation_last: dict | None = None
        self._rotation_whole_s = -math.inf
        self._rotation_events = 0
        self._battery_last: dict[tuple[int, int, str], tuple[float, tuple]] = {}

    #: Write BatteryReceived to events.jsonl (a mission with batteries: the rotation's inputs);
    #: without batteries the live page's SYS_STATUS battery is in the .tlog only (replay reads
    #: it there), not one line per vehicle per second here.
    battery_events: bool = True

    def event(self, ev) -> None:
        if isinstance(ev, BatteryReceived) and not (self.battery_events and self._battery_news(ev)):
            return
        if not isinstance(ev, (TelemetryReceived, *HEALTH_EVENTS)):
            self.events.write(ev)

    def _battery_news(self, ev: BatteryReceived) -> bool:
        """Whether a battery report goes to events.jsonl: when its charge (the whole percent the
        autopilot reports), its charge state or what it knows changed since the last one written
        for that vehicle and message, or :data:`BATTERY_RECORD_PERIOD_S` after it. Every report
        is in the .tlog anyway; a line per vehicle per second was 98 % of events.jsonl (67 MB
        for the two hours of ``wildfire_2h``; 9 MB now)."""
        key = (ev.link_id, ev.sysid, ev.source)
        mark = (
            None if ev.remaining_frac is None else round(ev.remaining_frac * 100.0),
            ev.charge_state,
            ev.time_remaining_s is None,
            ev.consumed_mah is None,
        )
        last = self._battery_last.get(key)
        if last is not None and last[1] == mark and ev.t_s - last[0] < BATTERY_RECORD_PERIOD_S:
            return False
        self._battery_last[key] = (ev.t_s, mark)
        return True

    def rotation(self, op: Operator, now_s: float) -> None:
        """``rotation.jsonl`` (a mission with batteries): after a control tick, the rotation's
        state (:meth:`gcs.operations.rotation_setup.RotationSetup.state`) when it changed, with
        the rotation events since the line before: the whole state (``{"t_s", "state"}``) on the
        first line and every :data:`ROTATION_SNAPSHOT_S`, otherwise what changed
        (``{"t_s", "changed"}``, :func:`rotation_patch`); ``"events"`` when there are any. The
        replay draws its rotation panel from it (docs/live_view.md, :func:`read_rotation`)."""
        state = op.rotation_state()
        if state is None:
            return
        events = op.rotation_events(self._rotation_events)
        last = self._rotation_last
        if state == last and not events:
            return
        if self._rotation is None:
            self._rotation = MetricsWriter(self.dir / ROTATION_FILE, compact=True)
        line: dict[str, Any] = {"t_s": round(now_s, 3)}
        patch = None
        if last is not None and now_s - self._rotation_whole_s < ROTATION_SNAPSHOT_S:
            patch = rotation_patch(last, state)
        if patch is None:
            line["state"] = state
            self._rotation_whole_s = now_s
        else:
            line["changed"] = patch
        if events:
            line["events"] = events
        self._rotation.write(line)
        self._rotation_last = state
        self._rotation_events += len(events)

    def close(self) -> None:
        for w in (self.tlog, self.events, self.metrics, self._rotation):
            if w is not None:
                w.close()


def summary(
    mission: Mission,
    op: Operator,
    seed: int,
    kind: str,
    wall_s: float,
    speedup: float,
    report: dict | None,
    run_dir: Path,
    now_s: float,
    times: FlightTimes | None = None,
) -> dict:
    """``summary.json``: the station's view of the flight, plus the emulator's truth if any.

    Both TU figures cover the same span, the mission seconds flown (``flown_span_s``: all of
    the mission, or up to Ctrl-C); the report's truth must be taken over the same span. The
    pace: ``speedup_requested``, ``speedup_achieved`` (simulated / wall seconds while the
    mission ran: what the results were flown at), ``speedup_overall`` (mission seconds flown /
    ``wall_s``, start-up, take-off and landing included), ``speedup_slow``."""
    recs = op.records
    span = flown_span_s(op)
    pace = times.pace() if times is not None else None
    overall = span / wall_s if wall_s > 0 else None
    s = {
        "mission": mission.name,
        "backend": kind,
        "seed": seed,
        "phase": op.phase,
        "station": _station_tu(op, span),
        "duration_s": op.config.duration_s,
        "flown_span_s": span,
        "mission_s_flown": span,
        "wall_s": wall_s,
        "sim_s_flight": now_s - op.t_start_s,
        "speedup_requested": speedup,
        "speedup_achieved": pace,
        "speedup_overall": overall,
        "speedup_slow": pace is not None and pace < SLOW_PACE_FRACTION * speedup,
        "station_cpu_s": time.process_time(),
        "mission_t0_s": op.mission_t0_s,
        "interrupted_at_s": None
        if times is None or times.interrupt_s is None or op.mission_t0_s is None
        else max(0.0, times.interrupt_s - op.mission_t0_s),
        "vehicles_discovered": len(op.fleet),
        "refusal": op.refusal,
        "live_tasks": None
        if op.live_tasks is None
        else {
            "sysids": list(op.live_tasks.sysids),
            "never_heard": list(op.live_tasks.waiting_for()),
        },
        "reclaimed": len(op.reclaimed),
        "counters": op.counters,
        "endurance": op.rotation_summary(),
        "interrupted": op.interrupted,
        "end_status": op.end_status,
        "interrupt_report": None
        if op.interrupted is None
        else [
            {"link_id": v[0], "sysid": v[1], "state": text, "confirmed": ok}
            for v, text, ok in op.interrupt_report(now_s)
        ],
        "param_changes": op.param_changes,
        "limit_warnings": op.limit_warnings,
        "operator_actions": [dataclasses.asdict(a) for a in op.actions],
        "links": [
            {
                "link_id": l.link_id,
                "frames_out": l.stats.frames_out,
                "frames_in": l.stats.decode.frames,
                "bad_data": l.stats.decode.bad_data,
                "raw_frames": l.stats.decode.raw_frames,
                "signature_rejected": l.stats.decode.signature_rejected,
                "stream_fallbacks": l.stats.data_stream_fallbacks,
                "refused_sysids": l.stats.refused_sysids,
                "refused_by_sysid": dict(l.stats.refused_by_sysid),
                "inconsistent_frames": l.stats.inconsistent_frames,
                "messages_disabled": l.stats.messages_disabled,
            }
            for l in op.station.links
        ],
        "audit": None
        if op.audit_report is None
        else {
            "cleared_to_fly": op.audit_report.cleared_to_fly,
            "overridden": op.audit_report.overridden,
            "unsafe": [[a.link_id, a.sysid] for a in op.audit_report.unsafe],
            # vehicles discovered after the fleet audit, each audited on its own
            "late": op.late_audit_summary(),
        },
        "run_dir": str(run_dir),
    }
    servers = {id(l.terrain_server): l.terrain_server for l in op.station.links}
    served = [t for t in servers.values() if t is not None]
    if served:  # ArduPilot's terrain protocol (gcs/terrain.py, docs/terrain.md §6)
        s["terrain"] = {
            "requests_answered": sum(t.requests for t in served),
            "terrain_data_sent": sum(t.data_sent for t in served),
            "reports": [
                {"link_id": l.link_id, "sysid": sysid, **dataclasses.asdict(r)}
                for l in op.station.links
                for sysid, r in sorted(l.terrain_reports.items())
            ],
        }
    if recs:
        s["final"] = recs[-1].row()
    if report is not None:
        s["truth"] = report["truth"]
        s["emulator"] = report["stats"]
    return s


def stopped_summary(
    mission: Mission, seed: int, kind: str, run_dir: Path, exc: BaseException, wall_s: float
) -> dict:
    """``summary.json`` of a flight stopped before its station loop returned (interrupted while
    starting, Ctrl-C twice, SIGTERM twice, or an error): why, so a run directory is never left
    without one."""
    import asyncio

    interrupted = isinstance(exc, (asyncio.CancelledError, KeyboardInterrupt))
    return {
        "mission": mission.name,
        "backend": kind,
        "seed": seed,
        "phase": "stopped",
        "stopped": "interrupted (Ctrl-C or SIGTERM)"
        if interrupted
        else f"{type(exc).__name__}: {exc}",
        "wall_s": wall_s,
        "run_dir": str(run_dir),
    }


def run_meta(
    mission: Mission, opts: FlyOptions, seed: int, kind: str, speedup: float, connections
) -> dict:
    """``run.json``: seed, code version, backend, links and the options of this run."""
    return {
        "seed": seed,
        "code_version": code_version(),
        "backend": kind,
        "speedup": speedup,
        "connections": list(connections),
        "python": sys.version.split()[0],
        "options": {
            f.name: getattr(opts, f.name)
            for f in dataclasses.fields(opts)
            if not callable(getattr(opts, f.name))  # hooks (status, on_live, attach_view, ...)
        },
        "started_unix_s": time.time(),
    }

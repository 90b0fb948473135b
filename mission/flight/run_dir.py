"""A flight's run directory: where it goes, what is written at start, the summary at the end.

A run directory holds: ``mission.yaml`` (resolved), ``run.json`` (seed, code version, options),
``flight.tlog`` (every frame both ways), ``events.jsonl``, ``metrics.csv`` (one row per control
tick), ``summary.json`` and, when emulated, ``truth.npz``. Records are written by a background
thread every half second (:mod:`gcs.records`), off the control path; ``close()`` writes the rest.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

from gcs.events import TelemetryReceived
from gcs.operations import Operator
from gcs.records import EventLog, MetricsWriter, TlogWriter
from mission.flight.fly_options import FlyOptions
from mission.format.schema import Mission
from mission.format.version import code_version

__all__ = ["new_run_dir", "Records", "run_meta", "summary", "stopped_summary"]


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

    def event(self, ev) -> None:
        if not isinstance(ev, TelemetryReceived):
            self.events.write(ev)

    def close(self) -> None:
        for w in (self.tlog, self.events, self.metrics):
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
) -> dict:
    """``summary.json``: the station's view of the flight, plus the emulator's truth if any."""
    tu1, tu2 = op.station_tu()
    recs = op.records
    sim_s = (recs[-1].t_mission_s + mission.run.control_period_s) if recs else 0.0
    s = {
        "mission": mission.name,
        "backend": kind,
        "seed": seed,
        "phase": op.phase,
        "station": {"tu1": tu1, "tu2": tu2, "ticks": len(recs)},
        "duration_s": op.config.duration_s,
        "mission_s_flown": sim_s,
        "wall_s": wall_s,
        "speedup_requested": speedup,
        "station_cpu_s": time.process_time(),
        "speedup_achieved": (now_s - op.t_start_s) / wall_s if wall_s > 0 else None,
        "mission_t0_s": op.mission_t0_s,
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
        },
        "run_dir": str(run_dir),
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
            if f.name not in ("status", "on_operator", "on_live")
        },
        "started_unix_s": time.time(),
    }

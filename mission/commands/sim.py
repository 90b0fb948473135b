"""phireman sim: the paper's RTNUA simulation, many seeded runs, TU1/TU2 with 95 % CIs."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import pathlib
import sys
import time

HELP = "simulate the paper's problem in-process and print TU1/TU2 (mean ± 95 % CI)"
DESCRIPTION = """\
Run the RTNUA simulation of the paper (drones on a ring around the base, tasks random-walking in
the field, per-step attrition) with a registered planner, over many seeded scenarios, and print
TU1 and TU2 as mean ± 95 % confidence interval, plus the time per run.

Sizes are the paper's Table III (XS S M L XL). The default 'scaled' reading multiplies every
length (r, q, v, R, ring radius and noise, task sigma) by field half-width / 5, which is the only
reading under which the paper's M/L/XL numbers are reachable; '--reading literal' keeps the printed
lengths (see README).

examples:
  phireman sim                                   # S, 1 %/step, 100 seeds, PhiIREMAN (async)
  phireman sim --size M --info central --seeds 20
  phireman sim --method mccst --attrition 0.02
  phireman sim --set step_size=0.3 --set max_speed_m_s=0.2 --out runs/s1
  phireman sim --mission wildfire --out runs/wf    # play a mission file in-process, then:
  phireman replay runs/wf                          # plots and an animation of that run
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from planner.problem import SIZES

    p.add_argument("--size", default="S", type=str.upper, choices=list(SIZES), help="problem size (default S)")
    p.add_argument("--attrition", default=0.01, type=float, metavar="P",
                   help="per-drone, per-step loss probability (default 0.01)")
    p.add_argument("--seeds", default=100, type=int, metavar="N", help="number of seeded scenarios (default 100)")
    p.add_argument("--seed-start", default=0, type=int, metavar="S", help="first seed (default 0)")
    p.add_argument("--method", default="phireman", help="planner name (default phireman); see --list-methods")
    p.add_argument("--list-methods", action="store_true", help="list the registered planners and exit")
    p.add_argument("--info", choices=["async", "central"], default=None,
                   help="PhiIREMAN/DCCRS information model (default: the method's own, async for phireman)")
    p.add_argument("--reading", choices=["scaled", "literal"], default="scaled", help="length reading (default scaled)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a problem field (e.g. max_speed_m_s=0.2, task_border=none) or a planner "
                        "parameter (e.g. step_size=0.3); repeatable")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="write runs.csv, summary.json, fig2_timeseries.png and frames.png here")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--mission", default=None, metavar="MISSION",
                   help="play a mission file (or shipped example name) in-process instead of a paper preset; "
                        "--seeds counts from the mission's seed (default 1 run); --out writes a run directory")


def run(args) -> int:
    from mission.cli import UserError
    from mission.sim import default_workers, mean_ci95, run_episode, run_many
    from planner.methods import UnknownMethod, make_planner, method_names
    from planner.problem import problem_preset

    if args.list_methods:
        print("\n".join(method_names()))
        return 0
    if args.mission is not None:
        return _run_mission(args)
    if args.seeds < 1:
        raise UserError("--seeds must be >= 1")
    from mission.commands.sweep import split_overrides

    problem_over, params = split_overrides(args.set)
    if args.info is not None:
        params["info"] = args.info
    try:
        problem = problem_preset(args.size, args.attrition, args.reading, **problem_over)
        make_planner(args.method, problem, params)  # validate names and parameters before running
    except UnknownMethod as exc:
        raise UserError(str(exc)) from None
    except (ValueError, TypeError) as exc:
        raise UserError(str(exc)) from None

    seeds = list(range(args.seed_start, args.seed_start + args.seeds))
    workers = args.workers or default_workers()
    label = (f"{args.method}{'/' + params['info'] if 'info' in params else ''} | size {problem.size} "
             f"({problem.n_drones} drones, {problem.n_tasks} tasks) | attrition {100 * args.attrition:g} %/step "
             f"| {args.reading} reading | {len(seeds)} seeds")
    print(label, file=sys.stderr)
    t0 = time.perf_counter()
    bar = None
    if not args.no_progress:
        from tqdm import tqdm
        bar = tqdm(total=len(seeds), unit="run", file=sys.stderr, leave=False)
    rows = run_many(problem, args.method, params, seeds, workers, progress=bar.update if bar else None)
    if bar:
        bar.close()
    wall = time.perf_counter() - t0
    tu1, tu1_ci = mean_ci95([100 * r["tu1"] for r in rows])
    tu2, tu2_ci = mean_ci95([100 * r["tu2"] for r in rows])
    per_run = sum(r["wall_s"] for r in rows) / len(rows)
    print(f"TU1 = {tu1:.2f} ± {tu1_ci:.2f} %")
    print(f"TU2 = {tu2:.2f} ± {tu2_ci:.2f} %")
    print(f"{len(rows)} runs in {wall:.1f} s wall ({per_run:.3f} s per run per core, {workers} workers)")

    if args.out is not None:
        out = args.out
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "runs.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=["seed", "method", "tu1", "tu2", "wall_s", "final_alive", "final_active"])
            w.writeheader()
            for r in rows:
                w.writerow({k: r[k] for k in w.fieldnames})
        summary = {"method": args.method, "params": params, "problem": dataclasses.asdict(problem),
                   "seeds": seeds, "tu1_pct": tu1, "tu1_ci95_pct": tu1_ci, "tu2_pct": tu2,
                   "tu2_ci95_pct": tu2_ci, "wall_s": wall, "s_per_run": per_run}
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
        from mission.plots import plot_frame_strip, plot_time_series

        plot_time_series(rows, problem.n_drones, problem.n_tasks, label, out / "fig2_timeseries.png")
        frames = [0, problem.n_steps // 8, problem.n_steps // 3, problem.n_steps * 2 // 3, problem.n_steps]
        ep = run_episode(problem, args.method, params, seeds[0], record=True, frames=frames)
        plot_frame_strip(ep.record, frames, problem, f"{label.split(' | ')[0]}, seed {seeds[0]}",
                         out / "frames.png")
        print(f"wrote {out}/runs.csv, summary.json, fig2_timeseries.png, frames.png")
    return 0


def _run_mission(args) -> int:
    from mission.cli import UserError
    from mission.examples import example_path
    from mission.load import MissionError, load_mission
    from mission.playback import run_inprocess, write_run_dir
    from mission.sim import mean_ci95

    path = pathlib.Path(args.mission)
    if not path.exists():
        try:
            path = example_path(args.mission)
        except (KeyError, ValueError, FileNotFoundError):
            raise UserError(f"{args.mission}: no such file or shipped example") from None
    try:
        mission = load_mission(path)
    except MissionError as exc:
        raise UserError("invalid mission:\n  " + "\n  ".join(exc.errors)) from None
    n = args.seeds if "--seeds" in sys.argv else 1
    seeds = [mission.run.seed + k for k in range(n)]
    print(mission.summary(), file=sys.stderr)
    results = []
    for seed in seeds:
        try:
            r = run_inprocess(mission, seed)
        except ValueError as exc:
            raise UserError(str(exc)) from None
        results.append(r)
        print(f"seed {seed}: TU1 = {100 * r.tu1:.2f} %, TU2 = {100 * r.tu2:.2f} %, {len(r.losses)} losses, "
              f"{r.wall_s:.2f} s")
    if len(results) > 1:
        tu1, c1 = mean_ci95([100 * r.tu1 for r in results])
        tu2, c2 = mean_ci95([100 * r.tu2 for r in results])
        print(f"TU1 = {tu1:.2f} ± {c1:.2f} %\nTU2 = {tu2:.2f} ± {c2:.2f} %")
    if args.out is not None:
        write_run_dir(mission, results[0], args.out)
        print(f"wrote run directory {args.out} (seed {results[0].seed}); see it with: phireman replay {args.out}")
    return 0

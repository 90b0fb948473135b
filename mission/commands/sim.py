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
  phireman sim --method mccst --attrition 2%      # or 0.02; --seed 100 --seeds 20 runs seeds 100..119
  phireman sim --set step_size=0.3 --set max_speed_m_s=0.2 --out runs/s1
  phireman sim --mission wildfire --out runs/wf    # play a mission file in-process, then:
  phireman replay runs/wf                          # plots and an animation of that run
  phireman sim --mission canyon --terrain-aware off  # terrain radio, today's disc planner

With --mission the mission file sets the size, attrition, planner and its parameters: --size,
--attrition, --method, --info, --reading, --set and --workers are refused rather than ignored.
Confidence intervals reaching past 0 or 100 % (few seeds) are printed clipped to [0, 100].
"""


#: Options that describe a paper preset; a mission file fixes these itself.
_PRESET_ONLY = {
    "size": ("--size", "the mission's vehicles.count and tasks set the size"),
    "attrition": (
        "--attrition",
        "the mission sets attrition (attrition.rate_per_s, hazard zones, scripted losses)",
    ),
    "method": ("--method", "the mission names its planner (planner.method)"),
    "info": ("--info", "the mission sets the information model (planner.info)"),
    "reading": ("--reading", "a mission is already in metres; readings apply to the paper's units"),
    "set": (
        "--set",
        "the mission sets its problem and planner parameters (planner.params, radio, vehicles)",
    ),
    "workers": ("--workers", "mission runs are played one after another in this process"),
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mission.commands.options import add_seed_arguments, add_workers_argument, rate_arg
    from planner.problem import SIZES

    p.add_argument(
        "--size", default=None, type=str.upper, choices=list(SIZES), help="problem size (default S)"
    )
    p.add_argument(
        "--attrition",
        default=None,
        type=rate_arg,
        metavar="P",
        help="per-drone, per-step loss probability, a fraction (0.01) or a percent (1%%); default 0.01",
    )
    add_seed_arguments(p, None, "number of seeded scenarios (default 100; with --mission 1)")
    p.add_argument(
        "--method", default=None, help="planner name (default phireman); see --list-methods"
    )
    p.add_argument(
        "--list-methods", action="store_true", help="list the registered planners and exit"
    )
    p.add_argument(
        "--info",
        choices=["async", "central"],
        default=None,
        help="PhiIREMAN/DCCRS information model (default: the method's own, async for phireman)",
    )
    p.add_argument(
        "--reading",
        choices=["scaled", "literal"],
        default=None,
        help="length reading (default scaled)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a problem field (e.g. max_speed_m_s=0.2, task_border=none) or a planner "
        "parameter (e.g. step_size=0.3); repeatable",
    )
    add_workers_argument(p)
    p.add_argument(
        "--out",
        type=pathlib.Path,
        default=None,
        help="write runs.csv, summary.json, fig2_timeseries.png and frames.png here",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--mission",
        default=None,
        metavar="MISSION",
        help="play a mission file (or shipped example name) in-process instead of a paper preset; "
        "--seed replaces the mission's seed, --seeds N plays N seeds from it (default 1); "
        "--out writes a run directory. --size/--attrition/--method/--info/--reading/--set/"
        "--workers do not apply (the mission sets them)",
    )
    p.add_argument(
        "--battery",
        choices=["mission", "unlimited"],
        default="mission",
        help="with --mission: the mission's batteries (default), or 'unlimited' to play the "
        "same mission with endless batteries (the reference for relay rotation)",
    )
    p.add_argument(
        "--terrain-aware",
        choices=["on", "altitude", "off"],
        default=None,
        help="with a terrain mission (radio.model: terrain): 'on' (default) planning in 3-D, "
        "each drone's altitude between the clearance and the ceiling, tree edges and moves "
        "checked against the terrain radio, relay positions searched; 'altitude' terrain "
        "following with the disc planner; 'off' today's system, the disc planner at one altitude "
        "above the base (docs/terrain.md)",
    )
    p.add_argument(
        "--rotation",
        choices=["mission", "on", "off"],
        default="mission",
        help="with --mission: relay rotation through the base as the mission says (default), "
        "'on', or 'off': fly until the firmware's low-battery failsafe, relaunch after the swap",
    )


def ci_note(n: int, clipped: bool) -> str | None:
    """A line for people when the confidence interval is not meaningful or was clipped."""
    if n < 3:
        return (
            f"note: {n} run(s): too few for a useful 95 % CI; intervals wider than the 0-100 % range "
            f"are shown clipped to [0, 100] (use --seeds 3 or more; 30+ for tight intervals)"
        )
    if clipped:
        return "note: intervals reaching past 0 or 100 % are shown clipped to [0, 100]"
    return None


def run(args) -> int:
    from mission.commands.options import UserError, resolve_workers, writable_dir
    from mission.experiments.sim import format_pct_ci, mean_ci95, run_episode, run_many
    from planner.methods import UnknownMethod, make_planner, method_names, params_with_info
    from planner.problem import problem_preset

    if args.list_methods:
        print("\n".join(method_names()))
        return 0
    if args.mission is not None:
        return _run_mission(args)
    if args.terrain_aware is not None:
        raise UserError("--terrain-aware applies to a terrain mission (--mission canyon)")
    if args.battery != "mission" or args.rotation != "mission":
        raise UserError(
            "--battery and --rotation apply to a mission with batteries (--mission wildfire_2h); "
            "the paper's presets have endless batteries"
        )
    args.size = args.size or "S"
    args.attrition = 0.01 if args.attrition is None else args.attrition
    args.method = args.method or "phireman"
    args.reading = args.reading or "scaled"
    n_seeds = 100 if args.seeds is None else args.seeds
    seed0 = 0 if args.seed is None else args.seed
    from mission.commands.sweep import check_overrides, split_overrides

    problem_over, params = split_overrides(args.set)
    try:
        problem = problem_preset(args.size, args.attrition, args.reading, **problem_over)
    except (ValueError, TypeError) as exc:
        raise UserError(str(exc)) from None
    if args.method not in method_names():
        raise UserError(
            f"--method: unknown planner {args.method!r}; valid methods: {', '.join(method_names())}"
        )
    check_overrides([args.method], problem, params)
    try:
        if args.info is not None:  # one rule for which methods take which model (planner.methods)
            params = params_with_info(args.method, params, args.info)
        make_planner(args.method, problem, params)  # validate values before running
    except UnknownMethod as exc:
        raise UserError(str(exc)) from None
    except (ValueError, TypeError) as exc:
        raise UserError(str(exc)) from None

    if args.out is not None:
        writable_dir(args.out)  # before the runs, not after them
    seeds = list(range(seed0, seed0 + n_seeds))
    workers = resolve_workers(args.workers)
    label = (
        f"{args.method}{'/' + params['info'] if 'info' in params else ''} | size {problem.size} "
        f"({problem.n_drones} drones, {problem.n_tasks} tasks) | attrition {100 * args.attrition:g} %/step "
        f"| {args.reading} reading | {len(seeds)} seeds"
    )
    print(label, file=sys.stderr)
    t0 = time.perf_counter()
    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=len(seeds), unit="run", file=sys.stderr, leave=False)
    try:
        rows = run_many(
            problem, args.method, params, seeds, workers, progress=bar.update if bar else None
        )
    except KeyboardInterrupt:
        done = bar.n if bar else 0
        if bar:
            bar.close()
        print(
            f"interrupted after {done} of {len(seeds)} runs; nothing was written", file=sys.stderr
        )
        raise
    if bar:
        bar.close()
    wall = time.perf_counter() - t0
    tu1, tu1_ci = mean_ci95([100 * r["tu1"] for r in rows])
    tu2, tu2_ci = mean_ci95([100 * r["tu2"] for r in rows])
    per_run = sum(r["wall_s"] for r in rows) / len(rows)
    t1_txt, c1 = format_pct_ci(tu1, tu1_ci)
    t2_txt, c2 = format_pct_ci(tu2, tu2_ci)
    print(f"TU1 = {t1_txt} %")
    print(f"TU2 = {t2_txt} %")
    note = ci_note(len(rows), c1 or c2)
    if note:
        print(note, file=sys.stderr)
    print(
        f"{len(rows)} runs in {wall:.1f} s wall ({per_run:.3f} s per run per core, {workers} workers)"
    )

    if args.out is not None:
        out = args.out
        with open(out / "runs.csv", "w", newline="") as fh:
            w = csv.DictWriter(
                fh,
                fieldnames=[
                    "seed",
                    "method",
                    "tu1",
                    "tu2",
                    "wall_s",
                    "final_alive",
                    "final_active",
                ],
            )
            w.writeheader()
            for r in rows:
                w.writerow({k: r[k] for k in w.fieldnames})
        summary = {
            "method": args.method,
            "params": params,
            "problem": dataclasses.asdict(problem),
            "seeds": seeds,
            "tu1_pct": tu1,
            "tu1_ci95_pct": tu1_ci,
            "tu2_pct": tu2,
            "tu2_ci95_pct": tu2_ci,
            "wall_s": wall,
            "s_per_run": per_run,
        }
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
        from mission.view.plots import plot_frame_strip, plot_time_series

        title = (
            f"{args.method}, size {problem.size}, {100 * args.attrition:g} %/step attrition, "
            f"{len(seeds)} seeds: TU1 {t1_txt} %, TU2 {t2_txt} %"
        )
        plot_time_series(
            rows, problem.n_drones, problem.n_tasks, title, out / "fig2_timeseries.png"
        )
        frames = [
            0,
            problem.n_steps // 8,
            problem.n_steps // 3,
            problem.n_steps * 2 // 3,
            problem.n_steps,
        ]
        ep = run_episode(problem, args.method, params, seeds[0], record=True, frames=frames)
        plot_frame_strip(
            ep.record,
            frames,
            problem,
            f"{args.method}, size {problem.size}, {100 * args.attrition:g} %/step, seed {seeds[0]}: "
            f"TU1 {100 * ep.tu1:.1f} %, TU2 {100 * ep.tu2:.1f} %",
            out / "frames.png",
        )
        print(f"wrote {out}/runs.csv, summary.json, fig2_timeseries.png, frames.png")
    return 0


def _refuse_preset_flags(args) -> None:
    from mission.commands.options import UserError

    given = [
        (flag, why)
        for attr, (flag, why) in _PRESET_ONLY.items()
        if getattr(args, attr, None) not in (None, [])
    ]
    if not given:
        return
    flags = " and ".join(f for f, _ in given)
    reasons = "; ".join(f"{f}: {why}" for f, why in given)
    raise UserError(
        f"{flags} {'does' if len(given) == 1 else 'do'} not apply with --mission ({reasons}). "
        f"Edit a copy of the mission (phireman mission show {args.mission} > my.yaml; "
        f"phireman mission new --preset S --attrition 2% writes a paper configuration), "
        f"or drop --mission to simulate the paper's preset"
    )


def _run_mission(args) -> int:
    from mission.commands.options import UserError, endurance_line, writable_dir
    from mission.format.examples import example_path, list_examples
    from mission.format.load import MissionError, load_mission
    from mission.experiments.playback import run_inprocess, write_run_dir
    from mission.experiments.sim import format_pct_ci, mean_ci95

    _refuse_preset_flags(args)
    path = pathlib.Path(args.mission)
    if not path.exists():
        try:
            path = example_path(args.mission)
        except (KeyError, ValueError, FileNotFoundError):
            raise UserError(
                f"--mission {args.mission}: no such file or shipped example "
                f"({', '.join(list_examples())})"
            ) from None
    try:
        mission = load_mission(path)
    except MissionError as exc:
        raise UserError("invalid mission:\n  " + "\n  ".join(exc.errors)) from None
    if args.out is not None:
        writable_dir(args.out)  # before the runs, not after them
    if args.terrain_aware is not None and mission.radio.model != "terrain":
        raise UserError(
            f"--terrain-aware: mission {mission.name} has the disc radio (radio.model: disc); "
            "it applies to a terrain mission (radio.model: terrain, e.g. canyon)"
        )
    aware = args.terrain_aware or "on"
    n = 1 if args.seeds is None else args.seeds
    first = mission.run.seed if args.seed is None else args.seed
    seeds = [first + k for k in range(n)]
    print(mission.summary(), file=sys.stderr)
    results = []
    bar = None
    if n > 1 and not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=n, unit="run", file=sys.stderr, leave=False)
    try:
        for seed in seeds:
            try:
                r = run_inprocess(
                    mission,
                    seed,
                    battery=args.battery,
                    rotation=args.rotation,
                    terrain_aware=aware,
                )
            except ValueError as exc:
                raise UserError(str(exc)) from None
            results.append(r)
            n_lost = sum(ev["event"] == "vehicle_lost" for ev in r.losses)
            line = (
                f"seed {seed}: TU1 = {100 * r.tu1:.2f} %, TU2 = {100 * r.tu2:.2f} %, {n_lost} losses, "
                f"{r.wall_s:.2f} s"
            )
            if r.endurance is not None:
                line += f"; {endurance_line(r.endurance)}"
            if r.terrain is not None:
                g = r.terrain
                line += (
                    f"; terrain-aware {aware}: {g['crashes']} crashes into the ground, least "
                    f"clearance {g['min_clearance_m']:.1f} m, highest {g['max_agl_m']:.0f} m AGL, "
                    f"{g['drones_above_ceiling']} drones above the ceiling"
                )
            (bar.write(line) if bar else print(line))
            if bar:
                bar.update(1)
    finally:
        if bar:
            bar.close()
    if len(results) > 1:
        t1, c1 = format_pct_ci(*mean_ci95([100 * r.tu1 for r in results]))
        t2, c2 = format_pct_ci(*mean_ci95([100 * r.tu2 for r in results]))
        print(f"TU1 = {t1} %\nTU2 = {t2} %")
        note = ci_note(len(results), c1 or c2)
        if note:
            print(note, file=sys.stderr)
        ends = [r.endurance for r in results if r.endurance is not None]
        if ends:
            print(
                f"rotations {sum(e['rotations'] for e in ends) / len(ends):.1f} per run; "
                f"battery failsafes in the air {sum(e['battery_failsafes_in_air'] for e in ends)}, "
                f"at the critical level {sum(e['critical_in_air'] for e in ends)}, "
                f"landed away from the base {sum(e['landed_away'] for e in ends)} "
                f"(over {len(ends)} runs); min battery in the air "
                f"{100 * min(e['min_battery_in_air'] for e in ends):.0f} %"
            )
    if args.out is not None:
        write_run_dir(mission, results[0], args.out)  # an OSError: one line (mission.cli.main)
        print(
            f"wrote run directory {args.out} (seed {results[0].seed}); see it with: phireman replay {args.out}"
        )
    return 0

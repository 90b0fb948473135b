"""phireman sweep: run a grid of seeded simulations into a resumable SQLite results store."""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys

HELP = "run a grid of seeded simulations (e.g. the paper's Table II) into a resumable results store"
DESCRIPTION = """\
Run every (configuration, seed) of a grid with mission.sim and store one row per run in an SQLite
results store: the full resolved configuration, the seed, the code version, TU1/TU2, wall time and
status. Runs already in the store are skipped, so killing a sweep at any moment (Ctrl-C, kill -9,
a lost node) and rerunning the same command finishes it with nothing lost or duplicated. A run that
raises is stored as an error row and the sweep goes on (exit status 1 if the grid has error rows).

grids:
  paper-table      Table II: sizes XS S M L XL x attrition 0 0.5 1 2 5 %/step x phireman, dccrs,
                   mccst x 100 seeds = 7,500 runs (--sizes/--attrition/--methods select a subset)
  paper-ablations  at S / 1 %: default, Þ = 0 (phireman-no-task), nodes only, v = 0.1 and 0.2,
                   σ = 0 and 0.2 (paper units, times the preset's length unit) x 100 seeds
  custom           --sizes x --attrition x --methods x --seeds, with --set overrides

executors:
  local (default)  a process pool of --workers processes (chunks of seeds, largest configs first)
  dask             --scheduler tcp://host:port uses an existing cluster (every worker must have
                   this package installed); without --scheduler a LocalCluster of --workers
                   single-threaded processes. Runs are deterministic by seed: same rows either way.

examples:
  phireman sweep --grid paper-table --store results.sqlite
  phireman sweep --grid paper-ablations --store results.sqlite --workers 2
  phireman sweep --grid custom --sizes XS S --attrition 0 0.01 --methods phireman --seeds 10 \\
                 --set n_steps=50 --store quick.sqlite
  phireman sweep --grid paper-table --executor dask --scheduler tcp://10.0.0.5:8786 --store results.sqlite
  phireman report results.sqlite --out report/
"""

GRIDS = ("paper-table", "paper-ablations", "custom")


def add_common_arguments(p: argparse.ArgumentParser, seeds_default: int = 100,
                         store_default: str = "results.sqlite") -> None:
    """Options shared by sweep and tune: seeds, reading, overrides, executor, store."""
    from mission.sim import default_workers

    p.add_argument("--store", type=pathlib.Path, default=pathlib.Path(store_default),
                   help=f"SQLite results store (created if missing; default {store_default})")
    p.add_argument("--seeds", type=int, default=seeds_default, metavar="N",
                   help=f"seeded scenarios per configuration (default {seeds_default})")
    p.add_argument("--seed-start", type=int, default=0, metavar="S", help="first seed (default 0)")
    p.add_argument("--reading", choices=["scaled", "literal"], default="scaled",
                   help="length reading (default scaled, PAPER_NOTES §6.4)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a problem field (metres, e.g. n_steps=50) or a planner parameter "
                        "(e.g. step_size=0.3) in every configuration; repeatable")
    p.add_argument("--executor", choices=["local", "dask"], default="local",
                   help="local process pool (default) or dask")
    p.add_argument("--workers", type=int, default=default_workers(), metavar="N",
                   help=f"worker processes for the local pool or a Dask LocalCluster (default {default_workers()})")
    p.add_argument("--scheduler", default=None, metavar="ADDR",
                   help="existing Dask scheduler, e.g. tcp://host:8786 (implies --executor dask)")
    p.add_argument("--chunk", type=int, default=None, metavar="N",
                   help="seeds per worker task (default: about 8 s of work, 1-10 seeds)")
    p.add_argument("--retry-errors", action="store_true", help="run this grid's error rows again")
    p.add_argument("--rerun-other-code", action="store_true",
                   help="run again this grid's rows that were made by another code version")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--grid", choices=GRIDS, default="paper-table", help="which grid (default paper-table)")
    p.add_argument("--sizes", nargs="+", default=None, metavar="SIZE",
                   help="sizes (XS S M L XL; space- or comma-separated; default all)")
    p.add_argument("--attrition", nargs="+", default=None, metavar="P",
                   help="per-step attrition levels as fractions (0.01) or percents (1%%); default the paper's 5")
    p.add_argument("--methods", nargs="+", default=None, metavar="NAME",
                   help="planner names (default phireman dccrs mccst); see 'phireman sim --list-methods'")
    add_common_arguments(p)
    p.add_argument("--dry-run", action="store_true", help="print the plan (runs, present, to do) and exit")


def split_list(values: list[str] | None) -> list[str] | None:
    if values is None:
        return None
    return [v for item in values for v in item.replace(",", " ").split() if v]


def parse_attrition(values: list[str] | None) -> list[float] | None:
    from mission.cli import UserError

    items = split_list(values)
    if items is None:
        return None
    out = []
    for v in items:
        try:
            out.append(float(v[:-1]) / 100 if v.endswith("%") else float(v))
        except ValueError:
            raise UserError(f"--attrition: expected a fraction like 0.01 or a percent like 1%, got {v!r}") from None
        if not 0.0 <= out[-1] <= 1.0:
            raise UserError(f"--attrition: {v} is not a probability in [0, 1]")
    return out


def parse_value(text: str, field=None):
    """A --set / --grid value: typed by the ProblemConfig field when there is one, else JSON or str."""
    if field is not None:
        default = field.default
        if isinstance(default, bool):
            return text.lower() in ("1", "true", "yes", "on")
        if isinstance(default, int):
            return int(float(text))
        if isinstance(default, float):
            return float(text)
        return text
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def split_overrides(pairs: list[str], option: str = "--set") -> tuple[dict, dict]:
    """KEY=VALUE items -> (problem overrides, planner params)."""
    from mission.cli import UserError
    from planner.problem import ProblemConfig

    fields = {f.name: f for f in dataclasses.fields(ProblemConfig)}
    problem, params = {}, {}
    for item in pairs:
        if "=" not in item:
            raise UserError(f"{option} expects KEY=VALUE, got {item!r}")
        key, value = (s.strip() for s in item.split("=", 1))
        if key in ("size", "reading", "attrition_per_step"):
            raise UserError(f"{option} {key}: use --sizes / --reading / --attrition instead")
        try:
            if key in fields:
                problem[key] = parse_value(value, fields[key])
            else:
                params[key] = parse_value(value)
        except ValueError:
            raise UserError(f"{option} {key}: expected a number, got {value!r}") from None
    return problem, params


def validate_methods(methods: list[str] | None) -> None:
    from mission.cli import UserError
    from planner.methods import method_names

    for m in methods or []:
        if m not in method_names():
            raise UserError(f"unknown method {m!r}; valid methods: {', '.join(method_names())}")


def execute(grid, args, argv: list[str]) -> int:
    """Run ``grid`` with the common options; print a summary; return the exit status."""
    from mission.cli import UserError
    from mission.store import ResultStore, StoreError
    from mission.sweep import code_version, run_sweep

    if args.workers < 1:
        raise UserError("--workers must be >= 1")
    if args.chunk is not None and args.chunk < 1:
        raise UserError("--chunk must be >= 1")
    try:
        store = ResultStore(args.store)
    except StoreError as exc:
        raise UserError(str(exc)) from None
    with store:
        print(f"{grid.name}: {len(grid.configs)} configurations x {len(grid.seeds)} seeds = "
              f"{grid.n_runs} runs -> {args.store} ({code_version()})", file=sys.stderr)
        try:
            summary = run_sweep(grid, store, executor=args.executor, workers=args.workers,
                                scheduler=args.scheduler, chunk=args.chunk, progress=not args.no_progress,
                                retry_errors=args.retry_errors, rerun_other_code=args.rerun_other_code,
                                argv=argv)
        except ValueError as exc:
            raise UserError(str(exc)) from None
        for where, msg in summary.resolve_errors.items():
            print(f"warning: {where}: {msg} (its runs are stored as errors)", file=sys.stderr)
        if summary.other_code:
            versions = "; ".join(f"{n} rows by {v}" for v, n in summary.other_code.items())
            print(f"warning: runs already present were made by other code ({versions}); they were kept. "
                  f"Use a new store or --rerun-other-code to redo them.", file=sys.stderr)
        errors_in_grid = len(summary.keys & store.keys("error"))
    print(f"{summary.present} present, {summary.completed} completed now ({summary.errors} errors), "
          f"{summary.remaining} remaining, in {summary.wall_s:.1f} s wall")
    if summary.lost:
        print(f"{summary.lost} runs lost to executor failures; rerun the same command to retry them",
              file=sys.stderr)
    if summary.interrupted:
        print("interrupted: every completed run is stored; rerun the same command to finish", file=sys.stderr)
        return 130
    if errors_in_grid:
        print(f"{errors_in_grid} runs of this grid are error rows (see 'phireman report'; "
              f"--retry-errors runs them again)", file=sys.stderr)
        return 1
    return 0


def build_grid(args):
    from mission.cli import UserError
    from mission.sweep import custom_grid, paper_ablations_grid, paper_table_grid
    from planner.problem import SIZES

    sizes = split_list(args.sizes)
    if sizes is not None:
        sizes = [s.upper() for s in sizes]
        bad = [s for s in sizes if s not in SIZES]
        if bad:
            raise UserError(f"unknown size(s) {', '.join(bad)}; valid sizes: {', '.join(SIZES)}")
    attrition = parse_attrition(args.attrition)
    methods = split_list(args.methods)
    validate_methods(methods)
    if args.seeds < 1:
        raise UserError("--seeds must be >= 1")
    seeds = range(args.seed_start, args.seed_start + args.seeds)
    problem, params = split_overrides(args.set)
    if args.grid == "paper-table":
        grid = paper_table_grid(seeds, sizes, attrition, methods, args.reading, params, problem)
    elif args.grid == "paper-ablations":
        if sizes or attrition or methods:
            raise UserError("paper-ablations is fixed at S / 1 % with its own variants; "
                            "--sizes/--attrition/--methods do not apply (use --grid custom)")
        grid = paper_ablations_grid(seeds, args.reading, params=params, problem_overrides=problem)
    else:
        if not (sizes and attrition is not None and methods):
            raise UserError("--grid custom needs --sizes, --attrition and --methods")
        grid = custom_grid(sizes, attrition, methods, seeds, args.reading, params, problem)
    try:
        for spec in grid.configs:
            spec.problem()
    except ValueError as exc:
        raise UserError(str(exc)) from None
    return grid


def run(args) -> int:
    grid = build_grid(args)
    if args.dry_run:
        return _dry_run(grid, args)
    return execute(grid, args, ["phireman", *sys.argv[1:]])


def _dry_run(grid, args) -> int:
    from mission.store import ResultStore
    from mission.sweep import estimate_run_s, resolve

    present = set()
    if args.store.exists():
        with ResultStore(args.store, readonly=True) as store:
            present = store.keys()
    todo_s = 0.0
    todo = 0
    for spec in grid.configs:
        rc = resolve(spec)
        missing = sum(rc.run_key(s) not in present for s in grid.seeds)
        todo += missing
        todo_s += missing * estimate_run_s(rc.problem)
        note = f"  [{rc.resolve_error}]" if rc.resolve_error else ""
        print(f"{spec.size:>2} {100 * spec.attrition:4g} % {spec.method:<20} {spec.label:<12} "
              f"{missing:4d}/{len(grid.seeds)} to run{note}")
    print(f"{grid.n_runs} runs, {grid.n_runs - todo} present, {todo} to run "
          f"(rough estimate {todo_s / 60 / max(args.workers, 1):.0f} min on {args.workers} workers)")
    return 0

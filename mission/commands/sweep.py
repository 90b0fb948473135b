"""phireman sweep: run a grid of seeded simulations into a resumable SQLite results store."""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys

HELP = "run a grid of seeded simulations (e.g. the paper's Table II) into a resumable results store"
DESCRIPTION = """\
Run every (configuration, seed) of a grid with mission.experiments.sim and store one row per run in an SQLite
results store: the full resolved configuration, the seed, the code version, TU1/TU2, wall time and
status. Runs already in the store are skipped, so killing a sweep at any moment (Ctrl-C, kill -9,
a lost node) and rerunning the same command finishes it with nothing lost or duplicated. A run that
raises is stored as an error row and the sweep goes on (exit status 1 if the grid has error rows,
or if runs were lost to the executor: rerun the same command to finish).

grids:
  paper-table      Table II: sizes XS S M L XL x attrition 0 0.5 1 2 5 %/step x phireman, dccrs,
                   mccst x 100 seeds = 7,500 runs (--size/--attrition/--method select a subset)
  paper-ablations  at S / 1 %: default, Þ = 0 (phireman-no-task), nodes only, v = 0.1 and 0.2,
                   σ = 0 and 0.2 (paper units, times the preset's length unit) x 100 seeds
  custom           --size x --attrition x --method x --seeds, with --set overrides

executors:
  local (default)  a process pool of --workers processes (chunks of seeds, largest configs first)
  dask             --scheduler tcp://host:port (or the file 'dask scheduler --scheduler-file'
                   writes) uses an existing cluster (every worker must have this package
                   installed); without --scheduler a LocalCluster of --workers single-threaded
                   processes. Runs are deterministic by seed: same rows either way.

on a Dask cluster (this package, same version, on every machine: pip install -e '.[dask]'):
  dask scheduler --port 8786                            # on one machine (HEAD)
  dask worker tcp://HEAD:8786 --nthreads 1 --nworkers N  # on each machine, N = its cores
  phireman sweep --grid paper-table --scheduler tcp://HEAD:8786 --store results.sqlite
  A worker lost mid-sweep (killed, its machine gone) loses nothing: the scheduler runs its tasks
  again on the other workers and the command finishes with every row. If the scheduler goes (or
  one task kills 3 workers), the runs in flight are reported lost and the command exits 1; rerun
  it to finish. With no worker left the sweep waits for one to join.
  On one machine, on loopback with ports the system chooses (what
  tests/mission/test_sweep_dask_cluster.py runs; the scheduler writes its address to sched.json):
  dask scheduler --host 127.0.0.1 --port 0 --dashboard-address 127.0.0.1:0 --scheduler-file sched.json
  dask worker --scheduler-file sched.json --nthreads 1    # twice: two worker processes
  phireman sweep --grid custom --size XS --attrition 0 1% --method phireman dccrs --seeds 3 --chunk 1 --scheduler sched.json --store cluster.sqlite

examples:
  phireman sweep --grid paper-table --store results.sqlite
  phireman sweep --grid paper-ablations --store results.sqlite --workers 2
  phireman sweep --grid custom --size XS S --attrition 0 1% --method phireman --seeds 10 \\
                 --set n_steps=50 --store quick.sqlite
  phireman sweep --grid paper-table --executor dask --scheduler tcp://10.0.0.5:8786 --store results.sqlite
  phireman sweep --grid paper-table --dry-run      # runs to do and a time estimate
  phireman report results.sqlite --out report/

--size/--method take one or more values (--sizes/--methods are accepted as aliases); --seed S
--seeds N runs seeds S..S+N-1 (--seed-start is an alias of --seed).
"""

GRIDS = ("paper-table", "paper-ablations", "custom")


def add_common_arguments(
    p: argparse.ArgumentParser, seeds_default: int = 100, store_default: str = "results.sqlite"
) -> None:
    """Options shared by sweep and tune: seeds, reading, overrides, executor, store."""
    from mission.commands.options import add_seed_arguments, add_workers_argument

    p.add_argument(
        "--store",
        type=pathlib.Path,
        default=pathlib.Path(store_default),
        help=f"SQLite results store file (created if missing; default {store_default})",
    )
    add_seed_arguments(
        p, seeds_default, f"seeded scenarios per configuration (default {seeds_default})"
    )
    p.add_argument(
        "--reading",
        choices=["scaled", "literal"],
        default="scaled",
        help="length reading (default scaled, docs/design/model.md §6.4)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a problem field (metres, e.g. n_steps=50) or a planner parameter "
        "(e.g. step_size=0.3) in every configuration; repeatable",
    )
    p.add_argument(
        "--executor",
        choices=["local", "dask"],
        default="local",
        help="local process pool (default) or dask",
    )
    add_workers_argument(p, "worker processes for the local pool or a Dask LocalCluster")
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDR",
        help="existing Dask scheduler: its address, e.g. tcp://host:8786, or the file written by "
        "'dask scheduler --scheduler-file FILE' (implies --executor dask)",
    )
    p.add_argument(
        "--chunk",
        type=int,
        default=None,
        metavar="N",
        help="seeds per worker task (default: about 8 s of work, 1-10 seeds)",
    )
    p.add_argument("--retry-errors", action="store_true", help="run this grid's error rows again")
    p.add_argument(
        "--rerun-other-code",
        action="store_true",
        help="run again this grid's rows that were made by another code version",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--grid", choices=GRIDS, default="paper-table", help="which grid (default paper-table)"
    )
    p.add_argument(
        "--size",
        "--sizes",
        dest="sizes",
        nargs="+",
        default=None,
        metavar="SIZE",
        help="sizes (XS S M L XL; space- or comma-separated; default all; alias --sizes)",
    )
    p.add_argument(
        "--attrition",
        nargs="+",
        default=None,
        metavar="P",
        help="per-step attrition levels as fractions (0.01) or percents (1%%); default the paper's 5",
    )
    p.add_argument(
        "--method",
        "--methods",
        dest="methods",
        nargs="+",
        default=None,
        metavar="NAME",
        help="planner names (default phireman dccrs mccst; alias --methods); "
        "see 'phireman sim --list-methods'",
    )
    add_common_arguments(p)
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="print the plan (runs, present, to do, time estimate) and exit",
    )


def split_list(values: list[str] | None) -> list[str] | None:
    if values is None:
        return None
    return [v for item in values for v in item.replace(",", " ").split() if v]


def parse_attrition(values: list[str] | None) -> list[float] | None:
    from mission.commands.options import parse_rate

    items = split_list(values)
    if items is None:
        return None
    return [parse_rate(v) for v in items]


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
    from mission.commands.options import UserError
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


def validate_methods(methods: list[str] | None, option: str = "--method") -> None:
    from mission.commands.options import UserError, did_you_mean
    from planner.methods import method_names

    for m in methods or []:
        if m not in method_names():
            raise UserError(
                f"{option}: unknown planner {m!r}{did_you_mean(m, method_names())}; "
                f"valid methods: {', '.join(method_names())}"
            )


def planner_parameter_names(method: str, problem) -> list[str] | None:
    """The parameter names ``method`` accepts (its params dataclass / dict), or None if unknown."""
    from planner.methods import make_planner

    prm = getattr(make_planner(method, problem, {}), "params", None)
    if dataclasses.is_dataclass(prm):
        return [f.name for f in dataclasses.fields(prm)]
    if isinstance(prm, dict):
        return list(prm)
    return None


def check_overrides(methods, problem, params: dict, option: str = "--set") -> None:
    """Refuse, before anything runs, a planner parameter that one of ``methods`` does not take.

    A misspelt key would otherwise fail every run (stored as error rows) or be silently ignored.
    """
    from mission.commands.options import UserError, did_you_mean
    from planner.problem import ProblemConfig

    problem_fields = [f.name for f in dataclasses.fields(ProblemConfig)]
    methods = list(dict.fromkeys(methods))
    names = {m: planner_parameter_names(m, problem) for m in methods}
    for method in methods:
        taken = names[method]
        if taken is None:
            continue
        for key in params:
            if key in taken:
                continue
            hint = did_you_mean(key, taken + problem_fields)
            takers = [m for m in methods if m != method and key in (names[m] or [])]
            where = (
                f"; only {', '.join(takers)} take(s) it, so run {method} separately"
                if takers
                else ""
            )
            raise UserError(
                f"{option} {key}: not a parameter of {method} nor a problem field{hint}{where}. "
                f"{method} takes: {', '.join(taken)}"
            )


def execute(grid, args, argv: list[str]) -> int:
    """Run ``grid`` with the common options; print a summary; return the exit status."""
    from mission.commands.options import UserError
    from mission.experiments.store import ResultStore, StoreError
    from mission.experiments.sweep import code_version, run_sweep

    from mission.commands.options import resolve_workers, writable_file

    args.workers = resolve_workers(args.workers)
    if args.chunk is not None and args.chunk < 1:
        raise UserError("--chunk must be >= 1")
    writable_file(args.store, "--store", "results.sqlite")  # before any run
    try:
        store = ResultStore(args.store)
    except StoreError as exc:
        raise UserError(str(exc)) from None
    with store:
        print(
            f"{grid.name}: {len(grid.configs)} configurations x {len(grid.seeds)} seeds = "
            f"{grid.n_runs} runs -> {args.store} ({code_version()})",
            file=sys.stderr,
        )
        try:
            summary = run_sweep(
                grid,
                store,
                executor=args.executor,
                workers=args.workers,
                scheduler=scheduler_address(args.scheduler),
                chunk=args.chunk,
                progress=not args.no_progress,
                retry_errors=args.retry_errors,
                rerun_other_code=args.rerun_other_code,
                argv=argv,
            )
        except ValueError as exc:
            raise UserError(str(exc)) from None
        for where, msg in summary.resolve_errors.items():
            print(f"warning: {where}: {msg} (its runs are stored as errors)", file=sys.stderr)
        if summary.other_code:
            versions = "; ".join(f"{n} rows by {v}" for v, n in summary.other_code.items())
            print(
                f"warning: runs already present were made by other code ({versions}); they were kept. "
                f"Use a new store or --rerun-other-code to redo them.",
                file=sys.stderr,
            )
        errors_in_grid = len(summary.keys & store.keys("error"))
    print(
        f"{summary.present} present, {summary.completed} completed now ({summary.errors} errors), "
        f"{summary.remaining} remaining, in {summary.wall_s:.1f} s wall"
    )
    if summary.lost:
        print(
            f"{summary.lost} runs lost to executor failures; rerun the same command to retry them",
            file=sys.stderr,
        )
    if summary.interrupted:
        print(
            "interrupted: every completed run is stored; rerun the same command to finish",
            file=sys.stderr,
        )
        return 130
    if errors_in_grid:
        print(
            f"{errors_in_grid} runs of this grid are error rows (see 'phireman report'; "
            f"--retry-errors runs them again)",
            file=sys.stderr,
        )
        return 1
    # Lost runs (a scheduler gone, a task that killed its workers) leave the grid incomplete: a
    # script chaining 'sweep && report' must not go on as if it were done.
    return 1 if summary.lost else 0


def scheduler_address(value: str | None) -> str | None:
    """--scheduler: a Dask scheduler address as given, or the address in a scheduler file.

    ``dask scheduler --scheduler-file FILE`` writes its address (with the port it chose for
    ``--port 0``) to FILE as JSON; anything with ``://`` or that is not a file is an address.
    """
    from mission.commands.options import UserError

    if value is None or "://" in value:
        return value
    path = pathlib.Path(value)
    if not (path.is_file() or path.suffix == ".json"):
        return value  # host:port
    try:
        address = json.loads(path.read_text())["address"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UserError(
            f"--scheduler {value}: not a readable Dask scheduler file "
            f"({type(exc).__name__}: {exc}); give tcp://host:port or the file of "
            f"'dask scheduler --scheduler-file'"
        ) from None
    return str(address)


def build_grid(args):
    from mission.commands.options import UserError
    from mission.experiments.sweep import custom_grid, paper_ablations_grid, paper_table_grid
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
    seed0 = args.seed or 0
    seeds = range(seed0, seed0 + args.seeds)
    problem, params = split_overrides(args.set)
    if args.grid == "paper-table":
        grid = paper_table_grid(seeds, sizes, attrition, methods, args.reading, params, problem)
    elif args.grid == "paper-ablations":
        if sizes or attrition or methods:
            raise UserError(
                "paper-ablations is fixed at S / 1 % with its own variants; "
                "--size/--attrition/--method do not apply (use --grid custom)"
            )
        grid = paper_ablations_grid(seeds, args.reading, params=params, problem_overrides=problem)
    else:
        if not (sizes and attrition is not None and methods):
            raise UserError("--grid custom needs --size, --attrition and --method")
        grid = custom_grid(sizes, attrition, methods, seeds, args.reading, params, problem)
    check_grid(grid)
    return grid


def check_grid(grid, option: str = "--set") -> None:
    """Every configuration's problem builds and every planner takes its parameters: refuse up front."""
    from mission.commands.options import UserError

    try:
        problems = [spec.problem() for spec in grid.configs]
    except (ValueError, TypeError) as exc:
        raise UserError(str(exc)) from None
    methods = [spec.method for spec in grid.configs]
    seen = set()
    for spec, problem in zip(grid.configs, problems):
        key = (spec.method, tuple(sorted(spec.params)))
        if key not in seen:
            seen.add(key)
            check_overrides([spec.method] + methods, problem, spec.params, option)


def run(args) -> int:
    grid = build_grid(args)
    if args.dry_run:
        return _dry_run(grid, args)
    return execute(grid, args, ["phireman", *sys.argv[1:]])


def _fmt_duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _dry_run(grid, args) -> int:
    from mission.commands.options import UserError, resolve_workers
    from mission.experiments.store import ResultStore, StoreError
    from mission.experiments.sweep import estimate_run_s, measured_costs, resolve

    workers = resolve_workers(args.workers)
    present = set()
    measured = {}
    if args.store.exists():
        try:
            with ResultStore(args.store, readonly=True) as store:
                present = store.keys()
                measured = measured_costs(store.runs())
        except StoreError as exc:
            raise UserError(str(exc)) from None
    todo_s = 0.0
    todo = 0
    from_store = 0
    for spec in grid.configs:
        rc = resolve(spec)
        missing = sum(rc.run_key(s) not in present for s in grid.seeds)
        todo += missing
        todo_s += missing * estimate_run_s(rc.problem, spec.method, measured)
        from_store += missing * ((spec.size.upper(), spec.method) in measured)
        note = f"  [{rc.resolve_error}]" if rc.resolve_error else ""
        print(
            f"{spec.size:>2} {100 * spec.attrition:4g} % {spec.method:<20} {spec.label:<12} "
            f"{missing:4d}/{len(grid.seeds)} to run{note}"
        )
    basis = (
        "this store's recorded run times"
        if from_store == todo and todo
        else "run times measured on a 2-core machine (mission.experiments.sweep.MEASURED_RUN_S)"
        if not from_store
        else "this store's run times where it has the size and method, else times measured on a 2-core machine"
    )
    print(
        f"{grid.n_runs} runs, {grid.n_runs - todo} present, {todo} to run: about "
        f"{_fmt_duration(todo_s / workers)} on {workers} workers (from {basis}; "
        f"slower if the cores are shared)"
    )
    return 0

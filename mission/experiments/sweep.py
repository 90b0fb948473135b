"""Sweeps: grids of (size, attrition, method, parameters) × seeds, run on a process pool or Dask.

A :class:`Grid` is a list of :class:`ConfigSpec` (one problem configuration and method each) and a
list of seeds. :func:`run_sweep` resolves every configuration (the planner's full parameter set,
defaults included), hashes it with each seed into a run key, skips the keys the store already holds,
and runs the rest in chunks of seeds on an executor:

* ``local``: a process pool on this machine (in-process when ``workers == 1``);
* ``dask``: an existing ``dask.distributed`` cluster (``scheduler='tcp://host:port'``), or a
  ``LocalCluster`` of ``workers`` single-threaded processes.

Workers only compute: each returns its rows and the parent writes them to the store, one
transaction per chunk, so a sweep killed at any moment loses only the runs in flight and rerunning
the same command completes it with nothing lost or duplicated. A run that raises is recorded as an
``error`` row (exception type and message) and the sweep goes on. Every run is deterministic given
its seed (``mission.experiments.sim.run_episode``), so the executor and the number of workers do not change the
results.

Local pool workers are started with the ``forkserver`` method (they must not inherit the parent's
SQLite handle or threads), so a script calling :func:`run_sweep` with ``workers > 1`` needs the
usual ``if __name__ == "__main__":`` guard; the ``phireman`` command has it.

Length (over the ~600 lines this code base aims for): the grids, the run key, the two executors and cancellation stay in one
module because they share one contract (a run key is the hash of the resolved configuration and
seed; a chunk's rows land in one transaction; a cancelled chunk leaves no row). Splitting them
would spread that contract over files that must change together.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import signal
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any
from collections.abc import Callable, Iterable, Iterator

from mission.experiments.store import ResultStore, utc_now
from mission.format.version import (
    code_version,
)  # re-exported: one code version for rows and run dirs

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

__all__ = [
    "ConfigSpec",
    "Grid",
    "ResolvedConfig",
    "Chunk",
    "SweepSummary",
    "paper_table_grid",
    "paper_ablations_grid",
    "custom_grid",
    "product_grid",
    "ABLATION_VARIANTS",
    "resolve",
    "plan_chunks",
    "run_chunk",
    "run_sweep",
    "code_version",
    "canonical_json",
    "estimate_run_s",
    "measured_costs",
    "MEASURED_RUN_S",
    "LocalExecutor",
    "DaskExecutor",
    "EXECUTORS",
]

log = logging.getLogger(__name__)

EXECUTORS = ("local", "dask")


# ----------------------------------------------------------------------------------------------
# Configurations and grids
# ----------------------------------------------------------------------------------------------


def _json_default(obj: Any) -> Any:
    try:
        import numpy as np
    except ImportError:  # pragma: no cover
        np = None  # type: ignore[assignment]
    if np is not None and isinstance(obj, np.generic):
        return obj.item()
    if np is not None and isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    return str(obj)


def canonical_json(obj: Any) -> str:
    """Deterministic JSON (sorted keys, no spaces): the input of every hash in the store."""
    return json.dumps(
        obj, sort_keys=True, separators=(",", ":"), default=_json_default, ensure_ascii=False
    )


def _hash(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:32]


@dataclass
class ConfigSpec:
    """One configuration as asked for: a preset problem, overrides, a method and its parameters.

    ``problem_overrides`` are :class:`planner.problem.ProblemConfig` fields in SI units (metres),
    applied after the reading's scaling; ``params`` are planner parameters (unknown keys make the
    runs fail, and are recorded as error rows).
    """

    size: str
    attrition: float
    method: str
    reading: str = "scaled"
    params: dict = field(default_factory=dict)
    problem_overrides: dict = field(default_factory=dict)
    label: str = ""

    def spec_dict(self) -> dict:
        """What identifies the request (the label and the grid name do not)."""
        return {
            "size": self.size.upper(),
            "attrition": float(self.attrition),
            "reading": self.reading,
            "method": self.method,
            "params": dict(self.params),
            "problem_overrides": dict(self.problem_overrides),
        }

    @property
    def spec_key(self) -> str:
        return _hash(canonical_json(self.spec_dict()))

    def problem(self):
        """The resolved :class:`ProblemConfig` (raises ValueError for a bad size or override)."""
        from planner.problem import problem_preset

        return problem_preset(
            self.size, float(self.attrition), self.reading, **self.problem_overrides
        )


@dataclass
class Grid:
    """A named list of configurations, each run for every seed."""

    name: str
    configs: list[ConfigSpec]
    seeds: list[int]

    @property
    def n_runs(self) -> int:
        return len(self.configs) * len(self.seeds)


def _norm_attrition(levels: Iterable[float] | None) -> list[float]:
    from planner.problem import ATTRITION_LEVELS

    return [float(p) for p in (ATTRITION_LEVELS if levels is None else levels)]


def paper_table_grid(
    seeds: Iterable[int] = range(100),
    sizes: Iterable[str] | None = None,
    attrition: Iterable[float] | None = None,
    methods: Iterable[str] | None = None,
    reading: str = "scaled",
    params: dict | None = None,
    problem_overrides: dict | None = None,
) -> Grid:
    """Table II: 5 sizes × 5 attrition levels × (phireman, dccrs, mccst) × seeds (7,500 runs at 100).

    ``sizes``, ``attrition`` and ``methods`` select a subset; ``params`` / ``problem_overrides``
    apply to every configuration (normally empty).
    """
    from mission.experiments.paper import PAPER_METHODS
    from planner.problem import SIZES

    sizes = [s.upper() for s in (SIZES if sizes is None else sizes)]
    methods = list(PAPER_METHODS if methods is None else methods)
    configs = [
        ConfigSpec(size, p, method, reading, dict(params or {}), dict(problem_overrides or {}))
        for size in sizes
        for p in _norm_attrition(attrition)
        for method in methods
    ]
    return Grid("paper-table", configs, list(seeds))


#: The paper's ablations at S / 1 %: (label, method, paper-unit problem overrides).
#: Speeds and task sigma are in paper length units and are multiplied by the preset's
#: ``length_unit_m`` (1 at S in both readings).
ABLATION_VARIANTS: tuple[tuple[str, str, dict], ...] = (
    ("default", "phireman", {}),
    ("Þ = 0", "phireman-no-task", {}),
    ("nodes only", "phireman-nodes-only", {}),
    ("v = 0.1", "phireman", {"max_speed_m_s": 0.1}),
    ("v = 0.2", "phireman", {"max_speed_m_s": 0.2}),
    ("σ = 0", "phireman", {"task_walk_sigma_m": 0.0}),
    ("σ = 0.2", "phireman", {"task_walk_sigma_m": 0.2}),
)


def paper_ablations_grid(
    seeds: Iterable[int] = range(100),
    reading: str = "scaled",
    size: str = "S",
    attrition: float = 0.01,
    params: dict | None = None,
    problem_overrides: dict | None = None,
) -> Grid:
    """The ablation table: default, Þ = 0, nodes only, v = 0.1 / 0.2, σ = 0 / 0.2 at S / 1 %."""
    from planner.problem import problem_preset

    unit_m = problem_preset(size, attrition, reading).length_unit_m
    configs = []
    for label, method, paper_units in ABLATION_VARIANTS:
        over = dict(problem_overrides or {})
        over.update({k: v * unit_m for k, v in paper_units.items()})
        configs.append(
            ConfigSpec(size, float(attrition), method, reading, dict(params or {}), over, label)
        )
    return Grid("paper-ablations", configs, list(seeds))


def custom_grid(
    sizes: Iterable[str],
    attrition: Iterable[float],
    methods: Iterable[str],
    seeds: Iterable[int],
    reading: str = "scaled",
    params: dict | None = None,
    problem_overrides: dict | None = None,
    name: str = "custom",
) -> Grid:
    """Any product of sizes × attrition levels × methods, with common overrides."""
    configs = [
        ConfigSpec(
            size.upper(), p, method, reading, dict(params or {}), dict(problem_overrides or {})
        )
        for size in sizes
        for p in _norm_attrition(attrition)
        for method in methods
    ]
    return Grid(name, configs, list(seeds))


def product_grid(
    method: str,
    axes: dict[str, list],
    seeds: Iterable[int],
    size: str = "S",
    attrition: float = 0.01,
    reading: str = "scaled",
    params: dict | None = None,
    problem_overrides: dict | None = None,
    include_defaults: bool = True,
    name: str = "tune",
) -> Grid:
    """A hyper-parameter grid: every combination of ``axes`` (key -> values) for one method.

    Keys that are :class:`ProblemConfig` fields become problem overrides, the others planner
    parameters. With ``include_defaults`` the unmodified configuration is added (label
    ``(defaults)``) so a search shows what it gains over the current defaults.
    """
    import itertools

    from planner.problem import ProblemConfig

    problem_fields = {f.name for f in dataclasses.fields(ProblemConfig)}
    keys = list(axes)
    configs = []
    if include_defaults:
        configs.append(
            ConfigSpec(
                size.upper(),
                float(attrition),
                method,
                reading,
                dict(params or {}),
                dict(problem_overrides or {}),
                "(defaults)",
            )
        )
    for values in itertools.product(*(axes[k] for k in keys)):
        prm, over = dict(params or {}), dict(problem_overrides or {})
        for k, v in zip(keys, values):
            (over if k in problem_fields else prm)[k] = v
        label = ", ".join(f"{k}={v}" for k, v in zip(keys, values))
        spec = ConfigSpec(size.upper(), float(attrition), method, reading, prm, over, label)
        if include_defaults and spec.spec_key == configs[0].spec_key:
            continue
        configs.append(spec)
    return Grid(name, configs, list(seeds))


# ----------------------------------------------------------------------------------------------
# Resolution and keys
# ----------------------------------------------------------------------------------------------


@dataclass
class ResolvedConfig:
    """A configuration with its full resolved content, as hashed and stored."""

    spec: ConfigSpec
    problem: Any
    """The :class:`ProblemConfig`."""
    config: dict
    """{problem: asdict(problem), method, params: resolved parameters, params_resolved: bool}"""
    config_key: str
    resolve_error: str | None = None
    """Why the parameters could not be resolved (the runs will fail the same way and be recorded)."""

    def run_key(self, seed: int) -> str:
        return _hash(f"{canonical_json(self.config)}|seed={int(seed)}")


def resolve(spec: ConfigSpec) -> ResolvedConfig:
    """Resolve a spec: build its problem and planner once to read every parameter, defaults included.

    Raises
    ------
    ValueError
        The problem itself is invalid (unknown size or reading, bad override): a grid mistake.
    """
    from planner.methods import make_planner

    problem = spec.problem()
    params: dict = dict(spec.params)
    error = None
    try:
        planner = make_planner(spec.method, problem, spec.params)
        prm = getattr(planner, "params", None)
        if dataclasses.is_dataclass(prm) and not isinstance(prm, type):
            params = json.loads(canonical_json(dataclasses.asdict(prm)))
        elif isinstance(prm, dict):
            params = json.loads(canonical_json(prm))
    except (
        Exception
    ) as exc:  # recorded: every run of this config will fail and be stored as an error
        error = f"{type(exc).__name__}: {exc}"
    config = {
        "problem": dataclasses.asdict(problem),
        "method": spec.method,
        "params": params,
        "params_resolved": error is None,
    }
    config = json.loads(canonical_json(config))
    return ResolvedConfig(spec, problem, config, _hash(canonical_json(config)), error)


# ----------------------------------------------------------------------------------------------
# Chunks and the worker function
# ----------------------------------------------------------------------------------------------


@dataclass
class Chunk:
    """Seeds of one configuration, run one after another in one worker task."""

    id: int
    problem: Any
    method: str
    params: dict
    seeds: list[int]
    keys: list[str]
    cost_s: float
    """Rough estimate of the chunk's run time on one core, seconds (for ordering and the ETA)."""


#: Measured wall seconds per run in a pool worker (2 workers on a 2-core machine) for ΦIREMAN
#: (async), 200 steps, scaled reading: mean over 100 seeds of a fresh paper-table sweep at main
#: ``855fc95`` (its store's ``wall_s``; the whole table took 13.7 min, docs/results/benchmarks.md,
#: seventh pass). (size, attrition per step) -> seconds.
MEASURED_RUN_S: dict[tuple[str, float], float] = {
    ("XS", 0.0): 0.068,
    ("XS", 0.005): 0.067,
    ("XS", 0.01): 0.06,
    ("XS", 0.02): 0.055,
    ("XS", 0.05): 0.039,
    ("S", 0.0): 0.085,
    ("S", 0.005): 0.084,
    ("S", 0.01): 0.071,
    ("S", 0.02): 0.072,
    ("S", 0.05): 0.045,
    ("M", 0.0): 0.122,
    ("M", 0.005): 0.099,
    ("M", 0.01): 0.089,
    ("M", 0.02): 0.082,
    ("M", 0.05): 0.056,
    ("L", 0.0): 0.255,
    ("L", 0.005): 0.181,
    ("L", 0.01): 0.149,
    ("L", 0.02): 0.122,
    ("L", 0.05): 0.079,
    ("XL", 0.0): 0.982,
    ("XL", 0.005): 0.681,
    ("XL", 0.01): 0.493,
    ("XL", 0.02): 0.357,
    ("XL", 0.05): 0.204,
}
#: Cost of a method relative to ΦIREMAN (async), same store (the ablations' variants at S / 1 %;
#: phireman-central from the earlier store of docs/results/paper_table), all sizes together.
METHOD_COST_FACTOR: dict[str, float] = {
    "phireman": 1.0,
    "dccrs": 0.92,
    "mccst": 1.63,
    "phireman-central": 0.8,
    "phireman-no-task": 1.01,
    "phireman-nodes-only": 0.97,
}


def estimate_run_s(problem, method: str = "phireman", measured: dict | None = None) -> float:
    """Expected wall seconds of one run in one worker.

    From ``measured`` ((size, method) -> recorded mean seconds at 200 steps, e.g. the store's own
    rows, see :func:`measured_costs`) when it has this size and method, else from the table
    measured on this project's 2-core machine (``MEASURED_RUN_S``, interpolated in attrition,
    times ``METHOD_COST_FACTOR``). Scaled by ``n_steps / 200``; other sizes (custom drone counts)
    follow the O(n²) pair terms from the nearest preset.
    """
    steps = problem.n_steps / 200.0
    size = str(getattr(problem, "size", "")).upper()
    if measured and (size, method) in measured:
        return steps * measured[(size, method)]
    import numpy as np

    from planner.problem import problem_preset

    sizes = sorted({s for s, _ in MEASURED_RUN_S}, key=lambda s: problem_preset(s, 0.0).n_drones)
    by_n = {s: problem_preset(s, 0.0).n_drones for s in sizes}
    nearest = min(sizes, key=lambda s: abs(by_n[s] - problem.n_drones))
    levels = sorted(p for s, p in MEASURED_RUN_S if s == nearest)
    base = float(
        np.interp(
            problem.attrition_per_step, levels, [MEASURED_RUN_S[(nearest, p)] for p in levels]
        )
    )
    scale = (problem.n_drones / by_n[nearest]) ** 2 if problem.n_drones > by_n[nearest] else 1.0
    return steps * base * scale * METHOD_COST_FACTOR.get(method, 1.0)


def measured_costs(rows) -> dict[tuple[str, str], float]:
    """(size, method) -> mean wall seconds per ok run, normalised to 200 steps, from store rows."""
    sums: dict[tuple[str, str], list[float]] = {}
    for r in rows:
        if r.get("status") != "ok" or not r.get("wall_s"):
            continue
        try:
            n_steps = json.loads(r["config_json"])["problem"]["n_steps"]
        except (KeyError, TypeError, ValueError):
            continue
        sums.setdefault((r["size"], r["method"]), []).append(r["wall_s"] * 200.0 / max(n_steps, 1))
    return {k: sum(v) / len(v) for k, v in sums.items() if len(v) >= 3}


def plan_chunks(
    todo: list[tuple[ResolvedConfig, list[int]]], chunk: int | None = None, target_s: float = 8.0
) -> list[Chunk]:
    """Split the pending seeds of each configuration into chunks, most expensive chunks first.

    With ``chunk=None`` the size is chosen so a chunk takes about ``target_s`` (1 to 10 seeds):
    long enough to amortise the task overhead, short enough that a kill loses little and that the
    cheap chunks at the end balance the load.
    """
    chunks: list[Chunk] = []
    for rc, seeds in todo:
        per_run = estimate_run_s(rc.problem, rc.spec.method)
        size = chunk or max(1, min(10, int(target_s / max(per_run, 1e-6))))
        for i in range(0, len(seeds), size):
            part = seeds[i : i + size]
            chunks.append(
                Chunk(
                    len(chunks),
                    rc.problem,
                    rc.spec.method,
                    dict(rc.spec.params),
                    part,
                    [rc.run_key(s) for s in part],
                    per_run * len(part),
                )
            )
    # Largest per-run cost first (then larger chunks), stable for equal costs.
    chunks.sort(key=lambda c: (-c.cost_s / len(c.seeds), -len(c.seeds), c.id))
    return chunks


def run_chunk(chunk: Chunk) -> list[dict]:
    """Run every seed of a chunk (in a worker); never raises for a failing run.

    Returns one row per seed with ``run_key``, ``seed``, ``status``, ``error``, ``tu1``, ``tu2``,
    ``wall_s``, ``final_alive``, ``final_active``, ``code_version``, ``host``, ``created_utc``.
    """
    from mission.experiments.sim import run_episode

    version, host = code_version(), socket.gethostname()
    rows = []
    for seed, key in zip(chunk.seeds, chunk.keys):
        t0 = time.perf_counter()
        row = {"run_key": key, "seed": int(seed)}
        try:
            r = run_episode(chunk.problem, chunk.method, chunk.params, int(seed)).row()
            row.update(
                status="ok",
                error=None,
                tu1=float(r["tu1"]),
                tu2=float(r["tu2"]),
                wall_s=float(r["wall_s"]),
                final_alive=int(r["final_alive"]),
                final_active=int(r["final_active"]),
            )
        except (
            Exception
        ) as exc:  # one failed run is data, the sweep goes on (docs/design/architecture.md §7)
            log.debug("run %s seed %s failed", chunk.method, seed, exc_info=True)
            row.update(
                status="error",
                error=f"{type(exc).__name__}: {exc}"[:4000],
                tu1=None,
                tu2=None,
                wall_s=time.perf_counter() - t0,
                final_alive=None,
                final_active=None,
            )
        row.update(code_version=version, host=host, created_utc=utc_now())
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------------------------
# Executors
# ----------------------------------------------------------------------------------------------


def _worker_init() -> None:
    """Pool worker: leave Ctrl-C to the parent, and exit if the parent disappears (kill -9)."""
    import multiprocessing
    from multiprocessing.connection import wait

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = multiprocessing.parent_process()  # the sweep process (not the forkserver)
    if parent is None or parent.sentinel is None:  # pragma: no cover - fork context
        return

    def watch() -> None:
        wait([parent.sentinel])  # ready when the sweep process is gone, however it died
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


class LocalExecutor:
    """A process pool on this machine (``workers`` processes); in-process when ``workers == 1``."""

    name = "local"

    def __init__(self, workers: int = 1) -> None:
        self.workers = max(1, int(workers))
        self._pool: ProcessPoolExecutor | None = None

    def run(self, chunks: list[Chunk]) -> Iterator[tuple[Chunk, list[dict] | BaseException]]:
        """Yield ``(chunk, rows)`` as chunks complete (``(chunk, exc)`` if the executor lost it)."""
        if self.workers == 1:
            for c in chunks:
                yield c, run_chunk(c)
            return
        import multiprocessing
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

        # forkserver: workers do not inherit the parent's SQLite handle, threads or tqdm state.
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(["mission.experiments.sweep", "mission.experiments.sim"])
        self._pool = ProcessPoolExecutor(
            max_workers=self.workers, mp_context=ctx, initializer=_worker_init
        )
        pending = {self._pool.submit(run_chunk, c): c for c in chunks}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                c = pending.pop(fut)
                exc = fut.exception()
                yield c, (exc if exc is not None else fut.result())
        self.close()

    def close(self, cancel: bool = False) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        if cancel:
            # Stop the workers now (they ignore SIGINT); completed chunks are already stored.
            from mission.experiments.sim import stop_pool_now

            stop_pool_now(pool)
        else:
            pool.shutdown(wait=True)


class DaskExecutor:
    """A ``dask.distributed`` cluster: an existing one (``scheduler``) or a LocalCluster.

    Every worker must be able to import this package (``pip install -e .`` or a shared venv).
    A worker lost mid-sweep loses nothing: the scheduler runs its tasks again on the others (up to
    ``distributed.scheduler.allowed-failures`` worker deaths per task). A task lost beyond that,
    or with the scheduler, comes back as an exception: its runs are not stored and a rerun retries
    them (tests/mission/test_sweep_dask_cluster.py).
    """

    name = "dask"

    def __init__(self, workers: int = 1, scheduler: str | None = None) -> None:
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError as exc:  # pragma: no cover - optional dependency
            raise RuntimeError(
                "the dask executor needs dask[distributed] (pip install 'phireman[dask]')"
            ) from exc
        self.cluster = None
        if logging.getLogger().getEffectiveLevel() >= logging.WARNING:
            # distributed configures its own INFO logging; keep the progress bar readable unless -v
            logging.getLogger("distributed").setLevel(logging.WARNING)
        if scheduler:
            self.client = Client(scheduler, timeout=30)
        else:
            self.cluster = LocalCluster(
                n_workers=max(1, int(workers)),
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,
            )
            self.client = Client(self.cluster)
        self.workers = len(self.client.scheduler_info().get("workers", {})) or workers
        self._futures: list = []

    def run(self, chunks: list[Chunk]) -> Iterator[tuple[Chunk, list[dict] | BaseException]]:
        from dask.distributed import as_completed

        token = hashlib.sha256(f"{os.getpid()}-{time.time()}".encode()).hexdigest()[:8]
        by_key = {}
        n = len(chunks)
        for i, c in enumerate(chunks):
            fut = self.client.submit(
                run_chunk,
                c,
                key=f"phireman-chunk-{token}-{c.id}",
                pure=False,
                priority=n - i,
                retries=1,
            )
            by_key[fut.key] = c
            self._futures.append(fut)
        for fut in as_completed(self._futures):
            c = by_key[fut.key]
            try:
                result = fut.result()
            except Exception as exc:  # lost worker, import error on a remote worker, ...
                result = exc
            fut.release()
            yield c, result
        self._futures = []

    def close(self, cancel: bool = False) -> None:
        try:
            if cancel and self._futures:
                self.client.cancel(self._futures, force=True)
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()
                self.cluster = None


# ----------------------------------------------------------------------------------------------
# The sweep
# ----------------------------------------------------------------------------------------------


@dataclass
class SweepSummary:
    grid: str
    planned: int
    """Runs in the grid."""
    present: int
    """Runs already in the store when the sweep started (skipped)."""
    completed: int = 0
    """Runs completed and stored by this sweep."""
    errors: int = 0
    """Of those, runs that raised (stored with status 'error')."""
    lost: int = 0
    """Runs lost to executor failures (not stored; a rerun retries them)."""
    interrupted: bool = False
    wall_s: float = 0.0
    other_code: dict = field(default_factory=dict)
    """code_version -> count of present rows made by code other than this process's."""
    resolve_errors: dict = field(default_factory=dict)
    """label/method -> message, for configurations whose parameters did not resolve."""
    keys: set = field(default_factory=set, repr=False)
    """Every run key of the grid."""

    @property
    def remaining(self) -> int:
        return self.planned - self.present - self.completed


def _fmt_s(s: float) -> str:
    s = int(max(0, s))
    return (
        f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"
        if s >= 3600
        else f"{s // 60:02d}:{s % 60:02d}"
    )


def run_sweep(
    grid: Grid,
    store: ResultStore,
    executor: str = "local",
    workers: int = 1,
    scheduler: str | None = None,
    chunk: int | None = None,
    progress: bool = True,
    retry_errors: bool = False,
    rerun_other_code: bool = False,
    argv: list[str] | None = None,
    on_rows: Callable[[list[dict]], None] | None = None,
) -> SweepSummary:
    """Run every run of ``grid`` that ``store`` does not hold yet; return what happened.

    Ctrl-C (and SIGTERM) stop the sweep cleanly: the executor is cancelled, everything completed is
    already committed, and ``summary.interrupted`` is set. Rerunning finishes the remaining runs.

    Parameters
    ----------
    grid : the configurations and seeds
    store : the results store (this process writes; workers only compute)
    executor : 'local' (process pool; in-process with one worker) or 'dask'
    workers : processes for the local pool or the Dask LocalCluster
    scheduler : address of an existing Dask scheduler (``tcp://host:port``); implies 'dask'
    chunk : seeds per task (default: about 8 s of work, 1–10 seeds)
    progress : show a tqdm progress bar on stderr
    retry_errors : delete this grid's error rows first so they run again
    rerun_other_code : delete this grid's rows made by other code versions first
    argv : the command line, for the sweep log
    on_rows : called with each stored batch (tests, custom progress)

    Raises
    ------
    ValueError
        An invalid configuration in the grid (bad size, reading or problem override) or executor.
    """
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor {executor!r}; valid executors: {', '.join(EXECUTORS)}")
    t0 = time.perf_counter()
    version = code_version()
    resolved = [resolve(spec) for spec in grid.configs]  # ValueError on a bad problem: nothing runs
    meta: dict[str, tuple[ResolvedConfig, str]] = {}
    for rc in resolved:
        for s in grid.seeds:
            meta.setdefault(rc.run_key(s), (rc, grid.name))
    grid_keys = set(meta)

    if retry_errors:
        n = store.delete_runs(grid_keys & store.keys("error"))
        if n:
            log.info("deleted %d error rows to retry them", n)
    if rerun_other_code:
        stale = [
            r["run_key"]
            for r in store.runs("code_version != ?", (version,))
            if r["run_key"] in grid_keys
        ]
        if stale:
            log.info("deleted %d rows made by other code versions", store.delete_runs(stale))
    present = grid_keys & store.keys()
    other = {v: n for v, n in store.code_versions_of(present).items() if v != version}
    summary = SweepSummary(
        grid.name, len(grid_keys), len(present), other_code=other, keys=grid_keys
    )
    for rc in resolved:
        if rc.resolve_error:
            summary.resolve_errors[rc.spec.label or rc.spec.method] = rc.resolve_error

    todo = []
    for rc in resolved:
        seeds = [s for s in grid.seeds if rc.run_key(s) not in present]
        # one config may appear twice in a grid (same key): run it once
        seeds = [s for s in seeds if meta[rc.run_key(s)][0] is rc]
        if seeds:
            todo.append((rc, seeds))
    chunks = plan_chunks(todo, chunk)
    sweep_id = store.start_sweep(
        grid.name,
        list(argv or []),
        executor if not scheduler else f"dask {scheduler}",
        workers,
        version,
        summary.planned,
        summary.present,
    )
    if not chunks:
        store.finish_sweep(sweep_id, 0, 0, False, time.perf_counter() - t0)
        summary.wall_s = time.perf_counter() - t0
        return summary

    total_cost = sum(c.cost_s for c in chunks)
    done_cost = 0.0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(
            total=summary.planned,
            initial=summary.present,
            unit="run",
            dynamic_ncols=True,
            desc=grid.name,
            smoothing=0.05,
        )

    old_term = None
    if threading.current_thread() is threading.main_thread():

        def _term(signum, frame):
            raise KeyboardInterrupt

        old_term = signal.signal(signal.SIGTERM, _term)

    ex: DaskExecutor | LocalExecutor | None = None
    warned_code = False
    t_run = time.perf_counter()
    try:
        if executor == "dask" or scheduler:
            ex = DaskExecutor(workers, scheduler)
        else:
            ex = LocalExecutor(workers)
        t_run = time.perf_counter()  # the ETA counts from here, not from the cluster start-up
        for c, result in ex.run(chunks):
            if isinstance(result, BaseException):
                summary.lost += len(c.seeds)
                log.error(
                    "chunk of %d runs (%s, seeds %s..%s) lost to the executor: %s: %s",
                    len(c.seeds),
                    c.method,
                    c.seeds[0],
                    c.seeds[-1],
                    type(result).__name__,
                    result,
                )
            else:
                rows = []
                for r in result:
                    if r["code_version"] != version and not warned_code:
                        warned_code = True
                        log.warning(
                            "a worker runs other code than this process (%s, here %s)",
                            r["code_version"],
                            version,
                        )
                    rc, gname = meta[r["run_key"]]
                    spec = rc.spec
                    rows.append(
                        {
                            **r,
                            "config_key": rc.config_key,
                            "spec_key": spec.spec_key,
                            "grid": gname,
                            "label": spec.label,
                            "size": spec.size.upper(),
                            "attrition": float(spec.attrition),
                            "reading": spec.reading,
                            "method": spec.method,
                            "spec_json": canonical_json(spec.spec_dict()),
                            "config_json": canonical_json(rc.config),
                        }
                    )
                store.insert_runs(rows)  # one transaction per chunk
                summary.completed += len(rows)
                summary.errors += sum(r["status"] == "error" for r in rows)
                if on_rows:
                    on_rows(rows)
            done_cost += c.cost_s
            if bar is not None:
                bar.update(len(c.seeds))
                elapsed = time.perf_counter() - t_run
                eta = elapsed * (total_cost - done_cost) / max(done_cost, 1e-9)
                post = f"work-ETA {_fmt_s(eta)}"
                if summary.errors:
                    post += f", {summary.errors} errors"
                bar.set_postfix_str(post, refresh=False)
    except KeyboardInterrupt:
        summary.interrupted = True
    finally:
        if ex is not None:
            try:
                ex.close(cancel=summary.interrupted)
            except Exception:  # closing must not mask the outcome
                log.warning("executor did not close cleanly", exc_info=True)
        if bar is not None:
            bar.close()
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)
        summary.wall_s = time.perf_counter() - t0
        store.finish_sweep(
            sweep_id, summary.completed, summary.errors, summary.interrupted, summary.wall_s
        )
    return summary

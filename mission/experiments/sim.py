"""In-process RTNUA simulation: the paper's world model driven by a registered planner.

One episode = ``problem.n_steps`` steps of :func:`mission.experiments.world_loop.run_world` (measure ->
plan -> attrit -> step, docs/design/model.md §7 #2, #16) on the paper's scenario
(:func:`vehicle_emu.world.draw_scenario`), with the planner's displacements as they are (the
paper's world has no geofence).

Runs are independent given their seed, so results do not depend on how many worker processes run
them (``run_many``).
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ProcessPoolExecutor
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from mission.experiments.world_loop import EpisodeRecord, run_world
from planner.hazard import HazardMap
from planner.methods import make_planner
from planner.metrics import UptimeSeries, uptime_series
from planner.problem import ProblemConfig
from vehicle_emu.world import World, draw_scenario, spawn_streams

__all__ = [
    "EpisodeRecord",
    "EpisodeResult",
    "run_episode",
    "run_many",
    "mean_ci95",
    "format_pct_ci",
]

log = logging.getLogger(__name__)


def stop_pool_now(pool: ProcessPoolExecutor) -> None:
    """Stop a process pool at once (Ctrl-C, an error): queued work is cancelled and the workers,
    which ignore SIGINT, are terminated and joined, so nothing is left running or printing."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=5)


@dataclass
class EpisodeResult:
    seed: int
    method: str
    tu1: float
    tu2: float
    series: UptimeSeries
    alive_count: np.ndarray  # (tau,) alive drones at each measured step
    active_count: np.ndarray  # (tau,) alive and active drones
    wall_s: float
    record: EpisodeRecord | None = None

    def row(self) -> dict:
        return {
            "seed": self.seed,
            "method": self.method,
            "tu1": self.tu1,
            "tu2": self.tu2,
            "wall_s": self.wall_s,
            "final_alive": int(self.alive_count[-1]),
            "final_active": int(self.active_count[-1]),
        }


def run_episode(
    problem: ProblemConfig,
    method: str,
    params: dict | None,
    seed: int,
    record: bool = False,
    frames: Iterable[int] = (),
    loss_prob_fn: Callable[[int, np.ndarray], np.ndarray] | None = None,
    hazards: HazardMap | None = None,
) -> EpisodeResult:
    """Simulate one episode and score it.

    Parameters
    ----------
    problem : the scenario family
    method : planner name (planner.methods.METHODS)
    params : planner parameters (unknown keys raise ValueError)
    seed : run seed; scenario, attrition and algorithm streams are derived from it
    record : keep full trajectories in ``result.record``
    frames : steps at which to keep the task tree (with ``record``)
    loss_prob_fn : optional ``(t_step, pos_m) -> (N,) loss probability`` replacing the uniform
        per-step attrition (hazard zones, scripted losses)
    hazards : the hazard zones the planner is told about (``TickInput.hazards``; None: none, as
        the paper's presets)
    """
    t0 = time.perf_counter()
    streams = spawn_streams(seed)
    scenario = draw_scenario(problem, streams)
    world = World.from_scenario(problem, scenario)
    planner = make_planner(method, problem, params, streams.algorithm)
    run = run_world(
        world,
        planner,
        problem.n_steps,
        problem.attrition_per_step if loss_prob_fn is None else loss_prob_fn,
        scenario.attrition_u,
        record=record,
        frames=set(frames),
        hazards=hazards,
    )
    series = uptime_series(run.connected[: problem.n_steps])
    return EpisodeResult(
        seed,
        method,
        series.tu1,
        series.tu2,
        series,
        run.alive_count,
        run.active_count,
        time.perf_counter() - t0,
        run.record,
    )


def _run_chunk(args) -> list[dict]:
    problem, method, params, seeds = args
    out = []
    for s in seeds:
        r = run_episode(problem, method, params, s)
        d = r.row()
        d["tu1_step"] = r.series.tu1_step
        d["alive_count"] = r.alive_count
        d["active_count"] = r.active_count
        d["n_connected"] = r.series.n_connected
        out.append(d)
    return out


def _ignore_sigint() -> None:
    """Pool worker: Ctrl-C is the parent's to handle (otherwise every worker prints a traceback)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_many(
    problem: ProblemConfig,
    method: str,
    params: dict | None,
    seeds: list[int],
    workers: int | None = None,
    progress: Callable[[int], None] | None = None,
) -> list[dict]:
    """Run many seeds, in worker processes when ``workers`` > 1; results sorted by seed.

    Each chunk of seeds is independent; the result does not depend on ``workers``. On Ctrl-C the
    workers are stopped (they ignore SIGINT themselves) and KeyboardInterrupt propagates.
    """
    workers = workers or 1
    if workers <= 1 or len(seeds) <= 1:
        rows = []
        for s in seeds:
            rows.extend(_run_chunk((problem, method, params, [s])))
            if progress:
                progress(1)
        return rows
    from concurrent.futures import as_completed

    chunk = max(1, min(10, len(seeds) // (workers * 4) or 1))
    chunks = [seeds[i : i + chunk] for i in range(0, len(seeds), chunk)]
    rows = []
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_ignore_sigint)
    try:
        futures = [pool.submit(_run_chunk, (problem, method, params, c)) for c in chunks]
        for fut in as_completed(futures):
            part = fut.result()
            rows.extend(part)
            if progress:
                progress(len(part))
    except BaseException:
        stop_pool_now(pool)
        raise
    pool.shutdown(wait=True)
    return sorted(rows, key=lambda r: r["seed"])


def mean_ci95(values) -> tuple[float, float]:
    """Mean and the half-width of its 95 % Student-t confidence interval (nan half-width if
    n < 2; nan, nan if n = 0). The one definition: ``phireman sim``, ``phireman play`` and the
    report (:mod:`mission.experiments.report`) use it."""
    from scipy import stats

    x = np.asarray(values, dtype=float)
    if len(x) < 2:
        return (float(x.mean()) if len(x) else float("nan"), float("nan"))
    half = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x))
    return float(x.mean()), float(half)


def format_pct_ci(mean: float, half: float, lo: float = 0.0, hi: float = 100.0) -> tuple[str, bool]:
    """'80.00 ± 1.23', or the interval clipped to [lo, hi] when it reaches past them.

    Returns the text and whether it was clipped. A percentage cannot leave [0, 100], so an
    interval that does (few seeds, skewed data) is shown as its clipped bounds rather than as a
    ± half-width wider than the range: '80.00 (CI 0.00–100.00 clipped)'.
    """
    if np.isnan(mean):
        return "–", False
    if np.isnan(half):
        return f"{mean:.2f} (1 run, no CI)", False
    if mean - half < lo - 1e-9 or mean + half > hi + 1e-9:
        return (
            f"{mean:.2f} (CI {max(lo, mean - half):.2f}–{min(hi, mean + half):.2f} clipped)",
            True,
        )
    return f"{mean:.2f} ± {half:.2f}", False

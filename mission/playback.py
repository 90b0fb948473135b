"""Playing a mission file in-process: the paper's world model, the mission's geography.

The in-process backend is the fast rehearsal of a mission (and the reference the emulator backend
is compared with). It maps the mission onto the world model of ``vehicle_emu.world``:

* one world step = one control period ``run.control_period_s``;
* drones start at the mission's spawn (ring with seeded noise, or explicit positions);
* tasks follow their tracks (sampled at every step), seeded random walks, or the ``random``
  generator; live ``mavlink`` tasks cannot be rehearsed in-process and are refused;
* attrition per drone and step: background rate, plus every hazard zone that contains the drone
  and is active, converted with p = 1 - exp(-rate * dt); scripted losses happen at their step.

Random streams follow ``vehicle_emu.world.spawn_streams``: spawn noise and task walks come from the
scenario stream, attrition uniforms from the attrition stream, so the same seed gives the same run.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import pathlib
import time
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from mission.schema import HazardZone, Mission
from mission.sim import EpisodeRecord
from planner.methods import TickInput, make_planner
from planner.metrics import UptimeSeries, uptime_series
from vehicle_emu.world import RunStreams, World, spawn_streams, walk_tasks

__all__ = ["MissionScenario", "build_scenario", "spawn_positions", "task_track_m", "task_position_fn", "zone_mask",
           "loss_probability", "PlaybackResult", "run_inprocess", "write_run_dir"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MissionScenario:
    """Everything random or scripted about one play of a mission, drawn up front."""

    dt_s: float
    drone_pos0_m: np.ndarray   # (N, 2) north, east
    task_track_m: np.ndarray   # (T+1, M, 2) task positions at every step
    task_names: list[str]
    attrition_u: np.ndarray    # (T, N) uniforms
    scripted_step: np.ndarray  # (N,) step at which each drone is scripted to die (-1 never)


def spawn_positions(mission: Mission, rng: np.random.Generator) -> np.ndarray:
    """(N, 2) start positions: the spawn ring with seeded noise, or the explicit positions."""
    emu = mission.vehicles.emulated
    n = mission.vehicles.count
    if emu is None or emu.spawn.ring is not None:
        ring = emu.spawn.ring if emu is not None else None
        radius = ring.radius_m if ring is not None else 0.0
        noise = ring.noise_m if ring is not None else 0.0
        angles = 2 * np.pi * np.arange(n) / n
        return radius * np.stack([np.cos(angles), np.sin(angles)], 1) + rng.normal(0, noise, (n, 2))
    assert emu.spawn.positions is not None  # a spawn is a ring or positions (the schema)
    pts = np.array([[p.north_m, p.east_m] for p in emu.spawn.positions], dtype=float)
    if len(pts) < n:  # schema allows fewer positions than drones: the rest start at the base
        pts = np.vstack([pts, np.zeros((n - len(pts), 2))])
    return pts[:n]


def task_track_m(mission: Mission, rng: np.random.Generator, n_steps: int, *,
                 live: str = "refuse") -> tuple[np.ndarray, list[str]]:
    """(n_steps + 1, M, 2) task positions at every control step, and the task names.

    Tasks are drawn in file order from ``rng`` (the scenario stream). A live MAVLink task has no
    track to draw: ``live='refuse'`` raises ValueError (in-process and emulated runs need every
    task's truth), ``live='nan'`` gives it a NaN column that the ground station fills from the
    tracker (:class:`gcs.tasks.LiveTasks`).
    """
    dt = mission.run.control_period_s
    times = np.arange(n_steps + 1) * dt
    columns, names = [], []
    for i, task in enumerate(mission.tasks):
        label = task.name or f"task {i}"
        kind = task.kind
        if kind == "track":
            assert task.track is not None  # each kind has its field (the schema)
            pts = [(p.t_s, *p.local_m(mission.origin)) for p in task.track]
            t_k = np.array([p[0] for p in pts])
            north = np.interp(times, t_k, [p[1] for p in pts])
            east = np.interp(times, t_k, [p[2] for p in pts])
            columns.append(np.stack([north, east], 1)[:, None, :])
            names.append(label)
        elif kind == "random_walk":
            rw = task.random_walk
            assert rw is not None
            start = np.array([rw.start.local_m(mission.origin)], dtype=float)
            sigma = rw.sigma_m_per_sqrt_s * math.sqrt(dt)
            half = rw.field_half_width_m if rw.field_half_width_m is not None else float("inf")
            border = rw.border if math.isfinite(half) else "none"
            inc = rng.normal(0, sigma, (n_steps, 1, 2))
            columns.append(walk_tasks(start, inc, half, border))
            names.append(label)
        elif kind == "random":
            gen = task.random
            assert gen is not None
            w = gen.field_half_width_m
            start = rng.uniform(-w, w, (gen.count, 2))
            inc = rng.normal(0, gen.sigma_m_per_sqrt_s * math.sqrt(dt), (n_steps, gen.count, 2))
            columns.append(walk_tasks(start, inc, w, gen.border))
            names += [f"{label} {k}" for k in range(gen.count)]
        elif live == "nan":
            columns.append(np.full((n_steps + 1, 1, 2), np.nan))
            names.append(label)
        else:
            assert task.mavlink is not None
            raise ValueError(f"tasks[{i}]: a live MAVLink task (sysid {task.mavlink.sysid}) has no "
                             "track to simulate; fly it against real links (--connect) instead")
    return np.concatenate(columns, axis=1), names


def task_position_fn(track_m: np.ndarray, dt_s: float):
    """A ``t_s -> (M, 2)`` function interpolating a sampled track (for the emulator's truth)."""
    times = np.arange(len(track_m)) * dt_s

    def position(t_s: float) -> np.ndarray:
        k = float(np.clip(t_s / dt_s, 0, len(track_m) - 1))
        lo = int(math.floor(k))
        hi = min(lo + 1, len(track_m) - 1)
        a = k - lo
        return (1 - a) * track_m[lo] + a * track_m[hi]

    position.times_s = times  # type: ignore[attr-defined]  # read by the emulator's truth
    return position


def build_scenario(mission: Mission, seed: int | None = None) -> MissionScenario:
    """Draw a mission's scenario from ``seed`` (default: ``mission.run.seed``)."""
    seed = mission.run.seed if seed is None else seed
    streams: RunStreams = spawn_streams(seed)
    n_steps = mission.run.n_steps
    dt = mission.run.control_period_s
    pos0 = spawn_positions(mission, streams.scenario)
    track, names = task_track_m(mission, streams.scenario, n_steps)
    n = len(pos0)
    scripted = np.full(n, -1, dtype=np.int64)
    for loss in mission.attrition.scripted:
        if loss.vehicle < n:
            step = int(math.floor(loss.t_s / dt + 1e-9))
            scripted[loss.vehicle] = step if scripted[loss.vehicle] < 0 else min(scripted[loss.vehicle], step)
    return MissionScenario(dt, pos0, track, names, streams.attrition.random((n_steps, n)), scripted)


def zone_mask(zone: HazardZone, pos_m: np.ndarray) -> np.ndarray:
    """(N,) bool: which positions (north, east) lie in the zone (vectorised over drones)."""
    north, east = pos_m[:, 0], pos_m[:, 1]
    if zone.circle is not None:
        c = zone.circle.center
        return np.hypot(north - c.north_m, east - c.east_m) <= zone.circle.radius_m
    inside = np.zeros(len(pos_m), dtype=bool)
    pts = zone.polygon
    assert pts is not None  # a zone is a circle or a polygon (the schema)
    for a, b in zip(pts, pts[1:] + pts[:1]):  # loop over polygon edges, vectorised over drones
        crosses = (a.north_m > north) != (b.north_m > north)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = a.east_m + (north - a.north_m) * (b.east_m - a.east_m) / (b.north_m - a.north_m)
        inside ^= crosses & (east < x)
    return inside


def loss_probability(mission: Mission, t_s: float, pos_m: np.ndarray) -> np.ndarray:
    """(N,) per-step loss probability: background plus active hazard zones containing each drone."""
    rate = np.full(len(pos_m), mission.attrition.rate_per_s)
    for zone in mission.attrition.hazard_zones:
        if zone.active(t_s):
            rate = rate + zone.rate_per_s * zone_mask(zone, pos_m)
    return -np.expm1(-rate * mission.run.control_period_s)


@dataclass
class PlaybackResult:
    seed: int
    tu1: float
    tu2: float
    series: UptimeSeries
    record: EpisodeRecord
    losses: list[dict]
    wall_s: float
    task_names: list[str]


def run_inprocess(mission: Mission, seed: int | None = None, frames: Collection[int] = ()) -> PlaybackResult:
    """Play ``mission`` on the in-process world model with its planner (one tick per control period)."""
    t0 = time.perf_counter()
    seed = mission.run.seed if seed is None else seed
    scn = build_scenario(mission, seed)
    problem = dataclasses.replace(mission.problem_config(), n_drones=len(scn.drone_pos0_m),
                                  n_tasks=scn.task_track_m.shape[1])
    params = dict(mission.planner.params)
    if mission.planner.method in ("phireman", "dccrs"):
        params.setdefault("info", mission.planner.info)
    planner = make_planner(mission.planner.method, problem, params, spawn_streams(seed).algorithm)
    world = World(problem, scn.drone_pos0_m.copy(), np.ones(len(scn.drone_pos0_m), bool), scn.task_track_m)
    tau, n, m = mission.run.n_steps, problem.n_drones, problem.n_tasks
    rec = EpisodeRecord(np.zeros((tau + 1, n, 2)), np.zeros((tau + 1, n), bool), np.zeros((tau + 1, n), bool),
                        scn.task_track_m, np.zeros((tau + 1, m), bool))
    frames = set(frames)
    losses = []
    # The station clips every target into the mission's geofence (gcs.control); so does this
    # backend, with the same fence (runners.control_config, one place for its default).
    from mission.runners import MissionScenario as _FlyScenario, control_config
    fence = control_config(mission, _FlyScenario(scn.drone_pos0_m, scn.task_track_m, scn.dt_s)).geofence
    for t in range(tau + 1):
        active = world.active()
        rec.connected[t] = world.tasks_connected(active)
        rec.pos_m[t], rec.alive[t], rec.active[t] = world.pos_m, world.alive, active
        if t == tau:
            break
        out = planner.plan(TickInput(t, world.pos_m, world.alive, active, world.task_pos_m, world.base_m))
        if t in frames or not frames:
            rec.trees[t] = out.tree
        p_loss = loss_probability(mission, t * scn.dt_s, world.pos_m)
        p_loss = np.where(scn.scripted_step == t, 1.0, p_loss)
        disp_m = fence.clip_ne(world.pos_m + out.disp_m) - world.pos_m
        lost = world.step(disp_m, active, p_loss, scn.attrition_u[t])
        for i in np.flatnonzero(lost):
            losses.append({"t_s": (t + 1) * scn.dt_s, "event": "vehicle_lost", "index": int(i),
                           "scripted": bool(scn.scripted_step[i] == t),
                           "north_m": float(world.pos_m[i, 0]), "east_m": float(world.pos_m[i, 1])})
    series = uptime_series(rec.connected[:tau])
    return PlaybackResult(seed, series.tu1, series.tu2, series, rec, losses, time.perf_counter() - t0,
                          scn.task_names)


def write_run_dir(mission: Mission, result: PlaybackResult, out_dir: pathlib.Path, backend: str = "inprocess") -> None:
    """Record a played mission: resolved mission, seed, code version, events, metrics, truth, summary."""
    from mission.load import dump_mission
    from mission.sweep import code_version

    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "mission.yaml").write_text(dump_mission(mission, header=f"resolved mission, seed {result.seed}"))
    with open(out_dir / "events.jsonl", "w") as fh:
        for ev in result.losses:
            fh.write(json.dumps(ev) + "\n")
    rec, s = result.record, result.series
    tau = len(s.tu1_step)
    with open(out_dir / "metrics.csv", "w") as fh:
        fh.write("t_s,alive,active,tasks_connected,tasks_ever_connected,tu1_so_far,tu2_so_far\n")
        for t in range(tau):
            fh.write(f"{t * mission.run.control_period_s:g},{int(rec.alive[t].sum())},{int(rec.active[t].sum())},"
                     f"{int(s.n_connected[t])},{int(s.n_ever_connected[t])},"
                     f"{s.tu1_step[:t + 1].mean():.6f},{s.tu2_step[:t + 1].mean():.6f}\n")
    np.savez_compressed(out_dir / "truth.npz", t_s=np.arange(tau + 1) * mission.run.control_period_s,
                        pos_ne_m=rec.pos_m, alive=rec.alive, active=rec.active, task_pos_ne_m=rec.task_pos_m,
                        task_connected=rec.connected)
    trees = {str(t): {"nodes_ne_m": tr.nodes_m.tolist(), "parent": tr.parent.tolist(), "n_tasks": tr.n_tasks}
             for t, tr in rec.trees.items() if tr is not None}
    (out_dir / "trees.json").write_text(json.dumps(trees))
    summary = {"backend": backend, "mission": mission.name, "seed": result.seed, "code_version": code_version(),
               "tu1": result.tu1, "tu2": result.tu2, "truth_tu1": result.tu1, "truth_tu2": result.tu2,
               "n_losses": len(result.losses), "final_alive": int(rec.alive[-1].sum()),
               "final_active": int(rec.active[-1].sum()), "wall_s": result.wall_s,
               "task_names": result.task_names}
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))

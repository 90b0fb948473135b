"""What one seed of a mission draws: spawn positions, task tracks, attrition uniforms and the
per-step loss probability - one drawing order for every backend.

The in-process playback (:mod:`mission.playback`) and the emulated flights
(:mod:`mission.mission_world`) both draw from here, so the same seed gives the same spawn, the
same task motion and the same losses on both (common random numbers, docs/design/model.md §6.1):

* drones start at the mission's spawn (ring with seeded noise, or explicit positions);
* tasks follow their tracks (sampled at every control step), seeded random walks, or the
  ``random`` generator; live ``mavlink`` tasks have no track to draw;
* attrition per drone and step: background rate, plus every hazard zone that contains the drone
  and is active, converted with p = 1 - exp(-rate * dt); scripted losses happen at their step.

Random streams follow ``vehicle_emu.world.spawn_streams``: spawn noise and task walks come from
the scenario stream, attrition uniforms from the attrition stream.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mission.schema import HazardZone, Mission
from vehicle_emu.world import RunStreams, spawn_streams, walk_tasks

__all__ = ["MissionScenario", "build_scenario", "spawn_positions", "task_track_m",
           "task_position_fn", "zone_mask", "loss_probability"]


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


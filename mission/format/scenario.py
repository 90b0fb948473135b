"""What one seed of a mission draws: spawn positions, task tracks, attrition uniforms, the
per-step loss probability and the fence - one scenario type and one drawing order for every
backend.

:class:`MissionScenario` is the only mission scenario type. The in-process playback
(:mod:`mission.experiments.playback`), the emulated flights (:mod:`mission.flight.mission_world`) and the station
(:mod:`mission.flight.station_loop`) all use it, so the same seed gives the same spawn, the same task
motion and the same losses on each (common random numbers, docs/design/model.md §6.1):

* drones start at the mission's spawn (ring with seeded noise, or explicit positions);
* tasks follow their tracks (sampled at every control step), seeded random walks, or the
  ``random`` generator; live ``mavlink`` tasks have no track to draw;
* attrition per drone and step: background rate, plus every hazard zone that contains the drone
  and is active, converted with p = 1 - exp(-rate * dt); scripted losses happen at their step;
* the station's altitude layers and geofence (:func:`control_config`): the mission's fence, or
  the task field plus :data:`FENCE_MARGIN_M`.

Random streams follow ``vehicle_emu.world.spawn_streams``: spawn noise and task walks come from
the scenario stream, attrition uniforms from the attrition stream.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from gcs.control import ControlConfig, Geofence, TerrainAltitude
from mission.format.schema import Attrition, HazardZone, Mission
from planner.hazard import HazardMap, HazardZone as PlannerHazardZone
from vehicle_emu.world import RunStreams, spawn_streams, walk_tasks

__all__ = [
    "MissionScenario",
    "build_scenario",
    "spawn_positions",
    "task_track_m",
    "task_position_fn",
    "track_at",
    "zone_mask",
    "loss_probability",
    "control_config",
    "hazard_map",
    "FENCE_MARGIN_M",
    "POSITION_LOOP_TAU_S",
]

#: Without a mission geofence, the fence is the task field plus this margin, metres.
FENCE_MARGIN_M = 100.0

#: Time constant of a multicopter's position loop (ArduPilot/PX4 position controllers, and the
#: emulator's ``Physics.tau_pos_s``): the station leads its targets by this much (ControlConfig).
POSITION_LOOP_TAU_S = 1.0


@dataclass(frozen=True)
class MissionScenario:
    """Everything random or scripted about one run of a mission, drawn up front from its seed
    (:func:`build_scenario`)."""

    spawn_ne_m: np.ndarray
    """(N, 2) start positions (north, east), mission frame, metres."""
    task_track_m: np.ndarray
    """(tau + 1, M, 2) task positions at t = k * dt_s, metres (NaN columns: live tasks)."""
    dt_s: float
    """The control period, seconds: one world step."""
    task_names: list[str] = field(default_factory=list)
    attrition_u: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    """(tau, N) uniforms of the attrition stream: drone i is lost at step t iff u[t, i] < p_i(t)."""
    scripted_step: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(N,) step in which each drone is scripted to be lost (-1: never)."""
    attrition: Attrition = field(default_factory=Attrition)
    """The mission's attrition section (background rate, hazard zones, scripted losses)."""

    def task_pos_m(self, t_s: float) -> np.ndarray:
        """(M, 2) task positions at mission time ``t_s`` (linear between steps, held at the ends)."""
        return track_at(self.task_track_m, self.dt_s, t_s)

    def loss_probability(self, t_s: float, pos_m: np.ndarray) -> np.ndarray:
        """(N,) loss probability of the step starting at ``t_s``: background plus the active hazard
        zones containing each position (scripted losses not included)."""
        return _loss_probability(self.attrition, self.dt_s, t_s, pos_m)

    def step_loss_probability(self, t_step: int, pos_m: np.ndarray) -> np.ndarray:
        """(N,) loss probability of world step ``t_step``, scripted losses included (p = 1 in the
        step that contains their time): the in-process world's ``loss_prob``."""
        p = self.loss_probability(t_step * self.dt_s, pos_m)
        return np.where(self.scripted_step == t_step, 1.0, p)


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


def _tak_who(src) -> str:
    for key in ("uid", "callsign", "callsign_pattern", "callsign_regex"):
        if getattr(src, key) is not None:
            return f"{key} {getattr(src, key)!r}"
    return "?"


def task_track_m(
    mission: Mission,
    rng: np.random.Generator,
    n_steps: int,
    *,
    live: str = "refuse",
    tak: bool = False,
) -> tuple[np.ndarray, list[str]]:
    """(n_steps + 1, M, 2) task positions at every control step, and the task names.

    Tasks are drawn in file order from ``rng`` (the scenario stream). A live MAVLink task has no
    track to draw: ``live='refuse'`` raises ValueError (in-process and emulated runs need every
    task's truth), ``live='nan'`` gives it a NaN column that the ground station fills from the
    tracker (:class:`gcs.tasks.LiveTasks`). ``tak``: a TAK crew gets NaN columns (one per slot)
    that the station fills from its reports (:class:`gcs.tak.TakCrews`); without it TAK crews
    raise ValueError (the in-process simulator has no truth for them).
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
        elif kind == "tak" and tak:
            # A TAK crew has no track anywhere: the station fills its column from the crew's
            # reports (gcs.tak.TakCrews); the emulator's truth sees it as unknown (NaN).
            assert task.tak is not None
            columns.append(np.full((n_steps + 1, task.count, 2), np.nan))
            names += [label] if task.count == 1 else [f"{label} {k}" for k in range(task.count)]
        elif live == "nan" and kind == "mavlink":
            columns.append(np.full((n_steps + 1, 1, 2), np.nan))
            names.append(label)
        elif kind == "tak":
            assert task.tak is not None
            raise ValueError(
                f"tasks[{i}]: a TAK crew ({_tak_who(task.tak)}) has no track to simulate; "
                "fly it with 'phireman fly' (emulated or real vehicles), its position comes "
                "from the crew's TAK reports"
            )
        else:
            assert task.mavlink is not None
            raise ValueError(
                f"tasks[{i}]: a live MAVLink task (sysid {task.mavlink.sysid}) has no "
                "track to simulate; fly it against real links (--connect) instead"
            )
    return np.concatenate(columns, axis=1), names


def track_at(track_m: np.ndarray, dt_s: float, t_s: float) -> np.ndarray:
    """(M, 2) positions at ``t_s`` of a track sampled every ``dt_s`` (``track_m``: (K, M, 2)):
    linear between samples, every column at once, exact at the samples, held at the ends."""
    last = len(track_m) - 1
    k = min(max(t_s / dt_s, 0.0), float(last))
    lo = int(math.floor(k))
    hi = min(lo + 1, last)
    a = k - lo
    return track_m[lo] * (1 - a) + track_m[hi] * a


def task_position_fn(track_m: np.ndarray, dt_s: float) -> Callable[[float], np.ndarray]:
    """A ``t_s -> (M, 2)`` function interpolating a sampled track (:func:`track_at`)."""
    return lambda t_s: track_at(track_m, dt_s, t_s)


def build_scenario(
    mission: Mission, seed: int | None = None, *, live_tasks: bool = False, tak: bool = False
) -> MissionScenario:
    """Draw a mission's scenario from ``seed`` (default: ``mission.run.seed``).

    Order of the draws: the scenario stream gives the ring noise, then each task entry in file
    order (random starts, then walk increments); the attrition stream gives the (tau, N)
    uniforms. ``live_tasks``: a live MAVLink task gets a NaN column (the station fills it from
    its tracker) instead of raising ValueError (:func:`task_track_m`).
    """
    seed = mission.run.seed if seed is None else seed
    streams: RunStreams = spawn_streams(seed)
    n_steps = mission.run.n_steps
    dt = mission.run.control_period_s
    pos0 = spawn_positions(mission, streams.scenario)
    track, names = task_track_m(
        mission, streams.scenario, n_steps, live="nan" if live_tasks else "refuse", tak=tak
    )
    n = len(pos0)
    scripted = np.full(n, -1, dtype=np.int64)
    for loss in mission.attrition.scripted:
        if loss.vehicle < n:
            step = int(math.floor(loss.t_s / dt + 1e-9))
            scripted[loss.vehicle] = (
                step if scripted[loss.vehicle] < 0 else min(scripted[loss.vehicle], step)
            )
    return MissionScenario(
        pos0, track, dt, names, streams.attrition.random((n_steps, n)), scripted, mission.attrition
    )


def zone_mask(zone: HazardZone, pos_m: np.ndarray) -> np.ndarray:
    """(N,) bool: which positions (north, east) lie in the zone (:meth:`HazardZone.contains_ne`)."""
    return np.asarray(zone.contains_ne(pos_m), dtype=bool)


def _loss_probability(
    attrition: Attrition, dt_s: float, t_s: float, pos_m: np.ndarray
) -> np.ndarray:
    rate = np.full(len(pos_m), attrition.rate_per_s)
    for zone in attrition.hazard_zones:
        if zone.active(t_s):
            rate = rate + zone.rate_per_s * zone_mask(zone, pos_m)
    return -np.expm1(-rate * dt_s)


def loss_probability(mission: Mission, t_s: float, pos_m: np.ndarray) -> np.ndarray:
    """(N,) per-step loss probability: background plus active hazard zones containing each drone."""
    return _loss_probability(mission.attrition, mission.run.control_period_s, t_s, pos_m)


def hazard_map(attrition: Attrition) -> HazardMap | None:
    """The mission's hazard zones as the planner sees them (planner.hazard), None without zones:
    the one conversion from the mission schema (metres, mission frame, mission clock)."""
    zones = []
    for z in attrition.hazard_zones:
        end_s = math.inf if z.end_s is None else z.end_s
        if z.circle is not None:
            c = z.circle.center
            zones.append(
                PlannerHazardZone(
                    z.rate_per_s,
                    center_m=(c.north_m, c.east_m),
                    radius_m=z.circle.radius_m,
                    start_s=z.start_s,
                    end_s=end_s,
                )
            )
        else:
            assert z.polygon is not None  # a circle or a polygon (the schema)
            zones.append(
                PlannerHazardZone(
                    z.rate_per_s,
                    polygon_m=tuple((v.north_m, v.east_m) for v in z.polygon),
                    start_s=z.start_s,
                    end_s=end_s,
                )
            )
    return HazardMap(tuple(zones)) if zones else None


def terrain_altitude(mission: Mission) -> TerrainAltitude | None:
    """How the station flies over a ``radio.model: terrain`` mission's DEM: ``terrain.cruise_agl_m``
    above the ground under each target, ``clearance_m`` along every path, layers capped at
    ``ceiling_agl_m`` (docs/terrain.md §6); None for the disc radio (a flat earth)."""
    if mission.radio.model != "terrain" or mission.terrain is None:
        return None
    from mission.format.terrain import build_terrain, descent_rate_m_s

    dem = build_terrain(mission)
    assert dem is not None  # a terrain section
    from planner.terrain import TerrainRadio

    spec = mission.terrain
    link = mission.radio.terrain_link
    return TerrainAltitude(
        dem,
        mission.origin.alt_amsl_m,
        clearance_m=spec.clearance_m,
        ceiling_agl_m=spec.ceiling_agl_m,
        radio=TerrainRadio(dem, link.link_budget()),
        crew_antenna_agl_m=link.crew_antenna_agl_m,
        descent_step_m=descent_rate_m_s(mission) * mission.run.control_period_s,
    )


def control_config(
    mission: Mission, scenario: MissionScenario | None = None, *, over_terrain: bool = False
) -> ControlConfig:
    """Altitude layers from the mission's flight limits; the mission's geofence, or by default the
    task field plus :data:`FENCE_MARGIN_M` (wide enough for the scenario's tracks and spawn); the
    mission's hazard zones for the planner (:func:`hazard_map`). ``over_terrain``: the station's
    flight of a terrain mission, altitudes over its DEM (:func:`terrain_altitude`)."""
    lim = mission.vehicles.limits
    half = mission.problem_config().field_half_width_m
    if scenario is not None:
        half = max(
            half,
            float(np.abs(scenario.task_track_m).max(initial=0.0)),
            float(np.abs(scenario.spawn_ne_m).max(initial=0.0)),
        )
    # The station's flights over terrain (over_terrain); the in-process world flies its own
    # terrain following (vehicle_emu.world.TerrainFlight) from the planner's 2-D moves.
    terrain = terrain_altitude(mission) if over_terrain else None
    fence = mission.geofence
    geofence = Geofence.square(
        fence.half_width_m if fence.half_width_m is not None else half + FENCE_MARGIN_M,
        fence.max_alt_m if fence.max_alt_m is not None else math.inf,
    )
    return ControlConfig(
        cruise_alt_m=lim.cruise_alt_m
        if mission.terrain is None or terrain is None
        else mission.terrain.cruise_agl_m,
        layer_spacing_m=lim.layer_spacing_m,
        n_layers=lim.n_layers,
        geofence=geofence,
        lead=1.0 + POSITION_LOOP_TAU_S / mission.run.control_period_s,
        hazards=hazard_map(mission.attrition),
        terrain=terrain,
    )

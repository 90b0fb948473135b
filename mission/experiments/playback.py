"""Playing a mission file in-process: the paper's world model, the mission's geography.

The in-process backend is the fast rehearsal of a mission (and the reference the emulator backend
is compared with). It maps the mission onto the world model of ``vehicle_emu.world``:

* one world step = one control period ``run.control_period_s``;
* drones start at the mission's spawn (ring with seeded noise, or explicit positions);
* tasks follow their tracks (sampled at every step), seeded random walks, or the ``random``
  generator; live ``mavlink`` tasks cannot be rehearsed in-process and are refused;
* attrition per drone and step: background rate, plus every hazard zone that contains the drone
  and is active, converted with p = 1 - exp(-rate * dt); scripted losses happen at their step;
* the world loop is :func:`mission.experiments.world_loop.run_world` (the one ``phireman sim`` and the sweep
  use), and each step's targets come from the station's own tick, :func:`gcs.control.tick`
  (planner -> geofence clip), through :func:`mission.experiments.world_loop.station_control`.

Random streams follow ``vehicle_emu.world.spawn_streams``: spawn noise and task walks come from the
scenario stream, attrition uniforms from the attrition stream, so the same seed gives the same run.
The drawing itself lives in :mod:`mission.format.scenario`, shared with the emulated flights.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import pathlib
import time
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from mission.format.schema import Mission
from mission.format.scenario import (  # re-exported: they were drawn here before mission.format.scenario
    MissionScenario,
    build_scenario,
    control_config,
    loss_probability,
    spawn_positions,
    task_position_fn,
    task_track_m,
    zone_mask,
)
from mission.experiments.endurance import endurance_run
from mission.experiments.world_loop import EpisodeRecord, run_world, station_control
from mission.format.terrain import descent_rate_m_s, terrain_aware_planner, terrain_radio
from planner.methods import Planner, make_planner
from planner.metrics import UptimeSeries, uptime_series
from planner.terrain import path_agl_m
from vehicle_emu.world import TerrainFlight, World, spawn_streams

__all__ = [
    "MissionScenario",
    "build_scenario",
    "spawn_positions",
    "task_track_m",
    "task_position_fn",
    "zone_mask",
    "loss_probability",
    "control_config",
    "PlaybackResult",
    "TERRAIN_AWARE",
    "terrain_flight",
    "terrain_summary",
    "run_inprocess",
    "write_run_dir",
]

log = logging.getLogger(__name__)


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
    endurance: dict | None = None
    """Rotations, failsafes, landings away, minimum battery in the air (batteries only)."""
    battery_frac: np.ndarray | None = None
    """(tau, N) battery fraction at each step (batteries only)."""
    terrain: dict | None = None
    """Over terrain: crashes, least clearance along every flight, highest height above ground
    (:func:`terrain_summary`)."""


def run_inprocess(
    mission: Mission,
    seed: int | None = None,
    frames: Collection[int] = (),
    *,
    battery: str = "mission",
    rotation: str = "mission",
    terrain_aware: str = "on",
) -> PlaybackResult:
    """Play ``mission`` on the in-process world model with its planner (one tick per control period).

    ``battery`` 'unlimited' plays a mission with batteries as if they were endless, ``rotation``
    'off' / 'on' overrides the mission's ``endurance.rotation`` (the two references of
    docs/design/endurance.md §5). ``terrain_aware`` says how a ``radio.model: terrain``
    mission is flown (:data:`TERRAIN_AWARE`, docs/terrain.md §3); the truth's links need line of
    sight whatever it says."""
    t0 = time.perf_counter()
    seed = mission.run.seed if seed is None else seed
    scn = build_scenario(mission, seed)
    problem = dataclasses.replace(
        mission.problem_config(), n_drones=len(scn.spawn_ne_m), n_tasks=scn.task_track_m.shape[1]
    )
    params = mission.planner.run_params()
    planner = make_planner(mission.planner.method, problem, params, spawn_streams(seed).algorithm)
    world = World(
        problem, scn.spawn_ne_m.copy(), np.ones(len(scn.spawn_ne_m), bool), scn.task_track_m
    )
    flight = terrain_flight(mission, terrain_aware)
    if flight is not None:
        if mission.endurance.battery is not None:
            raise ValueError("a terrain radio with batteries is not supported yet")
        world.with_terrain(flight)
        planner = terrain_planner(
            planner, mission, flight, terrain_aware, problem.max_speed_m_s * problem.dt_s
        )
    tau = mission.run.n_steps
    task_dist_m = np.hypot(*scn.task_track_m.reshape(-1, 2).T)
    endurance = endurance_run(
        mission.endurance,
        len(scn.spawn_ne_m),
        mission.run.duration_s,
        scn.dt_s,
        mission.vehicles.limits.max_speed_m_s,
        mean_post_dist_m=0.5 * float(task_dist_m.mean()) if task_dist_m.size else 0.0,
        battery=battery,
        rotation=rotation,
    )
    # Targets as the station computes them (gcs.control.tick: planner, then the mission's fence).
    run = run_world(
        world,
        planner,
        tau,
        scn.step_loss_probability,
        scn.attrition_u,
        controller=station_control(control_config(mission, scn)),
        record=True,
        frames=set(frames) or None,
        endurance=endurance,
    )
    rec = run.record
    assert rec is not None  # record=True
    dt = scn.dt_s
    losses = [
        {
            "t_s": (t + 1) * dt,
            "event": "vehicle_lost",
            "index": i,
            "scripted": bool(scn.scripted_step[i] == t),
            "north_m": float(rec.pos_m[t + 1, i, 0]),
            "east_m": float(rec.pos_m[t + 1, i, 1]),
        }
        for t, i in run.losses
    ]
    series = uptime_series(rec.connected[:tau])
    result = PlaybackResult(
        seed, series.tu1, series.tu2, series, rec, losses, time.perf_counter() - t0, scn.task_names
    )
    if flight is not None:
        result.terrain = terrain_summary(flight, rec, world.terrain_crashes)
    if endurance is not None:
        result.endurance = endurance.summary()
        result.battery_frac = np.array(endurance.battery_log)
        result.losses += [
            {"t_s": e.t_s, "event": e.kind, "index": e.drone, "other": e.other}
            for e in endurance.events
        ]
        result.losses.sort(key=lambda ev: ev["t_s"])
    return result


#: How a terrain mission is flown (docs/terrain.md §3): 'off' is today's system (the disc planner,
#: every drone at ``vehicles.cruise_alt_m`` above the base's ground); 'altitude' the disc planner
#: with terrain following at ``terrain.cruise_agl_m`` under the ceiling; 'on' planning in 3-D:
#: each drone's altitude between the clearance and the ceiling chosen by the planner, its moves
#: checked against the terrain radio and relay positions searched (planner.terrain_aware).
TERRAIN_AWARE: tuple[str, ...] = ("on", "altitude", "off")


def terrain_flight(mission: Mission, terrain_aware: str) -> TerrainFlight | None:
    """How drones fly and talk over the mission's terrain (None: the disc radio): terrain
    following at ``terrain.cruise_agl_m`` unless ``terrain_aware`` is 'off', then one altitude,
    ``vehicles.cruise_alt_m`` above the base's ground (docs/terrain.md §3)."""
    if terrain_aware not in TERRAIN_AWARE:
        raise ValueError(f"terrain_aware must be one of {', '.join(TERRAIN_AWARE)}")
    if mission.radio.model != "terrain":
        return None
    spec = mission.terrain
    assert spec is not None  # radio.model terrain needs a terrain section (validated)
    radio = terrain_radio(mission)
    assert radio is not None  # radio.model terrain
    ground = radio.terrain
    link = mission.radio.terrain_link
    lim = mission.vehicles.limits
    base_ground_m = float(ground.height_m(np.zeros((1, 2)))[0])
    return TerrainFlight(
        radio,
        mode="flat" if terrain_aware == "off" else "follow",
        alt_agl_m=spec.cruise_agl_m,
        flat_alt_amsl_m=base_ground_m + lim.cruise_alt_m,
        clearance_m=spec.clearance_m,
        ceiling_agl_m=spec.ceiling_agl_m,
        max_climb_m=lim.climb_rate_m_s * mission.run.control_period_s,
        max_descent_m=descent_rate_m_s(mission) * mission.run.control_period_s,
        crew_antenna_agl_m=link.crew_antenna_agl_m,
        base_antenna_agl_m=link.base_antenna_agl_m,
    )


def terrain_planner(
    planner: Planner, mission: Mission, flight: TerrainFlight, terrain_aware: str, max_step_m: float
) -> Planner:
    """The mission's planner over terrain: as it is when terrain-blind; when ``terrain_aware``
    is 'on', planning in 3-D (:func:`mission.format.terrain.terrain_aware_planner`, as the station
    plans). ``max_step_m``: the longest horizontal move in one step, metres."""
    if terrain_aware != "on":
        return planner
    return terrain_aware_planner(planner, mission, flight.radio, max_step_m)


def terrain_summary(flight: TerrainFlight, rec: EpisodeRecord, crashes: int) -> dict:
    """Crashes into the ground; along every flight of a drone alive at its start (one step,
    128 samples): the least height above the ground (metres) and how many such flights passed
    lower than the terrain's ``clearance_m``, the highest height above the ground (metres) and
    how many flights (``flights_above_ceiling``) and drones (``drones_above_ceiling``) went
    higher than its ``ceiling_agl_m``."""
    assert rec.alt_amsl_m is not None  # recorded in terrain worlds
    ground = flight.radio.terrain
    tau = len(rec.pos_m) - 1
    least, highest, below, above = np.inf, -np.inf, 0, 0
    high_drones = np.zeros(rec.alive.shape[1], dtype=bool)
    for t in range(tau):  # loop over time; vectorised over drones
        live = rec.alive[t]
        if live.any():
            agl = path_agl_m(
                ground,
                rec.pos_m[t][live],
                rec.pos_m[t + 1][live],
                rec.alt_amsl_m[t][live],
                rec.alt_amsl_m[t + 1][live],
                n_samples=128,
            )
            c, h = agl.min(axis=1), agl.max(axis=1)
            least, highest = min(least, float(c.min())), max(highest, float(h.max()))
            below += int((c < flight.clearance_m).sum()) if flight.mode == "follow" else 0
            over = h > flight.ceiling_agl_m + 1e-6
            above += int(over.sum())
            high_drones[np.flatnonzero(live)[over]] = True
    return {
        "mode": flight.mode,
        "crashes": int(crashes),
        "min_clearance_m": least,
        "flights_below_clearance": below,
        "max_agl_m": highest if np.isfinite(highest) else 0.0,
        "flights_above_ceiling": above,
        "drones_above_ceiling": int(high_drones.sum()),
    }


def write_run_dir(
    mission: Mission, result: PlaybackResult, out_dir: pathlib.Path, backend: str = "inprocess"
) -> None:
    """Record a played mission: resolved mission, seed, code version, events, metrics, truth, summary."""
    from mission.format.load import dump_mission
    from mission.format.version import code_version

    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "mission.yaml").write_text(
        dump_mission(mission, header=f"resolved mission, seed {result.seed}")
    )
    with open(out_dir / "events.jsonl", "w") as fh:
        for ev in result.losses:
            fh.write(json.dumps(ev) + "\n")
    rec, s = result.record, result.series
    tau = len(s.tu1_step)
    with open(out_dir / "metrics.csv", "w") as fh:
        fh.write("t_s,alive,active,tasks_connected,tasks_ever_connected,tu1_so_far,tu2_so_far\n")
        for t in range(tau):
            fh.write(
                f"{t * mission.run.control_period_s:g},{int(rec.alive[t].sum())},{int(rec.active[t].sum())},"
                f"{int(s.n_connected[t])},{int(s.n_ever_connected[t])},"
                f"{s.tu1_step[: t + 1].mean():.6f},{s.tu2_step[: t + 1].mean():.6f}\n"
            )
    truth: dict[str, np.ndarray] = {
        "t_s": np.arange(tau + 1) * mission.run.control_period_s,
        "pos_ne_m": rec.pos_m,
        "alive": rec.alive,
        "active": rec.active,
        "task_pos_ne_m": rec.task_pos_m,
        "task_connected": rec.connected,
    }
    if rec.alt_amsl_m is not None:  # over terrain: the drones' heights AMSL
        truth["alt_amsl_m"] = rec.alt_amsl_m
    np.savez_compressed(out_dir / "truth.npz", **truth)  # type: ignore[arg-type]  # names -> arrays
    trees = {
        str(t): {
            "nodes_ne_m": tr.nodes_m.tolist(),
            "parent": tr.parent.tolist(),
            "n_tasks": tr.n_tasks,
        }
        for t, tr in rec.trees.items()
        if tr is not None
    }
    (out_dir / "trees.json").write_text(json.dumps(trees))
    summary = {
        "backend": backend,
        "mission": mission.name,
        "seed": result.seed,
        "code_version": code_version(),
        "tu1": result.tu1,
        "tu2": result.tu2,
        "truth_tu1": result.tu1,
        "truth_tu2": result.tu2,
        "n_losses": sum(ev["event"] == "vehicle_lost" for ev in result.losses),
        "final_alive": int(rec.alive[-1].sum()),
        "final_active": int(rec.active[-1].sum()),
        "wall_s": result.wall_s,
        "task_names": result.task_names,
    }
    if result.endurance is not None:
        summary["endurance"] = result.endurance
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))

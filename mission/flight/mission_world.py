"""The emulator built for a mission, and the mission's world rules applied to it.

* :func:`mission_scenario` - the seed's draws for a flight (:func:`mission.format.scenario.build_scenario`,
  the one mission scenario type, with the runner's error for live tasks);
* :func:`control_config` - the station's altitude layers and geofence for the mission
  (defined in :mod:`mission.format.scenario`, re-exported);
* :func:`build_swarm` - the emulator (:class:`vehicle_emu.swarm.Swarm`) for the mission;
* :class:`MissionWorld` - attrition, scripted losses, hazard zones and task motion applied to
  that emulator on the mission clock (runner side: never visible to the station).
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from mission.flight.fly_options import RunnerError
from mission.format.scenario import (  # re-exported: importers of mission.flight.mission_world
    FENCE_MARGIN_M,
    POSITION_LOOP_TAU_S,
    MissionScenario,
    build_scenario,
    control_config,
)
from mission.format.schema import Mission
from planner.metrics import task_uptime
from vehicle_emu.battery import BatteryConfig, SwapConfig
from vehicle_emu.radio import RadioConfig
from vehicle_emu.swarm import Swarm
from vehicle_emu.terrain import Ground

__all__ = [
    "MissionScenario",
    "mission_scenario",
    "control_config",
    "build_swarm",
    "mission_ground",
    "terrain_spacing_m",
    "MissionWorld",
    "FENCE_MARGIN_M",
    "POSITION_LOOP_TAU_S",
]

log = logging.getLogger(__name__)


def _speed_params(
    personalities: list[str],
    max_speed_m_s: float,
    climb_rate_m_s: float,
    descent_rate_m_s: float | None,
    user: dict | None,
) -> dict:
    """Per-vehicle parameters that make the emulated autopilots fly the mission's limits from
    boot, as the station would set them on real vehicles (:func:`gcs.limits.limit_params`, so
    the station finds nothing to write). Explicit overrides (``params``) win."""
    from gcs.autopilot import ARDUPILOT, PX4
    from gcs.limits import limit_params

    user = user or {}
    out = {}
    for i, p in enumerate(personalities):
        want = limit_params(
            ARDUPILOT if p == "ardupilot" else PX4, max_speed_m_s, climb_rate_m_s, descent_rate_m_s
        )
        out[i] = {k: v for k, v in want.items() if k not in user}
    return out


def _battery(mission: Mission, max_speed_m_s: float, climb_rate_m_s: float):
    """The emulator's packs and ground crew for the mission's ``endurance`` section (None, None:
    endless batteries). docs/design/endurance.md §6."""
    spec = mission.endurance.battery
    if spec is None:
        return None, None
    battery = BatteryConfig(
        hover_endurance_s=spec.endurance_s,
        speed_drain_frac=spec.speed_drain_frac,
        ref_speed_m_s=max_speed_m_s,
        ref_climb_m_s=climb_rate_m_s,
    )
    return battery, SwapConfig(swap_time_s=mission.endurance.base.resources().swap_time_s)


def mission_scenario(
    mission: Mission, seed: int | None = None, *, live_tasks: bool = False
) -> MissionScenario:
    """The seed's draws for a flight of ``mission`` (:func:`mission.format.scenario.build_scenario`:
    spawn, task tracks, attrition uniforms, in the in-process simulator's order); a live MAVLink
    task without ``live_tasks`` is a :class:`RunnerError`. TAK crews are always NaN columns: every
    flight, emulated or real, fills them from the crews' reports (gcs.tak)."""
    try:
        return build_scenario(mission, seed, live_tasks=live_tasks, tak=True)
    except ValueError as exc:  # live MAVLink tasks
        raise RunnerError(str(exc)) from None


def _personalities(mission: Mission, override: str | None) -> list[str]:
    n = mission.vehicles.count
    p = override or (
        mission.vehicles.emulated.personality if mission.vehicles.emulated else "ardupilot"
    )
    if p == "mixed":
        return ["ardupilot" if i % 2 == 0 else "px4" for i in range(n)]
    if p not in ("ardupilot", "px4"):
        raise RunnerError(f"unknown personality {p!r}; valid: ardupilot, px4, mixed")
    return [p] * n


class _MissionSwarm(Swarm):
    """A swarm whose full autopilot/physics tick runs at ``tick_s`` cadence only.

    ``Swarm.next_timer_s`` also wakes for every radio-delayed packet; the base class then runs a
    whole tick (every core, physics, radio) per delivery, which at 50 vehicles, per-hop latency
    and a 20x speed-up multiplies the emulator's CPU several times and starves its sockets.
    Between ticks only the delayed packets are delivered here.
    """

    def handle_timer(self, now_s: float) -> None:
        if self.stats["ticks"] and now_s < self.now_s + self.tick_s - 1e-9:
            self._deliver_delayed(now_s, inbound=True)
            return
        super().handle_timer(now_s)

    step = handle_timer


def build_swarm(
    mission: Mission,
    scenario: MissionScenario,
    *,
    seed: int,
    personality: str | None = None,
    unix_time_at_zero_s: float = 1.7e9,
    mux: bool = True,
    params: dict | None = None,
    tick_s: float = 0.05,
) -> Swarm:
    """The emulator for ``mission``: count, personality, spawn, radio, flight limits.

    Attrition is *not* armed here: :class:`MissionWorld` switches it on when the station starts
    the mission (take-off is not part of the paper's horizon), then applies the background rate,
    the scripted losses and the hazard zones on the mission clock.
    """
    if mission.vehicles.emulated is None:
        raise RunnerError(
            "the mission flies real vehicles (vehicles.real); use --connect or an emulated mission"
        )
    emu = mission.vehicles.emulated
    radio = RadioConfig(
        radio_range_m=emu.radio_range_m or mission.radio.range_m,
        base_range_m=mission.radio.base_range_m,
        latency_per_hop_s=mission.radio.latency_s,
        loss_per_hop=min(mission.radio.loss_prob, 0.999),
    )
    o = mission.origin
    ground = mission_ground(mission)
    down = (
        np.zeros(len(scenario.spawn_ne_m))
        if ground is None
        else ground.ground_down_m(scenario.spawn_ne_m)  # on the ground under each spawn point
    )
    spawn = np.column_stack([scenario.spawn_ne_m, down])
    pers = _personalities(mission, personality)
    battery, swap = _battery(mission, emu.max_speed_m_s, emu.climb_rate_m_s)
    swarm = _MissionSwarm(
        emu.count,
        personality=pers,
        per_vehicle_params=_speed_params(
            pers, emu.max_speed_m_s, emu.climb_rate_m_s, emu.descent_rate_m_s, params
        ),
        home_lla=(o.lat_deg, o.lon_deg, o.alt_amsl_m),
        spawn_ned_m=spawn,
        radio=radio,
        hazard_per_s=0.0,
        task_pos_fn=None,
        mux=mux,
        params=params,
        rng=np.random.default_rng(np.random.SeedSequence([int(seed), 0xE1])),
        truth_period_s=mission.run.control_period_s,
        unix_time_at_zero_s=unix_time_at_zero_s,
        max_speed_h_m_s=emu.max_speed_m_s,
        tick_s=tick_s,
        radio_period_s=0.2,
        battery=battery,
        battery_swap=swap,
        ground=ground,
        terrain_spacing_m=terrain_spacing_m(mission),
    )
    swarm.physics.climb_rate_m_s[:] = emu.climb_rate_m_s
    return swarm


def mission_ground(mission: Mission) -> Ground | None:
    """The emulator's terrain for a ``radio.model: terrain`` mission (its DEM and the terrain
    radio, docs/terrain.md §5); None for the disc radio and a flat earth."""
    if mission.radio.model != "terrain":
        return None
    from mission.format.terrain import build_terrain
    from planner.terrain import TerrainRadio

    dem = build_terrain(mission)
    assert dem is not None  # radio.model terrain needs a terrain section (validated)
    link = mission.radio.terrain_link
    return Ground(
        TerrainRadio(dem, link.link_budget()),
        mission.origin.alt_amsl_m,
        base_antenna_agl_m=link.base_antenna_agl_m,
        crew_antenna_agl_m=link.crew_antenna_agl_m,
    )


def terrain_spacing_m(mission: Mission) -> int:
    """TERRAIN_SPACING of the emulated ArduPilots: the DEM's post spacing (whole metres, at
    least 1), so the vehicles hold the map at the resolution the station has it; 100 (the
    firmware's default) without terrain."""
    spec = mission.terrain
    if spec is None:
        return 100
    spacing = spec.synthetic.spacing_m if spec.synthetic is not None else None
    if spacing is None and spec.geotiff is not None:
        spacing = spec.geotiff.spacing_m
    return max(1, int(round(spacing or 100)))


class MissionWorld:
    """The mission's world rules applied to the emulator on the mission clock (runner side):
    attrition switched on at mission start, scripted losses, hazard zones, task motion for the
    ground truth. Never visible to the station.

    Losses follow the in-process world's draws (common random numbers, docs/design/model.md §6.1): at
    mission step ``t`` vehicle ``i`` is lost iff ``u[t, i] < p_i(t)``, with the uniforms of
    :func:`mission.format.scenario.build_scenario` (the run's attrition stream) and the per-step
    probability of :meth:`MissionScenario.loss_probability` (background rate plus the active
    hazard zones containing the vehicle, from its true position at the step). The loss takes
    effect half a step later (the in-process world measures connectivity, then attrits, then
    moves), through the emulator's kill hook. Scripted losses happen at their exact times.
    The truth is sampled on the mission's step grid ``t0 + k * dt``, so both backends integrate
    TU1/TU2 over the same ``duration / dt`` instants of ``[0, duration)``.
    """

    def __init__(
        self, mission: Mission, scenario: MissionScenario, swarm: Swarm, seed: int | None = None
    ) -> None:
        self.mission = mission
        self.scenario = scenario
        self.swarm = swarm
        self.t0_s: float | None = None
        # ``seed`` is accepted for older callers: the uniforms are the scenario's, drawn from the
        # seed the scenario was built with (one drawing, mission.format.scenario.build_scenario).
        del seed
        self._attrition_u = scenario.attrition_u
        self._step = 0
        self._stopped = False
        self._doomed = np.zeros(swarm.n, dtype=bool)
        self._ground_safe = mission.endurance.battery is not None
        self.losses: list[tuple[float, int, str]] = []
        swarm.task_pos_fn = self._task_pos
        # Sample 0 was recorded without tasks; restart the truth log with tasks from here on.
        tr = swarm.truth
        tr.t_s.clear()
        tr.pos_ned_m.clear()
        tr.alive.clear()
        tr.active.clear()
        tr.task_connected.clear()

    def _task_pos(self, t_s: float) -> np.ndarray:
        return self.scenario.task_pos_m(0.0 if self.t0_s is None else t_s - self.t0_s)

    def start(self, t0_s: float) -> None:
        """The station began the mission at emulator time ``t0_s``."""
        self.t0_s = t0_s
        self.swarm.track_clearance = True  # over terrain: least height above it, mission only
        if self.mission.terrain is not None:  # counted once at 90 % of the cruise height
            self.swarm.clearance_from_agl_m = 0.9 * self.mission.terrain.cruise_agl_m
        self.swarm.attrition.hazard_per_s = np.zeros(self.swarm.n)
        for loss in self.mission.attrition.scripted:
            if loss.vehicle < self.swarm.n:
                self.swarm.attrition.add_kill(t0_s + loss.t_s, loss.vehicle)
                self._doomed[loss.vehicle] = True
                self.losses.append((loss.t_s, loss.vehicle, "scripted"))
        # The launch's truth grid may already hold a sample at (or after) t0; the mission's grid
        # starts with its own sample there, so drop it (else the first instant counted twice).
        tr = self.swarm.truth
        while tr.t_s and tr.t_s[-1] >= t0_s - 1e-9:
            tr.t_s.pop()
            for column in (tr.pos_ned_m, tr.alive, tr.active, tr.task_connected):
                del column[len(tr.t_s) :]
        self.swarm.sample_truth_from(t0_s)
        self.poll(self.swarm.now_s)
        log.info("mission world started at t=%.2f s", t0_s)

    def poll(self, now_s: float) -> None:
        """Draw the losses of every mission step that has begun (call at least every dt/2)."""
        if self.t0_s is None or self._stopped:
            return
        dt = self.mission.run.control_period_s
        u = self._attrition_u
        while self._step < len(u) and now_s >= self.t0_s + self._step * dt - 1e-9:
            t = self._step
            pos = self.swarm.physics.pos_ned_m[:, :2]
            p = self.scenario.loss_probability(t * dt, pos)
            ph = self.swarm.physics
            hit = ph.alive & ~self._doomed & (u[t] < p)
            if self._ground_safe:
                # With batteries, a drone on the ground (a spare, one on a pad) is out of the
                # mesh and safe from attrition, as in the paper's world with endurance
                # (mission.experiments.world_loop, docs/design/endurance.md §5).
                hit &= ph.armed & ~ph.landed
            for i in np.flatnonzero(hit).tolist():
                self._doomed[i] = True
                self.swarm.attrition.add_kill(self.t0_s + (t + 0.5) * dt, i)
                self.losses.append(((t + 0.5) * dt, i, "attrition"))
            self._step += 1

    def stop_attrition(self) -> None:
        """The mission is over: no more random losses (the end is not part of the horizon)."""
        self._stopped = True
        self.swarm.track_clearance = False
        self.t_end_s = self.swarm.now_s

    def report(self, duration_s: float) -> dict:
        """Ground truth for the summary and ``truth.npz`` (plain, picklable); TU over the first
        ``duration_s`` of the mission (the span flown: all of it, or up to Ctrl-C)."""
        truth = self.truth_tu(duration_s)
        truth["alive_end"] = int(self.swarm.alive.sum())
        arrays: dict[str, Any] = self.swarm.truth.arrays()
        arrays.update(
            mission_t0_s=np.float64(np.nan if self.t0_s is None else self.t0_s),
            sysid_of_index=self.swarm.sysid_of_index,
            network_of_index=self.swarm.network_of_index,
        )
        stats: dict[str, Any] = dict(self.swarm.stats)
        stats["cpu_s"] = time.process_time()
        if self.swarm.ground is not None:
            stats["least_agl_m"] = self.swarm.least_agl_m
            stats["highest_agl_m"] = self.swarm.highest_agl_m
        return {"truth": truth, "stats": stats, "arrays": arrays}

    def truth_tu(self, duration_s: float) -> dict:
        """Ground-truth TU1/TU2 over the truth samples in [t0, t0 + duration)."""
        tr = self.swarm.truth
        if self.t0_s is None or not tr.task_connected:
            return {"tu1": None, "tu2": None, "samples": 0, "span_s": duration_s}
        t = np.asarray(tr.t_s)
        sel = (t >= self.t0_s - 1e-9) & (t < self.t0_s + duration_s - 1e-9)
        conn = np.asarray(tr.task_connected)[sel]
        if len(conn) == 0:
            return {"tu1": None, "tu2": None, "samples": 0, "span_s": duration_s}
        tu1, tu2 = task_uptime(conn)
        return {"tu1": tu1, "tu2": tu2, "samples": int(len(conn)), "span_s": duration_s}

"""The one world loop: measure -> plan -> attrit -> step, for every in-process driver.

``phireman sim`` and the sweep (:func:`mission.experiments.sim.run_episode`, the paper's world) and the
in-process playback of a mission file (:func:`mission.experiments.playback.run_inprocess`) both call
:func:`run_world`. One step is (docs/design/model.md §4, §7 #2, #16):

1. measure: active drones D'(t) and connected tasks A(t) (the metrics' left Riemann sum);
2. control: the *controller* turns the world's truth into a displacement per drone;
3. attrition: drone i is lost iff ``u[t, i] < p_i(t)`` (one uniform per drone and step);
4. execute: active drones follow the displacement, disconnected ones fly home (or to the
   controller's recovery target), lost ones stop; tasks move on their pre-drawn tracks.

Controllers (the hook that differs between drivers):

* :func:`direct_control` (default) - the planner's displacement as is, and the planner's rally
  points (``recovery_target_m``, ``planner.resilient``) as the world's recovery rule: the
  paper's world, which has no geofence;
* :func:`station_control` - the ground station's own per-tick function, :func:`gcs.control.tick`
  (planner -> geofence clip -> targets), as a mission flown by the station computes its targets;
  the world then moves each active drone to its target.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from gcs.control import ControlConfig, tick as control_tick
from mission.experiments.endurance import EnduranceRun
from planner.hazard import HazardMap
from planner.methods import PlanOutput, Planner, TickInput
from vehicle_emu.world import World

__all__ = [
    "EpisodeRecord",
    "ControlOutput",
    "Controller",
    "WorldRun",
    "direct_control",
    "station_control",
    "run_world",
]

#: ``(t_step, pos_m) -> (N,) loss probability`` of one step, or one probability for every drone.
LossProb = float | Callable[[int, np.ndarray], np.ndarray]


@dataclass
class EpisodeRecord:
    """Full trajectories of one episode (for plots and replay)."""

    pos_m: np.ndarray  # (tau+1, N, 2)
    alive: np.ndarray  # (tau+1, N) bool
    active: np.ndarray  # (tau+1, N) bool
    task_pos_m: np.ndarray  # (tau+1, M, 2)
    connected: np.ndarray  # (tau+1, M) bool
    trees: dict = field(default_factory=dict)  # step -> TaskTree (metres), at recorded frames
    alt_amsl_m: np.ndarray | None = None  # (tau+1, N) drone heights AMSL, terrain worlds only


@dataclass(frozen=True)
class ControlOutput:
    """What a controller decided for one step."""

    disp_m: np.ndarray
    """(N, 2) displacement per drone this step, metres (the world uses the active rows only)."""
    tree: Any = None
    """The planner's task tree this step (for plots), or None."""
    recovery_target_m: np.ndarray | None = None
    """(N, 2) where disconnected drones fly instead of the base (NaN rows: the base), or None."""
    alt_agl_m: np.ndarray | None = None
    """(N,) the height above the ground each drone should hold over terrain, metres (the
    planner's ``PlanOutput.alt_agl_m``), or None: the terrain flight's one cruise height."""


class Controller(Protocol):
    def __call__(self, planner: Planner, tick: TickInput) -> ControlOutput: ...


def direct_control(planner: Planner, tick: TickInput) -> ControlOutput:
    """The paper's world: the planner's displacement as is (no fence); a planner that publishes
    rally points (``planner.resilient``) switches the world's recovery rule for its disconnected
    drones, every other planner leaves it at "fly home" (docs/design/model.md §4)."""
    out = planner.plan(tick)
    return ControlOutput(
        out.disp_m, out.tree, getattr(planner, "recovery_target_m", None), out.alt_agl_m
    )


class _Keep:
    """A planner that remembers its last answer (:func:`gcs.control.tick` returns no tree), and
    is told the drones' altitudes over terrain (``alt_amsl_m``), as a station reads them from
    telemetry: the station's tick plans in the plane."""

    def __init__(self, planner: Planner, alt_amsl_m: np.ndarray | None = None) -> None:
        self.planner = planner
        self.alt_amsl_m = alt_amsl_m
        self.last: PlanOutput | None = None

    def plan(self, tick: TickInput) -> PlanOutput:
        if self.alt_amsl_m is not None:
            tick = dataclasses.replace(tick, alt_amsl_m=self.alt_amsl_m)
        self.last = self.planner.plan(tick)
        return self.last


def station_control(config: ControlConfig) -> Controller:
    """The station's tick (:func:`gcs.control.tick`) as the world's controller.

    The world's vehicle reaches its target within the step (it has no position loop), so the
    target's lead is 1: the autopilot lag that ``ControlConfig.lead`` makes up for does not
    exist here, and a lead above 1 would move every drone ``lead`` times its planned step.
    Disconnected drones fly home: the station cannot reach them, and their autopilot's
    GCS-loss failsafe returns them to launch (no rally points are uploaded).
    """
    config = dataclasses.replace(config, lead=1.0)

    def control(planner: Planner, tick: TickInput) -> ControlOutput:
        keep = _Keep(planner, tick.alt_amsl_m)
        pos_ned_m = np.column_stack([tick.pos_m, np.zeros(len(tick.pos_m))])
        res = control_tick(
            pos_ned_m, tick.networked, tick.alive, tick.task_pos_m, keep, tick.t_step, config
        )
        disp = np.zeros_like(tick.pos_m)
        disp[res.rows] = res.target_ned_m[:, :2] - tick.pos_m[res.rows]
        last = keep.last
        return ControlOutput(
            disp,
            last.tree if last is not None else None,
            None,
            last.alt_agl_m if last is not None else None,
        )

    return control


@dataclass
class WorldRun:
    """What :func:`run_world` measured."""

    connected: np.ndarray
    """(tau + 1, M) bool: tasks connected at each measured instant (row tau: after the last step)."""
    alive_count: np.ndarray
    """(tau,) alive drones at each measured step."""
    active_count: np.ndarray
    """(tau,) alive and active drones at each measured step."""
    losses: list[tuple[int, int]]
    """(step, row) of every drone lost, in order (lost during step ``t``: gone at ``t + 1``)."""
    record: EpisodeRecord | None
    """Trajectories, with ``record=True``."""


def run_world(
    world: World,
    planner: Planner,
    n_steps: int,
    loss_prob: LossProb,
    attrition_u: np.ndarray,
    *,
    controller: Controller | None = None,
    record: bool = False,
    frames: Collection[int] | None = (),
    hazards: HazardMap | None = None,
    endurance: EnduranceRun | None = None,
) -> WorldRun:
    """Run ``world`` for ``n_steps`` steps under ``planner``.

    Parameters
    ----------
    world : the truth, at step 0 (advanced in place)
    planner : a planner from :func:`planner.methods.make_planner`
    n_steps : steps to run (tau)
    loss_prob : per-step loss probability, one float for every drone and step, or
        ``(t_step, pos_m) -> (N,)`` from the positions at the start of the step
    attrition_u : (>= tau, N) uniforms of the attrition stream
    controller : the step's control (:func:`direct_control` when None)
    record : keep trajectories in ``WorldRun.record``
    frames : steps at which to keep the task tree (with ``record``); None keeps every step
    hazards : the mission's hazard zones, given to the planner in every ``TickInput`` (None: no
        zones, the paper's world); :func:`station_control` passes its ``ControlConfig.hazards``
    endurance : batteries and relay rotation (:mod:`mission.experiments.endurance`); None: endless
        batteries, every alive drone planned (the paper's world, untouched)
    """
    control = direct_control if controller is None else controller
    tau = int(n_steps)
    n, m = len(world.pos_m), world.task_track_m.shape[1]
    if len(attrition_u) < tau:
        raise ValueError(f"{len(attrition_u)} rows of attrition uniforms for {tau} steps")
    connected = np.zeros((tau + 1, m), dtype=bool)
    alive_count = np.zeros(tau, dtype=np.int64)
    active_count = np.zeros(tau, dtype=np.int64)
    losses: list[tuple[int, int]] = []
    rec = None
    if record:
        rec = EpisodeRecord(
            np.zeros((tau + 1, n, 2)),
            np.zeros((tau + 1, n), bool),
            np.zeros((tau + 1, n), bool),
            world.task_track_m.copy(),
            connected,
        )
        if world.alt_amsl_m is not None:
            rec.alt_amsl_m = np.zeros((tau + 1, n))
    keep_tree = (lambda t: True) if frames is None else set(frames).__contains__
    for t in range(tau + 1):
        active = world.active()
        connected[t] = world.tasks_connected(active)
        if rec is not None:
            rec.pos_m[t], rec.alive[t], rec.active[t] = world.pos_m, world.alive, active
            if rec.alt_amsl_m is not None:
                rec.alt_amsl_m[t] = world.alt_amsl_m
        if t == tau:
            break
        alive_count[t], active_count[t] = world.alive.sum(), active.sum()
        if endurance is not None:
            lost, tree = _endurance_step(
                t, world, planner, control, active, loss_prob, attrition_u[t], hazards, endurance
            )
            if rec is not None and keep_tree(t):
                rec.trees[t] = tree
            losses.extend((t, int(i)) for i in np.flatnonzero(lost))
            continue
        out = control(
            planner,
            TickInput(
                t,
                world.pos_m,
                world.alive,
                active,
                world.task_pos_m,
                world.base_m,
                hazards,
                world.alt_amsl_m,
            ),
        )
        if rec is not None and keep_tree(t):
            rec.trees[t] = out.tree
        p_loss = loss_prob(t, world.pos_m) if callable(loss_prob) else loss_prob
        pos_before = world.pos_m if world.terrain is not None else None
        lost = world.step(out.disp_m, active, p_loss, attrition_u[t], out.recovery_target_m)
        if pos_before is not None:  # over terrain: heights, and flights into the ground
            lost = lost | world.fly_terrain(pos_before, alt_agl_m=out.alt_agl_m)
        losses.extend((t, int(i)) for i in np.flatnonzero(lost))
    return WorldRun(connected, alive_count, active_count, losses, rec)


def _endurance_step(
    t: int,
    world: World,
    planner: Planner,
    control: Controller,
    active: np.ndarray,
    loss_prob: LossProb,
    attrition_u: np.ndarray,
    hazards: HazardMap | None,
    endurance: EnduranceRun,
) -> tuple[np.ndarray, Any]:
    """One step with batteries (:mod:`mission.experiments.endurance`): the rotation policy decides
    who the planner plans; spares, returning drones and drones on the ground go where the policy
    says; the ground is safe from attrition; the batteries drain and the firmware's failsafes act.
    Returns (N,) bool, the drones lost this step (attrition or a critical-battery landing), and
    the planner's tree."""
    rot = endurance.before_step(t, world, active)
    planned = rot.planned & world.alive
    out = control(
        planner,
        TickInput(
            t, world.pos_m, planned, active & planned, world.task_pos_m, world.base_m, hazards
        ),
    )
    target = rot.target_m.copy()
    if out.recovery_target_m is not None:  # a planner's rally points, for its planned drones
        target[planned] = np.asarray(out.recovery_target_m, float)[planned]
    grounded = world.grounded if world.grounded is not None else np.zeros(len(planned), bool)
    p_loss = loss_prob(t, world.pos_m) if callable(loss_prob) else loss_prob
    p_loss = np.where(grounded, 0.0, p_loss)
    pos_before = world.pos_m.copy()
    lost = world.step(out.disp_m, active & planned, p_loss, attrition_u, target)
    return lost | endurance.after_step(t, world, pos_before), out.tree

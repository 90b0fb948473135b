"""The paper's world model: the ground truth of an RTNUA episode (docs/design/model.md §4, §7).

Everything here is vectorised over drones and tasks. The world owns positions, the alive mask,
attrition and task motion; "active" (networked) is recomputed exactly every step with
:func:`planner.geometry.active_mask` (the same function the emulator's radio uses).

Random streams (common random numbers, docs/design/model.md §6.1): a run's integer ``seed`` is split by
:class:`numpy.random.SeedSequence` into three independent children,

* ``scenario``  ring noise, initial task positions and every task random-walk increment,
* ``attrition`` one uniform per drone per step (drone i dies at step t iff u[t, i] < p_i(t)),
* ``algorithm`` anything a planner draws,

so two methods run on the same seed see the same tasks and the same attrition draws.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.geometry import active_mask, bounded_moves, step_toward, tasks_connected
from planner.problem import ProblemConfig

__all__ = ["Scenario", "RunStreams", "spawn_streams", "draw_scenario", "walk_tasks", "World"]


@dataclass(frozen=True)
class RunStreams:
    """The three independent generators of one run."""

    scenario: np.random.Generator
    attrition: np.random.Generator
    algorithm: np.random.Generator


def spawn_streams(seed: int) -> RunStreams:
    """Split ``seed`` into the scenario / attrition / algorithm streams (fixed order, stable)."""
    s_scn, s_att, s_alg = np.random.SeedSequence(int(seed)).spawn(3)
    return RunStreams(
        np.random.default_rng(s_scn), np.random.default_rng(s_att), np.random.default_rng(s_alg)
    )


@dataclass(frozen=True)
class Scenario:
    """Everything random about one episode, drawn up front."""

    drone_pos0_m: np.ndarray
    """(N, 2) initial drone positions, metres."""
    task_track_m: np.ndarray
    """(tau + 1, M, 2) task positions at every step, metres."""
    attrition_u: np.ndarray
    """(tau, N) uniforms in [0, 1): drone i is lost at step t iff u[t, i] < p."""


def walk_tasks(
    start_m: np.ndarray, increments_m: np.ndarray, half_width_m: float, border: str
) -> np.ndarray:
    """Integrate a Gaussian random walk with a border policy.

    Parameters
    ----------
    start_m : (M, 2) initial positions, metres
    increments_m : (tau, M, 2) per-step increments, metres
    half_width_m : field is [-w, w]^2
    border : 'none' (unbounded), 'clip' (stop at the border) or 'reflect' (mirror back in)

    Returns
    -------
    (tau + 1, M, 2) positions, metres
    """
    if border == "none":
        return np.concatenate([start_m[None], start_m[None] + np.cumsum(increments_m, axis=0)])
    out = np.empty((len(increments_m) + 1,) + start_m.shape)
    out[0] = start_m
    w = half_width_m
    for t, inc in enumerate(increments_m):  # loop over time only; vectorised over tasks
        nxt = out[t] + inc
        if border == "clip":
            nxt = np.clip(nxt, -w, w)
        elif border == "reflect":
            # Fold into [-w, w] with period 4w (mirror images), exact for any step size.
            nxt = np.abs(np.mod(nxt + w, 4 * w) - 2 * w) - w
            nxt = -nxt  # keep orientation: the fold above maps x in [-w, w] to -x
        else:
            raise ValueError(f"unknown border policy {border!r}")
        out[t + 1] = nxt
    return out


def draw_scenario(problem: ProblemConfig, streams: RunStreams) -> Scenario:
    """Draw the paper's scenario: ring of drones, uniform tasks with a random walk, attrition uniforms."""
    rng = streams.scenario
    n, m, tau = problem.n_drones, problem.n_tasks, problem.n_steps
    angles = 2 * np.pi * np.arange(n) / n  # evenly spaced (docs/design/model.md §7 #14)
    ring = problem.ring_radius_m * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    drone_pos0 = ring + rng.normal(0.0, problem.ring_noise_m, size=(n, 2))
    w = problem.field_half_width_m
    task0 = rng.uniform(-w, w, size=(m, 2))
    increments = rng.normal(0.0, problem.task_walk_sigma_m, size=(tau, m, 2))
    track = walk_tasks(task0, increments, w, problem.task_border)
    u = streams.attrition.random(size=(tau, n))
    return Scenario(drone_pos0, track, u)


@dataclass
class World:
    """Mutable ground truth of one episode; rows are stable (dead drones stay, masked)."""

    problem: ProblemConfig
    pos_m: np.ndarray
    """(N, 2) drone positions, metres."""
    alive: np.ndarray
    """(N,) bool, False once attrited (irreversible)."""
    task_track_m: np.ndarray
    """(tau + 1, M, 2) task positions per step, metres."""
    t_step: int = 0
    base_m: np.ndarray = field(default_factory=lambda: np.zeros(2))
    grounded: np.ndarray | None = None
    """(N,) bool: on the ground at the base (endurance model, mission.experiments.endurance): out of
    the mesh, no attrition. None: every alive drone flies (the paper's world)."""

    @classmethod
    def from_scenario(cls, problem: ProblemConfig, scenario: Scenario) -> World:
        return cls(
            problem,
            scenario.drone_pos0_m.copy(),
            np.ones(len(scenario.drone_pos0_m), bool),
            scenario.task_track_m,
        )

    @property
    def task_pos_m(self) -> np.ndarray:
        return self.task_track_m[min(self.t_step, len(self.task_track_m) - 1)]

    def active(self) -> np.ndarray:
        """(N,) bool: alive and connected to the base through alive drones (exact)."""
        p = self.problem
        flying = self.alive if self.grounded is None else self.alive & ~self.grounded
        return active_mask(self.pos_m, flying, p.radio_range_m, p.base_range_m, self.base_m)

    def tasks_connected(self, active: np.ndarray) -> np.ndarray:
        """(M,) bool: an active drone strictly within r of each task."""
        return tasks_connected(self.task_pos_m, self.pos_m, active, self.problem.radio_range_m)

    def step(
        self,
        disp_m: np.ndarray,
        active: np.ndarray,
        loss_prob: np.ndarray | float,
        attrition_u: np.ndarray,
        recovery_target_m: np.ndarray | None = None,
    ) -> np.ndarray:
        """Advance one step (docs/design/model.md §7 #2: plan -> attrition -> execute -> tasks walk).

        Parameters
        ----------
        disp_m : (N, 2) planner instructions, metres; used only for active drones.
        active : (N,) bool, the active mask measured at the start of this step.
        loss_prob : (N,) or scalar, per-drone loss probability this step.
        attrition_u : (N,) uniforms of this step.
        recovery_target_m : (N, 2), optional. The rally-point rule (a world option that only a
            planner publishing rally points switches on, ``planner.resilient``): a disconnected
            drone flies to its row instead of the base; NaN rows, and ``None`` (the paper's rule,
            every other method), fly home.

        Returns
        -------
        (N,) bool: the drones lost at this step.
        """
        p = self.problem
        vmax = p.max_speed_m_s * p.dt_s
        # Disconnected but alive: straight home at full speed (never overshooting the base).
        home = self.base_m
        if recovery_target_m is None:
            # Compiled when available: the lines below in one pass, bit for bit
            # (tests/planner/test_graph_kernels.py).
            lost = self.alive & (attrition_u < loss_prob)
            moved = bounded_moves(
                self.pos_m, np.asarray(disp_m, dtype=float), active, self.alive & ~lost, home, vmax
            )
            if moved is not None:
                self.alive = self.alive & ~lost
                self.pos_m = moved
                self.t_step += 1
                return lost
        if recovery_target_m is not None:
            target = np.asarray(recovery_target_m, dtype=float)
            home = np.where(np.isfinite(target).all(axis=1)[:, None], target, self.base_m)
        disp = np.where(active[:, None], disp_m, step_toward(self.pos_m, home, vmax))
        # The world enforces the speed limit whatever the planner says.
        norm = np.linalg.norm(disp, axis=1)
        disp = disp * (np.minimum(1.0, vmax / np.where(norm > 0, norm, 1.0)))[:, None]
        lost = self.alive & (attrition_u < loss_prob)
        self.alive = self.alive & ~lost
        self.pos_m = self.pos_m + disp * self.alive[:, None]  # attrited drones cease all movement
        self.t_step += 1
        return lost

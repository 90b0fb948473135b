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
from planner.terrain import TerrainRadio, path_agl_m, path_clearance_m

__all__ = [
    "Scenario",
    "RunStreams",
    "spawn_streams",
    "draw_scenario",
    "walk_tasks",
    "World",
    "TerrainFlight",
]


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


#: Terrain following keeps this much above ``TerrainFlight.clearance_m`` and below
#: ``TerrainFlight.ceiling_agl_m`` at its path samples, metres: the ground between two samples of a
#: step (at most a few metres apart) can rise or fall a little past its samples on a steep wall.
CLEARANCE_MARGIN_M = 1.0


@dataclass(frozen=True)
class TerrainFlight:
    """How drones fly and talk over terrain (a mission's ``radio.model: terrain``, docs/terrain.md).

    ``mode`` 'flat' is today's flight: every drone holds one altitude AMSL (the base's ground plus
    the cruise altitude, as the station commands over a flat earth) and a flight whose straight
    path goes into the ground is a crash. 'follow' is terrain following (ArduPilot's
    ``TERRAIN_FOLLOW``): each drone holds ``alt_agl_m`` above the ground under it, climbing at
    most ``max_climb_m`` and descending at most ``max_descent_m`` per step, and shortens a step
    whose straight path would pass closer than ``clearance_m`` to the ground or higher than
    ``ceiling_agl_m`` above it (docs/terrain.md §3)."""

    radio: TerrainRadio
    mode: str = "follow"
    """'follow' or 'flat'."""
    alt_agl_m: float = 40.0
    """'follow': the height above ground each drone holds, metres."""
    flat_alt_amsl_m: float = 0.0
    """'flat': the one altitude every drone holds, metres AMSL."""
    clearance_m: float = 10.0
    """'follow': the least height above the ground along any flight, metres."""
    max_climb_m: float = 2.5
    """Largest climb in one step, metres."""
    max_descent_m: float | None = None
    """Largest descent in one step, metres (the vehicles' descent speed x the step, as the
    station limits it, docs/terrain.md §6.2); None: ``max_climb_m``."""
    ceiling_agl_m: float = float("inf")
    """'follow': the highest a drone may fly above the ground, metres (a step whose straight path
    would pass higher, off a cliff faster than the drone can descend, is shortened)."""
    crew_antenna_agl_m: float = 1.5
    """Height of a crew's radio above the ground, metres."""
    base_antenna_agl_m: float = 1.5
    """Height of the base's antenna above the ground, metres."""

    def __post_init__(self) -> None:
        if self.mode not in ("follow", "flat"):
            raise ValueError(f"TerrainFlight.mode must be 'follow' or 'flat', got {self.mode!r}")
        if self.max_descent_m is not None and not self.max_descent_m > 0:
            raise ValueError(f"TerrainFlight.max_descent_m must be > 0, got {self.max_descent_m}")

    @property
    def descent_m(self) -> float:
        """The largest descent in one step, metres."""
        return self.max_climb_m if self.max_descent_m is None else self.max_descent_m

    def start_alt_amsl_m(self, pos_ne_m: np.ndarray) -> np.ndarray:
        """(N,) the altitude each drone starts at (already at its cruise height), metres AMSL."""
        if self.mode == "flat":
            return np.full(len(pos_ne_m), self.flat_alt_amsl_m)
        return self.radio.terrain.height_m(pos_ne_m) + self.alt_agl_m


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
    terrain: TerrainFlight | None = None
    """Terrain, its radio and how drones fly over it (docs/terrain.md); None: the paper's flat
    world and disc radio, untouched."""
    alt_amsl_m: np.ndarray | None = None
    """(N,) drone heights AMSL, metres (with ``terrain`` only; set by :meth:`with_terrain`)."""
    terrain_crashes: int = 0
    """Drones lost by flying into the ground (with ``terrain`` only)."""

    @classmethod
    def from_scenario(cls, problem: ProblemConfig, scenario: Scenario) -> World:
        return cls(
            problem,
            scenario.drone_pos0_m.copy(),
            np.ones(len(scenario.drone_pos0_m), bool),
            scenario.task_track_m,
        )

    def with_terrain(self, terrain: TerrainFlight) -> World:
        """This world over ``terrain``: drones start at their cruise altitude (in place)."""
        self.terrain = terrain
        self.alt_amsl_m = terrain.start_alt_amsl_m(self.pos_m)
        return self

    @property
    def task_pos_m(self) -> np.ndarray:
        return self.task_track_m[min(self.t_step, len(self.task_track_m) - 1)]

    def active(self) -> np.ndarray:
        """(N,) bool: alive and connected to the base through alive drones (exact)."""
        p = self.problem
        flying = self.alive if self.grounded is None else self.alive & ~self.grounded
        if self.terrain is not None:
            assert self.alt_amsl_m is not None  # set with the terrain (with_terrain)
            tf = self.terrain
            base_h = float(tf.radio.terrain.height_m(self.base_m[None])[0])
            return tf.radio.active_mask(
                self.pos_m, self.alt_amsl_m, flying, self.base_m, base_h + tf.base_antenna_agl_m
            )
        return active_mask(self.pos_m, flying, p.radio_range_m, p.base_range_m, self.base_m)

    def tasks_connected(self, active: np.ndarray) -> np.ndarray:
        """(M,) bool: an active drone strictly within r of each task (over terrain: an active
        drone whose link to the crew's radio closes)."""
        if self.terrain is not None:
            assert self.alt_amsl_m is not None  # set with the terrain (with_terrain)
            tp = self.task_pos_m
            ground = self.terrain.radio.terrain.height_m(tp)
            return self.terrain.radio.tasks_connected(
                tp, ground + self.terrain.crew_antenna_agl_m, self.pos_m, self.alt_amsl_m, active
            )
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

    def fly_terrain(
        self,
        pos_before_m: np.ndarray,
        n_fractions: int = 8,
        n_samples: int = 32,
        alt_agl_m: np.ndarray | None = None,
    ) -> np.ndarray:
        """Heights over the terrain for the step just taken by :meth:`step` (from
        ``pos_before_m``, (N, 2) metres), per :class:`TerrainFlight`. 'follow' shortens each
        horizontal move to the longest of ``n_fractions`` equal parts whose straight flight keeps
        ``clearance_m`` above the ground and stays under ``ceiling_agl_m`` at ``n_samples``
        points, with :data:`CLEARANCE_MARGIN_M` to spare (the margin covers the ground between
        the samples); 'flat' holds the one altitude and a flight into the ground is a crash.
        ``alt_agl_m`` (N,): 'follow' holds each drone's own height above the ground, as a planner
        that chooses altitudes commands it; None: ``TerrainFlight.alt_agl_m`` for every drone
        (either kept within [``clearance_m`` + margin, ``ceiling_agl_m`` - margin]). Returns (N,) bool, the drones that crashed
        this step."""
        tf = self.terrain
        assert tf is not None and self.alt_amsl_m is not None  # terrain worlds only
        ground = tf.radio.terrain
        alt0 = self.alt_amsl_m
        move = self.pos_m - pos_before_m
        if tf.mode == "flat":
            alt1 = alt0 + np.clip(tf.flat_alt_amsl_m - alt0, -tf.descent_m, tf.max_climb_m)
            clear = path_clearance_m(ground, pos_before_m, self.pos_m, alt0, alt1, n_samples)
            crash = self.alive & (clear < 0)
        else:
            best_pos, best_alt = pos_before_m.copy(), alt0.copy()
            want_agl = tf.alt_agl_m if alt_agl_m is None else np.asarray(alt_agl_m, dtype=float)
            agl = np.clip(
                want_agl, tf.clearance_m + CLEARANCE_MARGIN_M, tf.ceiling_agl_m - CLEARANCE_MARGIN_M
            )
            # Fractions from short to long (a handful): keep the longest that keeps clearance.
            for k in range(n_fractions + 1):
                end = pos_before_m + (k / n_fractions) * move
                want = ground.height_m(end) + agl
                alt1 = alt0 + np.clip(want - alt0, -tf.descent_m, tf.max_climb_m)
                agl_path = path_agl_m(ground, pos_before_m, end, alt0, alt1, n_samples)
                clear = agl_path.min(axis=1)
                # Above the ceiling anywhere along the flight, not only at its end: a narrow
                # canyon's floor can pass under a step that starts and ends over its rims.
                high = agl_path.max(axis=1) > tf.ceiling_agl_m - CLEARANCE_MARGIN_M
                ok = ((clear >= tf.clearance_m + CLEARANCE_MARGIN_M) & ~high) | (k == 0)
                best_pos = np.where(ok[:, None], end, best_pos)
                best_alt = np.where(ok, alt1, best_alt)
            self.pos_m, alt1 = best_pos, best_alt
            clear = path_clearance_m(ground, pos_before_m, self.pos_m, alt0, alt1, n_samples)
            crash = self.alive & (clear < 0)
        self.alt_amsl_m = np.where(self.alive, alt1, alt0)
        self.alive = self.alive & ~crash
        self.terrain_crashes += int(crash.sum())
        return crash

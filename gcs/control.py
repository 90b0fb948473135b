"""The control tick: what the station believes -> the planner -> one position target per vehicle.

A pure function (docs/design/architecture.md §1.1, §2.3 "per-tick hot path"): no clock, no sockets, no truth.
Its inputs are what the station *believes* (a :class:`~gcs.fleet.FleetSnapshot`-like set of
arrays, positions in the mission's local NED frame converted from GLOBAL_POSITION_INT) and the
task positions; its output is a target for every planned row, in the same frame. Encoding those
targets (a Python loop over vehicles) happens at the codec edge, in :mod:`gcs.operations`.

Targets:

* horizontal = current position + the planner's displacement for this tick (``PlanOutput.disp_m``,
  already within ``v * dt``);
* altitude = the vehicle's cruise layer, ``cruise_alt_m + (row % n_layers) * layer_spacing_m``
  above the base (the mission's ``FlightLimits.layer_alt_m``), so neighbours in the row order fly
  on different layers;
* clipped to the geofence: an axis-aligned box in the mission frame (the mission schema has no
  geofence section yet; the runner passes the task field plus a margin).

Over terrain (``ControlConfig.terrain``, docs/terrain.md §6) the altitude is the ground under the
target (the mission's DEM) plus the row's layer height above it, and never lower than
``clearance_m`` over the highest ground between the vehicle and its target. A target whose straight
path from the vehicle's present altitude would come closer than that to the ground is replaced by
a climb where the vehicle is ("climb first, then move"): every setpoint's straight path clears the
terrain, not only its end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from planner.hazard import HazardMap
from planner.methods import Planner, TickInput
from planner.terrain import Terrain, TerrainRadio, path_clearance_m

__all__ = [
    "FIRMWARE_DESCENT_RATE_M_S",
    "ControlConfig",
    "Geofence",
    "TerrainAltitude",
    "TickResult",
    "layer_alt_m",
    "terrain_targets",
    "tick",
]


@dataclass(frozen=True)
class Geofence:
    """An axis-aligned box in the mission NED frame (metres) plus an altitude ceiling."""

    north_min_m: float = -math.inf
    north_max_m: float = math.inf
    east_min_m: float = -math.inf
    east_max_m: float = math.inf
    max_alt_m: float = math.inf
    """Ceiling above the base station, metres."""

    def __post_init__(self) -> None:
        if not (self.north_min_m < self.north_max_m and self.east_min_m < self.east_max_m):
            raise ValueError(f"empty geofence {self}")
        if not self.max_alt_m > 0:
            raise ValueError(f"max_alt_m must be > 0, got {self.max_alt_m}")

    @classmethod
    def square(cls, half_width_m: float, max_alt_m: float = math.inf) -> Geofence:
        """A square of half-width ``half_width_m`` centred on the base station."""
        if not half_width_m > 0:
            raise ValueError(f"half_width_m must be > 0, got {half_width_m}")
        return cls(-half_width_m, half_width_m, -half_width_m, half_width_m, max_alt_m)

    def clip_ne(self, ne_m: np.ndarray) -> np.ndarray:
        """(K, 2) north/east clipped into the box."""
        return np.column_stack(
            [
                np.clip(ne_m[:, 0], self.north_min_m, self.north_max_m),
                np.clip(ne_m[:, 1], self.east_min_m, self.east_max_m),
            ]
        )


@dataclass(frozen=True)
class TerrainAltitude:
    """Altitudes over a mission's DEM (docs/terrain.md §6): the ground the station knows (a map,
    not the vehicles' truth) and how high above it to fly."""

    terrain: Terrain
    """Ground heights AMSL in the mission frame."""
    origin_amsl_m: float
    """Altitude of the mission frame's origin (down = 0), metres AMSL."""
    clearance_m: float = 15.0
    """Least height above the ground along any setpoint's straight path, metres."""
    ceiling_agl_m: float = math.inf
    """Highest layer above the ground, metres (a path over higher ground may need more)."""
    n_samples: int = 16
    """Points sampled along each path (ends included: ``n_samples + 1``)."""
    radio: TerrainRadio | None = None
    """The link model over this ground: crews count as covered "as the station sees them" when a
    heard vehicle's link to the crew's radio closes (None: the disc of ``radio_range_m``)."""
    crew_antenna_agl_m: float = 1.5
    """A crew's radio above its ground, metres."""
    corridor_m: float = 5.0
    """The ground is also sampled this far either side of each path, metres: a vehicle's
    position loop does not fly the straight line exactly (a turn swings it a few metres out),
    and by a steep wall a few metres sideways is many metres up."""
    descent_step_m: float = math.inf
    """The most a vehicle descends in one control period, metres (its descent speed x the
    period). A step out over falling ground is shortened so that the vehicle, descending at that
    speed, stays under the ceiling (:func:`terrain_targets`); inf: steps are not shortened."""

    def __post_init__(self) -> None:
        if not self.clearance_m >= 0 or not self.ceiling_agl_m > 0:
            raise ValueError("clearance_m must be >= 0 and ceiling_agl_m > 0")
        if not self.descent_step_m > 0:
            raise ValueError(f"descent_step_m must be > 0, got {self.descent_step_m}")

    def rtl_min_alt_m(self, fence: Geofence) -> float:
        """The least altitude above the origin at which a straight line home anywhere in
        ``fence`` clears the ground by ``clearance_m``: the highest post of the DEM inside the
        fence's box (every post where the fence is unbounded), plus the clearance, metres. What
        the firmware's RTL must fly home at over terrain (:func:`gcs.audit.audit_rtl_altitude`)."""
        t = self.terrain
        rows, cols = t.height_amsl_m.shape
        north = t.north0_m + t.spacing_m * np.arange(rows)
        east = t.east0_m + t.spacing_m * np.arange(cols)
        # the posts inside the box and one beyond each side: the ground between posts is bilinear
        pad = t.spacing_m
        r = (north >= fence.north_min_m - pad) & (north <= fence.north_max_m + pad)
        c = (east >= fence.east_min_m - pad) & (east <= fence.east_max_m + pad)
        grid = t.height_amsl_m[np.ix_(r, c)] if r.any() and c.any() else t.height_amsl_m
        return float(grid.max()) + self.clearance_m - self.origin_amsl_m


#: The descent speed both firmwares fly position targets at by default, m/s: ArduCopter's
#: ``WPNAV_SPEED_DN`` 150 cm/s (libraries/AC_WPNav/AC_WPNav.cpp, default
#: ``WPNAV_WP_SPEED_DOWN_CMS`` in AC_WPNav.h) and PX4's ``MPC_Z_VEL_MAX_DN`` 1.5 m/s, the offboard
#: descent limit (src/modules/mc_pos_control/mc_pos_control_params.c). What the station plans for
#: unless the mission sets ``vehicles.descent_rate_m_s``, which it then writes (gcs.limits).
FIRMWARE_DESCENT_RATE_M_S = 1.5


@dataclass(frozen=True)
class ControlConfig:
    """Altitudes and fence. Units in the names."""

    cruise_alt_m: float = 30.0
    """Lowest flight layer above the base station, metres."""
    layer_spacing_m: float = 5.0
    n_layers: int = 3
    geofence: Geofence = Geofence()
    lead: float = 1.0
    """Target = position + ``lead`` x the planner's displacement. An autopilot's position loop
    covers only part of the way to a target within one control period (a first-order loop with
    time constant tau reaches 1 - exp(-dt / tau) of it); a lead of 1 + tau / dt puts the target
    ahead ("carrot") so the vehicle moves the planned distance per tick, at most at its speed
    limit. 1 = target exactly at the planned point."""
    hazards: HazardMap | None = None
    """The mission's hazard zones, passed to the planner each tick (``TickInput.hazards``); None:
    no zones (planners that do not use them ignore them)."""
    terrain: TerrainAltitude | None = None
    """Over terrain: ``cruise_alt_m`` and the layers are heights above the ground under the
    target, and every path clears the ground (:func:`terrain_targets`); the geofence's
    ``max_alt_m`` (above the base) is not applied, the ceiling is ``terrain.ceiling_agl_m``.
    None: a flat earth, altitudes above the base."""

    def __post_init__(self) -> None:
        if not self.cruise_alt_m > 0:
            raise ValueError(f"cruise_alt_m must be > 0, got {self.cruise_alt_m}")
        if not self.lead >= 1.0:
            raise ValueError(f"lead must be >= 1, got {self.lead}")
        if self.n_layers < 1 or self.layer_spacing_m < 0:
            raise ValueError("n_layers must be >= 1 and layer_spacing_m >= 0")


def layer_alt_m(rows: npt.ArrayLike, config: ControlConfig) -> np.ndarray:
    """(K,) cruise altitude above the base of each row (vectorised ``FlightLimits.layer_alt_m``);
    over terrain, the layer's height above the ground (capped by the terrain ceiling)."""
    rows = np.asarray(rows, dtype=int)
    alt = config.cruise_alt_m + (rows % config.n_layers) * config.layer_spacing_m
    if config.terrain is not None:
        return np.minimum(alt, config.terrain.ceiling_agl_m)
    return np.minimum(alt, config.geofence.max_alt_m)


def terrain_targets(
    pos_ned_m: np.ndarray, target_ne_m: np.ndarray, agl_m: np.ndarray, ta: TerrainAltitude
) -> np.ndarray:
    """(K, 3) targets over terrain, mission NED (down = -(altitude AMSL - origin)).

    Parameters
    ----------
    pos_ned_m : (K, 3) the vehicles' positions, mission NED, metres
    target_ne_m : (K, 2) where each should go, metres
    agl_m : (K,) the height above the ground under the target each should hold, metres
    ta : the terrain and its clearance

    Each target's altitude is the ground under it plus ``agl_m``, raised to ``clearance_m`` over
    the highest ground sampled between the vehicle and the target, and ``corridor_m`` either
    side (the floor). A vehicle below
    the floor, or whose straight path to the target would pass closer than ``clearance_m`` to
    the ground, gets a climb to that altitude over its own position instead.

    Over falling ground (a rim, then a canyon) the step is first shortened
    (:func:`descent_fraction`): to the farthest point along it at which the vehicle, descending
    at most ``descent_step_m`` this period and never below the floor, is still under
    ``ceiling_agl_m`` over the lowest ground it has passed (or no further above it than where
    it is now). So a vehicle leaving a rim walks down the wall at its descent speed instead of
    crossing at the rim's clearance.
    """
    pos = np.asarray(pos_ned_m, dtype=float).reshape(-1, 3)
    tgt = np.asarray(target_ne_m, dtype=float).reshape(-1, 2)
    alt_now = ta.origin_amsl_m - pos[:, 2]
    if math.isfinite(ta.descent_step_m) and math.isfinite(ta.ceiling_agl_m):
        frac = descent_fraction(pos[:, :2], alt_now, tgt, ta)
        tgt = pos[:, :2] + frac[:, None] * (tgt - pos[:, :2])
    ground = ta.terrain
    band = ground.height_m(_band(pos[:, :2], tgt, ta))  # (K, 3, S + 1)
    floor = band.max(axis=(1, 2)) + ta.clearance_m
    alt = ground.height_m(tgt) + np.asarray(agl_m, dtype=float)
    # Never above the ceiling over the lowest ground on the way: toward rising ground the climb
    # starts over the low ground the vehicle leaves (a slot's floor rising 6 m put a vehicle 3 m
    # over the ceiling). The floor still wins: clearing the ground comes first.
    alt = np.maximum(np.minimum(alt, band.min(axis=(1, 2)) + ta.ceiling_agl_m), floor)
    clear = path_clearance_m(ground, pos[:, :2], tgt, alt_now, alt, ta.n_samples)
    # A vehicle below the floor climbs first: autopilots limit horizontal speed and climb rate
    # separately (ArduCopter WPNAV_SPEED / WPNAV_SPEED_UP, PX4 MPC_XY_VEL_MAX / MPC_Z_VEL_MAX_UP),
    # so a climbing move runs under its straight line. From the floor up, every point of the
    # flight is at least as high as the floor whatever the speeds. 1 cm of slack.
    climb = (alt_now < floor - 0.01) | (clear < ta.clearance_m - 0.01)
    ne = np.where(climb[:, None], pos[:, :2], tgt)
    alt = np.where(climb, np.maximum(alt, alt_now), alt)
    return np.column_stack([ne, ta.origin_amsl_m - alt])


def _band(pos_ne_m: np.ndarray, target_ne_m: np.ndarray, ta: TerrainAltitude) -> np.ndarray:
    """(K, 3, S + 1, 2) the points sampled along each path: the straight line (index 0) and
    the lines ``corridor_m`` either side of it, from the vehicle (sample 0) to the target."""
    f = np.linspace(0.0, 1.0, ta.n_samples + 1)
    d = target_ne_m - pos_ne_m
    pts = pos_ne_m[:, None, :] + f[None, :, None] * d[:, None, :]  # (K, S, 2)
    # ... and two lines ``corridor_m`` either side: the flown path is not quite straight
    side = np.column_stack([-d[:, 1], d[:, 0]])
    side *= (ta.corridor_m / np.maximum(np.linalg.norm(d, axis=1), 1e-9))[:, None]
    return np.stack([pts, pts + side[:, None, :], pts - side[:, None, :]], axis=1)


def descent_fraction(
    pos_ne_m: np.ndarray, alt_amsl_m: np.ndarray, target_ne_m: np.ndarray, ta: TerrainAltitude
) -> np.ndarray:
    """(K,) how much of each step to fly, in [0, 1], so that the vehicle stays under the ceiling
    over falling ground (:func:`terrain_targets`).

    At the path's samples ``j`` (fractions ``f = j / n_samples``), reached at ``f`` of the
    period, the vehicle is no lower than ``max(alt - f * descent_step_m, floor_j)``, where
    ``floor_j`` is ``clearance_m`` over the highest ground (with the corridor) up to sample
    ``j``; its excess over the ceiling is that minus the lowest ground (with the corridor) up to
    ``j`` minus ``ceiling_agl_m``. The fraction is that of the farthest sample up to which every
    excess is at most ``max(0, excess at the vehicle)``: a vehicle already too high (after a
    climb over a ridge) still moves, but no step makes it worse."""
    pos = np.asarray(pos_ne_m, dtype=float).reshape(-1, 2)
    tgt = np.asarray(target_ne_m, dtype=float).reshape(-1, 2)
    g = ta.terrain.height_m(_band(pos, tgt, ta))  # (K, 3, S + 1)
    floor = np.maximum.accumulate(g.max(axis=1), axis=1) + ta.clearance_m
    # the lowest ground with the corridor too: a vehicle a few metres off its line by a steep
    # wall is over ground many metres lower (a slot's floor), and so nearer the ceiling
    low = np.minimum.accumulate(g.min(axis=1), axis=1)
    # A vehicle flies its step in one period at a steady speed and descends at most its descent
    # speed meanwhile: at sample j it can be at most j / S of the period's descent lower. (All of
    # it from the first sample let a vehicle 5 m too high cross a slot's edge and fly over its
    # floor 2 m above the ceiling.)
    frac = np.arange(ta.n_samples + 1) / ta.n_samples
    reach = np.asarray(alt_amsl_m, dtype=float)[:, None] - ta.descent_step_m * frac[None, :]
    excess = np.maximum(reach, floor) - low - ta.ceiling_agl_m  # (K, S + 1)
    # every sample up to the one flown to must be under the bound (the first above it ends the step)
    ok = np.logical_and.accumulate(excess <= np.maximum(excess[:, :1], 0.0) + 1e-6, axis=1)
    return np.asarray(ok.sum(axis=1) - 1, dtype=float) / ta.n_samples


def descent_fraction_reference(
    pos_ne_m: np.ndarray, alt_amsl_m: np.ndarray, target_ne_m: np.ndarray, ta: TerrainAltitude
) -> np.ndarray:
    """:func:`descent_fraction` by plain loops over vehicles and samples (for tests)."""
    out = np.zeros(len(pos_ne_m))
    for k in range(len(pos_ne_m)):
        p, t = np.asarray(pos_ne_m[k], float), np.asarray(target_ne_m[k], float)
        d = t - p
        n = max(float(np.hypot(*d)), 1e-9)
        side = np.array([-d[1], d[0]]) * ta.corridor_m / n
        hi, lo, excess0 = -math.inf, math.inf, 0.0
        for j in range(ta.n_samples + 1):
            c = p + (j / ta.n_samples) * d
            line = [ta.terrain.height_m_reference(*q) for q in (c, c + side, c - side)]
            hi, lo = max(hi, *line), min(lo, *line)
            f = j / ta.n_samples
            reach = max(float(alt_amsl_m[k]) - f * ta.descent_step_m, hi + ta.clearance_m)
            excess = reach - lo - ta.ceiling_agl_m
            if j == 0:
                excess0 = max(excess, 0.0)
            if excess > excess0 + 1e-6:
                break
            out[k] = j / ta.n_samples
    return out


@dataclass(frozen=True)
class TickResult:
    """What one tick decided."""

    rows: np.ndarray
    """(K,) int: fleet rows that get a target (networked, with a position)."""
    target_ned_m: np.ndarray
    """(K, 3) float64: targets in the mission NED frame (down = -altitude above the base)."""
    disp_m: np.ndarray
    """(K, 2) float64: the planner's horizontal displacement for those rows, metres."""
    info: dict[str, Any]
    """The planner's diagnostics."""


def tick(
    pos_ned_m: np.ndarray,
    networked: np.ndarray,
    alive: np.ndarray,
    task_pos_m: np.ndarray,
    planner: Planner,
    t_step: int,
    config: ControlConfig = ControlConfig(),
) -> TickResult:
    """One control tick.

    Parameters
    ----------
    pos_ned_m : (N, 3) float64 - believed positions, mission NED, metres (NaN: no fix yet)
    networked : (N,) bool - D'(t) as the station sees it (heard within the timeout)
    alive : (N,) bool - not believed lost
    task_pos_m : (M, 2) float64 - task positions (north, east), metres (NaN: unknown, planned at
        the base)
    planner : a planner from :func:`planner.methods.make_planner` (central information)
    t_step : int - tick index since the start of the run
    config : altitudes and fence

    Returns
    -------
    TickResult with one target per networked row that has a position.
    """
    pos = np.asarray(pos_ned_m, dtype=float).reshape(-1, 3)
    has_pos = np.isfinite(pos).all(axis=1)
    planned = np.asarray(networked, dtype=bool) & np.asarray(alive, dtype=bool) & has_pos
    ne = np.where(has_pos[:, None], pos[:, :2], 0.0)
    tasks = np.asarray(task_pos_m, dtype=float).reshape(-1, 2)
    # A task with no known position (a live crew not heard yet, or whose TAK report went stale:
    # gcs.tak) is planned at the base: a zero-length branch of the tree, so no relay chases a
    # position that may be wrong and none is kept for it; the planners refuse NaN.
    tasks = np.where(np.isfinite(tasks).all(axis=1)[:, None], tasks, 0.0)
    ta = config.terrain
    alt_amsl = None
    if ta is not None:
        # Over terrain the planner is told the altitudes from telemetry (a terrain-aware planner
        # plans the mesh at them, docs/terrain.md §6.2); a row with no fix is put at the floor.
        alt_amsl = np.where(
            has_pos, ta.origin_amsl_m - pos[:, 2], ta.terrain.height_m(ne) + ta.clearance_m
        )
    out = planner.plan(
        TickInput(
            int(t_step),
            ne,
            np.asarray(alive, bool) & has_pos,
            planned,
            tasks,
            hazards=config.hazards,
            alt_amsl_m=alt_amsl,
        )
    )
    rows = np.flatnonzero(planned)
    disp = np.asarray(out.disp_m, dtype=float)[rows]
    target_ne = config.geofence.clip_ne(ne[rows] + config.lead * disp)
    if ta is not None:
        agl = layer_alt_m(rows, config)
        if out.alt_agl_m is not None:
            # The planner's height for each drone (planner.terrain_aware), its layer below it so
            # that neighbours in the row order still fly apart, never below the clearance.
            below = agl - config.cruise_alt_m
            agl = np.maximum(np.asarray(out.alt_agl_m, float)[rows] - below, ta.clearance_m)
        target = terrain_targets(pos[rows], target_ne, agl, ta)
    else:
        target = np.column_stack([target_ne, -layer_alt_m(rows, config)])
    return TickResult(rows, target, disp, dict(out.info or {}))

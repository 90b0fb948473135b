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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from planner.hazard import HazardMap
from planner.methods import Planner, TickInput

__all__ = ["ControlConfig", "Geofence", "TickResult", "layer_alt_m", "tick"]


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

    def __post_init__(self) -> None:
        if not self.cruise_alt_m > 0:
            raise ValueError(f"cruise_alt_m must be > 0, got {self.cruise_alt_m}")
        if not self.lead >= 1.0:
            raise ValueError(f"lead must be >= 1, got {self.lead}")
        if self.n_layers < 1 or self.layer_spacing_m < 0:
            raise ValueError("n_layers must be >= 1 and layer_spacing_m >= 0")


def layer_alt_m(rows: npt.ArrayLike, config: ControlConfig) -> np.ndarray:
    """(K,) cruise altitude above the base of each row (vectorised ``FlightLimits.layer_alt_m``)."""
    rows = np.asarray(rows, dtype=int)
    alt = config.cruise_alt_m + (rows % config.n_layers) * config.layer_spacing_m
    return np.minimum(alt, config.geofence.max_alt_m)


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
    out = planner.plan(
        TickInput(
            int(t_step),
            ne,
            np.asarray(alive, bool) & has_pos,
            planned,
            tasks,
            hazards=config.hazards,
        )
    )
    rows = np.flatnonzero(planned)
    disp = np.asarray(out.disp_m, dtype=float)[rows]
    target_ne = config.geofence.clip_ne(ne[rows] + config.lead * disp)
    target = np.column_stack([target_ne, -layer_alt_m(rows, config)])
    return TickResult(rows, target, disp, dict(out.info or {}))

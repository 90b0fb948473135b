"""Batteries in the paper's world: the truth the rotation policy is flown against in process.

The RTNUA world (:mod:`vehicle_emu.world`) has endless batteries. A mission with an
``endurance.battery`` section (:class:`mission.format.schema.EnduranceSpec`) plays with this model
instead (docs/design/endurance.md §5):

* every drone in the air drains ``(1 + f (v / v_max)^2) / endurance_s`` of its battery per second
  (``f``: ``speed_drain_frac``), a drone on the ground nothing;
* the firmware's own failsafes act on the truth: at ``low_frac`` a drone returns to launch on
  its own (the station is told, :meth:`planner.endurance.RotationPolicy.failsafe`), at
  ``critical_frac`` it lands where it is, lost to the mission (and counted as landed away when
  that is not the base);
* the rotation policy (:class:`planner.endurance.RotationPolicy`) decides who is planned, who
  flies out to relieve whom, who goes home; drones on the ground are out of the mesh and immune
  to attrition; a swap gives a full battery.

The policy sees the battery as SYS_STATUS would report it (whole percent) and plans the way home
at the full-speed drain: what the station could know.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.endurance import (
    RETURNING,
    RotationEvent,
    RotationOutput,
    RotationPolicy,
)
from vehicle_emu.world import World

__all__ = ["EnduranceRun", "endurance_run", "LAND_RADIUS_M"]

#: A returning drone this close to the base has landed, metres.
LAND_RADIUS_M = 1.0


@dataclass
class EnduranceRun:
    """The battery truth and the rotation policy of one in-process run (module docstring)."""

    policy: RotationPolicy
    endurance_s: float
    speed_drain_frac: float
    low_frac: float
    critical_frac: float
    dt_s: float
    max_speed_m_s: float
    battery_frac: np.ndarray = field(init=False)
    events: list[RotationEvent] = field(default_factory=list)
    critical_in_air: int = 0
    landed_away: int = 0
    min_battery_in_air: float = 1.0
    battery_log: list[np.ndarray] = field(default_factory=list)
    """(N,) battery fraction at every step (for plots and replay)."""
    end_s: float = math.inf
    """The mission's end (its length: step ``t`` is at ``t * dt_s``): relays due after it stay."""

    def __post_init__(self) -> None:
        self.battery_frac = np.ones(self.policy.n_drones)
        self._last_drain_per_s = np.zeros(self.policy.n_drones)

    def before_step(self, t: int, world: World, active: np.ndarray) -> RotationOutput:
        """The policy's decision at the start of step ``t``: who is planned, where the others go."""
        n = len(world.pos_m)
        if world.grounded is None:
            world.grounded = np.zeros(n, bool)
        now_s = t * self.dt_s
        d_home = np.hypot(*(world.pos_m - world.base_m).T)
        landed = (self.policy.phase == RETURNING) & (d_home <= LAND_RADIUS_M)
        # What telemetry would say: whole percent, and the drain of the last step (as the station
        # estimates it from consecutive readings); the way home planned at the full-speed drain.
        reported = np.round(self.battery_frac * 100.0) / 100.0
        hover = 1.0 / self.endurance_s
        drain = np.maximum(self._last_drain_per_s, hover)
        out = self.policy.step(
            now_s,
            world.pos_m,
            world.alive,
            reported,
            drain,
            networked=active,
            landed_at_base=landed,
            base_m=world.base_m,
            return_drain_per_s=np.full(n, (1.0 + self.speed_drain_frac) * hover),
            end_s=self.end_s,
        )
        self.events.extend(out.events)
        self.battery_frac[out.battery_swapped] = 1.0
        world.grounded = out.on_ground & world.alive
        self.battery_log.append(self.battery_frac.copy())
        return out

    def after_step(self, t: int, world: World, pos_before_m: np.ndarray) -> np.ndarray:
        """Drain the batteries of the step just flown; the firmware's failsafes act.

        Returns (N,) bool: drones lost to a critical-battery landing this step.
        """
        assert world.grounded is not None  # set by before_step
        flying = world.alive & ~world.grounded
        speed = np.hypot(*(world.pos_m - pos_before_m).T) / self.dt_s
        frac_speed = np.minimum(speed / self.max_speed_m_s, 1.0)
        drain = self.dt_s / self.endurance_s * (1.0 + self.speed_drain_frac * frac_speed**2)
        self.battery_frac = np.where(flying, self.battery_frac - drain, self.battery_frac)
        self._last_drain_per_s = np.where(flying, drain / self.dt_s, 0.0)
        if flying.any():
            self.min_battery_in_air = min(
                self.min_battery_in_air, float(self.battery_frac[flying].min())
            )
        now_s = (t + 1) * self.dt_s
        # Low battery: the firmware returns to launch on its own (once per battery).
        low = flying & (self.battery_frac <= self.low_frac) & (self.policy.phase != RETURNING)
        for i in np.flatnonzero(low):
            self.events.append(self.policy.failsafe(int(i), now_s))
        # Critical: it lands where it is; away from the base it is lost to the mission.
        crit = flying & (self.battery_frac <= self.critical_frac)
        if crit.any():
            d_home = np.hypot(*(world.pos_m - world.base_m).T)
            self.critical_in_air += int(crit.sum())
            self.landed_away += int((crit & (d_home > LAND_RADIUS_M)).sum())
            world.alive = world.alive & ~crit
            for i in np.flatnonzero(crit):
                self.events.append(RotationEvent(now_s, "critical_landing", int(i)))
        return crit

    def summary(self) -> dict[str, Any]:
        """What ``phireman sim --mission`` and summary.json report beside TU1/TU2."""
        s = self.policy.summary()
        return {
            "rotations": s["rotations"],
            "swaps": s["swaps"],
            "forced_returns": s["forced_returns"],
            "battery_failsafes_in_air": s["failsafe_returns"] + self.critical_in_air,
            "critical_in_air": self.critical_in_air,
            "landed_away": self.landed_away,
            "no_spare": s["no_spare"],
            "min_battery_in_air": round(self.min_battery_in_air, 4),
            "planned_at_start": self.policy.flying,
        }


def endurance_run(
    endurance: Any,
    n_drones: int,
    horizon_s: float,
    dt_s: float,
    max_speed_m_s: float,
    mean_post_dist_m: float,
    *,
    battery: str = "mission",
    rotation: str = "mission",
) -> EnduranceRun | None:
    """The endurance model of a mission's ``endurance`` section, or None for endless batteries.

    Parameters
    ----------
    endurance : the mission's :class:`mission.format.schema.EnduranceSpec`
    n_drones, horizon_s, dt_s, max_speed_m_s : the fleet, the mission's length, its step, speed
    mean_post_dist_m : typical distance from the base to a relay's post (the plan's way out)
    battery : 'mission' or 'unlimited' (``--battery unlimited``: endless, the reference)
    rotation : 'mission', 'on' or 'off' (``--rotation off``: the firmware's failsafe only)
    """
    spec = endurance.battery
    if spec is None or battery == "unlimited":
        return None
    rotate = endurance.rotation if rotation == "mission" else rotation == "on"
    policy = endurance.policy(n_drones, horizon_s, max_speed_m_s, mean_post_dist_m, rotate)
    return EnduranceRun(
        policy,
        spec.endurance_s,
        spec.speed_drain_frac,
        spec.low_frac,
        spec.critical_frac,
        dt_s,
        max_speed_m_s,
        end_s=horizon_s,
    )

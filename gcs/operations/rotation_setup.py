"""The rotation of one flight (:class:`RotationSetup`): the relay-rotation policy and what the
station knows of the batteries, apart from the operator's step that runs it
(:mod:`gcs.operations.rotation`) so that the operator's shared state can name it without an
import circle (tests/test_layering.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.endurance import (
    RotationEvent,
    RotationPolicy,
)

__all__ = ["RotationSetup"]


@dataclass
class RotationSetup:
    """The rotation of one flight: the policy and what the station knows of the batteries from
    the mission (not truth: the nominal endurance the operator wrote down)."""

    policy: RotationPolicy
    hover_drain_per_s: float
    """Nominal drain in a hover, fraction per second (1 / the mission's endurance): the floor
    of the estimate, and the drain before the first estimate."""
    return_drain_factor: float = 1.0
    """The drain flying home at full speed over the hover drain (1 + speed_drain_frac)."""
    base_ne_m: tuple[float, float] = (0.0, 0.0)
    """The base (the vehicles' home) in the mission frame, metres north / east."""
    land_radius_m: float = 30.0
    """Disarmed within this of the base = landed at the base, metres (GPS and RTL spread)."""
    full_frac: float = 0.95
    """A charge at least this after landing = a fresh battery."""
    failsafe_margin_frac: float = 0.05
    """An RTL / LAND nobody commanded, on a vehicle at most this above the policy's low level
    (``critical_frac``) or reporting a low charge state, is the firmware's battery failsafe."""
    lost_after_s: float = 30.0
    """A flying vehicle silent this long is lost to the rotation (the planner drops it sooner)."""
    counters: dict[str, int] = field(
        default_factory=lambda: {"battery_failsafes": 0, "landed_away": 0, "reboots": 0}
    )
    min_battery_in_air: float = 1.0
    events: list[RotationEvent] = field(default_factory=list)
    gone: set[int] = field(default_factory=set)
    """Rows landed away from the base (lost to the mission)."""
    landed_s: dict[int, float] = field(default_factory=dict)
    """Row -> when it was seen landed at the base (a reboot after it confirms the swap)."""
    landed_frac: dict[int, float] = field(default_factory=dict)
    home_ne_m: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    """(N, 2) each row's pad (first heard disarmed on the ground), mission frame (NaN: not yet)."""
    rebooted_home: set[int] = field(default_factory=set)
    """Rows power-cycled since they were sent home (the crew's swap), until the swap is
    confirmed: the reboot may come before the station heard the landing."""
    home_cmd_s: dict[int, float] = field(default_factory=dict)
    """Row -> when it was last told to go home / land (retry pacing)."""
    time_to_reserve_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    """(N,) at the last tick (inf: not draining)."""

    def __post_init__(self) -> None:
        if not self.hover_drain_per_s > 0:
            raise ValueError(f"hover_drain_per_s must be > 0, got {self.hover_drain_per_s}")

    def summary(self) -> dict[str, Any]:
        """For the status line and summary.json (the in-process run's keys, where they exist)."""
        s = self.policy.summary()
        return {
            "rotations": s["rotations"],
            "swaps": s["swaps"],
            "forced_returns": s["forced_returns"],
            "battery_failsafes_in_air": self.counters["battery_failsafes"],
            "landed_away": self.counters["landed_away"],
            "no_spare": s["no_spare"],
            "min_battery_in_air": round(self.min_battery_in_air, 4),
            "planned_at_start": self.policy.flying,
            "reboots": self.counters["reboots"],
            "recovered": s["recovered"],
            "in_air": s["in_air"],
            "ready": s["ready"],
            "on_pads": s["on_pads"],
            "batteries_charged": s["batteries_charged"],
        }

"""Attrition: random vehicle losses at a hazard rate, plus scripted kills at given times.

A lost vehicle stops moving and goes silent forever (its core is killed; its row stays, with
``alive = False``: arrays are never compacted, docs/design/architecture.md §3.1).

Random losses are a Poisson process per vehicle: over a step of ``dt_s`` an alive vehicle dies
with probability ``1 - exp(-hazard_per_s * dt_s)``, so the result does not depend on the tick
rate. Randomness comes from the injected generator only.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Attrition"]


class Attrition:
    """Loss model of N vehicles.

    Parameters
    ----------
    n_vehicles : int
    hazard_per_s : float or (N,) array
        Failure rate lambda per second (0 disables random losses).
    kills : iterable of (t_s, index)
        Scripted kills: vehicle ``index`` dies at vehicle time ``t_s``.
    rng : numpy.random.Generator
    airborne_only : bool
        If true, only vehicles that are armed and off the ground can fail at random.
    """

    def __init__(
        self, n_vehicles: int, hazard_per_s=0.0, kills=(), rng=None, airborne_only: bool = False
    ) -> None:
        self.hazard_per_s = np.broadcast_to(
            np.asarray(hazard_per_s, dtype=float), (n_vehicles,)
        ).copy()
        if np.any(self.hazard_per_s < 0) or not np.all(np.isfinite(self.hazard_per_s)):
            raise ValueError("hazard_per_s must be finite and >= 0")
        self.kills = sorted((float(t), int(i)) for t, i in kills)
        for _, i in self.kills:
            if not 0 <= i < n_vehicles:
                raise ValueError(f"scripted kill index {i} out of range 0..{n_vehicles - 1}")
        self._next_kill = 0
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.airborne_only = airborne_only

    def add_kill(self, t_s: float, index: int) -> None:
        """Schedule one more scripted kill."""
        pending = self.kills[self._next_kill :] + [(float(t_s), int(index))]
        self.kills = self.kills[: self._next_kill] + sorted(pending)

    def step(
        self, t0_s: float, t1_s: float, alive: np.ndarray, airborne: np.ndarray | None = None
    ) -> list[tuple[int, str]]:
        """Vehicles that die in (t0_s, t1_s]: list of (index, cause), cause 'scripted'/'hazard'."""
        dead: list[tuple[int, str]] = []
        seen = set()
        while self._next_kill < len(self.kills) and self.kills[self._next_kill][0] <= t1_s:
            _, i = self.kills[self._next_kill]
            self._next_kill += 1
            if alive[i] and i not in seen:
                dead.append((i, "scripted"))
                seen.add(i)
        dt = t1_s - t0_s
        if dt > 0 and np.any(self.hazard_per_s > 0):
            p = -np.expm1(-self.hazard_per_s * dt)
            hit = self.rng.random(len(p)) < p
            hit &= alive
            if self.airborne_only and airborne is not None:
                hit &= airborne
            dead.extend((int(i), "hazard") for i in np.flatnonzero(hit) if int(i) not in seen)
        return dead

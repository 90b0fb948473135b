"""Clocks: a virtual clock for deterministic tests, a real clock with a speed-up factor.

Every vehicle timer (heartbeats, GUID_TIMEOUT, FS_GCS_TIMEOUT, COM_OF_LOSS_T, telemetry) runs
on the *vehicle* clock that these produce. Under a speed-up S, all of them run S times faster
in wall time, exactly like SITL's SIM_SPEEDUP; a GCS must therefore also scale its heartbeat
period, or the failsafe fires (measured on SITL at S = 10, MAVLINK_NOTES §5).
"""

from __future__ import annotations

import time

__all__ = ["VirtualClock", "RealClock"]


class VirtualClock:
    """Time moves only when told to (tests, lockstep runs)."""

    def __init__(self, t0_s: float = 0.0) -> None:
        self.t_s = float(t0_s)

    def now(self) -> float:
        return self.t_s

    def advance(self, dt_s: float) -> float:
        if dt_s < 0:
            raise ValueError("a clock cannot go backwards")
        self.t_s += dt_s
        return self.t_s

    def wall_delay_s(self, vehicle_dt_s: float) -> float:
        return 0.0


class RealClock:
    """Vehicle time = (monotonic wall time since start) x speedup.

    Parameters
    ----------
    speedup : float
        SITL's SIM_SPEEDUP: 1 = real time, 10 = ten times faster.
    time_fn : callable
        Monotonic wall clock in seconds (injectable, e.g. ``loop.time``).
    """

    def __init__(self, speedup: float = 1.0, time_fn=time.monotonic, t0_s: float = 0.0) -> None:
        if not speedup > 0:
            raise ValueError(f"speedup must be > 0, got {speedup}")
        self.speedup = float(speedup)
        self._time_fn = time_fn
        self._wall0 = time_fn()
        self._t0_s = float(t0_s)
        self.unix_time_at_zero_s = time.time() - self._t0_s / self.speedup

    def now(self) -> float:
        return self._t0_s + (self._time_fn() - self._wall0) * self.speedup

    def wall_delay_s(self, vehicle_dt_s: float) -> float:
        """Wall seconds until ``vehicle_dt_s`` of vehicle time has passed."""
        return max(0.0, vehicle_dt_s / self.speedup)

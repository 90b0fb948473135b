"""Clocks: a virtual clock for deterministic tests, a real clock with a speed-up factor.

Every vehicle timer (heartbeats, GUID_TIMEOUT, FS_GCS_TIMEOUT, COM_OF_LOSS_T, telemetry) runs
on the *vehicle* clock that these produce. Under a speed-up S, all of them run S times faster
in wall time, exactly like SITL's SIM_SPEEDUP; a GCS must therefore also scale its heartbeat
period, or the failsafe fires (measured on SITL at S = 10, docs/design/mavlink.md §5.1).
"""

from __future__ import annotations

import time

__all__ = ["VirtualClock", "RealClock", "PacedClock", "PacedReader"]


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


class PacedClock:
    """Lock-step pacing for an emulator and a station in separate processes (SITL's lock-step
    idea: when a process lags, simulated time slows down instead of jumping).

    The emulator owns simulated time in ``sim`` (e.g. a ``multiprocessing.RawValue('d')`` its
    parent created) and moves it forward in :meth:`advance`, once per emulator iteration:

    * by wall time x ``speedup`` since the previous call, but by at most ``max_step_s``, so a
      stalled emulator (descheduled, swapping) slows the simulation instead of jumping it;
    * never beyond ``ack.value + slack_s``, where ``ack`` is the simulated time the station last
      read (its clock writes it on every read), so a stalled station cannot miss its own heartbeat
      or setpoint deadlines in *simulated* time: the vehicles wait for it.

    ``slack_s`` must stay below the shortest vehicle-side link timeout (PX4 COM_OF_LOSS_T, 1 s)
    and the station must read its clock at least every ``slack_s / 2`` of simulated time while
    idle, or it throttles the emulator. ``time_fn`` is injectable (tests).
    """

    def __init__(self, speedup: float, sim, ack, *, max_step_s: float = 0.2,
                 slack_s: float = 0.5, time_fn=time.monotonic) -> None:
        if not speedup > 0:
            raise ValueError(f"speedup must be > 0, got {speedup}")
        if not (max_step_s > 0 and slack_s > 0):
            raise ValueError("max_step_s and slack_s must be > 0")
        self.speedup = float(speedup)
        self.sim = sim
        self.ack = ack
        self.max_step_s = float(max_step_s)
        self.slack_s = float(slack_s)
        self._time_fn = time_fn
        self._last_wall = time_fn()
        self.unix_time_at_zero_s = time.time() - float(sim.value) / self.speedup
        self.stats = {"advances": 0, "capped_by_step": 0, "capped_by_ack": 0}

    def now(self) -> float:
        return self.sim.value

    def advance(self) -> float:
        """Move simulated time forward (see the class docstring); returns the new time."""
        wall = self._time_fn()
        dt = max(0.0, wall - self._last_wall) * self.speedup
        self._last_wall = wall
        t0 = self.sim.value
        t = t0 + min(dt, self.max_step_s)
        if dt > self.max_step_s:
            self.stats["capped_by_step"] += 1
        limit = self.ack.value + self.slack_s
        if t > limit:
            t = limit
            self.stats["capped_by_ack"] += 1
        if t > t0:
            self.sim.value = t
            self.stats["advances"] += 1
        return self.sim.value

    def wall_delay_s(self, vehicle_dt_s: float) -> float:
        return max(0.0, vehicle_dt_s / self.speedup)


class PacedReader:
    """The station's side of a :class:`PacedClock`. :meth:`acknowledge` says "everything due up
    to ``t`` is done" (the station's loop calls it once per iteration with the time it read at
    the start); a station that falls behind (CPU-bound, stalled) thereby holds the emulator back
    instead of missing its heartbeat and setpoint deadlines in simulated time."""

    def __init__(self, speedup: float, sim, ack) -> None:
        self.speedup = float(speedup)
        self.sim = sim
        self.ack = ack
        self.unix_time_at_zero_s = time.time() - float(sim.value) / self.speedup

    def now(self) -> float:
        return self.sim.value

    def acknowledge(self, t_s: float) -> None:
        if t_s > self.ack.value:
            self.ack.value = t_s

    def wall_delay_s(self, vehicle_dt_s: float) -> float:
        return max(0.0, vehicle_dt_s / self.speedup)

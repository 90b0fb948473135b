"""One Clock protocol, and the clocks both sides of a link run on.

Why here: the ground station (:mod:`gcs`) and the emulator (:mod:`vehicle_emu`) must follow one
notion of time (under a speed-up S every timer of both sides runs S times faster in wall time,
docs/design/mavlink.md §4.2), but they never import each other (import-linter contracts in
``pyproject.toml``). :mod:`mavedge` is the one leaf package below both, and the clock is part of
the link's edge: the Unix anchor is what MAVLink signing timestamps and ``.tlog`` stamps are
computed from. This module imports only the standard library.

One name for each idea:

* :class:`Clock` - what every clock offers: :meth:`~Clock.now` (simulated / vehicle seconds),
  :meth:`~Clock.wall_delay_s` (wall seconds until ``dt_s`` of clock time has passed) and
  :attr:`~Clock.unix_time_at_zero_s` (the Unix time, seconds since the epoch, that
  ``now() == 0`` stands for: signing timestamps and tlog stamps are ``unix_time_at_zero_s +
  now_s``);
* :class:`VirtualClock` - time moves only when told to (tests, lock-step drivers);
* :class:`RealClock` - monotonic wall time x speed-up (SITL's SIM_SPEEDUP); two processes that
  pass one ``wall0_s`` reading of CLOCK_MONOTONIC (system-wide) follow one clock;
* :class:`PacedClock` - the emulator's side of lock-step pacing: it owns simulated time in a
  shared value and advances it from wall time, never far beyond the station's acknowledgement;
* :class:`PacedReader` - the station's side of a :class:`PacedClock`: reads the shared time and
  acknowledges it.

Every vehicle timer (heartbeats, GUID_TIMEOUT, FS_GCS_TIMEOUT, COM_OF_LOSS_T, telemetry) runs on
the clock these produce; under a speed-up a GCS must scale its heartbeat period too, or the
failsafe fires (measured on SITL at S = 10, docs/design/mavlink.md §5.1).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable

__all__ = ["Clock", "SharedValue", "VirtualClock", "RealClock", "PacedClock", "PacedReader"]

#: How much wall time a :class:`PacedClock` catches up after slow iterations (ArduPilot SITL's
#: clamp on its frame-time debt, libraries/SITL/SIM_Aircraft.cpp ``Aircraft::sync_frame_time``).
CATCH_UP_WALL_S = 0.1

#: Default Unix anchor of a virtual clock (a fixed, recent instant: runs are reproducible).
VIRTUAL_UNIX_TIME_AT_ZERO_S = 1.7e9


@runtime_checkable
class Clock(Protocol):
    """What the station, the emulator and their drivers need of a clock."""

    def now(self) -> float:
        """Simulated (vehicle) time, seconds."""
        ...

    def wall_delay_s(self, dt_s: float) -> float:
        """Wall seconds until ``dt_s`` seconds of this clock have passed (>= 0)."""
        ...

    @property
    def unix_time_at_zero_s(self) -> float:
        """The Unix time (seconds since the epoch) that ``now() == 0`` stands for."""
        ...


class SharedValue(Protocol):
    """A float shared between processes, e.g. ``multiprocessing.RawValue('d')``."""

    value: float


def _check_speedup(speedup: float) -> float:
    if not speedup > 0:
        raise ValueError(f"speedup must be > 0, got {speedup}")
    return float(speedup)


class VirtualClock:
    """Time moves only when told to (tests, lock-step drivers); no wall delay."""

    def __init__(
        self, t0_s: float = 0.0, unix_time_at_zero_s: float = VIRTUAL_UNIX_TIME_AT_ZERO_S
    ) -> None:
        self.t_s = float(t0_s)
        self.unix_time_at_zero_s = float(unix_time_at_zero_s)

    def now(self) -> float:
        return self.t_s

    def advance(self, dt_s: float) -> float:
        """Move time forward by ``dt_s``; returns the new time."""
        if dt_s < 0:
            raise ValueError("a clock cannot go backwards")
        self.t_s += dt_s
        return self.t_s

    def wall_delay_s(self, dt_s: float) -> float:
        return 0.0


class RealClock:
    """Vehicle time = ``t0_s`` + (monotonic wall time - ``wall0_s``) x ``speedup``.

    Parameters
    ----------
    speedup : float
        SITL's SIM_SPEEDUP: 1 = real time, 10 = ten times faster.
    time_fn : callable
        Monotonic wall clock in seconds (injectable, e.g. ``loop.time``).
    t0_s : float
        The clock's reading at ``wall0_s``.
    wall0_s : float, optional
        The ``time_fn`` reading at which the clock reads ``t0_s`` (default: now). With
        ``time.monotonic`` (CLOCK_MONOTONIC is system-wide), processes given one ``wall0_s``
        follow one clock.
    unix_time_fn : callable
        Unix time in seconds (injectable), read once for :attr:`unix_time_at_zero_s`.
    """

    def __init__(
        self,
        speedup: float = 1.0,
        time_fn: Callable[[], float] = time.monotonic,
        t0_s: float = 0.0,
        *,
        wall0_s: float | None = None,
        unix_time_fn: Callable[[], float] = time.time,
    ) -> None:
        self.speedup = _check_speedup(speedup)
        self._time_fn = time_fn
        now_wall = time_fn()
        self.wall0_s = now_wall if wall0_s is None else float(wall0_s)
        self.t0_s = float(t0_s)
        # Unix time at clock time 0: wall time now minus the wall time since clock time 0.
        self.unix_time_at_zero_s = (
            unix_time_fn() - (now_wall - self.wall0_s) - self.t0_s / self.speedup
        )

    def now(self) -> float:
        return self.t0_s + (self._time_fn() - self.wall0_s) * self.speedup

    def wall_delay_s(self, dt_s: float) -> float:
        return max(0.0, dt_s / self.speedup)


class PacedClock:
    """Lock-step pacing for an emulator and a station in separate processes (SITL's lock-step
    idea: when a process lags, simulated time slows down instead of jumping).

    The emulator owns simulated time in ``sim`` (e.g. a ``multiprocessing.RawValue('d')`` its
    parent created) and moves it forward in :meth:`advance`, once per emulator iteration:

    * by wall time x ``speedup`` since the previous call, but by at most ``max_step_s``, so a
      stalled emulator (descheduled, swapping) slows the simulation instead of jumping it;
    * what the step limit cut off is caught up by the following iterations (each still at most
      ``max_step_s``), up to ``catch_up_wall_s`` of wall time; beyond that it is lost. This is
      ArduPilot SITL's rule (libraries/SITL/SIM_Aircraft.cpp, ``Aircraft::sync_frame_time``:
      frames that ran late are made up by not sleeping, with the debt clamped at 0.1 s of wall
      time), so one slow iteration (a control tick's setpoint burst) costs no simulated time,
      while a long stall still slows the simulation;
    * never beyond ``ack.value + slack_s``, where ``ack`` is the simulated time the station last
      acknowledged (:meth:`PacedReader.acknowledge`), so a stalled station cannot miss its own
      heartbeat or setpoint deadlines in *simulated* time: the vehicles wait for it. What the
      station withheld is owed like a slow iteration's time, under the same clamp: a station
      that lags for a moment (a control tick's planning, a burst of telemetry) is caught up on
      once it acknowledges, so the flight still averages ``speedup``; one that stays behind
      slows the simulation (``stats["held_by_ack_s"]`` counts what was lost).

    ``slack_s`` must stay below the shortest vehicle-side link timeout (PX4 COM_OF_LOSS_T, 1 s)
    and the station must acknowledge at least every ``slack_s / 2`` of simulated time while
    idle, or it throttles the emulator. ``time_fn`` and ``unix_time_fn`` are injectable (tests).
    """

    def __init__(
        self,
        speedup: float,
        sim: SharedValue,
        ack: SharedValue,
        *,
        max_step_s: float = 0.2,
        slack_s: float = 0.5,
        catch_up_wall_s: float = CATCH_UP_WALL_S,
        time_fn: Callable[[], float] = time.monotonic,
        unix_time_fn: Callable[[], float] = time.time,
    ) -> None:
        self.speedup = _check_speedup(speedup)
        if not (max_step_s > 0 and slack_s > 0 and catch_up_wall_s >= 0):
            raise ValueError("max_step_s and slack_s must be > 0, catch_up_wall_s >= 0")
        self.sim = sim
        self.ack = ack
        self.max_step_s = float(max_step_s)
        self.slack_s = float(slack_s)
        #: The most simulated time the step limit may defer to later iterations.
        self.max_debt_s = float(catch_up_wall_s) * self.speedup
        self._debt_s = 0.0
        self._time_fn = time_fn
        self._last_wall = time_fn()
        self.unix_time_at_zero_s = unix_time_fn() - float(sim.value) / self.speedup
        #: Counts of iterations, and the simulated seconds each limit withheld (``held_*_s``:
        #: wall time x speedup that did not become simulated time; their sum over a run is
        #: how far the simulation fell behind ``speedup``).
        self.stats: dict[str, float] = {
            "advances": 0,
            "capped_by_step": 0,
            "capped_by_ack": 0,
            "held_by_step_s": 0.0,
            "held_by_ack_s": 0.0,
        }

    def now(self) -> float:
        return float(self.sim.value)

    def advance(self) -> float:
        """Move simulated time forward (see the class docstring); returns the new time."""
        wall = self._time_fn()
        dt = max(0.0, wall - self._last_wall) * self.speedup + self._debt_s
        self._last_wall = wall
        t0 = self.sim.value
        step = min(dt, self.max_step_s)
        rest = dt - step  # due by the wall clock, not taken in this iteration
        t = t0 + step
        limit = self.ack.value + self.slack_s
        by_ack = t > limit
        if by_ack:
            # The station has not acknowledged this far: the vehicles wait for it. What it
            # withheld is owed like a slow iteration's time, under the same clamp: a station
            # that lagged for a moment (a control tick, a burst of datagrams) is caught up on
            # once it acknowledges, a stalled one slows the simulation.
            self.stats["capped_by_ack"] += 1
            rest += t - max(limit, t0)
            t = limit
        self._debt_s = min(rest, self.max_debt_s)
        lost = rest - self._debt_s
        if lost > 0:
            if by_ack:
                self.stats["held_by_ack_s"] += lost
            else:
                self.stats["capped_by_step"] += 1
                self.stats["held_by_step_s"] += lost
        if t > t0:
            self.sim.value = t
            self.stats["advances"] += 1
        return float(self.sim.value)

    def wall_delay_s(self, dt_s: float) -> float:
        return max(0.0, dt_s / self.speedup)


class PacedReader:
    """The station's side of a :class:`PacedClock`. :meth:`acknowledge` says "everything due up
    to ``t_s`` is done" (the station's loop calls it once per iteration with the time it read at
    the start); a station that falls behind (CPU-bound, stalled) thereby holds the emulator back
    instead of missing its heartbeat and setpoint deadlines in simulated time."""

    def __init__(
        self,
        speedup: float,
        sim: SharedValue,
        ack: SharedValue,
        *,
        unix_time_fn: Callable[[], float] = time.time,
    ) -> None:
        self.speedup = _check_speedup(speedup)
        self.sim = sim
        self.ack = ack
        self.unix_time_at_zero_s = unix_time_fn() - float(sim.value) / self.speedup

    def now(self) -> float:
        return float(self.sim.value)

    def acknowledge(self, t_s: float) -> None:
        if t_s > self.ack.value:
            self.ack.value = t_s

    def wall_delay_s(self, dt_s: float) -> float:
        return max(0.0, dt_s / self.speedup)

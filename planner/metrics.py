"""Task-uptime metrics TU1 and TU2 (paper eqs. for TU1/TU2, discretised as docs/design/model.md §6.2).

Per scenario, with A_i(t) the connection indicator of task i at step t = 0 .. tau-1 (measured before
the step's motion, a left Riemann sum):

* TU1 = (1/tau) sum_t (1/m) sum_i A_i(t)
* TU2 = (1/tau) sum_t  sum_i A_i(t) / #{i : A_i(t') for some t' in [0, t]}   (inclusive window)

When no task has been connected yet the TU2 integrand is 0/0 and counts as 0 by default (the step
still counts in tau); ``zero_over_zero='skip'`` drops such steps from the average and ``'one'``
counts them as 1, for sensitivity reports. Values are fractions in [0, 1]; reports print percent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["UptimeSeries", "uptime_series", "task_uptime", "task_uptime_reference"]


@dataclass(frozen=True)
class UptimeSeries:
    """Per-step series of one run (the paper's Fig. 2 curves), each shape (tau,)."""

    tu1_step: np.ndarray
    """Fraction of tasks connected at each step."""
    tu2_step: np.ndarray
    """Connected tasks over tasks ever connected so far (inclusive), 0/0 -> 0."""
    n_connected: np.ndarray
    """Number of connected tasks ("ret")."""
    n_ever_connected: np.ndarray
    """Number of tasks connected at least once up to and including this step."""

    @property
    def tu1(self) -> float:
        return float(self.tu1_step.mean()) if len(self.tu1_step) else 0.0

    @property
    def tu2(self) -> float:
        return float(self.tu2_step.mean()) if len(self.tu2_step) else 0.0


def uptime_series(connected: np.ndarray) -> UptimeSeries:
    """Per-step TU1/TU2 integrands from a connection record.

    Parameters
    ----------
    connected : (tau, m) bool
        A_i(t) for t = 0 .. tau-1 and every task i.
    """
    connected = np.asarray(connected, dtype=bool)
    if connected.ndim != 2:
        raise ValueError(f"connected must be (tau, m) bool, got shape {connected.shape}")
    tau, m = connected.shape
    n_conn = connected.sum(axis=1)
    ever = np.logical_or.accumulate(connected, axis=0) if tau else connected
    n_ever = ever.sum(axis=1)
    tu1_step = n_conn / m if m else np.zeros(tau)
    tu2_step = np.divide(n_conn, n_ever, out=np.zeros(tau), where=n_ever > 0)
    return UptimeSeries(tu1_step.astype(float), tu2_step, n_conn, n_ever)


def task_uptime(connected: np.ndarray, zero_over_zero: str = "zero") -> tuple[float, float]:
    """(TU1, TU2) of one run, as fractions.

    Parameters
    ----------
    connected : (tau, m) bool
    zero_over_zero : {'zero', 'skip', 'one'}
        Treatment of TU2 steps before any task was ever connected.
    """
    s = uptime_series(connected)
    if zero_over_zero == "zero":
        return s.tu1, s.tu2
    undefined = s.n_ever_connected == 0
    if zero_over_zero == "one":
        return s.tu1, float(np.where(undefined, 1.0, s.tu2_step).mean())
    if zero_over_zero == "skip":
        ok = ~undefined
        return s.tu1, float(s.tu2_step[ok].mean()) if ok.any() else 0.0
    raise ValueError(f"zero_over_zero must be 'zero', 'skip' or 'one', got {zero_over_zero!r}")


def task_uptime_reference(connected: np.ndarray) -> tuple[float, float]:
    """Slow, loop-by-loop transcription of the definitions (for tests)."""
    rows = [list(map(bool, r)) for r in connected]
    tau = len(rows)
    m = len(rows[0]) if tau else 0
    tu1 = tu2 = 0.0
    ever = [False] * m
    for t in range(tau):
        for i in range(m):
            ever[i] = ever[i] or rows[t][i]
        now = sum(rows[t])
        tu1 += now / m
        denom = sum(ever)
        tu2 += now / denom if denom else 0.0
    return (tu1 / tau, tu2 / tau) if tau else (0.0, 0.0)

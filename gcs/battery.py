"""A vehicle's battery drain, estimated from its own telemetry (no ground truth).

SYS_STATUS reports ``battery_remaining`` in whole percent, so consecutive readings mostly repeat
and a naive difference is 0 or a whole percent: useless as a rate. What *is* exact is the moment
the reported level changes: that is when the charge crossed a quantization step. The slope
between two such edges, over a window of a few minutes, is the drain without the quantization
error (for a steady drain, exactly); a level held longer than that rate predicts bounds the rate
from above (the charge dropped less than one step since the last edge), so a vehicle that lands
and stops drawing is seen to stop within a step's time, not a window's.

Per vehicle, a handful of floats: the fleet view (:mod:`gcs.fleet`) keeps one per row and feeds
it every :class:`gcs.events.BatteryReceived` with a remaining charge.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

__all__ = ["DrainEstimator", "QUANTUM_FRAC"]

#: One step of SYS_STATUS ``battery_remaining`` (1 %), as a fraction.
QUANTUM_FRAC = 0.01


@dataclass
class DrainEstimator:
    """Edge-to-edge slope of one vehicle's reported charge (module docstring)."""

    window_s: float = 180.0
    """Edges older than this (beyond the last two) are forgotten, seconds."""
    min_span_s: float = 10.0
    """Two edges closer than this give no rate yet (a single jump is not a slope)."""
    level: float = math.nan
    """The last reported level, fraction."""
    rate_per_s: float = math.nan
    """Edge-to-edge drain, fraction of capacity per second (NaN: not enough edges yet)."""
    last_edge_s: float = math.nan
    """When the level last changed downwards, seconds."""
    _edges: deque[tuple[float, float]] = field(default_factory=deque)

    def reset(self) -> None:
        """A new battery (a swap, a reboot): forget the old one's edges."""
        self.level = math.nan
        self.rate_per_s = math.nan
        self.last_edge_s = math.nan
        self._edges.clear()

    def update(self, t_s: float, frac: float) -> None:
        """One reported level ``frac`` at ``t_s``."""
        if math.isnan(self.level):
            self.level = frac  # the first report lands mid-step: not an edge
            return
        if frac > self.level + 0.5 * QUANTUM_FRAC:
            self.reset()  # charged: a swap, or the monitor recalibrated
            self.level = frac
            return
        if frac < self.level - 0.5 * QUANTUM_FRAC:
            self._edges.append((t_s, frac))
            self.level = frac
            self.last_edge_s = t_s
            while len(self._edges) > 2 and t_s - self._edges[0][0] > self.window_s:
                self._edges.popleft()
            (t0, f0), (t1, f1) = self._edges[0], self._edges[-1]
            if len(self._edges) >= 2 and t1 - t0 >= self.min_span_s:
                self.rate_per_s = (f0 - f1) / (t1 - t0)

    def drain_per_s(self, now_s: float) -> float:
        """The drain at ``now_s``: the edge slope, bounded by one step over the time since the
        last edge (NaN while unknown)."""
        return bounded_drain(self.rate_per_s, self.last_edge_s, now_s)


def bounded_drain(rate_per_s: float, last_edge_s: float, now_s: float) -> float:
    """``rate_per_s``, but at most one quantization step over the time since the last edge."""
    if math.isnan(rate_per_s):
        return math.nan
    since_s = now_s - last_edge_s
    if since_s > 0 and since_s * rate_per_s > QUANTUM_FRAC:
        return QUANTUM_FRAC / since_s
    return rate_per_s

"""Live task positions: tasks (crews, rovers) whose position comes from their own MAVLink system.

A task tracker is a MAVLink system the station never flies (``StationConfig.task_sysids``): its
GLOBAL_POSITION_INT arrives as :class:`gcs.events.TaskPositionReceived`, is converted to the
mission's local frame (the same geodetic origin as the fleet view), and replaces that task's
column in the planned task positions. Before a tracker's first fix its column is NaN (the operator
does not launch until every task has a position); afterwards the last fix is held when the
tracker falls silent, and :meth:`LiveTasks.silent` says which ones are.

Several tasks may not share one sysid (one tracker is one position); a sysid is matched on every
link, since a tracker may reach the station over a different radio than the drones.
"""

from __future__ import annotations

import logging
import math
from typing import Mapping

import numpy as np

from gcs.events import TaskPositionReceived
from gcs.fleet import MissionOrigin
from planner.geometry import geodetic_to_ned_m

__all__ = ["LiveTasks"]

log = logging.getLogger(__name__)


class LiveTasks:
    """The latest position of every live task, in the mission's local NE frame.

    Parameters
    ----------
    origin : the mission frame's origin
    columns : task column index -> MAVLink sysid of its tracker
    """

    def __init__(self, origin: MissionOrigin, columns: Mapping[int, int]) -> None:
        sysids = list(columns.values())
        if len(set(sysids)) != len(sysids):
            raise ValueError(f"two live tasks share a tracker sysid: {sorted(columns.items())}")
        self.origin = origin
        self._column_of = {int(s): int(c) for c, s in columns.items()}
        self._cols = np.array(sorted(self._column_of.values()), dtype=int)
        self._ne_m = np.full((len(self._cols), 2), np.nan)
        self._row_of_col = {int(c): k for k, c in enumerate(self._cols)}
        self._last_fix_s = np.full(len(self._cols), -math.inf)

    @property
    def sysids(self) -> tuple[int, ...]:
        return tuple(sorted(self._column_of))

    def __len__(self) -> int:
        return len(self._cols)

    def apply(self, event) -> bool:
        """Fold one event; True if it was a position of one of our trackers."""
        if not isinstance(event, TaskPositionReceived) or event.sysid not in self._column_of:
            return False
        k = self._row_of_col[self._column_of[event.sysid]]
        o = self.origin
        ned = geodetic_to_ned_m(event.lat_deg, event.lon_deg, event.alt_amsl_m,
                                o.lat_deg, o.lon_deg, o.alt_amsl_m)
        first = not math.isfinite(self._last_fix_s[k])
        self._ne_m[k] = ned[:2]
        self._last_fix_s[k] = max(self._last_fix_s[k], event.t_s)
        if first:
            log.info("live task (tracker sysid %d): first position %.1f m N, %.1f m E",
                     event.sysid, ned[0], ned[1])
        return True

    def fill(self, task_pos_m: np.ndarray) -> np.ndarray:
        """``task_pos_m`` (M, 2) with every live column replaced by its latest fix (NaN before
        the first one). Returns a new array."""
        out = np.array(task_pos_m, dtype=float, copy=True).reshape(-1, 2)
        if len(self._cols):
            out[self._cols] = self._ne_m
        return out

    def waiting_for(self) -> tuple[int, ...]:
        """Sysids of trackers not heard yet."""
        inv = {c: s for s, c in self._column_of.items()}
        return tuple(sorted(inv[int(c)] for k, c in enumerate(self._cols)
                            if not math.isfinite(self._last_fix_s[k])))

    def silent(self, now_s: float, timeout_s: float) -> tuple[int, ...]:
        """Sysids of trackers whose last fix is older than ``timeout_s`` (or never came)."""
        inv = {c: s for s, c in self._column_of.items()}
        return tuple(sorted(inv[int(c)] for k, c in enumerate(self._cols)
                            if now_s - self._last_fix_s[k] > timeout_s))

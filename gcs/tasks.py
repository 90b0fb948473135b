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
from collections.abc import Mapping

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
        # Row k of the arrays: task column _cols[k], tracker _sysid[k].
        self._cols = np.array(sorted(columns), dtype=int)
        self._sysid = np.array([columns[c] for c in self._cols], dtype=int)
        self._row_of = {int(sysid): k for k, sysid in enumerate(self._sysid)}
        self._ne_m = np.full((len(self._cols), 2), np.nan)
        self._last_fix_s = np.full(len(self._cols), -math.inf)

    @property
    def sysids(self) -> tuple[int, ...]:
        return tuple(sorted(self._row_of))

    def __len__(self) -> int:
        return len(self._cols)

    def apply(self, event: object) -> bool:
        """Fold one event; True if it was a position of one of our trackers."""
        if not isinstance(event, TaskPositionReceived) or event.sysid not in self._row_of:
            return False
        k = self._row_of[event.sysid]
        o = self.origin
        ned = geodetic_to_ned_m(
            event.lat_deg, event.lon_deg, event.alt_amsl_m, o.lat_deg, o.lon_deg, o.alt_amsl_m
        )
        first = not math.isfinite(self._last_fix_s[k])
        self._ne_m[k] = ned[:2]
        self._last_fix_s[k] = max(self._last_fix_s[k], event.t_s)
        if first:
            log.info(
                "live task (tracker sysid %d): first position %.1f m N, %.1f m E",
                event.sysid,
                ned[0],
                ned[1],
            )
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
        return self._sysids_where(~np.isfinite(self._last_fix_s))

    def silent(self, now_s: float, timeout_s: float) -> tuple[int, ...]:
        """Sysids of trackers whose last fix is older than ``timeout_s`` (or never came)."""
        return self._sysids_where(now_s - self._last_fix_s > timeout_s)

    def _sysids_where(self, rows: np.ndarray) -> tuple[int, ...]:
        return tuple(sorted(int(x) for x in self._sysid[rows]))

"""The rally step: the planner's rally points kept on every vehicle while the mission runs.

A mixin of :class:`gcs.operations.Operator`, active only when the operator was given a
:class:`gcs.rally.RallyKeeper` (``Operator(rally=...)``; :mod:`mission.flight.station_loop` gives one
when the planner publishes rally points: ``phireman-resilient`` with ``rally`` on):

* after every control tick the planner's points (:func:`gcs.rally.planner_rally_points_m`) are
  published to the keeper, which adopts them only when they moved enough (rate limit);
* every poll of the run and the end, every vehicle heard and in the plan that does not hold the
  current set gets an upload; the vehicle's replies (``MissionProtocolReceived`` events) are
  answered at once;
* at the end the set is cleared (a count of 0) and an ``rtl`` end command waits for the vehicle
  to confirm the clear (at most :data:`END_CLEAR_WAIT_S`), so the end RTL goes home, not to a rally
  point (both firmwares choose the RTL destination when RTL starts: ArduCopter
  ``ModeRTL::compute_return_target``, PX4 ``RTL::setRtlTypeAndDestination``);
* the firmware settings that make RTL use the points (:func:`gcs.rally.rally_param_writes`) are
  read and written in the audit, with the mission's limits (:mod:`gcs.operations.audit`).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs.link import LinkUsageError, UnknownVehicle
from gcs.operations._state import OperatorState
from gcs.operations.phases import Phase
from gcs.rally import MissionProtocolReceived, planner_rally_points_m

if TYPE_CHECKING:
    from gcs.fleet import FleetSnapshot

__all__ = ["RallyStep", "END_CLEAR_WAIT_S"]

log = logging.getLogger(__name__)

#: How long (station seconds) the end RTL of a vehicle waits for it to confirm that its rally
#: points are cleared (a lost link: it returns to the nearest rally point instead, still safe).
END_CLEAR_WAIT_S = 5.0


class RallyStep(OperatorState):
    """Rally points of :class:`gcs.operations.Operator` (see the module docstring)."""

    planner: Any

    def _send_rally(self, out: list[tuple[tuple[int, int], Any]], now_s: float) -> None:
        for vid, msg in out:
            try:
                self.station.send_message(vid, msg, now_s)
            except (UnknownVehicle, LinkUsageError) as exc:
                log.info("link %d sysid %d: rally message not sent: %s", *vid, exc)

    def _on_mission_protocol(self, event: MissionProtocolReceived, key: tuple[int, int]) -> None:
        if self.rally is not None:
            self._send_rally(self.rally.on_event(event, event.t_s), event.t_s)

    def _rally_after_tick(self, now_s: float) -> None:
        """The planner just planned: publish its rally points (the keeper rate-limits)."""
        if self.rally is not None and self._phase == Phase.RUN:
            self.rally.publish(planner_rally_points_m(self.planner), now_s)

    def _rally_poll(self, snap: FleetSnapshot, now_s: float) -> None:
        """Uploads to every vehicle heard and in the plan (run and end phases)."""
        if self.rally is None or self._phase not in (Phase.RUN, Phase.END):
            return
        self._rally_clear_at_end(now_s)
        rows = np.flatnonzero(~snap.lost & self._in_plan(snap)).tolist()
        self._send_rally(self.rally.poll([self._vid(snap, i) for i in rows], now_s), now_s)

    def _rally_clear_at_end(self, now_s: float) -> None:
        """In the end phase the set is empty (adopted at once, whatever the rate limit)."""
        assert self.rally is not None
        if (
            self._phase == Phase.END
            and self.rally.points_ne_m is not None
            and len(self.rally.points_ne_m)
        ):
            self.rally.publish(np.zeros((0, 2)), now_s, force=True)

    def _rally_holds_end(self, vid: tuple[int, int], now_s: float) -> bool:
        """True while ``vid``'s end RTL should wait for its rally points to be cleared (the
        end step asks before its first RTL, in the poll that entered the end: clear first)."""
        if self.rally is None:
            return False
        self._rally_clear_at_end(now_s)
        if self.rally.version == 0 or self.rally.up_to_date(vid):
            return False
        assert self.end_t0_s is not None  # set by begin_end
        return now_s - self.end_t0_s < END_CLEAR_WAIT_S

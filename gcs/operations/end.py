"""The end step: RTL or LAND every vehicle heard until it obeys, done once every vehicle heard
has landed (or at ``end_timeout_s``), then (``restore_params``) the previous value of every
parameter the station changed written back.

A mixin of :class:`gcs.operations.Operator` (split out of one 950-line module along this seam:
the end of a flight). It holds no state of its own: the attributes are the operator's
(``end_t0_s``, ``end_status``, ``_restore_sent_s``..., set up in ``Operator.__init__``).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from gcs.autopilot import adapter_for
from gcs.fleet import FleetSnapshot
from gcs.link import LinkUsageError, UnknownVehicle
from gcs.operations._state import OperatorState
from gcs.operations.config import OVERRIDE, _Row
from gcs.operations.phases import TRANSITIONS, Trigger

__all__ = ["EndStep"]

log = logging.getLogger(__name__)


class EndStep(OperatorState):
    """The end of a flight for :class:`gcs.operations.Operator` (see the module docstring)."""

    def begin_end(self, now_s: float) -> None:
        """Stop planning and send every vehicle home (RTL) or down (LAND)."""
        if Trigger.END not in TRANSITIONS[self.phase]:
            return  # ending already, done or refused: nothing to end
        self._enter(Trigger.END, now_s)
        self.end_t0_s = now_s
        for row in self._rows.values():
            row.next_action_s = -math.inf

    def _restore(self, now_s: float) -> bool:
        """Write back the previous value of every parameter the station changed (once); True
        while the echoes are awaited."""
        if self._restore_sent_s is None:
            self._restore_sent_s = now_s
            done: set[tuple[int, int, str]] = set()
            for c in list(reversed(self.param_changes)):
                key = (c["link_id"], c["sysid"], c["name"])
                if (
                    key in done
                    or c.get("purpose") == "restore"
                    or not c.get("ok")
                    or c.get("previous") is None
                ):
                    continue
                done.add(key)
                self._set_param(
                    key[:2], key[2], float(c["previous"]), float(c["value"]), "restore", now_s
                )
        return bool(self._sets_pending) and now_s - self._restore_sent_s < 10.0

    def _poll_end(self, snap: FleetSnapshot, now_s: float) -> None:
        """Send the end command until obeyed; done once every vehicle heard is on the ground
        (disarmed: ArduCopter and PX4 both disarm after landing at the end of RTL / LAND), or at
        ``end_timeout_s`` (:attr:`end_status` then says how many were still in the air)."""
        airborne = 0
        for i in np.flatnonzero(~snap.lost).tolist():
            if not snap.armed[i]:
                continue  # on the ground
            airborne += 1
            adapter = adapter_for(int(snap.autopilot[i]))
            mode = snap.mode[i]
            vid = self._vid(snap, i)
            # Obeying (or already coming down on its own, e.g. a battery failsafe LAND), or an
            # operator sent it home / down: the vehicle finishes on its own. One a forwarded
            # client took is the client's to bring down: never commanded behind its back.
            if mode in (adapter.rtl_mode, adapter.land_mode) or self.released.get(vid) in (
                "rtl",
                "land",
                OVERRIDE,
            ):
                continue
            row = self._rows.setdefault(i, _Row())
            if now_s < row.next_action_s:
                continue
            if self.config.end == "rtl" and self._rally_holds_end(vid, now_s):
                continue  # its rally points are being cleared first (gcs/operations/rally.py)
            row.next_action_s = now_s + self.config.action_retry_s
            try:
                self.station.clear_position_target(vid, now_s)
                if self.config.end == "rtl":
                    self.station.rtl(vid, now_s)
                else:
                    self.station.land(vid, now_s)
            except (LinkUsageError, UnknownVehicle, ValueError) as exc:
                log.info("link %d sysid %d: %s", *vid, exc)
        heard = int((~snap.lost).sum())
        self.end_status = {
            "on_ground": heard - airborne,
            "in_air": airborne,
            "not_heard": int(snap.lost.sum()),
        }
        if airborne == 0 or now_s - self._phase_since_s >= self.config.end_timeout_s:
            if self.config.restore_params and self._restore(now_s):
                return  # wait for the echoes (or restore_timeout_s)
            if airborne:
                log.info(
                    "end: %d vehicle(s) still in the air after %.0f s (returning on their own)",
                    airborne,
                    now_s - self._phase_since_s,
                )
            self._enter(Trigger.END_TIMEOUT if airborne else Trigger.LANDED, now_s)

"""The audit of a vehicle discovered after the fleet's pre-flight audit: it is kept on the ground
and out of the plan until it passed the same audit on its own.

A real drone powered on late, a SITL instance slow to boot or an emulated fleet slow to start
sends its first HEARTBEAT after the audit began (``discover_timeout_s`` ran out with part of the
fleet). Such a vehicle was once launched and flown with no parameter read at all. Now, in the
launch and run phases, each one goes through the fleet audit's steps, one vehicle at a time and
independently of the others: the same reads (:meth:`AuditStep._audit_names
<gcs.operations.audit.AuditStep._audit_names>`: lost-link, battery, the return altitude over
terrain, limits, rally settings) in the same rounds and timeouts, the same fixes with
``apply_failsafes``, the same verdict (:meth:`AuditStep._audit_report
<gcs.operations.audit.AuditStep._audit_report>`, ``override_audit`` honoured), then the limits
(``set_limits``) and the rally settings. Cleared, it joins the plan and is launched like any
vehicle the run reclaims (:meth:`LaunchStep._reclaim <gcs.operations.launch.LaunchStep._reclaim>`).
Refused, it stays on the ground for the whole flight: a log warning, an :class:`OperatorAction`
``audit`` in ``events.jsonl`` (through ``Operator.on_action``) and its verdict in
:meth:`LateAuditStep.late_audit_summary` (the summary's audit section).

A vehicle that reboots (the same link and sysid: a battery swap's power cycle) keeps its verdict:
its parameters persist across a power cycle (both firmwares keep them in their storage).

A mixin of :class:`gcs.operations.Operator`; its state is ``late_audits`` (set up in
``Operator.__init__``), one :class:`LateAudit` per late vehicle.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from gcs import audit as audit_mod
from gcs.fleet import FleetSnapshot
from gcs.operations._state import OperatorState
from gcs.operations.audit import OPTIONAL_GRACE_S
from gcs.operations.config import OperatorAction
from gcs.operations.phases import Phase

__all__ = ["LateAuditStep", "LateAudit", "LateStep", "LATE_AUDIT"]

log = logging.getLogger(__name__)

#: The ``action`` of the :class:`OperatorAction` recording a late vehicle's verdict in
#: ``events.jsonl`` (``source`` :data:`LATE_AUDIT_SOURCE`, ``result`` the verdict).
LATE_AUDIT = "audit"
LATE_AUDIT_SOURCE = "pre-flight audit"


class LateStep(StrEnum):
    """Where a late vehicle's audit is."""

    READ = "read"
    FIX = "fix"
    """Fixes sent (``apply_failsafes``), waiting for their echoes; then the verdict."""
    LIMITS = "limits"
    RALLY = "rally"
    CLEARED = "cleared"
    REFUSED = "refused"


@dataclass
class LateAudit:
    """One late vehicle's audit (times are station seconds)."""

    started_s: float
    step_since_s: float
    step: LateStep = LateStep.READ
    round: int = 1
    last_param_s: float = -math.inf
    """When the last of its audit reads was answered (the reads' deadline runs from it)."""
    initial_report: audit_mod.AuditReport | None = None
    """Its audit before ``apply_failsafes`` wrote anything (None: nothing was written)."""
    report: audit_mod.AuditReport | None = None
    """Its verdict (None while reading or fixing)."""

    @property
    def cleared(self) -> bool:
        return self.step == LateStep.CLEARED

    @property
    def blocking(self) -> list[str]:
        """The blocking findings of its verdict, ``NAME: why`` (none before the verdict)."""
        if self.report is None:
            return []
        return [f"{f.param}: {f.message}" for va in self.report.vehicles for f in va.blocking]

    @property
    def verdict(self) -> str:
        """``pending``, ``cleared``, ``overridden`` or ``refused``."""
        if self.step == LateStep.REFUSED:
            return "refused"
        if self.report is None or not self.cleared:
            return "pending"
        return "overridden" if self.report.overridden else "cleared"


class LateAuditStep(OperatorState):
    """The audit of vehicles discovered after the fleet's (see the module docstring)."""

    late_audits: dict[tuple[int, int], LateAudit]  # set up in Operator.__init__

    def _audit_gate(self, snap: FleetSnapshot) -> np.ndarray:
        """(N,) bool: rows the audit lets fly (every row with the audit off; else audited with
        the fleet, or cleared on their own)."""
        ok = np.ones(snap.n_vehicles, dtype=bool)
        if not self.config.audit or len(self._audit_vids) >= snap.n_vehicles:
            return ok  # (fleet rows never go away: every row is one the fleet audit read)
        for i in range(snap.n_vehicles):
            vid = self._vid(snap, i)
            if vid not in self._audit_vids:
                la = self.late_audits.get(vid)
                ok[i] = la is not None and la.cleared
        return ok

    def _late_audit_heard(self, vid: tuple[int, int], t_s: float) -> bool:
        """An audit parameter of ``vid`` was answered: True if its late audit is reading."""
        la = self.late_audits.get(vid)
        if la is None or la.step != LateStep.READ:
            return False
        la.last_param_s = max(la.last_param_s, t_s)
        return True

    def _poll_late_audits(self, snap: FleetSnapshot, now_s: float) -> None:
        """Launch and run phases: start the audit of every vehicle the fleet audit did not
        cover, and advance those under way."""
        if not self.config.audit or self._phase not in (Phase.LAUNCH, Phase.RUN):
            return
        if snap.n_vehicles <= len(self._audit_vids) and not self.late_audits:
            return  # the common case: every vehicle was audited with the fleet
        for i in range(snap.n_vehicles):
            vid = self._vid(snap, i)
            if vid in self._audit_vids:
                continue
            la = self.late_audits.get(vid)
            if la is None:
                la = self.late_audits[vid] = LateAudit(started_s=now_s, step_since_s=now_s)
                log.info(
                    "link %d sysid %d was discovered after the pre-flight audit: it stays on the "
                    "ground until it passed the audit on its own",
                    *vid,
                )
                self._late_request(
                    vid, self._audit_names(int(snap.autopilot[i]), {}, first=True), now_s
                )
            if la.step not in (LateStep.CLEARED, LateStep.REFUSED):
                self._late_advance(snap, i, vid, la, now_s)

    def _late_request(self, vid: tuple[int, int], names: list[str], now_s: float) -> None:
        for name in names:
            self._params_pending.add((*vid, name))
            self.station.request_param(vid, name, now_s)

    def _late_pending(self, pending: set[tuple[int, int, str]], vid: tuple[int, int]) -> list[str]:
        return [p[2] for p in pending if p[0] == vid[0] and p[1] == vid[1]]

    def _late_advance(
        self, snap: FleetSnapshot, i: int, vid: tuple[int, int], la: LateAudit, now_s: float
    ) -> None:
        """One vehicle's audit, as :meth:`AuditStep._poll_audit
        <gcs.operations.audit.AuditStep._poll_audit>` does it for the fleet."""
        cfg = self.config
        autopilot = int(snap.autopilot[i])
        if la.step == LateStep.READ:
            pending = self._late_pending(self._params_pending, vid)
            in_time = now_s - max(la.started_s, la.last_param_s) < cfg.audit_timeout_s
            if pending and in_time:
                required = [n for n in pending if not self._optional_param(n)]
                if required or now_s - la.last_param_s < OPTIONAL_GRACE_S:
                    return
            for name in pending:  # optional ones past the grace, or every read past the timeout
                self._params_pending.discard((*vid, name))
                try:
                    self.station.link(vid[0]).cancel_param(vid[1], name, now_s)
                except (KeyError, IndexError):
                    pass
            if in_time and la.round < cfg.audit_rounds:
                la.round += 1
                if not snap.lost[i]:
                    names = self._audit_names(autopilot, self._params.get(vid, {}), first=False)
                    self._late_request(vid, names, now_s)
                if self._late_pending(self._params_pending, vid):
                    return
            la.step, la.step_since_s = LateStep.FIX, now_s
            if cfg.apply_failsafes:
                before = self._write_fixes(self._late_vehicles(vid, autopilot), now_s)
                if self._late_pending(self._sets_pending, vid):
                    la.initial_report = before
                    return
        if la.step == LateStep.FIX:
            if self._late_waits_for_writes(vid, la, now_s):
                return
            report = self._audit_report(
                self._late_vehicles(vid, autopilot), override=cfg.override_audit
            )
            la.report = report
            if not report.cleared_to_fly:
                la.step, la.step_since_s = LateStep.REFUSED, now_s
                log.warning(
                    "link %d sysid %d, discovered after the pre-flight audit, failed it: it stays "
                    "on the ground for the whole flight\n%s",
                    *vid,
                    report.summary(),
                )
                self._late_record(vid, la, now_s)
                return
            if report.overridden:
                log.warning(
                    "pre-flight audit of link %d sysid %d OVERRIDDEN:\n%s", *vid, report.summary()
                )
            la.step, la.step_since_s = LateStep.LIMITS, now_s
            if self._limits_wanted():
                self._send_limits(self._late_vehicles(vid, autopilot), now_s)
        if la.step == LateStep.LIMITS:
            if self._late_waits_for_writes(vid, la, now_s):
                return
            la.step, la.step_since_s = LateStep.RALLY, now_s
            if self.rally is not None:
                self._send_rally_params(self._late_vehicles(vid, autopilot), now_s)
        if la.step == LateStep.RALLY:
            if self._late_waits_for_writes(vid, la, now_s):
                return
            la.step, la.step_since_s = LateStep.CLEARED, now_s
            log.info("link %d sysid %d passed the pre-flight audit: it may fly", *vid)
            self._late_record(vid, la, now_s)

    def _late_waits_for_writes(self, vid: tuple[int, int], la: LateAudit, now_s: float) -> bool:
        """Its writes of this step still unconfirmed (the link ends every one with Confirmed or
        Failed; ``audit_timeout_s`` is a backstop, as for the fleet)."""
        return bool(self._late_pending(self._sets_pending, vid)) and (
            now_s - la.step_since_s < self.config.audit_timeout_s
        )

    def _late_vehicles(
        self, vid: tuple[int, int], autopilot: int
    ) -> dict[tuple[int, int], tuple[int, dict[str, float]]]:
        return {vid: (autopilot, self._params.get(vid, {}))}

    def _late_record(self, vid: tuple[int, int], la: LateAudit, now_s: float) -> None:
        """The verdict in ``events.jsonl`` (an :class:`OperatorAction` ``audit``)."""
        assert la.report is not None  # recorded at the verdict
        blocking = la.blocking
        result = la.verdict + (f" ({'; '.join(blocking)})" if blocking else "")
        if self.on_action is not None:
            self.on_action(
                OperatorAction(now_s, LATE_AUDIT, vid[0], vid[1], LATE_AUDIT_SOURCE, result)
            )

    def late_audit_summary(self) -> list[dict[str, Any]]:
        """Per vehicle discovered after the fleet audit: ``link_id``, ``sysid``, ``verdict``
        (:attr:`LateAudit.verdict`), ``started_s`` and the ``blocking`` findings of its
        verdict (``NAME: why``)."""
        out = []
        for vid, la in sorted(self.late_audits.items()):
            out.append(
                {
                    "link_id": vid[0],
                    "sysid": vid[1],
                    "verdict": la.verdict,
                    "started_s": la.started_s,
                    "blocking": la.blocking,
                }
            )
        return out

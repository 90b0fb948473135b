"""The audit step: lost-link parameter reads in rounds, ``apply_failsafes`` fixes and the
mission's speed limits, every write confirmed by its PARAM_VALUE echo.

A mixin of :class:`gcs.operations.Operator` (split out of one 950-line module along this seam:
everything that reads or writes a vehicle's parameters, and the PARAM_* events that answer it).
It holds no state of its own: the attributes are the operator's (``_params``,
``_params_pending``, ``_param_types``, ``_sets_pending``, ``param_changes``, ``audit_report``...,
set up in ``Operator.__init__``).
"""

from __future__ import annotations

import logging
import math

from gcs import audit as audit_mod
from gcs import limits as limits_mod
from gcs import rally as rally_mod
from gcs.events import ParamReceived, ParamSetConfirmed, ParamSetFailed, ParamTimedOut
from gcs.fleet import FleetSnapshot
from gcs.link import UnknownVehicle
from gcs.landing import RTL_ALT_NAMES
from gcs.operations._state import OperatorState
from gcs.operations.phases import Phase, Trigger

__all__ = ["AuditStep"]

log = logging.getLogger(__name__)

#: (link_id, sysid) -> (MAV_AUTOPILOT, the parameters read from it).
_Vehicles = dict[tuple[int, int], tuple[int, dict[str, float]]]

#: After every required audit read was answered, how long optional ones are still waited for
#: (station seconds): a firmware's answers to one burst of reads arrive within a fraction of it.
OPTIONAL_GRACE_S = 1.5


class AuditStep(OperatorState):
    """Parameter reads and writes of :class:`gcs.operations.Operator` (see the module docstring)."""

    # ------------------------------------------------------------------ events

    def _on_param_received(self, event: ParamReceived, key: tuple[int, int]) -> None:
        self._last_param_s = max(self._last_param_s, event.t_s)
        self._params.setdefault(key, {})[event.name] = event.value
        self._param_types.setdefault(key, {})[event.name] = event.param_type
        self._params_pending.discard((*key, event.name))
        # Renamed parameters: the firmware has one spelling; stop asking for the other.
        for alt in audit_mod.ALTERNATIVE_NAMES.get(event.name, ()):
            if (*key, alt) in self._params_pending:
                self._params_pending.discard((*key, alt))
                try:
                    self.station.link(key[0]).cancel_param(key[1], alt, event.t_s)
                except (KeyError, IndexError):
                    pass
        late = self._late_audit_heard(key, event.t_s)  # a vehicle discovered after the audit
        for extra in audit_mod.FOLLOW_UP_PARAMS.get(event.name, ()):
            if (self.phase == Phase.AUDIT or late) and extra not in self._params.get(key, {}):
                self._params_pending.add((*key, extra))
                self.station.request_param(key, extra, event.t_s)

    def _on_param_timed_out(self, event: ParamTimedOut, key: tuple[int, int]) -> None:
        self._params_pending.discard((*key, event.name))

    def _on_param_set(
        self, event: ParamSetConfirmed | ParamSetFailed, key: tuple[int, int]
    ) -> None:
        """A write's outcome (confirmed by its echo, or failed): recorded in ``param_changes``."""
        if (*key, event.name) not in self._sets_pending:
            return
        self._sets_pending.discard((*key, event.name))
        ok = isinstance(event, ParamSetConfirmed)
        change = {
            "link_id": key[0],
            "sysid": key[1],
            "name": event.name,
            "previous": event.previous if isinstance(event, ParamSetConfirmed) else None,
            "value": event.value,
            "ok": ok,
            "reason": event.reason if isinstance(event, ParamSetFailed) else "",
        }
        if isinstance(event, ParamSetFailed):
            change["requested"] = event.requested
        for c in reversed(self.param_changes):  # the latest write of this name
            if (c["link_id"], c["sysid"], c["name"]) == (*key, event.name):
                change["previous"] = c["previous"]
                c.update(change)
                break
        (log.info if ok else log.warning)(
            "link %d sysid %d: %s %s",
            *key,
            event.name,
            f"set to {event.value:g}" if ok else f"NOT set: {change['reason']}",
        )

    # ------------------------------------------------------------------ the audit phase

    def _start_audit(self, snap: FleetSnapshot, now_s: float) -> None:
        """Discovery is over: request the audit's (and the limits') parameters of every vehicle,
        or launch at once when the audit is off."""
        log.info("discovered %d vehicle(s)", snap.n_vehicles)
        if not self.config.audit:
            self._start_launch(snap, now_s, Trigger.FOUND_UNAUDITED)
            return
        self._enter(Trigger.FOUND, now_s)
        for i in range(snap.n_vehicles):
            vid = self._vid(snap, i)
            self._audit_vids.add(vid)
            for name in self._audit_names(int(snap.autopilot[i]), {}, first=True):
                self._params_pending.add((*vid, name))
                self.station.request_param(vid, name, now_s)

    def _audit_names(self, autopilot: int, got: dict[str, float], *, first: bool) -> list[str]:
        """The parameters the audit reads of one vehicle that are not in ``got`` yet: the
        lost-link ones, the limits (``set_limits``), the battery's and the return altitude, the
        landing's (with a relay rotation, gcs/landing.py), the rally settings (with a rally
        keeper). A later round (``first`` False) leaves out the
        optional ones (gcs/audit.py OPTIONAL_PARAMS: absent on some firmware versions)."""
        names = [
            n
            for n in audit_mod.params_still_needed(autopilot, got)
            if first or n not in audit_mod.OPTIONAL_PARAMS
        ]
        extra: list[str] = []
        if self._limits_wanted():  # vehicles discovered late, reads lost: the limits too
            extra += self._limit_names(autopilot)
        extra += self._battery_params(autopilot)
        extra += self._rtl_params(autopilot)  # over terrain: the return altitude
        extra += self._rotation_landing_params(autopilot)  # with a rotation: its landing
        if self.rally is not None:  # the settings that make RTL use rally points
            extra += rally_mod.RALLY_PARAMS.get(autopilot, ())
        names += [n for n in extra if n not in got and n not in names]
        return names

    def _audit_report(
        self, vehicles: _Vehicles, *, override: bool = False
    ) -> audit_mod.AuditReport:
        """The audit of ``vehicles`` with the mission's settings (battery, return altitude)."""
        cfg = self.config
        return audit_mod.audit_fleet(
            vehicles,
            self.gcs_sysid,
            override=override,
            battery=cfg.battery_audit,
            battery_low_frac=cfg.battery_low_frac,
            rtl_min_alt_m=cfg.rtl_min_alt_m,
        )

    def _poll_audit(self, snap: FleetSnapshot, now_s: float) -> None:
        """Wait for the reads (in rounds), fix (``apply_failsafes``), audit, write the limits;
        then launch, or refuse."""
        # The reads' deadline runs from the last answer: 50 PX4 vehicles have some 850
        # parameters to read, 16 in flight per link, more than a minute while every read is
        # answered; a link that keeps answering is not a dead one.
        in_time = now_s - max(self._phase_since_s, self._last_param_s) < self.config.audit_timeout_s
        if self._params_pending and in_time:
            # Optional parameters (absent on some firmware versions, gcs/audit.py
            # OPTIONAL_PARAMS) are not waited for once every other read has been answered for
            # OPTIONAL_GRACE_S: a firmware without them would otherwise hold the audit for a
            # whole read timeout with retries (~10 s on PX4 1.18: COM_OBL_ACT), and a station
            # restarted in flight would reclaim its vehicles that much later.
            required = [p for p in self._params_pending if not self._optional_param(p[2])]
            if required or now_s - self._last_param_s < OPTIONAL_GRACE_S:
                return
            for link_id, sysid, name in sorted(self._params_pending):
                try:
                    self.station.link(link_id).cancel_param(sysid, name, now_s)
                except (KeyError, IndexError):
                    pass
            self._params_pending.clear()
        if in_time and self._audit_round < self.config.audit_rounds:
            # Another round for whatever timed out (a loaded link, a vehicle still booting);
            # names a firmware does not have (the other GCS-sysid spelling) just time out again.
            self._audit_round += 1
            for i in range(snap.n_vehicles):
                vid = self._vid(snap, i)
                self._audit_vids.add(vid)  # discovered during the audit: in it from this round
                names = self._audit_names(
                    int(snap.autopilot[i]), self._params.get(vid, {}), first=False
                )
                if snap.lost[i]:
                    continue
                for name in names:
                    self._params_pending.add((*vid, name))
                    self.station.request_param(vid, name, now_s)
            if self._params_pending:
                return
        # The vehicles the reads were asked of; one discovered after the last round is audited
        # on its own once the launch starts (gcs/operations/late_audit.py).
        vehicles = {
            self._vid(snap, i): (int(snap.autopilot[i]), self._params.get(self._vid(snap, i), {}))
            for i in range(snap.n_vehicles)
            if self._vid(snap, i) in self._audit_vids
        }
        if self.config.apply_failsafes:
            if self._fixes_sent_s is None:
                if self._send_fixes(vehicles, now_s):
                    return
            elif self._sets_pending and now_s - self._fixes_sent_s < self.config.audit_timeout_s:
                return  # the link ends every set with Confirmed or Failed; this is a backstop
        report = self._audit_report(vehicles, override=self.config.override_audit)
        self.audit_report = report
        if not report.cleared_to_fly:
            log.warning("pre-flight audit refused the flight:\n%s", report.summary())
            self.refusal = "the pre-flight audit found unsafe lost-link settings"
            self._enter(Trigger.UNSAFE, now_s)
            return
        if report.overridden:
            log.warning("pre-flight audit OVERRIDDEN:\n%s", report.summary())
        if self._limits_wanted():
            if self._limits_sent_s is None:
                self._limits_sent_s = now_s
                if self._send_limits(vehicles, now_s):
                    return
            elif self._sets_pending and now_s - self._limits_sent_s < self.config.audit_timeout_s:
                return
        if self.rally is not None:
            if self._rally_params_sent_s is None:
                self._rally_params_sent_s = now_s
                if self._send_rally_params(vehicles, now_s):
                    return
            elif (
                self._sets_pending
                and now_s - self._rally_params_sent_s < self.config.audit_timeout_s
            ):
                return
        self._rotation_use_landing(vehicles)
        self._start_launch(snap, now_s, Trigger.CLEARED)

    def _battery_params(self, autopilot: int) -> tuple[str, ...]:
        """The battery-failsafe parameters to read (none with ``battery_audit`` off)."""
        if self.config.battery_audit == "off":
            return ()
        return audit_mod.BATTERY_AUDIT_PARAMS.get(autopilot, ())

    def _optional_param(self, name: str) -> bool:
        """A read not waited for past OPTIONAL_GRACE_S: the ones some firmware versions lack
        (gcs/audit.py OPTIONAL_PARAMS) and, read for the rotation's landing alone, the return
        altitude (an unanswered one lands from the firmware's default, gcs/landing.py). Over
        terrain the return altitude is the audit's own, and waited for."""
        if name in audit_mod.OPTIONAL_PARAMS:
            return True
        return self.config.rtl_min_alt_m is None and name in RTL_ALT_NAMES

    def _rtl_params(self, autopilot: int) -> tuple[str, ...]:
        """Over terrain (``rtl_min_alt_m``), the return-altitude parameter to read."""
        rtl = audit_mod.RTL_ALT_PARAMS.get(autopilot)
        if self.config.rtl_min_alt_m is None or rtl is None:
            return ()
        return (rtl[0],)

    def _limit_names(self, autopilot: int) -> tuple[str, ...]:
        """The limit parameters read and written on this firmware (gcs.limits)."""
        return limits_mod.limit_names(autopilot, self.config.descent_rate_m_s is not None)

    def _limits_wanted(self) -> bool:
        return self.config.set_limits and self.config.max_speed_m_s is not None

    def _send_limits(self, vehicles: _Vehicles, now_s: float) -> bool:
        """PARAM_SET the mission's speed / climb limits where a vehicle differs; True if any
        write was sent (each is confirmed by its PARAM_VALUE echo, ``param_changes``)."""
        cfg = self.config
        climb = cfg.climb_rate_m_s if cfg.climb_rate_m_s is not None else math.inf
        assert cfg.max_speed_m_s is not None  # only called when _limits_wanted()
        for vid, (autopilot, params) in sorted(vehicles.items()):
            wanted = self._limit_names(autopilot)
            missing = [n for n in wanted if n not in params]
            if missing:
                self.limit_warnings.append(
                    f"link {vid[0]} sysid {vid[1]}: could not read {', '.join(missing)}: the "
                    "mission's speed limits are not enforced by this vehicle"
                )
                log.warning("%s", self.limit_warnings[-1])
            if not math.isfinite(climb):
                params = {
                    k: v
                    for k, v in params.items()
                    if k != "WPNAV_SPEED_UP" and k != "MPC_Z_VEL_MAX_UP"
                }
            for name, value in limits_mod.limit_writes(
                autopilot,
                params,
                cfg.max_speed_m_s,
                climb if math.isfinite(climb) else 1.0,
                cfg.descent_rate_m_s,
            ):
                self._set_param(vid, name, value, params.get(name), "limit", now_s)
        return bool(self._sets_pending)

    def _send_rally_params(self, vehicles: _Vehicles, now_s: float) -> bool:
        """PARAM_SET what makes each vehicle's RTL use the rally points (gcs/rally.py
        RALLY_PARAMS); True if any write was sent."""
        for vid, (autopilot, params) in sorted(vehicles.items()):
            for name, value in rally_mod.rally_param_writes(autopilot, params):
                self._set_param(vid, name, value, params.get(name), "rally", now_s)
        return bool(self._sets_pending)

    def _set_param(
        self,
        vid: tuple[int, int],
        name: str,
        value: float,
        previous: float | None,
        purpose: str,
        now_s: float,
    ) -> bool:
        ptype = self._param_types.get(vid, {}).get(name)
        if ptype is None:
            return False
        try:
            self.station.set_param(vid, name, value, ptype, now_s, previous=previous)
        except (UnknownVehicle, ValueError) as exc:
            log.warning("link %d sysid %d: cannot set %s: %s", *vid, name, exc)
            return False
        self._sets_pending.add((*vid, name))
        self.param_changes.append(
            {
                "link_id": vid[0],
                "sysid": vid[1],
                "name": name,
                "previous": previous,
                "value": value,
                "ok": None,
                "reason": "pending",
                "purpose": purpose,
            }
        )
        log.info(
            "link %d sysid %d: setting %s %g -> %g (%s)",
            *vid,
            name,
            math.nan if previous is None else previous,
            value,
            purpose,
        )
        return True

    def _send_fixes(self, vehicles: _Vehicles, now_s: float) -> bool:
        """PARAM_SET every fixable blocking finding; True if any write was sent."""
        before = self._write_fixes(vehicles, now_s)
        self._fixes_sent_s = now_s
        if self._sets_pending:
            self.initial_audit_report = before
            return True
        return False

    def _write_fixes(self, vehicles: _Vehicles, now_s: float) -> audit_mod.AuditReport:
        """PARAM_SET every fixable blocking finding of ``vehicles``; returns their audit before
        the writes."""
        cfg = self.config
        before = self._audit_report(vehicles)
        for va in before.unsafe:
            vid = (va.link_id, va.sysid)
            autopilot, params = vehicles[vid]
            fixes = audit_mod.failsafe_fixes(autopilot, params, self.gcs_sysid)
            if cfg.battery_audit == "require":
                fixes += audit_mod.battery_fixes(autopilot, params, cfg.battery_low_frac)
            if cfg.rtl_min_alt_m is not None:
                fixes += audit_mod.rtl_altitude_fixes(autopilot, params, cfg.rtl_min_alt_m)
            for name, value in fixes:
                self._set_param(vid, name, value, params.get(name), "failsafe", now_s)
        return before

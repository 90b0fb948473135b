"""Pre-flight audit of lost-link behaviour: pure functions over parameter dicts.

The station reads the parameters listed in :data:`AUDIT_PARAMS` (``StationLink.request_param``),
then :func:`audit_fleet` says, per vehicle, what a lost link would do and whether it is safe to
fly. Rules (MAVLINK_NOTES §1.4, §1.5, §3):

ArduPilot
  * ``FS_GCS_ENABLE`` = 0: no GCS failsafe; a vehicle cut off keeps flying its last target
    -> **blocking**. 2 (continue AUTO) -> warning. Others (RTL / SmartRTL / Land) fine.
  * ``SYSID_MYGCS`` (newer: ``MAV_GCS_SYSID``, optional range up to ``MAV_GCS_SYSID_HI``) must
    include our sysid, else our heartbeats do not count for the failsafe -> **blocking**.
  * ``FS_GCS_TIMEOUT`` > 10 s -> warning; ``GUID_TIMEOUT`` reported (velocity targets only).
PX4
  * ``NAV_DLL_ACT`` = 0 (data-link loss action disabled, the default) -> **blocking**;
    5/6 (terminate / disarm: falls out of the sky) -> **blocking**.
  * ``COM_OBL_RC_ACT`` (offboard loss action) 6/7 (terminate / disarm) -> **blocking**;
    1/2 (altitude / manual: needs a pilot) -> warning. Without a manual control signal (no RC,
    the usual swarm set-up) PX4 falls back from 0-2 to Return (``Failsafe::checkModeFallback``,
    src/modules/commander/failsafe/failsafe.cpp); the finding says so.
  * ``COM_OF_LOSS_T``, ``COM_DL_LOSS_T`` reported.
Unknown autopilot or a parameter that could not be read -> **blocking**.

A blocking finding refuses the flight unless ``override=True`` (the verdict then says so).

:func:`failsafe_fixes` lists the parameter writes that clear the *fixable* blocking findings
(``phireman fly --apply-failsafes``): ArduPilot ``FS_GCS_ENABLE`` 0 -> 1 (RTL), the GCS sysid
(whichever of ``SYSID_MYGCS`` / ``MAV_GCS_SYSID`` the vehicle has) -> ours; PX4 ``NAV_DLL_ACT``
0 / 5 / 6 -> 2 (Return). A parameter that could not be read, an unknown autopilot or a
dangerous offboard-loss action is not fixed here and still blocks.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from gcs.autopilot import ARDUPILOT, PX4

__all__ = ["Finding", "VehicleAudit", "AuditReport", "AUDIT_PARAMS", "params_to_read",
           "ALTERNATIVE_NAMES", "FOLLOW_UP_PARAMS", "OPTIONAL_PARAMS", "params_still_needed",
           "audit_ardupilot", "audit_px4", "audit_vehicle", "audit_fleet", "failsafe_fixes",
           "FS_GCS_ENABLE_FIX", "NAV_DLL_ACT_FIX"]

#: What to read per autopilot. ArduPilot alternatives: old or new GCS-sysid names.
AUDIT_PARAMS: dict[int, tuple[str, ...]] = {
    ARDUPILOT: ("FS_GCS_ENABLE", "FS_GCS_TIMEOUT", "GUID_TIMEOUT", "SYSID_MYGCS",
                "MAV_GCS_SYSID", "MAV_GCS_SYSID_HI"),
    PX4: ("COM_OF_LOSS_T", "COM_OBL_RC_ACT", "NAV_DLL_ACT", "COM_DL_LOSS_T"),
}

BLOCKING, WARNING, INFO = "blocking", "warning", "info"

_FS_GCS_ENABLE = {0: "disabled", 1: "RTL", 2: "continue AUTO, else RTL", 3: "SmartRTL or RTL",
                  4: "SmartRTL or Land", 5: "Land", 6: "auto DO_LAND_START or RTL",
                  7: "brake or land"}
_NAV_DLL_ACT = {0: "disabled", 1: "hold", 2: "return", 3: "land", 5: "terminate", 6: "disarm"}
_COM_OBL_RC_ACT = {0: "position", 1: "altitude", 2: "manual", 3: "return", 4: "land", 5: "hold",
                   6: "terminate", 7: "disarm"}


#: Spellings of one parameter across firmware versions: once one is read, the others are not
#: asked for again (a firmware has only one of them; re-reading the other just times out).
ALTERNATIVE_NAMES: dict[str, tuple[str, ...]] = {
    "SYSID_MYGCS": ("MAV_GCS_SYSID",), "MAV_GCS_SYSID": ("SYSID_MYGCS",)}
#: Read only once the key was read (the GCS-sysid range exists only with the new name).
FOLLOW_UP_PARAMS: dict[str, tuple[str, ...]] = {"MAV_GCS_SYSID": ("MAV_GCS_SYSID_HI",)}
#: Absent on many firmwares and not needed for a verdict: never re-requested.
OPTIONAL_PARAMS = frozenset({"MAV_GCS_SYSID_HI"})


def params_to_read(autopilot: int) -> tuple[str, ...]:
    """Parameter names to request from a vehicle with this HEARTBEAT.autopilot (all of them;
    :func:`params_still_needed` says which are still worth asking for)."""
    return AUDIT_PARAMS.get(autopilot, ())


def params_still_needed(autopilot: int, got: Mapping[str, float]) -> list[str]:
    """Names still to request, given the values ``got`` so far: a name is skipped once read, once
    another spelling of it was read, while its follow-up key is unread, or (optional) at all
    unless its key was read."""
    follow = {f: k for k, fs in FOLLOW_UP_PARAMS.items() for f in fs}
    out = []
    for name in params_to_read(autopilot):
        if name in got or any(a in got for a in ALTERNATIVE_NAMES.get(name, ())):
            continue
        key = follow.get(name)
        if key is not None and key not in got:
            continue
        out.append(name)
    return out


@dataclass(frozen=True)
class Finding:
    severity: str
    """``blocking``, ``warning`` or ``info``."""
    param: str
    message: str


@dataclass(frozen=True)
class VehicleAudit:
    link_id: int
    sysid: int
    autopilot: int
    findings: tuple[Finding, ...]

    @property
    def blocking(self) -> tuple[Finding, ...]:
        return tuple(f for f in self.findings if f.severity == BLOCKING)

    @property
    def safe(self) -> bool:
        return not self.blocking


@dataclass(frozen=True)
class AuditReport:
    vehicles: tuple[VehicleAudit, ...]
    overridden: bool = False
    cleared_to_fly: bool = field(default=False)
    """True when no vehicle has a blocking finding, or the operator overrode them."""

    @property
    def unsafe(self) -> tuple[VehicleAudit, ...]:
        return tuple(v for v in self.vehicles if not v.safe)

    def summary(self) -> str:
        lines = []
        for v in self.vehicles:
            state = "ok" if v.safe else "UNSAFE"
            lines.append(f"link {v.link_id} sysid {v.sysid}: {state}")
            lines += [f"  [{f.severity}] {f.param}: {f.message}" for f in v.findings]
        verdict = ("cleared to fly" if self.cleared_to_fly and not self.overridden else
                   "cleared to fly (OVERRIDDEN: unsafe lost-link settings)" if self.cleared_to_fly
                   else "REFUSED: fix the settings above or override")
        lines.append(verdict)
        return "\n".join(lines)


def _missing(name: str) -> Finding:
    return Finding(BLOCKING, name, "could not be read; lost-link behaviour unknown")


def audit_ardupilot(params: Mapping[str, float], gcs_sysid: int = 255) -> tuple[Finding, ...]:
    out: list[Finding] = []
    fs = params.get("FS_GCS_ENABLE")
    if fs is None:
        out.append(_missing("FS_GCS_ENABLE"))
    else:
        what = _FS_GCS_ENABLE.get(int(fs), f"unknown value {fs:g}")
        if int(fs) == 0:
            out.append(Finding(BLOCKING, "FS_GCS_ENABLE", "0: no GCS failsafe; a vehicle cut off "
                               "from the station keeps flying its last target"))
        elif int(fs) == 2:
            out.append(Finding(WARNING, "FS_GCS_ENABLE", f"2: {what}"))
        else:
            out.append(Finding(INFO, "FS_GCS_ENABLE", f"{int(fs)}: {what}"))
    timeout = params.get("FS_GCS_TIMEOUT")
    if timeout is not None:
        sev = WARNING if timeout > 10 else INFO
        out.append(Finding(sev, "FS_GCS_TIMEOUT", f"{timeout:g} s after the last GCS heartbeat"))
    guid = params.get("GUID_TIMEOUT")
    if guid is not None:
        out.append(Finding(INFO, "GUID_TIMEOUT", f"{guid:g} s (velocity targets only; position "
                           "targets persist and are re-sent every second)"))
    # SYSID_MYGCS was renamed MAV_GCS_SYSID (ArduPilot PR #30627); either may be present.
    name = "MAV_GCS_SYSID" if "MAV_GCS_SYSID" in params else "SYSID_MYGCS"
    mygcs = params.get(name)
    if mygcs is None:
        out.append(_missing("SYSID_MYGCS / MAV_GCS_SYSID"))
    else:
        lo = int(mygcs)
        hi = int(params.get("MAV_GCS_SYSID_HI", 0) or 0)
        ok = lo == gcs_sysid or (hi > lo and lo <= gcs_sysid <= hi)
        if ok:
            out.append(Finding(INFO, name, f"{lo} includes our sysid {gcs_sysid}"))
        else:
            out.append(Finding(BLOCKING, name, f"{lo}{f'..{hi}' if hi > lo else ''} does not "
                               f"include our sysid {gcs_sysid}: our heartbeats would not count "
                               "for the GCS failsafe"))
    return tuple(out)


def audit_px4(params: Mapping[str, float], gcs_sysid: int = 255) -> tuple[Finding, ...]:
    out: list[Finding] = []
    dll = params.get("NAV_DLL_ACT")
    if dll is None:
        out.append(_missing("NAV_DLL_ACT"))
    else:
        what = _NAV_DLL_ACT.get(int(dll), f"unknown value {dll:g}")
        if int(dll) == 0:
            out.append(Finding(BLOCKING, "NAV_DLL_ACT", "0: data-link loss failsafe disabled "
                               "(PX4 default)"))
        elif int(dll) in (5, 6):
            out.append(Finding(BLOCKING, "NAV_DLL_ACT", f"{int(dll)}: {what} on link loss"))
        else:
            out.append(Finding(INFO, "NAV_DLL_ACT", f"{int(dll)}: {what}"))
    obl = params.get("COM_OBL_RC_ACT")
    if obl is None:
        out.append(_missing("COM_OBL_RC_ACT"))
    else:
        what = _COM_OBL_RC_ACT.get(int(obl), f"unknown value {obl:g}")
        sev = BLOCKING if int(obl) in (6, 7) else WARNING if int(obl) in (1, 2) else INFO
        note = " (without RC: return)" if int(obl) in (0, 1, 2) else ""
        out.append(Finding(sev, "COM_OBL_RC_ACT", f"{int(obl)}: {what}{note} on offboard loss"))
    for name, meaning in (("COM_OF_LOSS_T", "offboard loss timeout"),
                          ("COM_DL_LOSS_T", "data-link loss timeout")):
        if name in params:
            out.append(Finding(INFO, name, f"{params[name]:g} s {meaning}"))
    return tuple(out)


def audit_vehicle(link_id: int, sysid: int, autopilot: int, params: Mapping[str, float],
                  gcs_sysid: int = 255) -> VehicleAudit:
    if autopilot == ARDUPILOT:
        findings = audit_ardupilot(params, gcs_sysid)
    elif autopilot == PX4:
        findings = audit_px4(params, gcs_sysid)
    else:
        findings = (Finding(BLOCKING, "-", f"unknown autopilot {autopilot}: lost-link behaviour "
                            "cannot be checked"),)
    return VehicleAudit(link_id, sysid, autopilot, findings)


def audit_fleet(vehicles: Mapping[tuple[int, int], tuple[int, Mapping[str, float]]],
                gcs_sysid: int = 255, *, override: bool = False) -> AuditReport:
    """Audit every vehicle; ``vehicles`` maps (link_id, sysid) -> (autopilot, params)."""
    audits = tuple(audit_vehicle(link, sysid, ap, params, gcs_sysid)
                   for (link, sysid), (ap, params) in sorted(vehicles.items()))
    all_safe = all(a.safe for a in audits)
    return AuditReport(audits, overridden=override and not all_safe,
                       cleared_to_fly=all_safe or override)


#: ArduPilot FS_GCS_ENABLE value written by --apply-failsafes: 1 = RTL (ArduCopter
#: Parameters.cpp; the failsafe's action in GUIDED, events.cpp failsafe_gcs_on_event).
FS_GCS_ENABLE_FIX = 1
#: PX4 NAV_DLL_ACT value written by --apply-failsafes: 2 = Return mode
#: (src/modules/commander/commander_params.yaml).
NAV_DLL_ACT_FIX = 2


def failsafe_fixes(autopilot: int, params: Mapping[str, float],
                   gcs_sysid: int = 255) -> tuple[tuple[str, float], ...]:
    """``(name, value)`` writes that clear this vehicle's fixable blocking findings.

    Only parameters that were read are written (the vehicle has them, under that spelling), and
    only when the audit blocks on them; nothing for a safe vehicle.
    """
    out: list[tuple[str, float]] = []
    if autopilot == ARDUPILOT:
        fs = params.get("FS_GCS_ENABLE")
        if fs is not None and int(fs) == 0:
            out.append(("FS_GCS_ENABLE", float(FS_GCS_ENABLE_FIX)))
        # The spelling the firmware has (SYSID_MYGCS was renamed MAV_GCS_SYSID, PR #30627).
        name = "MAV_GCS_SYSID" if "MAV_GCS_SYSID" in params else "SYSID_MYGCS"
        if name in params:
            lo = int(params[name])
            hi = int(params.get("MAV_GCS_SYSID_HI", 0) or 0)
            if not (lo == gcs_sysid or (hi > lo and lo <= gcs_sysid <= hi)):
                # With a range, lo = ours keeps [ours, hi] (or a single id once hi <= ours).
                out.append((name, float(gcs_sysid)))
    elif autopilot == PX4:
        dll = params.get("NAV_DLL_ACT")
        if dll is not None and int(dll) in (0, 5, 6):
            out.append(("NAV_DLL_ACT", float(NAV_DLL_ACT_FIX)))
    return tuple(out)

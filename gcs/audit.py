"""Pre-flight audit of lost-link behaviour: pure functions over parameter dicts.

The station reads the parameters listed in :data:`AUDIT_PARAMS` (``StationLink.request_param``),
then :func:`audit_fleet` says, per vehicle, what a lost station (heartbeats) or a lost setpoint
stream would make the vehicle do, and whether that is safe. Safe means: it flies home (Return /
RTL / SmartRTL-or-RTL). Landing where it is, holding away from home, disarming or terminating in
the air, or carrying on without the station is **blocking** (docs/design/mavlink.md §1.4, §1.5, §3). The
rules follow each firmware's own source, cited at each rule below.

ArduPilot Copter (ArduCopter/events.cpp ``failsafe_gcs_check`` / ``failsafe_gcs_on_event``)
  * ``FS_GCS_ENABLE``: 1 RTL, 2 (4.0+: RTL; 3.x: continue AUTO else RTL), 3 SmartRTL-or-RTL ->
    fine; 6 (mission DO_LAND_START / DO_RETURN_PATH_START, else RTL) -> warning; 0 disabled,
    4 SmartRTL-or-Land, 5 Land, 7 Brake-or-Land -> **blocking** (fix: 1).
  * ``FS_OPTIONS`` (4.0+): no bit changes the GCS failsafe in GUIDED (bit 1 only in AUTO, bit 4
    only in pilot-controlled modes, bit 2 is the RC failsafe); reported, never blocking.
  * ``SYSID_MYGCS`` (newer: ``MAV_GCS_SYSID``, optional range up to ``MAV_GCS_SYSID_HI``) must
    include our sysid, else our heartbeats do not count and the failsafe never arms ->
    **blocking** (fix: ours).
  * ``FS_GCS_TIMEOUT`` (4.x; 3.x has a fixed 5 s) > 10 s -> warning; ``GUID_TIMEOUT`` reported.
PX4 (src/modules/commander/failsafe/failsafe.cpp, framework.cpp)
  * ``NAV_DLL_ACT`` (data-link loss): 2 Return fine; 0 disabled (the default), 1 Hold, 3 Land,
    5 Terminate, 6 Disarm, 7 Hold-without-failsafe -> **blocking** (fix: 2).
    ``COM_DLL_EXCEPT`` (newer PX4) bit 2 (Offboard) ignores it in OFFBOARD -> **blocking**
    (fix: clear the bit).
  * Offboard loss after ``COM_OF_LOSS_T``: ``COM_OBL_RC_ACT`` 3 Return fine; 4 Land, 5 Hold,
    6 Terminate, 7 Disarm -> **blocking** (fix: 3). 0-2 (Position / Altitude / Stabilized) fall
    back to a manual mode *for a pilot*; without manual control (no RC, the usual swarm set-up,
    always with ``COM_RC_IN_MODE`` 4) PX4 since PR #26289 (main 2026-01, backported to 1.16)
    takes the RC-loss action ``NAV_RCL_ACT`` instead: not 2 (Return) -> **blocking** (fix: 2).
    PX4 v1.14 to that fix stayed in Position mode and hovered; only the data-link failsafe
    then brings it home (it outranks the fallback): a warning.
  * PX4 <= v1.13 (``COM_OBL_ACT`` present): offboard loss without RC -> ``COM_OBL_ACT``; not
    2 (Return) -> **blocking** (fix: 2).
  * ``COM_DL_LOSS_T``, ``COM_FAIL_ACT_T`` (hold before acting), ``COM_RC_IN_MODE``,
    ``COM_RCL_EXCEPT`` reported.
Unknown autopilot or a parameter that matters and could not be read -> **blocking**;
parameters that older firmware lacks are in :data:`OPTIONAL_PARAMS` (reasons in
:data:`OPTIONAL_REASONS`) and their absence means "this firmware has no such setting".

Battery failsafes (``battery`` = ``"require"`` for a mission with batteries, ``"warn"`` for one
without them on real firmware, ``"off"``: not read; docs/design/endurance.md §3). A drone must fly
home at the firmware's *first* battery action, never land where it is (in the fire area) or fly on
until the critical level:
ArduPilot Copter (AP_BattMonitor_Params.cpp ``FS_LOW_ACT`` / ``FS_CRT_ACT`` @Values for Copter;
ArduCopter/events.cpp ``handle_battery_failsafe`` -> ``do_failsafe_action`` with
``Copter::FailsafeAction``: 0 None, 1 Land, 2 RTL, 3 SmartRTL-or-RTL, 4 SmartRTL-or-Land,
5 Terminate, 6 DO_LAND_START-or-RTL, 7 Brake-or-Land)
  * ``BATT_FS_LOW_ACT`` 2, 3 fine; 6 warning; 0, 1, 4, 5, 7 **blocking** (fix: 2).
  * ``BATT_LOW_MAH`` and ``BATT_LOW_VOLT`` both 0: the low failsafe never fires -> **blocking**
    (fix: ``BATT_LOW_MAH`` = the mission's low level x ``BATT_CAPACITY``, when both are known).
  * ``BATT_CRT_*`` at or above ``BATT_LOW_*``: the critical action (usually Land) comes first ->
    **blocking**. ``BATT_FS_CRT_ACT`` 5 (Terminate) **blocking**, 0 warning, Land expected.
  * The firmware's low level (``BATT_LOW_MAH / BATT_CAPACITY``) above the mission's
    ``low_frac``: the firmware returns before the plan expects -> warning.
PX4 (src/modules/commander/commander_params.yaml ``COM_LOW_BAT_ACT``; failsafe/failsafe.cpp
``checkStateAndMode`` battery warnings: ``BAT_LOW_THR`` only warns, the first *action* comes at
``BAT_CRIT_THR``, Land at ``BAT_EMERGEN_THR``)
  * ``COM_LOW_BAT_ACT`` 3 (Return at critical, Land at emergency) and 1 (Return, older PX4)
    fine; 0 (Warning only) and 2 (Land at critical) **blocking** (fix: 3).
  * thresholds not in order ``BAT_LOW_THR > BAT_CRIT_THR > BAT_EMERGEN_THR`` -> warning;
    ``BAT_CRIT_THR`` above the mission's ``low_frac`` -> warning.
With ``battery="warn"`` every battery finding is at most a warning.

A blocking finding refuses the flight unless ``override=True`` (the verdict then says so).

:func:`failsafe_fixes` lists the parameter writes that clear every *fixable* blocking finding
(``phireman fly --apply-failsafes``). A parameter that could not be read or an unknown autopilot
is not fixed and still blocks.
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field
from collections.abc import Mapping

from gcs.autopilot import ARDUPILOT, PX4
from gcs.landing import LANDING_ONLY_PARAMS, RTL_ALT_PARAMS

__all__ = [
    "Finding",
    "VehicleAudit",
    "AuditReport",
    "AUDIT_PARAMS",
    "params_to_read",
    "ALTERNATIVE_NAMES",
    "FOLLOW_UP_PARAMS",
    "OPTIONAL_PARAMS",
    "OPTIONAL_REASONS",
    "params_still_needed",
    "audit_ardupilot",
    "audit_px4",
    "audit_vehicle",
    "audit_fleet",
    "failsafe_fixes",
    "FS_GCS_ENABLE_FIX",
    "NAV_DLL_ACT_FIX",
    "NAV_RCL_ACT_FIX",
    "COM_OBL_RC_ACT_FIX",
    "COM_OBL_ACT_FIX",
    "BATTERY_AUDIT_PARAMS",
    "BATTERY_AUDIT_MODES",
    "audit_battery",
    "battery_fixes",
    "BATT_FS_LOW_ACT_FIX",
    "COM_LOW_BAT_ACT_FIX",
    "RTL_ALT_PARAMS",
    "audit_rtl_altitude",
    "rtl_altitude_fixes",
]

#: What to read per autopilot. ArduPilot alternatives: old or new GCS-sysid names.
AUDIT_PARAMS: dict[int, tuple[str, ...]] = {
    ARDUPILOT: (
        "FS_GCS_ENABLE",
        "FS_GCS_TIMEOUT",
        "FS_OPTIONS",
        "GUID_TIMEOUT",
        "SYSID_MYGCS",
        "MAV_GCS_SYSID",
        "MAV_GCS_SYSID_HI",
    ),
    PX4: (
        "COM_OF_LOSS_T",
        "COM_OBL_RC_ACT",
        "NAV_RCL_ACT",
        "NAV_DLL_ACT",
        "COM_DL_LOSS_T",
        "COM_RC_IN_MODE",
        "COM_RCL_EXCEPT",
        "COM_DLL_EXCEPT",
        "COM_FAIL_ACT_T",
        "COM_OBL_ACT",
    ),
}

BLOCKING, WARNING, INFO = "blocking", "warning", "info"

# ArduCopter Parameters.cpp FS_GCS_ENABLE @Values; actions as failsafe_gcs_on_event maps them
# (an out-of-range value falls to its ``default:`` branch, RTL).
_FS_GCS_ENABLE = {
    0: "disabled: a cut-off copter keeps flying its last target",
    1: "RTL (Land if RTL cannot start)",
    2: "RTL (4.0+; Copter 3.x continues an AUTO mission)",
    3: "SmartRTL, else RTL",
    4: "SmartRTL, else Land where it is",
    5: "Land where it is",
    6: "the mission's DO_LAND_START / DO_RETURN_PATH_START sequence, else RTL",
    7: "Brake, else Land where it is",
}
_FS_GCS_SAFE, _FS_GCS_WARN = frozenset({1, 2, 3}), frozenset({6})
# FS_OPTIONS bits (ArduCopter Copter.h FailsafeOption; events.cpp failsafe_gcs_on_event).
_FS_OPTIONS_BITS = {
    1: "continue AUTO on RC failsafe",
    2: "continue AUTO on GCS failsafe",
    4: "continue GUIDED on RC failsafe (the GCS failsafe still fires)",
    8: "continue landing on any failsafe",
    16: "continue pilot-controlled modes on GCS failsafe",
    32: "release gripper",
}

# PX4 gcs_connection_loss_failsafe_mode (failsafe.h) as fromNavDllOrRclActParam maps it; shared
# by NAV_DLL_ACT and NAV_RCL_ACT. 7 (newest PX4) is "Hold mode, no failsafe": Action::None in the
# failsafe state machine; unknown values fall to ``default:``, also Action::None.
_NAV_ACT = {
    0: "no action (disabled)",
    1: "Hold where it is",
    2: "Return",
    3: "Land where it is",
    5: "Terminate: motors off, falls",
    6: "Disarm in the air",
    7: "no failsafe action (Hold as a mode switch)",
}
# offboard_loss_failsafe_mode (failsafe.h) as fromOffboardLossActParam maps it.
_COM_OBL_RC_ACT = {
    0: "Position mode",
    1: "Altitude mode",
    2: "Stabilized mode",
    3: "Return",
    4: "Land where it is",
    5: "Hold where it is",
    6: "Terminate: motors off, falls",
    7: "Disarm in the air",
}
# PX4 <= v1.13 commander_params.c COM_OBL_ACT (offboard loss without RC).
_COM_OBL_ACT = {
    -1: "disabled",
    0: "Land where it is",
    1: "Hold where it is",
    2: "Return",
    3: "Terminate: motors off, falls",
    4: "Lockdown: disarm in the air",
}
# COM_DLL_EXCEPT / COM_RCL_EXCEPT bits (failsafe.h LinkLossExceptionBits).
_EXCEPT_MISSION, _EXCEPT_AUTO, _EXCEPT_OFFBOARD = 1, 2, 4
# COM_RC_IN_MODE (failsafe.h RcInMode): 4 = manual control disabled.
_RC_IN_MODE_DISABLED = 4


#: Spellings of one parameter across firmware versions: once one is read, the others are not
#: asked for again (a firmware has only one of them; re-reading the other just times out).
ALTERNATIVE_NAMES: dict[str, tuple[str, ...]] = {
    "SYSID_MYGCS": ("MAV_GCS_SYSID",),
    "MAV_GCS_SYSID": ("SYSID_MYGCS",),
}
#: Read only once the key was read (the GCS-sysid range exists only with the new name).
FOLLOW_UP_PARAMS: dict[str, tuple[str, ...]] = {"MAV_GCS_SYSID": ("MAV_GCS_SYSID_HI",)}
#: Why each optional parameter may be absent: a firmware that lacks it has no such setting, so
#: its absence is not "unknown" (these are asked for once, never re-requested).
OPTIONAL_REASONS: dict[str, str] = {
    "MAV_GCS_SYSID_HI": "GCS-sysid range, only with the MAV_GCS_SYSID spelling (PR #30627)",
    "FS_GCS_TIMEOUT": "Copter 3.x has a fixed 5 s GCS timeout (events.cpp FS_GCS_TIMEOUT_MS)",
    "FS_OPTIONS": "added in Copter 4.0; older firmware has no failsafe options",
    "COM_DLL_EXCEPT": "data-link-loss exceptions exist only in recent PX4 (failsafe.h)",
    "COM_FAIL_ACT_T": "the hold-before-action delay came with the v1.14 failsafe framework",
    "COM_RCL_EXCEPT": "absent on old PX4; informational (RC loss, not station loss)",
    "COM_OBL_ACT": "PX4 <= v1.13 only (offboard loss without RC); v1.14 removed it",
}
#: Absent on many firmwares: never re-requested (see :data:`OPTIONAL_REASONS`).
# The landing's own parameters, read with a relay rotation (gcs/landing.py): not waited for.
OPTIONAL_REASONS.update(
    dict.fromkeys(LANDING_ONLY_PARAMS, "landing speeds: an absent one counts at its default")
)
OPTIONAL_PARAMS = frozenset(OPTIONAL_REASONS)


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
        verdict = (
            "cleared to fly"
            if self.cleared_to_fly and not self.overridden
            else "cleared to fly (OVERRIDDEN: unsafe lost-link settings)"
            if self.cleared_to_fly
            else "REFUSED: fix the settings above or override"
        )
        lines.append(verdict)
        return "\n".join(lines)


def _missing(name: str) -> Finding:
    return Finding(BLOCKING, name, "could not be read; lost-link behaviour unknown")


def _int(params: Mapping[str, float], name: str) -> int | None:
    v = params.get(name)
    return None if v is None else int(round(v))


# ------------------------------------------------------------------------------- ArduPilot


def _gcs_sysid(params: Mapping[str, float]) -> str:
    # SYSID_MYGCS was renamed MAV_GCS_SYSID (ArduPilot PR #30627); either may be present.
    return "MAV_GCS_SYSID" if "MAV_GCS_SYSID" in params else "SYSID_MYGCS"


def _sysid_ok(params: Mapping[str, float], name: str, gcs_sysid: int) -> bool:
    lo = int(params[name])
    hi = int(params.get("MAV_GCS_SYSID_HI", 0) or 0)
    return lo == gcs_sysid or (hi > lo and lo <= gcs_sysid <= hi)


def audit_ardupilot(params: Mapping[str, float], gcs_sysid: int = 255) -> tuple[Finding, ...]:
    out: list[Finding] = []
    fs = _int(params, "FS_GCS_ENABLE")
    if fs is None:
        out.append(_missing("FS_GCS_ENABLE"))
    else:
        # failsafe_gcs_on_event: FS_GCS_ENABLE -> desired_action; default branch -> RTL.
        what = _FS_GCS_ENABLE.get(fs, f"unknown value {fs}: the firmware falls back to RTL")
        sev = (
            INFO
            if fs in _FS_GCS_SAFE
            else WARNING
            if fs in _FS_GCS_WARN or fs not in _FS_GCS_ENABLE
            else BLOCKING
        )
        out.append(Finding(sev, "FS_GCS_ENABLE", f"{fs}: station lost: {what}"))
    opts = _int(params, "FS_OPTIONS")
    if opts is not None:
        # events.cpp failsafe_gcs_on_event: GCS_CONTINUE_IF_AUTO applies only in AUTO,
        # GCS_CONTINUE_IF_PILOT_CONTROL only when !flightmode->is_autopilot() (GUIDED is one),
        # CONTINUE_IF_LANDING only while landing. We fly GUIDED, so none of them keeps a cut-off
        # copter going; the AUTO one is flagged in case a pilot switches to AUTO.
        bits = [f"{b} ({what})" for b, what in _FS_OPTIONS_BITS.items() if opts & b]
        sev = WARNING if opts & 2 else INFO
        text = ", ".join(bits) if bits else "no options"
        out.append(
            Finding(sev, "FS_OPTIONS", f"{opts}: {text}; none changes the GCS failsafe in GUIDED")
        )
    timeout = params.get("FS_GCS_TIMEOUT")
    if timeout is not None:
        sev = WARNING if timeout > 10 else INFO
        out.append(Finding(sev, "FS_GCS_TIMEOUT", f"{timeout:g} s after the last GCS heartbeat"))
    guid = params.get("GUID_TIMEOUT")
    if guid is not None:
        out.append(
            Finding(
                INFO,
                "GUID_TIMEOUT",
                f"{guid:g} s (velocity targets only; position "
                "targets persist and are re-sent every second)",
            )
        )
    name = _gcs_sysid(params)
    if name not in params:
        out.append(_missing("SYSID_MYGCS / MAV_GCS_SYSID"))
    else:
        lo = int(params[name])
        hi = int(params.get("MAV_GCS_SYSID_HI", 0) or 0)
        rng = f"{lo}{f'..{hi}' if hi > lo else ''}"
        if _sysid_ok(params, name, gcs_sysid):
            out.append(Finding(INFO, name, f"{rng} includes our sysid {gcs_sysid}"))
        else:
            # failsafe_gcs_check returns while sysid_myggcs_last_seen_time_ms() == 0.
            out.append(
                Finding(
                    BLOCKING,
                    name,
                    f"{rng} does not include our sysid {gcs_sysid}: "
                    "our heartbeats do not count, the GCS failsafe never arms",
                )
            )
    return tuple(out)


# ------------------------------------------------------------------------------------ PX4


def _px4_offboard(params: Mapping[str, float]) -> list[Finding]:
    """What offboard (setpoint-stream) loss does: Failsafe::checkModeFallback."""
    out: list[Finding] = []
    obl = _int(params, "COM_OBL_RC_ACT")
    rcl = _int(params, "NAV_RCL_ACT")
    old = _int(params, "COM_OBL_ACT")  # PX4 <= v1.13 only
    rc_mode = _int(params, "COM_RC_IN_MODE")
    if rc_mode is None:
        out.append(
            Finding(
                WARNING,
                "COM_RC_IN_MODE",
                "could not be read; whether an RC is "
                "expected is unknown (the verdict assumes none)",
            )
        )
    elif rc_mode == _RC_IN_MODE_DISABLED:
        out.append(
            Finding(
                INFO,
                "COM_RC_IN_MODE",
                "4: no manual control at all: every 'without RC' case below applies",
            )
        )
    else:
        out.append(
            Finding(
                INFO,
                "COM_RC_IN_MODE",
                f"{rc_mode}: an RC / joystick may be used; the verdict assumes none is present",
            )
        )
    if obl is None:
        out.append(_missing("COM_OBL_RC_ACT"))
    if rcl is None:
        out.append(_missing("NAV_RCL_ACT"))
    if old is not None:
        # PX4 <= v1.13 (state_machine_helper): COM_OBL_ACT without RC, COM_OBL_RC_ACT with RC.
        what = _COM_OBL_ACT.get(old, f"unknown value {old}")
        sev = INFO if old == COM_OBL_ACT_FIX else BLOCKING
        out.append(Finding(sev, "COM_OBL_ACT", f"{old}: offboard loss without RC: {what}"))
        if obl is not None:
            what = _COM_OBL_RC_ACT.get(obl, f"unknown value {obl}")
            sev = INFO if obl == COM_OBL_RC_ACT_FIX else WARNING
            out.append(Finding(sev, "COM_OBL_RC_ACT", f"{obl}: offboard loss with RC: {what}"))
        if rcl is not None:
            out.append(
                Finding(
                    INFO,
                    "NAV_RCL_ACT",
                    f"{rcl}: RC loss: {_NAV_ACT.get(rcl, f'unknown value {rcl}')}",
                )
            )
        return out
    if obl is None:
        return out
    if obl == COM_OBL_RC_ACT_FIX:
        out.append(Finding(INFO, "COM_OBL_RC_ACT", "3: offboard loss: Return, with or without RC"))
        if rcl is not None:
            out.append(
                Finding(
                    INFO,
                    "NAV_RCL_ACT",
                    f"{rcl}: RC loss (RC present at arming): "
                    f"{_NAV_ACT.get(rcl, f'unknown value {rcl}')}",
                )
            )
        return out
    if obl in (4, 5, 6, 7) or obl not in _COM_OBL_RC_ACT:
        what = _COM_OBL_RC_ACT.get(obl, f"unknown value {obl}")
        out.append(Finding(BLOCKING, "COM_OBL_RC_ACT", f"{obl}: offboard loss: {what}"))
        return out
    # 0-2: FallbackPosCtrl/AltCtrl/Stab. modeCanRun() ignores mode_req_manual_control
    # (framework.cpp), so without the fix of PR #26289 PX4 stays in that manual mode with no
    # pilot; with it, checkModeFallback replaces a manual fallback by NAV_RCL_ACT's action when
    # manual_control_signal_lost (set whenever no valid manual_control_setpoint arrives,
    # rcAndDataLinkCheck.cpp, so also with COM_RC_IN_MODE 4).
    mode = _COM_OBL_RC_ACT[obl]
    out.append(
        Finding(
            WARNING,
            "COM_OBL_RC_ACT",
            f"{obl}: offboard loss: with RC, {mode} for "
            "the pilot; without RC, current PX4 takes NAV_RCL_ACT's action (next "
            f"finding), PX4 v1.14-1.16.0 stays in {mode} and hovers until the "
            "data-link failsafe; 3 (Return) is version-independent",
        )
    )
    if rcl is not None:
        what = _NAV_ACT.get(rcl, f"unknown value {rcl}: no failsafe action")
        sev = INFO if rcl == NAV_RCL_ACT_FIX else BLOCKING
        out.append(
            Finding(
                sev, "NAV_RCL_ACT", f"offboard loss: without RC, PX4 uses NAV_RCL_ACT={rcl}: {what}"
            )
        )
    return out


def audit_px4(params: Mapping[str, float], gcs_sysid: int = 255) -> tuple[Finding, ...]:
    out: list[Finding] = []
    dll = _int(params, "NAV_DLL_ACT")
    if dll is None:
        out.append(_missing("NAV_DLL_ACT"))
    else:
        # checkStateAndMode: gcs_connection_lost -> fromNavDllOrRclActParam(NAV_DLL_ACT).
        what = _NAV_ACT.get(dll, f"unknown value {dll}: no failsafe action")
        sev = INFO if dll == NAV_DLL_ACT_FIX else BLOCKING
        out.append(Finding(sev, "NAV_DLL_ACT", f"{dll}: station lost: {what}"))
    exc = _int(params, "COM_DLL_EXCEPT")
    if exc is not None:
        # isFailsafeIgnored(user_intended_mode, COM_DLL_EXCEPT): bit 2 Offboard, bit 1 auto modes.
        if exc & _EXCEPT_OFFBOARD:
            out.append(
                Finding(
                    BLOCKING,
                    "COM_DLL_EXCEPT",
                    f"{exc}: data-link loss ignored in "
                    "Offboard: a cut-off vehicle relies on the offboard-loss action",
                )
            )
        elif exc & _EXCEPT_AUTO:
            out.append(
                Finding(
                    WARNING,
                    "COM_DLL_EXCEPT",
                    f"{exc}: data-link loss ignored in auto modes (Hold, Takeoff, Return, Land)",
                )
            )
        else:
            out.append(Finding(INFO, "COM_DLL_EXCEPT", f"{exc}: no exception for Offboard"))
    out += _px4_offboard(params)
    rexc = _int(params, "COM_RCL_EXCEPT")
    if rexc is not None:
        note = "RC loss ignored in Offboard" if rexc & _EXCEPT_OFFBOARD else "no Offboard exception"
        out.append(Finding(INFO, "COM_RCL_EXCEPT", f"{rexc}: {note} (RC loss, not station loss)"))
    delay = params.get("COM_FAIL_ACT_T")
    if delay is not None:
        # framework.cpp: with COM_FAIL_ACT_T > 0.1 s, Hold first (not for Disarm / Terminate).
        sev = WARNING if delay > 10 else INFO
        out.append(Finding(sev, "COM_FAIL_ACT_T", f"{delay:g} s in Hold before a failsafe action"))
    for name, meaning in (
        ("COM_OF_LOSS_T", "offboard loss timeout"),
        ("COM_DL_LOSS_T", "data-link loss timeout"),
    ):
        if name in params:
            out.append(Finding(INFO, name, f"{params[name]:g} s {meaning}"))
    return tuple(out)


# ------------------------------------------------------------------------------- batteries

#: The battery-failsafe parameters read per autopilot (``battery`` not ``"off"``).
BATTERY_AUDIT_PARAMS: dict[int, tuple[str, ...]] = {
    ARDUPILOT: (
        "BATT_FS_LOW_ACT",
        "BATT_FS_CRT_ACT",
        "BATT_LOW_MAH",
        "BATT_LOW_VOLT",
        "BATT_CRT_MAH",
        "BATT_CRT_VOLT",
        "BATT_CAPACITY",
    ),
    PX4: ("COM_LOW_BAT_ACT", "BAT_LOW_THR", "BAT_CRIT_THR", "BAT_EMERGEN_THR"),
}
#: ``off`` (not read), ``warn`` (findings at most warnings), ``require`` (blocking as found).
BATTERY_AUDIT_MODES = ("off", "warn", "require")

# AP_BattMonitor_Params.cpp FS_LOW_ACT / FS_CRT_ACT @Values (Copter), the actions
# ArduCopter/events.cpp do_failsafe_action takes for Copter::FailsafeAction.
_BATT_FS_ACT = {
    0: "None: warns and flies on",
    1: "Land where it is",
    2: "RTL",
    3: "SmartRTL, else RTL",
    4: "SmartRTL, else Land where it is",
    5: "Terminate: motors off, falls",
    6: "the mission's DO_LAND_START, else RTL",
    7: "Brake, else Land where it is",
}
_BATT_LOW_SAFE, _BATT_LOW_WARN = frozenset({2, 3}), frozenset({6})
# PX4 commander_params.yaml COM_LOW_BAT_ACT (failsafe.h LowBatteryAction).
_COM_LOW_BAT_ACT = {
    0: "Warning only: flies on until empty",
    1: "Return at the critical level (older PX4)",
    2: "Land where it is at the critical level",
    3: "Return at the critical level, Land at the emergency level",
}
_COM_LOW_BAT_SAFE = frozenset({1, 3})
#: ArduPilot BATT_FS_LOW_ACT written by --apply-failsafes: 2 = RTL (Copter::FailsafeAction::RTL).
BATT_FS_LOW_ACT_FIX = 2
#: PX4 COM_LOW_BAT_ACT written by --apply-failsafes: 3 = Return at critical, Land at emergency.
COM_LOW_BAT_ACT_FIX = 3


def _batt_ardupilot(params: Mapping[str, float], low_frac: float | None) -> list[Finding]:
    out: list[Finding] = []
    low = _int(params, "BATT_FS_LOW_ACT")
    if low is None:
        out.append(_missing_battery("BATT_FS_LOW_ACT"))
    else:
        what = _BATT_FS_ACT.get(low, f"unknown value {low}")
        sev = INFO if low in _BATT_LOW_SAFE else WARNING if low in _BATT_LOW_WARN else BLOCKING
        out.append(Finding(sev, "BATT_FS_LOW_ACT", f"{low}: low battery: {what}"))
    crt = _int(params, "BATT_FS_CRT_ACT")
    if crt is not None:
        what = _BATT_FS_ACT.get(crt, f"unknown value {crt}")
        sev = BLOCKING if crt == 5 else WARNING if crt == 0 or crt not in _BATT_FS_ACT else INFO
        out.append(Finding(sev, "BATT_FS_CRT_ACT", f"{crt}: critical battery: {what}"))
    low_mah, low_v = params.get("BATT_LOW_MAH"), params.get("BATT_LOW_VOLT")
    crt_mah, crt_v = params.get("BATT_CRT_MAH"), params.get("BATT_CRT_VOLT")
    if low_mah is None and low_v is None:
        out.append(_missing_battery("BATT_LOW_MAH / BATT_LOW_VOLT"))
    elif not (low_mah or 0) > 0 and not (low_v or 0) > 0:
        out.append(
            Finding(
                BLOCKING,
                "BATT_LOW_MAH",
                "BATT_LOW_MAH and BATT_LOW_VOLT are 0: the low-battery failsafe never fires",
            )
        )
    for name, lo, cr in (("BATT_CRT_MAH", low_mah, crt_mah), ("BATT_CRT_VOLT", low_v, crt_v)):
        if lo is not None and cr is not None and lo > 0 and cr > 0 and cr >= lo:
            out.append(
                Finding(
                    BLOCKING,
                    name,
                    f"{cr:g} is not below the low level {lo:g}: the critical action comes first",
                )
            )
    cap = params.get("BATT_CAPACITY")
    if cap is not None and cap > 0 and low_mah is not None and low_mah > 0:
        fw = low_mah / cap
        if low_frac is not None and fw > low_frac + 0.005:
            out.append(
                Finding(
                    WARNING,
                    "BATT_LOW_MAH",
                    f"{low_mah:g} of {cap:g} mAh: the firmware returns at {fw:.0%}, the mission "
                    f"plans down to {low_frac:.0%}",
                )
            )
        else:
            out.append(Finding(INFO, "BATT_LOW_MAH", f"{low_mah:g} of {cap:g} mAh ({fw:.0%})"))
    return out


def _batt_px4(params: Mapping[str, float], low_frac: float | None) -> list[Finding]:
    out: list[Finding] = []
    act = _int(params, "COM_LOW_BAT_ACT")
    if act is None:
        out.append(_missing_battery("COM_LOW_BAT_ACT"))
    else:
        what = _COM_LOW_BAT_ACT.get(act, f"unknown value {act}")
        sev = INFO if act in _COM_LOW_BAT_SAFE else BLOCKING
        out.append(Finding(sev, "COM_LOW_BAT_ACT", f"{act}: {what}"))
    lo, cr, em = (params.get(n) for n in ("BAT_LOW_THR", "BAT_CRIT_THR", "BAT_EMERGEN_THR"))
    if cr is None:
        out.append(_missing_battery("BAT_CRIT_THR"))
    if lo is not None and cr is not None and em is not None and not lo > cr > em:
        out.append(
            Finding(
                WARNING,
                "BAT_CRIT_THR",
                f"thresholds not in order: low {lo:g} > critical {cr:g} > emergency {em:g}",
            )
        )
    if cr is not None:
        if low_frac is not None and cr > low_frac + 0.005:
            out.append(
                Finding(
                    WARNING,
                    "BAT_CRIT_THR",
                    f"{cr:g}: the firmware's first action comes at {cr:.0%}, the mission plans "
                    f"down to {low_frac:.0%}",
                )
            )
        else:
            out.append(Finding(INFO, "BAT_CRIT_THR", f"{cr:g}: the first battery action"))
    return out


def _missing_battery(name: str) -> Finding:
    return Finding(BLOCKING, name, "could not be read; battery failsafe behaviour unknown")


def audit_battery(
    autopilot: int,
    params: Mapping[str, float],
    *,
    battery: str = "require",
    low_frac: float | None = None,
) -> tuple[Finding, ...]:
    """The battery-failsafe findings of one vehicle (module docstring); ``low_frac``: the
    mission's low level (``endurance.battery.low_frac``), compared with the firmware's."""
    if battery not in BATTERY_AUDIT_MODES:
        raise ValueError(f"battery must be one of {BATTERY_AUDIT_MODES}, got {battery!r}")
    if battery == "off":
        return ()
    if autopilot == ARDUPILOT:
        found = _batt_ardupilot(params, low_frac)
    elif autopilot == PX4:
        found = _batt_px4(params, low_frac)
    else:
        return ()  # the lost-link audit already blocks an unknown autopilot
    if battery == "warn":
        found = [
            Finding(WARNING, f.param, f.message + " (mission without batteries: not refused)")
            if f.severity == BLOCKING
            else f
            for f in found
        ]
    return tuple(found)


def battery_fixes(
    autopilot: int, params: Mapping[str, float], low_frac: float | None = None
) -> tuple[tuple[str, float], ...]:
    """``(name, value)`` writes that clear the fixable blocking battery findings: the low action
    to return to launch, and (ArduPilot) a low level where none is set, when the capacity and
    the mission's ``low_frac`` are known."""
    blocking = {
        f.param
        for f in audit_battery(autopilot, params, low_frac=low_frac)
        if f.severity == BLOCKING
    }
    out: list[tuple[str, float]] = []
    if autopilot == ARDUPILOT:
        if "BATT_FS_LOW_ACT" in blocking and "BATT_FS_LOW_ACT" in params:
            out.append(("BATT_FS_LOW_ACT", float(BATT_FS_LOW_ACT_FIX)))
        cap = params.get("BATT_CAPACITY") or 0.0
        if "BATT_LOW_MAH" in blocking and "BATT_LOW_MAH" in params and cap > 0 and low_frac:
            out.append(("BATT_LOW_MAH", float(round(low_frac * cap))))
    elif autopilot == PX4:
        if "COM_LOW_BAT_ACT" in blocking and "COM_LOW_BAT_ACT" in params:
            out.append(("COM_LOW_BAT_ACT", float(COM_LOW_BAT_ACT_FIX)))
    return tuple(out)


def audit_vehicle(
    link_id: int,
    sysid: int,
    autopilot: int,
    params: Mapping[str, float],
    gcs_sysid: int = 255,
    *,
    battery: str = "off",
    battery_low_frac: float | None = None,
    rtl_min_alt_m: float | None = None,
) -> VehicleAudit:
    if autopilot == ARDUPILOT:
        findings = audit_ardupilot(params, gcs_sysid) + audit_battery(
            autopilot, params, battery=battery, low_frac=battery_low_frac
        )
    elif autopilot == PX4:
        findings = audit_px4(params, gcs_sysid) + audit_battery(
            autopilot, params, battery=battery, low_frac=battery_low_frac
        )
    else:
        findings = (
            Finding(
                BLOCKING,
                "-",
                f"unknown autopilot {autopilot}: lost-link behaviour cannot be checked",
            ),
        )
    if rtl_min_alt_m is not None:
        findings += audit_rtl_altitude(autopilot, params, rtl_min_alt_m)
    return VehicleAudit(link_id, sysid, autopilot, findings)


def audit_fleet(
    vehicles: Mapping[tuple[int, int], tuple[int, Mapping[str, float]]],
    gcs_sysid: int = 255,
    *,
    override: bool = False,
    battery: str = "off",
    battery_low_frac: float | None = None,
    rtl_min_alt_m: float | None = None,
) -> AuditReport:
    """Audit every vehicle; ``vehicles`` maps (link_id, sysid) -> (autopilot, params);
    ``battery``: the battery-failsafe audit's mode (:data:`BATTERY_AUDIT_MODES`);
    ``rtl_min_alt_m``: over terrain, the least return altitude above home
    (:func:`audit_rtl_altitude`; None: not audited)."""
    audits = tuple(
        audit_vehicle(
            link,
            sysid,
            ap,
            params,
            gcs_sysid,
            battery=battery,
            battery_low_frac=battery_low_frac,
            rtl_min_alt_m=rtl_min_alt_m,
        )
        for (link, sysid), (ap, params) in sorted(vehicles.items())
    )
    all_safe = all(a.safe for a in audits)
    return AuditReport(
        audits, overridden=override and not all_safe, cleared_to_fly=all_safe or override
    )


#: ArduPilot FS_GCS_ENABLE written by --apply-failsafes: 1 = RTL (ArduCopter Parameters.cpp;
#: events.cpp failsafe_gcs_on_event FS_GCS_ENABLED_ALWAYS_RTL).
FS_GCS_ENABLE_FIX = 1
#: PX4 NAV_DLL_ACT / NAV_RCL_ACT written by --apply-failsafes: 2 = Return mode
#: (failsafe.h gcs_connection_loss_failsafe_mode::Return_mode).
NAV_DLL_ACT_FIX = 2
NAV_RCL_ACT_FIX = 2
#: PX4 COM_OBL_RC_ACT Return (failsafe.h offboard_loss_failsafe_mode::Return_mode).
COM_OBL_RC_ACT_FIX = 3
#: PX4 <= v1.13 COM_OBL_ACT Return (commander_params.c).
COM_OBL_ACT_FIX = 2


def failsafe_fixes(
    autopilot: int, params: Mapping[str, float], gcs_sysid: int = 255
) -> tuple[tuple[str, float], ...]:
    """``(name, value)`` writes that clear this vehicle's fixable blocking findings.

    Only parameters that were read are written (the vehicle has them, under that spelling), and
    only when the audit blocks on them; nothing for a safe vehicle. Values are floats; the
    operator sends each with the PARAM_VALUE param_type it read (all integers here).
    """
    out: list[tuple[str, float]] = []
    blocking = {
        f.param
        for f in (
            audit_ardupilot(params, gcs_sysid)
            if autopilot == ARDUPILOT
            else audit_px4(params, gcs_sysid)
            if autopilot == PX4
            else ()
        )
        if f.severity == BLOCKING
    }
    if autopilot == ARDUPILOT:
        if "FS_GCS_ENABLE" in blocking and "FS_GCS_ENABLE" in params:
            out.append(("FS_GCS_ENABLE", float(FS_GCS_ENABLE_FIX)))
        # The spelling the firmware has (SYSID_MYGCS was renamed MAV_GCS_SYSID, PR #30627).
        name = _gcs_sysid(params)
        if name in blocking and name in params:
            # With a range, lo = ours keeps [ours, hi] (or a single id once hi <= ours).
            out.append((name, float(gcs_sysid)))
    elif autopilot == PX4:
        for name, value in (
            ("NAV_DLL_ACT", NAV_DLL_ACT_FIX),
            ("COM_OBL_RC_ACT", COM_OBL_RC_ACT_FIX),
            ("NAV_RCL_ACT", NAV_RCL_ACT_FIX),
            ("COM_OBL_ACT", COM_OBL_ACT_FIX),
        ):
            if name in blocking and name in params:
                out.append((name, float(value)))
        if "COM_DLL_EXCEPT" in blocking and "COM_DLL_EXCEPT" in params:
            cleared = int(params["COM_DLL_EXCEPT"]) & ~_EXCEPT_OFFBOARD
            out.append(("COM_DLL_EXCEPT", float(cleared)))
    return tuple(out)


# Over terrain, the firmware's own return. A lost station, a low battery or a forced return
# sends a vehicle home by the firmware's RTL, which climbs (never descends) to its return
# altitude above home over where it is, then flies a straight line home at that altitude
# (:data:`gcs.landing.RTL_ALT_PARAMS`, with the firmware code cited there; PX4's metadata allows
# 0 to 150 m). On a flat earth any return altitude clears the ground; over terrain the straight
# line must clear the highest ground the vehicle can be sent home across: the mission's operating
# area (docs/terrain.md §6.2).


def audit_rtl_altitude(
    autopilot: int, params: Mapping[str, float], min_alt_m: float
) -> tuple[Finding, ...]:
    """The return-altitude finding of one vehicle over terrain: **blocking** when the firmware's
    RTL would fly home lower than ``min_alt_m`` above home (fix: :func:`rtl_altitude_fixes`)."""
    spec = RTL_ALT_PARAMS.get(autopilot)
    if spec is None:
        return ()  # the lost-link audit already blocks an unknown autopilot
    name, per_m = spec
    raw = params.get(name)
    if raw is None:
        return (
            Finding(
                BLOCKING, name, "could not be read; the return altitude over terrain is unknown"
            ),
        )
    alt_m = float(raw) / per_m
    if alt_m + 0.5 < min_alt_m:
        return (
            Finding(
                BLOCKING,
                name,
                f"{raw:g}: RTL flies home {alt_m:.0f} m above home; the ground it may cross needs "
                f"{min_alt_m:.0f} m (terrain)",
            ),
        )
    return (Finding(INFO, name, f"{raw:g}: RTL flies home at least {alt_m:.0f} m above home"),)


def rtl_altitude_fixes(
    autopilot: int, params: Mapping[str, float], min_alt_m: float
) -> tuple[tuple[str, float], ...]:
    """``(name, value)``: the return altitude raised to ``min_alt_m`` (whole metres, up) when
    :func:`audit_rtl_altitude` blocks on it and the parameter was read."""
    spec = RTL_ALT_PARAMS.get(autopilot)
    if spec is None or spec[0] not in params:
        return ()
    if not any(f.severity == BLOCKING for f in audit_rtl_altitude(autopilot, params, min_alt_m)):
        return ()
    name, per_m = spec
    return ((name, float(math.ceil(min_alt_m) * per_m)),)

"""Operator actions: one vehicle (or all) taken out of the plan and held, sent home or down,
released or brought back (``rejoin``), a battery swap confirmed by the ground crew
(``confirm_swap``), the Ctrl-C interrupt with its report, and the policy for a forwarded
client's override (:meth:`OperatorActions.forwarded_override`).

A mixin of :class:`gcs.operations.Operator` (split out of one 950-line module along this seam:
what a person asks of the flight, as opposed to what the plan does). It holds no state of its
own: the attributes are the operator's (``released``, ``actions``, ``on_action``,
``interrupted``, set up in ``Operator.__init__``).
"""

from __future__ import annotations

import logging
import math
from typing import Protocol

from gcs.autopilot import adapter_for
from gcs.fleet import FleetSnapshot
from gcs.link import LinkUsageError, UnknownVehicle
from gcs.operations._state import OperatorState
from gcs.operations.config import (
    OPERATOR_ACTIONS,
    OVERRIDE,
    OVERRIDE_REFUSED,
    OperatorAction,
    _Row,
)
from gcs.operations.phases import Phase, Trigger

__all__ = ["OperatorActions"]

log = logging.getLogger(__name__)

#: Phases in which nothing was launched: an "end" interrupt has nobody to tell.
_NOTHING_LAUNCHED = frozenset({Phase.DISCOVER, Phase.AUDIT, Phase.REFUSED})

#: A refusal is recorded again for the same vehicle, client and command only after this long
#: (a client re-sends an unanswered command a few times; every copy is still answered).
_REFUSAL_LOG_S = 10.0


class ForwardedOverride(Protocol):
    """What :meth:`OperatorActions.forwarded_override` reads of a :class:`gcs.forward.Override`
    (the forwarder is an adapter; the operator does not import it)."""

    client: str
    vids: tuple[tuple[int, int], ...]

    def what(self, autopilot: int | None = None) -> str: ...


class OperatorActions(OperatorState):
    """What an operator may ask of :class:`gcs.operations.Operator` (see the module docstring)."""

    def operator_command(
        self, action: str, vid: tuple[int, int] | None, now_s: float, source: str = ""
    ) -> list[OperatorAction]:
        """An operator's request for one vehicle ``(link_id, sysid)`` or, with ``vid=None``, for
        every vehicle heard. Goes through the station's normal command path (acks, retries,
        events, .tlog); returns what was done, one :class:`OperatorAction` per vehicle."""
        if action not in OPERATOR_ACTIONS:
            raise ValueError(f"unknown action {action!r}; valid: {', '.join(OPERATOR_ACTIONS)}")
        snap = self.fleet.snapshot(now_s)
        if vid is None and action == "confirm_swap":
            raise ValueError("confirm_swap confirms one vehicle's swap: name the vehicle")
        if vid is None:
            rows = [i for i in range(snap.n_vehicles) if not snap.lost[i]]
        else:
            if tuple(vid) not in self._known:
                raise UnknownVehicle(f"no vehicle link {vid[0]} sysid {vid[1]}")
            rows = [self.fleet.index_of(*vid)]
        out = []
        for i in rows:
            v = self._vid(snap, i)
            result = self._operator_act(action, snap, i, v, now_s)
            rec = OperatorAction(now_s, action, v[0], v[1], source, result)
            self.actions.append(rec)
            log.warning("operator %s: %s link %d sysid %d -> %s", source or "?", action, *v, result)
            if self.on_action is not None:
                self.on_action(rec)
            out.append(rec)
        return out

    def _operator_act(
        self, action: str, snap: FleetSnapshot, i: int, vid: tuple[int, int], now_s: float
    ) -> str:
        if action == "confirm_swap":  # the plan is not touched: the rotation's bookkeeping
            return self._rotation_confirm_swap(i, now_s)
        self.overrides.pop(vid, None)  # the station's operator has it now
        if action == "rejoin":
            if self.released.pop(vid, None) is None:
                return "was not released"
            row = self._rows.setdefault(i, _Row())
            row.next_action_s = -math.inf  # reclaimed at the next poll like a recovered vehicle
            return "rejoined"
        self.released[vid] = action
        try:
            if action == "hold":
                if not snap.has_position[i]:
                    return "released (no position yet: holds its last target)"
                self._hold(snap, [i], now_s)
                return "sent"
            if action in ("rtl", "land"):
                self.station.clear_position_target(vid, now_s)
                (self.station.rtl if action == "rtl" else self.station.land)(vid, now_s)
                return "sent"
        except (LinkUsageError, UnknownVehicle, ValueError) as exc:
            return f"not sent: {exc}"
        return "released"

    def forwarded_override(
        self, ov: ForwardedOverride, now_s: float, *, refuse: bool = False
    ) -> str | None:
        """A forwarded client (QGroundControl, MAVProxy through ``phireman fly --forward``) sent
        a command that changes who flies the vehicles ``ov.vids`` (:func:`gcs.forward.override_of`).
        Returns None to pass it on, or the reason it is refused (the forwarder tells the client).

        A vehicle the plan flies (known, not released) is never switched back behind the
        client's back. By default (``phireman fly --forward-overrides honour``) it leaves the
        plan as if the operator held it (``released`` ``override``: not planned, reclaimed,
        relaunched or end-commanded; its position target and our retried flight commands stop)
        and the record says who took it (:attr:`overrides`, an :class:`OperatorAction`
        ``override``), until an operator's ``rejoin``. With ``refuse`` it stays in the plan and
        the command is refused (recorded as ``override-refused``). A vehicle the operator
        already took out of the plan (held) is the client's to command either way; so is every
        vehicle once the flight is over (done or refused)."""
        if self.phase in (Phase.DONE, Phase.REFUSED):
            return None
        targets = [v for v in ov.vids if v in self._known]
        if not targets:
            return None  # a system the station does not fly (never heard by it)
        snap = self.fleet.snapshot(now_s)
        autopilot = {self._vid(snap, i): int(snap.autopilot[i]) for i in range(snap.n_vehicles)}
        t_m = self.t_mission_s(now_s) if self.mission_t0_s is not None else None
        when = f"t+{t_m:.0f} s" if t_m is not None else "before the mission"
        flown = [v for v in targets if v not in self.released]
        if refuse and flown:
            names = ", ".join(str(s) if l == 0 else f"{l}:{s}" for l, s in flown)
            many = "s" if len(flown) > 1 else ""
            reason = (
                f"phireman: vehicle{many} {names} {'are' if many else 'is'} flown by the relay "
                "plan; hold it on the station first"
            )
            for v in flown:
                what = ov.what(autopilot.get(v))
                last = self._refusals_logged.get(v)
                if (
                    last is None
                    or last[1:] != (ov.client, what)
                    or now_s - last[0] >= _REFUSAL_LOG_S
                ):
                    self._refusals_logged[v] = (now_s, ov.client, what)
                    self._record(
                        OperatorAction(
                            now_s, OVERRIDE_REFUSED, v[0], v[1], ov.client, f"{what} ({when})"
                        )
                    )
            return reason
        for v in targets:
            what = ov.what(autopilot.get(v))
            prev = self.overrides.get(v)
            self.released[v] = OVERRIDE
            try:  # no setpoint or command retry of ours undoes it
                self.station.clear_position_target(v, now_s)
                self.station.withdraw_flight_commands(v, now_s, f"withdrawn: {ov.client} took it")
            except (LinkUsageError, UnknownVehicle):
                pass
            if (
                prev is not None
                and prev.source == ov.client
                and prev.result.startswith(what + " (")
            ):
                continue  # the same command again (a client's retry): recorded once
            rec = OperatorAction(now_s, OVERRIDE, v[0], v[1], ov.client, f"{what} ({when})")
            self.overrides[v] = rec
            self._record(rec)
        return None

    def _record(self, rec: OperatorAction) -> None:
        self.actions.append(rec)
        log.warning(
            "%s: %s link %d sysid %d: %s",
            rec.source,
            rec.action,
            rec.link_id,
            rec.sysid,
            rec.result,
        )
        if self.on_action is not None:
            self.on_action(rec)

    def interrupt(self, action: str, now_s: float) -> None:
        """The operator stopped the flight (Ctrl-C): ``end`` -> the mission's end action (RTL or
        LAND), else ``hold`` / ``rtl`` / ``land`` for every vehicle heard; planning stops."""
        self.interrupted = action
        if action == "end":
            if self.phase in _NOTHING_LAUNCHED:
                self._enter(Trigger.INTERRUPT, now_s)  # nothing to tell anyone
            else:
                self.begin_end(now_s)
            return
        self.operator_command(action, None, now_s, source="interrupt")
        self._enter(Trigger.INTERRUPT, now_s)

    def interrupt_report(self, now_s: float) -> list[tuple[tuple[int, int], str, bool]]:
        """After :meth:`interrupt`: per vehicle ``(vid, what it was told and what it does now,
        obeying)`` for people."""
        snap = self.fleet.snapshot(now_s)
        out = []
        for i in range(snap.n_vehicles):
            vid = self._vid(snap, i)
            adapter = adapter_for(int(snap.autopilot[i]))
            mode, armed = snap.mode[i], bool(snap.armed[i])
            action = self.interrupted or "end"
            if action == "end":
                action = self.config.end  # the mission's end action: "rtl" or "land"
            if snap.lost[i]:
                out.append(
                    (
                        vid,
                        f"not heard (lost or out of range; last mode {mode}): its own "
                        "link-loss failsafe decides",
                        False,
                    )
                )
                continue
            if not armed:
                out.append((vid, f"on the ground ({mode})", True))
                continue
            taken = self.overrides.get(vid)
            if taken is not None and action == self.config.end:
                # The end command is never sent to it (gcs/operations/end.py): say whose it is.
                out.append(
                    (vid, f"{taken.source} flies it ({taken.result}); now {mode}: not told", True)
                )
                continue
            want = {
                "rtl": (adapter.rtl_mode, adapter.land_mode),
                "land": (adapter.land_mode,),
                "hold": (adapter.guided_mode,),
            }.get(action, ())
            ok = mode in want
            told = {"rtl": "RTL", "land": "LAND", "hold": "HOLD where it is"}.get(action, action)
            out.append(
                (
                    vid,
                    f"told {told}; now {mode}"
                    if ok
                    else f"told {told}; no confirmation yet (mode {mode}): if the station is "
                    "gone, its link-loss failsafe acts",
                    ok,
                )
            )
        return out

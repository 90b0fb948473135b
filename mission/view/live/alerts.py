"""Alerts that interrupt the operator: what the live page shows as a banner with a sound until
someone acknowledges it (docs/live_view.md, "Alerts").

Sans-I/O, explicit time: :meth:`AlertBook.update` takes one picture of the fleet as the station
believes it (the vehicle states of :func:`mission.view.live.state.classify`, modes, batteries,
crews connected) and the time; :meth:`AlertBook.acknowledge` takes an operator's acknowledgement.
Each returns the records to log (:class:`AlertRaised`, :class:`AlertAcknowledged`, written to
the run directory's ``events.jsonl`` by the caller). Nothing here reads a clock or a socket.

Four kinds, each raised on the *edge* into its condition (once, not every frame) and armed again
when the condition ends:

* ``failsafe`` - a vehicle in the air enters RTL or LAND (state ``returning``) without the station
  having commanded it (an operator action, the end of the mission, a rotation home): the
  autopilot's own failsafe (GCS loss, battery, EKF, geofence) or another GCS;
* ``lost`` - a vehicle that was flying (networked, reclaimed, held, returning) is no longer heard;
  one on the ground going silent (powered off at the base) is not an alert;
* ``crew`` - a crew not connected to the base for longer than :attr:`AlertConfig.crew_cut_off_s`
  during the mission;
* ``battery`` - a vehicle off the ground with its remaining charge below
  :attr:`AlertConfig.battery_low_frac`, or its autopilot reporting the battery low or worse
  (BATTERY_STATUS ``charge_state`` >= 2).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

__all__ = [
    "ALERT_KINDS",
    "AlertAcknowledged",
    "AlertBook",
    "AlertConfig",
    "AlertRaised",
    "DEFAULT_CREW_CUT_OFF_S",
    "DEFAULT_BATTERY_LOW_FRAC",
]

ALERT_KINDS = ("failsafe", "lost", "crew", "battery")
#: A crew cut off from the base this long is an alert (``phireman fly --alert-crew-after``).
DEFAULT_CREW_CUT_OFF_S = 60.0
#: Below this remaining charge a vehicle's battery is an alert, unless the mission's battery
#: section sets its own ``low_frac`` (the level the rotation sends a relay home at).
DEFAULT_BATTERY_LOW_FRAC = 0.25
#: MAV_BATTERY_CHARGE_STATE_LOW (common.xml): the autopilot's own "low".
_CHARGE_STATE_LOW = 2
_FLYING = frozenset({"networked", "reclaimed", "held", "returning"})


@dataclass(frozen=True)
class AlertConfig:
    """Thresholds of the alerts (seconds, fractions)."""

    crew_cut_off_s: float = DEFAULT_CREW_CUT_OFF_S
    battery_low_frac: float = DEFAULT_BATTERY_LOW_FRAC

    def __post_init__(self) -> None:
        if not (math.isfinite(self.crew_cut_off_s) and self.crew_cut_off_s >= 0):
            raise ValueError(f"crew_cut_off_s must be >= 0, got {self.crew_cut_off_s}")
        if not 0.0 <= self.battery_low_frac <= 1.0:
            raise ValueError(f"battery_low_frac must be in [0, 1], got {self.battery_low_frac}")


@dataclass(frozen=True)
class AlertRaised:
    """An alert began (what ``events.jsonl`` records)."""

    alert_id: int
    kind: str
    subject: str
    """The vehicle (``"LINK:SYSID"``) or the crew's name."""
    text: str
    t_s: float


@dataclass(frozen=True)
class AlertAcknowledged:
    """An operator acknowledged an alert (what ``events.jsonl`` records)."""

    alert_id: int
    kind: str
    subject: str
    t_s: float
    source: str
    """Who: ``web 127.0.0.1`` (the page's client address)."""


@dataclass
class _Alert:
    raised: AlertRaised
    acked: AlertAcknowledged | None = None
    cleared_s: float | None = None
    """When its condition ended (it stays on the banner until acknowledged)."""

    def as_dict(self) -> dict:
        r = self.raised
        return {
            "id": r.alert_id,
            "kind": r.kind,
            "subject": r.subject,
            "text": r.text,
            "t_s": round(r.t_s, 1),
            "cleared": self.cleared_s is not None,
            "acked": self.acked is not None,
        }


@dataclass
class AlertBook:
    """Open, acknowledged and past alerts of one flight (module docstring)."""

    config: AlertConfig = field(default_factory=AlertConfig)
    keep: int = 200
    """Alerts kept for the page once acknowledged (the log keeps them all)."""
    _alerts: dict[int, _Alert] = field(default_factory=dict)
    _open: dict[tuple[str, str], int] = field(default_factory=dict)
    """(kind, subject) -> the alert whose condition still holds."""
    _prev_state: dict[str, str] = field(default_factory=dict)
    _cut_since: dict[str, float] = field(default_factory=dict)
    _next_id: int = 1

    # ------------------------------------------------------------------ inputs

    def update(
        self,
        now_s: float,
        *,
        vehicles: Sequence[str],
        states: Sequence[str],
        modes: Sequence[str],
        commanded: Iterable[str] = (),
        battery_frac: Sequence[float] | None = None,
        charge_state: Sequence[int] | None = None,
        crews: Sequence[str] = (),
        crews_connected: Sequence[bool] = (),
        mission_running: bool = True,
    ) -> list[AlertRaised]:
        """One picture at ``now_s``; returns the alerts raised by it.

        Parameters
        ----------
        vehicles, states, modes : per vehicle: ``"LINK:SYSID"``, its state (one of
            :data:`mission.view.live.state.STATES`), its mode name
        commanded : vehicles the station itself sent to RTL or LAND (not a failsafe)
        battery_frac : (N,) remaining charge, fraction (NaN: unknown)
        charge_state : (N,) MAV_BATTERY_CHARGE_STATE (0: not reported)
        crews, crews_connected : per crew: its name, connected to the base now
        mission_running : the run phase (crews are only alerted on while it lasts)
        """
        out: list[AlertRaised] = []
        commanded = set(commanded)
        cfg = self.config
        for k, (vid, state) in enumerate(zip(vehicles, states)):
            prev = self._prev_state.get(vid)
            self._prev_state[vid] = state
            returning = state == "returning" and vid not in commanded
            self._hold(
                out,
                now_s,
                "failsafe",
                vid,
                returning and prev in _FLYING - {"returning"},
                returning,
                f"vehicle {vid} in {modes[k] or '?'}: failsafe (not commanded)",
            )
            lost = state == "lost"
            self._hold(
                out,
                now_s,
                "lost",
                vid,
                lost and prev in _FLYING,
                lost,
                f"vehicle {vid} lost (not heard; last {prev})",
            )
            frac = math.nan if battery_frac is None else float(battery_frac[k])
            cs = 0 if charge_state is None else int(charge_state[k])
            # On the ground (waiting for its swap at the base) a low battery is expected.
            low = state not in ("lost", "landed") and (
                frac < cfg.battery_low_frac or cs >= _CHARGE_STATE_LOW
            )
            pct = "?" if math.isnan(frac) else f"{100 * frac:.0f} %"
            self._hold(out, now_s, "battery", vid, low, low, f"vehicle {vid} battery low: {pct}")
        for name, ok in zip(crews, crews_connected):
            if ok or not mission_running:
                self._cut_since.pop(name, None)
                cut = False
            else:
                since = self._cut_since.setdefault(name, now_s)
                cut = now_s - since >= cfg.crew_cut_off_s
            since_s = self._cut_since.get(name, now_s)
            self._hold(
                out,
                now_s,
                "crew",
                name,
                cut,
                cut,
                f"{name} cut off from the base for {now_s - since_s:.0f} s",
            )
        return out

    def _hold(
        self, out: list, now_s: float, kind: str, subject: str, start: bool, holds: bool, text: str
    ) -> None:
        """Raise on ``start`` unless already open; close the open one when ``holds`` ends."""
        key = (kind, subject)
        open_id = self._open.get(key)
        if open_id is not None:
            if not holds:
                self._alerts[open_id].cleared_s = now_s
                del self._open[key]
            return
        if not start:
            return
        rec = AlertRaised(self._next_id, kind, subject, text, float(now_s))
        self._next_id += 1
        self._alerts[rec.alert_id] = _Alert(rec)
        self._open[key] = rec.alert_id
        out.append(rec)
        self._trim()

    def acknowledge(
        self, alert_id: int | str, now_s: float, source: str
    ) -> list[AlertAcknowledged]:
        """The operator acknowledged ``alert_id`` (or ``"all"``): the records to log (none for an
        alert already acknowledged). Raises KeyError for an unknown id."""
        if alert_id == "all":
            ids = [i for i, a in self._alerts.items() if a.acked is None]
        else:
            i = int(alert_id)
            if i not in self._alerts:
                raise KeyError(f"no alert {alert_id}")
            ids = [i] if self._alerts[i].acked is None else []
        out = []
        for i in ids:
            a = self._alerts[i]
            a.acked = AlertAcknowledged(i, a.raised.kind, a.raised.subject, float(now_s), source)
            out.append(a.acked)
        self._trim()
        return out

    def _trim(self) -> None:
        done = [
            i
            for i, a in self._alerts.items()
            if a.acked is not None and i not in self._open.values()
        ]
        for i in done[: max(0, len(done) - self.keep)]:
            del self._alerts[i]

    # ------------------------------------------------------------------ outputs

    def unacknowledged(self) -> list[dict]:
        """What the banner shows: every alert not acknowledged yet, oldest first."""
        return [a.as_dict() for a in self._alerts.values() if a.acked is None]

    def recent(self, limit: int = 20) -> list[dict]:
        """The last ``limit`` alerts, acknowledged or not, newest first."""
        return [a.as_dict() for a in list(self._alerts.values())[-limit:]][::-1]

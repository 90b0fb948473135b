"""Crews from TAK: task positions from the Cursor-on-Target reports of the crews' TAK phones.

A crew (task column) is a TAK contact named by its ``uid`` or its ``callsign``, or one of the
slots of a callsign pattern (glob or regular expression) that a new contact matching it takes
when it first reports. Each report (:class:`TakContactReported`, built by the TAK adapter from a
:class:`gcs.cot.CotEvent`) replaces the crew's column in the planned task positions, converted
to the mission's local frame.

**Stale is unknown.** A CoT event says how long it holds (``stale``). Once that time has passed
with no newer report, :meth:`TakCrews.expire` (called with the station's time on every poll)
makes the crew *unknown*: its column is NaN, as a live task before its first fix
(:mod:`gcs.tasks`). The station never plans a NaN column where the crew was: ``gcs.control.tick``
plans an unknown crew at the base (a zero-length branch of the tree, no relay chases a position
that may be wrong) and the coverage metrics count it as not connected. A fresh report makes it
known again.

Sans-I/O: every time is an argument (station seconds); the adapter converts the event's own
lifetime (``stale - time``, clock-skew free) to station time.
"""

from __future__ import annotations

import fnmatch
import logging
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from gcs.fleet import MissionOrigin
from planner.geometry import geodetic_to_ned_m

__all__ = ["CrewMatch", "TakContactReported", "TakCrews", "CrewState"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TakContactReported:
    """A TAK contact's position report, as the station received it."""

    t_s: float
    """Station time of receipt, seconds."""
    uid: str
    callsign: str | None
    lat_deg: float
    lon_deg: float
    hae_m: float | None
    """Height above the WGS 84 ellipsoid, metres (None: unknown)."""
    stale_s: float
    """Station time after which the report no longer holds, seconds."""
    cot_type: str = ""
    """The CoT type (``a-f-G-U-C``: a friendly ground unit)."""

    def __post_init__(self) -> None:
        if not self.uid:
            raise ValueError("a TAK report needs a uid")
        if not (math.isfinite(self.lat_deg) and -90.0 <= self.lat_deg <= 90.0):
            raise ValueError(f"lat_deg must be in [-90, 90], got {self.lat_deg}")
        if not (math.isfinite(self.lon_deg) and -180.0 <= self.lon_deg <= 180.0):
            raise ValueError(f"lon_deg must be in [-180, 180], got {self.lon_deg}")
        if not (math.isfinite(self.t_s) and not math.isnan(self.stale_s)):
            raise ValueError("t_s must be finite and stale_s a number")


@dataclass(frozen=True)
class CrewMatch:
    """Which TAK contact a crew column is: exactly one of ``uid``, ``callsign``,
    ``callsign_pattern`` (glob, case-insensitive) or ``callsign_regex`` (full match)."""

    name: str
    uid: str | None = None
    callsign: str | None = None
    callsign_pattern: str | None = None
    callsign_regex: str | None = None

    def __post_init__(self) -> None:
        given = [
            k
            for k in ("uid", "callsign", "callsign_pattern", "callsign_regex")
            if getattr(self, k) is not None
        ]
        if len(given) != 1:
            raise ValueError(f"crew {self.name!r}: exactly one matcher, got {given or 'none'}")
        if self.callsign_regex is not None:
            re.compile(self.callsign_regex)  # raises re.error on a bad expression

    @property
    def named(self) -> bool:
        """One given contact (uid or callsign), not a slot of a pattern."""
        return self.uid is not None or self.callsign is not None

    def matches(self, uid: str, callsign: str | None) -> bool:
        if self.uid is not None:
            return uid == self.uid
        if callsign is None:
            return False
        if self.callsign is not None:
            return callsign.casefold() == self.callsign.casefold()
        if self.callsign_pattern is not None:
            return fnmatch.fnmatchcase(callsign.casefold(), self.callsign_pattern.casefold())
        assert self.callsign_regex is not None  # exactly one matcher (constructor)
        return re.fullmatch(self.callsign_regex, callsign) is not None


@dataclass(frozen=True)
class CrewState:
    """One crew column as people see it."""

    column: int
    name: str
    uid: str | None
    """The contact in this column (None: no contact yet)."""
    callsign: str | None
    known: bool
    """Has a report that is not stale."""
    last_s: float
    """Station time of the last report (-inf: never)."""
    stale_s: float
    """When the last report went / goes stale (-inf: never heard)."""
    last_ne_m: np.ndarray
    """(2,) the last reported position (north, east), metres (NaN: never heard)."""


class TakCrews:
    """The latest position of every TAK crew, in the mission's local NE frame.

    Parameters
    ----------
    origin : the mission frame's origin
    columns : task column index -> its :class:`CrewMatch` (a pattern's slots: one column each)
    """

    def __init__(self, origin: MissionOrigin, columns: Mapping[int, CrewMatch]) -> None:
        self.origin = origin
        self._cols = sorted(columns)
        self._match = [columns[c] for c in self._cols]
        n = len(self._cols)
        self._uid: list[str | None] = [None] * n
        self._callsign: list[str | None] = [None] * n
        self._ne_m = np.full((n, 2), np.nan)
        self._last_s = np.full(n, -math.inf)
        self._stale_s = np.full(n, -math.inf)
        self._known = np.zeros(n, dtype=bool)
        self._row_of_uid: dict[str, int] = {}
        self.counters = {"reports": 0, "ignored": 0, "out_of_order": 0, "expired": 0, "joined": 0}

    def __len__(self) -> int:
        return len(self._cols)

    @property
    def columns(self) -> tuple[int, ...]:
        return tuple(self._cols)

    def _row_for(self, uid: str, callsign: str | None) -> int | None:
        row = self._row_of_uid.get(uid)
        if row is not None:
            return row
        # Named crews first (a contact named in the mission is never taken by a pattern), then
        # a free pattern slot; a named crew whose contact is unknown may be taken by a new uid
        # with its callsign (a phone restarted with a new uid).
        for named in (True, False):
            for k, m in enumerate(self._match):
                if m.named != named or not m.matches(uid, callsign):
                    continue
                if self._uid[k] is None or (named and not self._known[k]):
                    old = self._uid[k]
                    if old is not None:
                        del self._row_of_uid[old]
                    self._uid[k] = uid
                    self._row_of_uid[uid] = k
                    if not named:
                        self.counters["joined"] += 1
                        log.info(
                            "TAK contact %s (%s) joins as crew %r",
                            uid,
                            callsign,
                            self._match[k].name,
                        )
                    return k
        return None

    def apply(self, event: object) -> bool:
        """Fold one event; True if it was a report of one of our crews."""
        if not isinstance(event, TakContactReported):
            return False
        row = self._row_for(event.uid, event.callsign)
        if row is None:
            self.counters["ignored"] += 1
            return False
        if event.t_s < self._last_s[row]:
            self.counters["out_of_order"] += 1
            return True
        if event.stale_s <= event.t_s:  # stale on arrival: says nothing about now
            self.counters["ignored"] += 1
            return True
        o = self.origin
        ned = geodetic_to_ned_m(
            event.lat_deg,
            event.lon_deg,
            o.alt_amsl_m,  # the horizontal position is what the plan uses
            o.lat_deg,
            o.lon_deg,
            o.alt_amsl_m,
        )
        if not self._known[row]:
            log.info(
                "TAK crew %r (%s): position %.1f m N, %.1f m E",
                self._match[row].name,
                event.callsign or event.uid,
                ned[0],
                ned[1],
            )
        self._ne_m[row] = ned[:2]
        self._last_s[row] = event.t_s
        self._stale_s[row] = event.stale_s
        self._known[row] = True
        if event.callsign:
            self._callsign[row] = event.callsign
        self.counters["reports"] += 1
        return True

    def expire(self, now_s: float) -> list[int]:
        """Make every crew whose report went stale by ``now_s`` unknown; returns their columns."""
        gone = np.flatnonzero(self._known & (self._stale_s <= now_s))
        for k in gone.tolist():
            self._known[k] = False
            self.counters["expired"] += 1
            log.warning(
                "TAK crew %r (%s) is stale since %.1f s: planned as unknown",
                self._match[k].name,
                self._callsign[k] or self._uid[k],
                self._stale_s[k],
            )
        return [self._cols[k] for k in gone.tolist()]

    def fill(self, task_pos_m: np.ndarray) -> np.ndarray:
        """``task_pos_m`` (M, 2) with every TAK column replaced by its crew's position, NaN
        where the crew is unknown (never heard, or stale). Returns a new array."""
        out = np.array(task_pos_m, dtype=float, copy=True).reshape(-1, 2)
        if self._cols:
            out[self._cols] = np.where(self._known[:, None], self._ne_m, np.nan)
        return out

    def waiting_for(self) -> tuple[str, ...]:
        """Names of named crews (uid or callsign) never heard; pattern slots never wait."""
        return tuple(
            m.name
            for k, m in enumerate(self._match)
            if m.named and not math.isfinite(self._last_s[k])
        )

    def states(self) -> list[CrewState]:
        return [
            CrewState(
                column=c,
                name=self._match[k].name,
                uid=self._uid[k],
                callsign=self._callsign[k],
                known=bool(self._known[k]),
                last_s=float(self._last_s[k]),
                stale_s=float(self._stale_s[k]),
                last_ne_m=self._ne_m[k].copy(),
            )
            for k, c in enumerate(self._cols)
        ]

"""The rotation of one flight (:class:`RotationSetup`): the relay-rotation policy and what the
station knows of the batteries, apart from the operator's step that runs it
(:mod:`gcs.operations.rotation`) so that the operator's shared state can name it without an
import circle (tests/test_layering.py)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gcs.landing import LandingDescent
from planner.endurance import (
    AIR,
    INBOUND,
    PHASES,
    SWAPPING,
    RotationEvent,
    RotationPolicy,
)

__all__ = ["RotationSetup", "SWAP_CONFIRM"]

log = logging.getLogger(__name__)

#: Who confirms a battery swap (``RotationSetup.swap_confirm``, ``phireman fly --swap-confirm``).
SWAP_CONFIRM = ("auto", "manual")

#: A relay's reserve time is recorded to this many seconds (``RotationSetup.state``): the state
#: then stays equal from one tick to the next while nothing happens, and is recorded only when
#: it changes.
RESERVE_ROUND_S = 5.0


@dataclass
class RotationSetup:
    """The rotation of one flight: the policy and what the station knows of the batteries from
    the mission (not truth: the nominal endurance the operator wrote down)."""

    policy: RotationPolicy
    hover_drain_per_s: float
    """Nominal drain in a hover, fraction per second (1 / the mission's endurance): the floor
    of the estimate, and the drain before the first estimate."""
    return_drain_factor: float = 1.0
    """The drain flying home at full speed over the hover drain (1 + speed_drain_frac)."""
    base_ne_m: tuple[float, float] = (0.0, 0.0)
    """The base (the vehicles' home) in the mission frame, metres north / east."""
    land_radius_m: float = 30.0
    """Disarmed within this of the base = landed at the base, metres (GPS and RTL spread)."""
    full_frac: float = 0.95
    """A charge at least this after landing = a fresh battery."""
    failsafe_margin_frac: float = 0.05
    """An RTL / LAND nobody commanded, on a vehicle at most this above the policy's low level
    (``critical_frac``) or reporting a low charge state, is the firmware's battery failsafe."""
    lost_after_s: float = 30.0
    """A flying vehicle silent this long is lost to the rotation (the planner drops it sooner)."""
    swap_confirm: str = "auto"
    """Who ends a swap on a pad (docs/design/endurance.md §8): ``auto``, the station, when the
    vehicle comes back powered and full (a reboot, or a charge risen to ``full_frac``), or the
    ground crew first (the operator action ``confirm_swap``); ``manual``, only the ground crew.
    Either way a confirmed vehicle is ready once it is heard without a low battery."""
    counters: dict[str, int] = field(
        default_factory=lambda: {
            "battery_failsafes": 0,
            "landed_away": 0,
            "reboots": 0,
            "swaps_confirmed_by_crew": 0,
        }
    )
    min_battery_in_air: float = 1.0
    events: list[RotationEvent] = field(default_factory=list)
    gone: set[int] = field(default_factory=set)
    """Rows landed away from the base (lost to the mission)."""
    landed_s: dict[int, float] = field(default_factory=dict)
    """Row -> when it was seen landed at the base (a reboot after it confirms the swap)."""
    landed_frac: dict[int, float] = field(default_factory=dict)
    home_ne_m: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    """(N, 2) each row's pad (first heard disarmed on the ground), mission frame (NaN: not yet)."""
    rebooted_home: set[int] = field(default_factory=set)
    """Rows power-cycled since they were sent home (the crew's swap), until the swap is
    confirmed: the reboot may come before the station heard the landing."""
    home_cmd_s: dict[int, float] = field(default_factory=dict)
    """Row -> when it was last told to go home / land (retry pacing)."""
    time_to_reserve_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    """(N,) at the last tick (inf: not draining)."""
    tick_s: float = math.nan
    """When the last tick ran (station core seconds): the time ``time_to_reserve_s`` counts from."""
    confirmed_s: dict[int, float] = field(default_factory=dict)
    """Row -> when the ground crew confirmed its swap (until the swap is done or it is lost)."""
    land_from_m: float = 0.0
    """Height above the pad a vehicle lands from (the top flight layer), metres: with the
    vehicles' landing parameters, the policy's ``land_s`` (:meth:`use_landing`)."""
    replan: Callable[[float], RotationPolicy] | None = field(default=None, repr=False)
    """The policy again with another ``land_s`` (the plan's K counts it); None: kept as built."""

    def __post_init__(self) -> None:
        if not self.hover_drain_per_s > 0:
            raise ValueError(f"hover_drain_per_s must be > 0, got {self.hover_drain_per_s}")
        if self.swap_confirm not in SWAP_CONFIRM:
            raise ValueError(
                f"swap_confirm must be one of {', '.join(SWAP_CONFIRM)}, got {self.swap_confirm!r}"
            )

    def use_landing(
        self, descents: Sequence[LandingDescent], return_alts_m: Sequence[float] | None = None
    ) -> float | None:
        """Plan with the vehicles' own landing (:mod:`gcs.landing`, from the parameters the audit
        read), before the first tick: ``land_s`` becomes the slowest vehicle's descent from
        :attr:`land_from_m`, or from its return altitude where that is higher (``return_alts_m``,
        one per descent: a relay sent home by RTL climbs to it first, and lands from it;
        :func:`gcs.landing.return_alt_m`), and the policy is built again (:attr:`replan`: the
        reserve, the turnaround and K all count it; a mission's own ``endurance.params.land_s``
        still wins). Returns the new ``land_s``; None when nothing changed (no vehicle, no
        :attr:`replan`, the rotation already ticking, or a plan the new landing makes
        impossible, logged)."""
        if not descents or self.replan is None or math.isfinite(self.tick_s):
            return None
        heights = [self.land_from_m] * len(descents) if return_alts_m is None else return_alts_m
        if len(heights) != len(descents):
            raise ValueError(f"{len(heights)} return altitudes for {len(descents)} descents")
        land_s = max(d.time_s(max(self.land_from_m, float(h))) for d, h in zip(descents, heights))
        if land_s == self.policy.params.land_s:
            return None
        try:
            policy = self.replan(land_s)
        except ValueError as exc:  # a landing so slow that no sortie is left
            log.warning("rotation: kept the default landing (%.0f s): %s", land_s, exc)
            return None
        log.info(
            "rotation: the vehicles land in %.0f s from %.0f m (was %.0f s): %d of %d fly at once",
            land_s,
            self.land_from_m,
            self.policy.params.land_s,
            policy.flying,
            policy.n_drones,
        )
        self.policy = policy
        return float(policy.params.land_s)

    def state(self, ids: Sequence[str]) -> dict[str, Any]:
        """The rotation as the operator's view draws it (docs/design/endurance.md §8), JSON-able.

        Times are absolute (station core seconds), so the state of a quiet tick equals the one
        before it (what ``rotation.jsonl`` relies on to record changes only). ``ids``: the
        vehicle id (``"LINK:SYSID"``) of each fleet row; the policy's rows are the fleet's.

        Keys: ``swap_confirm``; ``vehicles`` and ``phase`` (one entry per policy row);
        ``inbound`` (``[spare, relay]`` pairs: who relieves whom); ``reserve_at_s`` (relay ->
        when it reaches its reserve, whole seconds to :data:`RESERVE_ROUND_S`; relays in the plan
        with no spare on its way); ``pads`` (one per pad: the vehicle on it, when its swap started, when the
        crew confirmed it); ``swap_time_s``; ``return_speed_m_s`` (for the spares' ETA);
        ``batteries`` (charged on the shelf, the charging
        ones' finish times, the ones waiting for a charger, chargers); ``counters``
        (:meth:`summary`).
        """
        pol = self.policy
        n = pol.n_drones
        who = [str(ids[i]) if i < len(ids) else f"row {i}" for i in range(n)]
        ph = pol.phase
        pads: list[dict[str, Any]] = []
        for p in range(pol.base.pads):
            rows = np.flatnonzero((pol.pad == p) & (ph == SWAPPING))
            if not rows.size:
                pads.append({"vehicle": None})
                continue
            i = int(rows[0])
            pads.append(
                {
                    "vehicle": who[i],
                    "since_s": round(float(pol.swap_end_s[i]) - pol.base.swap_time_s, 1),
                    "confirmed_s": None
                    if i not in self.confirmed_s
                    else round(self.confirmed_s[i], 1),
                }
            )
        reserve: dict[str, int] = {}
        ttr = self.time_to_reserve_s
        if ttr.shape == (n,) and math.isfinite(self.tick_s):
            for i in np.flatnonzero((ph == AIR) & (pol.replaced_by < 0)).tolist():
                if math.isfinite(ttr[i]):
                    at = RESERVE_ROUND_S * round((self.tick_s + ttr[i]) / RESERVE_ROUND_S)
                    reserve[who[i]] = int(round(at))
        return {
            "swap_confirm": self.swap_confirm,
            "vehicles": who,
            "phase": [PHASES[int(p)] for p in ph],
            "inbound": [
                [who[k], who[int(pol.replaces[k])]]
                for k in np.flatnonzero((ph == INBOUND) & (pol.replaces >= 0)).tolist()
            ],
            "reserve_at_s": reserve,
            "pads": pads,
            "swap_time_s": pol.base.swap_time_s,
            "return_speed_m_s": pol.params.return_speed_m_s,
            "batteries": {
                "charged": pol.stock,
                "charging_done_s": [round(t, 1) for t in pol.charging_done_s],
                "queued": pol.charge_queue,
                "chargers": pol.base.chargers,
            },
            "counters": self.summary(),
        }

    def event_dicts(self, start: int, ids: Sequence[str]) -> list[dict[str, Any]]:
        """``events[start:]`` as JSON-able dicts (``t_s``, ``kind``, ``vehicle``, ``other``), the
        rows named by their vehicle ids."""

        def name(i: int) -> str | None:
            return None if i < 0 else str(ids[i]) if i < len(ids) else f"row {i}"

        return [
            {
                "t_s": round(e.t_s, 1),
                "kind": e.kind,
                "vehicle": name(e.drone),
                "other": name(e.other),
            }
            for e in self.events[start:]
        ]

    def summary(self) -> dict[str, Any]:
        """For the status line and summary.json (the in-process run's keys, where they exist)."""
        s = self.policy.summary()
        return {
            "rotations": s["rotations"],
            "swaps": s["swaps"],
            "forced_returns": s["forced_returns"],
            "battery_failsafes_in_air": self.counters["battery_failsafes"],
            "landed_away": self.counters["landed_away"],
            "no_spare": s["no_spare"],
            "min_battery_in_air": round(self.min_battery_in_air, 4),
            "planned_at_start": self.policy.flying,
            "land_s": round(float(self.policy.params.land_s), 1),
            "reboots": self.counters["reboots"],
            "swap_confirm": self.swap_confirm,
            "swaps_confirmed_by_crew": self.counters["swaps_confirmed_by_crew"],
            "recovered": s["recovered"],
            "in_air": s["in_air"],
            "ready": s["ready"],
            "on_pads": s["on_pads"],
            "batteries_charged": s["batteries_charged"],
        }

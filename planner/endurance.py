"""Relay rotation through the base: batteries, landing pads, swaps and the decision who flies.

A multirotor relay flies 20-40 minutes; a wildfire operation lasts hours. This module is the one
policy that keeps a mesh up through battery swaps (docs/design/endurance.md): before a relay's
battery reaches its *reserve* (the charge it needs to fly home with a margin above the firmware's
critical level), a charged drone waiting at the base flies to the relay's position; only once the
replacement holds that position and is networked does the tired relay leave the plan and fly
home, land on a pad, get a charged battery (a swap of ``swap_time_s``; the battery taken out
charges for ``charge_time_s`` on one of ``chargers``) and wait as a spare.

The same :class:`RotationPolicy` runs in the paper's world (:mod:`vehicle_emu.world` with an
endurance model, driven by :mod:`mission.experiments.world_loop`) and in the ground station's tick
(:mod:`gcs.operations`), so it is pure: time (``now_s``) and every measurement are arguments,
nothing is read from a clock or from ground truth it was not given. The station gives it what its
telemetry says (battery fraction and drain rate estimated from SYS_STATUS / BATTERY_STATUS); the
paper's world gives it the world's own battery.

Phases of a drone (:data:`PHASES`):

* ``air``       in the plan: the planner moves it;
* ``inbound``   a spare flying from the base to the position of the relay it replaces;
* ``returning`` left the plan, flying home (replaced, or out of reserve);
* ``landed``    on the ground at the base, waiting for a free pad;
* ``swapping``  on a pad while its battery is changed (``swap_time_s``, or until the ground crew
  confirms the swap when the caller passes ``swap_done``);
* ``no_battery`` on the ground at the base, off the pads, no charged battery in stock: waits;
* ``ready``     charged and parked at the base: a spare;
* ``lost``      gone (attrition, a failsafe landing away from the base, a vehicle not heard).

Everything is vectorised over drones; the few decisions per tick that pair a spare with a relay
loop over the relays that need one this tick (a handful), never over the fleet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

__all__ = [
    "AIR",
    "INBOUND",
    "RETURNING",
    "LANDED",
    "SWAPPING",
    "NO_BATTERY",
    "READY",
    "LOST",
    "PHASES",
    "BaseResources",
    "EnduranceParams",
    "FleetPlan",
    "PAD_UTILISATION",
    "REFILL_MARGIN",
    "RotationEvent",
    "RotationOutput",
    "RotationPolicy",
    "plan_fleet",
    "time_to_reserve_s",
]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]

AIR, INBOUND, RETURNING, LANDED, SWAPPING, NO_BATTERY, READY, LOST = range(8)
#: Phase codes -> names (the order of the constants above).
PHASES: tuple[str, ...] = (
    "air",
    "inbound",
    "returning",
    "landed",
    "swapping",
    "no_battery",
    "ready",
    "lost",
)


#: A refill (``EnduranceParams.refill_lost``) keeps this many times the spares in circulation a
#: post needs (``RotationPolicy.spare_ratio``): turnarounds vary, spares are lost too.
REFILL_MARGIN = 1.5

#: The share of the pads' time a plan may use (:func:`plan_fleet`); at full use every small delay
#: queues drones at the base, and the queue only grows.
PAD_UTILISATION = 0.8


@dataclass(frozen=True)
class BaseResources:
    """What the base can do for batteries (the mission's ``endurance.base`` section).

    Defaults: a field crew with four landing pads, a one-minute swap, one charged spare battery
    per drone of a 50-drone fleet and sixteen chargers that need 45 minutes each
    (docs/design/endurance.md §2).
    """

    pads: int = 4
    """Landing pads where a battery can be swapped, one drone at a time each."""
    swap_time_s: float = 60.0
    """Time on the pad for one swap (land, change, power up)."""
    spare_batteries: int = 50
    """Charged batteries at the start, beyond the one in every drone."""
    chargers: int = 16
    """Batteries that can charge at once."""
    charge_time_s: float = 2700.0
    """Time to charge one battery."""

    def __post_init__(self) -> None:
        problems = []
        if self.pads < 1:
            problems.append(f"pads must be >= 1, got {self.pads}")
        if self.chargers < 0:
            problems.append(f"chargers must be >= 0, got {self.chargers}")
        if self.spare_batteries < 0:
            problems.append(f"spare_batteries must be >= 0, got {self.spare_batteries}")
        for name in ("swap_time_s", "charge_time_s"):
            if not getattr(self, name) > 0:
                problems.append(f"{name} must be > 0, got {getattr(self, name)}")
        if problems:
            raise ValueError("; ".join(problems))


@dataclass(frozen=True)
class EnduranceParams:
    """The rotation policy's settings (defaults: docs/design/endurance.md §3)."""

    critical_frac: float = 0.10
    """The firmware's critical level as a fraction of capacity: never reached in the air."""
    margin_frac: float = 0.05
    """Charge kept above critical on landing, for wind, a go-around, a pad that is busy."""
    return_speed_m_s: float = 5.0
    """Speed of a drone flying home or out to a relay, m/s."""
    handover_s: float = 20.0
    """Time the spare holds the relay's position, networked, before the relay leaves."""
    launch_s: float = 15.0
    """Time from the launch decision until a spare leaves the ground (arm, take off)."""
    land_s: float = 0.0
    """Time from over the pad to disarmed on it (the firmware's landing descent): 0 in the
    paper's 2-D world, which has no altitude; the station sets it from its flight layers
    (docs/design/endurance.md §7). It counts in the reserve (the charge to fly home *and land*),
    the turnaround and the cycle."""
    hold_radius_m: float = 10.0
    """A spare within this distance of the relay's position holds it."""
    slack_s: float = 30.0
    """Extra lead time when deciding to launch a spare (estimates are estimates)."""
    refill_lost: bool = True
    """Refill a post lost in the air (attrition) from the ready spares, up to the plan's K and
    while the spares in circulation keep the plan's ratio to the posts (docs/design/endurance.md
    §3); off: a relay lost in the air leaves its post empty for the rest of the mission. On by
    default since a paired 100-seed study of ``wildfire_2h`` (docs/results/endurance.md: TU1
    +0.73 points, better on 90 seeds, worse on 5, no battery failsafe in the air either way)."""

    def __post_init__(self) -> None:
        problems = []
        if not 0.0 <= self.critical_frac < 1.0:
            problems.append(f"critical_frac must be in [0, 1), got {self.critical_frac}")
        if not 0.0 <= self.margin_frac < 1.0 - self.critical_frac:
            problems.append(f"margin_frac must be in [0, 1 - critical), got {self.margin_frac}")
        for name in ("return_speed_m_s", "hold_radius_m"):
            if not getattr(self, name) > 0:
                problems.append(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("handover_s", "launch_s", "land_s", "slack_s"):
            if not getattr(self, name) >= 0:
                problems.append(f"{name} must be >= 0, got {getattr(self, name)}")
        if problems:
            raise ValueError("; ".join(problems))


def reserve_frac(
    dist_home_m: FloatArray, drain_per_s: FloatArray, params: EnduranceParams
) -> FloatArray:
    """(N,) the battery fraction at which each drone must start home.

    Enough to fly ``dist_home_m`` at ``return_speed_m_s`` draining ``drain_per_s``, descend to the
    pad (``land_s``) and land with ``critical_frac + margin_frac`` left.
    """
    fly_home_frac = np.asarray(drain_per_s, float) * (
        np.asarray(dist_home_m, float) / params.return_speed_m_s + params.land_s
    )
    return params.critical_frac + params.margin_frac + fly_home_frac


def time_to_reserve_s(
    battery_frac: FloatArray,
    drain_per_s: FloatArray,
    dist_home_m: FloatArray,
    params: EnduranceParams,
    return_drain_per_s: FloatArray | None = None,
) -> FloatArray:
    """(N,) seconds until each drone must start home (0 when already due; inf if not draining).

    Parameters
    ----------
    battery_frac : (N,) remaining charge, fraction of capacity (NaN: unknown -> 0 s)
    drain_per_s : (N,) fraction of capacity used per second at the current load
    dist_home_m : (N,) distance to the base, metres
    return_drain_per_s : (N,) the drain on the way home (at return speed); default
        ``drain_per_s``
    """
    b = np.asarray(battery_frac, float)
    r = np.asarray(drain_per_s, float)
    r_home = r if return_drain_per_s is None else np.asarray(return_drain_per_s, float)
    left = b - reserve_frac(dist_home_m, r_home, params)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(r > 0, left / np.where(r > 0, r, 1.0), np.inf)
    t = np.where(np.isnan(b), 0.0, t)
    return np.maximum(t, 0.0)


@dataclass(frozen=True)
class FleetPlan:
    """How many drones fly and how many wait (:func:`plan_fleet`)."""

    flying: int
    """Drones in the plan at once."""
    spares: int
    """Drones on the ground or in transit, cycling through the base."""
    sortie_s: float
    """Useful time in the plan per battery (take-off to reserve, minus the way out)."""
    limit: str
    """What bounds ``flying``: 'fleet', 'pads', 'batteries' or 'none' (no rotation needed)."""
    ground_s: float = 0.0
    """The rest of a drone's cycle, away from the plan (the way out and home, the handover, the
    landing, the swap): a post needs ``ground_s / sortie_s`` spares in circulation."""


def plan_fleet(
    n_drones: int,
    endurance_s: float,
    horizon_s: float,
    base: BaseResources,
    params: EnduranceParams,
    mean_dist_m: float,
) -> FleetPlan:
    """How many drones to keep in the plan so that rotations never starve the mesh.

    A battery gives ``endurance_s`` of hover. Per battery a drone spends the way out
    (``launch_s + d / v``), the useful sortie, the handover, the way home and the swap. Three
    budgets bound the number flying at once, K (docs/design/endurance.md §4):

    * the fleet: each of the K positions needs a fresh drone every sortie, and a drone is away from
      the plan for the cycle's non-useful part: ``K * cycle / sortie <= n_drones``;
    * the pads: ``K / sortie`` swaps per second at most ``PAD_UTILISATION * pads / swap_time_s``;
    * the batteries: at every time t up to the horizon, the ``K * (1 + t / sortie)`` battery lives
      used so far at most the ones in the drones, the spare stock and what the chargers have given
      back by then (the first charged battery comes back one charge after the first swap).

    When the mission is shorter than one sortie, everything flies (no rotation needed).
    """
    if n_drones < 1:
        raise ValueError(f"n_drones must be >= 1, got {n_drones}")
    if not endurance_s > 0 or not horizon_s > 0:
        raise ValueError("endurance_s and horizon_s must be > 0")
    v = params.return_speed_m_s
    transit_s = params.launch_s + mean_dist_m / v
    usable_s = endurance_s * (1.0 - params.critical_frac - params.margin_frac)
    # Useful time per battery: the usable charge less the way out and back, the landing, the
    # handover and the lead the policy takes (a relay is relieved up to ``slack_s`` before its
    # reserve).
    sortie_s = (
        usable_s
        - 2.0 * (mean_dist_m / v)
        - params.launch_s
        - params.land_s
        - params.handover_s
        - params.slack_s
    )
    if sortie_s <= 0:
        raise ValueError(
            f"a battery of {endurance_s:.0f} s cannot reach {mean_dist_m:.0f} m and come back "
            "with its reserve: no rotation is possible"
        )
    ground_s = base.swap_time_s + params.handover_s + transit_s + mean_dist_m / v + params.land_s
    if horizon_s <= sortie_s:
        return FleetPlan(n_drones, 0, sortie_s, "none", ground_s)
    cycle_s = sortie_s + ground_s
    k_fleet = math.floor(n_drones * sortie_s / cycle_s)
    # Pads busy at most PAD_UTILISATION of the time: a queue at full use grows without bound.
    k_pads = math.floor(PAD_UTILISATION * base.pads * sortie_s / base.swap_time_s)

    # Battery lives used by time t: the K in the air at the start and one per post per sortie,
    # K * (1 + t / sortie). Lives available: one in every drone, the stock, and what the chargers
    # give back, which starts one charge after the first swaps (about one sortie in). Both are
    # piecewise linear in t, so the bound is checked at the kink and at the horizon.
    def lives(t_s: float) -> float:
        charged = base.chargers * max(0.0, t_s - sortie_s - base.charge_time_s) / base.charge_time_s
        return n_drones + base.spare_batteries + charged

    k_batteries = min(
        math.floor(lives(t) / (1.0 + t / sortie_s))
        for t in (min(horizon_s, sortie_s + base.charge_time_s), horizon_s)
    )
    bounds = {"fleet": k_fleet, "pads": k_pads, "batteries": k_batteries}
    limit = min(bounds, key=lambda k: bounds[k])
    flying = max(1, min(n_drones - 1, bounds[limit]))
    return FleetPlan(flying, n_drones - flying, sortie_s, limit, ground_s)


@dataclass(frozen=True)
class RotationEvent:
    """Something the operator and the summary should know (``kind`` names in the docstring)."""

    t_s: float
    kind: str
    """'launch' (spare sent to relay ``other``), 'handover' (spare ``drone`` took ``other``'s
    place), 'return' (replaced), 'forced_return' (out of reserve without a replacement),
    'landed', 'swap_start', 'swap_done', 'no_spare', 'no_battery', 'pad_wait',
    'lost', 'failsafe_return' (the firmware's low-battery RTL, :meth:`RotationPolicy.failsafe`),
    'recovered' (a lost drone back at the base, charged, :meth:`RotationPolicy.recovered`),
    'refill' (a spare into a post lost in the air, ``EnduranceParams.refill_lost``) and, without
    rotation, 'relaunch'."""
    drone: int
    other: int = -1


@dataclass(frozen=True)
class RotationOutput:
    """One tick's decision."""

    planned: BoolArray
    """(N,) drones the planner plans this tick (phase ``air``)."""
    target_m: FloatArray
    """(N, 2) where each drone outside the plan goes (NaN rows: planned or lost). Inbound spares:
    the relay's position; returning, landed, on a pad or ready: the base."""
    on_ground: BoolArray
    """(N,) drones that should be on the ground at the base (landed, on a pad, ready)."""
    battery_swapped: BoolArray
    """(N,) drones whose swap finished this tick (the caller gives them a full battery)."""
    events: tuple[RotationEvent, ...] = ()


@dataclass
class RotationPolicy:
    """The rotation state machine (module docstring): one instance per mission.

    Parameters
    ----------
    n_drones : fleet size
    flying : drones in the plan at the start (:func:`plan_fleet`); the others start ``ready``
    base, params : the base's resources and the policy's settings
    """

    n_drones: int
    flying: int
    base: BaseResources = field(default_factory=BaseResources)
    params: EnduranceParams = field(default_factory=EnduranceParams)
    rotate: bool = True
    """False: no rotation, the reference every result is compared with (``--rotation off``):
    every drone flies until its firmware's low-battery failsafe sends it home (reported with
    :meth:`failsafe`), swaps at the base like the others and relaunches into the plan as soon as
    it is ready."""
    spare_ratio: float = 0.0
    """Spares in circulation a post needs (:attr:`FleetPlan.ground_s` over its ``sortie_s``);
    ``EnduranceParams.refill_lost`` refills a post only while the spares left keep
    :data:`REFILL_MARGIN` times this (0: the plan's own ratio, ``(n - flying) / flying``)."""
    turnaround_s: float = 0.0
    """A spare's time on the ground between two sorties (:attr:`FleetPlan.ground_s`): a refill
    keeps enough ready spares for every relief due within this and its launch lead."""
    phase: IntArray = field(init=False)
    replaces: IntArray = field(init=False)
    """(N,) the relay an inbound spare replaces (-1: none)."""
    replaced_by: IntArray = field(init=False)
    """(N,) the spare inbound to this relay (-1: none)."""
    swap_end_s: FloatArray = field(init=False)
    pad: IntArray = field(init=False)
    """(N,) the pad (0 .. ``base.pads - 1``) a drone is being swapped on (-1: none): the lowest
    free pad when its swap starts, free again when the swap is done or the drone is lost. What
    the operator's view names ("vehicle 7 on pad 2"); no decision depends on which pad."""
    stock: int = field(init=False)
    """Charged batteries on the shelf."""
    charging_done_s: list[float] = field(init=False)
    """Finish times of the batteries on a charger (sorted)."""
    charge_queue: int = field(init=False)
    """Empty batteries waiting for a free charger."""
    counters: dict[str, int] = field(init=False)
    _reported: set[tuple[str, int]] = field(init=False)

    def __post_init__(self) -> None:
        n = self.n_drones
        if not 0 <= self.flying <= n:
            raise ValueError(f"flying must be in [0, {n}], got {self.flying}")
        self.phase = np.full(n, READY, np.int64)
        self.phase[: self.flying] = AIR
        self.replaces = np.full(n, -1, np.int64)
        self.replaced_by = np.full(n, -1, np.int64)
        self.swap_end_s = np.full(n, np.inf)
        self.pad = np.full(n, -1, np.int64)
        self.stock = self.base.spare_batteries
        self.charging_done_s = []
        self.charge_queue = 0
        self.counters = {
            "rotations": 0,
            "forced_returns": 0,
            "failsafe_returns": 0,
            "swaps": 0,
            "no_spare": 0,
            "recovered": 0,
        }
        self._reported = set()

    # -- the per-tick decision --------------------------------------------------------------

    def step(
        self,
        now_s: float,
        pos_m: FloatArray,
        alive: BoolArray,
        battery_frac: FloatArray,
        drain_per_s: FloatArray,
        networked: BoolArray,
        landed_at_base: BoolArray,
        base_m: FloatArray | None = None,
        swap_done: BoolArray | None = None,
        return_drain_per_s: FloatArray | None = None,
        end_s: float = math.inf,
    ) -> RotationOutput:
        """Advance the rotation to ``now_s`` and decide this tick.

        Parameters
        ----------
        now_s : mission time, seconds (non-decreasing between calls)
        pos_m : (N, 2) positions, metres, in the frame of ``base_m``
        alive : (N,) drones that exist (not attrited, still heard)
        battery_frac : (N,) remaining charge as a fraction (NaN: unknown)
        drain_per_s : (N,) fraction per second at the current load (in the air: as measured;
            used for the reserve)
        networked : (N,) connected to the base through the mesh (the handover's link check)
        landed_at_base : (N,) on the ground at the base (the caller's own test: disarmed at home,
            or within the landing radius in the paper's world)
        base_m : (2,) base position (default origin)
        swap_done : (N,) the ground crew confirmed the swap of a drone on a pad (or it came back
            powered and full); None: swaps finish after ``swap_time_s``
        return_drain_per_s : (N,) the drain flying home at return speed (the reserve's way
            home); default ``drain_per_s``
        end_s : the mission's end, in the clock of ``now_s`` (inf: none known). A relay whose
            reserve falls after it (by more than ``slack_s``) holds its post to the end: it is
            not relieved, nor moved earlier in the relief schedule, and spends no spare's battery
            (docs/design/endurance.md §3)
        """
        n = self.n_drones
        p = self.params
        base = np.zeros(2) if base_m is None else np.asarray(base_m, float)
        pos = np.asarray(pos_m, float)
        alive = np.asarray(alive, bool)
        batt = np.asarray(battery_frac, float)
        rate = np.asarray(drain_per_s, float)
        networked = np.asarray(networked, bool)
        landed = np.asarray(landed_at_base, bool)
        events: list[RotationEvent] = []
        swapped = np.zeros(n, bool)
        ph = self.phase

        # 1. Losses: a lost spare frees its relay; a lost relay frees its spare (who joins the plan).
        newly_lost = (ph != LOST) & ~alive
        for i in np.flatnonzero(newly_lost):
            events.append(RotationEvent(now_s, "lost", int(i)))
            j = int(self.replaces[i])
            if j >= 0:
                self.replaced_by[j] = -1
            k = int(self.replaced_by[i])
            if k >= 0:
                self.replaces[k] = -1
                if ph[k] == INBOUND:
                    ph[k] = AIR  # it was flying to a relay that is gone: plan it where it is
        ph[newly_lost] = LOST
        self.pad[newly_lost] = -1
        self.replaces[newly_lost] = -1
        self.replaced_by[newly_lost] = -1

        # 2. Chargers: finished batteries go to the shelf, queued ones start.
        self._advance_chargers(now_s)

        # 3. Ground: returning drones that landed take a pad, swaps end.
        arrived = (ph == RETURNING) & landed
        ph[arrived] = LANDED
        for i in np.flatnonzero(arrived):
            events.append(RotationEvent(now_s, "landed", int(i)))
        if swap_done is None:
            done = (ph == SWAPPING) & (self.swap_end_s <= now_s)
        else:
            done = (ph == SWAPPING) & np.asarray(swap_done, bool)
        for i in np.flatnonzero(done):
            ph[i] = READY
            swapped[i] = True
            self.swap_end_s[i] = np.inf
            self.pad[i] = -1
            self.counters["swaps"] += 1
            events.append(RotationEvent(now_s, "swap_done", int(i)))
        # A landed drone waits off the pads until a pad and a charged battery are both free.
        pads_free = self.base.pads - int(np.count_nonzero(ph == SWAPPING))
        for i in np.flatnonzero((ph == LANDED) | (ph == NO_BATTERY)):
            if self.stock <= 0:
                if ph[i] != NO_BATTERY:
                    ph[i] = NO_BATTERY
                    events.append(RotationEvent(now_s, "no_battery", int(i)))
                continue
            if pads_free <= 0:
                if ("pad_wait", int(i)) not in self._reported:
                    self._reported.add(("pad_wait", int(i)))
                    events.append(RotationEvent(now_s, "pad_wait", int(i)))
                continue
            pads_free -= 1
            self._reported.discard(("pad_wait", int(i)))
            self._start_swap(int(i), now_s, events)

        # 4. Handover: an inbound spare holding its relay's position, networked, takes its place.
        inbound = np.flatnonzero(ph == INBOUND)
        for k in inbound.tolist():
            j = int(self.replaces[k])
            if j < 0:
                continue
            if networked[k] and np.hypot(*(pos[k] - pos[j])) <= p.hold_radius_m:
                ph[k] = AIR
                ph[j] = RETURNING
                self.replaces[k] = -1
                self.replaced_by[j] = -1
                self.counters["rotations"] += 1
                events.append(RotationEvent(now_s, "handover", int(k), j))
                events.append(RotationEvent(now_s, "return", j, int(k)))

        # 5. Reserve: who must go home now, and who needs a spare launched now.
        dist = np.hypot(pos[:, 0] - base[0], pos[:, 1] - base[1])
        in_air = (ph == AIR) | (ph == INBOUND)
        t_res = time_to_reserve_s(batt, rate, dist, p, return_drain_per_s)
        if not self.rotate:
            # No rotation: only the firmware's failsafe (:meth:`failsafe`) sends a drone home, and
            # a drone ready at the base relaunches into the plan at once.
            for i in np.flatnonzero(ph == READY):
                ph[i] = AIR
                events.append(RotationEvent(now_s, "relaunch", int(i)))
            return self._output(ph, pos, base, swapped, events)
        forced = in_air & (t_res <= 0.0)
        for i in np.flatnonzero(forced):
            k = int(self.replaced_by[i])
            j = int(self.replaces[i])
            if k >= 0:  # its spare continues and joins the plan where it arrives
                self.replaces[k] = -1
                ph[k] = AIR
            if j >= 0:  # a spare out of reserve before its handover: the relay stays
                self.replaced_by[j] = -1
            self.replaces[i] = -1
            self.replaced_by[i] = -1
            ph[i] = RETURNING
            self.counters["forced_returns"] += 1
            events.append(RotationEvent(now_s, "forced_return", int(i)))
        lead_s = p.launch_s + dist / p.return_speed_m_s + p.handover_s + p.slack_s
        waiting = (ph == AIR) & (self.replaced_by < 0)
        if math.isfinite(end_s):
            waiting &= t_res <= end_s - now_s + p.slack_s
        relief_s = self._relief_schedule(t_res, dist, waiting, alive)
        need = waiting & (relief_s <= lead_s)
        if need.any():
            # Most urgent first; the fullest spare goes.
            order = np.flatnonzero(need)[np.argsort(relief_s[need], kind="stable")]
            spares = np.flatnonzero(ph == READY)
            spares = spares[np.argsort(-np.nan_to_num(batt[spares], nan=0.0), kind="stable")]
            for n_used, j in enumerate(order):
                if n_used >= len(spares):
                    # Starved only when its own reserve is due, not when the schedule wanted it
                    # relieved early (docs/design/endurance.md §3).
                    if t_res[j] <= lead_s[j] and ("no_spare", int(j)) not in self._reported:
                        self._reported.add(("no_spare", int(j)))
                        self.counters["no_spare"] += 1
                        events.append(RotationEvent(now_s, "no_spare", int(j)))
                    continue
                k = int(spares[n_used])
                ph[k] = INBOUND
                self.replaces[k] = int(j)
                self.replaced_by[j] = k
                self._reported.discard(("no_spare", int(j)))
                events.append(RotationEvent(now_s, "launch", k, int(j)))
        if p.refill_lost:
            self._refill(now_s, alive, batt, events, relief_s - lead_s)

        return self._output(ph, pos, base, swapped, events)

    def _refill(
        self,
        now_s: float,
        alive: BoolArray,
        batt: FloatArray,
        events: list[RotationEvent],
        relief_after_lead_s: FloatArray,
    ) -> None:
        """One ready spare (the fullest) joins the plan at the base when fewer than K posts are
        held, and the spares left in circulation still relieve every post: at least
        :data:`REFILL_MARGIN` × :attr:`spare_ratio` per post, and as many ready spares left as
        the reliefs due (relays without a spare whose relief, ``relief_after_lead_s`` after
        their launch lead, falls within :attr:`turnaround_s`: a spare grounded now is back too
        late for them). A post lost in the air is held again (``refill`` event)."""
        ph = self.phase
        k = self.flying
        if k <= 0 or k >= self.n_drones:
            return
        posts = int(np.count_nonzero(ph == AIR))
        circulating = int(np.count_nonzero(alive & (ph != AIR) & (ph != LOST)))
        ready = np.flatnonzero(ph == READY)
        if self.spare_ratio > 0:
            ratio = REFILL_MARGIN * self.spare_ratio
        else:
            ratio = (self.n_drones - k) / k
        if posts >= k or not ready.size or circulating - 1 < ratio * (posts + 1):
            return
        due = (ph == AIR) & (self.replaced_by < 0) & (relief_after_lead_s <= self.turnaround_s)
        if ready.size - 1 < int(np.count_nonzero(due)):
            return
        i = int(ready[np.argmax(np.nan_to_num(batt[ready], nan=0.0))])
        ph[i] = AIR
        events.append(RotationEvent(now_s, "refill", i))

    def _output(
        self,
        ph: IntArray,
        pos: FloatArray,
        base: FloatArray,
        swapped: BoolArray,
        events: list[RotationEvent],
    ) -> RotationOutput:
        """Targets of the drones outside the plan, from their phases."""
        n = self.n_drones
        target = np.full((n, 2), np.nan)
        inb = np.flatnonzero(ph == INBOUND)
        target[inb] = pos[self.replaces[inb]]
        home = (ph == RETURNING) | (ph == LANDED) | (ph == SWAPPING) | (ph == NO_BATTERY)
        home |= ph == READY
        target[home] = base
        on_ground = (ph == LANDED) | (ph == SWAPPING) | (ph == NO_BATTERY) | (ph == READY)
        return RotationOutput(ph == AIR, target, on_ground, swapped, tuple(events))

    def _relief_schedule(
        self, t_res: FloatArray, dist_m: FloatArray, waiting: BoolArray, alive: BoolArray
    ) -> FloatArray:
        """(N,) seconds from now until each waiting relay should be relieved (inf elsewhere).

        No later than its reserve, and no two reliefs closer than the base can turn a spare
        around: ``spacing = max(turnaround / spares in circulation, swap_time / pads)``, where a
        spare's turnaround is its way out and back, the handover, the landing and a swap. Relays whose reserves
        fall due together (the first battery of a fleet that took off together) are relieved
        early, one spacing apart, instead of all at once with too few spares: the backward pass
        ``r_k = min(t_res_k, r_(k+1) - spacing)`` over the relays sorted by reserve, as a reversed
        running minimum (docs/design/endurance.md §3).
        """
        out = np.full(self.n_drones, np.inf)
        idx = np.flatnonzero(waiting)
        if idx.size == 0:
            return out
        p = self.params
        circulating = int(np.count_nonzero(alive & (self.phase != AIR) & (self.phase != LOST)))
        turnaround_s = (
            p.launch_s
            + 2.0 * float(dist_m[idx].mean()) / p.return_speed_m_s
            + p.handover_s
            + p.land_s
            + self.base.swap_time_s
        )
        spacing_s = max(turnaround_s / max(1, circulating), self.base.swap_time_s / self.base.pads)
        order = idx[np.argsort(t_res[idx], kind="stable")]
        ranks = np.arange(order.size) * spacing_s
        shifted = t_res[order] - ranks
        # r_k = min_{j >= k}(t_res_j - j * spacing) + k * spacing
        out[order] = np.minimum.accumulate(shifted[::-1])[::-1] + ranks
        return out

    def failsafe(self, i: int, now_s: float) -> RotationEvent:
        """Drone ``i``'s firmware sent it home on its own (a low-battery failsafe's RTL): it leaves
        the plan as if out of reserve. Its inbound spare, if any, joins the plan where it
        arrives. Returns the event to log ('failsafe_return')."""
        k = int(self.replaced_by[i])
        if k >= 0:
            self.replaces[k] = -1
            self.phase[k] = AIR
        j = int(self.replaces[i])
        if j >= 0:
            self.replaced_by[j] = -1
        self.replaces[i] = -1
        self.replaced_by[i] = -1
        if self.phase[i] != LOST:
            self.phase[i] = RETURNING
        self.counters["failsafe_returns"] += 1
        return RotationEvent(now_s, "failsafe_return", int(i))

    def recovered(self, i: int, now_s: float) -> RotationEvent:
        """Drone ``i``, once lost, is back on the ground at the base, powered up and charged (a
        power-cycled vehicle is the same vehicle): a spare again. Returns the event to log
        ('recovered'). Its battery is not taken from the shelf: the policy did not swap it."""
        if self.phase[i] != LOST:
            raise ValueError(f"drone {i} is not lost (phase {PHASES[int(self.phase[i])]})")
        self.phase[i] = READY
        self.counters["recovered"] += 1
        return RotationEvent(now_s, "recovered", int(i))

    # -- the base's batteries --------------------------------------------------------------

    def _start_swap(self, i: int, now_s: float, events: list[RotationEvent]) -> None:
        self.stock -= 1
        self.phase[i] = SWAPPING
        self.swap_end_s[i] = now_s + self.base.swap_time_s
        taken = set(self.pad[(self.phase == SWAPPING) & (self.pad >= 0)].tolist())
        # The step starts a swap only while fewer than ``pads`` drones are on the pads.
        self.pad[i] = next(p for p in range(self.base.pads) if p not in taken)
        self.charge_queue += 1  # the battery taken out goes to the chargers
        self._advance_chargers(now_s)
        events.append(RotationEvent(now_s, "swap_start", i))

    def _advance_chargers(self, now_s: float) -> None:
        while True:
            # Batteries finished by now go to the shelf; each frees its charger at its own time,
            # so a queued battery starts then, not now.
            if self.charging_done_s and self.charging_done_s[0] <= now_s:
                t_free = self.charging_done_s.pop(0)
                self.stock += 1
                if self.charge_queue > 0:
                    self.charge_queue -= 1
                    self.charging_done_s.append(t_free + self.base.charge_time_s)
                    self.charging_done_s.sort()
                continue
            if self.charge_queue > 0 and len(self.charging_done_s) < self.base.chargers:
                self.charge_queue -= 1
                self.charging_done_s.append(now_s + self.base.charge_time_s)
                self.charging_done_s.sort()
                continue
            return

    # -- what the operator sees ------------------------------------------------------------

    def summary(self) -> dict[str, int]:
        """Counters and the base's state, for the status line and summary.json."""
        ph = self.phase
        return {
            **self.counters,
            "in_air": int(np.count_nonzero((ph == AIR) | (ph == INBOUND) | (ph == RETURNING))),
            "ready": int(np.count_nonzero(ph == READY)),
            "on_pads": int(np.count_nonzero(ph == SWAPPING)),
            "waiting": int(np.count_nonzero((ph == LANDED) | (ph == NO_BATTERY))),
            "batteries_charged": self.stock,
            "batteries_charging": len(self.charging_done_s) + self.charge_queue,
        }

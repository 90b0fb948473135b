"""The rotation step: relays rotated through the base in the station's control tick
(docs/design/endurance.md §1-§3), when the mission has batteries.

A mixin of :class:`gcs.operations.Operator`. Each control tick it runs
:class:`planner.endurance.RotationPolicy` on what the station's telemetry says, the way the paper's
world drives it in process (``mission/experiments/endurance.py``):

* only ``air`` vehicles reach the planner (its ``alive`` and ``networked`` masks); spares
  ``ready`` stay on the ground at home (the launch flies only the planned K);
* an ``inbound`` spare is armed, taken off (the launch's ``_drive``) and sent to its relay's
  position; the policy hands the post over once it holds it, networked;
* a ``returning`` vehicle is sent home: RTL, or with ``end: land`` a target over the base and
  LAND there (the station's usual end action);
* ``landed_at_base`` = heard, disarmed, within ``land_radius_m`` of its pad (where it was
  first heard on the ground: its home, where RTL lands it; the base's centre until then);
* the swap is confirmed by the ground crew (the operator action ``confirm_swap``), or, with
  ``swap_confirm`` ``auto`` (the default), when the vehicle comes back powered and full (a reboot,
  :class:`gcs.events.VehicleRebooted`, or a charge that rose to ``full_frac``): ``swap_done``;
  the reboot may come before the station heard it land (the crew pulled the pack as it
  disarmed): a reboot after it was sent home counts, and a returning vehicle last heard low at
  the base is not lost while it is silent;
* the firmware's own low-battery RTL or LAND (a mode change the station did not command, on a
  vehicle whose battery is low) -> :meth:`planner.endurance.RotationPolicy.failsafe`; a vehicle
  that lands away from the base is gone for the mission (counted ``landed_away``);
* a lost vehicle (not heard, or landed away) heard again on its pad, disarmed and full, is the
  same vehicle back: a spare again (:meth:`planner.endurance.RotationPolicy.recovered`).

A vehicle on the ground at the base may go silent (its battery is out): it is not lost. Without a
:class:`RotationSetup` nothing here runs and the operator flies exactly as before.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from gcs.autopilot import adapter_for
from gcs.events import HomePositionReceived, ModeChanged, VehicleRebooted
from gcs.fleet import FleetSnapshot
from gcs.landing import LANDING_PARAMS, RTL_ALT_PARAMS, landing_descent, return_alt_m
from gcs.link import LinkUsageError, UnknownVehicle
from gcs.operations._state import OperatorState
from gcs.operations.config import _Row
from gcs.operations.phases import Phase
from gcs.operations.rotation_setup import RotationSetup
from planner.endurance import (
    AIR,
    INBOUND,
    LANDED,
    LOST,
    NO_BATTERY,
    PHASES,
    READY,
    RETURNING,
    SWAPPING,
    RotationEvent,
    time_to_reserve_s,
)
from planner.geometry import geodetic_to_ned_m

__all__ = ["RotationSetup", "RotationStep"]

log = logging.getLogger(__name__)

_GROUND = (LANDED, SWAPPING, NO_BATTERY, READY)


class RotationStep(OperatorState):
    """The rotation of :class:`gcs.operations.Operator` (see the module docstring)."""

    # ------------------------------------------------------------------ the audit's parameters

    def _rotation_landing_params(self, autopilot: int) -> tuple[str, ...]:
        """The landing parameters the audit reads of a vehicle when the flight rotates relays
        (:data:`gcs.landing.LANDING_PARAMS`) and its return altitude (a relay sent home by RTL
        lands from it when it is above the layers, :data:`gcs.landing.RTL_ALT_PARAMS`); none
        without a rotation."""
        if self.rotation is None:
            return ()
        rtl = RTL_ALT_PARAMS.get(autopilot)
        return LANDING_PARAMS.get(autopilot, ()) + ((rtl[0],) if rtl is not None else ())

    def _rotation_use_landing(
        self, vehicles: dict[tuple[int, int], tuple[int, dict[str, float]]]
    ) -> None:
        """The audit is over: the rotation plans with the vehicles' own landing, from their own
        return altitude where it is above the layers (what they gave, with the station's
        confirmed writes, e.g. the mission's WPNAV_SPEED_DN or the return altitude raised over
        terrain; the firmware's defaults for what they did not give)."""
        rot = self.rotation
        if rot is None or not vehicles:
            return
        written: dict[tuple[int, int], dict[str, float]] = {}
        for c in self.param_changes:
            if c.get("ok"):
                written.setdefault((c["link_id"], c["sysid"]), {})[c["name"]] = c["value"]
        own = [
            (ap, {**params, **written.get(vid, {})})
            for vid, (ap, params) in sorted(vehicles.items())
        ]
        rot.use_landing(
            [landing_descent(ap, p) for ap, p in own], [return_alt_m(ap, p) for ap, p in own]
        )

    # ------------------------------------------------------------------ masks

    def _rotation_may_fly(self, n: int) -> np.ndarray:
        """(n,) rows the station may launch, reclaim or keep in the air: all without a rotation;
        with one, the ``air`` and ``inbound`` ones (and rows beyond the policy's fleet)."""
        rot = self.rotation
        ok = np.ones(n, dtype=bool)
        if rot is None:
            return ok
        m = min(n, rot.policy.n_drones)
        ph = rot.policy.phase[:m]
        ok[:m] = (ph == AIR) | (ph == INBOUND)
        return ok

    # ------------------------------------------------------------------ events

    def _rotation_on_mode(self, event: ModeChanged, key: tuple[int, int]) -> None:
        """The firmware's own RTL / LAND / Hold (any of its failsafe modes) on a low battery: the
        policy is told (failsafe), and the vehicle is sent home, not reclaimed."""
        rot = self.rotation
        if rot is None or self._phase != Phase.RUN or key in self.released:
            return
        i = self.fleet.index_of(*key)
        if i >= rot.policy.n_drones or rot.policy.phase[i] not in (AIR, INBOUND):
            return
        snap = self.fleet.snapshot(event.t_s)
        adapter = adapter_for(int(snap.autopilot[i]))
        # Any failsafe mode, not only RTL and LAND: ArduCopter's BATT_FS_LOW_ACT 3 flies SMART_RTL
        # (the audit accepts it), and PX4 begins its battery failsafe with a Hold (AUTO.LOITER for
        # COM_FAIL_ACT_T, failsafe.cpp) before it returns. Taken back into the plan from either,
        # a drone on a failing battery was flown on: the station reclaimed PX4 SIH vehicles from
        # their critical-battery Hold four times (docs/results/endurance.md).
        if event.mode not in (adapter.rtl_mode, adapter.land_mode, *adapter.failsafe_modes):
            return
        batt = float(snap.battery_frac[i]) if snap.battery_frac is not None else math.nan
        state = int(snap.battery_charge_state[i]) if snap.battery_charge_state is not None else 0
        low = rot.policy.params.critical_frac + rot.failsafe_margin_frac
        # MAV_BATTERY_CHARGE_STATE 2 LOW .. 4 EMERGENCY: the autopilot says so itself.
        if (math.isfinite(batt) and batt <= low) or 2 <= state <= 4:
            rot.counters["battery_failsafes"] += 1
            rot.events.append(rot.policy.failsafe(i, event.t_s))
            log.warning(
                "link %d sysid %d: battery failsafe %s at %.0f %%", *key, event.mode, 100 * batt
            )

    def _rotation_on_home(self, event: HomePositionReceived, key: tuple[int, int]) -> None:
        """The vehicle's pad from its HOME_POSITION (where RTL lands it), first heard before
        the launch: a relay sent home is never heard disarmed in the RUN before the crew pulls
        its pack, so without this its pad would be the base's centre, tens of metres off, and the
        silent vehicle down on its own pad would be lost to the rotation for good."""
        rot = self.rotation
        if rot is None:
            return
        nd = rot.policy.n_drones
        i = self.fleet.index_of(*key)
        if i >= nd:
            return
        if rot.home_ne_m.shape != (nd, 2):
            rot.home_ne_m = np.full((nd, 2), np.nan)
        if not np.isnan(rot.home_ne_m[i, 0]):
            return
        o = self.fleet.origin
        ned = geodetic_to_ned_m(
            event.lat_deg, event.lon_deg, event.alt_amsl_m, o.lat_deg, o.lon_deg, o.alt_amsl_m
        )
        rot.home_ne_m[i] = np.asarray(ned, float).reshape(-1)[:2]

    def _rotation_on_reboot(self, event: VehicleRebooted, key: tuple[int, int]) -> None:
        """A power-cycled vehicle is the same vehicle: its launch bookkeeping starts over."""
        if self.rotation is None:
            return
        rot = self.rotation
        rot.counters["reboots"] += 1
        i = self.fleet.index_of(*key)
        self._rows[i] = _Row()
        # The crew's swap (docs/design/endurance.md §6.4), to confirm: not a spare's reboot
        # (READY: its swap was confirmed already, from the new boot's full charge reported
        # before the reboot was noticed; kept, the mark would confirm its next swap unseen).
        if i < rot.policy.n_drones and rot.policy.phase[i] in (
            RETURNING,
            LANDED,
            SWAPPING,
            NO_BATTERY,
        ):
            rot.rebooted_home.add(i)

    # ------------------------------------------------------------------ the tick

    def _rotation_step(self, snap: FleetSnapshot, alt_m: np.ndarray, now_s: float) -> np.ndarray:
        """Run the policy on the station's telemetry; returns (N,) the rows it plans."""
        rot = self.rotation
        assert rot is not None  # only called with a rotation
        pol = rot.policy
        n, m = snap.n_vehicles, min(snap.n_vehicles, pol.n_drones)
        nd = pol.n_drones
        base = np.asarray(rot.base_ne_m, dtype=float)
        pos = np.tile(base, (nd, 1))
        has = snap.has_position[:m]
        pos[:m][has] = snap.pos_ned_m[:m, :2][has]
        dist = np.hypot(*(pos - base).T)
        ph = pol.phase
        heard = np.zeros(nd, bool)
        heard[:m] = ~snap.lost[:m]
        armed = np.zeros(nd, bool)
        armed[:m] = snap.armed[:m]
        # Each vehicle's pad: where it was first heard on the ground (its home, where RTL brings
        # it back and the crew swaps it), which may be tens of metres from the base's centre.
        if rot.home_ne_m.shape != (nd, 2):
            rot.home_ne_m = np.full((nd, 2), np.nan)
        seen = np.zeros(nd, bool)
        seen[:m] = has & heard[:m] & ~armed[:m]
        new = seen & np.isnan(rot.home_ne_m[:, 0])
        rot.home_ne_m[new] = pos[new]
        home = np.where(np.isnan(rot.home_ne_m), base, rot.home_ne_m)
        dist_home = np.hypot(*(pos - home).T)
        recent = np.zeros(nd, bool)
        recent[:m] = now_s - snap.last_heard_s[:m] <= rot.lost_after_s
        batt = np.full(nd, np.nan)
        if snap.battery_frac is not None:
            batt[:m] = snap.battery_frac[:m]
        # A lost vehicle heard again on its pad, disarmed and full, is the same vehicle back
        # (powered up again, its pack charged): a spare (docs/design/endurance.md §7).
        back = (ph == LOST) & heard & recent & ~armed & (dist_home <= rot.land_radius_m)
        back &= batt >= rot.full_frac
        # A vehicle discovered after the pre-flight audit is no vehicle of the rotation until it
        # passed its own (gcs/operations/late_audit.py): lost to the policy, which counts on it
        # for nothing; once cleared, heard on its pad and charged, it is a spare (back).
        audited = np.ones(nd, bool)
        audited[:m] = self._audit_gate(snap)[:m]
        back &= audited
        for i in np.flatnonzero(back).tolist():
            rot.gone.discard(i)
            rot.landed_s.pop(i, None)
            rot.landed_frac.pop(i, None)
            rot.rebooted_home.discard(i)
            rot.events.append(pol.recovered(i, now_s))
            log.info("row %d heard again on its pad, charged: a spare again", i)
        on_ground = np.isin(ph, _GROUND)
        alive = np.zeros(nd, bool)
        # On the ground at the base a vehicle may be silent: its battery is out for a swap. So may
        # a returning one last heard down at the base: the crew may pull the pack in the very
        # moment it disarms, before a heartbeat says so (the emulator's crew does).
        low = np.ones(nd, bool)
        low[:m] = ~(np.nan_to_num(alt_m[:m], nan=0.0) > self.config.airborne_alt_m)
        down_home = (ph == RETURNING) & (dist_home <= rot.land_radius_m) & low
        alive[:m] = recent[:m] | on_ground[:m] | down_home[:m]
        alive &= audited
        # Landed away from the base (a critical-battery LAND in the field): gone for the mission.
        away = heard & ~armed & (dist_home > rot.land_radius_m)
        away &= np.isin(ph, (AIR, INBOUND, RETURNING))
        for i in np.flatnonzero(away & self._was_flying(nd)).tolist():
            if i not in rot.gone:
                rot.gone.add(i)
                rot.counters["landed_away"] += 1
                log.warning(
                    "row %d landed %.0f m from its pad: lost to the mission", i, dist_home[i]
                )
        if rot.gone:
            alive[list(rot.gone)] = False
        est = np.zeros(nd)
        if snap.drain_per_s is not None:
            est[:m] = np.nan_to_num(snap.drain_per_s[:m], nan=0.0)
        drain = np.maximum(est, rot.hover_drain_per_s)
        networked = np.zeros(nd, bool)
        networked[:m] = snap.networked[:m]
        landed = heard & ~armed & (dist_home <= rot.land_radius_m)
        for i in np.flatnonzero(landed & (ph == RETURNING)).tolist():
            rot.landed_s[i] = now_s
            rot.landed_frac[i] = float(batt[i])
        rebooted = np.full(nd, -np.inf)
        if snap.rebooted_s is not None:
            rebooted[:m] = snap.rebooted_s[:m]
        landed_at = np.array([rot.landed_s.get(i, np.inf) for i in range(nd)])
        landed_frac = np.array([rot.landed_frac.get(i, np.nan) for i in range(nd)])
        full = batt >= rot.full_frac
        rose = full & ~(landed_frac >= rot.full_frac)  # NaN (unknown at landing) counts as rose
        # A reboot since it was sent home is the crew's swap, whether the station heard it land
        # before (rebooted > landed_at) or only after it (powered off before the disarm was heard).
        booted_home = np.zeros(nd, bool)
        booted_home[list(rot.rebooted_home)] = True
        swap_done = np.zeros(nd, bool)
        if rot.swap_confirm == "auto":
            swap_done = (ph == SWAPPING) & full & ((rebooted > landed_at) | rose | booted_home)
        # The ground crew's confirmation (docs/design/endurance.md §8): ready once the vehicle is
        # heard again without a low battery (not the pack that came home in it).
        crew = np.zeros(nd, bool)
        crew[[i for i in rot.confirmed_s if i < nd]] = True
        crew &= (ph == SWAPPING) & heard & ~(np.isfinite(batt) & (batt < rot.full_frac))
        swap_done |= crew
        ret_drain = np.full(nd, rot.hover_drain_per_s * rot.return_drain_factor)
        out = pol.step(
            now_s,
            pos,
            alive,
            batt,
            drain,
            networked=networked,
            landed_at_base=landed,
            base_m=base,
            swap_done=swap_done,
            return_drain_per_s=ret_drain,
            end_s=(
                math.inf
                if self.mission_t0_s is None
                else self.mission_t0_s + self.config.duration_s
            ),
        )
        for i in np.flatnonzero(out.battery_swapped).tolist():
            rot.rebooted_home.discard(i)
            if i in rot.confirmed_s:
                rot.counters["swaps_confirmed_by_crew"] += 1
        for i in [i for i in rot.confirmed_s if pol.phase[i] != SWAPPING]:
            del rot.confirmed_s[i]  # done, or lost on the pad
        rot.events.extend(out.events)
        for ev in out.events:
            log.info("rotation t=%.0f s: %s row %d (%d)", ev.t_s, ev.kind, ev.drone, ev.other)
        rot.time_to_reserve_s = time_to_reserve_s(batt, drain, dist, pol.params, ret_drain)
        rot.tick_s = now_s
        flying = heard & armed & (np.isin(pol.phase, (AIR, INBOUND, RETURNING)))
        if flying.any() and np.isfinite(batt[flying]).any():
            rot.min_battery_in_air = min(rot.min_battery_in_air, float(np.nanmin(batt[flying])))
        self._rotation_command(snap, out.target_m, alt_m, now_s)
        planned = np.ones(n, dtype=bool)
        planned[:m] = out.planned[:m]
        return planned

    def _was_flying(self, nd: int) -> np.ndarray:
        flew = np.zeros(nd, bool)
        for i in range(nd):
            row = self._rows.get(i)
            flew[i] = row is not None and (row.flew or row.launched)
        return flew

    def _rotation_command(
        self, snap: FleetSnapshot, target_m: np.ndarray, alt_m: np.ndarray, now_s: float
    ) -> None:
        """Targets for inbound spares in the air; home for returning vehicles."""
        rot = self.rotation
        assert rot is not None
        ph = rot.policy.phase
        m = min(snap.n_vehicles, rot.policy.n_drones)
        airborne = (
            ~snap.lost[:m]
            & snap.armed[:m]
            & np.isfinite(alt_m[:m])
            & (alt_m[:m] > self.config.airborne_alt_m)
        )
        inbound = np.flatnonzero((ph[:m] == INBOUND) & airborne & np.isfinite(target_m[:m, 0]))
        inbound = np.array([i for i in inbound.tolist() if self._vid(snap, i) not in self.released])
        if len(inbound):
            self._send_layer_targets(snap, inbound, target_m[inbound], now_s)
        for i in np.flatnonzero((ph[:m] == RETURNING) & ~snap.lost[:m] & snap.armed[:m]).tolist():
            vid = self._vid(snap, i)
            if vid in self.released:
                continue
            adapter = adapter_for(int(snap.autopilot[i]))
            mode = snap.mode[i]
            if mode in (adapter.rtl_mode, adapter.land_mode, *adapter.home_modes):
                continue  # on its way down or home (its own failsafe, or our command)
            if now_s - rot.home_cmd_s.get(i, -math.inf) < self.config.action_retry_s:
                continue
            try:
                if self.config.end == "rtl":
                    # Over terrain RTL's straight line at one altitude may run into a hill
                    # between the post and home: climb over the highest ground first, as at the
                    # mission's end (gcs/operations/end.py _climb_before_rtl).
                    if self._climb_before_rtl(snap, i, now_s):
                        rot.home_cmd_s[i] = now_s
                        continue
                    self.station.clear_position_target(vid, now_s)
                    self.station.rtl(vid, now_s)
                    rot.home_cmd_s[i] = now_s
                else:
                    pad = rot.home_ne_m[i] if i < len(rot.home_ne_m) else np.full(2, np.nan)
                    pad = np.where(np.isnan(pad), np.asarray(rot.base_ne_m, float), pad)
                    d = float(np.hypot(*(snap.pos_ned_m[i, :2] - pad)))
                    if d <= rot.land_radius_m / 3:
                        self.station.clear_position_target(vid, now_s)
                        self.station.land(vid, now_s)
                        rot.home_cmd_s[i] = now_s
                    else:
                        self._send_layer_targets(snap, np.array([i]), pad[None, :], now_s)
            except (LinkUsageError, UnknownVehicle, ValueError) as exc:
                log.info("link %d sysid %d: %s", *vid, exc)
        # A vehicle that left the plan is not reclaimed from the RTL it was sent on.
        for i in np.flatnonzero(np.isin(ph[:m], (RETURNING, LOST, *_GROUND))).tolist():
            row = self._rows.get(i)
            if row is not None:
                row.reclaiming = False

    def _rotation_confirm_swap(self, i: int, now_s: float) -> str:
        """The ground crew confirms the swap of row ``i`` (the operator action ``confirm_swap``);
        returns what was done, for the action's record."""
        rot = self.rotation
        if rot is None:
            return "not confirmed: this flight has no relay rotation"
        pol = rot.policy
        phase = PHASES[int(pol.phase[i])] if i < pol.n_drones else "not in the rotation"
        if i >= pol.n_drones or pol.phase[i] != SWAPPING:
            return f"not confirmed: no swap requested ({phase})"
        if i in rot.confirmed_s:
            return "already confirmed"
        rot.confirmed_s[i] = now_s
        rot.events.append(RotationEvent(now_s, "crew_confirmed", i))
        log.info("rotation t=%.0f s: the crew confirmed the swap of row %d", now_s, i)
        return "swap confirmed (ready once heard with a charged battery)"

    def _fleet_ids(self) -> list[str]:
        """``"LINK:SYSID"`` of each fleet row (the rotation's rows are the fleet's)."""
        f = self.fleet
        return [f"{l}:{s}" for l, s in zip(f.link_of_index.tolist(), f.sysid_of_index.tolist())]

    def rotation_state(self) -> dict[str, Any] | None:
        """The rotation as the operator's view draws it (:meth:`RotationSetup.state`; None
        without batteries)."""
        return None if self.rotation is None else self.rotation.state(self._fleet_ids())

    def rotation_events(self, start: int = 0) -> list[dict[str, Any]]:
        """The rotation's events from the ``start``-th on, the vehicles by id
        (:meth:`RotationSetup.event_dicts`; [] without batteries)."""
        if self.rotation is None:
            return []
        return self.rotation.event_dicts(start, self._fleet_ids())

    def rotation_summary(self) -> dict[str, Any] | None:
        """The rotation's counters (None without batteries)."""
        return None if self.rotation is None else self.rotation.summary()

"""The launch step: waves of take-off, the take-off grace, retries with back-off, pre-arm
refusals at a steady pace, and driving any vehicle back to "armed, airborne, guided" (reclaim in
flight, relaunch after a landing), in every phase after discovery.

A mixin of :class:`gcs.operations.Operator` (split out of one 950-line module along this seam:
everything that commands a vehicle into the air, with the COMMAND_ACK outcomes that pace it). It
holds no state of its own: the attributes are the operator's (``_rows``, ``_waves``, ``_wave``,
``counters``, ``reclaimed``..., set up in ``Operator.__init__``).
"""

from __future__ import annotations

import logging
import math

import numpy as np
import numpy.typing as npt

from gcs.autopilot import adapter_for
from gcs.control import layer_alt_m, terrain_targets
from gcs.events import CommandFailed, CommandTimedOut
from gcs.fleet import FleetSnapshot
from gcs.link import LinkUsageError, UnknownVehicle
from gcs.operations._state import OperatorState
from gcs.operations.config import _Row
from gcs.operations.phases import Trigger
from gcs.wire import mavlink

__all__ = ["LaunchStep"]

log = logging.getLogger(__name__)

#: COMMAND_ACK results of an arm command that mean "not ready yet" (retried at a steady pace).
_NOT_READY = (
    mavlink.MAV_RESULT_FAILED,
    mavlink.MAV_RESULT_TEMPORARILY_REJECTED,
    mavlink.MAV_RESULT_DENIED,
)


class LaunchStep(OperatorState):
    """Take-off, retries and reclaim of :class:`gcs.operations.Operator` (see the module
    docstring)."""

    # ------------------------------------------------------------------ events

    def _on_command_failed(
        self, event: CommandFailed | CommandTimedOut, key: tuple[int, int]
    ) -> None:
        """A command that failed or timed out: back off, or (an arm refused) retry steadily."""
        self.counters["command_failures"] += 1
        row = self._rows.get(self.fleet.index_of(*key)) if key in self._known else None
        refused_arm = (
            isinstance(event, CommandFailed)
            and event.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM
            and event.result in _NOT_READY
        )
        if row is not None:
            if refused_arm:
                # Not ready (EKF/GPS converging): ask again at a steady pace, no back-off
                # (ArduPilot GCS_Common.cpp handle_command_component_arm_disarm answers
                # MAV_RESULT_FAILED; PX4 Commander.cpp TEMPORARILY_REJECTED).
                row.not_ready_s = event.t_s
                row.refused_attempt = row.attempt
                if row.failed_attempt == row.attempt:  # its take-off failed first: uncount
                    row.failures = max(0, row.failures - 1)
                    row.failed_attempt = -1
                row.next_action_s = event.t_s + self.config.prearm_retry_s
            elif row.failed_attempt != row.attempt and row.refused_attempt != row.attempt:
                row.failed_attempt = row.attempt
                row.failures += 1
                # Back off: the next attempt waits action_retry_s x 2^(failures-1), capped.
                backoff = min(
                    self.config.action_retry_s * 2 ** (row.failures - 1), self.config.max_backoff_s
                )
                row.next_action_s = max(row.next_action_s, event.t_s + backoff)
            row.takeoff_s = -math.inf  # the take-off is not under way: the back-off rules
        log.info(
            "link %d sysid %d: command %d %s",
            event.link_id,
            event.sysid,
            event.command,
            type(event).__name__,
        )

    # ------------------------------------------------------------------ the launch phase

    def not_ready(self, snap: FleetSnapshot, now_s: float) -> list[tuple[int, int]]:
        """Heard, unarmed vehicles that refused to arm recently (still converging)."""
        out = []
        for i in range(snap.n_vehicles):
            row = self._rows.get(i)
            if row is None or snap.lost[i] or snap.armed[i]:
                continue
            if now_s - row.not_ready_s <= 2 * self.config.prearm_retry_s + 2.0:
                out.append(self._vid(snap, i))
        return out

    def _start_launch(self, snap: FleetSnapshot, now_s: float, trigger: Trigger) -> None:
        """Enter the launch (``trigger``: from discovery or from the audit); waves of
        ``wave_size`` rows in discovery order."""
        self._enter(trigger, now_s)
        self._launch_since_s = now_s
        # A vehicle the fleet audit did not cover waits for its own (gcs.operations.late_audit)
        # and is launched by the run's reclaim once cleared.
        rows = np.flatnonzero(self._audit_gate(snap)).tolist()
        k = self.config.wave_size
        self._waves = [rows[j : j + k] for j in range(0, len(rows), k)]
        self._wave = 0
        self._wave_since_s = now_s

    def _height_m(self, snap: FleetSnapshot) -> np.ndarray:
        """(N,) each vehicle's height, metres: above its home on a flat earth; over terrain,
        above the DEM's ground under it. A vehicle flying in a canyon below its home on the rim
        is airborne (docs/terrain.md §6.2); read above home, it was not, and was sent TAKEOFF."""
        # Mission NED down is relative to the mission origin's altitude; home AMSL per vehicle.
        alt_amsl = self.fleet.origin.alt_amsl_m - snap.pos_ned_m[:, 2]
        ta = self.control.terrain
        if ta is None:
            return alt_amsl - snap.home_amsl_m
        ne = np.nan_to_num(snap.pos_ned_m[:, :2])
        return alt_amsl - ta.terrain.height_m(ne)

    def _poll_launch(self, snap: FleetSnapshot, now_s: float) -> None:
        """Start the next wave when most of this one is airborne (or at ``wave_timeout_s``),
        drive every started wave's vehicles, and start the run once most have climbed."""
        cfg = self.config
        alt = self._height_m(snap)
        heard = ~snap.lost
        fin = np.isfinite(alt)
        airborne = heard & snap.armed & fin & (alt > cfg.airborne_alt_m)
        # With a rotation, only the planned K take off; the spares wait on the ground.
        may_fly = self._rotation_may_fly(snap.n_vehicles)
        if self._wave < len(self._waves):
            wave = [i for i in self._waves[self._wave] if i < snap.n_vehicles and may_fly[i]]
            live = int(heard[wave].sum()) if wave else 0
            up = int(airborne[wave].sum()) if wave else 0
            if (
                up >= cfg.wave_airborne_frac * max(1, live)
                or now_s - self._wave_since_s >= cfg.wave_timeout_s
            ):
                log.info(
                    "wave %d/%d: %d/%d airborne at t=%.1f s",
                    self._wave + 1,
                    len(self._waves),
                    up,
                    len(wave),
                    now_s,
                )
                self._wave += 1
                self._wave_since_s = now_s
        # Every started wave (and late discoveries): launch / keep flying.
        in_plan = self._in_plan(snap)
        for w in self._waves[: self._wave + 1]:
            for i in w:
                if i < snap.n_vehicles and heard[i] and in_plan[i] and may_fly[i]:
                    self._drive(snap, i, alt, now_s)
        if self._wave >= len(self._waves):
            # The climb of the vehicles the launch started: one discovered since (audited on its
            # own, gcs.operations.late_audit) is launched by the run's reclaim, not waited for.
            waved = np.zeros(snap.n_vehicles, dtype=bool)
            waved[[i for w in self._waves for i in w if i < snap.n_vehicles]] = True
            rows = np.flatnonzero(heard & may_fly & waved)
            target = layer_alt_m(rows, self.control)
            climbed = fin[rows] & (
                np.where(fin[rows], alt[rows], 0.0) >= cfg.climbed_alt_frac * target
            )
            waiting = self.not_ready(snap, now_s)
            in_time = now_s - self._launch_since_s < cfg.launch_timeout_s
            if waiting and in_time:
                # Vehicles still refusing to arm (SITL: EKF/GPS ~40 s after boot): the climb
                # timeout counts from when the last of them was still not ready.
                self._wave_since_s = now_s
            elif waiting and not self._launch_gave_up:
                self._launch_gave_up = True
                log.warning(
                    "launch: %d vehicle(s) still not ready to arm after %.0f s: %s",
                    len(waiting),
                    cfg.launch_timeout_s,
                    "; ".join(
                        f"link {l} sysid {s}: {self.prearm.get((l, s), (0, '?'))[1]}"
                        for l, s in waiting
                    ),
                )
            if (
                climbed.sum() >= cfg.wave_climbed_frac * max(1, len(rows))
                or now_s - self._wave_since_s >= cfg.wave_timeout_s
            ):
                log.info(
                    "launch complete at t=%.1f s: %d/%d climbed",
                    now_s,
                    int(climbed.sum()),
                    len(rows),
                )
                self._start_run(now_s)

    def _start_run(self, now_s: float) -> None:
        self._enter(Trigger.LAUNCHED, now_s)
        self.mission_t0_s = now_s
        self._next_tick_s = now_s
        self._t_step = 0

    def _drive(
        self,
        snap: FleetSnapshot,
        i: int,
        alt: np.ndarray,
        now_s: float,
        hold_position: bool = False,
    ) -> bool:
        """Bring vehicle ``i`` to "armed, airborne, guided"; returns True if it already is."""
        row = self._rows.setdefault(i, _Row())
        adapter = adapter_for(int(snap.autopilot[i]))
        guided = adapter.is_guided(int(snap.custom_mode[i]))
        armed = bool(snap.armed[i])
        airborne = bool(np.isfinite(alt[i]) and alt[i] > self.config.airborne_alt_m and armed)
        if airborne:
            row.flew = True
        if guided and airborne:
            row.failures = 0
            row.not_ready_s = -math.inf
            if row.reclaiming:
                row.reclaiming = False
                row.reclaims += 1
                self.reclaimed.append((now_s, *self._vid(snap, i)))
                log.info("reclaimed link %d sysid %d", *self._vid(snap, i))
            return True
        if armed and row.armed_seen_s < row.takeoff_s:
            row.armed_seen_s = now_s
        if now_s < row.next_action_s:
            return False
        # Taking off: leave it alone (no second GUIDED/OFFBOARD, arm or take-off) for
        # takeoff_grace_s after the command, and again after it was first seen armed (PX4 arms
        # only after more than a second of setpoint streaming, then ramps the climb up over
        # MPC_TKO_RAMP_T: its 2 m can take longer than the grace counted from the command).
        if not airborne and (
            now_s - row.takeoff_s < self.config.takeoff_grace_s
            or (
                armed
                and guided
                and row.armed_seen_s >= row.takeoff_s
                and now_s - row.armed_seen_s < self.config.takeoff_grace_s
            )
        ):
            return False
        vid = self._vid(snap, i)
        target_alt = float(layer_alt_m([i], self.control)[0])
        row.next_action_s = now_s + self.config.action_retry_s
        row.attempt += 1
        try:
            if airborne:
                # Reclaim in flight: hold where it is (at its layer), then the guided mode.
                if snap.has_position[i]:
                    self._hold(snap, [i], now_s)
                self.station.engage_guided(vid, now_s)
                self.counters["reclaim_attempts"] += 1
                row.reclaiming = True
                log.info("reclaiming link %d sysid %d from %s", *vid, snap.mode[i])
                return False
            climb = (
                armed
                and guided
                and not adapter.takeoff_by_offboard_climb
                and row.launched
                and not row.climb_sent
                and bool(snap.has_position[i])
                and bool(np.isfinite(alt[i]))
                and float(alt[i]) > self.config.liftoff_alt_m
            )
            row.climb_sent = climb
            if climb:
                # Off the ground but short of airborne (a take-off stopped short): ArduCopter
                # refuses a second NAV_TAKEOFF here ("can't takeoff again", Mode::do_user_takeoff
                # in ArduCopter/mode.cpp: MAV_RESULT_FAILED while !land_complete), so a retried
                # take-off would fail forever. A position target at its layer climbs it instead
                # (GUIDED flies position targets in the air).
                self._hold(snap, [i], now_s)
                self.counters["takeoff_climbs"] += 1
                log.info(
                    "link %d sysid %d: off the ground at %.1f m, climbing by position target",
                    *vid,
                    float(alt[i]),
                )
                return False
            if row.flew:
                self.counters["relaunches"] += 1  # it flew, landed (e.g. RTL) and goes again
                row.flew = False
            row.launched = True
            row.takeoff_s = now_s
            if adapter.takeoff_by_offboard_climb:
                if not snap.has_position[i]:
                    return False
                self.station.takeoff(vid, target_alt, now_s)  # stream, OFFBOARD, arm (PX4)
            else:
                if not guided:
                    self.station.engage_guided(vid, now_s)
                if not armed:
                    self.station.arm(vid, now_s)
                self.station.takeoff(vid, target_alt, now_s)
        except (LinkUsageError, UnknownVehicle) as exc:
            log.info("link %d sysid %d: %s", *vid, exc)
        except ValueError as exc:  # e.g. unknown autopilot: nothing we can command
            log.warning("link %d sysid %d: %s", *vid, exc)
        return False

    def _hold(self, snap: FleetSnapshot, rows: npt.ArrayLike, now_s: float) -> None:
        rows = np.asarray(rows, dtype=int)
        self._send_layer_targets(snap, rows, snap.pos_ned_m[rows, :2], now_s)

    def _send_layer_targets(
        self, snap: FleetSnapshot, rows: np.ndarray, target_ne_m: np.ndarray, now_s: float
    ) -> int:
        """Send vehicles ``rows`` to ``target_ne_m`` (K, 2) at their layer's altitude: above home
        on a flat earth; over terrain, above the ground under the target with the whole path
        clear of the ground (:func:`gcs.control.terrain_targets`). Every target the station sends
        outside the planner's tick (holds, the rotation's spares and returns) goes through here."""
        layer = layer_alt_m(rows, self.control)
        if self.control.terrain is not None:
            target = terrain_targets(snap.pos_ned_m[rows], target_ne_m, layer, self.control.terrain)
        else:
            target = np.column_stack([target_ne_m, -layer])
        return self._send_targets(snap, rows, target, now_s)

    def _send_targets(
        self, snap: FleetSnapshot, rows: np.ndarray, target_ned_m: np.ndarray, now_s: float
    ) -> int:
        if len(rows) == 0:
            return 0
        lat, lon, alt_rel = self.fleet.targets_to_global(rows, target_ned_m)
        sent = 0
        for k, i in enumerate(rows.tolist()):  # the codec edge: one frame per vehicle
            if not math.isfinite(alt_rel[k]):
                continue
            self.station.set_position_target(
                self._vid(snap, i), float(lat[k]), float(lon[k]), float(alt_rel[k]), now_s
            )
            sent += 1
        return sent

    def _reclaim(self, snap: FleetSnapshot, now_s: float) -> None:
        """Drive every heard vehicle still in the plan to "armed, airborne, guided" (the run's
        reclaim and relaunch)."""
        alt = self._height_m(snap)
        # A row already armed, airborne, guided and settled is a no-op for _drive (it would
        # only set flew, failures and not_ready_s to what they are): skip it without the
        # per-row adapter calls (this runs on every poll, for every vehicle of the fleet).
        airborne = snap.armed & np.isfinite(alt) & (alt > self.config.airborne_alt_m)
        guided_name = {a: adapter_for(a).guided_mode for a in set(snap.autopilot.tolist())}
        autopilot, mode, get = snap.autopilot.tolist(), snap.mode, self._rows.get
        flying = airborne.tolist()
        never = -math.inf
        # The rows to drive, in order, found in one pass (_drive(i) changes row i alone, so
        # deciding every row first is deciding each just before its turn).
        todo = [
            i
            for i in np.flatnonzero(
                ~snap.lost & self._in_plan(snap) & self._rotation_may_fly(snap.n_vehicles)
            ).tolist()
            if not (
                flying[i]
                and (row := get(i)) is not None
                and (gm := guided_name[autopilot[i]])
                and mode[i] == gm
                and row.flew
                and not row.reclaiming
                and row.failures == 0
                and row.not_ready_s == never
            )
        ]
        for i in todo:
            self._drive(snap, i, alt, now_s)

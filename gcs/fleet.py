"""What the station believes about its fleet, folded from link events into arrays.

Positions are in the **mission's** local NED frame (one named geodetic origin), converted from
GLOBAL_POSITION_INT. LOCAL_POSITION_NED is never used here: each autopilot's local frame is
relative to its own EKF origin, which differs per vehicle (docs/design/mavlink.md §1.6).

Rows are stable: a vehicle keeps its row index for the whole run, lost or not
(docs/design/architecture.md §3.1); ``index`` (the row) and ``sysid`` (MAVLink id) are distinct, and
``(link_id, sysid)`` is the vehicle identity (sysids repeat across MAVLink networks).

State per vehicle at ``snapshot(now_s)``:

* **networked** - heard within ``timeout_s`` and not returning: the paper's D'(t), planned for;
* **lost** - silent for longer than ``timeout_s`` (or the link declared it lost);
* **returning** - heard again after being lost while in a failsafe mode (ArduPilot RTL/LAND,
  PX4 AUTO.RTL/POSCTL...): it must be reclaimed (switched back to GUIDED/OFFBOARD) before it
  rejoins the plan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from gcs.autopilot import adapter_for
from gcs.battery import QUANTUM_FRAC, DrainEstimator
from gcs.events import (
    ArmedChanged,
    BatteryReceived,
    EstimatorReceived,
    Event,
    GpsReceived,
    HomePositionReceived,
    ModeChanged,
    RadioStatusReceived,
    SensorsReceived,
    TelemetryReceived,
    VehicleDiscovered,
    VehicleLost,
    VehicleRebooted,
    VehicleRecovered,
)
from planner.geometry import geodetic_to_ned_m, ned_to_geodetic

__all__ = ["MissionOrigin", "FleetSnapshot", "FleetView", "HEALTH_COLUMNS", "MASK_COLUMNS"]

#: Columns of :attr:`FleetSnapshot.health`.
HEALTH_COLUMNS = ("gps_fix", "satellites", "hdop", "est_ratio", "rssi", "remrssi")
#: Columns of :attr:`FleetSnapshot.masks`.
MASK_COLUMNS = ("sensors_present", "sensors_enabled", "sensors_health", "est_flags", "est_source")
_EST_SOURCES = {"EKF_STATUS_REPORT": 1, "ESTIMATOR_STATUS": 2}


@dataclass(frozen=True)
class MissionOrigin:
    """The mission frame's origin (NED, metres, around this point)."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float

    def __post_init__(self) -> None:
        if not (
            -90 <= self.lat_deg <= 90
            and -180 <= self.lon_deg <= 180
            and math.isfinite(self.alt_amsl_m)
        ):
            raise ValueError(f"invalid mission origin {self}")


@dataclass(frozen=True)
class FleetSnapshot:
    """The fleet at one instant, struct of arrays; row i is the same vehicle in every array."""

    t_s: float
    link_id: np.ndarray
    """(N,) int: link of each row."""
    sysid_of_index: np.ndarray
    """(N,) int: MAVLink sysid of each row."""
    pos_ned_m: np.ndarray
    """(N, 3) float64: position in the mission NED frame, metres (NaN until the first fix)."""
    vel_ned_m_s: np.ndarray
    """(N, 3) float64: velocity NED, m/s (NaN until the first fix)."""
    has_position: np.ndarray
    """(N,) bool."""
    home_amsl_m: np.ndarray
    """(N,) float64: each vehicle's home altitude AMSL, metres: HOME_POSITION's once the vehicle
    sent one, else GLOBAL_POSITION_INT ``alt - relative_alt`` (NaN before either)."""
    last_heard_s: np.ndarray
    """(N,) float64: core time of the last event from the vehicle, seconds."""
    networked: np.ndarray
    """(N,) bool: heard within the timeout and not returning (D'(t))."""
    lost: np.ndarray
    """(N,) bool: silent."""
    returning: np.ndarray
    """(N,) bool: heard again after a loss, in a failsafe mode: to be reclaimed."""
    armed: np.ndarray
    """(N,) bool."""
    custom_mode: np.ndarray
    """(N,) int: HEARTBEAT.custom_mode."""
    autopilot: np.ndarray
    """(N,) int: HEARTBEAT.autopilot (3 ArduPilot, 12 PX4)."""
    mode: tuple[str, ...]
    """Mode names, per row."""
    home_reported: np.ndarray | None = None
    """(N,) bool: ``home_amsl_m`` is from HOME_POSITION (not the estimate)."""
    battery_frac: np.ndarray | None = None
    """(N,) float64: remaining charge, fraction (NaN: never reported). SYS_STATUS's, else
    BATTERY_STATUS's."""
    battery_voltage_v: np.ndarray | None = None
    battery_current_a: np.ndarray | None = None
    battery_consumed_mah: np.ndarray | None = None
    battery_time_remaining_s: np.ndarray | None = None
    """(N,) float64: the autopilot's own estimate (BATTERY_STATUS), NaN if not reported."""
    battery_charge_state: np.ndarray | None = None
    """(N,) int: MAV_BATTERY_CHARGE_STATE of the last BATTERY_STATUS (0: undefined / none)."""
    drain_per_s: np.ndarray | None = None
    """(N,) float64: drain estimated from the vehicle's own reports, fraction of capacity per
    second (:mod:`gcs.battery`; NaN until two level changes were seen)."""
    rebooted_s: np.ndarray | None = None
    """(N,) float64: core time of the vehicle's last reboot (-inf: none seen)."""
    health: np.ndarray | None = None
    """(N, 6) float64, what a pilot watches (gcs.link_health; NaN: never reported), columns
    :data:`HEALTH_COLUMNS`: GPS fix type, satellites, HDOP, the estimator's worst test ratio,
    RADIO_STATUS rssi and remrssi."""
    masks: np.ndarray | None = None
    """(N, 5) int64 (-1: never reported), columns :data:`MASK_COLUMNS`: SYS_STATUS sensors
    present / enabled / healthy, the estimator's flags, and which message sent them
    (1 EKF_STATUS_REPORT, 2 ESTIMATOR_STATUS)."""

    @property
    def n_vehicles(self) -> int:
        return len(self.sysid_of_index)


class FleetView:
    """Folds link events (:meth:`apply`) into per-vehicle rows; :meth:`snapshot` reads them."""

    def __init__(self, origin: MissionOrigin, *, timeout_s: float = 5.0) -> None:
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        self.origin = origin
        self.timeout_s = timeout_s
        self._index: dict[tuple[int, int], int] = {}
        self._link: list[int] = []
        self._sysid: list[int] = []
        self._custom_mode: list[int] = []
        self._autopilot: list[int] = []
        # Numeric rows in preallocated arrays (capacity doubles): a snapshot slices them
        # instead of converting lists of tuples (it runs on every poll of the operator).
        self._cap = 0
        self._geo = np.empty((0, 3))  # lat, lon, alt_amsl (NaN = none)
        self._vel = np.empty((0, 3))
        self._home_amsl = np.empty(0)
        self._home_reported = np.empty(0, dtype=bool)
        self._last_heard = np.empty(0)
        self._link_lost = np.empty(0, dtype=bool)
        self._was_lost = np.empty(0, dtype=bool)
        self._armed = np.empty(0, dtype=bool)
        # Batteries (docs/design/endurance.md §3): remaining, V, A, mAh used, time remaining,
        # charge state; the drain estimate's rate and last level change per row.
        self._batt = np.empty((0, 6))
        self._rate = np.empty(0)
        self._last_edge = np.empty(0)
        self._rebooted = np.empty(0)
        self._batt_t = np.empty(0)  # when the level (column 0) was last reported
        self._pos_t = np.empty(0)  # when the position was last reported
        self._health = np.empty((0, len(HEALTH_COLUMNS)))
        self._masks = np.empty((0, len(MASK_COLUMNS)), dtype=np.int64)
        self._drain_est: list[DrainEstimator] = []
        #: (autopilot, custom_mode) -> (mode name, failsafe mode?): a fleet shows few modes, and
        #: the adapters' answers depend on these two numbers alone.
        self._mode_info: dict[tuple[int, int], tuple[str, bool]] = {}
        # What snapshot() derives from rows that change rarely, kept between polls (the
        # operator polls ~16 times per vehicle second): the mission-NED position of each row,
        # converted again only for the rows whose geodetic position changed since (the
        # conversion is element-wise: a row's bits do not depend on which rows are converted
        # with it, tests/gcs/test_fleet.py), and the per-row mode facts, dropped whenever an
        # autopilot or custom_mode changes.
        self._pos = np.empty((0, 3))
        self._pos_stale: set[int] = set()
        self._pos_origin: MissionOrigin | None = None
        self._modes: tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ rows

    def __len__(self) -> int:
        return len(self._sysid)

    def register(self, link_id: int, sysid: int) -> int:
        """The row of vehicle ``(link_id, sysid)``, creating it if needed (rows never move)."""
        key = (link_id, sysid)
        idx = self._index.get(key)
        if idx is not None:
            return idx
        idx = self._index[key] = len(self._sysid)
        if idx >= self._cap:
            self._grow(max(16, 2 * self._cap))
        self._link.append(link_id)
        self._sysid.append(sysid)
        self._custom_mode.append(0)
        self._autopilot.append(0)
        self._modes = None
        self._geo[idx] = math.nan
        self._pos_stale.add(idx)
        self._vel[idx] = math.nan
        self._home_amsl[idx] = math.nan
        self._home_reported[idx] = False
        self._last_heard[idx] = -math.inf
        self._link_lost[idx] = False
        self._was_lost[idx] = False
        self._armed[idx] = False
        self._batt[idx] = math.nan
        self._batt[idx, 5] = 0
        self._rate[idx] = math.nan
        self._last_edge[idx] = math.nan
        self._rebooted[idx] = -math.inf
        self._batt_t[idx] = -math.inf
        self._pos_t[idx] = -math.inf
        self._health[idx] = math.nan
        self._masks[idx] = -1
        self._drain_est.append(DrainEstimator())
        return idx

    def _grow(self, cap: int) -> None:
        for name in (
            "_geo",
            "_pos",
            "_vel",
            "_home_amsl",
            "_home_reported",
            "_last_heard",
            "_link_lost",
            "_was_lost",
            "_armed",
            "_batt",
            "_rate",
            "_last_edge",
            "_rebooted",
            "_batt_t",
            "_pos_t",
            "_health",
            "_masks",
        ):
            old = getattr(self, name)
            new = np.empty((cap, *old.shape[1:]), dtype=old.dtype)
            new[: len(old)] = old
            setattr(self, name, new)
        self._cap = cap

    def index_of(self, link_id: int, sysid: int) -> int:
        try:
            return self._index[(link_id, sysid)]
        except KeyError:
            raise KeyError(f"no vehicle (link {link_id}, sysid {sysid}) in the fleet") from None

    @property
    def sysid_of_index(self) -> np.ndarray:
        return np.array(self._sysid, dtype=int)

    @property
    def link_of_index(self) -> np.ndarray:
        return np.array(self._link, dtype=int)

    # ------------------------------------------------------------------ events

    def apply(self, event: Event) -> None:
        """Fold one link event into the rows (events of other kinds are ignored)."""
        if not isinstance(event, Event):
            return  # link state (LinkUp / LinkDown): no vehicle row
        i = self.register(event.link_id, event.sysid)
        last = float(self._last_heard[i])
        if event.t_s - last > self.timeout_s and math.isfinite(last):
            self._was_lost[i] = True  # silent past the timeout, whatever the link said
        if isinstance(event, VehicleLost):
            self._link_lost[i] = True
            self._was_lost[i] = True
            return  # a loss is not hearing from it
        self._last_heard[i] = max(last, event.t_s)
        if isinstance(event, TelemetryReceived):
            self._geo[i] = (event.lat_deg, event.lon_deg, event.alt_amsl_m)
            self._pos_t[i] = event.t_s
            self._pos_stale.add(i)
            self._vel[i] = event.vel_ned_m_s
            if not self._home_reported[i]:
                # A stand-in until HOME_POSITION: on PX4 alt and relative_alt come from different
                # estimates (global position vs local z minus home z) and their difference moves
                # by 1-2.5 m in flight, which would move every altitude target with it.
                self._home_amsl[i] = event.alt_amsl_m - event.rel_alt_m
        elif isinstance(event, HomePositionReceived):
            self._home_amsl[i] = event.alt_amsl_m
            self._home_reported[i] = True
        elif isinstance(event, VehicleDiscovered):
            self._autopilot[i] = event.autopilot
            self._custom_mode[i] = event.custom_mode
            self._modes = None
            self._armed[i] = event.armed
            self._link_lost[i] = False
        elif isinstance(event, VehicleRecovered):
            self._link_lost[i] = False
            self._was_lost[i] = True
            self._custom_mode[i] = event.custom_mode
            self._modes = None
            self._settle(i)
        elif isinstance(event, ModeChanged):
            self._custom_mode[i] = event.custom_mode
            self._modes = None
            self._settle(i)
        elif isinstance(event, ArmedChanged):
            self._armed[i] = event.armed
        elif isinstance(event, BatteryReceived):
            self._apply_battery(i, event)
        elif isinstance(event, GpsReceived):
            h = self._health[i]
            h[0] = event.fix_type
            h[1] = math.nan if event.satellites is None else event.satellites
            h[2] = math.nan if event.hdop is None else event.hdop
        elif isinstance(event, SensorsReceived):
            self._masks[i, :3] = (event.present, event.enabled, event.health)
        elif isinstance(event, EstimatorReceived):
            self._masks[i, 3:] = (event.flags, _EST_SOURCES[event.source])
            self._health[i, 3] = math.nan if event.variance is None else event.variance
        elif isinstance(event, RadioStatusReceived):
            self._health[i, 4:] = [
                math.nan if x is None else x for x in (event.rssi, event.remrssi)
            ]
        elif isinstance(event, VehicleRebooted):
            # Power-cycled: a new battery (or none reported yet) and the same vehicle; what it
            # said before the reboot no longer describes it. The reboot is noticed at the first
            # position report of the new boot (this event comes just before it), which comes
            # after its first battery reports (an autopilot reports a position only once it has
            # one): a level reported since the boot (now_s - time_boot_s) and since the old
            # boot's last position is the new battery's and is kept. Cleared, a spare just
            # confirmed full by it had an unknown charge, due now, and was sent home at once.
            self._rebooted[i] = event.t_s
            booted_s = event.t_s - event.time_boot_s
            t_batt = self._batt_t[i]
            kept = t_batt >= booted_s and t_batt > self._pos_t[i]
            kept = kept and math.isfinite(self._batt[i, 0])
            level = float(self._batt[i, 0])
            self._batt[i] = math.nan
            self._batt[i, 5] = 0
            self._drain_est[i].reset()
            self._rate[i] = math.nan
            self._last_edge[i] = math.nan
            self._was_lost[i] = False
            if kept:
                self._batt[i, 0] = level
                self._drain_est[i].update(float(self._batt_t[i]), level)

    def _apply_battery(self, i: int, event: BatteryReceived) -> None:
        b = self._batt[i]
        frac = event.remaining_frac
        if frac is not None and (event.source == "SYS_STATUS" or math.isnan(b[0])):
            b[0] = frac
            self._batt_t[i] = event.t_s
            if event.source == "SYS_STATUS":  # one source of levels for the drain's edges
                est = self._drain_est[i]
                est.update(event.t_s, frac)
                self._rate[i] = est.rate_per_s
                self._last_edge[i] = est.last_edge_s
        for col, value in (
            (1, event.voltage_v),
            (2, event.current_a),
            (3, event.consumed_mah),
            (4, event.time_remaining_s),
        ):
            if value is not None:
                b[col] = value
        if event.source == "BATTERY_STATUS":
            b[5] = event.charge_state

    def _settle(self, i: int) -> None:
        # Heard and not in a failsafe mode: reclaimed (or never left); a normal member again.
        key = (self._autopilot[i], self._custom_mode[i])
        if not (self._mode_info.get(key) or self._new_mode_info(key))[1]:
            self._was_lost[i] = False

    # ------------------------------------------------------------------ reading

    def snapshot(self, now_s: float) -> FleetSnapshot:
        """The fleet as believed at ``now_s`` (vectorised geodetic -> mission NED)."""
        n = len(self._sysid)
        geo: np.ndarray = self._geo[:n]
        has_pos = np.isfinite(geo).all(axis=1)
        pos = self._positions(n, has_pos)
        last = self._last_heard[:n].copy()
        heard = (now_s - last <= self.timeout_s) & ~self._link_lost[:n]
        if self._modes is None:
            cache = self._mode_info
            infos = [
                cache.get(key) or self._new_mode_info(key)
                for key in zip(self._autopilot, self._custom_mode)
            ]
            self._modes = (
                tuple(name for name, _ in infos),
                np.fromiter((f for _, f in infos), dtype=bool, count=n),
                np.array(self._autopilot, dtype=int),
                np.array(self._custom_mode, dtype=np.int64),
            )
        modes, failsafe, autopilot, custom = self._modes
        returning = heard & self._was_lost[:n] & failsafe
        return FleetSnapshot(
            t_s=now_s,
            link_id=self.link_of_index,
            sysid_of_index=self.sysid_of_index,
            pos_ned_m=pos,
            vel_ned_m_s=self._vel[:n].copy(),
            has_position=has_pos,
            home_amsl_m=self._home_amsl[:n].copy(),
            last_heard_s=last,
            networked=heard & ~returning,
            lost=~heard,
            returning=returning,
            armed=self._armed[:n].copy(),
            custom_mode=custom.copy(),
            autopilot=autopilot.copy(),
            mode=modes,
            home_reported=self._home_reported[:n].copy(),
            battery_frac=self._batt[:n, 0].copy(),
            battery_voltage_v=self._batt[:n, 1].copy(),
            battery_current_a=self._batt[:n, 2].copy(),
            battery_consumed_mah=self._batt[:n, 3].copy(),
            battery_time_remaining_s=self._batt[:n, 4].copy(),
            battery_charge_state=self._batt[:n, 5].astype(int),
            drain_per_s=self._drain(n, now_s),
            rebooted_s=self._rebooted[:n].copy(),
            health=self._health[:n].copy(),
            masks=self._masks[:n].copy(),
        )

    def _drain(self, n: int, now_s: float) -> np.ndarray:
        """(n,) the drain estimates at ``now_s``: each row's edge slope, at most one
        quantization step over the time since its last level change (gcs.battery)."""
        rate, since = self._rate[:n], now_s - self._last_edge[:n]
        with np.errstate(invalid="ignore", divide="ignore"):
            held = (since > 0) & (since * rate > QUANTUM_FRAC)
            return np.where(held, QUANTUM_FRAC / np.where(held, since, 1.0), rate)

    def _positions(self, n: int, has_pos: np.ndarray) -> np.ndarray:
        """(n, 3) mission-NED positions (NaN without one): ``geodetic_to_ned_m`` of every row
        with a position, converting only the rows changed since the last call."""
        if self._pos_origin != self.origin:
            self._pos_origin = self.origin
            self._pos_stale.update(range(n))
        if self._pos_stale:
            rows = np.array(sorted(self._pos_stale), dtype=np.intp)
            self._pos_stale.clear()
            self._pos[rows] = np.nan
            rows = rows[has_pos[rows]]
            if len(rows):
                geo, o = self._geo, self.origin
                self._pos[rows] = geodetic_to_ned_m(
                    geo[rows, 0], geo[rows, 1], geo[rows, 2], o.lat_deg, o.lon_deg, o.alt_amsl_m
                )
        return self._pos[:n].copy()

    def _positions_reference(self, n: int) -> np.ndarray:
        """The slow, obviously-correct :meth:`_positions`: every row converted now."""
        geo: np.ndarray = self._geo[:n]
        has_pos = np.isfinite(geo).all(axis=1)
        pos = np.full((n, 3), np.nan)
        if has_pos.any():
            o = self.origin
            pos[has_pos] = geodetic_to_ned_m(
                geo[has_pos, 0],
                geo[has_pos, 1],
                geo[has_pos, 2],
                o.lat_deg,
                o.lon_deg,
                o.alt_amsl_m,
            )
        return pos

    def _new_mode_info(self, key: tuple[int, int]) -> tuple[str, bool]:
        adapter = adapter_for(key[0])
        info = self._mode_info[key] = (adapter.mode_name(key[1]), adapter.is_failsafe_mode(key[1]))
        return info

    def targets_to_global(
        self, indices: npt.ArrayLike, target_ned_m: npt.ArrayLike
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mission-NED targets to what SET_POSITION_TARGET_GLOBAL_INT (frame 6) wants.

        Parameters
        ----------
        indices : (K,) int - fleet rows the targets are for
        target_ned_m : (K, 3) float64 - targets in the mission NED frame, metres

        Returns
        -------
        lat_deg, lon_deg, alt_above_home_m : (K,) float64 each. The altitude is relative to
        *each vehicle's* home (AMSL target minus that vehicle's home AMSL); NaN where the
        vehicle's home is not known yet.
        """
        idx = np.asarray(indices, dtype=int)
        tgt = np.asarray(target_ned_m, dtype=float).reshape(len(idx), 3)
        o = self.origin
        lat, lon, alt_amsl = ned_to_geodetic(tgt, o.lat_deg, o.lon_deg, o.alt_amsl_m)
        home = self._home_amsl[: len(self)][idx] if len(idx) else np.empty(0)
        return (np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(alt_amsl - home))

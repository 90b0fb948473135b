"""Vectorised 3-D kinematics of N multicopters (one call per tick for all vehicles).

Model (deliberately simple, docs/design/architecture.md §6 struct-of-arrays):

* Each vehicle has a control kind: ``CTRL_POS`` (track ``target_pos_ned_m`` with a first-order
  P law plus optional velocity feed-forward), ``CTRL_VEL`` (track ``target_vel_ned_m_s``) or
  ``CTRL_LAND`` (hold north/east of ``target_pos_ned_m``, descend at ``land_speed_m_s``).
* The commanded velocity is saturated: horizontal norm <= ``max_speed_h_m_s``, climb <=
  ``climb_rate_m_s``, descent <= ``descent_rate_m_s``. The actual velocity follows it as a
  first-order lag (``tau_vel_s``) and is saturated again, so the limits hold at every instant.
* Ground: ``pos[:, DOWN] <= ground_down_m``. A vehicle on the ground that is not commanded to
  climb is ``landed`` and does not slide horizontally.
* Disarmed or dead vehicles do not move (a dead vehicle freezes where it died: the paper's
  attrition model only needs it to stop relaying).

Frames: all positions here are NED metres around the *world* origin (the base / swarm home).
Each vehicle core converts to its own EKF origin for LOCAL_NED on the wire.
"""

from __future__ import annotations

import numpy as np

from planner.geometry import DOWN, EAST, NORTH

from . import _kernels
from .battery import Battery, BatteryConfig

__all__ = ["Physics", "CTRL_POS", "CTRL_VEL", "CTRL_LAND"]

CTRL_POS, CTRL_VEL, CTRL_LAND = 0, 1, 2

#: Largest integration sub-step; bigger ``dt_s`` is split so that large virtual-clock jumps in
#: tests integrate the same trajectory as small real-time ticks.
MAX_SUBSTEP_S = 0.05
#: Height above ground below which a vehicle counts as on the ground.
GROUND_EPS_M = 0.05


class Physics:
    """State arrays and the vectorised step of N vehicles.

    Parameters
    ----------
    pos_ned_m : (N, 3) float64
        Initial positions (world NED, metres). The initial ``DOWN`` is taken as ground level.
    max_speed_h_m_s, climb_rate_m_s, descent_rate_m_s : float
        Default limits (per-vehicle arrays can be changed afterwards).
    tau_pos_s : float
        Time constant of the position loop (commanded speed = error / tau_pos_s).
    tau_vel_s : float
        Time constant of the velocity lag.
    """

    def __init__(
        self,
        pos_ned_m,
        max_speed_h_m_s: float = 10.0,
        climb_rate_m_s: float = 2.5,
        descent_rate_m_s: float = 1.5,
        tau_pos_s: float = 1.0,
        tau_vel_s: float = 0.3,
        origin_lla: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ):
        pos = np.array(pos_ned_m, dtype=float).reshape(-1, 3)
        self.origin_lla = tuple(float(v) for v in origin_lla)
        """World origin (lat_deg, lon_deg, alt_amsl_m): the base station / swarm home."""
        n = len(pos)
        self.n = n
        self.pos_ned_m = pos
        """(N, 3) float64 — positions, metres, world NED."""
        self.vel_ned_m_s = np.zeros((n, 3))
        """(N, 3) float64 — velocities, m/s, NED."""
        self.yaw_rad = np.zeros(n)
        """(N,) float64 — heading, rad, 0 = north, clockwise."""
        self.ground_down_m = pos[:, DOWN].copy()
        """(N,) float64 — ground level (DOWN coordinate) under each vehicle, metres."""
        self.target_pos_ned_m = pos.copy()
        self.target_vel_ned_m_s = np.zeros((n, 3))
        self.ctrl = np.full(n, CTRL_POS, dtype=np.int8)
        self.max_speed_h_m_s = np.full(n, float(max_speed_h_m_s))
        self.climb_rate_m_s = np.full(n, float(climb_rate_m_s))
        self.descent_rate_m_s = np.full(n, float(descent_rate_m_s))
        self.land_speed_m_s = np.full(n, 0.5)
        self.land_fast_m_s = np.full(n, float(descent_rate_m_s))
        """(N,) float64 — a landing's first stage, above ``land_slow_alt_m`` (ArduCopter
        LAND_SPEED_HIGH, else WPNAV_SPEED_DN; PX4 MPC_Z_V_AUTO_DN at most), m/s."""
        self.land_slow_alt_m = np.full(n, np.inf)
        """(N,) float64 — above this height over the ground a landing descends at
        ``land_fast_m_s`` (ArduCopter LAND_ALT_LOW, PX4 MPC_LAND_ALT1), metres; inf: the whole
        descent at ``land_speed_m_s``."""
        self.land_crawl_alt_m = np.full(n, np.inf)
        """(N,) float64 — below this height a landing descends at ``land_speed_m_s`` (PX4
        MPC_LAND_ALT2; ArduCopter: LAND_ALT_LOW too), linear in between, metres."""
        self.armed = np.zeros(n, dtype=bool)
        self.alive = np.ones(n, dtype=bool)
        self.landed = np.ones(n, dtype=bool)
        self.battery_frac = np.ones(n)
        self.battery_drain_per_s = 0.0
        self.battery: Battery | None = None
        """The packs' truth (vehicle_emu.battery), None: endless batteries (the default)."""
        self.tau_pos_s = float(tau_pos_s)
        self.tau_vel_s = float(tau_vel_s)
        self.lat_deg = np.zeros(n)
        self.lon_deg = np.zeros(n)
        self.alt_amsl_m = np.zeros(n)
        self.update_geodetic()

    def enable_battery(self, config: BatteryConfig) -> Battery:
        """Drain batteries from now on (:mod:`vehicle_emu.battery`); ``battery_frac`` follows
        the packs' state of charge."""
        self.battery = Battery(self.n, config)
        self.battery_frac = self.battery.soc
        return self.battery

    def update_geodetic(self) -> None:
        """Recompute ``lat_deg``, ``lon_deg``, ``alt_amsl_m`` (N,) for all vehicles (one call,
        :func:`vehicle_emu._kernels.ned_to_geodetic`)."""
        if self.n:
            self.lat_deg, self.lon_deg, self.alt_amsl_m = _kernels.ned_to_geodetic(
                self.pos_ned_m, *self.origin_lla
            )

    # -- commands (called by the vehicle cores; index = array row) -----------------------------

    def hold(self, i: int) -> None:
        """Brake and hold the current position (ArduPilot ``init(true)`` / PX4 Hold)."""
        self.ctrl[i] = CTRL_POS
        self.target_pos_ned_m[i] = self.pos_ned_m[i]
        self.target_vel_ned_m_s[i] = 0.0

    def command_position(self, i: int, pos_ned_m, ff_vel_ned_m_s=None) -> None:
        self.ctrl[i] = CTRL_POS
        self.target_pos_ned_m[i] = pos_ned_m
        self.target_vel_ned_m_s[i] = 0.0 if ff_vel_ned_m_s is None else ff_vel_ned_m_s

    def command_velocity(self, i: int, vel_ned_m_s) -> None:
        self.ctrl[i] = CTRL_VEL
        self.target_vel_ned_m_s[i] = vel_ned_m_s

    def command_land(self, i: int) -> None:
        self.ctrl[i] = CTRL_LAND
        self.target_pos_ned_m[i, :2] = self.pos_ned_m[i, :2]
        self.target_vel_ned_m_s[i] = 0.0

    # -- step ------------------------------------------------------------------------------------

    def step(self, dt_s: float) -> None:
        """Advance every vehicle by ``dt_s`` seconds (split into sub-steps): one compiled pass
        over the vehicles (:func:`vehicle_emu._kernels.physics_step`) when available, else
        :meth:`step_reference`."""
        if dt_s <= 0 or self.n == 0:
            return
        if not _kernels.active():
            self.step_reference(dt_s)
            return
        n_sub = max(1, int(np.ceil(dt_s / MAX_SUBSTEP_S)))
        h = dt_s / n_sub
        alpha = 1.0 - np.exp(-h / self.tau_vel_s)  # as _substep computes it (NumPy's exp)
        pos, vel, yaw, landed, consumed, energy, current, voltage = _kernels.physics_step(
            self, n_sub, h, float(alpha), CTRL_VEL, CTRL_LAND, GROUND_EPS_M
        )
        self.pos_ned_m, self.vel_ned_m_s, self.yaw_rad, self.landed = pos, vel, yaw, landed
        batt = self.battery
        if batt is not None:
            batt.consumed_mah, batt.energy_wh = consumed, energy
            batt.current_a, batt.voltage_v = current, voltage
            self.battery_frac = batt.soc
        else:
            self._drain_without_pack(dt_s)

    def step_reference(self, dt_s: float) -> None:
        """:meth:`step` by NumPy, one sub-step of every vehicle at a time (the reference)."""
        if dt_s <= 0 or self.n == 0:
            return
        n_sub = max(1, int(np.ceil(dt_s / MAX_SUBSTEP_S)))
        h = dt_s / n_sub
        batt = self.battery
        for _ in range(n_sub):
            self._substep(h)
            if batt is not None:
                batt.step(h, self.vel_ned_m_s, self.armed & self.alive)
        if batt is not None:
            self.battery_frac = batt.soc
        else:
            self._drain_without_pack(dt_s)

    def _drain_without_pack(self, dt_s: float) -> None:
        """Without a battery model, the flat ``battery_drain_per_s`` of the flying vehicles."""
        if self.battery_drain_per_s:
            drain = self.battery_drain_per_s * dt_s * (self.armed & self.alive)
            self.battery_frac = np.maximum(0.0, self.battery_frac - drain)

    def _commanded_velocity(self) -> np.ndarray:
        pos_err = self.target_pos_ned_m - self.pos_ned_m  # (N,3)
        v_cmd = pos_err / self.tau_pos_s + self.target_vel_ned_m_s  # CTRL_POS
        is_vel = self.ctrl == CTRL_VEL
        v_cmd[is_vel] = self.target_vel_ned_m_s[is_vel]
        is_land = self.ctrl == CTRL_LAND
        if is_land.any():
            v_cmd[is_land, DOWN] = self.land_descent_m_s()[is_land]
        return v_cmd

    def land_descent_m_s(self) -> np.ndarray:
        """(N,) the landing descent speed at each vehicle's height over the ground, m/s (down).

        Fast down to the slow-down height, then the landing speed: ArduCopter
        ``Mode::land_run_vertical_control`` (ArduCopter/mode.cpp) descends at WPNAV_SPEED_DN
        (LAND_SPEED_HIGH 0) until LAND_ALT_LOW, then at LAND_SPEED; PX4
        ``FlightTaskAuto::_prepareLandSetpoints`` (src/modules/flight_mode_manager/tasks/Auto/
        FlightTaskAuto.cpp) interpolates from the descent limit at MPC_LAND_ALT1 to
        MPC_LAND_SPEED at MPC_LAND_ALT2."""
        h = self.ground_down_m - self.pos_ned_m[:, DOWN]
        lo, hi = self.land_crawl_alt_m, self.land_slow_alt_m
        with np.errstate(invalid="ignore", divide="ignore"):
            ramp = np.where(h >= hi, 1.0, np.where(h <= lo, 0.0, (h - lo) / (hi - lo)))
        fast = np.maximum(self.land_fast_m_s, self.land_speed_m_s)
        return self.land_speed_m_s + ramp * (fast - self.land_speed_m_s)

    def _saturate_inplace(self, v: np.ndarray, descent_limit: np.ndarray) -> None:
        speed_h = np.hypot(v[:, NORTH], v[:, EAST])
        scale = np.minimum(1.0, self.max_speed_h_m_s / np.maximum(speed_h, 1e-12))
        v[:, NORTH] *= scale
        v[:, EAST] *= scale
        np.clip(v[:, DOWN], -self.climb_rate_m_s, descent_limit, out=v[:, DOWN])

    def _substep(self, h: float) -> None:
        moving = self.armed & self.alive
        v_cmd = self._commanded_velocity()
        is_land = self.ctrl == CTRL_LAND
        descent_limit = np.where(
            is_land, np.maximum(self.land_fast_m_s, self.land_speed_m_s), self.descent_rate_m_s
        )
        self._saturate_inplace(v_cmd, descent_limit)
        on_ground = self.pos_ned_m[:, DOWN] >= self.ground_down_m - GROUND_EPS_M
        # Landed vehicles do not slide: only a climb command gets them off the ground.
        stuck = on_ground & (v_cmd[:, DOWN] >= 0)
        v_cmd[stuck] = 0.0
        alpha = 1.0 - np.exp(-h / self.tau_vel_s)
        vel = self.vel_ned_m_s + (v_cmd - self.vel_ned_m_s) * alpha
        self._saturate_inplace(vel, descent_limit)
        vel[~moving] = 0.0
        pos = self.pos_ned_m + vel * h
        below = pos[:, DOWN] > self.ground_down_m
        pos[below, DOWN] = self.ground_down_m[below]
        vel[below, DOWN] = np.minimum(vel[below, DOWN], 0.0)
        # Disarmed in the air (forced disarm) drops to the ground: motors off.
        dropped = ~self.armed & self.alive & (pos[:, DOWN] < self.ground_down_m)
        pos[dropped, DOWN] = self.ground_down_m[dropped]
        self.pos_ned_m = pos
        self.vel_ned_m_s = vel
        self.landed = (pos[:, DOWN] >= self.ground_down_m - GROUND_EPS_M) & (
            (v_cmd[:, DOWN] >= 0) | ~moving
        )
        speed_h = np.hypot(vel[:, NORTH], vel[:, EAST])
        turning = speed_h > 0.5
        self.yaw_rad = np.where(turning, np.arctan2(vel[:, EAST], vel[:, NORTH]), self.yaw_rad)

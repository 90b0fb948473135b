"""The battery truth of N emulated multicopters (vectorised; docs/design/endurance.md §6).

Off unless a :class:`BatteryConfig` is given (``Physics.enable_battery``, ``Swarm(battery=...)``):
without one the emulator's batteries are endless, as they always were.

Model, per vehicle and per physics sub-step ``h`` (seconds):

* current, A: ``I = I_hover (1 + f (v_h / v_ref)^2 + c max(0, v_up) / climb_ref)`` while armed
  and alive, 0 disarmed (motors off, the autopilot's own draw is neglected). ``I_hover =
  capacity / hover_endurance`` is the mission's ``BatterySpec`` (``endurance_s``,
  ``speed_drain_frac``: mission.format.schema), plus a climb term (``climb_drain_factor`` at the
  reference climb rate; descending gives nothing back);
* consumed charge ``mAh += I h / 3.6``; consumed energy ``Wh += V I h / 3600``;
* state of charge ``soc = 1 - consumed / capacity`` (clipped to [0, 1]);
* terminal voltage ``V = cells OCV(soc) - I R``: a resting LiPo cell curve (:data:`LIPO_OCV_V`,
  piecewise linear) less the sag over the pack's internal resistance.

The firmware's view of this battery (what it reports, when its failsafes fire) is
:mod:`vehicle_emu.battery_monitor`. :func:`battery_step_reference` is the plain-loop reference of
:func:`battery_step` (docs/design/architecture.md §6).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planner.endurance import BaseResources
from planner.geometry import DOWN, EAST, NORTH

__all__ = [
    "BatteryConfig",
    "SwapConfig",
    "Battery",
    "battery_step",
    "battery_step_reference",
    "ocv_cell_v",
    "LIPO_OCV_SOC",
    "LIPO_OCV_V",
]

#: Resting (open-circuit) voltage of one LiPo cell against its state of charge: a typical
#: discharge curve (4.20 V full, the knee below 10 %), piecewise linear between these points.
LIPO_OCV_SOC = (0.0, 0.05, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70, 0.80, 0.90, 1.00)
LIPO_OCV_V = (3.27, 3.61, 3.69, 3.73, 3.77, 3.79, 3.82, 3.87, 3.92, 4.00, 4.08, 4.20)
_OCV_SOC = np.array(LIPO_OCV_SOC)
_OCV_V = np.array(LIPO_OCV_V)


@dataclass(frozen=True, kw_only=True)
class BatteryConfig:
    """One pack type for every vehicle. The defaults are ArduPilot SITL's copter pack (3S,
    ``BATT_CAPACITY`` 3300 mAh, libraries/AP_BattMonitor/AP_BattMonitor_Params.cpp) on the
    mission's default 25-minute hover endurance (mission.format.schema.BatterySpec)."""

    capacity_mah: float = 3300.0
    """Usable capacity, mAh."""
    cells: int = 3
    """Cells in series."""
    hover_endurance_s: float = 1500.0
    """Hover time on a full pack, seconds (BatterySpec.endurance_s)."""
    speed_drain_frac: float = 0.3
    """Extra drain at ``ref_speed_m_s``: ``(1 + f (v / v_ref)^2)`` (BatterySpec.speed_drain_frac)."""
    ref_speed_m_s: float = 10.0
    """Horizontal speed of the full speed term, m/s (the mission's max speed)."""
    climb_drain_factor: float = 0.5
    """Extra drain, as a fraction of hover, when climbing at ``ref_climb_m_s``."""
    ref_climb_m_s: float = 2.5
    """Climb rate of the full climb term, m/s."""
    internal_resistance_ohm: float = 0.015
    """Pack internal resistance, ohm (voltage sag = current x resistance)."""

    def __post_init__(self) -> None:
        for name in (
            "capacity_mah",
            "hover_endurance_s",
            "ref_speed_m_s",
            "ref_climb_m_s",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        for name in ("speed_drain_frac", "climb_drain_factor", "internal_resistance_ohm"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be >= 0, got {v!r}")
        if int(self.cells) != self.cells or not 1 <= self.cells <= 14:
            raise ValueError(f"cells must be an integer in 1..14, got {self.cells!r}")

    @property
    def hover_current_a(self) -> float:
        """Current at hover, A: capacity over hover endurance."""
        return self.capacity_mah * 3.6 / self.hover_endurance_s


def _default_swap_time_s() -> float:
    # One place for the default: the planner's base (docs/design/endurance.md §2).
    return float(BaseResources().swap_time_s)


@dataclass(frozen=True, kw_only=True)
class SwapConfig:
    """The ground crew at the base (docs/design/endurance.md §6.4): a vehicle landed and disarmed
    within ``home_radius_m`` of its home with a used pack (below ``used_below_frac``) is powered
    off, gets a full pack and boots again ``swap_time_s`` later."""

    swap_time_s: float = field(default_factory=_default_swap_time_s)
    """Power off to power on, seconds (mission ``endurance.base.swap_time_s``)."""
    home_radius_m: float = 3.0
    """How close to its home (horizontally) a vehicle must have landed to be swapped, m."""
    used_below_frac: float = 0.95
    """A pack at or above this state of charge is not swapped (a vehicle that never flew)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.swap_time_s) and self.swap_time_s > 0):
            raise ValueError(f"swap_time_s must be > 0, got {self.swap_time_s!r}")
        if not (math.isfinite(self.home_radius_m) and self.home_radius_m >= 0):
            raise ValueError(f"home_radius_m must be >= 0, got {self.home_radius_m!r}")
        if not 0.0 < self.used_below_frac <= 1.0:
            raise ValueError(f"used_below_frac must be in (0, 1], got {self.used_below_frac!r}")


def ocv_cell_v(soc):
    """Resting voltage of one cell (V) at state of charge ``soc`` (fraction, array or scalar)."""
    return np.interp(soc, _OCV_SOC, _OCV_V)


def battery_step(cfg: BatteryConfig, consumed_mah, energy_wh, vel_ned_m_s, drawing, h_s: float):
    """One sub-step of every pack (vectorised).

    Parameters
    ----------
    cfg : BatteryConfig
    consumed_mah, energy_wh : (N,) float64
        Charge (mAh) and energy (Wh) drawn so far.
    vel_ned_m_s : (N, 3) float64
        Velocity over the sub-step, m/s, NED.
    drawing : (N,) bool
        Armed and alive (motors running).
    h_s : float
        Sub-step, seconds.

    Returns
    -------
    current_a, consumed_mah, energy_wh, voltage_v : (N,) float64
        Current over the sub-step (A), the new totals, and the terminal voltage (V) at the end.
    """
    speed_h = np.hypot(vel_ned_m_s[:, NORTH], vel_ned_m_s[:, EAST])
    climb = np.maximum(0.0, -vel_ned_m_s[:, DOWN])
    factor = (
        1.0
        + cfg.speed_drain_frac * (speed_h / cfg.ref_speed_m_s) ** 2
        + cfg.climb_drain_factor * climb / cfg.ref_climb_m_s
    )
    current = np.where(drawing, cfg.hover_current_a * factor, 0.0)
    consumed = consumed_mah + current * h_s / 3.6
    soc = np.clip(1.0 - consumed / cfg.capacity_mah, 0.0, 1.0)
    voltage = cfg.cells * ocv_cell_v(soc) - current * cfg.internal_resistance_ohm
    energy = energy_wh + voltage * current * h_s / 3600.0
    return current, consumed, energy, voltage


def battery_step_reference(
    cfg: BatteryConfig, consumed_mah, energy_wh, vel_ned_m_s, drawing, h_s: float
):
    """:func:`battery_step` one vehicle at a time (the slow reference)."""
    n = len(consumed_mah)
    out = np.zeros((4, n))
    for i in range(n):
        vn, ve, vd = (float(c) for c in vel_ned_m_s[i])
        if drawing[i]:
            factor = (
                1.0
                + cfg.speed_drain_frac * (math.hypot(vn, ve) / cfg.ref_speed_m_s) ** 2
                + cfg.climb_drain_factor * max(0.0, -vd) / cfg.ref_climb_m_s
            )
            current = cfg.hover_current_a * factor
        else:
            current = 0.0
        consumed = float(consumed_mah[i]) + current * h_s / 3.6
        soc = min(1.0, max(0.0, 1.0 - consumed / cfg.capacity_mah))
        k = max(1, min(len(LIPO_OCV_SOC) - 1, int(np.searchsorted(_OCV_SOC, soc, side="right"))))
        s0, s1 = LIPO_OCV_SOC[k - 1], LIPO_OCV_SOC[k]
        v0, v1 = LIPO_OCV_V[k - 1], LIPO_OCV_V[k]
        ocv = v0 + (v1 - v0) * (soc - s0) / (s1 - s0)
        voltage = cfg.cells * ocv - current * cfg.internal_resistance_ohm
        energy = float(energy_wh[i]) + voltage * current * h_s / 3600.0
        out[:, i] = current, consumed, energy, voltage
    return out[0], out[1], out[2], out[3]


class Battery:
    """State arrays of N packs (one per physics row).

    Parameters
    ----------
    n : int
    config : BatteryConfig
    """

    def __init__(self, n: int, config: BatteryConfig) -> None:
        self.config = config
        self.n = int(n)
        self.consumed_mah = np.zeros(n)
        """(N,) charge drawn from the pack in the vehicle, mAh."""
        self.energy_wh = np.zeros(n)
        """(N,) energy drawn, Wh."""
        self.current_a = np.zeros(n)
        """(N,) current over the last sub-step, A."""
        self.voltage_v = np.full(n, config.cells * float(ocv_cell_v(1.0)))
        """(N,) terminal voltage, V."""

    @property
    def soc(self) -> np.ndarray:
        """(N,) true state of charge, fraction of capacity."""
        # np.clip without its Python-level wrapper (read several times a tick).
        return np.minimum(np.maximum(1.0 - self.consumed_mah / self.config.capacity_mah, 0.0), 1.0)

    def step(self, h_s: float, vel_ned_m_s: np.ndarray, drawing: np.ndarray) -> None:
        """Advance every pack by one sub-step (:func:`battery_step`)."""
        self.current_a, self.consumed_mah, self.energy_wh, self.voltage_v = battery_step(
            self.config, self.consumed_mah, self.energy_wh, vel_ned_m_s, drawing, h_s
        )

    def replace(self, i: int) -> None:
        """A full pack in vehicle ``i`` (the swap), at rest."""
        self.consumed_mah[i] = 0.0
        self.energy_wh[i] = 0.0
        self.current_a[i] = 0.0
        self.voltage_v[i] = self.config.cells * float(ocv_cell_v(1.0))

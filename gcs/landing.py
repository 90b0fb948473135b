"""The firmware's landing descent, from the vehicle's own parameters: how long a vehicle takes
from its flight layer to the ground of its pad, which the relay rotation counts in every relay's
reserve and in every spare's turnaround (``land_s``, docs/design/endurance.md §7).

Both firmwares land in two stages, fast down to a slow-down height, then at the landing speed:

* ArduCopter ``Mode::land_run_vertical_control`` (ArduCopter/mode.cpp), used by LAND and by the
  end of RTL: ``LAND_SPEED_HIGH`` (cm/s; 0: ``WPNAV_SPEED_DN``, the descent limit
  ``ModeLand::init`` gives the position controller; never slower than ``LAND_SPEED``) down to
  ``LAND_ALT_LOW`` (cm, at least 100), then ``LAND_SPEED`` (cm/s). The square-root controller
  that meets ``LAND_ALT_LOW`` rounds the corner off by about a second; not counted here.
* PX4 ``FlightTaskAuto::_prepareLandSetpoints`` (src/modules/flight_mode_manager/tasks/Auto/
  FlightTaskAuto.cpp): from ``MPC_Z_VEL_MAX_DN`` at ``MPC_LAND_ALT1`` (m; at least
  ``MPC_LAND_ALT2``, ``FlightTaskAuto::updateParams``) linearly down to ``MPC_LAND_SPEED`` at
  ``MPC_LAND_ALT2`` (m), the trajectory limited to ``MPC_Z_V_AUTO_DN`` in descent
  (``FlightTaskAuto::_updateTrajConstraints``).

The parameters are read by the pre-flight audit when the flight rotates relays
(:data:`LANDING_PARAMS`); a parameter the vehicle did not give counts at the firmware's default
(:data:`FIRMWARE_DEFAULTS`: ArduCopter/Parameters.cpp, libraries/AC_WPNav/AC_WPNav.cpp; PX4
src/modules/mc_pos_control/multicopter_autonomous_params.c and
multicopter_takeoff_land_params.c). The emulator
models the same descent on its side (vehicle_emu/physics.py ``Physics.land_descent_m_s``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from gcs.autopilot import ARDUPILOT, PX4

__all__ = [
    "FIRMWARE_DEFAULTS",
    "LANDING_ONLY_PARAMS",
    "LANDING_PARAMS",
    "LandingDescent",
    "RTL_ALT_DEFAULTS",
    "RTL_ALT_NAMES",
    "RTL_ALT_PARAMS",
    "landing_descent",
    "return_alt_m",
]

#: The parameters a vehicle lands by, per autopilot (read by the audit with a rotation).
LANDING_PARAMS: dict[int, tuple[str, ...]] = {
    ARDUPILOT: ("LAND_SPEED", "LAND_SPEED_HIGH", "LAND_ALT_LOW", "WPNAV_SPEED_DN"),
    PX4: (
        "MPC_LAND_SPEED",
        "MPC_LAND_ALT1",
        "MPC_LAND_ALT2",
        "MPC_Z_V_AUTO_DN",
        "MPC_Z_VEL_MAX_DN",
    ),
}

#: The ones read for the landing alone (not also as the mission's descent limit, gcs/limits.py):
#: optional reads (gcs/audit.py ``OPTIONAL_PARAMS``), not waited for: a firmware without one
#: (ArduPilot 4.7 renamed them LAND_SPD_MS, LAND_SPD_HIGH_MS, LAND_ALT_LOW_M) lands at its default
#: here, and its audit is not held up.
LANDING_ONLY_PARAMS: frozenset[str] = frozenset(
    n for names in LANDING_PARAMS.values() for n in names
) - {"WPNAV_SPEED_DN", "MPC_Z_VEL_MAX_DN"}

#: The firmware's defaults of :data:`LANDING_PARAMS`, in the firmware's units (ArduCopter cm/s and
#: cm, PX4 m/s and m).
FIRMWARE_DEFAULTS: dict[int, dict[str, float]] = {
    ARDUPILOT: {
        "LAND_SPEED": 50.0,
        "LAND_SPEED_HIGH": 0.0,
        "LAND_ALT_LOW": 1000.0,
        "WPNAV_SPEED_DN": 150.0,
    },
    PX4: {
        "MPC_LAND_SPEED": 0.7,
        "MPC_LAND_ALT1": 10.0,
        "MPC_LAND_ALT2": 5.0,
        "MPC_Z_V_AUTO_DN": 1.5,
        "MPC_Z_VEL_MAX_DN": 1.5,
    },
}


# The firmware's own return: a relay the rotation sends home by RTL climbs (never descends) to
# its return altitude above home, flies home there, and lands from it, so it lands from the
# higher of its flight layer and that altitude: ArduCopter mode_rtl.cpp ``ModeRTL::build_path``
# / ``compute_return_target`` (RTL_ALT, cm above home, the higher of it and the current
# altitude; RTL_ALT_TYPE 0, the default; RTL_ALT_FINAL 0 lands); PX4
# src/modules/navigator/rtl.cpp ``RTL::computeReturnAltitude`` (RTL_RETURN_ALT, m above home,
# never below the current altitude; the RTL_CONE_ANG cone lowers it only within RTL_MIN_DIST,
# 10 m, of home). Over terrain the audit raises it above the highest ground (gcs/audit.py
# ``audit_rtl_altitude``), and the landing is then that much longer.
#: The return-altitude parameter per autopilot and its scale (parameter units per metre).
RTL_ALT_PARAMS: dict[int, tuple[str, float]] = {
    ARDUPILOT: ("RTL_ALT", 100.0),
    PX4: ("RTL_RETURN_ALT", 1.0),
}

#: Their names, whichever the autopilot.
RTL_ALT_NAMES: frozenset[str] = frozenset(name for name, _ in RTL_ALT_PARAMS.values())

#: Their firmware defaults, in the parameter's units: ArduCopter/config.h ``RTL_ALT`` 1500 cm;
#: PX4 src/modules/navigator/rtl_params.yaml ``RTL_RETURN_ALT`` 60 m.
RTL_ALT_DEFAULTS: dict[int, float] = {ARDUPILOT: 1500.0, PX4: 60.0}


def return_alt_m(autopilot: int, params: Mapping[str, float] | None = None) -> float:
    """The least height above home a vehicle of ``autopilot`` flies home at in RTL, metres,
    from ``params`` (the firmware's default when it did not give its own); 0 for an autopilot
    without one known here."""
    spec = RTL_ALT_PARAMS.get(autopilot)
    if spec is None:
        return 0.0
    name, per_m = spec
    return float((params or {}).get(name, RTL_ALT_DEFAULTS[autopilot])) / per_m


@dataclass(frozen=True)
class LandingDescent:
    """A two-stage landing: ``fast_m_s`` above ``slow_alt_m``, ``land_m_s`` below
    ``land_alt_m``, the speed linear in the height in between (ArduCopter: the two heights are
    one). Heights above the pad, metres; speeds down, m/s."""

    fast_m_s: float
    slow_alt_m: float
    land_alt_m: float
    land_m_s: float

    def __post_init__(self) -> None:
        if not (self.fast_m_s > 0 and self.land_m_s > 0):
            raise ValueError(f"landing speeds must be > 0, got {self.fast_m_s}, {self.land_m_s}")
        if not 0.0 <= self.land_alt_m <= self.slow_alt_m:
            raise ValueError(
                f"need 0 <= land_alt_m <= slow_alt_m, got {self.land_alt_m}, {self.slow_alt_m}"
            )

    def speed_m_s(self, alt_m: float) -> float:
        """The descent speed at ``alt_m`` above the pad, m/s."""
        if alt_m >= self.slow_alt_m:
            return self.fast_m_s
        if alt_m <= self.land_alt_m:
            return self.land_m_s
        k = (alt_m - self.land_alt_m) / (self.slow_alt_m - self.land_alt_m)
        return self.land_m_s + k * (self.fast_m_s - self.land_m_s)

    def time_s(self, alt_m: float) -> float:
        """Seconds from ``alt_m`` above the pad to the ground (the integral of 1 / speed)."""
        alt = max(0.0, float(alt_m))
        lo, hi = self.land_alt_m, self.slow_alt_m
        t = max(0.0, alt - hi) / self.fast_m_s + min(alt, lo) / self.land_m_s
        top = min(alt, hi)
        if top > lo:  # the ramp: v = land + (h - lo) * slope
            dv = self.fast_m_s - self.land_m_s
            if abs(dv) < 1e-12:
                t += (top - lo) / self.land_m_s
            else:
                t += (hi - lo) / dv * math.log(self.speed_m_s(top) / self.land_m_s)
        return t


def landing_descent(autopilot: int, params: Mapping[str, float] | None = None) -> LandingDescent:
    """The landing of a vehicle of ``autopilot`` with ``params`` (the ones it gave; the others at
    the firmware's defaults, :data:`FIRMWARE_DEFAULTS`). An unknown autopilot lands as
    ArduCopter's defaults."""
    ap = autopilot if autopilot in FIRMWARE_DEFAULTS else ARDUPILOT
    got = params or {}
    p = {k: float(got.get(k, v)) for k, v in FIRMWARE_DEFAULTS[ap].items()}
    if ap == PX4:
        land, top, cap = p["MPC_LAND_SPEED"], p["MPC_Z_VEL_MAX_DN"], p["MPC_Z_V_AUTO_DN"]
        lo = p["MPC_LAND_ALT2"]
        hi = max(p["MPC_LAND_ALT1"], lo)
        fast = min(top, cap)
        if cap < top and top > land:
            # The ramp toward MPC_Z_VEL_MAX_DN meets the MPC_Z_V_AUTO_DN limit below ALT1.
            hi = lo + (hi - lo) * max(0.0, cap - land) / (top - land)
        return LandingDescent(fast, hi, lo, min(land, fast))
    high = p["LAND_SPEED_HIGH"]
    land = abs(p["LAND_SPEED"]) / 100.0
    fast = max((high if high > 0 else p["WPNAV_SPEED_DN"]) / 100.0, land)
    alt_low = max(p["LAND_ALT_LOW"], 100.0) / 100.0
    return LandingDescent(fast, alt_low, alt_low, land)

"""The mission's flight limits as each firmware's own parameters (pure functions).

A planning limit that the vehicle does not enforce is not a limit: the planner moves targets at
most ``max_speed_m_s`` per second, but between two targets the autopilot's position controller
flies at its own speed limit (ArduCopter SITL flew 6.5-6.7 m/s in the first seconds of GUIDED
against a mission limit of 5 m/s). So at launch the station writes the firmware's limits from
the mission (:class:`gcs.operations.Operator`, ``set_limits``), confirms each from the
PARAM_VALUE echo, and restores the previous values after landing when asked
(``restore_params``). Which parameters:

ArduPilot Copter
  ``WPNAV_SPEED`` (cm/s): the horizontal speed of GUIDED position targets (ModeGuided uses the
  waypoint navigation library, ``AC_WPNav::set_wp_destination``; ``WPNAV_SPEED`` is its
  ``_wp_speed_cms``) and of RTL when ``RTL_SPEED`` = 0 (ArduCopter/mode_rtl.cpp).
  ``WPNAV_SPEED_UP`` (cm/s): climb speed (``AC_WPNav::_wp_speed_up_cms``), take-off included.
PX4 multicopter
  ``MPC_XY_CRUISE`` (m/s): auto modes (Return) horizontal speed; ``MPC_XY_VEL_MAX`` (m/s): the
  horizontal velocity limit of every position-controlled mode, OFFBOARD included
  (src/modules/mc_pos_control/MulticopterPositionControl.cpp applies it to the velocity
  constraints of all setpoints). MPC_XY_CRUISE must not exceed MPC_XY_VEL_MAX
  (mc_pos_control_params.c), so it is written first when both go down and last when the cap
  goes up.
  ``MPC_Z_VEL_MAX_UP`` (m/s): climb speed limit.

Descent, only when the mission sets ``vehicles.descent_rate_m_s`` (docs/terrain.md §6.2: over a
canyon under the ceiling, the descent speed is how fast a vehicle gets down the wall):
ArduCopter ``WPNAV_SPEED_DN`` (cm/s, ``AC_WPNav::_wp_speed_down_cms``, default 150) and PX4
``MPC_Z_VEL_MAX_DN`` (m/s, the offboard descent limit, default 1.5, at most 4:
src/modules/mc_pos_control/mc_pos_control_params.c).
"""

from __future__ import annotations

from collections.abc import Mapping

from gcs.autopilot import ARDUPILOT, PX4

__all__ = ["DESCENT_PARAMS", "LIMIT_PARAMS", "limit_names", "limit_params", "limit_writes"]

#: Parameters that carry the mission's limits, per HEARTBEAT.autopilot, in write order.
LIMIT_PARAMS: dict[int, tuple[str, ...]] = {
    ARDUPILOT: ("WPNAV_SPEED", "WPNAV_SPEED_UP"),
    PX4: ("MPC_XY_CRUISE", "MPC_XY_VEL_MAX", "MPC_Z_VEL_MAX_UP"),
}

#: The descent speed's parameter, per HEARTBEAT.autopilot, read and written after the others when
#: the mission sets a descent rate.
DESCENT_PARAMS: dict[int, str] = {ARDUPILOT: "WPNAV_SPEED_DN", PX4: "MPC_Z_VEL_MAX_DN"}


def limit_names(autopilot: int, descent: bool = False) -> tuple[str, ...]:
    """The limit parameters to read and write on this firmware, in write order (``descent``:
    with the descent speed's)."""
    names = LIMIT_PARAMS.get(autopilot, ())
    if descent and autopilot in DESCENT_PARAMS:
        names += (DESCENT_PARAMS[autopilot],)
    return names


def limit_params(
    autopilot: int,
    max_speed_m_s: float,
    climb_rate_m_s: float,
    descent_rate_m_s: float | None = None,
) -> dict[str, float]:
    """``{name: value}`` in the firmware's own units for these limits (empty if unknown firmware;
    the descent speed only when ``descent_rate_m_s`` is given)."""
    if autopilot == ARDUPILOT:
        out = {
            "WPNAV_SPEED": round(100.0 * max_speed_m_s, 1),
            "WPNAV_SPEED_UP": round(100.0 * climb_rate_m_s, 1),
        }
        if descent_rate_m_s is not None:
            out["WPNAV_SPEED_DN"] = round(100.0 * descent_rate_m_s, 1)
        return out
    if autopilot == PX4:
        out = {
            "MPC_XY_CRUISE": float(max_speed_m_s),
            "MPC_XY_VEL_MAX": float(max_speed_m_s),
            "MPC_Z_VEL_MAX_UP": float(climb_rate_m_s),
        }
        if descent_rate_m_s is not None:
            out["MPC_Z_VEL_MAX_DN"] = float(descent_rate_m_s)
        return out
    return {}


def limit_writes(
    autopilot: int,
    current: Mapping[str, float],
    max_speed_m_s: float,
    climb_rate_m_s: float,
    descent_rate_m_s: float | None = None,
    *,
    rel_tol: float = 1e-3,
) -> list[tuple[str, float]]:
    """``(name, value)`` writes needed to bring ``current`` (values read from the vehicle) to the
    mission's limits, in :data:`LIMIT_PARAMS` order; parameters that were not read are skipped
    (the caller reports them)."""
    want = limit_params(autopilot, max_speed_m_s, climb_rate_m_s, descent_rate_m_s)
    out = []
    for name in limit_names(autopilot, descent_rate_m_s is not None):
        if name not in current or name not in want:
            continue
        have, value = float(current[name]), want[name]
        if abs(have - value) > rel_tol * max(abs(value), 1e-9):
            out.append((name, value))
    if (
        autopilot == PX4
        and "MPC_XY_VEL_MAX" in current
        and want["MPC_XY_VEL_MAX"] > float(current["MPC_XY_VEL_MAX"])
    ):
        out.sort(key=lambda nv: nv[0] != "MPC_XY_VEL_MAX")  # raise the cap before the cruise
    return out

"""What a pilot watches, per vehicle, as the columns of a live-page frame (live and replay).

Everything comes from the station's belief (:class:`gcs.fleet.FleetSnapshot`: batteries and the
drain estimate of :mod:`gcs.battery`, the health reports of :mod:`gcs.link_health`) plus the
packet loss the link counted (:mod:`gcs.link_quality`). docs/live_view.md lists every column.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from gcs.wire import mavlink
from planner.geometry import ned_to_geodetic

__all__ = [
    "health_columns",
    "unhealthy_sensors",
    "estimator_problems",
    "minutes_to_reserve",
    "GPS_FIX_NAMES",
    "LOSS_WINDOW_S",
]

#: Packet loss is shown over windows of this many station seconds (gcs.link_quality), live
#: and in replay.
LOSS_WINDOW_S = 10.0

#: GPS_FIX_TYPE (common.xml) as the page names it.
GPS_FIX_NAMES = {
    0: "no GPS",
    1: "no fix",
    2: "2D",
    3: "3D",
    4: "DGPS",
    5: "RTK float",
    6: "RTK fixed",
    7: "static",
    8: "PPP",
}

_SENSOR_ENUM = mavlink.enums["MAV_SYS_STATUS_SENSOR"]
#: Bit -> short name ("GPS", "3D_MAG", "AHRS", ...), from the dialect's MAV_SYS_STATUS_SENSOR.
SENSOR_NAMES = {
    int(bit): e.name.replace("MAV_SYS_STATUS_SENSOR_", "").replace("MAV_SYS_STATUS_", "")
    for bit, e in _SENSOR_ENUM.items()
    if bit & (bit - 1) == 0 and bit < 2**31
}

# The filter's flags (EKF_STATUS_FLAGS / ESTIMATOR_STATUS_FLAGS share bits 0-9): what a position
# controller needs (ArduCopter ekf_position_ok: attitude, horizontal velocity and an absolute
# horizontal position, not constant-position mode), named the way a pilot reads them.
_NEEDED = (
    (1, "attitude"),
    (2, "horiz. velocity"),
    (4, "vert. velocity"),
    (16, "abs. position"),
    (32, "abs. altitude"),
)
_CONST_POS = 128
#: Bad-news bits per source: EKF_UNINITIALIZED / EKF_GPS_GLITCHING (ArduPilot),
#: ESTIMATOR_GPS_GLITCH / ESTIMATOR_ACCEL_ERROR (PX4).
_BAD = {
    1: ((1024, "uninitialised"), (32768, "GPS glitch")),
    2: ((1024, "GPS glitch"), (2048, "accel error")),
}
#: An innovation test ratio at or above this is shown (Mission Planner's EKF window turns such a
#: bar orange at 0.5 and red at 0.8; 1.0 is where the filter rejects the measurement).
RATIO_WARN = 0.8


@lru_cache(maxsize=256)
def unhealthy_sensors(present: int, enabled: int, health: int) -> tuple[str, ...]:
    """Names of the sensors present and enabled but not healthy (SYS_STATUS masks)."""
    if present < 0:
        return ()
    bad = present & enabled & ~health
    return tuple(name for bit, name in SENSOR_NAMES.items() if bad & bit)


@lru_cache(maxsize=256)
def estimator_problems(flags: int, source: int, ratio_x100: int) -> str | None:
    """ "ok", or what is wrong with the navigation filter; None if it never reported.

    ``source``: 1 EKF_STATUS_REPORT, 2 ESTIMATOR_STATUS; ``ratio_x100``: the worst innovation
    test ratio x 100 (-1: not reported)."""
    if flags < 0:
        return None
    out = [f"no {name}" for bit, name in _NEEDED if not flags & bit]
    if flags & _CONST_POS:
        out.append("constant-position mode")
    out += [name for bit, name in _BAD.get(source, ()) if flags & bit]
    if ratio_x100 >= 100 * RATIO_WARN:
        out.append(f"test ratio {ratio_x100 / 100:.2f}")
    return "; ".join(out) if out else "ok"


def minutes_to_reserve(
    battery_frac: np.ndarray, drain_per_s: np.ndarray, reserve_frac: float
) -> np.ndarray:
    """(N,) minutes until each battery reaches ``reserve_frac`` at its estimated drain (NaN while
    the drain is unknown or zero; 0 once there)."""
    b = np.asarray(battery_frac, float)
    r = np.asarray(drain_per_s, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(r > 0, (b - reserve_frac) / np.where(r > 0, r, 1.0), np.nan)
    return np.maximum(t, 0.0) / 60.0


def _col(a: np.ndarray, nd: int) -> list:
    a = np.asarray(a, dtype=float)
    return [None if not math.isfinite(x) else x for x in np.round(a, nd).tolist()]


def _icol(a: np.ndarray) -> list:
    a = np.asarray(a, dtype=float)
    return [None if not math.isfinite(x) else int(x) for x in a.tolist()]


def health_columns(
    snap,
    origin,
    now_s: float,
    *,
    loss_frac: Sequence[float | None] | None = None,
    reserve_min: np.ndarray | None = None,
) -> dict:
    """The per-vehicle health columns of a frame (lists, one entry per fleet row; None: not
    known).

    Parameters
    ----------
    snap : gcs.fleet.FleetSnapshot
    origin : gcs.fleet.MissionOrigin (the mission frame's; for latitude / longitude)
    now_s : the snapshot's time (seconds since last heard)
    loss_frac : per row, the packet loss over the last window (None: no frames)
    reserve_min : (N,) minutes to the battery reserve (NaN: unknown)
    """
    n = snap.n_vehicles
    pos = snap.pos_ned_m
    if n:
        lat, lon, amsl = ned_to_geodetic(pos, origin.lat_deg, origin.lon_deg, origin.alt_amsl_m)
        lat, lon, amsl = np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(amsl)
    else:
        lat = lon = amsl = np.empty(0)
    nan = np.full(n, np.nan)
    health = snap.health if snap.health is not None else np.full((n, 6), np.nan)
    masks = snap.masks if snap.masks is not None else np.full((n, 5), -1, dtype=np.int64)
    batt = snap.battery_frac if snap.battery_frac is not None else nan
    volt = snap.battery_voltage_v if snap.battery_voltage_v is not None else nan
    vel = snap.vel_ned_m_s
    ratio = health[:, 3]
    ratio_x100 = np.where(np.isfinite(ratio), np.round(ratio * 100), -1).astype(int).tolist()
    m = masks.tolist()
    since = now_s - snap.last_heard_s
    return {
        "lat": _col(lat, 6),
        "lon": _col(lon, 6),
        "amsl": _col(amsl, 1),
        "ahome": _col(amsl - snap.home_amsl_m, 1),
        "gs": _col(np.hypot(vel[:, 0], vel[:, 1]) if n else nan, 1),
        "bat": _icol(np.round(batt * 100)),
        "volt": _col(volt, 2),
        "res_min": _col(nan if reserve_min is None else reserve_min, 1),
        "gps": _icol(health[:, 0]),
        "sats": _icol(health[:, 1]),
        "hdop": _col(health[:, 2], 2),
        "rssi": _icol(health[:, 4]),
        "remrssi": _icol(health[:, 5]),
        "loss": [None if x is None else round(100.0 * x, 1) for x in loss_frac]
        if loss_frac is not None
        else [None] * n,
        "since": _col(np.where(np.isfinite(since), since, np.nan), 1),
        "sensors_bad": [
            ",".join(unhealthy_sensors(r[0], r[1], r[2])) if r[0] >= 0 else None for r in m
        ],
        "ekf": [estimator_problems(r[3], r[4], q) for r, q in zip(m, ratio_x100)],
    }

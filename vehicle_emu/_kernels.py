"""Compiled per-tick kernels of the emulator (Numba), each the fast twin of a NumPy reference.

The emulator steps a few dozen to a few thousand vehicles every tick. At 50 vehicles each NumPy
call costs more than the arithmetic it does, and a tick of the physics, the batteries, the
geodetic update and the radio's hop counts made some two hundred of them: a fifth of the
emulator's CPU in a two-hour flight (docs/results/endurance.md, "Speed"). Each kernel here does
one of those in a single pass over the vehicles. The slow, obviously-correct version stays where
it was and is the reference the tests compare with (tests/vehicle_emu/test_emu_kernels.py):

* :func:`physics_step` - :meth:`vehicle_emu.physics.Physics.step_reference` (with
  :func:`vehicle_emu.battery.battery_step` in every sub-step);
* :func:`ned_to_geodetic` - :func:`planner.geometry.ned_to_geodetic` (pymap3d);
* :func:`hop_counts` - :meth:`vehicle_emu.radio.Radio._hop_counts_reference` (scipy's
  breadth-first search over :func:`planner.geometry.neighbour_pairs`);
* :func:`frame_rows` - :func:`vehicle_emu.telemetry_batch.pack_frames_reference` (MAVLink 2
  framing and the X.25 checksum of a batch of payloads, one fastcrc call per frame).

Bit-identity (planner/_kernels.py explains the rules: no ``fastmath``, the same operation order).
Arithmetic, square roots and ``hypot`` give the same bits as NumPy. NumPy may evaluate ``exp``,
``sin``, ``cos``, ``tan``, ``arctan`` and ``arctan2`` with its own SIMD code (SVML on AVX-512),
which can differ from the C library's in the last bit: the kernels take every such value of the
reference that does not depend on the vehicle (the origin's sines and cosines, the velocity lag's
``1 - exp(-h / tau)``) from the caller, computed by NumPy as the reference computes it, and what
remains (a vehicle's heading, latitude and longitude) agrees with the reference to an ulp or two.

When Numba is missing (``planner._kernels.NUMBA``) or :data:`ENABLED` is False, the callers run
their references.
"""

from __future__ import annotations

import math

import numpy as np

from planner import geometry
from planner._kernels import NUMBA, njit

__all__ = ["NUMBA", "ENABLED", "physics_step", "ned_to_geodetic", "hop_counts", "frame_rows"]

#: False: every caller runs its NumPy reference (tests and benchmarks compare the two).
ENABLED = True


def active() -> bool:
    """Whether the callers should use the kernels (Numba importable and :data:`ENABLED`)."""
    return NUMBA and ENABLED


# ---------------------------------------------------------------------------------------------
# Physics and batteries (vehicle_emu.physics, vehicle_emu.battery)
# ---------------------------------------------------------------------------------------------


@njit(cache=True)
def _np_max(a: float, b: float) -> float:
    # np.maximum: NaN if either is NaN.
    if a != a:
        return a
    if b != b:
        return b
    return a if a >= b else b


@njit(cache=True)
def _np_min(a: float, b: float) -> float:
    # np.minimum: NaN if either is NaN.
    if a != a:
        return a
    if b != b:
        return b
    return a if a <= b else b


@njit(cache=True)
def _np_clip(a: float, lo: float, hi: float) -> float:
    # np.clip = np.minimum(np.maximum(a, lo), hi).
    return _np_min(_np_max(a, lo), hi)


@njit(cache=True)
def _np_interp(x: float, xp: np.ndarray, fp: np.ndarray) -> float:
    # np.interp (numpy/_core/src/multiarray/compiled_base.c arr_interp): the last point below or
    # at x, then slope * (x - xp[j]) + fp[j] (retried from the right end on NaN); ends clamped.
    n = len(xp)
    if x != x:
        return x
    if x < xp[0]:
        return fp[0]
    if x > xp[n - 1]:
        return fp[n - 1]
    if x == xp[n - 1]:
        return fp[n - 1]
    lo = 0
    hi = n - 1
    while hi - lo > 1:  # xp[lo] <= x < xp[hi]
        mid = (lo + hi) // 2
        if xp[mid] <= x:
            lo = mid
        else:
            hi = mid
    if xp[lo] == x:
        return fp[lo]
    slope = (fp[lo + 1] - fp[lo]) / (xp[lo + 1] - xp[lo])
    r = slope * (x - xp[lo]) + fp[lo]
    if r != r:
        r = slope * (x - xp[lo + 1]) + fp[lo + 1]
        if r != r and fp[lo] == fp[lo + 1]:
            r = fp[lo]
    return r


@njit(cache=True)
def _saturate(
    vn: float, ve: float, vd: float, vmax: float, climb: float, down_limit: float
) -> tuple[float, float, float]:
    # Physics._saturate_inplace for one vehicle.
    speed_h = math.hypot(vn, ve)
    scale = _np_min(1.0, vmax / _np_max(speed_h, 1e-12))
    return vn * scale, ve * scale, _np_clip(vd, -climb, down_limit)


@njit(cache=True)
def _physics_step(
    n_sub: int,
    h: float,
    alpha: float,
    tau_pos: float,
    ground_eps: float,
    ctrl_vel: int,
    ctrl_land: int,
    pos: np.ndarray,
    vel: np.ndarray,
    yaw: np.ndarray,
    ground: np.ndarray,
    tpos: np.ndarray,
    tvel: np.ndarray,
    ctrl: np.ndarray,
    vmax: np.ndarray,
    climb: np.ndarray,
    descent: np.ndarray,
    land_fast: np.ndarray,
    land_speed: np.ndarray,
    land_slow: np.ndarray,
    land_crawl: np.ndarray,
    armed: np.ndarray,
    alive: np.ndarray,
    landed: np.ndarray,
    with_battery: bool,
    batt_consts: np.ndarray,
    ocv_soc: np.ndarray,
    ocv_v: np.ndarray,
    consumed: np.ndarray,
    energy: np.ndarray,
    current: np.ndarray,
    voltage: np.ndarray,
):
    n = pos.shape[0]
    pos2 = np.empty((n, 3))
    vel2 = np.empty((n, 3))
    yaw2 = np.empty(n)
    landed2 = np.empty(n, dtype=np.bool_)
    consumed2 = np.empty(len(consumed))
    energy2 = np.empty(len(energy))
    current2 = np.empty(len(current))
    voltage2 = np.empty(len(voltage))
    hover_a, speed_f, ref_speed, climb_f, ref_climb, capacity, cells, r_int = (
        batt_consts[0],
        batt_consts[1],
        batt_consts[2],
        batt_consts[3],
        batt_consts[4],
        batt_consts[5],
        batt_consts[6],
        batt_consts[7],
    )
    for i in range(n):
        pn, pe, pd = pos[i, 0], pos[i, 1], pos[i, 2]
        vn, ve, vd = vel[i, 0], vel[i, 1], vel[i, 2]
        y = yaw[i]
        lnd = landed[i]
        g = ground[i]
        moving = armed[i] and alive[i]
        drawing = moving
        is_vel = ctrl[i] == ctrl_vel
        is_land = ctrl[i] == ctrl_land
        down_limit = _np_max(land_fast[i], land_speed[i]) if is_land else descent[i]
        if with_battery:
            c_mah, e_wh, cur, volt = consumed[i], energy[i], current[i], voltage[i]
        else:
            c_mah = e_wh = cur = volt = 0.0
        for _ in range(n_sub):
            # Physics._commanded_velocity
            if is_vel:
                cn, ce, cd = tvel[i, 0], tvel[i, 1], tvel[i, 2]
            else:
                cn = (tpos[i, 0] - pn) / tau_pos + tvel[i, 0]
                ce = (tpos[i, 1] - pe) / tau_pos + tvel[i, 1]
                cd = (tpos[i, 2] - pd) / tau_pos + tvel[i, 2]
            if is_land:  # Physics.land_descent_m_s
                hgt = g - pd
                lo, hi = land_crawl[i], land_slow[i]
                if hgt >= hi:
                    ramp = 1.0
                elif hgt <= lo:
                    ramp = 0.0
                else:
                    ramp = (hgt - lo) / (hi - lo)
                fast = _np_max(land_fast[i], land_speed[i])
                cd = land_speed[i] + ramp * (fast - land_speed[i])
            cn, ce, cd = _saturate(cn, ce, cd, vmax[i], climb[i], down_limit)
            if pd >= g - ground_eps and cd >= 0:  # landed vehicles do not slide
                cn = ce = cd = 0.0
            vn = vn + (cn - vn) * alpha
            ve = ve + (ce - ve) * alpha
            vd = vd + (cd - vd) * alpha
            vn, ve, vd = _saturate(vn, ve, vd, vmax[i], climb[i], down_limit)
            if not moving:
                vn = ve = vd = 0.0
            pn = pn + vn * h
            pe = pe + ve * h
            pd = pd + vd * h
            if pd > g:
                pd = g
                vd = _np_min(vd, 0.0)
            if not armed[i] and alive[i] and pd < g:  # motors off in the air: dropped
                pd = g
            lnd = (pd >= g - ground_eps) and (cd >= 0 or not moving)
            if math.hypot(vn, ve) > 0.5:
                y = math.atan2(ve, vn)
            if with_battery:  # vehicle_emu.battery.battery_step
                speed_h = math.hypot(vn, ve)
                up = _np_max(0.0, -vd)
                ratio = speed_h / ref_speed
                factor = 1.0 + speed_f * (ratio * ratio) + climb_f * up / ref_climb
                cur = hover_a * factor if drawing else 0.0
                c_mah = c_mah + cur * h / 3.6
                soc = _np_clip(1.0 - c_mah / capacity, 0.0, 1.0)
                volt = cells * _np_interp(soc, ocv_soc, ocv_v) - cur * r_int
                e_wh = e_wh + volt * cur * h / 3600.0
        pos2[i, 0], pos2[i, 1], pos2[i, 2] = pn, pe, pd
        vel2[i, 0], vel2[i, 1], vel2[i, 2] = vn, ve, vd
        yaw2[i] = y
        landed2[i] = lnd
        if with_battery:
            consumed2[i], energy2[i], current2[i], voltage2[i] = c_mah, e_wh, cur, volt
    return pos2, vel2, yaw2, landed2, consumed2, energy2, current2, voltage2


def physics_step(ph, n_sub: int, h: float, alpha: float, ctrl_vel: int, ctrl_land: int, eps: float):
    """``n_sub`` sub-steps of ``h`` seconds of every vehicle of ``ph`` (a
    :class:`vehicle_emu.physics.Physics`), its batteries drained in each: new position, velocity,
    yaw and landed arrays (and the packs' new consumed charge, energy, current and voltage).
    ``alpha`` is the velocity lag's ``1 - exp(-h / tau_vel_s)`` as the reference computes it."""
    batt = ph.battery
    if batt is not None:
        cfg = batt.config
        consts = np.array(
            [
                cfg.hover_current_a,
                cfg.speed_drain_frac,
                cfg.ref_speed_m_s,
                cfg.climb_drain_factor,
                cfg.ref_climb_m_s,
                cfg.capacity_mah,
                float(cfg.cells),
                cfg.internal_resistance_ohm,
            ]
        )
        from .battery import _OCV_SOC, _OCV_V

        arrays = (batt.consumed_mah, batt.energy_wh, batt.current_a, batt.voltage_v)
        ocv = (_OCV_SOC, _OCV_V)
    else:
        consts = _NO_BATTERY
        arrays = (_EMPTY, _EMPTY, _EMPTY, _EMPTY)
        ocv = (_EMPTY, _EMPTY)
    return _physics_step(
        int(n_sub),
        float(h),
        float(alpha),
        float(ph.tau_pos_s),
        float(eps),
        int(ctrl_vel),
        int(ctrl_land),
        ph.pos_ned_m,
        ph.vel_ned_m_s,
        ph.yaw_rad,
        ph.ground_down_m,
        ph.target_pos_ned_m,
        ph.target_vel_ned_m_s,
        ph.ctrl,
        ph.max_speed_h_m_s,
        ph.climb_rate_m_s,
        ph.descent_rate_m_s,
        ph.land_fast_m_s,
        ph.land_speed_m_s,
        ph.land_slow_alt_m,
        ph.land_crawl_alt_m,
        ph.armed,
        ph.alive,
        ph.landed,
        batt is not None,
        consts,
        *ocv,
        *arrays,
    )


_EMPTY = np.zeros(0)
_NO_BATTERY = np.zeros(8)


# ---------------------------------------------------------------------------------------------
# Geodetic positions (planner.geometry.ned_to_geodetic: pymap3d's ned2geodetic on WGS-84)
# ---------------------------------------------------------------------------------------------

_WGS84_A = 6378137.0
_WGS84_B = 6356752.31424518


def _origin_constants(lat0_deg: float, lon0_deg: float, h0_m: float) -> np.ndarray:
    """What pymap3d's ``enu2ecef`` / ``ecef2geodetic`` compute once for an origin (its ECEF
    position and the sines and cosines of its latitude and longitude) and the ellipsoid's
    constants, by NumPy as pymap3d computes them."""
    import pymap3d

    x0, y0, z0 = pymap3d.geodetic2ecef(lat0_deg, lon0_deg, h0_m)
    lat0 = np.radians(lat0_deg)
    lon0 = np.radians(lon0_deg)
    a, b = _WGS84_A, _WGS84_B
    big_e = np.sqrt(a**2 - b**2)
    return np.array(
        [
            float(x0),
            float(y0),
            float(z0),
            float(np.cos(lat0)),
            float(np.sin(lat0)),
            float(np.cos(lon0)),
            float(np.sin(lon0)),
            float(big_e),
            float(big_e**2),
            a / b,
            a**2,
            b**2,
            float(np.pi / 2 - np.finfo(np.float64).eps),
        ]
    )


_ORIGINS: dict[tuple[float, float, float], np.ndarray] = {}


@njit(cache=True)
def _isclose0(v: float) -> bool:
    # np.isclose(v, 0): |v| <= atol (1e-8) + rtol * 0; False for NaN and infinities.
    return abs(v) <= 1e-08


@njit(cache=True)
def _ned_to_geodetic(
    north: np.ndarray, east: np.ndarray, down: np.ndarray, k: np.ndarray, a: float, b: float
):
    n = len(north)
    lat_out = np.empty(n)
    lon_out = np.empty(n)
    alt_out = np.empty(n)
    x0, y0, z0, clat0, slat0, clon0, slon0 = k[0], k[1], k[2], k[3], k[4], k[5], k[6]
    big_e, e2, a_over_b, a2, b2, lim = k[7], k[8], k[9], k[10], k[11], k[12]
    half_pi = math.pi / 2
    to_deg = 180.0 / math.pi
    for i in range(n):
        up = -down[i]
        nn = north[i]
        ee = east[i]
        # pymap3d enu2uvw, then enu2ecef
        t = clat0 * up - slat0 * nn
        w = slat0 * up + clat0 * nn
        u = clon0 * t - slon0 * ee
        v = slon0 * t + clon0 * ee
        x = x0 + u
        y = y0 + v
        z = z0 + w
        # pymap3d ecef2geodetic (You 2000)
        r = math.sqrt(x * x + y * y + z * z)
        r2e2 = r * r - e2
        uu = math.sqrt(0.5 * r2e2 + 0.5 * math.hypot(r2e2, 2 * big_e * z))
        hxy = math.hypot(x, y)
        hue = math.hypot(uu, big_e)
        if _isclose0(uu) or _isclose0(hxy):
            if _isclose0(z):
                beta = 0.0
            elif z > 0:
                beta = half_pi
            else:
                beta = -half_pi
        else:
            beta = math.atan(hue / uu * z / hxy)
            beta = beta + ((b * uu - a * hue + e2) * math.sin(beta)) / (
                a * hue * 1 / math.cos(beta) - e2 * math.cos(beta)
            )
        lat = math.atan(a_over_b * math.tan(beta))
        if beta >= lim:
            lat = half_pi
        if beta <= -lim:
            lat = -half_pi
        lon = math.atan2(y, x)
        cos_beta = math.cos(beta)
        if beta >= lim or beta <= -lim:
            cos_beta = 0.0
        alt = math.hypot(z - b * math.sin(beta), hxy - a * cos_beta)
        if x * x / a2 + y * y / a2 + z * z / b2 < 1:
            alt = -alt
        lat_out[i] = lat * to_deg
        lon_out[i] = lon * to_deg
        alt_out[i] = alt
    return lat_out, lon_out, alt_out


def ned_to_geodetic(
    ned_m: np.ndarray, origin_lat_deg: float, origin_lon_deg: float, origin_alt_amsl_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, 3) or (3,) NED metres around an origin to (lat_deg, lon_deg, alt_amsl_m), each (N,)
    or a 0-d array: :func:`planner.geometry.ned_to_geodetic` (pymap3d, WGS-84, the reference),
    in one compiled pass when the kernels are :func:`active`. Every position the emulator
    reports goes through here, so its telemetry paths agree to the bit."""
    ned = np.asarray(ned_m, dtype=float)
    if not active():
        with np.errstate(all="ignore"):  # absurd (finite) positions: pymap3d's overflows
            return geometry.ned_to_geodetic(ned, origin_lat_deg, origin_lon_deg, origin_alt_amsl_m)
    lat, lon, alt = _ned_to_geodetic_rows(
        ned.reshape(-1, 3), origin_lat_deg, origin_lon_deg, origin_alt_amsl_m
    )
    if ned.ndim == 1:
        return lat.reshape(()), lon.reshape(()), alt.reshape(())
    return lat, lon, alt


def _ned_to_geodetic_rows(
    ned: np.ndarray, origin_lat_deg: float, origin_lon_deg: float, origin_alt_amsl_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    key = (float(origin_lat_deg), float(origin_lon_deg), float(origin_alt_amsl_m))
    k = _ORIGINS.get(key)
    if k is None:
        k = _ORIGINS[key] = _origin_constants(*key)
    return _ned_to_geodetic(
        np.ascontiguousarray(ned[:, 0]),
        np.ascontiguousarray(ned[:, 1]),
        np.ascontiguousarray(ned[:, 2]),
        k,
        _WGS84_A,
        _WGS84_B,
    )


# ---------------------------------------------------------------------------------------------
# Radio hop counts (vehicle_emu.radio)
# ---------------------------------------------------------------------------------------------


@njit(cache=True)
def _hop_counts(
    pos: np.ndarray, active: np.ndarray, base: np.ndarray, range_m: float, base_reach_m: float
) -> np.ndarray:
    n, dims = pos.shape
    hops = np.zeros(n, dtype=np.int64)
    queue = np.empty(n, dtype=np.int64)
    tail = 0
    for i in range(n):  # one hop: within the base's reach (np.linalg.norm(p - base))
        if not active[i]:
            continue
        s = 0.0
        for d in range(dims):
            dd = pos[i, d] - base[d]
            s = s + dd * dd
        if math.sqrt(s) <= base_reach_m:
            hops[i] = 1
            queue[tail] = i
            tail += 1
    front = 0
    while front < tail:  # breadth first: each vehicle first reached at its least hop count
        i = queue[front]
        front += 1
        for j in range(n):
            if not active[j] or hops[j] != 0:
                continue
            s = 0.0
            for d in range(dims):
                dd = pos[i, d] - pos[j, d]
                s = s + dd * dd
            if math.sqrt(s) <= range_m:
                hops[j] = hops[i] + 1
                queue[tail] = j
                tail += 1
    return hops


def hop_counts(
    pos_m: np.ndarray, active: np.ndarray, base_m: np.ndarray, range_m: float, base_reach_m: float
) -> np.ndarray:
    """(N,) int64 hop count of every active vehicle to the base (0 for the others): one hop
    within ``base_reach_m`` of the base, one more per link of at most ``range_m`` (the
    Euclidean distance over the columns of ``pos_m``, (N, D))."""
    return _hop_counts(
        np.ascontiguousarray(pos_m, dtype=float),
        np.ascontiguousarray(active, dtype=np.bool_),
        np.ascontiguousarray(base_m, dtype=float),
        float(range_m),
        float(base_reach_m),
    )


# ---------------------------------------------------------------------------------------------
# MAVLink 2 frames (vehicle_emu.telemetry_batch)
# ---------------------------------------------------------------------------------------------


@njit(cache=True)
def _x25(crc: int, byte: int) -> int:
    # pymavlink x25crc.accumulate (CRC-16/MCRF4XX), one byte.
    tmp = byte ^ (crc & 0xFF)
    tmp = (tmp ^ (tmp << 4)) & 0xFF
    return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF


@njit(cache=True)
def _frame_rows(
    pay: np.ndarray,
    seq: np.ndarray,
    sysid: np.ndarray,
    compid: np.ndarray,
    msgid: int,
    crc_extra: int,
):
    k, plen = pay.shape
    out = np.empty(k * (12 + plen), dtype=np.uint8)
    ends = np.empty(k, dtype=np.int64)
    o = 0
    for r in range(k):
        n = plen  # MAVLink 2 truncation: trailing zero bytes dropped, at least one kept
        while n > 1 and pay[r, n - 1] == 0:
            n -= 1
        start = o
        out[o] = 0xFD
        out[o + 1] = n
        out[o + 2] = 0
        out[o + 3] = 0
        out[o + 4] = seq[r] & 0xFF
        out[o + 5] = sysid[r] & 0xFF
        out[o + 6] = compid[r] & 0xFF
        out[o + 7] = msgid & 0xFF
        out[o + 8] = (msgid >> 8) & 0xFF
        out[o + 9] = (msgid >> 16) & 0xFF
        o += 10
        for c in range(n):
            out[o] = pay[r, c]
            o += 1
        crc = 0xFFFF
        for c in range(start + 1, o):
            crc = _x25(crc, out[c])
        crc = _x25(crc, crc_extra)
        out[o] = crc & 0xFF
        out[o + 1] = crc >> 8
        o += 2
        ends[r] = o
    return out[:o], ends


def frame_rows(
    pay: np.ndarray,
    seq: np.ndarray,
    sysid: np.ndarray,
    compid: np.ndarray,
    msgid: int,
    crc_extra: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Unsigned MAVLink 2 frames of ``k`` payloads ((k, P) uint8, the message's full wire
    length), one after the other: the bytes (uint8) and each frame's end offset ((k,) int64).
    ``seq``, ``sysid``, ``compid``: (k,) int64."""
    return _frame_rows(
        np.ascontiguousarray(pay),
        np.ascontiguousarray(seq),
        np.ascontiguousarray(sysid),
        np.ascontiguousarray(compid),
        int(msgid),
        int(crc_extra),
    )

"""Telemetry of a whole swarm per tick: each message type built once for every vehicle due.

The reference path (:meth:`vehicle_emu.link.VehicleCore.emit_telemetry`) builds one pymavlink
message per vehicle and stream and packs it (struct, header, x25 CRC) in Python: ~30 us a frame,
and at 1,000 PX4 vehicles with PX4's default streams (17.5 messages/s each) that alone is more
than a core. Here, per tick:

1. every vehicle with something due (:class:`~vehicle_emu.telemetry.StreamScheduler`) walks its
   due streams in its own order and reserves a sequence number and an output slot for each
   message type this module packs; other types (MISSION_CURRENT, AUTOPILOT_VERSION, ...) are
   built and encoded on the spot as before, so every vehicle's frames keep their order and
   sequence numbers;
2. per message type, the fields of all reserved rows are computed at once from the shared
   physics arrays (numpy), written into a structured array with pymavlink's wire layout
   (``unpacker`` format, ``ordered_fieldnames``), and framed in one preallocated matrix:
   MAVLink 2 header, payload truncated of trailing zeros as pymavlink does, and the x25 CRC
   (CRC-16/MCRF4XX with the message's CRC_EXTRA) computed column by column over all rows;
3. the frames go into the reserved slots.

Frames are byte-for-byte those of the reference path (tests/vehicle_emu/test_telemetry_batch.py
runs both on the same swarm state). A vehicle takes the reference path for the whole tick when
it signs its frames (the signature covers the sequence number and a per-frame timestamp) or
when any of its state is non-finite or absurd (the reference path counts a failing builder in
``telemetry_errors``; the vectorised one would have to reproduce each such case).

A little over the ~600 lines this code base aims for, on purpose: the framing keeps its slow
reference (:func:`pack_frames_reference`) next to the compiled path it is tested against.
"""

from __future__ import annotations

import logging
import math
import re

import numpy as np
from fastcrc import crc16

from mavedge import mavlink
from mavedge.units import INT32_MAX, INT32_MIN, UINT16_MAX, deg_to_e7, m_to_mm, yaw_rad_to_hdg_cdeg
from planner.geometry import DOWN, EAST, NORTH

from . import _kernels
from . import telemetry as tm
from .physics import CTRL_VEL

__all__ = ["BatchTelemetry", "pack_frames", "pack_frames_reference", "BATCHED_TYPES"]

log = logging.getLogger(__name__)

_FLT_MAX = float(np.finfo(np.float32).max)
_BASE_FLAGS = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED


_mcrf4xx = crc16.mcrf4xx  # X.25 CRC (CRC-16/MCRF4XX), as pymavlink's x25crc computes it
_CODES = {
    "f": "<f4",
    "d": "<f8",
    "B": "u1",
    "b": "i1",
    "H": "<u2",
    "h": "<i2",
    "I": "<u4",
    "i": "<i4",
    "Q": "<u8",
    "q": "<i8",
    "c": "S1",
}


class _Layout:
    """Wire layout of one message class: structured dtype, payload length, id bytes, CRC_EXTRA."""

    def __init__(self, cls) -> None:
        fmt = cls.unpacker.format.lstrip("<>=!@")
        tokens = re.findall(r"(\d*)([a-zA-Z?])", fmt)
        if len(tokens) != len(cls.ordered_fieldnames):
            raise ValueError(f"cannot map the wire layout of {cls.msgname}")
        spec: list[tuple] = []  # numpy dtype fields: (name, code) or (name, code, shape)
        for (count, code), name in zip(tokens, cls.ordered_fieldnames):
            n = int(count) if count else 1
            if code == "s":
                spec.append((name, f"S{n}"))
            elif n > 1:
                spec.append((name, _CODES[code], (n,)))
            else:
                spec.append((name, _CODES[code]))
        self.dtype = np.dtype(spec)
        self.plen = self.dtype.itemsize
        self.msgid = cls.id
        self.crc_extra = cls.crc_extra
        self.name = cls.msgname


_LAYOUTS: dict[int, _Layout] = {}


def _layout(cls) -> _Layout:
    lay = _LAYOUTS.get(cls.id)
    if lay is None:
        lay = _LAYOUTS[cls.id] = _Layout(cls)
    return lay


def _payloads(lay: _Layout, fields: dict, k: int) -> np.ndarray:
    """(k, payload length) uint8: the rows' payloads in pymavlink's wire layout."""
    rec = np.zeros(k, dtype=lay.dtype)
    for name, value in fields.items():
        rec[name] = value
    return rec.view(np.uint8).reshape(k, lay.plen)


def pack_frames(cls, fields: dict, seq, sysid, compid) -> list[bytes]:
    """Unsigned MAVLink 2 frames of ``cls``, one per row, as pymavlink would pack them.

    Framed and checksummed in one compiled pass (:func:`vehicle_emu._kernels.frame_rows`)
    when available, else :func:`pack_frames_reference`.

    Parameters
    ----------
    cls : pymavlink message class
    fields : mapping field name -> (k,) array or scalar (wire units; missing fields are 0)
    seq, sysid, compid : (k,) int arrays or scalars
    """
    if not _kernels.active():
        return pack_frames_reference(cls, fields, seq, sysid, compid)
    lay = _layout(cls)
    k = len(seq) if np.ndim(seq) else 1
    pay = _payloads(lay, fields, k)
    buf, ends = _kernels.frame_rows(
        pay, _column(seq, k), _column(sysid, k), _column(compid, k), lay.msgid, lay.crc_extra
    )
    data = buf.tobytes()
    bounds = ends.tolist()
    return [data[a:b] for a, b in zip([0, *bounds[:-1]], bounds)]


def _column(v, k: int) -> np.ndarray:
    """(k,) int64 of a scalar or a (k,) sequence."""
    if np.ndim(v) == 0:
        return np.full(k, v, dtype=np.int64)
    return np.asarray(v, dtype=np.int64)


def pack_frames_reference(cls, fields: dict, seq, sysid, compid) -> list[bytes]:
    """:func:`pack_frames` by NumPy and fastcrc (one CRC call per frame): the reference."""
    lay = _layout(cls)
    k = len(seq) if np.ndim(seq) else 1
    pay = _payloads(lay, fields, k)
    plen = lay.plen
    # MAVLink 2 payload truncation (pymavlink MAVLink_message._pack): trailing zero bytes are
    # dropped, at least one byte stays.
    nz = pay != 0
    last = plen - np.argmax(nz[:, ::-1], axis=1)
    length = np.where(nz.any(axis=1), last, 1)
    width = 12 + plen
    m = np.zeros((k, width), dtype=np.uint8)
    m[:, 0] = 0xFD
    m[:, 1] = length
    m[:, 4] = seq
    m[:, 5] = sysid
    m[:, 6] = compid
    m[:, 7] = lay.msgid & 0xFF
    m[:, 8] = (lay.msgid >> 8) & 0xFF
    m[:, 9] = (lay.msgid >> 16) & 0xFF
    m[:, 10 : 10 + plen] = pay
    # The X.25 CRC of each frame (header after the magic byte, payload, crc_extra), by
    # fastcrc (pymavlink's own x25crc uses it), one C call per frame.
    buf = m.tobytes()
    view = memoryview(buf)
    extra = bytes((lay.crc_extra,))
    out = []
    for r, n in enumerate(length.tolist()):
        start = r * width
        crc = _mcrf4xx(extra, _mcrf4xx(view[start + 1 : start + 10 + n]))
        out.append(buf[start : start + 10 + n] + crc.to_bytes(2, "little"))
    return out


# --------------------------------------------------------------------------------------------
# Vectorised fields, the same arithmetic as the scalar builders of vehicle_emu.telemetry
# --------------------------------------------------------------------------------------------


def _e7(deg: np.ndarray) -> np.ndarray:
    """mavedge.units.deg_to_e7 over an array: round half-even, clamp to int32, non-finite ->
    INT32_MAX."""
    with np.errstate(invalid="ignore", over="ignore"):
        v = _clip(np.round(deg * 1e7), INT32_MIN, INT32_MAX)
    return np.where(np.isfinite(deg), v, INT32_MAX).astype(np.int64)


def _clip(v: np.ndarray, lo: float, hi: float) -> np.ndarray:
    # np.clip is np.minimum(np.maximum(v, lo), hi) (NaN kept), without its Python-level wrapper
    # (a few microseconds a call: several calls per message type and tick).
    return np.minimum(np.maximum(v, lo), hi)


def _mm(m: np.ndarray) -> np.ndarray:
    return _clip(np.round(m * 1000.0), INT32_MIN, INT32_MAX).astype(np.int64)


def _cm_s(v: np.ndarray) -> np.ndarray:
    return _clip(np.round(v * 100.0), -32767, 32767).astype(np.int64)


def _hdg(yaw: np.ndarray) -> np.ndarray:
    return np.mod(np.round(np.degrees(yaw) * 100.0).astype(np.int64), 36000)


def _f32(v: np.ndarray) -> np.ndarray:
    return _clip(v, -_FLT_MAX, _FLT_MAX)


def _boot_ms(b, rows, now_s):
    return ((np.trunc((now_s - b.boot_s[rows]) * 1000.0)).astype(np.int64)) & 0xFFFFFFFF


def _usec(b, rows, now_s):
    return np.maximum(0, np.trunc((now_s - b.boot_s[rows]) * 1e6)).astype(np.int64)


def _heartbeat(b, cores, rows, now_s):
    base, status, modes = [], [], []
    for c in cores:
        f = _BASE_FLAGS
        if c._behaviour != "hold":
            f |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if c.armed:
            f |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            status.append(
                mavlink.MAV_STATE_CRITICAL if c.gcs_failsafe else mavlink.MAV_STATE_ACTIVE
            )
        else:
            status.append(mavlink.MAV_STATE_STANDBY)
        base.append(f)
        modes.append(c._mode_key)
    return {
        "type": mavlink.MAV_TYPE_QUADROTOR,
        "autopilot": b.autopilot[rows],
        "base_mode": base,
        "custom_mode": modes,
        "system_status": status,
        "mavlink_version": 3,
    }


def _sys_status(b, cores, rows, now_s):
    if b.ph.battery is not None:
        # The firmware's own numbers (vehicle_emu.battery_monitor), one call per vehicle at the
        # codec edge: the same function the reference builder calls.
        f = np.array([c.batt.sys_status_fields() for c in cores], dtype=np.int64).reshape(-1, 5)
        s = tm.SYS_STATUS_SENSORS | f[:, 0]
        return {
            "onboard_control_sensors_present": s,
            "onboard_control_sensors_enabled": s,
            "onboard_control_sensors_health": tm.SYS_STATUS_SENSORS
            | f[:, 1]
            | b.health_extra[rows],
            "load": 100,
            "voltage_battery": f[:, 2],
            "current_battery": f[:, 3],
            "battery_remaining": f[:, 4],
        }
    batt = b.ph.battery_frac[rows]
    s = tm.SYS_STATUS_SENSORS
    return {
        "onboard_control_sensors_present": s,
        "onboard_control_sensors_enabled": s,
        "onboard_control_sensors_health": s | b.health_extra[rows],
        "load": 100,
        "voltage_battery": np.trunc(10500 + 2100 * batt).astype(np.int64),
        "current_battery": -1,
        "battery_remaining": np.round(batt * 100).astype(np.int64),
    }


def _global_position_int(b, cores, rows, now_s):
    ph = b.ph
    vel = ph.vel_ned_m_s[rows]
    alt = ph.alt_amsl_m[rows]
    return {
        "time_boot_ms": _boot_ms(b, rows, now_s),
        "lat": _e7(ph.lat_deg[rows]),
        "lon": _e7(ph.lon_deg[rows]),
        "alt": _mm(alt),
        "relative_alt": _mm(alt - b.home_alt_m[rows]),
        "vx": _cm_s(vel[:, NORTH]),
        "vy": _cm_s(vel[:, EAST]),
        "vz": _cm_s(vel[:, DOWN]),
        "hdg": _hdg(ph.yaw_rad[rows]),
    }


def _local_position_ned(b, cores, rows, now_s):
    ph = b.ph
    p = _f32(ph.pos_ned_m[rows] - b.home_ned_m[rows])
    v = _f32(ph.vel_ned_m_s[rows])
    return {
        "time_boot_ms": _boot_ms(b, rows, now_s),
        "x": p[:, 0],
        "y": p[:, 1],
        "z": p[:, 2],
        "vx": v[:, 0],
        "vy": v[:, 1],
        "vz": v[:, 2],
    }


def _speed_cog(vn: np.ndarray, ve: np.ndarray):
    # math.hypot / math.atan2 row by row: the scalar builder's exact functions (CPython's
    # hypot is not libm's, and the 0.1 m/s threshold must fall the same way).
    speed = [math.hypot(a, c) for a, c in zip(vn.tolist(), ve.tolist())]
    cog = [
        yaw_rad_to_hdg_cdeg(math.atan2(c, a)) if s > 0.1 else UINT16_MAX
        for a, c, s in zip(vn.tolist(), ve.tolist(), speed)
    ]
    return speed, cog


def _gps_raw_int(b, cores, rows, now_s):
    ph = b.ph
    v = ph.vel_ned_m_s[rows]
    speed, cog = _speed_cog(v[:, NORTH], v[:, EAST])
    return {
        "time_usec": _usec(b, rows, now_s),
        "fix_type": mavlink.GPS_FIX_TYPE_3D_FIX,
        "lat": _e7(ph.lat_deg[rows]),
        "lon": _e7(ph.lon_deg[rows]),
        "alt": _mm(ph.alt_amsl_m[rows]),
        "eph": 80,
        "epv": 120,
        "vel": [min(65534, int(round(s * 100))) for s in speed],
        "cog": cog,
        "satellites_visible": tm.satellites_of(b.sysid[rows]),
    }


def _home_position(b, cores, rows, now_s):
    return {
        "latitude": b.home_e7[rows, 0],
        "longitude": b.home_e7[rows, 1],
        "altitude": b.home_e7[rows, 2],
        "q": (1.0, 0.0, 0.0, 0.0),
        "time_usec": _usec(b, rows, now_s),
    }


def _targets(b, rows):
    ph = b.ph
    vel_ctrl = ph.ctrl[rows] == CTRL_VEL
    p = np.where(vel_ctrl[:, None], 0.0, ph.target_pos_ned_m[rows] - b.home_ned_m[rows])
    mask = np.where(vel_ctrl, 0b110111000111, 0b110111000000)
    return p, ph.target_vel_ned_m_s[rows], mask


def _position_target_local_ned(b, cores, rows, now_s):
    p, v, mask = _targets(b, rows)
    p, v = _f32(p), _f32(v)
    return {
        "time_boot_ms": _boot_ms(b, rows, now_s),
        "coordinate_frame": mavlink.MAV_FRAME_LOCAL_NED,
        "type_mask": mask,
        "x": p[:, 0],
        "y": p[:, 1],
        "z": p[:, 2],
        "vx": v[:, 0],
        "vy": v[:, 1],
        "vz": v[:, 2],
    }


def _position_target_global_int(b, cores, rows, now_s):
    ph = b.ph
    _, v, mask = _targets(b, rows)
    lat, lon, alt = _kernels.ned_to_geodetic(ph.target_pos_ned_m[rows], *ph.origin_lla)
    v = _f32(v)
    return {
        "time_boot_ms": _boot_ms(b, rows, now_s),
        "coordinate_frame": mavlink.MAV_FRAME_GLOBAL_INT,
        "type_mask": mask,
        "lat_int": _e7(np.asarray(lat)),
        "lon_int": _e7(np.asarray(lon)),
        "alt": _f32(np.asarray(alt)),
        "vx": v[:, 0],
        "vy": v[:, 1],
        "vz": v[:, 2],
    }


def _extended_sys_state(b, cores, rows, now_s):
    ph = b.ph
    landed = ph.landed[rows].tolist()
    vdown = ph.vel_ned_m_s[rows, DOWN].tolist()
    states = []
    for c, lnd, vd in zip(cores, landed, vdown):
        if lnd:
            states.append(mavlink.MAV_LANDED_STATE_ON_GROUND)
        elif vd > 0.2 and c._behaviour in ("land", "rtl"):
            states.append(mavlink.MAV_LANDED_STATE_LANDING)
        elif c._takeoff_target_down_m is not None:
            states.append(mavlink.MAV_LANDED_STATE_TAKEOFF)
        else:
            states.append(mavlink.MAV_LANDED_STATE_IN_AIR)
    return {"vtol_state": mavlink.MAV_VTOL_STATE_MC, "landed_state": states}


def _attitude(b, cores, rows, now_s):
    yaw = [math.atan2(math.sin(y), math.cos(y)) for y in b.ph.yaw_rad[rows].tolist()]
    return {"time_boot_ms": _boot_ms(b, rows, now_s), "yaw": yaw}


def _vfr_hud(b, cores, rows, now_s):
    ph = b.ph
    v = ph.vel_ned_m_s[rows]
    speed = [math.hypot(a, c) for a, c in zip(v[:, NORTH].tolist(), v[:, EAST].tolist())]
    landed = ph.landed[rows].tolist()
    throttle = [0 if lnd or not c.armed else 50 for c, lnd in zip(cores, landed)]
    return {
        "airspeed": speed,
        "groundspeed": speed,
        "heading": _hdg(ph.yaw_rad[rows]) // 100,
        "throttle": throttle,
        "alt": ph.alt_amsl_m[rows],
        "climb": -v[:, DOWN],
    }


def _ekf_status_report(b, cores, rows, now_s):
    r = tm.ESTIMATOR_RATIO
    return {
        "velocity_variance": r,
        "pos_horiz_variance": r,
        "pos_vert_variance": r,
        "compass_variance": r,
        "flags": tm.ESTIMATOR_FLAGS_OK,
    }


def _estimator_status(b, cores, rows, now_s):
    r = tm.ESTIMATOR_RATIO
    return {
        "time_usec": _usec(b, rows, now_s),
        "flags": tm.ESTIMATOR_FLAGS_OK,
        "vel_ratio": r,
        "pos_horiz_ratio": r,
        "pos_vert_ratio": r,
        "mag_ratio": r,
        "pos_horiz_accuracy": 0.5,
        "pos_vert_accuracy": 0.5,
    }


_M = mavlink
#: msg id -> (pymavlink class, vectorised field function).
BATCHED_TYPES = {
    tm.M_HEARTBEAT: (_M.MAVLink_heartbeat_message, _heartbeat),
    tm.M_SYS_STATUS: (_M.MAVLink_sys_status_message, _sys_status),
    tm.M_GLOBAL_POSITION_INT: (_M.MAVLink_global_position_int_message, _global_position_int),
    tm.M_LOCAL_POSITION_NED: (_M.MAVLink_local_position_ned_message, _local_position_ned),
    tm.M_GPS_RAW_INT: (_M.MAVLink_gps_raw_int_message, _gps_raw_int),
    tm.M_HOME_POSITION: (_M.MAVLink_home_position_message, _home_position),
    tm.M_POSITION_TARGET_LOCAL_NED: (
        _M.MAVLink_position_target_local_ned_message,
        _position_target_local_ned,
    ),
    tm.M_POSITION_TARGET_GLOBAL_INT: (
        _M.MAVLink_position_target_global_int_message,
        _position_target_global_int,
    ),
    tm.M_EXTENDED_SYS_STATE: (_M.MAVLink_extended_sys_state_message, _extended_sys_state),
    tm.M_ATTITUDE: (_M.MAVLink_attitude_message, _attitude),
    tm.M_VFR_HUD: (_M.MAVLink_vfr_hud_message, _vfr_hud),
    tm.M_EKF_STATUS_REPORT: (_M.MAVLink_ekf_status_report_message, _ekf_status_report),
    tm.M_ESTIMATOR_STATUS: (_M.MAVLink_estimator_status_message, _estimator_status),
}

_BATCHED_IDS = frozenset(BATCHED_TYPES)

#: Beyond this a value is "absurd" for the vectorised integer paths (yaw in radians, speeds):
#: such vehicles take the reference path, which handles any finite value.
_SANE = 1e9


class BatchTelemetry:
    """Emit the due telemetry of ``cores`` (rows ``core.index`` of one shared physics)."""

    def __init__(self, cores, physics) -> None:
        self.cores = list(cores)
        self.ph = physics
        if any(c.physics is not physics or c.index != i for i, c in enumerate(self.cores)):
            raise ValueError("cores must be rows 0..n-1 of the shared physics, in order")
        self.boot_s = np.array([c._boot_s for c in self.cores])
        self.home_ned_m = np.array([c.home_ned_m for c in self.cores]).reshape(-1, 3)
        self.home_alt_m = np.array([c.home_lla[2] for c in self.cores])
        self.home_e7 = np.array(
            [
                [deg_to_e7(c.home_lla[0]), deg_to_e7(c.home_lla[1]), m_to_mm(c.home_lla[2])]
                for c in self.cores
            ],
            dtype=np.int64,
        ).reshape(-1, 3)
        self.autopilot = np.array([c.pers.autopilot for c in self.cores], dtype=np.int64)
        self.health_extra = np.array(
            [c.pers.sys_status_health_extra for c in self.cores], dtype=np.int64
        )
        self.sysid = np.array([c.sysid for c in self.cores], dtype=np.int64)
        self.compid = np.array([c.compid for c in self.cores], dtype=np.int64)
        #: Earliest due time per vehicle, mirrored by each core's StreamScheduler, so that a
        #: tick visits only the vehicles with something due.
        self.next_any_s = np.full(len(self.cores), np.inf)
        for i, c in enumerate(self.cores):
            c.streams.mirror_into(self.next_any_s, i)
        self.n_batched = 0
        """Frames packed by the batch path so far."""
        self.n_reference = 0
        """Frames of vehicles that took the reference path (signing, non-finite state)."""

    def rebind(self, i: int, core) -> None:
        """Row ``i`` is served by a new ``core`` from now on (a vehicle that booted again)."""
        if core.physics is not self.ph or core.index != i:
            raise ValueError("the new core must be row i of the shared physics")
        self.cores[i] = core
        self.boot_s[i] = core._boot_s
        self.home_ned_m[i] = core.home_ned_m
        self.home_alt_m[i] = core.home_lla[2]
        self.home_e7[i] = (
            deg_to_e7(core.home_lla[0]),
            deg_to_e7(core.home_lla[1]),
            m_to_mm(core.home_lla[2]),
        )
        self.autopilot[i] = core.pers.autopilot
        self.health_extra[i] = core.pers.sys_status_health_extra
        self.sysid[i] = core.sysid
        self.compid[i] = core.compid
        core.streams.mirror_into(self.next_any_s, i)

    def _sane_rows(self) -> np.ndarray:
        ph = self.ph
        with np.errstate(invalid="ignore"):
            ok = (
                np.isfinite(ph.pos_ned_m).all(axis=1)
                & np.isfinite(ph.vel_ned_m_s).all(axis=1)
                & np.isfinite(ph.target_pos_ned_m).all(axis=1)
                & np.isfinite(ph.target_vel_ned_m_s).all(axis=1)
                & np.isfinite(ph.lat_deg)
                & np.isfinite(ph.lon_deg)
                & np.isfinite(ph.alt_amsl_m)
                & np.isfinite(ph.yaw_rad)
                & np.isfinite(ph.battery_frac)
                & (np.abs(ph.yaw_rad) < _SANE)
                & (np.abs(ph.vel_ned_m_s) < _SANE).all(axis=1)
                & (np.abs(ph.alt_amsl_m) < _SANE)
            )
        return ok

    @staticmethod
    def _one(core, msg_id: int, seq: int, now_s: float) -> bytes:
        """One frame by the reference builder with a reserved sequence number (b"" and a
        counted telemetry error if the builder fails, as in the reference path)."""
        try:
            msg = tm.BUILDERS[msg_id](core, now_s)
        except Exception:  # noqa: BLE001
            core.stats.telemetry_errors += 1
            return b""
        mav = core._codec._mav
        saved, mav.seq = mav.seq, seq
        try:
            return bytes(msg.pack(mav))
        finally:
            mav.seq = saved

    def emit(self, now_s: float) -> None:
        """Everything due at ``now_s``, for every live core (their ``emit_telemetry``)."""
        sane = None
        #: msg id -> (core, row, output slot, sequence number) of each frame, in reservation
        #: order.
        jobs: dict[int, list[tuple]] = {}
        batched = BATCHED_TYPES
        builders = tm.BUILDERS
        cores_all = self.cores
        for i in np.flatnonzero(self.next_any_s <= now_s + 1e-9).tolist():
            core = cores_all[i]
            if not core.alive:
                self.next_any_s[i] = np.inf  # silent forever
                continue
            streams = core.streams
            if sane is None:
                sane = self._sane_rows().tolist()
            codec = core._codec
            if codec.signing_enabled or not sane[core.index]:
                n0 = core.stats.messages_out
                core.emit_telemetry(now_s)
                self.n_reference += core.stats.messages_out - n0
                continue
            due = streams.due(now_s)
            if not due:
                continue
            out = core._out
            if _BATCHED_IDS.issuperset(due):
                # Every frame packed below: a slot and a sequence number each, in due order
                # (take_seq(n) reserves what n take_seq(1) would, one after the other).
                slot = len(out)
                seq = codec.take_seq(len(due))
                row = core.index
                for msg_id in due:
                    job = jobs.get(msg_id)
                    if job is None:
                        job = jobs[msg_id] = []
                    job.append((core, row, slot, seq))
                    slot += 1
                    seq = (seq + 1) & 0xFF
                out.extend([None] * len(due))
                if core._out_dirty is not None:
                    core._out_dirty.add(row)
                continue
            for msg_id in due:
                if msg_id in batched:
                    job = jobs.get(msg_id)
                    if job is None:
                        job = jobs[msg_id] = []
                    job.append((core, core.index, len(out), codec.take_seq(1)))
                    out.append(None)
                    if core._out_dirty is not None:
                        core._out_dirty.add(core.index)
                    continue
                try:
                    core._send(builders[msg_id](core, now_s))
                except Exception:  # noqa: BLE001 - as VehicleCore.emit_telemetry
                    core.stats.telemetry_errors += 1
                    core._warn_limited(
                        now_s,
                        f"telemetry:{msg_id}",
                        "sysid %d: building message %d failed",
                        core.sysid,
                        msg_id,
                        exc_info=True,
                    )
        for msg_id, job in jobs.items():
            cores, row_list, slots, seq_list = zip(*job)
            cls, fields_fn = batched[msg_id]
            rows = np.array(row_list, dtype=np.intp)
            seq = np.array(seq_list, dtype=np.int64)
            try:
                frames = pack_frames(
                    cls,
                    fields_fn(self, cores, rows, now_s),
                    seq,
                    self.sysid[rows],
                    self.compid[rows],
                )
            except Exception:  # noqa: BLE001 - never lose a tick: pack these the slow way
                log.exception(
                    "batched %s failed; packing %d frames one by one", cls.msgname, len(cores)
                )
                frames = [self._one(core, msg_id, s, now_s) for core, s in zip(cores, seq_list)]
            for core, slot, frame in zip(cores, slots, frames):
                core._out[slot] = frame
                st = core.stats
                st.messages_out += 1
                st.bytes_out += len(frame)
            self.n_batched += len(frames)

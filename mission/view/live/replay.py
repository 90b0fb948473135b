"""The live page for a recorded run: the station's belief rebuilt from the run directory.

What is read (a ``phireman fly`` run directory):

* ``events.jsonl`` - the station's link events (discovered, lost, recovered, mode, armed, home,
  status texts, command failures, live crew positions) and operator actions;
* ``flight.tlog`` - every frame in and out: GLOBAL_POSITION_INT of every vehicle (positions,
  velocity, heading; parsed with pymavlink) and the station's SET_POSITION_TARGET_GLOBAL_INT
  (the planned targets);
* ``metrics.csv`` - one row per control tick: mission start, TU1/TU2 so far, crews connected,
  networked vehicles;
* ``mission.yaml`` and ``run.json`` (seed) - base, crews (tracks redrawn from the seed, live crews
  from their recorded positions), hazard zones, geofence, radio ranges;
* ``rotation.jsonl`` (a flight with batteries) - the relay rotation's state when it changed and
  its events: the rotation panel (:mod:`mission.view.live.rotation`);
* ``truth.npz`` (emulated runs) - only for the optional "emulator truth" layer.

The same :class:`gcs.fleet.FleetView` the station used folds these events again, so each frame
is what the station believed at that instant. Times: the .tlog is stamped ``core time + offset``
(:class:`gcs.aio.StationAdapter`); the offset is recovered from the first HEARTBEAT of each
vehicle against its VehicleDiscovered event (same instant by construction).

Limits: the .tlog does not record which link a frame came on; a run with several links whose
vehicles share sysids (more than 254 emulated vehicles) is replayed per sysid, the position
going to the first link that discovered that sysid. The planner's task tree is not recorded:
replay draws the minimum spanning tree of base, crews and networked vehicles.
"""

from __future__ import annotations

import bisect
import csv
import dataclasses
import json
import logging
import math
import struct
from pathlib import Path
from typing import Any

import numpy as np

from gcs import events as gcs_events
from gcs.control import layer_alt_m
from gcs.fleet import FleetSnapshot, FleetView, MissionOrigin
from gcs.link_discovery import sys_status_battery
from gcs.link_health import health_event
from gcs.link_quality import SeqCounter
from gcs.operations.config import OVERRIDE, OVERRIDE_REFUSED, override_label
from gcs.wire import mavlink
from mission.view.live.alerts import DEFAULT_BATTERY_LOW_FRAC
from mission.view.live.health import LOSS_WINDOW_S, health_columns, minutes_to_reserve
from mission.flight.run_dir import ROTATION_FILE, read_rotation
from mission.view.live.rotation import MAX_EVENTS, rotation_frame
from mission.view.live.server import TruthUnavailable
from mission.view.live.state import Picture, classify, frame_dict, mission_meta, mst_tree
from mission.view.live.terrain import TerrainView
from planner.geometry import geodetic_to_ned_m

__all__ = ["ReplaySource", "frame_index", "load_replay", "read_metrics"]

log = logging.getLogger(__name__)

_STAMP = struct.Struct(">Q")
_POS, _TARGET, _HB = (
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT,
    mavlink.MAVLINK_MSG_ID_HEARTBEAT,
)
#: Health reports read from the .tlog (gcs.link_health's messages).
_HEALTH_IDS = frozenset(
    getattr(mavlink, f"MAVLINK_MSG_ID_{m}")
    for m in ("GPS_RAW_INT", "SYS_STATUS", "EKF_STATUS_REPORT", "ESTIMATOR_STATUS", "RADIO_STATUS")
)
_KEEP = frozenset((_POS, _TARGET, _HB)) | _HEALTH_IDS
_SYS_STATUS = mavlink.MAVLINK_MSG_ID_SYS_STATUS
#: A target not re-sent for this long (core seconds) is no longer shown (ArduPilot 1 s re-send).
TARGET_STALE_S = 3.0
MAX_FRAMES = 1500


def read_tlog(path: Path, gcs_sysid: int = 255, loss: dict | None = None):
    """(stamp_s, src sysid, src compid, msg) of the HEARTBEAT, GLOBAL_POSITION_INT,
    SET_POSITION_TARGET_GLOBAL_INT and health frames (GPS_RAW_INT, SYS_STATUS, EKF_STATUS_REPORT,
    ESTIMATOR_STATUS, RADIO_STATUS) of a .tlog (others are skipped undecoded).

    ``loss``: filled with sysid -> [(stamp_s, loss fraction or None)], the packet loss of each
    vehicle's autopilot frames (every message, decoded or not) over windows of
    :data:`mission.view.live.station.LOSS_WINDOW_S`, as the live view shows it."""
    counters: dict[int, SeqCounter] = {}
    window_end: dict[int, float] = {}
    raw = Path(path).read_bytes()
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    out, off, n = [], 0, len(raw)
    while off + 10 <= n:
        stamp = _STAMP.unpack_from(raw, off)[0] / 1e6
        i = off + 8
        magic, ln = raw[i], raw[i + 1]
        if magic == 0xFD:
            total = ln + 12 + (13 if raw[i + 2] & 1 else 0)
            seq, sysid, compid = raw[i + 4], raw[i + 5], raw[i + 6]
            msgid = raw[i + 7] | raw[i + 8] << 8 | raw[i + 9] << 16
        elif magic == 0xFE:
            total = ln + 8
            seq, sysid, compid, msgid = raw[i + 2], raw[i + 3], raw[i + 4], raw[i + 5]
        else:  # not a frame start: the file is damaged; resynchronise on the next byte
            off += 1
            continue
        frame = raw[i : i + total]
        off = i + total
        if loss is not None and compid == 1 and sysid != gcs_sysid and len(frame) == total:
            c = counters.get(sysid)
            if c is None:
                c = counters[sysid] = SeqCounter()
                window_end[sysid] = stamp + LOSS_WINDOW_S
            c.update(seq)
            if stamp >= window_end[sysid]:
                loss.setdefault(sysid, []).append((stamp, c.take_window()))
                window_end[sysid] = stamp + LOSS_WINDOW_S
        if msgid not in _KEEP or len(frame) < total:
            continue
        if msgid == _TARGET and sysid != gcs_sysid:
            continue
        try:
            msg = mav.decode(bytearray(frame))
        except Exception:  # noqa: BLE001 - a bad frame in a log is skipped
            continue
        out.append((stamp, sysid, compid, msg))
    return out


def _health_event(link_id: int, sysid: int, t_s: float, msg, battery: bool = False):
    """The station's event of one recorded health frame (gcs.link_health.health_event; with
    ``battery`` the BatteryReceived of a SYS_STATUS instead), None if it is not valid."""
    try:
        if battery:
            return sys_status_battery(link_id, sysid, t_s, msg)
        return health_event(link_id, sysid, t_s, msg)
    except (ValueError, KeyError):
        return None


def _event_from_record(rec: dict):
    cls = getattr(gcs_events, rec.get("type", ""), None)
    if cls is None or not isinstance(cls, type) or not issubclass(cls, gcs_events.Event):
        return None
    names = {f.name for f in dataclasses.fields(cls)}
    kw: dict[str, Any] = {
        k: (tuple(v) if isinstance(v, list) else v) for k, v in rec.items() if k in names
    }
    try:
        return cls(**kw)
    except (TypeError, ValueError):
        return None


def frame_index(index: int | None, n_frames: int) -> int:
    """A replay's frame ``index`` checked against its ``n_frames`` (None: the last).

    Raises IndexError out of range (the page's 400)."""
    if index is None:
        index = n_frames - 1
    if not 0 <= index < n_frames:
        raise IndexError(f"frame {index} out of range 0..{n_frames - 1}")
    return index


def read_metrics(path: Path) -> list[dict]:
    """The rows of a run's ``metrics.csv`` as floats (None where empty); [] without the file."""
    if not path.is_file():
        return []
    rows = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            try:
                rows.append({k: (float(v) if v not in ("", None) else None) for k, v in r.items()})
            except ValueError:
                continue
    return rows


@dataclasses.dataclass
class _Frame:
    t_s: float
    snap: FleetSnapshot
    hdg_deg: np.ndarray
    target_ned_m: np.ndarray
    released: dict
    reclaimed: set


class ReplaySource:
    """Frames of a recorded run (see the module docstring); :meth:`frame` by index."""

    tiles: dict | None  # set by the replay command (--tiles); read with getattr

    def __init__(self, run_dir: Path, *, dt_s: float = 0.5) -> None:
        from mission.format.load import load_mission
        from mission.flight.runners import control_config, live_task_columns, mission_scenario

        self.run_dir = run_dir = Path(run_dir)
        for need in ("mission.yaml", "events.jsonl", "flight.tlog"):
            if not (run_dir / need).is_file():
                raise FileNotFoundError(
                    f"{run_dir}: no {need} (a 'phireman fly' run directory "
                    "has mission.yaml, events.jsonl, flight.tlog, metrics.csv)"
                )
        self.mission = mission = load_mission(run_dir / "mission.yaml")
        self.terrain = TerrainView.of_mission(mission)
        meta = (
            json.loads((run_dir / "run.json").read_text())
            if (run_dir / "run.json").is_file()
            else {}
        )
        self.seed = int(meta.get("seed", mission.run.seed))
        self.scenario = mission_scenario(mission, self.seed, live_tasks=True)
        self.control = control_config(mission, self.scenario)
        self.live_cols = {sysid: col for col, sysid in live_task_columns(mission).items()}
        o = mission.origin
        self.origin = MissionOrigin(o.lat_deg, o.lon_deg, o.alt_amsl_m)
        battery = mission.endurance.battery
        self._reserve_frac = battery.low_frac if battery is not None else DEFAULT_BATTERY_LOW_FRAC
        records = [
            json.loads(line)
            for line in (run_dir / "events.jsonl").read_text().splitlines()
            if line.strip()
        ]
        # The alerts the live page raised and who acknowledged them (mission.view.live.alerts).
        self._alerts = [r for r in records if r.get("type") == "AlertRaised"]
        self._acks = {
            int(r["alert_id"]): float(r["t_s"])
            for r in records
            if r.get("type") == "AlertAcknowledged"
        }
        self.metrics = read_metrics(run_dir / "metrics.csv")
        self.t0_s = (
            self.metrics[0]["t_s"] - self.metrics[0]["t_mission_s"] if self.metrics else None
        )
        self.duration_s = (
            float(meta.get("options", {}).get("duration_s") or 0) or mission.run.duration_s
        )
        self.end_action = meta.get("options", {}).get("end")
        self._loss: dict[int, list] = {}
        tlog = read_tlog(run_dir / "flight.tlog", loss=self._loss)
        self._build(records, tlog, dt_s)
        self.rotation = self._read_rotation(run_dir / ROTATION_FILE)
        self.truth = self._read_truth(run_dir / "truth.npz")

    # ------------------------------------------------------------------ loading

    @staticmethod
    def _read_rotation(path: Path) -> list[dict] | None:
        """``rotation.jsonl`` (a flight with batteries; None without): its lines in time order,
        each with its whole state (:func:`mission.flight.run_dir.read_rotation` applies the
        lines that carry only what changed) and the number of events recorded up to it
        (``n_events``) into ``events``, one list for the whole file."""
        if not path.is_file():
            return None
        lines: list[dict] = []
        events: list[dict] = []
        for t_s, state, new in read_rotation(path):
            events.extend(new)
            lines.append({"t_s": t_s, "state": state, "events": events, "n_events": len(events)})
        return lines

    def _rotation_at(self, snap, t_s: float) -> dict | None:
        """The frame's ``rotation`` key at ``t_s``: the last recorded state at or before it."""
        if not self.rotation:
            return None
        k = bisect.bisect_right([r["t_s"] for r in self.rotation], t_s + 1e-9) - 1
        if k < 0:
            return None
        rec = self.rotation[k]
        n = rec["n_events"]
        events = rec["events"][max(0, n - MAX_EVENTS) : n]
        return rotation_frame(rec["state"], events, snap, t_s, self.t0_s)

    def _read_truth(self, path: Path):
        if not path.is_file():
            return None
        try:
            z = np.load(path)
            return {"t_s": z["t_s"], "pos": z["pos_ned_m"][..., :2], "alive": z["alive"]}
        except (KeyError, OSError, ValueError):
            return None

    def _build(self, records: list[dict], tlog, dt_s: float) -> None:
        evs, actions = [], []
        link_of: dict[int, int] = {}
        first_disc: dict[int, float] = {}
        for rec in records:
            if rec.get("type") == "OperatorAction":
                actions.append(rec)
                continue
            ev = _event_from_record(rec)
            if ev is None:
                continue
            evs.append(ev)
            if isinstance(ev, gcs_events.VehicleDiscovered):
                if ev.sysid in link_of and link_of[ev.sysid] != ev.link_id:
                    log.warning(
                        "replay: sysid %d on links %d and %d; positions go to link %d",
                        ev.sysid,
                        link_of[ev.sysid],
                        ev.link_id,
                        link_of[ev.sysid],
                    )
                link_of.setdefault(ev.sysid, ev.link_id)
                first_disc.setdefault(ev.sysid, ev.t_s)
        # tlog stamp offset: first HEARTBEAT of a vehicle <-> its VehicleDiscovered event.
        first_hb: dict[int, float] = {}
        for stamp, sysid, _compid, msg in tlog:
            if msg.get_msgId() == _HB and sysid in first_disc and sysid not in first_hb:
                first_hb[sysid] = stamp
        diffs = [first_hb[s] - first_disc[s] for s in first_hb]
        self.offset_s = float(np.median(diffs)) if diffs else (tlog[0][0] if tlog else 0.0)
        tel: list[gcs_events.Event] = []
        battery_recorded = any(isinstance(e, gcs_events.BatteryReceived) for e in evs)
        targets: dict = {}
        for stamp, sysid, compid, msg in tlog:
            t = stamp - self.offset_s
            mid = msg.get_msgId()
            if mid == _POS and sysid in link_of and compid == 1:
                if msg.lat == 0 and msg.lon == 0:
                    continue
                try:
                    tel.append(
                        gcs_events.TelemetryReceived(
                            link_of[sysid],
                            sysid,
                            t,
                            lat_deg=msg.lat / 1e7,
                            lon_deg=msg.lon / 1e7,
                            alt_amsl_m=msg.alt / 1000.0,
                            rel_alt_m=msg.relative_alt / 1000.0,
                            vel_ned_m_s=(msg.vx / 100.0, msg.vy / 100.0, msg.vz / 100.0),
                            yaw_rad=None if msg.hdg == 65535 else math.radians(msg.hdg / 100.0),
                            time_boot_s=msg.time_boot_ms / 1000.0,
                        )
                    )
                except ValueError:
                    continue
            elif mid in _HEALTH_IDS and sysid in link_of:
                hev = _health_event(link_of[sysid], sysid, t, msg)
                if hev is not None:
                    tel.append(hev)
                if mid == _SYS_STATUS and not battery_recorded:
                    # No BatteryReceived in events.jsonl (a mission without batteries): the
                    # live page's battery came from these SYS_STATUS frames.
                    bev = _health_event(link_of[sysid], sysid, t, msg, battery=True)
                    if bev is not None:
                        tel.append(bev)
            elif mid == _TARGET:
                targets.setdefault(msg.target_system, []).append(
                    (
                        t,
                        msg.lat_int / 1e7,
                        msg.lon_int / 1e7,
                        float(msg.alt),
                        int(msg.coordinate_frame),
                    )
                )
        self._targets = {s: (np.array([x[0] for x in v]), v) for s, v in targets.items()}
        stream = sorted(
            [(e.t_s, 0, k, e) for k, e in enumerate(evs)]
            + [(e.t_s, 1, k, e) for k, e in enumerate(tel)],
            key=lambda x: x[:3],
        )
        self.events = evs
        self.actions = actions
        t_first = stream[0][0] if stream else 0.0
        t_last = stream[-1][0] if stream else 0.0
        dt = max(dt_s, (t_last - t_first) / MAX_FRAMES)
        # The grid, plus a frame at every control tick (metrics.csv t_s): the slider can stand
        # on the very instant a metrics row was taken, so the page shows what the station
        # believed then (a grid frame up to dt earlier can precede a change the tick saw).
        ticks = [r["t_s"] for r in self.metrics if r.get("t_s") is not None]
        times = np.unique(
            np.concatenate([np.arange(t_first, t_last + dt, dt), np.asarray(ticks, dtype=float)])
        )
        fleet = FleetView(self.origin, timeout_s=2.0)  # mission.flight.runners.PLAN_SILENCE_S
        yaw: dict[tuple[int, int], float] = {}
        released: dict[tuple[int, int], str] = {}
        reclaimed: set = set()
        was_returning: set = set()
        act_t = sorted(actions, key=lambda a: a["t_s"])
        k = a = 0
        self.frames: list[_Frame] = []
        for t in times:
            while k < len(stream) and stream[k][0] <= t:
                ev = stream[k][3]
                fleet.apply(ev)
                if isinstance(ev, gcs_events.TelemetryReceived) and ev.yaw_rad is not None:
                    yaw[(ev.link_id, ev.sysid)] = math.degrees(ev.yaw_rad) % 360.0
                k += 1
            while a < len(act_t) and act_t[a]["t_s"] <= t:
                r = act_t[a]
                vid = (int(r["link_id"]), int(r["sysid"]))
                if r["action"] == "rejoin":
                    released.pop(vid, None)
                elif r["action"] == OVERRIDE:  # a forwarded client took it: say who
                    released[vid] = override_label(r.get("source", "?"), r.get("result", ""))
                elif r["action"] == "confirm_swap":
                    pass  # the rotation's bookkeeping (rotation.jsonl), not the plan's
                elif r["action"] != OVERRIDE_REFUSED:  # a refusal leaves it in the plan
                    released[vid] = r["action"]
                a += 1
            snap = fleet.snapshot(float(t))
            vids = list(zip(snap.link_id.tolist(), snap.sysid_of_index.tolist()))
            for i, v in enumerate(vids):  # reclaimed: back in the plan after a failsafe return
                if snap.returning[i]:
                    was_returning.add(v)
                elif v in was_returning and snap.networked[i] and snap.armed[i]:
                    reclaimed.add(v)
            hdg = np.array([yaw.get(v, math.nan) for v in vids], dtype=float)
            self.frames.append(
                _Frame(
                    float(t),
                    snap,
                    hdg,
                    self._targets_at(snap, float(t)),
                    dict(released),
                    set(reclaimed),
                )
            )
        self.times_s = [f.t_s for f in self.frames]

    def _targets_at(self, snap, t: float) -> np.ndarray:
        n = snap.n_vehicles
        out = np.full((n, 3), np.nan)
        o = self.origin
        for i, s in enumerate(snap.sysid_of_index.tolist()):
            got = self._targets.get(s)
            if got is None:
                continue
            ts, rows = got
            j = bisect.bisect_right(ts, t) - 1
            if j < 0 or t - ts[j] > TARGET_STALE_S:
                continue
            _, lat, lon, alt, frame = rows[j]
            ned = geodetic_to_ned_m(lat, lon, o.alt_amsl_m, o.lat_deg, o.lon_deg, o.alt_amsl_m)
            if frame == mavlink.MAV_FRAME_GLOBAL_INT:  # AMSL (PX4)
                down = -(alt - o.alt_amsl_m)
            else:  # relative to the vehicle's home
                home = snap.home_amsl_m[i]
                down = -(alt + (home - o.alt_amsl_m if math.isfinite(home) else 0.0))
            out[i] = (float(ned[0]), float(ned[1]), down)
        return out

    # ------------------------------------------------------------------ reading

    def t_mission(self, t_s: float) -> float | None:
        return None if self.t0_s is None else t_s - self.t0_s

    def crews_at(self, t_s: float) -> np.ndarray:
        tm = self.t_mission(t_s)
        crews = np.array(self.scenario.task_pos_m(max(0.0, tm or 0.0)), dtype=float)
        if self.live_cols:
            o = self.origin
            for ev in self.events:
                if ev.t_s > t_s:
                    break
                if isinstance(ev, gcs_events.TaskPositionReceived) and ev.sysid in self.live_cols:
                    ned = geodetic_to_ned_m(
                        ev.lat_deg, ev.lon_deg, o.alt_amsl_m, o.lat_deg, o.lon_deg, o.alt_amsl_m
                    )
                    crews[self.live_cols[ev.sysid]] = ned[:2]
        return crews

    def meta(self) -> dict:
        m = mission_meta(
            self.mission,
            self.control.geofence,
            mode="replay",
            actions=False,
            tiles=getattr(self, "tiles", None),
            duration_s=self.duration_s,
            end_action=self.end_action,
        )
        m["replay"] = {
            "t": [
                None if (tm := self.t_mission(t)) is None else round(tm, 2) for t in self.times_s
            ],
            "run_dir": str(self.run_dir),
            "has_truth": self.truth is not None,
        }
        # before the mission start the slider shows core time relative to the start
        if self.t0_s is not None:
            m["replay"]["t"] = [round(t - self.t0_s, 2) for t in self.times_s]
        else:
            m["replay"]["t"] = [round(t, 2) for t in self.times_s]
        return m

    def index_at(self, t_mission_s: float) -> int:
        """The frame at (or just before) mission time ``t_mission_s``."""
        t = t_mission_s + (self.t0_s or 0.0)
        return max(0, bisect.bisect_right(self.times_s, t + 1e-9) - 1)

    def tick_index(self, k: int) -> int:
        """The frame taken at the instant of metrics row ``k`` (every control tick has one)."""
        t = self.metrics[k]["t_s"]
        i = bisect.bisect_left(self.times_s, t)
        if i >= len(self.times_s) or self.times_s[i] != t:
            raise LookupError(f"no frame at tick {k} (t_s {t})")
        return i

    def phase_at(self, t_s: float) -> str:
        if self.t0_s is None or t_s < self.t0_s:
            return "launch"
        last = self.metrics[-1]["t_s"] if self.metrics else self.t0_s
        return "run" if t_s <= last + 1e-6 else "end"

    def frame(self, index: int | None = None, truth: bool = False) -> dict:
        """Frame ``index`` (default: the last); ``truth`` adds the emulator's truth layer.

        Raises
        ------
        IndexError
            ``index`` out of range.
        TruthUnavailable
            ``truth`` for a run without ``truth.npz`` (real vehicles), as on the live view.
        """
        if truth and (self.truth is None or not len(self.truth["t_s"])):
            raise TruthUnavailable(
                f"no emulator truth in {self.run_dir} (no truth.npz: a run with real vehicles)"
            )
        fr = self.frames[frame_index(index, len(self.frames))]
        snap, t = fr.snap, fr.t_s
        n = snap.n_vehicles
        states = classify(snap, fr.released, fr.reclaimed)
        crews = self.crews_at(t)
        relay = snap.networked & snap.has_position & (states == "networked")
        tree = mst_tree(np.zeros(2), crews, snap.pos_ned_m[relay, :2])
        upto = [r for r in self.metrics if r["t_s"] <= t + 1e-6]
        last = upto[-1] if upto else None
        series = {
            "t": [round(r["t_mission_s"], 1) for r in self.metrics],
            "crews": [int(r["tasks_covered"]) for r in self.metrics],
            "networked": [int(r["networked"]) for r in self.metrics],
            "lost": [int(r["lost"]) for r in self.metrics],
        }
        tm = self.t_mission(t)
        tracks = None
        if tm is not None and tm > 0:
            ts = np.arange(0.0, tm + 1e-9, 2.0)
            pts = np.array([self.scenario.task_pos_m(x) for x in ts])  # (K, M, 2)
            tracks = [
                [[round(a, 1), round(b, 1)] for a, b in pts[:, k].tolist() if math.isfinite(a)]
                for k in range(pts.shape[1])
            ]
        pic = Picture(
            t_s=t,
            t_mission_s=tm,
            phase=self.phase_at(t),
            snap=snap,
            states=states,
            heading_deg=fr.hdg_deg,
            target_ned_m=fr.target_ned_m,
            layer_alt_m=layer_alt_m(np.arange(n), self.control) if n else np.zeros(0),
            n_layers=self.control.n_layers,
            crews_ne_m=crews,
            tree=tree,
            tu1=None if last is None else last["tu1_so_far"],
            tu2=None if last is None else last["tu2_so_far"],
            series=series,
            events=self._events_until(t),
            crew_tracks=tracks,
            truth=self._truth_at(t) if truth else None,
            released=fr.released,
            health=health_columns(
                snap,
                self.origin,
                t,
                loss_frac=[self._loss_at(int(s), t) for s in snap.sysid_of_index.tolist()],
                reserve_min=minutes_to_reserve(
                    snap.battery_frac if snap.battery_frac is not None else np.full(n, np.nan),
                    snap.drain_per_s if snap.drain_per_s is not None else np.full(n, np.nan),
                    self._reserve_frac,
                ),
            ),
            rotation=self._rotation_at(snap, t),
        )
        frame = frame_dict(
            pic, self.mission.radio.range_m, self.mission.radio.base_range_m, terrain=self.terrain
        )
        frame["alerts"] = self._alerts_at(t)
        return frame

    def _alerts_at(self, t_s: float) -> dict:
        """The alerts raised by ``t_s`` (recorded), open until their recorded acknowledgement."""
        rows = []
        for r in self._alerts:
            if r["t_s"] > t_s + 1e-6:
                continue
            acked = self._acks.get(int(r["alert_id"]), math.inf) <= t_s + 1e-6
            rows.append(
                {
                    "id": int(r["alert_id"]),
                    "kind": r["kind"],
                    "subject": r["subject"],
                    "text": r["text"],
                    "t_s": round(float(r["t_s"]), 1),
                    "cleared": False,
                    "acked": acked,
                }
            )
        return {
            "open": [a for a in rows if not a["acked"]],
            "recent": rows[::-1][:20],
        }

    def _loss_at(self, sysid: int, t_s: float) -> float | None:
        """The packet loss of the last window closed at core time ``t_s`` (None: none yet)."""
        wins = self._loss.get(sysid)
        if not wins:
            return None
        k = bisect.bisect_right([w[0] for w in wins], t_s + self.offset_s) - 1
        return wins[k][1] if k >= 0 else None

    def _events_until(self, t_s: float, limit: int = 60) -> list[dict]:
        from mission.view.live.station import event_entry

        out = []
        for ev in self.events:
            if ev.t_s > t_s:
                break
            e = event_entry(ev)
            if e is not None:
                out.append((ev.t_s, e[0], (ev.link_id, ev.sysid), e[1]))
        for r in self.actions:
            if r["t_s"] <= t_s:
                out.append(
                    (
                        r["t_s"],
                        "action",
                        (r["link_id"], r["sysid"]),
                        f"operator {r['action'].upper()} from {r['source']}: {r['result']}",
                    )
                )
        out.sort(key=lambda x: x[0])
        res = []
        for k, (t, kind, vid, text) in enumerate(out[-limit:]):
            who = f"vehicle {vid[1]}" if vid[0] == 0 else f"vehicle {vid[0]}:{vid[1]}"
            tm = self.t_mission(t)
            res.append(
                {
                    "seq": k,
                    "t_s": round(t, 1),
                    "t_mission_s": None if tm is None else round(tm, 1),
                    "kind": kind,
                    "vehicle": f"{vid[0]}:{vid[1]}",
                    "text": f"{who} {text}",
                }
            )
        return res

    def _truth_at(self, t_s: float) -> dict | None:
        tr = self.truth
        if tr is None or not len(tr["t_s"]):
            return None
        j = int(np.clip(np.searchsorted(tr["t_s"], t_s), 0, len(tr["t_s"]) - 1))
        pos = tr["pos"][j]
        return {
            "n": np.round(pos[:, 0], 1).tolist(),
            "e": np.round(pos[:, 1], 1).tolist(),
            "alive": tr["alive"][j].astype(bool).tolist(),
        }


def load_replay(run_dir, **kw) -> ReplaySource:
    return ReplaySource(Path(run_dir), **kw)

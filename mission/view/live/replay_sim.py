"""The live page for an in-process run: ``phireman sim --mission M --out DIR`` then
``phireman replay DIR --serve PORT``.

An in-process run has no station and no MAVLink log: its run directory holds the world's truth
(``truth.npz``: positions, heights AMSL over terrain, alive, networked, crews and which are
connected), the planner's trees (``trees.json``), ``metrics.csv`` (TU1 / TU2 so far) and the
mission. Each frame is that truth drawn as the station would draw its belief: a drone alive is
heard where it is (``networked`` on the page), a drone attrited is ``lost`` where it fell. With
terrain (docs/terrain.md) the links carry their status and the page has the relief and link
profiles (:mod:`mission.view.live.terrain`), the picture of a terrain mission that ``phireman fly``
cannot fly yet.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from gcs.fleet import FleetSnapshot
from mission.view.live.replay import frame_index, read_metrics
from mission.view.live.state import Picture, classify, decimate, frame_dict, mission_meta
from mission.view.live.terrain import TerrainView

__all__ = ["SimReplaySource", "is_sim_run"]

#: HEARTBEAT.autopilot of ArduPilot (MAV_AUTOPILOT_ARDUPILOTMEGA): the page names its modes.
_ARDUPILOT = 3


def is_sim_run(run_dir: Path) -> bool:
    """A run directory of ``phireman sim --mission`` (truth, no MAVLink log)."""
    run_dir = Path(run_dir)
    return (run_dir / "truth.npz").is_file() and not (run_dir / "flight.tlog").is_file()


class SimReplaySource:
    """Frames of an in-process run directory (see the module docstring), by index."""

    tiles: dict | None = None  # set by the replay command (--tiles)

    def __init__(self, run_dir: Path) -> None:
        from mission.format.scenario import control_config
        from mission.view.replay import load_run

        self.run_dir = run_dir = Path(run_dir)
        run = load_run(run_dir)
        if run.mission is None:
            raise FileNotFoundError(f"{run_dir}: no mission.yaml (the page needs the mission)")
        self.run, self.mission = run, run.mission
        self.control = control_config(run.mission)
        self.terrain = TerrainView.of_mission(run.mission)
        z = np.load(run_dir / "truth.npz")
        n_t, n = run.pos_m.shape[:2]
        base_alt = run.mission.origin.alt_amsl_m
        self.alt_amsl_m = (
            np.asarray(z["alt_amsl_m"], dtype=float)[:n_t]
            if "alt_amsl_m" in z
            else np.full((n_t, n), base_alt + run.mission.vehicles.limits.cruise_alt_m)
        )
        self.metrics = read_metrics(run_dir / "metrics.csv")
        losses = (
            [json.loads(x) for x in (run_dir / "events.jsonl").read_text().splitlines() if x]
            if (run_dir / "events.jsonl").is_file()
            else []
        )
        self.losses = [e for e in losses if e.get("event") == "vehicle_lost"]
        keep = decimate(list(range(n_t)), 1500)
        self.index = keep
        ks = np.asarray(keep)
        self.series = {
            "t": np.round(run.t_s[ks], 1).tolist(),
            "crews": run.connected[ks].sum(axis=1).astype(int).tolist(),
            "networked": (run.alive & run.active)[ks].sum(axis=1).astype(int).tolist(),
            "lost": (~run.alive[ks]).sum(axis=1).astype(int).tolist(),
        }

    def meta(self) -> dict:
        m = mission_meta(
            self.mission,
            self.control.geofence,
            mode="replay",
            actions=False,
            tiles=self.tiles,
            duration_s=self.mission.run.duration_s,
        )
        m["replay"] = {
            "t": [round(float(self.run.t_s[k]), 2) for k in self.index],
            "run_dir": str(self.run_dir),
            "has_truth": False,
        }
        return m

    def frame(self, index: int | None = None, truth: bool = False) -> dict:
        """Frame ``index`` (default: the last). ``truth`` is refused: every frame is the truth.

        Raises
        ------
        IndexError
            ``index`` out of range.
        TruthUnavailable
            ``truth``: an in-process run has no station belief beside its truth.
        """
        from mission.view.live.server import TruthUnavailable

        if truth:
            raise TruthUnavailable(
                f"{self.run_dir} is an in-process run: every frame is already the truth"
            )
        index = frame_index(index, len(self.index))
        k = self.index[index]
        run, mission = self.run, self.mission
        t = float(run.t_s[k])
        n = run.pos_m.shape[1]
        alive = run.alive[k].astype(bool)
        pos = np.column_stack(
            [run.pos_m[k], mission.origin.alt_amsl_m - self.alt_amsl_m[k]]
        )  # NED about the base, as the station holds it
        snap = FleetSnapshot(
            t_s=t,
            link_id=np.zeros(n, dtype=int),
            sysid_of_index=np.arange(1, n + 1),
            pos_ned_m=pos,
            vel_ned_m_s=np.zeros((n, 3)),
            has_position=np.ones(n, dtype=bool),
            home_amsl_m=np.full(n, mission.origin.alt_amsl_m),
            last_heard_s=np.full(n, t),
            networked=alive & run.active[k].astype(bool),
            lost=~alive,
            returning=np.zeros(n, dtype=bool),
            armed=alive,
            custom_mode=np.full(n, 4),
            autopilot=np.full(n, _ARDUPILOT),
            mode=tuple("GUIDED" if a else "" for a in alive),
        )
        states = classify(snap, {}, set())
        from mission.view.replay import tree_at

        tr = tree_at(run, k)
        tree = {
            "nodes": np.round(np.asarray(tr.nodes_m, dtype=float), 1).tolist(),
            "parent": np.asarray(tr.parent).tolist(),
            "n_tasks": int(tr.n_tasks),
            "source": "the planner's task tree (recorded)"
            if run.trees
            else "semi-Steiner tree rebuilt from the crews' positions",
        }
        row = self.metrics[min(k, len(self.metrics) - 1)] if self.metrics else None
        upto = index + 1
        series = {key: v[:upto] for key, v in self.series.items()}
        pic = Picture(
            t_s=t,
            t_mission_s=t,
            phase="run" if t <= mission.run.duration_s + 1e-6 else "end",
            snap=snap,
            states=states,
            heading_deg=np.full(n, math.nan),
            target_ned_m=np.full((n, 3), np.nan),
            layer_alt_m=self.alt_amsl_m[k] - mission.origin.alt_amsl_m,
            n_layers=1,
            crews_ne_m=run.task_pos_m[k],
            tree=tree,
            tu1=None if row is None else row.get("tu1_so_far"),
            tu2=None if row is None else row.get("tu2_so_far"),
            series=series,
            events=self._events_until(t),
            released={},
        )
        return frame_dict(
            pic, mission.radio.range_m, mission.radio.base_range_m, terrain=self.terrain
        )

    def _events_until(self, t_s: float, limit: int = 60) -> list[dict]:
        out = []
        for seq, e in enumerate(self.losses):
            if e["t_s"] > t_s:
                break
            out.append(
                {
                    "seq": seq,
                    "t_s": round(float(e["t_s"]), 1),
                    "t_mission_s": round(float(e["t_s"]), 1),
                    "kind": "lost",
                    "vehicle": f"0:{int(e['index']) + 1}",
                    "text": f"vehicle {int(e['index']) + 1} lost (attrition)",
                }
            )
        return out[-limit:]

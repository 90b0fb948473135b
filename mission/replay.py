"""Replay a run directory: the paper's Fig. 2 series, a Fig. 4 frame strip, and an animation.

A run directory (written by ``phireman sim --mission``/``phireman fly``) holds ``truth.npz`` with
``t_s``, drone positions (``pos_ne_m`` (T, N, 2) or the emulator's ``pos_ned_m`` (T, N, 3)),
``alive``, ``active``, ``task_connected`` and ideally ``task_pos_ne_m``; ``mission.yaml`` (for
hazard zones, radio range and, if task positions were not recorded, to redraw them from the seed);
``trees.json`` (task trees by step) when the planner recorded them; ``summary.json``.
"""

from __future__ import annotations

import json
import pathlib
from dataclasses import dataclass

import numpy as np

__all__ = ["RunData", "load_run", "replay"]


@dataclass
class RunData:
    t_s: np.ndarray
    pos_m: np.ndarray          # (T, N, 2)
    alive: np.ndarray          # (T, N)
    active: np.ndarray         # (T, N)
    task_pos_m: np.ndarray     # (T, M, 2)
    connected: np.ndarray      # (T, M)
    trees: dict                # step index -> TaskTree-like (nodes_m, parent, n_tasks, segments())
    mission: object
    summary: dict


@dataclass(frozen=True)
class _Tree:
    nodes_m: np.ndarray
    parent: np.ndarray
    n_tasks: int

    def segments(self):
        k = np.arange(1, len(self.nodes_m))
        return self.nodes_m[self.parent[k]], self.nodes_m[k]


def load_run(run_dir: pathlib.Path) -> RunData:
    """Read a run directory; raises FileNotFoundError / ValueError with a clear message."""
    from mission.load import load_mission

    run_dir = pathlib.Path(run_dir)
    truth_path = run_dir / "truth.npz"
    if not truth_path.is_file():
        raise FileNotFoundError(f"{run_dir}: no truth.npz (replay needs a run recorded with ground truth)")
    truth = np.load(truth_path)
    mission = load_mission(run_dir / "mission.yaml") if (run_dir / "mission.yaml").is_file() else None
    summary = json.loads((run_dir / "summary.json").read_text()) if (run_dir / "summary.json").is_file() else {}
    if "pos_ne_m" in truth:
        pos = truth["pos_ne_m"]
    elif "pos_ned_m" in truth:
        pos = truth["pos_ned_m"][..., :2]
    else:
        raise ValueError(f"{truth_path}: no drone positions (pos_ne_m or pos_ned_m)")
    t_s = truth["t_s"]
    if "mission_t0_s" in truth:  # emulator truth also covers the launch: keep the mission interval
        keep = t_s >= float(truth["mission_t0_s"]) - 1e-9
        t_s = t_s[keep] - float(truth["mission_t0_s"])
        truth = {k: (truth[k][keep] if truth[k].ndim and len(truth[k]) == len(keep) else truth[k]) for k in truth}
    if "task_pos_ne_m" in truth:
        tasks = truth["task_pos_ne_m"]
    elif mission is not None:
        from mission.playback import build_scenario, task_position_fn

        scn = build_scenario(mission, summary.get("seed"))
        fn = task_position_fn(scn.task_track_m, scn.dt_s)
        tasks = np.stack([fn(t) for t in t_s])
    else:
        raise ValueError(f"{run_dir}: no task positions recorded and no mission.yaml to redraw them")
    n_samples = min(len(t_s), len(pos), len(tasks))
    connected = truth["task_connected"] if "task_connected" in truth else np.zeros(tasks.shape[:2], bool)
    trees = {}
    if (run_dir / "trees.json").is_file():
        for key, tr in json.loads((run_dir / "trees.json").read_text()).items():
            trees[int(key)] = _Tree(np.asarray(tr["nodes_ne_m"], float), np.asarray(tr["parent"], int), tr["n_tasks"])
    return RunData(t_s[:n_samples], pos[:n_samples], truth["alive"][:n_samples], truth["active"][:n_samples],
                   tasks[:n_samples], connected[:n_samples], trees, mission, summary)


def _tree_at(trees: dict, k: int):
    keys = [s for s in trees if s <= k]
    return trees[max(keys)] if keys else None


def _zone_painters(mission):
    import matplotlib.pyplot as plt

    painters = []
    if mission is None:
        return painters
    for zone in mission.attrition.hazard_zones:
        if zone.circle is not None:
            c = zone.circle

            def paint(ax, c=c):
                ax.add_patch(plt.Circle((c.center.east_m, c.center.north_m), c.radius_m, color="tab:red",
                                        alpha=0.12, hatch="//"))
        else:
            pts = [(p.east_m, p.north_m) for p in zone.polygon]

            def paint(ax, pts=pts):
                ax.add_patch(plt.Polygon(pts, closed=True, color="tab:red", alpha=0.12))
        painters.append(paint)
    return painters


def replay(run_dir: pathlib.Path, out_dir: pathlib.Path | None = None, animation: str = "gif",
           max_frames: int = 120, progress=None) -> list[pathlib.Path]:
    """Render fig2_timeseries.png, frames.png and an animation of a run; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FFMpegWriter, FuncAnimation, PillowWriter

    from mission.plots import _strip_legend, draw_frame

    run = load_run(run_dir)
    out_dir = pathlib.Path(out_dir or run_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    radio = run.mission.radio.range_m if run.mission is not None else 2.0
    base = run.mission.radio.base_range_m if run.mission is not None else radio
    extent = max(np.abs(run.task_pos_m).max(), np.abs(run.pos_m[run.alive]).max() if run.alive.any() else 1.0)
    zones = _zone_painters(run.mission)
    title = run.mission.name if run.mission is not None else run_dir.name
    n_drones, n_tasks = run.pos_m.shape[1], run.task_pos_m.shape[1]

    # Fig. 2: alive, alive and active, connected tasks
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(run.t_s, 100 * run.alive.mean(1), color="tab:gray", label="drones alive")
    ax.plot(run.t_s, 100 * (run.alive & run.active).mean(1), color="tab:blue", label="drones alive and active")
    ax.plot(run.t_s, 100 * run.connected.mean(1), color="tab:red", label="tasks connected (ret)")
    ever = np.logical_or.accumulate(run.connected, axis=0).sum(1)
    tu2 = np.divide(run.connected.sum(1), ever, out=np.zeros(len(ever)), where=ever > 0)
    ax.plot(run.t_s, 100 * tu2, color="tab:red", ls="--", lw=0.8, label="connected / ever connected")
    tu = ""
    truth = run.summary.get("truth") if isinstance(run.summary.get("truth"), dict) else {
        "tu1": run.summary.get("truth_tu1"), "tu2": run.summary.get("truth_tu2")}  # fly / in-process
    if truth.get("tu1") is not None:
        tu = f" — TU1 {100 * truth['tu1']:.1f} %, TU2 {100 * truth['tu2']:.1f} % (ground truth)"
    ax.set(xlabel="time (s)", ylabel="%", ylim=(0, 102), title=f"{title}{tu}")
    # Below the axes: inside, any corner hides a curve (they span 0-100 % over the whole run).
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, fontsize=8, frameon=False)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = out_dir / "fig2_timeseries.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)
    written.append(path)

    # Fig. 4: frame strip
    picks = np.unique(np.linspace(0, len(run.t_s) - 1, 5).round().astype(int))
    fig, axes = plt.subplots(1, len(picks), figsize=(3.3 * len(picks), 4.0))
    for ax, k in zip(np.atleast_1d(axes), picks):
        draw_frame(ax, run.pos_m[k], run.alive[k], run.active[k], run.task_pos_m[k], run.connected[k],
                   _tree_at(run.trees, k), radio, base, extent, hazard_zones=zones)
        ax.set_title(f"t = {run.t_s[k]:.0f} s: {run.connected[k].sum()}/{n_tasks} tasks, "
                     f"{(run.alive[k] & run.active[k]).sum()}/{n_drones} active", fontsize=8)
        ax.set_xlabel("east (m)", fontsize=7)
    np.atleast_1d(axes)[0].set_ylabel("north (m)", fontsize=7)
    _strip_legend(fig, np.atleast_1d(axes)[-1])
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.13, 1, 1))
    path = out_dir / "frames.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)
    written.append(path)

    if animation != "none":
        ks = np.unique(np.linspace(0, len(run.t_s) - 1, min(max_frames, len(run.t_s))).round().astype(int))
        fig, ax = plt.subplots(figsize=(5.5, 5.5))

        def draw(i):
            ax.clear()
            k = ks[i]
            draw_frame(ax, run.pos_m[k], run.alive[k], run.active[k], run.task_pos_m[k], run.connected[k],
                       _tree_at(run.trees, k), radio, base, extent, hazard_zones=zones)
            ax.set_title(f"{title}: t = {run.t_s[k]:.0f} s, {run.connected[k].sum()}/{n_tasks} tasks connected, "
                         f"{(run.alive[k] & run.active[k]).sum()} drones active", fontsize=8)
            if progress:
                progress(1)

        anim = FuncAnimation(fig, draw, frames=len(ks))
        if animation == "mp4":
            path = out_dir / "animation.mp4"
            anim.save(path, writer=FFMpegWriter(fps=10))
        else:
            path = out_dir / "animation.gif"
            anim.save(path, writer=PillowWriter(fps=10))
        plt.close(fig)
        written.append(path)
    return written

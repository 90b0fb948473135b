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
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from mission.format.schema import Mission

__all__ = [
    "RunData",
    "load_run",
    "replay",
    "find_run_dir",
    "check_animation_writer",
    "tree_at",
    "mark_interrupt",
    "link_profiles_figure",
]


@dataclass
class RunData:
    t_s: np.ndarray
    pos_m: np.ndarray  # (T, N, 2)
    alive: np.ndarray  # (T, N)
    active: np.ndarray  # (T, N)
    task_pos_m: np.ndarray  # (T, M, 2)
    connected: np.ndarray  # (T, M)
    trees: dict  # step index -> TaskTree-like (nodes_m, parent, n_tasks, segments())
    mission: Mission | None
    summary: dict
    mission_end_s: float | None = None
    """Mission time at which the mission ended (after it: the vehicles return to launch or land);
    None when the run does not say (then nothing is marked)."""
    end_action: str = "rtl"
    """What the vehicles did at the end (``phireman fly --end``): ``rtl`` or ``land``."""
    alt_amsl_m: np.ndarray | None = None
    """(T, N) drone heights AMSL, metres: recorded by an in-process run over terrain."""


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
    from mission.format.load import load_mission

    run_dir = pathlib.Path(run_dir)
    truth_path = run_dir / "truth.npz"
    if not truth_path.is_file():
        raise FileNotFoundError(
            f"{run_dir}: no truth.npz (replay needs a run recorded with ground truth)"
        )
    truth = np.load(truth_path)
    mission = (
        load_mission(run_dir / "mission.yaml") if (run_dir / "mission.yaml").is_file() else None
    )
    summary = (
        json.loads((run_dir / "summary.json").read_text())
        if (run_dir / "summary.json").is_file()
        else {}
    )
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
        truth = {
            k: (truth[k][keep] if truth[k].ndim and len(truth[k]) == len(keep) else truth[k])
            for k in truth
        }
    if "task_pos_ne_m" in truth:
        tasks = truth["task_pos_ne_m"]
    elif mission is not None:
        from mission.experiments.playback import build_scenario, task_position_fn

        scn = build_scenario(mission, summary.get("seed"))
        fn = task_position_fn(scn.task_track_m, scn.dt_s)
        tasks = np.stack([fn(t) for t in t_s])
    else:
        raise ValueError(
            f"{run_dir}: no task positions recorded and no mission.yaml to redraw them"
        )
    n_samples = min(len(t_s), len(pos), len(tasks))
    connected = (
        truth["task_connected"] if "task_connected" in truth else np.zeros(tasks.shape[:2], bool)
    )
    trees = {}
    if (run_dir / "trees.json").is_file():
        for key, tr in json.loads((run_dir / "trees.json").read_text()).items():
            trees[int(key)] = _Tree(
                np.asarray(tr["nodes_ne_m"], float), np.asarray(tr["parent"], int), tr["n_tasks"]
            )
    run_meta = (
        json.loads((run_dir / "run.json").read_text()) if (run_dir / "run.json").is_file() else {}
    )
    return RunData(
        t_s[:n_samples],
        pos[:n_samples],
        truth["alive"][:n_samples],
        truth["active"][:n_samples],
        tasks[:n_samples],
        connected[:n_samples],
        trees,
        mission,
        summary,
        _mission_end_s(summary, mission),
        str(run_meta.get("options", {}).get("end") or "rtl"),
        truth["alt_amsl_m"][:n_samples] if "alt_amsl_m" in truth else None,
    )


def _mission_end_s(summary: dict, mission) -> float | None:
    """When the mission ended, mission seconds: its duration, or earlier if the flight stopped
    early (``mission_s_flown`` of a ``phireman fly`` summary); in-process runs: the duration."""
    duration = summary.get("duration_s")
    if duration is None and mission is not None:
        duration = mission.run.duration_s
    flown = summary.get("mission_s_flown")
    ends = [float(x) for x in (duration, flown) if x is not None]
    return min(ends) if ends else None


def end_phase_text(run: RunData) -> str:
    """What the vehicles do after the mission end, for labels."""
    return "landing" if run.end_action == "land" else "return to launch (RTL)"


def _tree_at(trees: dict, k: int):
    keys = [s for s in trees if s <= k]
    return trees[max(keys)] if keys else None


def _zone_painters(mission):
    """The mission's hazard zones as :class:`mission.view.plots.ZoneArt` (patch and time window)."""
    import matplotlib.pyplot as plt

    from mission.view.plots import ZoneArt

    painters: list = []
    if mission is None:
        return painters
    for zone in mission.attrition.hazard_zones:
        if zone.circle is not None:
            c = zone.circle

            def paint(ax, c=c):
                return ax.add_patch(
                    plt.Circle((c.center.east_m, c.center.north_m), c.radius_m, zorder=0.5)
                )
        else:
            pts = [(p.east_m, p.north_m) for p in zone.polygon]

            def paint(ax, pts=pts):
                return ax.add_patch(plt.Polygon(pts, closed=True, zorder=0.5))

        painters.append(ZoneArt(paint, zone.start_s, zone.end_s))
    return painters


def find_run_dir(path: pathlib.Path) -> tuple[pathlib.Path, str | None]:
    """The run directory to replay: ``path`` itself, or the newest run directory inside it.

    ``phireman fly --out DIR`` makes ``DIR/<stamp>/`` while ``phireman sim --mission --out DIR``
    writes ``DIR`` itself; both are accepted. Returns the directory and a note for people when it
    picked one of several (or None).

    Raises
    ------
    FileNotFoundError
        With a hint: what a run directory holds and which commands write one.
    """
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such directory")
    if not path.is_dir():
        raise FileNotFoundError(
            f"{path} is a file; replay takes a run directory (holding truth.npz), "
            f"e.g. the --out of 'phireman sim --mission wildfire --out runs/wf'"
        )
    if (path / "truth.npz").is_file():
        return path, None
    runs = sorted(
        (d for d in path.iterdir() if d.is_dir() and (d / "truth.npz").is_file()),
        key=lambda d: ((d / "truth.npz").stat().st_mtime, d.name),
    )
    if runs:
        note = None
        if len(runs) > 1:
            note = (
                f"{path} holds {len(runs)} run directories; replaying the newest, {runs[-1].name} "
                f"(give its path to choose another)"
            )
        else:
            note = f"replaying {runs[-1]}"
        return runs[-1], note
    if (path / "summary.json").is_file() or (path / "flight.tlog").is_file():
        raise FileNotFoundError(
            f"{path} is a run directory without truth.npz: it was flown with real vehicles "
            f"(--connect), so there is no ground truth to draw; its metrics.csv and "
            f"flight.tlog hold what the station saw"
        )
    raise FileNotFoundError(
        f"{path}: no truth.npz here or in its subdirectories; a run directory is written by "
        f"'phireman sim --mission MISSION --out DIR' or 'phireman fly' (emulated)"
    )


def _task_names(run: RunData) -> list | None:
    """The crews' names as the live page gives them (``Task 7``, ``Engine 7``:
    :func:`mission.view.live.state.crew_names`); without mission.yaml, the recorded ones."""
    if run.mission is not None:
        from mission.view.live.state import crew_names

        names = crew_names(run.mission)
        if len(names) == run.task_pos_m.shape[1]:
            return names
    recorded = run.summary.get("task_names")
    return list(recorded) if recorded else None


def tree_at(run: RunData, k: int):
    """The task tree at sample ``k``: the recorded one, else rebuilt from the task positions."""
    tree = _tree_at(run.trees, k) if run.trees else None
    if tree is not None:
        return tree
    from planner.steiner import build_task_tree

    base = np.zeros(2)
    return build_task_tree(base, run.task_pos_m[k])


def _scene(run: RunData, fontsize: float = 9.0):
    from mission.view.plots import Scene

    radio = run.mission.radio.range_m if run.mission is not None else 2.0
    base = run.mission.radio.base_range_m if run.mission is not None else radio
    base = radio if base is None else base
    extent = max(
        np.abs(run.task_pos_m).max(), np.abs(run.pos_m[run.alive]).max() if run.alive.any() else 1.0
    )
    terrain = None
    if run.mission is not None:
        from mission.format.terrain import terrain_radio

        terrain = terrain_radio(run.mission)
    return Scene(
        radio,
        base,
        float(extent),
        _zone_painters(run.mission),
        _task_names(run),
        "m",
        tree_recomputed=not run.trees,
        fontsize=fontsize,
        mission_end_s=run.mission_end_s,
        terrain=terrain,
    )


def mark_interrupt(ax, summary: dict):
    """A dotted vertical line, in the legend, at the mission time Ctrl-C stopped the flight
    (``summary.json``'s ``interrupted_at_s``: the end of the span both TU figures cover; what
    follows is the vehicles returning). None when the run was not interrupted in flight."""
    t = summary.get("interrupted_at_s")
    if not summary.get("interrupted") or t is None:
        return None
    return ax.axvline(
        float(t), color="black", ls=":", lw=1.2, label=f"interrupted (Ctrl-C) at {float(t):.0f} s"
    )


def _after_end(run: RunData) -> np.ndarray:
    """(T,) which samples are after the mission end."""
    if run.mission_end_s is None:
        return np.zeros(len(run.t_s), bool)
    return run.t_s > run.mission_end_s + 1e-6


def check_animation_writer(animation: str) -> None:
    """Refuse up front an animation format whose encoder is missing (instead of failing at the end)."""
    if animation == "mp4":
        import shutil

        from matplotlib.animation import FFMpegWriter

        if shutil.which("ffmpeg") is None and not FFMpegWriter.isAvailable():
            raise ValueError(
                "--animation mp4 needs ffmpeg, which is not installed (apt install ffmpeg); "
                "use --animation gif (the default) or none"
            )


def replay(
    run_dir: pathlib.Path,
    out_dir: pathlib.Path | None = None,
    animation: str = "gif",
    max_frames: int = 100,
    progress=None,
) -> list[pathlib.Path]:
    """Render fig2_timeseries.png, frames.png and an animation of a run; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mission.view.plots import C_END, FrameView, strip_figure

    check_animation_writer(animation)
    run = load_run(run_dir)
    out_dir = pathlib.Path(out_dir or run_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    title = run.mission.name if run.mission is not None else pathlib.Path(run_dir).name
    n_drones, n_tasks = run.pos_m.shape[1], run.task_pos_m.shape[1]
    tu = ""
    truth: dict = (
        got
        if isinstance(got := run.summary.get("truth"), dict)
        else {"tu1": run.summary.get("truth_tu1"), "tu2": run.summary.get("truth_tu2")}
    )  # fly / in-process
    if truth.get("tu1") is not None:
        tu = f": TU1 {100 * truth['tu1']:.1f} %, TU2 {100 * truth['tu2']:.1f} % (ground truth)"
    seed = run.summary.get("seed")
    full_title = f"{title}{'' if seed is None else f', seed {seed}'}{tu}"

    # Fig. 2: alive, alive and active, connected tasks
    fig, ax = plt.subplots(figsize=(8, 4.8))
    ax.plot(
        run.t_s, 100 * run.alive.mean(1), color="tab:gray", label=f"drones alive (% of {n_drones})"
    )
    ax.plot(
        run.t_s,
        100 * (run.alive & run.active).mean(1),
        color="tab:blue",
        label=f"drones alive and networked (% of {n_drones})",
    )
    ax.plot(
        run.t_s,
        100 * run.connected.mean(1),
        color="tab:red",
        label=f"tasks connected (% of {n_tasks})",
    )
    ever = np.logical_or.accumulate(run.connected, axis=0).sum(1)
    tu2 = np.divide(run.connected.sum(1), ever, out=np.zeros(len(ever)), where=ever > 0)
    ax.plot(
        run.t_s,
        100 * tu2,
        color="tab:red",
        ls="--",
        lw=0.9,
        label="connected / ever connected (TU2's integrand)",
    )
    mark_interrupt(ax, run.summary)
    after = _after_end(run)
    if after.any():  # the mission is over: what follows is the flight home, not the planner
        assert run.mission_end_s is not None  # after.any() needs it
        ax.axvspan(
            run.mission_end_s,
            run.t_s[-1],
            color=C_END,
            alpha=0.12,
            lw=0,
            label=f"after the mission end: {end_phase_text(run)}",
        )
        ax.axvline(run.mission_end_s, color=C_END, ls="--", lw=1.2)
        ax.annotate(
            f"mission end\n(t = {run.mission_end_s:.0f} s)",
            (run.mission_end_s, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(4, -4),
            textcoords="offset points",
            va="top",
            fontsize=8.5,
            color="0.25",
        )
    ax.set_xlabel("mission time (s)", fontsize=10)
    ax.set_ylabel("%", fontsize=10)
    ax.set(ylim=(0, 102), xlim=(min(0.0, float(run.t_s[0])), float(run.t_s[-1])))
    ax.set_title(full_title, fontsize=10)
    ax.tick_params(labelsize=9)
    # Below the axes: inside, any corner hides a curve (they span 0-100 % over the whole run).
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, fontsize=8.5, frameon=False)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = out_dir / "fig2_timeseries.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)
    written.append(path)

    # Fig. 4: frame strip
    scene = _scene(run)
    after = _after_end(run)
    in_mission = np.flatnonzero(~after)
    if after.any() and len(in_mission):  # four frames of the mission, then the last one
        picks = np.unique(
            np.r_[in_mission[np.linspace(0, len(in_mission) - 1, 4).round().astype(int)], -1]
            % len(run.t_s)
        )
    else:
        picks = np.unique(np.linspace(0, len(run.t_s) - 1, 5).round().astype(int))
    fig, axes, _ = strip_figure(len(picks), scene)
    for ax, k in zip(axes, picks):
        FrameView(ax, scene).update(
            run.pos_m[k],
            run.alive[k],
            run.active[k],
            run.task_pos_m[k],
            run.connected[k],
            tree_at(run, k),
            t_s=float(run.t_s[k]),
            alt_amsl_m=None if run.alt_amsl_m is None else run.alt_amsl_m[k],
        )
        ax.set_title(
            f"t = {run.t_s[k]:.0f} s: {run.connected[k].sum()}/{n_tasks} tasks connected, "
            f"{(run.alive[k] & run.active[k]).sum()}/{n_drones} drones networked"
            + (f"\nafter the mission end: {end_phase_text(run)}" if after[k] else ""),
            fontsize=10,
            color="#a04000" if after[k] else "black",
        )
    fig.suptitle(full_title, fontsize=13)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    path = out_dir / "frames.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(path)

    if scene.terrain is not None and run.alt_amsl_m is not None:
        k = int(picks[len(picks) // 2])
        path = out_dir / "link_profiles.png"
        if link_profiles_figure(run, scene.terrain, k, path, full_title):
            written.append(path)

    if animation != "none":
        ks = np.unique(
            np.linspace(0, len(run.t_s) - 1, min(max_frames, len(run.t_s))).round().astype(int)
        )
        fps = max(4, min(12, round(len(ks) / 10)))  # about 10 s whatever the length
        path = out_dir / f"animation.{animation}"
        _animate(run, ks, full_title, path, fps, progress)
        written.append(path)
    return written


def link_profiles_figure(run: RunData, radio, k: int, path: pathlib.Path, title: str) -> bool:
    """Two link profiles at sample ``k`` of a terrain run (docs/terrain.md §2): the shortest link
    between networked drones that the terrain blocks, and the longest that closes. Writes
    ``path`` and returns True, or False when the frame has neither."""
    import matplotlib.pyplot as plt

    from mission.view.terrain import draw_link_profile
    from planner.geometry import neighbour_pairs
    from planner.terrain import LINK_BLOCKED, LINK_OK, link_profile

    assert run.alt_amsl_m is not None  # the caller checks: a terrain run
    idx = np.flatnonzero(run.alive[k] & run.active[k])
    if len(idx) < 2:
        return False
    pos = run.pos_m[k]
    p3 = np.column_stack([pos, run.alt_amsl_m[k]])
    pairs = idx[neighbour_pairs(pos[idx], radio.budget.max_range_m)]
    if not len(pairs):
        return False
    status = radio.link_status(p3[pairs[:, 0]], p3[pairs[:, 1]])
    dist = np.linalg.norm(pos[pairs[:, 0]] - pos[pairs[:, 1]], axis=1)
    chosen = []
    blocked = np.flatnonzero(status == LINK_BLOCKED)
    if len(blocked):
        chosen.append(("shortest link blocked", pairs[blocked[np.argmin(dist[blocked])]]))
    ok = np.flatnonzero(status == LINK_OK)
    if len(ok):
        chosen.append(("longest link that closes", pairs[ok[np.argmax(dist[ok])]]))
    fig, axes = plt.subplots(len(chosen), 1, figsize=(8, 3.4 * len(chosen)), squeeze=False)
    for ax, (what, (i, j)) in zip(axes[:, 0], chosen):
        prof = link_profile(radio.terrain, radio.budget, p3[i], p3[j])
        draw_link_profile(ax, prof, f"{what}, drones {i + 1} and {j + 1}")
    fig.suptitle(f"{title}\nlink profiles at t = {run.t_s[k]:.0f} s", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def _animate(
    run: RunData, ks: np.ndarray, title: str, path: pathlib.Path, fps: int, progress=None
) -> None:
    """Render the animation by blitting: the background (axes, legend, zones, base) is drawn once,
    each frame redraws only the moving artists onto a copy of it, so a 100-frame GIF takes seconds
    rather than minutes (a full figure redraw per frame is dominated by text layout)."""
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image

    from mission.view.plots import FrameView, legend_handles

    n_drones, n_tasks = run.pos_m.shape[1], run.task_pos_m.shape[1]
    scene = _scene(run, fontsize=8.0)
    dpi = 72 if path.suffix == ".gif" else 100
    fig = plt.figure(figsize=(9.6, 6.4), dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.08, 0.09, 0.56, 0.84))
    fig.legend(
        handles=legend_handles(scene),
        loc="center left",
        bbox_to_anchor=(0.655, 0.5),
        fontsize=7.5,
        frameon=False,
    )
    fig.suptitle(title, fontsize=10)
    view = FrameView(ax, scene, clock=True)
    moving = view.update(
        run.pos_m[0],
        run.alive[0],
        run.active[0],
        run.task_pos_m[0],
        run.connected[0],
        None,
        " ",
        t_s=float(run.t_s[0]),
    )
    after = _after_end(run)
    for a in moving:
        a.set_animated(True)
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)
    images = []
    ffmpeg = None
    if path.suffix == ".mp4":
        import subprocess

        w, h = canvas.get_width_height()
        ffmpeg = subprocess.Popen(
            [
                "ffmpeg",
                "-y",
                "-loglevel",
                "error",
                "-f",
                "rawvideo",
                "-pix_fmt",
                "rgba",
                "-s",
                f"{w}x{h}",
                "-r",
                str(fps),
                "-i",
                "-",
                "-pix_fmt",
                "yuv420p",
                "-vf",
                "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                str(path),
            ],
            stdin=subprocess.PIPE,
        )
    try:
        for k in ks:
            canvas.restore_region(background)
            for a in view.update(
                run.pos_m[k],
                run.alive[k],
                run.active[k],
                run.task_pos_m[k],
                run.connected[k],
                tree_at(run, k),
                f"t = {run.t_s[k]:5.0f} s\n{run.connected[k].sum()}/{n_tasks} tasks connected\n"
                f"{(run.alive[k] & run.active[k]).sum()}/{n_drones} drones networked"
                + (f"\nmission over: {end_phase_text(run)}" if after[k] else ""),
                t_s=float(run.t_s[k]),
                alt_amsl_m=None if run.alt_amsl_m is None else run.alt_amsl_m[k],
            ):
                ax.draw_artist(a)
            rgba = np.asarray(canvas.buffer_rgba())
            if ffmpeg is not None:
                ffmpeg.stdin.write(rgba.tobytes())  # type: ignore[union-attr]  # stdin=PIPE
            else:
                images.append(
                    Image.fromarray(rgba[..., :3]).quantize(
                        colors=256, method=Image.Quantize.MEDIANCUT
                    )
                )
            if progress:
                progress(1)
    finally:
        plt.close(fig)
        if ffmpeg is not None:
            ffmpeg.stdin.close()  # type: ignore[union-attr]  # stdin=PIPE
            if ffmpeg.wait() != 0:
                raise ValueError(f"ffmpeg failed to write {path}")
    if images:
        images[0].save(
            path,
            save_all=True,
            append_images=images[1:],
            duration=int(1000 / fps),
            loop=0,
            optimize=False,
        )

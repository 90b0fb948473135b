"""Figures people would rather look at than read: the paper's Fig. 2, a Fig. 4-style frame strip,
and the animation of a run.

Every map is drawn by one :class:`FrameView`: its artists are created once and updated per frame,
so a strip, a single frame and a 100-frame animation share the same look and the same complete
legend (:func:`legend_handles`), and an animation renders in seconds. Maps are east to the right,
north up, with the unit on the axes: metres for missions, paper length units for the paper's
presets (``unit``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.artist import Artist  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

__all__ = [
    "plot_time_series",
    "plot_frame_strip",
    "draw_frame",
    "Scene",
    "FrameView",
    "legend_handles",
    "short_name",
    "crew_links",
    "PAPER_UNIT",
    "ZoneArt",
    "C_END",
]

#: Axis label unit of the paper's presets (the scaled reading keeps paper units, docs/design/model.md §6.4).
PAPER_UNIT = "paper length units"

C_ACTIVE, C_IDLE, C_LOST = "tab:blue", "tab:gray", "black"
C_OK, C_CUT, C_TREE, C_BASE, C_HAZARD, C_CREW = (
    "tab:green",
    "tab:red",
    "tab:orange",
    "darkgreen",
    "tab:red",
    "green",
)
#: After the mission end (the vehicles return to launch or land): shading and marks.
C_END = "tab:orange"
#: A link the budget would close but the terrain cuts (docs/terrain.md §2).
C_BLOCKED = "#e31a1c"


def plot_time_series(
    rows: list[dict],
    n_drones: int,
    n_tasks: int,
    title: str,
    path,
    step_label: str = "step (paper time steps)",
) -> None:
    """Fig. 2: alive, alive-and-active drones and connected tasks over time across runs.

    Lines are the mean over runs; the shaded band around each spans the 5th to 95th percentile
    of the runs at that step (labelled in the legend).
    """
    fig, ax = plt.subplots(figsize=(8, 4.8))
    series = [
        ("alive_count", n_drones, "drones alive (% of initial)", C_IDLE),
        ("active_count", n_drones, "drones alive and networked (% of initial)", C_ACTIVE),
        ("n_connected", n_tasks, "tasks connected (% of tasks)", C_CUT),
    ]
    for key, total, label, colour in series:
        data = np.array([r[key][: len(rows[0]["tu1_step"])] for r in rows], dtype=float) / total
        t = np.arange(data.shape[1])
        ax.plot(t, 100 * data.mean(0), color=colour, label=f"{label}, mean of {len(rows)} runs")
        if len(rows) > 1:
            lo, hi = np.percentile(100 * data, [5, 95], axis=0)
            ax.fill_between(t, lo, hi, color=colour, alpha=0.15, linewidth=0)
    if len(rows) > 1:
        ax.fill_between(
            [], [], [], color="gray", alpha=0.25, linewidth=0, label="band: 5–95 % of runs"
        )
    ax.set_xlabel(step_label, fontsize=10)
    ax.set_ylabel("%", fontsize=10)
    ax.set_ylim(0, 102)
    ax.tick_params(labelsize=9)
    ax.set_title(title, fontsize=10)
    # Below the axes: inside, any corner hides a curve (they span 0-100 % over the whole run).
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, fontsize=8.5, frameon=False)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def short_name(name: str | None) -> str:
    """'Crew 1 (hand crew, east flank)' -> 'Crew 1': the label drawn next to a task."""
    return "" if not name else name.split(" (")[0].strip()


def crew_links(task_pos_m, pos_m, active, range_m) -> np.ndarray:
    """(K, 2, 2) segments task -> the nearest active drone strictly within range (what connects it)."""
    idx = np.flatnonzero(active)
    if not len(idx) or not len(task_pos_m):
        return np.zeros((0, 2, 2))
    d = np.linalg.norm(task_pos_m[:, None, :] - pos_m[idx][None, :, :], axis=2)
    near = d.argmin(1)
    ok = d[np.arange(len(task_pos_m)), near] < range_m
    return np.stack([task_pos_m[ok], pos_m[idx[near[ok]]]], 1)


@dataclass(frozen=True)
class ZoneArt:
    """A hazard zone on a map: ``paint(ax)`` adds its patch and returns it; the zone is active
    in ``[start_s, end_s)`` of mission time (``end_s`` None: to the end of the mission), as
    :meth:`mission.format.schema.HazardZone.active`."""

    paint: Callable
    start_s: float = 0.0
    end_s: float | None = None

    def active(self, t_s: float, mission_end_s: float | None = None) -> bool:
        """Active at ``t_s``; never after the mission end (attrition stops there)."""
        if mission_end_s is not None and t_s > mission_end_s + 1e-6:  # as replay._after_end
            return False
        return t_s >= self.start_s and (self.end_s is None or t_s < self.end_s)


#: Hazard zone looks: active (filled, hatched) and not active at the instant drawn (outline).
_ZONE_ON: dict[str, Any] = dict(
    facecolor=to_rgba(C_HAZARD, 0.15),
    edgecolor=to_rgba(C_HAZARD, 0.6),
    linestyle="-",
    hatch="//",
)
_ZONE_OFF: dict[str, Any] = dict(
    facecolor="none", edgecolor=to_rgba("0.45", 0.7), linestyle="--", hatch=None
)


@dataclass
class Scene:
    """What does not change during a run: ranges, extent, hazard zones, names, units."""

    radio_range_m: float
    base_range_m: float
    extent_m: float
    hazard_zones: list = field(default_factory=list)
    """:class:`ZoneArt` (or plain painters ``paint(ax)``, always active), mission.view.replay."""
    task_names: list | None = None
    unit: str = "m"
    tree_recomputed: bool = False
    """The tree is rebuilt from the recorded task positions (the run did not record the planner's)."""
    fontsize: float = 9.0
    mission_end_s: float | None = None
    """Mission time at which the mission ended (then: return to launch); None: not known."""
    terrain: Any = None
    """A :class:`planner.terrain.TerrainRadio` for a terrain mission: the map is drawn over its
    shaded relief and contours (:func:`mission.view.terrain.draw_terrain`), and given the drones'
    heights the links blocked by terrain are drawn apart from those that close (docs/terrain.md)."""


def legend_handles(scene: Scene) -> list:
    """Proxy artists for everything a map can show (also what is absent at a given instant)."""
    h = [
        Line2D([], [], marker="s", ls="", color=C_BASE, markersize=8, label="base station"),
        Patch(
            color=C_OK, alpha=0.15, label=f"base radio range ({scene.base_range_m:g} {scene.unit})"
        ),
        Line2D([], [], marker="o", ls="", color=C_ACTIVE, markersize=5, label="drone, networked"),
        Line2D(
            [],
            [],
            marker="o",
            ls="",
            color=C_IDLE,
            markersize=5,
            label="drone, cut off (flying home)",
        ),
        Line2D([], [], marker="x", ls="", color=C_LOST, markersize=6, label="drone lost"),
        Line2D(
            [],
            [],
            color=C_ACTIVE,
            alpha=0.5,
            lw=1,
            label=f"radio link (≤ {scene.radio_range_m:g} {scene.unit})"
            if scene.terrain is None
            else "radio link (closes over the terrain)",
        ),
        Line2D(
            [],
            [],
            marker="*",
            ls="",
            color=C_OK,
            markeredgecolor="black",
            markersize=12,
            label="task / crew, connected",
        ),
        Line2D(
            [],
            [],
            marker="*",
            ls="",
            color=C_CUT,
            markeredgecolor="black",
            markersize=12,
            label="task / crew, cut off",
        ),
        Line2D([], [], color=C_CREW, ls="--", lw=1.4, label="drone serving a crew"),
        Line2D(
            [],
            [],
            color=C_TREE,
            lw=1.6,
            marker="o",
            markerfacecolor="none",
            markersize=5,
            label="task tree"
            + (" (rebuilt from positions)" if scene.tree_recomputed else " (planner's)")
            + ", Steiner points",
        ),
    ]
    if scene.terrain is not None:
        h.append(
            Line2D(
                [], [], color=C_BLOCKED, lw=1, ls=(0, (5, 2, 1, 2)), label="link blocked by terrain"
            )
        )
        h.append(Patch(color="#b99a6b", alpha=0.6, label="terrain: shaded relief, contours"))
    if scene.hazard_zones:
        h.append(Patch(**_ZONE_ON, label="hazard zone, active"))
        if any(isinstance(z, ZoneArt) for z in scene.hazard_zones):
            h.append(Patch(**_ZONE_OFF, label="hazard zone, not active then"))
    return h


class FrameView:
    """One map on ``ax``: static background once, dynamic artists updated by :meth:`update`."""

    def __init__(self, ax, scene: Scene, clock: bool = False) -> None:
        self.ax, self.scene = ax, scene
        fs = scene.fontsize
        if scene.terrain is not None:
            from mission.view.terrain import draw_terrain

            draw_terrain(ax, scene.terrain.terrain, alpha=0.8, labels=fs >= 9)
        ax.add_patch(
            plt.Circle(
                (0, 0),
                min(scene.base_range_m, scene.radio_range_m),
                color=C_OK,
                alpha=0.12,
                zorder=0,
            )
        )
        self.zones: list[tuple[ZoneArt, Patch]] = []
        for zone in scene.hazard_zones:
            if isinstance(zone, ZoneArt):
                patch = zone.paint(ax)
                patch.set(**_ZONE_ON)
                self.zones.append((zone, patch))
            else:
                zone(ax)
        self.links = LineCollection([], colors=C_ACTIVE, alpha=0.3, linewidths=0.6, zorder=1)
        self.crew = LineCollection([], colors=C_CREW, linestyles="--", linewidths=1.4, zorder=2)
        self.tree = LineCollection([], colors=C_TREE, linewidths=1.6, alpha=0.85, zorder=2)
        self.blocked = LineCollection(
            [],
            colors=C_BLOCKED,
            alpha=0.6,
            linewidths=0.7,
            linestyles=[(0, (5, 2, 1, 2))],
            zorder=1,
        )
        for c in (self.links, self.blocked, self.crew, self.tree):
            ax.add_collection(c)
        empty = np.zeros((0, 2))
        self.steiner = ax.scatter(
            empty[:, 0], empty[:, 1], s=22, facecolors="none", edgecolors=C_TREE, zorder=3
        )
        self.lost = ax.scatter(
            empty[:, 0], empty[:, 1], marker="x", s=16, color=C_LOST, alpha=0.55, zorder=3
        )
        self.idle = ax.scatter(empty[:, 0], empty[:, 1], s=14, color=C_IDLE, zorder=4)
        self.active = ax.scatter(empty[:, 0], empty[:, 1], s=14, color=C_ACTIVE, zorder=4)
        self.task_ok = ax.scatter(
            empty[:, 0],
            empty[:, 1],
            marker="*",
            s=150,
            color=C_OK,
            edgecolors="black",
            linewidths=0.5,
            zorder=5,
        )
        self.task_cut = ax.scatter(
            empty[:, 0],
            empty[:, 1],
            marker="*",
            s=150,
            color=C_CUT,
            edgecolors="black",
            linewidths=0.5,
            zorder=5,
        )
        ax.plot([0], [0], marker="s", color=C_BASE, markersize=9, ls="", zorder=6)
        names = scene.task_names or []
        self.labels = [
            ax.text(
                0,
                0,
                short_name(n),
                fontsize=fs - 1.5,
                zorder=7,
                clip_on=True,
                bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.75),
            )
            for n in (names if len(names) <= 20 else [])
        ]
        for t in self.labels:
            t.set_visible(False)  # drawn by the layout below, which places them at draw time
        self.label_layout = _LabelLayout(ax, self.labels)
        ax.add_artist(self.label_layout)
        self.clock = (
            ax.text(
                0.02,
                0.98,
                "",
                transform=ax.transAxes,
                ha="left",
                va="top",
                fontsize=fs + 1,
                zorder=8,
                bbox=dict(boxstyle="round,pad=0.3", fc="white", ec="0.6", alpha=0.85),
            )
            if clock
            else None
        )
        lim = scene.extent_m * 1.15
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=fs - 1)
        ax.set_xlabel(f"east ({scene.unit})", fontsize=fs)
        ax.set_ylabel(f"north ({scene.unit})", fontsize=fs)
        ax.grid(alpha=0.2)

    def update(
        self,
        pos_m,
        alive,
        active,
        task_pos_m,
        connected,
        tree,
        clock_text: str = "",
        t_s: float | None = None,
        alt_amsl_m=None,
    ) -> list:
        """Redraw the dynamic part for one instant; returns the artists changed (for blitting).

        Positions are (north, east) rows; the map draws east on x and north on y. ``t_s``
        (mission time): hazard zones are drawn active only inside their time window.
        ``alt_amsl_m`` (N,) with a terrain scene: the links are the pairs within the larger of the
        disc's and the budget's range, those the terrain radio closes drawn as links, those it
        blocks apart (:meth:`planner.terrain.TerrainRadio.link_status`).
        """
        from planner.geometry import neighbour_pairs

        xy = lambda a: np.asarray(a, float)[..., ::-1]  # (north, east) -> (x = east, y = north)  # noqa: E731
        active = np.asarray(active, bool) & np.asarray(alive, bool)
        idx = np.flatnonzero(active)
        radio = self.scene.terrain
        reach = self.scene.radio_range_m
        if radio is not None and alt_amsl_m is not None:
            reach = max(reach, radio.budget.max_range_m)
        pairs = idx[neighbour_pairs(pos_m[idx], reach)] if len(idx) > 1 else np.zeros((0, 2), int)
        blocked = np.zeros((0, 2), int)
        if radio is not None and alt_amsl_m is not None and len(pairs):
            from planner.terrain import LINK_BLOCKED, LINK_OK

            p3 = np.column_stack([pos_m, alt_amsl_m])
            st = radio.link_status(p3[pairs[:, 0]], p3[pairs[:, 1]])
            pairs, blocked = pairs[st == LINK_OK], pairs[st == LINK_BLOCKED]
        self.links.set_segments(xy(pos_m[pairs]) if len(pairs) else [])  # type: ignore[arg-type]  # (n, 2, 2) arrays are fine
        self.blocked.set_segments(xy(pos_m[blocked]) if len(blocked) else [])  # type: ignore[arg-type]
        self.crew.set_segments(xy(crew_links(task_pos_m, pos_m, active, self.scene.radio_range_m)))  # type: ignore[arg-type]
        if tree is not None:
            a, b = tree.segments()
            self.tree.set_segments(xy(np.stack([a, b], 1)) if len(a) else [])  # type: ignore[arg-type]
            st = tree.nodes_m[tree.n_tasks + 1 :]
            self.steiner.set_offsets(xy(st) if len(st) else np.zeros((0, 2)))
        else:
            self.tree.set_segments([])
            self.steiner.set_offsets(np.zeros((0, 2)))
        dead, idle = ~np.asarray(alive, bool), np.asarray(alive, bool) & ~active
        self.lost.set_offsets(xy(pos_m[dead]))
        self.idle.set_offsets(xy(pos_m[idle]))
        self.active.set_offsets(xy(pos_m[active]))
        connected = np.asarray(connected, bool)
        self.task_ok.set_offsets(xy(task_pos_m[connected]))
        self.task_cut.set_offsets(xy(task_pos_m[~connected]))
        self.label_layout.anchors = xy(np.asarray(task_pos_m, float)[: len(self.labels)])
        for zone, patch in self.zones:
            on = t_s is None or zone.active(t_s, self.scene.mission_end_s)
            patch.set(**(_ZONE_ON if on else _ZONE_OFF))
        changed = [
            *(patch for _, patch in self.zones),
            self.links,
            self.blocked,
            self.crew,
            self.tree,
            self.steiner,
            self.lost,
            self.idle,
            self.active,
            self.task_ok,
            self.task_cut,
            self.label_layout,
        ]
        if self.clock is not None:
            self.clock.set_text(clock_text)
            changed.append(self.clock)
        return changed


class _LabelLayout(Artist):
    """Draws the crew labels where they do not collide, at draw time (when the axes' final size
    and the text extents are known, so a strip after ``tight_layout`` and every animation frame
    are laid out as they are drawn).

    Each label tries, in order, the eight places around its crew's marker (right-above first);
    it takes the first that overlaps no label placed before it and no crew marker, else the one
    overlapping the least; a label that would still cover another label is not drawn (its crew
    keeps its marker; the crews list of the live page names every crew)."""

    #: Offsets (points) from the marker's centre to the label's corner, tried in this order:
    #: (dx, dy, horizontal alignment, vertical alignment).
    PLACES = (
        (7, 3, "left", "bottom"),
        (-7, 3, "right", "bottom"),
        (7, -3, "left", "top"),
        (-7, -3, "right", "top"),
        (0, 9, "center", "bottom"),
        (0, -9, "center", "top"),
        (12, 0, "left", "center"),
        (-12, 0, "right", "center"),
    )
    MARKER_PT = 6.0  # half the crew star's size, points

    def __init__(self, ax, labels: list) -> None:
        super().__init__()
        self.ax = ax
        self.labels = labels
        self.anchors = np.zeros((0, 2))
        self.hidden_rows: list[int] = []
        """Labels left out at the last draw (they would have covered another label)."""
        self.set_zorder(7)

    def draw(self, renderer) -> None:
        if not self.get_visible() or not self.labels:
            return
        ax, px = self.ax, renderer.points_to_pixels(1.0)
        n = min(len(self.labels), len(self.anchors))
        pts = ax.transData.transform(self.anchors[:n]) if n else np.zeros((0, 2))
        ok: np.ndarray = np.asarray(np.isfinite(pts).all(axis=1), dtype=bool)
        m = self.MARKER_PT * px
        markers = [(x - m, y - m, x + m, y + m) for (x, y), good in zip(pts, ok) if good]
        frame = ax.bbox
        placed: list[tuple[float, float, float, float]] = []
        self.hidden_rows = []
        for i, label in enumerate(self.labels):
            if i >= n or not ok[i]:
                continue
            label.set_visible(True)
            label.set_position((0, 0))
            label.set_transform(matplotlib.transforms.IdentityTransform())
            label.set_horizontalalignment("left")
            label.set_verticalalignment("bottom")
            bb = label.get_window_extent(renderer)
            w, h = bb.width, bb.height
            x, y = pts[i]
            best = None
            for dx, dy, ha, va in self.PLACES:
                x0 = x + dx * px - {"left": 0.0, "center": w / 2, "right": w}[ha]
                y0 = y + dy * px - {"bottom": 0.0, "center": h / 2, "top": h}[va]
                box = (x0, y0, x0 + w, y0 + h)
                on_labels = sum(_overlap(box, b) for b in placed)
                on_marks = sum(_overlap(box, b) for j, b in enumerate(markers) if j != i)
                outside = w * h - _overlap(box, (frame.x0, frame.y0, frame.x1, frame.y1))
                score = (on_labels > 0, on_labels + on_marks + outside)
                if best is None or score < best[0]:
                    best = (score, box)
                if score == (False, 0.0):
                    break
            assert best is not None  # PLACES is not empty
            (covers, _), box = best
            if covers:
                label.set_visible(False)
                self.hidden_rows.append(i)
                continue
            placed.append(box)
            label.set_position((box[0], box[1]))
            label.draw(renderer)
            label.set_visible(False)  # drawn here only, never again by the axes
        self.stale = False


def _overlap(a, b) -> float:
    """Area shared by two boxes (x0, y0, x1, y1)."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    return w * h if w > 0 and h > 0 else 0.0


def draw_frame(
    ax,
    pos_m,
    alive,
    active,
    task_pos_m,
    connected,
    tree,
    radio_range_m,
    base_range_m,
    half_width_m,
    links: bool = True,
    hazard_zones=(),
    task_names=None,
    unit: str = "m",
) -> FrameView:
    """One snapshot on ``ax`` (kept for callers of the old API); returns its :class:`FrameView`."""
    view = FrameView(
        ax, Scene(radio_range_m, base_range_m, half_width_m, list(hazard_zones), task_names, unit)
    )
    view.update(
        pos_m, alive, active if links else np.zeros_like(active), task_pos_m, connected, tree
    )
    return view


def strip_figure(n_frames: int, scene: Scene):
    """A figure for a frame strip: frames in rows of three, the legend in the last cell."""
    cols = 3
    rows = (n_frames + 1 + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 5.2 * rows))
    axes = np.atleast_1d(axes).ravel()
    legend_ax = axes[n_frames]
    legend_ax.axis("off")
    legend_ax.legend(
        handles=legend_handles(scene),
        loc="upper left",
        fontsize=scene.fontsize + 1,
        frameon=False,
        title="legend",
        title_fontsize=scene.fontsize + 2,
        alignment="left",
    )
    for ax in axes[n_frames + 1 :]:
        ax.axis("off")
    return fig, axes[:n_frames], legend_ax


def plot_frame_strip(
    record,
    frames: list[int],
    problem,
    title: str,
    path,
    unit: str = PAPER_UNIT,
    step_s: float | None = None,
) -> None:
    """Fig. 4-style strip: a few snapshots of one run (east to the right, north up)."""
    trees = dict(record.trees)
    recomputed = any(trees.get(t) is None for t in frames)
    scene = Scene(
        problem.radio_range_m,
        problem.base_range_m,
        problem.field_half_width_m,
        unit=unit,
        tree_recomputed=recomputed,
    )
    fig, axes, legend_ax = strip_figure(len(frames), scene)
    for ax, t in zip(axes, frames):
        tree = trees.get(t)
        if tree is None:
            from planner.steiner import build_task_tree

            tree = build_task_tree(np.zeros(2), record.task_pos_m[t])
        FrameView(ax, scene).update(
            record.pos_m[t],
            record.alive[t],
            record.active[t],
            record.task_pos_m[t],
            record.connected[t],
            tree,
        )
        when = f"step {t}" if step_s is None else f"t = {t * step_s:g} s"
        ax.set_title(
            f"{when}: {record.connected[t].sum()}/{len(record.connected[t])} tasks connected, "
            f"{(record.active[t] & record.alive[t]).sum()}/{len(record.alive[t])} drones networked",
            fontsize=scene.fontsize + 1,
        )
    fig.suptitle(title, fontsize=13)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    fig.savefig(path, dpi=110)
    plt.close(fig)


# Kept for old imports.
def _strip_legend(fig, ax) -> None:  # pragma: no cover - superseded by strip_figure
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(
        handles, labels, loc="lower center", ncol=max(1, len(labels)), fontsize=8, frameon=False
    )

"""Figures people would rather look at than read: the paper's Fig. 2 and a Fig. 4-style strip."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_time_series", "plot_frame_strip", "draw_frame"]


def plot_time_series(rows: list[dict], n_drones: int, n_tasks: int, title: str, path) -> None:
    """Fig. 2: alive, alive-and-active drones and connected tasks over time (mean and 5-95 % band)."""
    fig, ax = plt.subplots(figsize=(7, 4))
    series = [("alive_count", n_drones, "drones alive", "tab:gray"),
              ("active_count", n_drones, "drones alive and active", "tab:blue"),
              ("n_connected", n_tasks, "tasks connected (ret)", "tab:red")]
    for key, total, label, colour in series:
        data = np.array([r[key][: len(rows[0]["tu1_step"])] for r in rows], dtype=float) / total
        t = np.arange(data.shape[1])
        ax.plot(t, 100 * data.mean(0), color=colour, label=label)
        lo, hi = np.percentile(100 * data, [5, 95], axis=0)
        ax.fill_between(t, lo, hi, color=colour, alpha=0.15, linewidth=0)
    ax.set_xlabel("step")
    ax.set_ylabel("% of initial drones / of tasks")
    ax.set_ylim(0, 102)
    ax.set_title(title, fontsize=10)
    # Below the axes: inside, any corner hides a curve (they span 0-100 % over the whole run).
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, fontsize=8, frameon=False)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def draw_frame(ax, pos_m, alive, active, task_pos_m, connected, tree, radio_range_m, base_range_m,
               half_width_m, links: bool = True, hazard_zones=()) -> None:
    """One snapshot: radio links, drones by state, tasks by connection, the task tree, the base."""
    from planner.geometry import neighbour_pairs

    ax.add_patch(plt.Circle((0, 0), min(base_range_m, radio_range_m), color="tab:green", alpha=0.12))
    for zone in hazard_zones:
        zone(ax)
    if links and active.any():
        idx = np.flatnonzero(active)
        pairs = idx[neighbour_pairs(pos_m[idx], radio_range_m)]
        if len(pairs):
            seg = pos_m[pairs]  # (P, 2, 2)
            ax.plot(seg[:, :, 1].T, seg[:, :, 0].T, color="tab:blue", alpha=0.15, lw=0.5)
    if tree is not None:
        for a, b in zip(*tree.segments()):
            ax.plot([a[1], b[1]], [a[0], b[0]], color="tab:orange", lw=1.2, alpha=0.8)
        st = tree.nodes_m[tree.n_tasks + 1:]
        if len(st):
            ax.scatter(st[:, 1], st[:, 0], s=12, facecolors="none", edgecolors="tab:orange")
    dead = ~alive
    idle = alive & ~active
    ax.scatter(pos_m[dead, 1], pos_m[dead, 0], marker="x", s=10, color="black", alpha=0.5, label="lost")
    ax.scatter(pos_m[idle, 1], pos_m[idle, 0], s=8, color="tab:gray", label="disconnected")
    ax.scatter(pos_m[active, 1], pos_m[active, 0], s=8, color="tab:blue", label="active")
    ax.scatter(task_pos_m[connected, 1], task_pos_m[connected, 0], marker="*", s=90, color="tab:green",
               edgecolors="black", linewidths=0.4, label="task (connected)")
    ax.scatter(task_pos_m[~connected, 1], task_pos_m[~connected, 0], marker="*", s=90, color="tab:red",
               edgecolors="black", linewidths=0.4, label="task (cut off)")
    ax.plot([0], [0], marker="s", color="tab:green", markersize=7)
    lim = half_width_m * 1.1
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=6)


def _strip_legend(fig, ax) -> None:
    """One legend for a frame strip, below the panels (inside one, it hides tasks near a corner)."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, 0.0), ncol=len(labels), fontsize=7,
               frameon=False)


def plot_frame_strip(record, frames: list[int], problem, title: str, path) -> None:
    """Fig. 4-style strip: a few snapshots of one run (east to the right, north up)."""
    fig, axes = plt.subplots(1, len(frames), figsize=(3.2 * len(frames), 3.9))
    axes = np.atleast_1d(axes)
    for ax, t in zip(axes, frames):
        draw_frame(ax, record.pos_m[t], record.alive[t], record.active[t], record.task_pos_m[t],
                   record.connected[t], record.trees.get(t), problem.radio_range_m,
                   problem.base_range_m, problem.field_half_width_m)
        ax.set_title(f"t = {t}: {record.connected[t].sum()}/{len(record.connected[t])} tasks, "
                     f"{record.active[t].sum()} active", fontsize=8)
    _strip_legend(fig, axes[-1])
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.13, 1, 1))
    fig.savefig(path, dpi=130)
    plt.close(fig)

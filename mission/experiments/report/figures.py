"""Fig. 3-style heatmaps of differences (size × attrition, diverging colour map centred at 0)."""

from __future__ import annotations

import math
import pathlib
from typing import TYPE_CHECKING

import numpy as np

from mission.experiments import paper
from mission.experiments.report.cells import Cell
from mission.experiments.report.markdown import METRIC_LABELS, _pct
from mission.experiments.report.stats import ALPHA, p_greater

if TYPE_CHECKING:
    from matplotlib.image import AxesImage


def _grid_of(
    cells: list[Cell], fn
) -> tuple[np.ndarray, np.ndarray, list[str], list[float], np.ndarray]:
    """``fn(cell) -> (value, mark, significant)`` on the size × attrition grid: the values (nan:
    no data), the marks, the row and column labels, and where the value is significant."""
    sizes = list(dict.fromkeys(c.size for c in cells))
    levels = sorted(dict.fromkeys(c.attrition for c in cells))
    z = np.full((len(sizes), len(levels)), np.nan)
    marks = np.full((len(sizes), len(levels)), "", dtype=object)
    sig = np.zeros((len(sizes), len(levels)), dtype=bool)
    for c in cells:
        i, j = sizes.index(c.size), levels.index(c.attrition)
        z[i, j], marks[i, j], sig[i, j] = fn(c)
    return z, marks, sizes, levels, sig


def _significant_only(z: np.ndarray, sig: np.ndarray) -> np.ndarray:
    return np.where(sig, z, np.nan)


def _common_limit(arrays) -> float:
    """One symmetric colour limit for panels that are compared with each other: the largest
    significant difference (callers pass the non-significant cells as nan), so one noisy cell
    cannot saturate the scale and wash the others out (issue 28 point 10)."""
    finite = [np.abs(z[np.isfinite(z)]) for z in arrays]
    finite = [f for f in finite if f.size]
    return max(1.0, max(float(f.max()) for f in finite)) if finite else 1.0


def _heatmap(ax, z, marks, sizes, levels, title, vmax=None, significant=None) -> AxesImage:
    """One panel. Cells where ``significant`` is False are drawn white (the colour of 0) with
    their number in grey: a difference the tests cannot tell from 0 gets no colour."""
    from matplotlib.colors import TwoSlopeNorm

    sig = np.ones(z.shape, dtype=bool) if significant is None else significant
    colour = np.where(sig | ~np.isfinite(z), z, 0.0)
    finite = colour[np.isfinite(colour) & sig]
    lim = vmax or (max(1.0, float(np.abs(finite).max())) if finite.size else 1.0)
    import matplotlib

    cmap = matplotlib.colormaps["RdBu"].with_extremes(bad="#dddddd")
    im = ax.imshow(
        np.ma.masked_invalid(colour),
        cmap=cmap,
        norm=TwoSlopeNorm(vcenter=0.0, vmin=-lim, vmax=lim),
        aspect="auto",
    )
    ax.set_xticks(range(len(levels)), [f"{_pct(p)} %" for p in levels])
    ax.set_yticks(range(len(sizes)), sizes)
    ax.set_xlabel("attrition per step")
    ax.set_ylabel("size")
    ax.set_title(title, fontsize=9)
    for i in range(z.shape[0]):
        for j in range(z.shape[1]):
            if np.isfinite(z[i, j]):
                strong = sig[i, j] and abs(z[i, j]) > 0.6 * lim
                ax.text(
                    j,
                    i,
                    f"{z[i, j]:+.1f}{marks[i, j]}",
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="white" if strong else ("black" if sig[i, j] else "#888888"),
                )
            else:
                ax.text(j, i, "n/a", ha="center", va="center", fontsize=7, color="#777777")
    return im


def _save(fig, path: pathlib.Path) -> pathlib.Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=130)
    return path


def _pair_diff(cells, other: str, metric: str):
    def fn(c: Cell):
        a, b = c.samples.get("phireman"), c.samples.get(other)
        if a is None or b is None or a.n == 0 or b.n == 0:
            return np.nan, "", False
        mark = (
            "*"
            if p_greater(a, b, metric) < ALPHA
            else ("°" if p_greater(b, a, metric) < ALPHA else "")
        )
        return a.mean(metric) - b.mean(metric), mark, bool(mark)

    return fn


def heatmaps(cells: list[Cell], out: pathlib.Path) -> list[pathlib.Path]:
    """Fig. 3-style heatmaps of differences; returns the PNG paths written."""
    from matplotlib.figure import Figure

    paths = []
    for other in ("dccrs", "mccst"):
        fig = Figure(figsize=(10, 4.2), layout="constrained")
        axes = fig.subplots(1, 2)
        pair_panels = [
            _grid_of(cells, _pair_diff(cells, other, metric)) for metric in paper.METRICS
        ]
        lim = _common_limit(_significant_only(z, sig) for z, *_, sig in pair_panels)
        for ax, metric, (z, marks, sizes, levels, sig) in zip(axes, paper.METRICS, pair_panels):
            im = _heatmap(
                ax,
                z,
                marks,
                sizes,
                levels,
                f"{METRIC_LABELS[metric]}: ΦIREMAN − {paper.METHOD_LABELS[other]} (pp)",
                vmax=lim,
                significant=sig,
            )
            fig.colorbar(im, ax=ax, shrink=0.8)
        fig.suptitle(
            f"ΦIREMAN − {paper.METHOD_LABELS[other]}; * ΦIREMAN significantly higher, "
            f"° significantly lower (one-tailed t-test, p < 0.05)",
            fontsize=9,
        )
        paths.append(_save(fig, out / f"fig3_phireman_minus_{other}.png"))

    # The paper's Fig. 3: ΦIREMAN minus the better baseline, ours against the paper's.
    def ours(metric):
        def fn(c: Cell):
            a = c.samples.get("phireman")
            base = [
                b for b in (c.samples.get(m) for m in ("dccrs", "mccst")) if b is not None and b.n
            ]
            if a is None or not a.n or not base:
                return np.nan, "", False
            v = c.unpaired[metric]
            mark = (
                "*" if (v.significant and v.best == "phireman") else ("°" if v.significant else "")
            )
            return a.mean(metric) - max(b.mean(metric) for b in base), mark, bool(mark)

        return fn

    def theirs(metric):
        def fn(c: Cell):
            vals = {
                m: paper.paper_value(c.size, c.attrition, m, metric) for m in paper.PAPER_METHODS
            }
            if any(v is None for v in vals.values()):
                return np.nan, "", False
            bold = paper.paper_bold(c.size, c.attrition, metric)
            mark = "*" if bold == "phireman" else ("°" if bold else "")
            return vals["phireman"][0] - max(vals["dccrs"][0], vals["mccst"][0]), mark, bool(mark)  # type: ignore[index]  # none is None (above)

        return fn

    fig = Figure(figsize=(10, 8), layout="constrained")
    axes = fig.subplots(2, 2)
    panels = {
        (row, col): _grid_of(cells, fn(metric))
        for row, (who, fn) in enumerate((("ours", ours), ("paper", theirs)))
        for col, metric in enumerate(paper.METRICS)
    }
    # compared panels share one colour scale
    lim = _common_limit(_significant_only(z, sig) for z, *_, sig in panels.values())
    for (row, col), (z, marks, sizes, levels, sig) in panels.items():
        who, metric = ("ours", "paper")[row], paper.METRICS[col]
        im = _heatmap(
            axes[row, col],
            z,
            marks,
            sizes,
            levels,
            f"{who}: {METRIC_LABELS[metric]}, ΦIREMAN − max(DCCRS, MCCST) (pp)",
            vmax=lim,
            significant=sig,
        )
        fig.colorbar(im, ax=axes[row, col], shrink=0.8)
    fig.suptitle(
        "Fig. 3 style: * ΦIREMAN beats both baselines, ° a baseline beats both others "
        "(p < 0.05; paper: its bold cells)",
        fontsize=9,
    )
    paths.append(_save(fig, out / "fig3_phireman_minus_best_baseline.png"))

    # Ours minus the paper, per method: where the reproduction deviates.
    fig = Figure(figsize=(10, 11), layout="constrained")
    axes = fig.subplots(3, 2)
    panels = {}
    for row, m in enumerate(paper.PAPER_METHODS):
        for col, metric in enumerate(paper.METRICS):

            def fn(c: Cell, m=m, metric=metric):
                d = c.delta(m, metric)
                if math.isnan(d):
                    return d, "", False
                # Significant: Δ outside the combined 95 % CIs of ours and the paper's.
                half = c.samples[m].mean_ci(metric)[1]  # type: ignore[union-attr]  # d not nan
                ref = paper.paper_value(c.size, c.attrition, m, metric)
                assert ref is not None  # d not nan
                sig = not math.isnan(half) and abs(d) > math.hypot(half, ref[1])
                return d, ("!" if c.grade(m, metric) is False else ""), sig

            panels[(row, col)] = _grid_of(cells, fn)
    lim = _common_limit(_significant_only(z, sig) for z, *_, sig in panels.values())
    for (row, col), (z, marks, sizes, levels, sig) in panels.items():
        m, metric = paper.PAPER_METHODS[row], paper.METRICS[col]
        im = _heatmap(
            axes[row, col],
            z,
            marks,
            sizes,
            levels,
            f"{paper.METHOD_LABELS[m]} {METRIC_LABELS[metric]}: ours − paper (pp)",
            vmax=lim,
            significant=sig,
        )
        fig.colorbar(im, ax=axes[row, col], shrink=0.8)
    fig.suptitle(
        "Ours − paper; ! outside the tolerance (ΦIREMAN 3 pp, baselines 5 pp); white: within "
        "the combined 95 % CIs",
        fontsize=9,
    )
    paths.append(_save(fig, out / "delta_vs_paper.png"))
    return paths

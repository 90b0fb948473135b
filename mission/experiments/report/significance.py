"""Our significance pattern against the paper's bold cells, and per baseline where it bolds ΦIREMAN."""

from __future__ import annotations

from mission.experiments import paper
from mission.experiments.report.cells import Cell
from mission.experiments.report.markdown import METRIC_LABELS, SHORT, _fmt_p, _pct
from mission.experiments.report.stats import ALPHA, p_greater, p_greater_paired


def _bold_agreement(cells: list[Cell]) -> tuple[str, dict]:
    agree_u = agree_p = total = 0
    diffs = []
    for c in cells:
        for metric in paper.METRICS:
            ref = paper.paper_bold(c.size, c.attrition, metric)
            u = c.unpaired[metric]
            p = c.paired[metric]
            if u.best is None:
                continue
            total += 1
            ours_u = u.best if u.significant else None
            ours_p = p.best if p.significant else None
            agree_u += ours_u == ref
            agree_p += ours_p == ref
            if ours_u != ref:
                name = lambda m: paper.METHOD_LABELS.get(m, m) if m else "none"  # noqa: E731
                means = ", ".join(
                    f"{SHORT.get(m, m)} {s.mean(metric):.2f}"
                    for m, s in c.samples.items()
                    if s is not None and s.n
                )
                diffs.append(
                    f"- {c.size} / {_pct(c.attrition)} % {METRIC_LABELS[metric]}: paper bolds "
                    f"{name(ref)}, we bold {name(ours_u)} (best {SHORT.get(u.best, u.best)}, "
                    f"p = {_fmt_p(u.p)}; paired: {name(ours_p)}, p = {_fmt_p(p.p)}; means {means})"
                )
    text = (
        f"The paper's bold cells are read from its LaTeX source (`\\textbf` entries of Table II), not "
        f"approximated. Of {total} (configuration, metric) cells with data, our unpaired test gives "
        f"the same bold method (or none) in **{agree_u}**, the paired test in **{agree_p}**."
    )
    pairwise, pair_stats = _phireman_vs_each(cells)
    if pairwise:
        text += "\n\n" + pairwise
    if diffs:
        text += (
            "\n\nCells where our unpaired significance differs from the paper's bolding:\n\n"
            + "\n".join(diffs)
        )
    return text, {"cells": total, "agree_unpaired": agree_u, "agree_paired": agree_p, **pair_stats}


def _phireman_vs_each(cells: list[Cell]) -> tuple[str, dict]:
    """Where the paper bolds ΦIREMAN, is ours significantly above each baseline on its own?

    A bold needs ΦIREMAN above *both* baselines; splitting the test per baseline shows which one
    a disagreement comes from (our DCCRS is a reconstruction, MCCST a published algorithm)."""
    baselines = [m for m in paper.PAPER_METHODS if m != "phireman"]
    bold_cells = []
    for c in cells:
        phi = c.samples.get("phireman")
        if phi is None or phi.n < 2:
            continue
        for metric in paper.METRICS:
            if paper.paper_bold(c.size, c.attrition, metric) != "phireman":
                continue
            others = {b: o for b in baselines if (o := c.samples.get(b)) is not None and o.n >= 2}
            if len(others) < len(baselines):
                continue
            bold_cells.append(
                {
                    b: (p_greater(phi, o, metric) < ALPHA, p_greater_paired(phi, o, metric) < ALPHA)
                    for b, o in others.items()
                }
            )
    if not bold_cells:
        return "", {}
    n = len(bold_cells)
    counts = {
        b: (sum(v[b][0] for v in bold_cells), sum(v[b][1] for v in bold_cells)) for b in baselines
    }
    both = (
        sum(all(v[b][0] for b in baselines) for v in bold_cells),
        sum(all(v[b][1] for b in baselines) for v in bold_cells),
    )
    parts = [
        f"{paper.METHOD_LABELS.get(b, b)} in **{counts[b][0]}** (paired {counts[b][1]})"
        for b in baselines
    ]
    text = (
        f"Per baseline: the paper bolds ΦIREMAN in {n} (configuration, metric) cells. There, our "
        f"ΦIREMAN is significantly above "
        + ", above ".join(parts)
        + f", and above both (a bold) in {both[0]} (paired {both[1]}); one-tailed tests at p < {ALPHA:g}."
    )
    stats_out = {"paper_bolds_phireman": n, "bold_both": both[0], "bold_both_paired": both[1]}
    stats_out.update({f"above_{b}": counts[b][0] for b in baselines})
    stats_out.update({f"above_{b}_paired": counts[b][1] for b in baselines})
    return text, stats_out

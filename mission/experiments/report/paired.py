"""Paired comparisons, cell by cell on shared seeds: ΦIREMAN under asynchronous and central
information against the paper, and your planner (``--method``) against ΦIREMAN."""

from __future__ import annotations

import math

import numpy as np

from mission.experiments import paper
from mission.experiments.report.cells import Cell
from mission.experiments.report.markdown import _fmt, _fmt_p, _md_table, _pct, _signed
from mission.experiments.report.stats import ALPHA, _quiet


def _central_vs_async(cells: list[Cell], central: list[Cell]) -> tuple[str, dict] | None:
    """PhiIREMAN under both information models against the paper, cell by cell (None when the
    store has no ``phireman-central`` runs on the paper-table configurations)."""
    by_key = {(c.size, c.attrition): c.samples.get("phireman-central") for c in central}
    if not any(s is not None and s.n for s in by_key.values()):
        return None
    rows, within = [], {"async": 0, "central": 0, "configs": 0}
    for c in cells:
        a, z = c.samples.get("phireman"), by_key.get((c.size, c.attrition))
        refs = [paper.paper_value(c.size, c.attrition, "phireman", k) for k in paper.METRICS]
        row = [
            c.size,
            _pct(c.attrition) + (" †" if c.attrition >= 0.05 else ""),
            " / ".join(f"{r[0]:.2f}" if r else "–" for r in refs),
        ]
        core = c.attrition <= 0.02 + 1e-12
        within["configs"] += core
        for name, smp in (("async", a), ("central", z)):
            ok_both = True
            for k, ref in zip(paper.METRICS, refs):
                if smp is None or smp.n == 0 or ref is None:
                    row.append("–")
                    ok_both = False
                    continue
                d = smp.mean(k) - ref[0]
                mean, half = smp.mean_ci(k)
                tol = paper.TOLERANCE_PP["phireman"] + 1e-9
                few = math.isnan(half) or half > tol  # as Cell.too_few_seeds
                ok = abs(d) <= tol and not few
                ok_both &= ok
                mark = " too few seeds" if few else (" ✓" if ok else "")
                row.append(f"{_fmt(mean, half)} ({_signed(d)}{mark})")
            within[name] += core and ok_both
        row.append(f"{a.n if a else 0} / {z.n if z else 0}")
        rows.append(row)
    table = _md_table(
        [
            "Size",
            "p (%)",
            "paper TU1 / TU2",
            "async TU1 (Δ)",
            "async TU2 (Δ)",
            "central TU1 (Δ)",
            "central TU2 (Δ)",
            "n async / central",
        ],
        rows,
        "lrllllll",
    )
    text = [
        table,
        "",
        f"- ΦIREMAN asynchronous (the paper's information model): within 3 pp on both TU1 and TU2 "
        f"in **{within['async']} of {within['configs']}** configurations at 0–2 % attrition.",
        f"- ΦIREMAN planned centrally (`phireman-central`, the ground station's model, same seeds): "
        f"within 3 pp in **{within['central']} of {within['configs']}**.",
    ]
    return "\n".join(text), within


def _paired_vs_phireman(cells: list[Cell], method: str) -> tuple[str, dict] | None:
    """Your planner (``--method``) against our ΦIREMAN, cell by cell, paired by seed (two-sided
    ``ttest_rel`` on the seeds both share: common random numbers). None without its runs."""
    from scipy import stats

    rows, counts = [], {"cells": 0, "below95": 0, "better_both": 0, "better_below95": 0, "worse": 0}
    for c in cells:
        a, b = c.samples.get(method), c.samples.get("phireman")
        if a is None or b is None or not a.n or not b.n:
            continue
        ref = paper.paper_value(c.size, c.attrition, "phireman", "tu1")
        below = ref is not None and ref[0] < 95.0
        row = [c.size, _pct(c.attrition) + (" ‡" if below else ""), "", ""]
        verdicts, n = [], 0
        for k in paper.METRICS:
            common = sorted(set(a.by_seed[k]) & set(b.by_seed[k]))
            n = len(common)
            x = np.array([a.by_seed[k][s] for s in common])
            y = np.array([b.by_seed[k][s] for s in common])
            if n < 2:
                row.append("–")
                verdicts.append(0)
                continue
            pv = 1.0 if np.all(x == y) else _quiet(stats.ttest_rel, x, y)
            d = float((x - y).mean())
            row.append(f"{_signed(d)} ({_fmt_p(pv)})")
            verdicts.append(0 if pv >= ALPHA else (1 if d > 0 else -1))
        row[2] = " / ".join(f"{b.mean(k):.2f}" for k in paper.METRICS)
        row[3] = " / ".join(f"{a.mean(k):.2f}" for k in paper.METRICS)
        better, worse = all(v == 1 for v in verdicts), any(v == -1 for v in verdicts)
        row += ["better (both)" if better else ("worse" if worse else "n.s."), str(n)]
        rows.append(row)
        counts["cells"] += 1
        counts["below95"] += below
        counts["better_both"] += better
        counts["better_below95"] += better and below
        counts["worse"] += worse
    if not rows:
        return None
    table = _md_table(
        [
            "Size",
            "p (%)",
            "`phireman` TU1 / TU2",
            f"`{method}` TU1 / TU2",
            "Δ TU1 (p)",
            "Δ TU2 (p)",
            "verdict",
            "n",
        ],
        rows,
        "lrllllll",
    )
    text = [
        f"Δ = `{method}` − `phireman` on the seeds both ran (pp); p: two-sided paired t-test "
        '(`ttest_rel`); "better (both)": Δ > 0 with p < 0.05 on TU1 and on TU2. ‡: the paper\'s '
        "ΦIREMAN is below 95 % TU1.",
        "",
        table,
        "",
        f"- significantly better on both TU1 and TU2 in **{counts['better_both']} of {counts['cells']}** "
        f"configurations ({counts['better_below95']} of the {counts['below95']} ‡ ones); significantly "
        f"worse on either in **{counts['worse']}**.",
    ]
    return "\n".join(text), counts

"""Configurations besides the paper's (custom sweeps, tuning) and the per-configuration CSV."""

from __future__ import annotations

import math

from mission.experiments import paper
from mission.experiments.report.markdown import _fmt, _md_table, _pct
from mission.experiments.report.stats import Sample
from mission.experiments.sweep import ConfigSpec


def _overrides_text(spec: ConfigSpec) -> str:
    items = {**spec.problem_overrides, **spec.params}
    return ", ".join(f"{k}={v}" for k, v in items.items()) or "—"


CSV_FIELDS = [
    "spec_key",
    "label",
    "size",
    "attrition",
    "reading",
    "method",
    "overrides",
    "n_ok",
    "n_error",
    "tu1_mean_pct",
    "tu1_ci95_pct",
    "tu2_mean_pct",
    "tu2_ci95_pct",
    "paper_tu1_pct",
    "paper_tu1_ci95_pct",
    "paper_tu2_pct",
    "paper_tu2_ci95_pct",
    "delta_tu1_pp",
    "delta_tu2_pp",
    "within_tolerance",
    "code_versions",
]


def _csv_row(s: Sample, in_table: bool) -> dict:
    spec = s.spec
    t1, c1 = s.mean_ci("tu1")
    t2, c2 = s.mean_ci("tu2")
    row = {
        "spec_key": spec.spec_key,
        "label": spec.label,
        "size": spec.size,
        "attrition": spec.attrition,
        "reading": spec.reading,
        "method": spec.method,
        "overrides": _overrides_text(spec),
        "n_ok": s.n,
        "n_error": s.n_error,
        "tu1_mean_pct": t1,
        "tu1_ci95_pct": c1,
        "tu2_mean_pct": t2,
        "tu2_ci95_pct": c2,
        "code_versions": "; ".join(f"{v} ({n})" for v, n in s.code_versions.items()),
    }
    p1 = paper.paper_value(spec.size, spec.attrition, spec.method, "tu1") if in_table else None
    p2 = paper.paper_value(spec.size, spec.attrition, spec.method, "tu2") if in_table else None
    if p1 and p2 and s.n:
        d1, d2 = t1 - p1[0], t2 - p2[0]
        tol = paper.TOLERANCE_PP.get(spec.method, 5.0)
        row.update(
            paper_tu1_pct=p1[0],
            paper_tu1_ci95_pct=p1[1],
            paper_tu2_pct=p2[0],
            paper_tu2_ci95_pct=p2[1],
            delta_tu1_pp=round(d1, 4),
            delta_tu2_pp=round(d2, 4),
            within_tolerance=abs(d1) <= tol and abs(d2) <= tol,
        )
    return {k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()}


def _differs_from_paper(problem_overrides: dict, params: dict, reading: str) -> list[str]:
    """Why configurations under these overrides are not the paper's (empty: they are)."""
    from planner.problem import problem_preset

    why = []
    ref = problem_preset("S", 0.01, reading)
    for k, v in problem_overrides.items():
        was = getattr(ref, k, None)
        why.append(
            f"{k}={v} (the paper's: {was:g})"
            if isinstance(was, (int, float)) and not isinstance(was, bool)
            else f"{k}={v}"
        )
    why += [f"{k}={v} (planner parameter)" for k, v in params.items()]
    return why


def _your_configurations(samples: list[tuple[Sample, str]]) -> str:
    """Every configuration with data, the user's first: (sample, paper cell text)."""
    rows_md = []
    for s, ref in samples:
        spec = s.spec
        rows_md.append(
            [
                spec.size,
                _pct(spec.attrition),
                spec.method,
                spec.label or "—",
                _overrides_text(spec),
                spec.reading,
                str(s.n),
                str(s.n_error),
                _fmt(*s.mean_ci("tu1")),
                _fmt(*s.mean_ci("tu2")),
                ref,
            ]
        )
    return _md_table(
        [
            "size",
            "p (%)",
            "method",
            "label",
            "overrides",
            "reading",
            "n",
            "errors",
            "TU1 (%)",
            "TU2 (%)",
            "paper TU1 / TU2",
        ],
        rows_md,
        "lrllllrrrrl",
    )

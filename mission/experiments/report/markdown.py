"""Formatting helpers of the Markdown report: numbers, p-values, signed deltas, tables."""

from __future__ import annotations

import math


METRIC_LABELS = {"tu1": "TU1", "tu2": "TU2"}


SHORT = {"phireman": "Φ", "dccrs": "D", "mccst": "M"}


def _fmt(mean: float, ci: float) -> str:
    """'mean ± half', or the interval clipped to [0, 100] when it reaches past (few seeds)."""
    from mission.experiments.sim import format_pct_ci

    if math.isnan(mean):
        return "–"
    if math.isnan(ci):
        return f"{mean:.2f}"
    return format_pct_ci(mean, ci)[0]


def _fmt_p(p: float) -> str:
    if math.isnan(p):
        return "–"
    return f"{p:.1e}" if p < 1e-3 else f"{p:.3f}"


def _pct(p: float) -> str:
    return f"{100 * p:g}"


def _signed(x: float) -> str:
    return "–" if math.isnan(x) else f"{x:+.2f}"


def _md_table(header: list[str], rows: list[list[str]], align: str | None = None) -> str:
    align = align or "l" * len(header)
    sep = ["---:" if a == "r" else (":---:" if a == "c" else "---") for a in align]
    out = ["| " + " | ".join(header) + " |", "| " + " | ".join(sep) + " |"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)

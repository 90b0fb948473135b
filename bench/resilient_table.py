"""Issue 15: ΦIREMAN-resilient against ΦIREMAN on the paper's 25 configurations, paired by seed.

Reads results stores written by ``phireman sweep`` (nothing is run here) and prints Markdown:

* the 25-configuration table: the paper's ΦIREMAN, ours (``phireman``), ``phireman-resilient``,
  Δ and the paired t-test p-values (two-sided, on the seeds both methods share: the scenarios and
  attrition draws are common random numbers);
* optionally (``--ablations``) the ablation table: each variant of ``phireman-resilient`` whose
  planner parameters differ from the defaults, paired against the default on the same seeds.

Rows are selected by method, size, attrition, the scaled reading, no problem overrides and (for
the main table) no parameter overrides. The ``phireman`` rows may come from another store (the
paper table's), so the method need not be rerun; ``--check-seeds`` lists seeds whose ``phireman``
rows must be rerun first with ``bench/resilient_check.py`` to prove that the stored rows still
match the code.

usage:
  python bench/resilient_table.py --baseline paper.sqlite --store resilient.sqlite [--ablations]
  # planned centrally (the station's case), against ΦIREMAN planned centrally
  python bench/resilient_table.py --baseline central.sqlite --base-method phireman-central \
      --store central.sqlite --new-set info=central
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys

import numpy as np
from scipy import stats

from mission.experiments.paper import paper_value
from planner.problem import ATTRITION_LEVELS, SIZES

NEW = "phireman-resilient"
BASE = "phireman"


def load(
    path: str, method: str, params: dict | None = None
) -> dict[tuple[str, float], dict[int, tuple[float, float]]]:
    """{(size, attrition): {seed: (tu1 %, tu2 %)}} for ``method`` with exactly these parameter overrides."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    out: dict = {}
    for size, att, seed, tu1, tu2, spec in con.execute(
        "SELECT size, attrition, seed, tu1, tu2, spec_json FROM runs WHERE method = ? AND status = 'ok' "
        "AND reading = 'scaled'",
        (method,),
    ):
        s = json.loads(spec)
        if s.get("problem_overrides") or (s.get("params") or {}) != (params or {}):
            continue
        out.setdefault((size, round(att, 6)), {})[int(seed)] = (100 * tu1, 100 * tu2)
    con.close()
    return out


def variants(path: str, method: str) -> list[dict]:
    """Every distinct parameter-override set of ``method`` in the store (no problem overrides)."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    seen = []
    for (spec,) in con.execute("SELECT DISTINCT spec_json FROM runs WHERE method = ?", (method,)):
        s = json.loads(spec)
        if not s.get("problem_overrides") and s.get("params") and s["params"] not in seen:
            seen.append(s["params"])
    con.close()
    return seen


def paired(
    a: dict[int, tuple], b: dict[int, tuple], k: int
) -> tuple[int, float, float, float, float]:
    """(n, mean a, mean b, mean(a - b), two-sided paired p) over the shared seeds, metric k."""
    seeds = sorted(set(a) & set(b))
    if len(seeds) < 2:
        return len(seeds), np.nan, np.nan, np.nan, np.nan
    x = np.array([a[s][k] for s in seeds])
    y = np.array([b[s][k] for s in seeds])
    p = 1.0 if np.all(x == y) else float(stats.ttest_rel(x, y).pvalue)
    return len(seeds), float(x.mean()), float(y.mean()), float((x - y).mean()), p


def _p(p: float) -> str:
    return "–" if np.isnan(p) else (f"{p:.1e}" if p < 1e-3 else f"{p:.3f}")


def _verdict(d: float, p: float) -> str:
    if np.isnan(p) or p >= 0.05:
        return "n.s."
    return "**better**" if d > 0 else "*worse*"


def main_table(
    baseline: dict, new: dict, base_label: str = BASE, new_label: str = NEW
) -> tuple[str, dict]:
    lines = [
        f"| Size | p (%) | paper Φ TU1 / TU2 | ours `{base_label}` TU1 / TU2 | `{new_label}` TU1 / TU2 "
        "| Δ TU1 (p) | Δ TU2 (p) | verdict | n |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: |",
    ]
    counts = {
        "better_both": 0,
        "worse_any": 0,
        "cells": 0,
        "below95": 0,
        "better_both_below95": 0,
        "worse_any_below95": 0,
        "better_tu1": 0,
        "better_tu2": 0,
        "better_both_1t": 0,
        "better_both_1t_below95": 0,
        "worse_any_1t": 0,
    }
    for size in SIZES:
        for att in ATTRITION_LEVELS:
            key = (size, round(att, 6))
            pv1, pv2 = (
                paper_value(size, att, "phireman", "tu1"),
                paper_value(size, att, "phireman", "tu2"),
            )
            a, b = new.get(key, {}), baseline.get(key, {})
            n, m1, b1, d1, p1 = paired(a, b, 0)
            _, m2, b2, d2, p2 = paired(a, b, 1)
            below = pv1 is not None and pv1[0] < 95.0
            if n >= 2:
                counts["cells"] += 1
                better = all(
                    not np.isnan(p) and p < 0.05 and d > 0 for d, p in ((d1, p1), (d2, p2))
                )
                worse = any(not np.isnan(p) and p < 0.05 and d < 0 for d, p in ((d1, p1), (d2, p2)))
                counts["better_both"] += better
                counts["worse_any"] += worse
                # one-tailed paired test in the direction of Δ (the paper's and `phireman report`'s convention)
                better1 = all(
                    not np.isnan(p) and p / 2 < 0.05 and d > 0 for d, p in ((d1, p1), (d2, p2))
                )
                worse1 = any(
                    not np.isnan(p) and p / 2 < 0.05 and d < 0 for d, p in ((d1, p1), (d2, p2))
                )
                counts["worse_any_1t"] += worse1
                counts["better_both_1t"] += better1
                counts["better_both_1t_below95"] += better1 and below
                counts["better_tu1"] += p1 < 0.05 and d1 > 0
                counts["better_tu2"] += p2 < 0.05 and d2 > 0
                if below:
                    counts["below95"] += 1
                    counts["better_both_below95"] += better
                    counts["worse_any_below95"] += worse
                verdict = (
                    "better (both)"
                    if better
                    else (
                        "worse"
                        if worse
                        else " / ".join(_verdict(d, p) for d, p in ((d1, p1), (d2, p2)))
                    )
                )
            else:
                verdict = "no data"
            paper = f"{pv1[0]:.2f} / {pv2[0]:.2f}" if pv1 and pv2 else "–"
            lines.append(
                f"| {size} | {100 * att:g} | {paper}{' ‡' if below else ''} | {b1:.2f} / {b2:.2f} | "
                f"{m1:.2f} / {m2:.2f} | {d1:+.2f} ({_p(p1)}) | {d2:+.2f} ({_p(p2)}) | {verdict} | {n} |"
            )
    return "\n".join(lines), counts


def ablation_table(path: str, cells: list[tuple[str, float]]) -> str:
    default = load(path, NEW)
    lines = [
        "| cell | variant | TU1 | TU2 | Δ TU1 vs default (p) | Δ TU2 vs default (p) | n |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for size, att in cells:
        key = (size, round(att, 6))
        d = default.get(key, {})
        if len(d) >= 2:
            arr = np.array(list(d.values()))
            lines.append(
                f"| {size} / {100 * att:g} % | default | {arr[:, 0].mean():.2f} | {arr[:, 1].mean():.2f} "
                f"| – | – | {len(d)} |"
            )
        for params in variants(path, NEW):
            v = load(path, NEW, params).get(key, {})
            if len(v) < 2:
                continue
            n, m1, _, d1, p1 = paired(v, d, 0)
            _, m2, _, d2, p2 = paired(v, d, 1)
            label = ", ".join(f"{k}={val}" for k, val in sorted(params.items()))
            lines.append(
                f"| {size} / {100 * att:g} % | {label} | {m1:.2f} | {m2:.2f} | {d1:+.2f} ({_p(p1)}) "
                f"| {d2:+.2f} ({_p(p2)}) | {n} |"
            )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--baseline", required=True, help="store with the phireman rows (e.g. the paper table's)"
    )
    ap.add_argument("--store", required=True, help="store with the phireman-resilient rows")
    ap.add_argument(
        "--ablations",
        nargs="*",
        default=None,
        metavar="SIZE:PCT",
        help="ablation cells, e.g. S:1 M:2 (default when given without values: S:1 M:2)",
    )
    ap.add_argument(
        "--base-method", default=BASE, help=f"method of the baseline rows (default {BASE})"
    )
    ap.add_argument(
        "--new-set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="parameter overrides of the new rows (e.g. info=central: the station's central planning)",
    )
    args = ap.parse_args(argv)
    new_params = {}
    for item in args.new_set:
        key, _, value = item.partition("=")
        new_params[key] = json.loads(value) if value[:1] in "0123456789-[{tf" else value
    base = load(args.baseline, args.base_method)
    new = load(args.store, NEW, new_params or None)
    label = NEW + (f" ({', '.join(args.new_set)})" if args.new_set else "")
    table, counts = main_table(base, new, args.base_method, label)
    print(table)
    print()
    print(
        f"- cells with data: {counts['cells']} of 25; significantly better on both TU1 and TU2 "
        f"(two-sided paired t-test, p < 0.05): **{counts['better_both']}**; significantly worse on TU1 or "
        f"TU2: **{counts['worse_any']}**; better on TU1: {counts['better_tu1']}, on TU2: {counts['better_tu2']}"
    )
    print(
        f"- among the {counts['below95']} cells where the paper's ΦIREMAN is below 95 % TU1 (‡): better on "
        f"both {counts['better_both_below95']}, worse on either {counts['worse_any_below95']}"
    )
    print(
        f"- with the one-tailed paired test (p/2 in the direction of Δ, the paper's convention): better on both "
        f"in {counts['better_both_1t']} cells, {counts['better_both_1t_below95']} of them ‡; worse on either in "
        f"{counts['worse_any_1t']}"
    )
    if args.ablations is not None:
        cells = []
        for item in args.ablations or ["S:1", "M:2"]:
            size, pct = item.split(":")
            cells.append((size.upper(), float(pct) / 100))
        print()
        print(ablation_table(args.store, cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Issue 28: ``phireman-resilient`` with the base's heard picture against the oracle base and ΦIREMAN.

Reads three results stores written by ``phireman sweep`` (nothing is run here) and prints
Markdown: per configuration, ΦIREMAN (``phireman``), the planner whose base read the truth
(``base_view='oracle'``: the rows of ``docs/results/resilient.sqlite.xz``, made before the
parameter existed, so their ``params`` are ``{}``) and the planner whose base hears the mesh
through the message layer (``base_view='heard'``, the default since issue 28; its rows'
``params`` are ``{}`` in its own store), with the paired differences (two-sided paired t-test on
the shared seeds, ``scipy.stats.ttest_rel``) and the Holm-corrected verdicts.

Holm's step-down correction (family-wise error 5 %) is applied per comparison over its 50 tests
(25 configurations x TU1 and TU2); a cell is "better" when Δ > 0 on both metrics with p < 0.05
(uncorrected) or adjusted p < 0.05 (Holm), "worse" when Δ < 0 on either with the same test.

usage:
  python bench/resilient_heard_table.py --phireman paper.sqlite --oracle resilient.sqlite \
      --heard resilient_heard.sqlite
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from resilient_table import NEW, _p, load, paired

from mission.experiments.paper import paper_value
from planner.problem import ATTRITION_LEVELS, SIZES


def holm(p: np.ndarray) -> np.ndarray:
    """Holm-adjusted p-values (NaN stays NaN and is left out of the family)."""
    p = np.asarray(p, float)
    out = np.full_like(p, np.nan)
    ok = np.flatnonzero(~np.isnan(p))
    order = ok[np.argsort(p[ok], kind="stable")]
    m = len(order)
    adj = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * p[order]))
    out[order] = adj
    return out


def compare(a: dict, b: dict) -> list[tuple]:
    """Per cell (size, att): (n, mean a TU1, TU2, Δ TU1, p TU1, Δ TU2, p TU2), a against b."""
    rows = []
    for size in SIZES:
        for att in ATTRITION_LEVELS:
            key = (size, round(att, 6))
            x, y = a.get(key, {}), b.get(key, {})
            n, m1, _, d1, p1 = paired(x, y, 0)
            _, m2, _, d2, p2 = paired(x, y, 1)
            rows.append((size, att, n, m1, m2, d1, p1, d2, p2))
    return rows


def _judge(d1: float, d2: float, q1: float, q2: float) -> tuple[bool, bool]:
    """(better on both, worse on either) at 5 % with p-values ``q1``, ``q2``."""
    sig = [not np.isnan(q) and q < 0.05 for q in (q1, q2)]
    better = sig[0] and sig[1] and d1 > 0 and d2 > 0
    worse = (sig[0] and d1 < 0) or (sig[1] and d2 < 0)
    return better, worse


def verdicts(rows: list[tuple]) -> tuple[list[str], dict]:
    """The cell verdicts (uncorrected / Holm) and the counts."""
    p = np.array([[r[6], r[8]] for r in rows]).ravel()
    adj = holm(p).reshape(-1, 2)
    counts = {
        k: 0
        for k in (
            "better",
            "worse",
            "better_holm",
            "worse_holm",
            "better_dd",
            "worse_dd",
            "better_dd_holm",
            "worse_dd_holm",
        )
    }
    out = []
    for r, (a1, a2) in zip(rows, adj):
        size, att, n, _, _, d1, p1, d2, p2 = r
        if n < 2:
            out.append("no data")
            continue
        pv = paper_value(size, att, "phireman", "tu1")
        below = pv is not None and pv[0] < 95.0

        b, w = _judge(d1, d2, p1, p2)
        bh, wh = _judge(d1, d2, a1, a2)
        counts["better"] += b
        counts["worse"] += w
        counts["better_holm"] += bh
        counts["worse_holm"] += wh
        counts["better_dd"] += b and below
        counts["worse_dd"] += w and below
        counts["better_dd_holm"] += bh and below
        counts["worse_dd_holm"] += wh and below
        word = "better" if b else ("worse" if w else "n.s.")
        word_h = "better" if bh else ("worse" if wh else "n.s.")
        out.append(f"{word} / {word_h}")
    return out, counts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--phireman", required=True, help="store with the phireman rows")
    ap.add_argument("--oracle", required=True, help="store with the oracle-base rows (params {})")
    ap.add_argument("--heard", required=True, help="store with the heard-base rows (params {})")
    args = ap.parse_args(argv)
    phi = load(args.phireman, "phireman")
    oracle = load(args.oracle, NEW)
    heard = load(args.heard, NEW)
    r_or, r_he, r_ho = compare(oracle, phi), compare(heard, phi), compare(heard, oracle)
    v_or, c_or = verdicts(r_or)
    v_he, c_he = verdicts(r_he)
    v_ho, c_ho = verdicts(r_ho)
    print(
        "| Size | p (%) | `phireman` TU1 / TU2 | oracle base TU1 / TU2 | Δ vs Φ TU1 (p) / TU2 (p) "
        "| verdict (unc. / Holm) | heard base TU1 / TU2 | Δ vs Φ TU1 (p) / TU2 (p) "
        "| verdict (unc. / Holm) | heard − oracle TU1 (p) / TU2 (p) | n |"
    )
    print("| --- | ---: | ---: | ---: | ---: | --- | ---: | ---: | --- | ---: | ---: |")
    for i, (size, att, *_rest) in enumerate(r_he):
        key = (size, round(att, 6))
        seeds = phi.get(key, {})
        base = np.array(list(seeds.values())) if seeds else np.full((1, 2), np.nan)
        pv = paper_value(size, att, "phireman", "tu1")
        dd = " ‡" if pv is not None and pv[0] < 95.0 else ""
        o, h, ho = r_or[i], r_he[i], r_ho[i]
        print(
            f"| {size} | {100 * att:g}{dd} | {base[:, 0].mean():.2f} / {base[:, 1].mean():.2f} "
            f"| {o[3]:.2f} / {o[4]:.2f} | {o[5]:+.2f} ({_p(o[6])}) / {o[7]:+.2f} ({_p(o[8])}) "
            f"| {v_or[i]} | {h[3]:.2f} / {h[4]:.2f} "
            f"| {h[5]:+.2f} ({_p(h[6])}) / {h[7]:+.2f} ({_p(h[8])}) | {v_he[i]} "
            f"| {ho[5]:+.2f} ({_p(ho[6])}) / {ho[7]:+.2f} ({_p(ho[8])}) | {h[2]} |"
        )
    print()
    for label, c in (
        ("oracle base vs `phireman`", c_or),
        ("heard base vs `phireman`", c_he),
        ("heard base vs oracle base", c_ho),
    ):
        print(
            f"- {label}: better on both TU1 and TU2 in **{c['better']}** cells uncorrected, "
            f"**{c['better_holm']}** Holm; worse on either in **{c['worse']}** uncorrected, "
            f"**{c['worse_holm']}** Holm (of the 16 ‡ cells: better {c['better_dd']} uncorrected, "
            f"{c['better_dd_holm']} Holm; worse {c['worse_dd']} uncorrected, {c['worse_dd_holm']} Holm)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The ablation table (S / 1 %): each variant against the default, and against the paper's italics."""

from __future__ import annotations

from mission.experiments import paper
from mission.experiments.report.markdown import _fmt, _fmt_p, _md_table
from mission.experiments.report.selection import Selector
from mission.experiments.report.stats import ALPHA, p_greater, p_greater_paired
from mission.experiments.sweep import paper_ablations_grid


def _ablations(
    selector: Selector, reading: str, params: dict, problem_overrides: dict
) -> tuple[str, list]:
    grid = paper_ablations_grid(
        seeds=[], reading=reading, params=params, problem_overrides=problem_overrides
    )
    samples = {spec.label: (spec, selector.sample(spec)) for spec in grid.configs}
    default = samples["default"][1]
    paper_rows = {r.label: r for r in paper.ABLATIONS}
    header = [
        "Configuration",
        "TU1 (ours)",
        "TU2 (ours)",
        "TU1 (paper)",
        "TU2 (paper)",
        "below default: ours TU1 / TU2 (p unpaired; paired)",
        "paper",
        "agrees",
    ]
    rows, csv_samples = [], []
    for label, (_spec, s) in samples.items():
        ref = paper_rows.get(label)
        csv_samples.append(s if s is not None else None)
        if s is None or s.n == 0:
            rows.append(
                [
                    label,
                    "–",
                    "–",
                    _fmt(ref.tu1, ref.tu1_ci) if ref else "–",
                    _fmt(ref.tu2, ref.tu2_ci) if ref else "–",
                    "no data",
                    "",
                    "",
                ]
            )
            continue
        cells = [
            label,
            _fmt(*s.mean_ci("tu1")),
            _fmt(*s.mean_ci("tu2")),
            _fmt(ref.tu1, ref.tu1_ci) if ref else "–",
            _fmt(ref.tu2, ref.tu2_ci) if ref else "–",
        ]
        if label == "default" or default is None or default.n < 2:
            cells += ["—", "—", "—"]
            rows.append(cells)
            continue
        verdicts, agrees = [], []
        for metric, paper_below in (
            ("tu1", ref.tu1_below if ref else None),
            ("tu2", ref.tu2_below if ref else None),
        ):
            p_below = p_greater(default, s, metric)  # default > variant  <=> variant below
            p_below_paired = p_greater_paired(default, s, metric)
            p_above = p_greater(s, default, metric)
            below = p_below < ALPHA
            word = "**below**" if below else ("**above**" if p_above < ALPHA else "n.s.")
            verdicts.append(f"{word} ({_fmt_p(p_below)}; {_fmt_p(p_below_paired)})")
            if paper_below is not None:
                agrees.append("✓" if below == paper_below and not (p_above < ALPHA) else "✗")
        paper_txt = (
            "both"
            if ref and ref.tu1_below and ref.tu2_below
            else "TU1 only"
            if ref and ref.tu1_below
            else "TU2 only"
            if ref and ref.tu2_below
            else "no"
        )
        cells += [" / ".join(verdicts), paper_txt, " ".join(agrees)]
        rows.append(cells)
    text = _md_table(header, rows, "lrrrrlll")
    text += (
        "\n\n'below' = one-tailed unpaired Student's t-test that the default beats the variant, "
        "p < 0.05 (paired test on shared seeds in the second p-value); 'above' = significantly above "
        "the default (the paper found none). 'agrees' compares the unpaired verdict with the paper's "
        "italics, TU1 then TU2."
    )
    return text, [s for s in csv_samples if s is not None]

"""The Markdown assembly: :func:`build_report` reads the store once and writes every section."""

from __future__ import annotations

import csv
import json
import math
import pathlib
from collections import Counter
from dataclasses import dataclass

from mission.experiments import paper
from mission.experiments.report.ablations import _ablations
from mission.experiments.report.cells import Cell, analyse_table
from mission.experiments.report.configs import (
    CSV_FIELDS,
    _csv_row,
    _differs_from_paper,
    _overrides_text,
    _your_configurations,
)
from mission.experiments.report.figures import heatmaps
from mission.experiments.report.markdown import _fmt, _md_table, _pct
from mission.experiments.report.paired import _central_vs_async, _paired_vs_phireman
from mission.experiments.report.selection import Selector, _spec_from_row
from mission.experiments.report.significance import _bold_agreement
from mission.experiments.report.table_ii import (
    _agreement_summary,
    _five_percent,
    _misses,
    _table_ii,
    _vs_paper,
)
from mission.experiments.store import ResultStore, utc_now
from mission.experiments.sweep import ConfigSpec


@dataclass
class ReportResult:
    markdown: pathlib.Path
    csv: pathlib.Path
    figures: list[pathlib.Path]
    summary: dict


def _too_few_seeds(cells: list[Cell], methods) -> tuple[str, dict]:
    """The warning at the top of the report when some comparisons with the paper cannot be graded
    (:meth:`Cell.too_few_seeds`): how many, how many seeds the store has, how many would do."""
    graded = few = 0
    need: list[int] = []
    for c in cells:
        for m in methods:
            for k in paper.METRICS:
                if math.isnan(c.delta(m, k)):
                    continue
                graded += 1
                if c.too_few_seeds(m, k):
                    few += 1
                    if (n := c.seeds_to_tell(m, k)) is not None:
                        need.append(n)
    stats = {"comparisons": graded, "too_few_seeds": few}
    if not few:
        return "", stats
    ns = sorted(
        {s.n for c in cells for m in methods if (s := c.samples.get(m)) is not None and s.n}
    )
    seeds = f"{ns[0]}" if len(ns) == 1 else f"{ns[0]}–{ns[-1]}"
    text = (
        f"> **Too few seeds to grade against the paper: {few} of {graded}** (configuration, method, "
        f"metric) comparisons say *too few seeds* instead of ✓ / ✗. There, the half-width of our "
        f"95 % confidence interval is wider than the tolerance (3 pp for ΦIREMAN, 5 pp for the "
        f"baselines): other seeds could land on either side of it, so a ✓ or ✗ would be chance. "
        f"This store has {seeds} seeds per configuration; the paper used 100."
    )
    if need:
        stats["seeds_needed_max"] = max(need)
        text += (
            f" At the spread of these runs, about {max(need)} seeds would bring the widest of those "
            f"intervals down to its tolerance ((1.96 s / tolerance)², s the standard deviation over seeds)."
        )
    text += (
        " The significance tests (bold, *, °) hold at any number of seeds, but with few seeds they "
        "find only large differences; the heatmaps colour only significant ones."
    )
    return text, stats


def build_report(
    store_path: str | pathlib.Path,
    out: str | pathlib.Path,
    reading: str = "scaled",
    params: dict | None = None,
    problem_overrides: dict | None = None,
    notes: str | None = None,
    figures: bool = True,
    extra_methods: tuple[str, ...] = (),
    progress=None,
) -> ReportResult:
    """Write ``report.md``, ``configs.csv`` and the heatmap PNGs for a results store into ``out``.

    ``params`` / ``problem_overrides`` must equal the ``--set`` overrides the sweeps used (normally
    none) so the paper grids' configurations are found; with overrides the configurations are not
    the paper's, so the report shows them (Table II, significance) without grading them against
    the paper's numbers. ``extra_methods`` adds columns to Table II (your own planner, run on the
    paper-table configurations): it takes part in the significance tests; the comparison with the
    paper covers the paper's three methods only.

    When the store is mostly not the paper's grid (a custom sweep, a tuning store), the report
    leads with the store's own configurations and shows only the paper sections that have data.
    ``progress(step_name)`` is called between the stages (for a progress bar).
    """
    tick = progress or (lambda name: None)
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    params, problem_overrides = dict(params or {}), dict(problem_overrides or {})
    with ResultStore(store_path, readonly=True) as store:
        rows = store.runs()
        sweeps = store.sweeps()
    tick("read the store")
    selector = Selector(rows)
    methods = tuple(paper.PAPER_METHODS) + tuple(
        m for m in extra_methods if m not in paper.PAPER_METHODS
    )
    all_cells = analyse_table(selector, reading, params, problem_overrides, methods)
    # Only configurations with data are shown: a custom grid of 4 cells is not 25 rows of '–'.
    cells = [c for c in all_cells if any(s is not None and s.n for s in c.samples.values())]
    pm = paper.PAPER_METHODS
    table_samples = [s for c in all_cells for s in c.samples.values() if s is not None]
    ablation_text, ablation_samples = _ablations(selector, reading, params, problem_overrides)
    has_ablations = any(
        s is not None and s.n and s.spec.label != "default" for s in ablation_samples
    )
    not_paper = _differs_from_paper(problem_overrides, params, reading)
    comparable = not not_paper
    summary_text, agree_stats = _agreement_summary(cells, pm)
    central_cells = analyse_table(
        selector, reading, params, problem_overrides, ("phireman-central",)
    )
    central = (
        _central_vs_async(
            cells,
            [
                c
                for c in central_cells
                if (c.size, c.attrition) in {(k.size, k.attrition) for k in cells}
            ],
        )
        if cells
        else None
    )
    if central is not None and comparable:
        summary_text += (
            f"\n- **ΦIREMAN planned centrally** (same seeds, the ground station's "
            f"model) within 3 pp at 0–2 %: **{central[1]['central']} of "
            f"{central[1]['configs']}** configurations (see the table below)"
        )
    bold_text, bold_stats = _bold_agreement(cells)
    tick("analysed Table II")

    # Other configurations (custom sweeps, tuning) in the store.
    other_specs: dict[str, ConfigSpec] = {}
    for r in rows:
        if r["run_key"] not in selector.used and r["spec_key"] not in other_specs:
            other_specs[r["spec_key"]] = _spec_from_row(r)
    other_samples = [
        s for s in (selector.sample(spec) for spec in other_specs.values()) if s is not None
    ]
    tick("collected the other configurations")

    used_versions = Counter(r["code_version"] for r in rows if r["run_key"] in selector.used)
    readings = Counter(r["reading"] for r in rows)
    n_ok = sum(r["status"] == "ok" for r in rows)
    expected_table = len(all_cells) * len(methods)
    have_table = sum(1 for s in table_samples if s.n)
    have_runs = sum(s.n for s in table_samples)
    other_runs = sum(s.n + s.n_error for s in other_samples)
    lead_with_yours = bool(other_samples) and other_runs >= have_runs
    show_paper = bool(cells)

    md = [f"# Evaluation report: {pathlib.Path(store_path).name}", ""]
    md += [
        f"- generated: {utc_now()} from `{store_path}` ({len(rows)} runs: {n_ok} ok, "
        f"{len(rows) - n_ok} errors)",
        f"- reading: **{reading}**"
        + (
            " (every length × field half-width / 5; docs/design/model.md §6.4)"
            if reading == "scaled"
            else " (lengths as printed)"
        )
        + "; readings in the store: "
        + ", ".join(f"{k} ({v})" for k, v in readings.items()),
        "- code version(s) of the rows in the paper tables: "
        + ("; ".join(f"`{v}` ({n} runs)" for v, n in used_versions.items()) or "none"),
        f"- the paper's Table II configurations: {len(cells)} of {len(all_cells)} have data "
        f"({have_table} of {expected_table} (configuration, method) cells, {have_runs} ok runs)",
        f"- paper values: {paper.SOURCE}",
        "- DCCRS is a **reconstruction** (docs/design/model.md §3.3): the original paper was not identified.",
    ]
    if params or problem_overrides:
        md.append(
            f"- overrides applied to every configuration: "
            f"{', '.join(f'{k}={v}' for k, v in {**problem_overrides, **params}.items())}"
        )
    if not comparable:
        md.append(
            f"- **not compared with the paper**: these configurations differ from the paper's "
            f"({'; '.join(not_paper)}), so the paper's numbers do not apply to them"
        )
    few_text, few_stats = _too_few_seeds(cells, pm) if comparable else ("", {})
    if sweeps:
        total_wall = sum(s["wall_s"] or 0.0 for s in sweeps)
        md.append(
            f"- sweeps: {len(sweeps)} invocations, {total_wall / 60:.1f} min wall in total "
            f"({sum(s['completed'] for s in sweeps)} runs completed by them)"
        )
    md.append("")
    if few_text:
        md += [few_text, ""]

    yours = []
    if lead_with_yours:
        for s in sorted(
            other_samples,
            key=lambda s: (s.spec.size, s.spec.attrition, s.spec.method, s.spec.label),
        ):
            yours.append((s, "— (not a paper configuration)"))
        for c in cells:
            for m, smp in c.samples.items():
                if smp is None or not smp.n:
                    continue
                ref = [paper.paper_value(c.size, c.attrition, m, k) for k in paper.METRICS]
                yours.append(
                    (
                        smp,
                        f"{ref[0][0]:.2f} / {ref[1][0]:.2f}"  # type: ignore[index]  # all(ref)
                        if comparable and all(ref)
                        else "— (differs from the paper)"
                        if all(ref)
                        else "—",
                    )
                )
        md += [
            "## Your configurations",
            "",
            f"{len(yours)} configurations with data, TU1 and TU2 in % (mean ± half-width of the 95 % CI "
            f"over seeds; clipped to [0, 100] when it reaches past). The paper's numbers are shown only "
            f"for configurations that are the paper's own.",
            "",
            _your_configurations(yours),
            "",
        ]

    if show_paper:
        md += [
            "## Summary (the paper's configurations in this store)"
            if lead_with_yours
            else "## Summary",
            "",
        ]
        if comparable:
            md += [summary_text]
        else:
            md += [
                "Not graded against the paper: the overrides make these configurations differ from it."
            ]
        if comparable:
            md += [
                f"- Significance pattern: {bold_stats['agree_unpaired']} of {bold_stats['cells']} cells match "
                f"the paper's bolding (unpaired), {bold_stats['agree_paired']} with the paired test."
            ]
        md += [""]

        md += [
            "## Table II (ours)",
            "",
            "TU1 and TU2 in %, mean ± half-width of the 95 % Student-t CI over seeds. **Bold**: the best "
            "method beats both others by a one-tailed unpaired Student's t-test (scipy `ttest_ind`, equal "
            "variances, `alternative='greater'`) at p < 0.05, the paper's test. *paired*: the same criterion "
            "with `ttest_rel` on the seeds both methods share (the scenarios are common random numbers); "
            "it shows the winning method and the larger of its two p-values. n = ok runs per method. "
            + ("† 5 % column: see below. " if any(c.attrition >= 0.05 for c in cells) else "")
            + "Only configurations with data are listed.",
            "",
            _table_ii(cells, methods),
            "",
        ]
        for m in methods:
            if m in paper.PAPER_METHODS:
                continue
            vs = _paired_vs_phireman(cells, m)
            if vs is not None:
                md += [f"## `{m}` against ΦIREMAN, paired by seed", "", vs[0], ""]
        if comparable:
            md += [
                "## Ours against the paper",
                "",
                "Each cell: ours vs paper (Δ = ours − paper, pp). ✓ when |Δ| ≤ 3 pp for ΦIREMAN, ≤ 5 pp for the "
                "baselines; *too few seeds* when the half-width of our 95 % CI is wider than that tolerance "
                "(other seeds could land on either side of it, so ✓ or ✗ would be chance).",
                "",
                _vs_paper(cells, pm),
                "",
            ]
            if central is not None:
                md += [
                    "## ΦIREMAN: asynchronous and central information against the paper",
                    "",
                    "The paper's ΦIREMAN passes messages between drones (asynchronous, reconstructed: "
                    "docs/design/model.md §5.4); `phireman-central` is the same planner given every networked "
                    "drone's current position, as the ground station has it. Same scenarios and "
                    "attrition draws (seeds). ✓: |Δ| ≤ 3 pp.",
                    "",
                    central[0],
                    "",
                ]
            if any(c.attrition <= 0.02 + 1e-12 for c in cells):
                md += [
                    "## Configurations that miss (0–2 % attrition)",
                    "",
                    "With an automatic diagnosis: whether the gap is within the combined confidence intervals, "
                    "and whether the other methods move the same way (a shared-model difference) or not "
                    "(planner-specific).",
                    "",
                    _misses(cells, pm),
                    "",
                ]
            if any(c.attrition >= 0.05 - 1e-12 for c in cells):
                md += ["## The 5 % column", "", _five_percent(cells, pm), ""]
            md += ["## Significance against the paper's bolding", "", bold_text, ""]
    if has_ablations:
        md += ["## Ablations (S / 1 %)", "", ablation_text, ""]
    tick("wrote the tables")

    figs: list[pathlib.Path] = []
    if figures and show_paper and comparable:
        figs = heatmaps(all_cells, out)
        md += ["## Figures", ""]
        md += [f"![{p.stem}]({p.name})" for p in figs]
        md += [
            "",
            "Diverging colour maps centred at 0 (blue: ΦIREMAN higher), one colour scale per figure so "
            "compared panels read alike. * ΦIREMAN significantly higher, ° significantly lower (one-tailed "
            "unpaired t-test, p < 0.05); grey: no data. Only significant differences are coloured (ours − "
            "paper: Δ outside the combined 95 % CIs); the others are white with their number in grey, and "
            "the colour scale spans the significant ones, so one noisy cell cannot saturate it.",
            "",
        ]
    tick("drew the figures")

    if other_samples and not lead_with_yours:
        rows_md = []
        for s in sorted(
            other_samples,
            key=lambda s: (s.spec.method, s.spec.size, s.spec.attrition, s.spec.label),
        ):
            rows_md.append(
                [
                    s.spec.label or "—",
                    s.spec.size,
                    _pct(s.spec.attrition),
                    s.spec.reading,
                    s.spec.method,
                    _overrides_text(s.spec),
                    str(s.n),
                    str(s.n_error),
                    _fmt(*s.mean_ci("tu1")),
                    _fmt(*s.mean_ci("tu2")),
                ]
            )
        md += [
            "## Other configurations in the store",
            "",
            _md_table(
                [
                    "label",
                    "size",
                    "p (%)",
                    "reading",
                    "method",
                    "overrides",
                    "n",
                    "errors",
                    "TU1",
                    "TU2",
                ],
                rows_md,
                "llrlllrrrr",
            ),
            "",
        ]

    errors: Counter[tuple[str, str]] = Counter()
    for r in rows:
        if r["status"] == "error":
            errors[(r["method"], (r["error"] or "?").splitlines()[0][:200])] += 1
    if errors:
        md += [
            "## Failed runs",
            "",
            _md_table(
                ["method", "error", "runs"],
                [[m, e.replace("|", "\\|"), str(n)] for (m, e), n in errors.most_common()],
                "llr",
            ),
            "",
        ]
    notes_sample = [
        n for s in table_samples + [a for a in ablation_samples if a is not None] for n in s.notes
    ]
    if notes_sample:
        md += ["## Data notes", ""] + [f"- {n}" for n in sorted(set(notes_sample))] + [""]
    if notes:
        md += ["## Notes", "", notes.strip(), ""]

    md_path = out / "report.md"
    md_path.write_text("\n".join(md) + "\n")
    csv_path = out / "configs.csv"
    with open(csv_path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS)
        w.writeheader()
        for s in table_samples:
            w.writerow(_csv_row(s, comparable))
        for s in [a for a in ablation_samples if a is not None] + other_samples:
            w.writerow(_csv_row(s, False))
    summary = {
        "agreement": agree_stats if comparable else {},
        "bold": bold_stats,
        "runs": len(rows),
        "ok": n_ok,
        "central_vs_async": None if central is None or not comparable else central[1],
        "table_cells_with_data": have_table,
        "paper_configs_with_data": len(cells),
        "your_configurations": len(yours) if lead_with_yours else len(other_samples),
        "leads_with_yours": lead_with_yours,
        "compared_with_paper": comparable and show_paper,
        "too_few_seeds": few_stats,
        "code_versions": dict(used_versions),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, ensure_ascii=False))
    return ReportResult(md_path, csv_path, figs, summary)

"""phireman report: Table II, significance tests, the paper comparison, ablations and heatmaps."""

from __future__ import annotations

import argparse
import pathlib

HELP = "turn a results store into Table II, ablations, Fig. 3 heatmaps and a comparison with the paper"
DESCRIPTION = """\
Read a results store written by 'phireman sweep' and write into --out:

  report.md      Table II (mean ± 95 % CI; bold where the best method beats both others by the
                 paper's one-tailed unpaired Student's t-test at p < 0.05, with a paired test beside
                 it since seeds are shared), ours vs the paper (Δ, ✓ within 3 pp for PhiIREMAN and
                 5 pp for the baselines), the agreement summary and every configuration that misses,
                 the 5 % column with its expected gap, where our significance differs from the
                 paper's bolding, the ablation table, other configurations in the store, failed runs
  fig3_*.png     heatmaps of PhiIREMAN − DCCRS, − MCCST and − the better baseline (ours and the
                 paper's), and ours − paper per method
  configs.csv    per-configuration statistics; summary.json: the headline numbers

Pass the same --reading and --set overrides the sweeps used (normally none) so the paper grids'
configurations are found.

examples:
  phireman report results.sqlite --out report/
  phireman report quick.sqlite --out /tmp/r --set n_steps=50 --notes docs/misses.md
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("store", type=pathlib.Path, help="results store (SQLite) written by 'phireman sweep'")
    p.add_argument("--out", type=pathlib.Path, required=True, help="output directory")
    p.add_argument("--reading", choices=["scaled", "literal"], default="scaled",
                   help="which reading's configurations to report (default scaled)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="the --set overrides the sweeps used (repeatable)")
    p.add_argument("--notes", type=pathlib.Path, default=None,
                   help="a Markdown file appended as the report's 'Notes' section (e.g. why configurations miss)")
    p.add_argument("--methods", nargs="+", default=[], metavar="NAME",
                   help="extra Table II columns besides phireman, dccrs, mccst: your own planner, swept on "
                        "the paper-table configurations (e.g. --grid paper-table --methods mine)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG heatmaps")


def run(args) -> int:
    from mission.cli import UserError
    from mission.commands.sweep import split_list, split_overrides
    from mission.report import build_report
    from mission.store import StoreError

    if not args.store.exists():
        raise UserError(f"no results store at {args.store}")
    problem, params = split_overrides(args.set)
    notes = None
    if args.notes is not None:
        try:
            notes = args.notes.read_text()
        except OSError as exc:
            raise UserError(f"--notes: {exc}") from None
    try:
        result = build_report(args.store, args.out, reading=args.reading, params=params,
                              problem_overrides=problem, notes=notes, figures=not args.no_figures,
                              extra_methods=tuple(split_list(args.methods) or ()))
    except StoreError as exc:
        raise UserError(str(exc)) from None
    a = result.summary["agreement"].get("phireman", {})
    print(f"wrote {result.markdown}, {result.csv.name} and {len(result.figures)} figures")
    if a:
        print(f"PhiIREMAN within 3 pp at 0-2 %: {a['within_both']} of {a['configs']} configurations "
              f"({a['with_data']} with data)")
    return 0

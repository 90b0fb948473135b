"""phireman report: Table II, significance tests, the paper comparison, ablations and heatmaps."""

from __future__ import annotations

import argparse
import pathlib
import sys

HELP = (
    "turn a results store into Table II, ablations, Fig. 3 heatmaps and a comparison with the paper"
)
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
configurations are found. With overrides (e.g. --set n_steps=50) the configurations are not the
paper's: they are tabulated and tested against each other, not graded against the paper's numbers.
A store that is mostly not the paper's grid (a custom sweep, a tuning store) leads with its own
configurations; paper sections appear only where the store has paper configurations.

examples:
  phireman report results.sqlite --out report/
  phireman report quick.sqlite --out /tmp/r --set n_steps=50 --notes docs/misses.md
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "store", type=pathlib.Path, help="results store (SQLite) written by 'phireman sweep'"
    )
    p.add_argument("--out", type=pathlib.Path, required=True, help="output directory")
    p.add_argument(
        "--reading",
        choices=["scaled", "literal"],
        default="scaled",
        help="which reading's configurations to report (default scaled)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="the --set overrides the sweeps used (repeatable)",
    )
    p.add_argument(
        "--notes",
        type=pathlib.Path,
        default=None,
        help="a Markdown file appended as the report's 'Notes' section (e.g. why configurations miss)",
    )
    p.add_argument(
        "--method",
        "--methods",
        dest="methods",
        nargs="+",
        default=[],
        metavar="NAME",
        help="extra Table II columns besides phireman, dccrs, mccst: your own planner, swept on "
        "the paper-table configurations (e.g. --grid paper-table --methods mine)",
    )
    p.add_argument("--no-figures", action="store_true", help="skip the PNG heatmaps")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    from mission.commands.options import UserError, writable_dir
    from mission.commands.sweep import split_list, split_overrides
    from mission.experiments.report import build_report
    from mission.experiments.store import StoreError

    if not args.store.exists():
        raise UserError(f"no results store at {args.store}")
    writable_dir(args.out)
    problem, params = split_overrides(args.set)
    notes = None
    if args.notes is not None:
        try:
            notes = args.notes.read_text()
        except OSError as exc:
            raise UserError(f"--notes: {exc}") from None
    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=5, unit="stage", file=sys.stderr, leave=False, desc="report")
    try:
        result = build_report(
            args.store,
            args.out,
            reading=args.reading,
            params=params,
            problem_overrides=problem,
            notes=notes,
            figures=not args.no_figures,
            extra_methods=tuple(split_list(args.methods) or ()),
            progress=(lambda name: (bar.set_postfix_str(name), bar.update(1))) if bar else None,
        )
    except (StoreError, FileNotFoundError) as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        raise UserError(f"--out {args.out}: {exc.strerror or exc}") from None
    finally:
        if bar:
            bar.close()
    s = result.summary
    print(f"wrote {result.markdown}, {result.csv.name} and {len(result.figures)} figures")
    if s["leads_with_yours"]:
        print(
            f"report.md leads with your {s['your_configurations']} configurations; "
            f"{s['paper_configs_with_data']} of the paper's 25 Table II configurations have data"
        )
    elif s["your_configurations"]:
        print(
            f"{s['your_configurations']} configurations besides the paper's: 'Other configurations' in report.md"
        )
    a = s["agreement"].get("phireman", {})
    if a and a["with_data"]:
        print(
            f"PhiIREMAN within 3 pp of the paper at 0-2 %: {a['within_both']} of {a['with_data']} "
            f"paper configurations with data (the paper's table has {a['configs'] if a['configs'] >= 20 else 20})"
        )
    elif s["paper_configs_with_data"] and not s["compared_with_paper"]:
        print(
            "not compared with the paper: the --set overrides make the configurations differ from it"
        )
    few = s.get("too_few_seeds") or {}
    if few.get("too_few_seeds"):
        print(
            f"too few seeds to grade {few['too_few_seeds']} of {few['comparisons']} comparisons with "
            "the paper (our 95 % CI wider than the tolerance): see the top of report.md"
        )
    return 0

"""phireman tune: grid search of a planner's free parameters at S / 1 %, as the paper did."""

from __future__ import annotations

import argparse
import pathlib
import shlex
import sys

HELP = "grid-search a planner's parameters (at S / 1 % by default) and rank the settings"
DESCRIPTION = """\
Run every combination of the --grid values for one method over --seeds seeded scenarios (the same
seeds for every combination), using the same resumable results store and executors as 'phireman
sweep', and print the settings ranked by mean TU1, then TU2. The current defaults are always
included as '(defaults)'. Each row also gives the one-tailed paired p-value that the best setting
beats it on TU1 (seeds are shared): settings with p >= 0.05 are statistically indistinguishable
from the best at this number of seeds.

Keys that are problem fields (ProblemConfig, e.g. n_steps) override the problem; any other key is a
planner parameter. A key that is neither is refused before anything runs (with the closest name).
With --out, writes the search as Markdown (the command line that reproduces it, the code version,
the ranked table) to --out/<method>_<size>_<attrition>pct.md, or to --out itself if it ends in .md.

examples:
  phireman tune --method phireman --grid step_size=0.1,0.2,0.3 --grid max_descent_steps=5,10,20 \\
                --seeds 30 --store tune.sqlite --out docs/tuning
  phireman tune --method dccrs --grid leader_gain=0.02,0.05,0.1 --seeds 30 --store tune.sqlite
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mission.commands.sweep import add_common_arguments

    p.add_argument(
        "--method",
        "--methods",
        dest="method",
        required=True,
        help="planner name (phireman, dccrs, mccst, ...)",
    )
    p.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        help="a parameter and its candidate values; repeatable (the search is their product)",
    )
    p.add_argument(
        "--size",
        "--sizes",
        dest="size",
        default="S",
        type=str.upper,
        help="problem size (default S, as the paper)",
    )
    p.add_argument(
        "--attrition",
        default="0.01",
        metavar="P",
        help="per-step attrition as a fraction or percent, 0.01 or 1%% (default 0.01, as the paper)",
    )
    add_common_arguments(p, seeds_default=30, store_default="tune.sqlite")
    p.add_argument(
        "--out",
        type=pathlib.Path,
        default=None,
        help="directory (or .md file) for the Markdown record of the search",
    )
    p.add_argument(
        "--top",
        type=int,
        default=0,
        metavar="N",
        help="print only the N best settings (default all)",
    )


def _parse_axes(items: list[str]) -> dict[str, list]:
    import dataclasses

    from mission.commands.options import UserError
    from mission.commands.sweep import parse_value
    from planner.problem import ProblemConfig

    fields = {f.name: f for f in dataclasses.fields(ProblemConfig)}
    axes: dict[str, list] = {}
    for item in items:
        if "=" not in item:
            raise UserError(f"--grid expects KEY=V1,V2,..., got {item!r}")
        key, values = (s.strip() for s in item.split("=", 1))
        if key in ("size", "reading", "attrition_per_step"):
            raise UserError(f"--grid {key}: use --size / --reading / --attrition")
        if key in axes:
            raise UserError(f"--grid {key} given twice")
        try:
            vals = [parse_value(v.strip(), fields.get(key)) for v in values.split(",") if v.strip()]
        except ValueError:
            raise UserError(f"--grid {key}: expected numbers, got {values!r}") from None
        if not vals:
            raise UserError(f"--grid {key}: no values")
        axes[key] = vals
    if not axes:
        raise UserError("give at least one --grid KEY=V1,V2,...")
    return axes


def reproduce_command(args) -> str:
    """The command line that reproduces this search (options that matter for the results)."""
    parts = ["phireman", "tune", "--method", args.method]
    for g in args.grid:
        parts += ["--grid", g]
    parts += ["--size", args.size, "--attrition", str(args.attrition), "--seeds", str(args.seeds)]
    if args.seed:
        parts += ["--seed", str(args.seed)]
    if args.reading != "scaled":
        parts += ["--reading", args.reading]
    for s in args.set:
        parts += ["--set", s]
    parts += ["--store", str(args.store)]
    if args.out is not None:
        parts += ["--out", str(args.out)]
    return shlex.join(parts)


def run(args) -> int:
    from mission.commands.options import UserError, writable_dir, writable_file
    from mission.commands.sweep import (
        check_grid,
        execute,
        parse_attrition,
        split_overrides,
        validate_methods,
    )
    from mission.experiments.report import (
        ALPHA,
        Selector,
        _fmt,
        _fmt_p,
        p_greater_paired,
        rank_samples,
    )
    from mission.experiments.store import ResultStore
    from mission.experiments.sweep import code_version, product_grid
    from planner.problem import SIZES

    validate_methods([args.method])
    if args.size not in SIZES:
        raise UserError(f"unknown size {args.size!r}; valid sizes: {', '.join(SIZES)}")
    if args.seeds < 2:
        raise UserError("--seeds must be >= 2 (confidence intervals and tests need two)")
    attrition = parse_attrition([args.attrition])
    assert attrition is not None  # given a list
    if len(attrition) != 1:
        raise UserError("--attrition takes one level")
    axes = _parse_axes(args.grid)
    problem, params = split_overrides(args.set)
    seed0 = args.seed or 0
    seeds = range(seed0, seed0 + args.seeds)
    grid = product_grid(
        args.method, axes, seeds, args.size, attrition[0], args.reading, params, problem
    )
    check_grid(grid, "--grid/--set")
    if args.out is not None:  # before the search, not after it
        (writable_file if args.out.suffix == ".md" else writable_dir)(args.out, "--out")
    command = reproduce_command(args)
    status = execute(grid, args, shlex.split(command))
    if status == 130:
        return status

    with ResultStore(args.store, readonly=True) as store:
        selector = Selector(store.runs())
    samples = [s for s in (selector.sample(spec) for spec in grid.configs) if s is not None]
    ranked = rank_samples(samples)
    best = ranked[0] if ranked and ranked[0].n else None
    header = ["rank", "setting", "TU1 (%)", "TU2 (%)", "n", "errors", "p(best > this, TU1, paired)"]
    rows = []
    for i, s in enumerate(ranked, 1):
        if best is None or s is best or s.n < 2:
            p_txt = "—"
        else:
            p = p_greater_paired(best, s, "tu1")
            p_txt = _fmt_p(p) + ("" if p < ALPHA else " (n.s.)")
        rows.append(
            [
                str(i),
                s.spec.label or "(defaults)",
                _fmt(*s.mean_ci("tu1")),
                _fmt(*s.mean_ci("tu2")),
                str(s.n),
                str(s.n_error),
                p_txt,
            ]
        )
    shown = rows[: args.top] if args.top > 0 else rows
    widths = [max(len(r[k]) for r in [header] + shown) for k in range(len(header))]
    print("  ".join(h.ljust(w) for h, w in zip(header, widths)))
    for r in shown:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)))
    if best is not None:
        print(
            f"best: {best.spec.label or '(defaults)'}  TU1 {_fmt(*best.mean_ci('tu1'))} %, "
            f"TU2 {_fmt(*best.mean_ci('tu2'))} %"
        )

    if args.out is not None:
        pct = f"{100 * attrition[0]:g}".replace(".", "p")
        path = (
            args.out
            if args.out.suffix == ".md"
            else args.out / f"{args.method}_{args.size}_{pct}pct.md"
        )
        path.parent.mkdir(parents=True, exist_ok=True)
        md = [
            f"# Tuning {args.method} at {args.size} / {100 * attrition[0]:g} %/step",
            "",
            "Reproduce with:",
            "",
            "```sh",
            command,
            "```",
            "",
            f"- code: `{code_version()}`",
            f"- reading: {args.reading}; seeds {seed0}..{seed0 + args.seeds - 1} "
            f"(the same for every setting)",
            "- search: "
            + "; ".join(f"`{k}` ∈ {{{', '.join(map(str, v))}}}" for k, v in axes.items()),
            f"- common overrides: {', '.join(args.set) or 'none'}",
            f"- ranked by mean TU1, then TU2; last column: one-tailed paired t-test that the best setting "
            f"beats this one on TU1 (n.s. = not significant at p < {ALPHA})",
            "",
        ]
        md.append("| " + " | ".join(header) + " |")
        md.append("| " + " | ".join(["---:", "---", "---:", "---:", "---:", "---:", "---"]) + " |")
        md += ["| " + " | ".join(r) + " |" for r in rows]
        if best is not None:
            md += [
                "",
                f"**Best:** {best.spec.label or '(defaults)'} — TU1 {_fmt(*best.mean_ci('tu1'))} %, "
                f"TU2 {_fmt(*best.mean_ci('tu2'))} %.",
            ]
        path.write_text("\n".join(md) + "\n")
        print(f"wrote {path}", file=sys.stderr)
    return status

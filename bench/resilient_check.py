"""Issue 15: do stored per-seed results still match the current code, bit for bit?

Reruns a few (method, size, attrition, seed) runs with ``mission.experiments.sim.run_episode`` and compares
TU1 / TU2 with the rows of a results store (the paper table's). Used to show that adding
``phireman-resilient`` (and the world's rally-point option) left ``phireman``, ``dccrs`` and
``mccst`` unchanged, and that the stored ``phireman`` rows can be paired against new runs.

usage:
  python bench/resilient_check.py STORE [--methods phireman dccrs mccst] [--cells S:1 XS:2 M:5 L:2]
                                        [--seeds 0 1 2] [--set KEY=VALUE ...]
  # the stored rows of the planner before issue 28 (its base read the truth): base_view=oracle
  python bench/resilient_check.py resilient.sqlite --methods phireman-resilient --set base_view=oracle
Exit status 1 if any run differs.
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys

from mission.experiments.sim import run_episode
from planner.problem import problem_preset


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("store")
    ap.add_argument("--methods", nargs="+", default=["phireman", "dccrs", "mccst"])
    ap.add_argument("--cells", nargs="+", default=["S:1", "XS:2", "M:5", "L:2"], metavar="SIZE:PCT")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument(
        "--set",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="parameters of the reruns (the stored rows are those without overrides)",
    )
    args = ap.parse_args(argv)
    params = dict(kv.split("=", 1) for kv in args.set)
    con = sqlite3.connect(f"file:{args.store}?mode=ro", uri=True)
    bad = 0
    for cell in args.cells:
        size, pct = cell.split(":")
        att = float(pct) / 100
        problem = problem_preset(size.upper(), att)
        for method in args.methods:
            for seed in args.seeds:
                rows = [
                    (tu1, tu2)
                    for tu1, tu2, spec in con.execute(
                        "SELECT tu1, tu2, spec_json FROM runs WHERE method = ? AND size = ? AND abs(attrition - ?) < 1e-9 "
                        "AND seed = ? AND status = 'ok' AND reading = 'scaled'",
                        (method, size.upper(), att, seed),
                    )
                    if not json.loads(spec).get("problem_overrides")
                    and not json.loads(spec).get("params")
                ]
                if not rows:
                    print(f"{method:10s} {size:2s} {pct:>3s} % seed {seed}: not in the store")
                    continue
                r = run_episode(problem, method, params, seed)
                same = (r.tu1, r.tu2) == rows[0]
                bad += not same
                print(
                    f"{method:10s} {size:2s} {pct:>3s} % seed {seed}: stored {rows[0][0]!r} {rows[0][1]!r} "
                    f"now {r.tu1!r} {r.tu2!r} {'identical' if same else 'DIFFERENT'}",
                    flush=True,
                )
    con.close()
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

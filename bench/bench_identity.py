"""Issue 16: per-seed TU1 / TU2 of the in-process simulation, this tree against another code tree.

Runs ``mission.experiments.sim.run_episode`` for every (method, size:attrition %, seed) in a subprocess whose
``PYTHONPATH`` is the given tree (e.g. ``git archive <commit> | tar -x -C /tmp/base``) and in this
tree, and compares the exact floats. Exit status 1 if any run differs.

    .venv/bin/python bench/bench_identity.py --baseline /tmp/base --cells S:1 M:1 XL:1 --seeds 0 1 2 3 4
    .venv/bin/python bench/bench_identity.py --baseline /tmp/base --methods dccrs@central   # METHOD@INFO
    .venv/bin/python bench/bench_identity.py --baseline /tmp/base --table-cost --seeds 0 1   # every Table II cell
    # a parameter only this tree knows (the baseline runs the method's defaults)
    .venv/bin/python bench/bench_identity.py --baseline /tmp/base --methods phireman-resilient \
        --new-params base_view=oracle

Each tree runs in one process after a warm-up run (imports, JIT cache loading), so the CPU seconds
per run are comparable. With ``--table-cost`` (every size x attrition level of Table II) it also
prints the CPU seconds per run per cell, old and new, and the Table II time they imply (100 seeds,
2 workers, perfect packing). Where runs differ, the means over the seeds and their 95 % confidence
intervals are printed (the t quantile of the paired seeds).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, sys, time
from mission.experiments.sim import run_episode
from planner.problem import problem_preset
out = []
items = json.loads(sys.argv[1])
extra = json.loads(sys.argv[2]) if len(sys.argv) > 2 else {}
def split(method):  # "dccrs@central": the method with params {"info": "central"}
    name, _, info = method.partition("@")
    return name, ({"info": info} if info else {}) | extra.get(name, {})
for method in sorted({it[0] for it in items}):
    run_episode(problem_preset("XS", 0.01), *split(method), 10_000)   # warm-up: imports, JIT caches
for item in items:
    method, size, att, seed = item
    c0 = time.process_time()
    r = run_episode(problem_preset(size, att), *split(method), seed)
    out.append([method, size, att, seed, r.tu1, r.tu2, time.process_time() - c0])
print(json.dumps(out))
"""


def run_tree(tree: str, items: list, extra: dict | None = None) -> list:
    env = {**os.environ, "PYTHONPATH": tree, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run(
        [sys.executable, "-c", CHILD, json.dumps(items), json.dumps(extra or {})],
        capture_output=True,
        text=True,
        env=env,
        cwd=tree,
    )
    if out.returncode:
        sys.exit(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def _ci(values):
    import numpy as np
    from scipy import stats

    v = np.asarray(values, float)
    if len(v) < 2:
        return float(v.mean()), float("nan")
    return float(v.mean()), float(stats.t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--baseline", required=True, help="root of the code tree to compare against")
    ap.add_argument("--methods", nargs="+", default=["phireman", "dccrs", "mccst"])
    ap.add_argument("--cells", nargs="+", default=["S:1"], metavar="SIZE:PCT")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    ap.add_argument(
        "--seed-range", type=int, nargs=2, metavar=("FIRST", "STOP"), help="seeds FIRST..STOP-1"
    )
    ap.add_argument(
        "--table-cost", action="store_true", help="every Table II cell (5 sizes x 5 levels)"
    )
    ap.add_argument("--quiet", action="store_true", help="one line per cell, not per run")
    ap.add_argument(
        "--new-params",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="parameters for this tree's runs only (every method that knows them: pass one "
        "method), e.g. base_view=oracle to run the old default of phireman-resilient",
    )
    args = ap.parse_args(argv)
    new_params = dict(kv.split("=", 1) for kv in args.new_params)
    extra = {m.partition("@")[0]: new_params for m in args.methods} if new_params else {}
    seeds = list(range(*args.seed_range)) if args.seed_range else args.seeds
    cells = args.cells
    if args.table_cost:
        cells = [
            f"{s}:{p}" for s in ("XS", "S", "M", "L", "XL") for p in ("0", "0.5", "1", "2", "5")
        ]
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    bad = 0
    total_old = total_new = 0.0
    for cell in cells:
        size, pct = cell.split(":")
        items = [[m, size.upper(), float(pct) / 100, s] for m in args.methods for s in seeds]
        old, new = run_tree(args.baseline, items), run_tree(here, items, extra)
        for m in args.methods:
            rows = [(o, n) for o, n in zip(old, new) if o[0] == m]
            diff = 0
            for o, n in rows:
                same = o[4:6] == n[4:6]
                diff += not same
                if not args.quiet:
                    print(
                        f"{o[0]:9s} {o[1]:2s} {pct:>4s} % seed {o[3]:3d}: TU1 {o[4]!r:22} {n[4]!r:22} TU2 "
                        f"{o[5]!r:22} {n[5]!r:22} {'identical' if same else 'DIFFERENT'}  "
                        f"cpu {o[6]:.2f} -> {n[6]:.2f} s",
                        flush=True,
                    )
            bad += diff
            c_old = sum(o[6] for o, _ in rows) / len(rows)
            c_new = sum(n[6] for _, n in rows) / len(rows)
            total_old += c_old
            total_new += c_new
            line = (
                f"{m:9s} {size:2s} {pct:>4s} %: {len(rows) - diff}/{len(rows)} identical, cpu s/run "
                f"{c_old:.3f} -> {c_new:.3f} ({c_old / c_new:.2f}x)"
            )
            if diff:
                for k, name in ((4, "TU1"), (5, "TU2")):
                    mo, ho = _ci([o[k] for o, _ in rows])
                    mn, hn = _ci([n[k] for _, n in rows])
                    line += f"; {name} {mo:.4f} ± {ho:.4f} -> {mn:.4f} ± {hn:.4f}"
            print(line, flush=True)
    if args.table_cost:
        print(
            f"Table II at 100 seeds, 2 workers (CPU s / 2, perfect packing): "
            f"{total_old * 100 / 2 / 60:.1f} min -> {total_new * 100 / 2 / 60:.1f} min"
        )
    print("all identical" if not bad else f"{bad} runs differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

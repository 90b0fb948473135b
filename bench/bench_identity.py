"""Issue 16: per-seed TU1 / TU2 of the in-process simulation, this tree against another code tree.

Runs ``mission.sim.run_episode`` for every (method, size:attrition %, seed) in a subprocess whose
``PYTHONPATH`` is the given tree (e.g. ``git archive <commit> | tar -x -C /tmp/base``) and in this
tree, and compares the exact floats. Exit status 1 if any run differs.

    .venv/bin/python bench/bench_identity.py --baseline /tmp/base --cells S:1 M:1 XL:1 --seeds 0 1 2 3 4
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, sys, time
from mission.sim import run_episode
from planner.problem import problem_preset
out = []
for item in json.loads(sys.argv[1]):
    method, size, att, seed = item
    c0 = time.process_time()
    r = run_episode(problem_preset(size, att), method, {}, seed)
    out.append([method, size, att, seed, r.tu1, r.tu2, time.process_time() - c0])
print(json.dumps(out))
"""


def run_tree(tree: str, items: list) -> list:
    env = {**os.environ, "PYTHONPATH": tree, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", CHILD, json.dumps(items)], capture_output=True, text=True,
                         env=env, cwd=tree)
    if out.returncode:
        sys.exit(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", required=True, help="root of the code tree to compare against")
    ap.add_argument("--methods", nargs="+", default=["phireman", "dccrs", "mccst"])
    ap.add_argument("--cells", nargs="+", default=["S:1"], metavar="SIZE:PCT")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    args = ap.parse_args(argv)
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    bad = 0
    for cell in args.cells:
        size, pct = cell.split(":")
        items = [[m, size.upper(), float(pct) / 100, s] for m in args.methods for s in args.seeds]
        old, new = run_tree(args.baseline, items), run_tree(here, items)
        for o, n in zip(old, new):
            same = o[4:6] == n[4:6]
            bad += not same
            print(f"{o[0]:9s} {o[1]:2s} {pct:>4s} % seed {o[3]:3d}: TU1 {o[4]!r:22} {n[4]!r:22} TU2 {o[5]!r:22} "
                  f"{n[5]!r:22} {'identical' if same else 'DIFFERENT'}  cpu {o[6]:.2f} -> {n[6]:.2f} s", flush=True)
    print("all identical" if not bad else f"{bad} runs differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

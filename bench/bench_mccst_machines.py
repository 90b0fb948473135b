"""Issue 16: how far MCCST's per-seed results move from one machine to another.

MCCST solves a QP each tick with PIQP, whose wheel ships three builds of its solver (AVX-512,
AVX2, generic x86-64) and loads the best one the CPU offers (``piqp/__init__.py``). The builds
round differently, and over a 200-step episode one last-bit difference grows into a different
flight, so a seed's TU1 / TU2 depends on the CPU it ran on. The other methods do not use PIQP.

This bench runs MCCST with each build forced in turn (every build runs on this machine, which
has AVX-512) for ``--seeds`` seeds of a few Table II cells, and compares each run with the same
seed under the build this machine loads by default. It prints, per build and cell, how many
seeds are identical, the largest per-seed difference, and the difference of the cell means with
the default build's 95 % confidence half-width beside it: the bound a user on another CPU should
expect. NumPy's own CPU dispatch (SVML on AVX-512 for ``h ** 3``) is a second source of such
differences that this bench does not vary.

    .venv/bin/python bench/bench_mccst_machines.py
    .venv/bin/python bench/bench_mccst_machines.py --cells S:1 L:2 --seeds 50 --builds piqp_python_avx2
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUILDS = ("default", "piqp_python_avx2", "piqp_python")

CHILD = r"""
import importlib, json, sys
build, cells, seeds = sys.argv[1], json.loads(sys.argv[2]), int(sys.argv[3])
import planner.mccst as mccst
if build != "default":
    mccst.piqp = importlib.import_module("piqp." + build)   # the module PIQP would load on that CPU
from mission.experiments.sim import run_episode
from planner.problem import problem_preset
out = []
for size, pct in cells:
    problem = problem_preset(size, pct / 100.0)
    for seed in range(seeds):
        r = run_episode(problem, "mccst", {}, seed)
        out.append([size, pct, seed, r.tu1, r.tu2])
print(json.dumps(out))
"""


def _run(build: str, cells: list, seeds: int) -> dict:
    env = dict(os.environ, PYTHONPATH=ROOT, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    res = subprocess.run(
        [sys.executable, "-c", CHILD, build, json.dumps(cells), str(seeds)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    rows = json.loads(res.stdout.strip().splitlines()[-1])
    return {(s, p, seed): (tu1, tu2) for s, p, seed, tu1, tu2 in rows}


def _half_width(values: list[float]) -> float:
    n = len(values)
    if n < 2:
        return math.nan
    mean = sum(values) / n
    var = sum((v - mean) ** 2 for v in values) / (n - 1)
    return 1.96 * math.sqrt(var / n)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--cells", nargs="+", default=["XS:1", "S:1", "M:2", "L:2", "XL:1"])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--builds", nargs="+", default=list(BUILDS[1:]), choices=BUILDS[1:])
    args = ap.parse_args(argv)
    cells = []
    for c in args.cells:
        size, _, pct = c.partition(":")
        cells.append([size.upper(), float(pct)])
    base = _run("default", cells, args.seeds)
    print(f"{len(cells)} cells x {args.seeds} seeds; TU in % points, vs the default build")
    print(
        f"{'build':18} {'cell':8} {'identical':>9} {'max |dTU1|':>10} {'max |dTU2|':>10} "
        f"{'d mean TU1':>10} {'d mean TU2':>10} {'95% CI +-':>12}"
    )
    for build in args.builds:
        other = _run(build, cells, args.seeds)
        for size, pct in cells:
            keys = [(size, pct, s) for s in range(args.seeds)]
            same = sum(base[k] == other[k] for k in keys)
            d1 = [100 * (other[k][0] - base[k][0]) for k in keys]
            d2 = [100 * (other[k][1] - base[k][1]) for k in keys]
            hw1 = _half_width([100 * base[k][0] for k in keys])
            hw2 = _half_width([100 * base[k][1] for k in keys])
            print(
                f"{build:18} {size + ':' + format(pct, 'g'):8} {same:>5}/{len(keys):<3} "
                f"{max(map(abs, d1)):10.2f} {max(map(abs, d2)):10.2f} "
                f"{sum(d1) / len(d1):+10.2f} {sum(d2) / len(d2):+10.2f} {hw1:6.2f}/{hw2:<5.2f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

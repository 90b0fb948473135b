"""Issue 16: CPU seconds per run of the paper's Table II (+ ablations), this tree against a previous
one, side by side in the same session, with the full sweep's time estimated from them.

Runs the configurations of ``mission.experiments.sweep.paper_table_grid`` (5 sizes x 5 attrition levels x
phireman / dccrs / mccst) and ``paper_ablations_grid`` (7 variants at S / 1 %) for a few seeds with
the previous code tree and with this one, one child process per (tree, size) with one BLAS thread
and a warm-up run per method (imports, Numba's cache), the two trees interleaved size by size (the
machine is shared: what drifts between sizes drifts for both). Every run's TU1 / TU2 are compared
bit for bit. Prints per cell and per (size, method) the CPU seconds per run, old -> new and the
ratio, then the full sweep (100 seeds) in CPU minutes and its wall time on ``--workers`` workers
(CPU / workers: perfect packing, no start-up; the real sweep adds its store and scheduling).

    .venv/bin/python bench/bench_table_cost.py --commit b97dcb8                 # git archive into a temp dir
    .venv/bin/python bench/bench_table_cost.py --baseline /tmp/base --seeds 0 1 2 --repeat 2
    .venv/bin/python bench/bench_table_cost.py --commit b97dcb8 --sizes XL --attrition 0 0.01 --no-ablations

Exit status 1 if any run's TU1 / TU2 differ between the trees.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections import defaultdict

SIZES = ("XS", "S", "M", "L", "XL")
LEVELS = (0.0, 0.005, 0.01, 0.02, 0.05)
METHODS = ("phireman", "dccrs", "mccst")

CHILD = r"""
import json, sys, time
from mission.experiments.sim import run_episode
from mission.experiments.sweep import paper_ablations_grid, paper_table_grid
from planner.problem import problem_preset
req = json.loads(sys.argv[1])
if req["grid"] == "table":
    grid = paper_table_grid(seeds=req["seeds"], sizes=req["sizes"], attrition=req["attrition"], methods=req["methods"])
else:
    grid = paper_ablations_grid(seeds=req["seeds"])
for method in sorted({c.method for c in grid.configs}):
    run_episode(problem_preset("XS", 0.01), method, {}, 10_000)      # warm-up: imports, JIT caches
out = []
for c in grid.configs:
    problem = c.problem()
    for seed in grid.seeds:
        cpu = []
        for _ in range(req["repeat"]):          # the least CPU of the repeats: the least disturbed
            c0 = time.process_time()
            r = run_episode(problem, c.method, c.params, int(seed))
            cpu.append(time.process_time() - c0)
        out.append([c.label or c.method, c.size, c.attrition, int(seed), r.tu1, r.tu2, min(cpu)])
print(json.dumps(out))
"""


def run_tree(tree: str, request: dict) -> list:
    env = {
        **os.environ,
        "PYTHONPATH": tree,
        "OMP_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "NUMBA_NUM_THREADS": "1",
    }
    out = subprocess.run(
        [sys.executable, "-c", CHILD, json.dumps(request)],
        capture_output=True,
        text=True,
        env=env,
        cwd=tree,
    )
    if out.returncode:
        sys.exit(f"{tree}: {out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def export_commit(commit: str, here: str) -> str:
    """``git archive <commit>`` of this repository into a fresh temporary directory."""
    dest = tempfile.mkdtemp(prefix=f"phireman-{commit[:10]}-")
    archive = subprocess.run(
        ["git", "-C", here, "archive", commit], capture_output=True, check=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", dest], input=archive, check=True)
    return dest


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--baseline", help="root of the previous code tree")
    src.add_argument("--commit", help="a commit of this repository (git archive into a temp dir)")
    ap.add_argument("--sizes", nargs="+", default=list(SIZES))
    ap.add_argument(
        "--attrition", nargs="+", type=float, default=list(LEVELS), help="fractions, e.g. 0.01"
    )
    ap.add_argument("--methods", nargs="+", default=list(METHODS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="run each (config, seed) this many times and keep the least CPU (a shared machine)",
    )
    ap.add_argument(
        "--no-ablations", action="store_true", help="skip the 7 ablation variants at S / 1 %%"
    )
    ap.add_argument(
        "--workers", type=int, default=2, help="workers of the sweep whose time is estimated"
    )
    ap.add_argument(
        "--sweep-seeds", type=int, default=100, help="seeds of the sweep whose time is estimated"
    )
    ap.add_argument("--quiet", action="store_true", help="no line per cell")
    args = ap.parse_args(argv)
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    base = args.baseline or export_commit(args.commit, here)
    print(
        f"old: {base}{f' (commit {args.commit})' if args.commit else ''}\nnew: {here}", flush=True
    )

    requests = [
        (
            size,
            {
                "grid": "table",
                "sizes": [size],
                "attrition": args.attrition,
                "methods": args.methods,
                "seeds": args.seeds,
                "repeat": args.repeat,
            },
        )
        for size in args.sizes
    ]
    if not args.no_ablations:
        requests.append(
            ("ablations", {"grid": "ablations", "seeds": args.seeds, "repeat": args.repeat})
        )
    rows = []  # (group, label, size, att, seed, old, new)
    for k, (group, req) in enumerate(requests):
        # alternate which tree goes first, so that a drift in load does not always favour one
        first, second = (base, here) if k % 2 == 0 else (here, base)
        a, b = run_tree(first, req), run_tree(second, req)
        old, new = (a, b) if first == base else (b, a)
        for o, n in zip(old, new, strict=True):
            assert o[:4] == n[:4], (o, n)
            rows.append((group, o[0], o[1], o[2], o[3], o, n))
        for label in dict.fromkeys(r[1] for r in rows if r[0] == group):
            for att in dict.fromkeys(r[3] for r in rows if r[0] == group and r[1] == label):
                cell = [r for r in rows if r[0] == group and r[1] == label and r[3] == att]
                same = sum(r[5][4:6] == r[6][4:6] for r in cell)
                c_old = sum(r[5][6] for r in cell) / len(cell)
                c_new = sum(r[6][6] for r in cell) / len(cell)
                if not args.quiet:
                    print(
                        f"{group:9s} {label:20s} {100 * att:4.1f} %: cpu s/run {c_old:7.3f} -> {c_new:7.3f} "
                        f"({c_old / c_new:4.2f}x)  TU1/TU2 identical {same}/{len(cell)}",
                        flush=True,
                    )

    # Per (size, method): mean CPU s per run over the levels and seeds measured.
    per = defaultdict(lambda: [0.0, 0.0, 0])
    for group, label, *_rest, o, n in rows:
        key = (group, label)
        per[key][0] += o[6]
        per[key][1] += n[6]
        per[key][2] += 1
    print("\nCPU s per run (mean over the levels and seeds measured), old -> new:")
    print(f"{'size':9s} " + "  ".join(f"{m:>24s}" for m in args.methods))
    for size in args.sizes:
        cells = []
        for m in args.methods:
            o, n, c = per[(size, m)]
            cells.append(f"{o / c:7.3f} -> {n / c:6.3f} {o / n:4.2f}x" if c else "-")
        print(f"{size:9s} " + "  ".join(f"{x:>24s}" for x in cells))
    if not args.no_ablations:
        o = sum(v[0] for k, v in per.items() if k[0] == "ablations")
        n = sum(v[1] for k, v in per.items() if k[0] == "ablations")
        c = sum(v[2] for k, v in per.items() if k[0] == "ablations")
        print(
            f"{'ablations':9s} {o / c:7.3f} -> {n / c:6.3f} {o / n:4.2f}x (7 variants at S / 1 %)"
        )

    # The sweep: every (config) at --sweep-seeds seeds; a config's cost is its measured mean.
    cfg = defaultdict(lambda: [0.0, 0.0, 0])
    for group, label, _size, att, *_rest, o, n in rows:
        cfg[(group, label, att)][0] += o[6]
        cfg[(group, label, att)][1] += n[6]
        cfg[(group, label, att)][2] += 1
    tot_old = sum(v[0] / v[2] for v in cfg.values()) * args.sweep_seeds / 60
    tot_new = sum(v[1] / v[2] for v in cfg.values()) * args.sweep_seeds / 60
    print(
        f"\nsweep estimate ({len(cfg)} configurations x {args.sweep_seeds} seeds): CPU {tot_old:.1f} -> "
        f"{tot_new:.1f} min ({tot_old / tot_new:.2f}x); wall on {args.workers} workers (CPU / workers, "
        f"perfect packing): {tot_old / args.workers:.1f} -> {tot_new / args.workers:.1f} min"
    )
    if args.commit:
        shutil.rmtree(base, ignore_errors=True)
    bad = sum(r[5][4:6] != r[6][4:6] for r in rows)
    print("TU1 / TU2: all identical" if not bad else f"TU1 / TU2: {bad} of {len(rows)} runs differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

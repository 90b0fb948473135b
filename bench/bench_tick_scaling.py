"""Benchmark: one planning tick against swarm size, central information (the ground station's case).

For each size (drones / tasks) a fresh subprocess (one BLAS thread, so peak RSS is its own) builds
the problem by scaling the XL geometry (field half-width grows with sqrt(tasks), so the task density
and the drones per task stay those of XL), spreads the swarm like a mid-mission swarm (uniform over
the inner third of the field, tasks uniform over the field), and times ``planner.plan`` for
``--ticks`` ticks, moving the drones by the planned displacement and the tasks by their random walk.
The first tick (tree build, JIT warm-up) is reported apart as ``first``.

    .venv/bin/python bench/bench_tick_scaling.py [--sizes 20 50 ... 10000] [--ticks 20] [--plot docs/results/tick_scaling.png]

CPU time (process_time) is printed beside wall time: on a shared machine it is the figure to quote.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

#: drones -> tasks: the paper's Table III sizes, then the issue-16 scale points.
TASKS = {20: 5, 50: 10, 100: 20, 200: 50, 500: 100, 1000: 200, 2000: 400, 5000: 700, 10000: 1000}

CHILD = r"""
import json, math, resource, sys, time
import numpy as np
from planner.methods import TickInput, make_planner
from planner.problem import problem_preset
n, m, ticks, method, seed = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], int(sys.argv[5])
xl = problem_preset("XL", 0.01)
half = xl.field_half_width_m * math.sqrt(m / xl.n_tasks)
prob = xl.replace(n_drones=n, n_tasks=m, field_half_width_m=half)
rng = np.random.default_rng(seed)
planner = make_planner(method, prob, {}, np.random.default_rng(seed + 1))
pos = rng.uniform(-half / 3, half / 3, (n, 2))
tasks = rng.uniform(-half, half, (m, 2))
alive = np.ones(n, bool)
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
wall, cpu = [], []
for t in range(ticks + 1):
    tasks = np.clip(tasks + rng.normal(0, prob.task_walk_sigma_m, tasks.shape), -half, half)
    tick = TickInput(t, pos, alive, alive, tasks)
    w0, c0 = time.perf_counter(), time.process_time()
    out = planner.plan(tick)
    wall.append(time.perf_counter() - w0); cpu.append(time.process_time() - c0)
    pos = pos + out.disp_m
w, c = np.array(wall[1:]) * 1e3, np.array(cpu[1:]) * 1e3
print(json.dumps({"drones": n, "tasks": m, "first_ms": wall[0] * 1e3,
                  "wall_p50_ms": float(np.median(w)), "wall_p95_ms": float(np.percentile(w, 95)),
                  "cpu_mean_ms": float(c.mean()), "cpu_p50_ms": float(np.median(c)),
                  "import_rss_mb": rss0,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(n: int, m: int, ticks: int, method: str, seed: int) -> dict | None:
    env = {
        **os.environ,
        "OMP_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "NUMBA_NUM_THREADS": "1",
    }
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(n), str(m), str(ticks), method, str(seed)],
        capture_output=True,
        text=True,
        env=env,
    )
    if out.returncode:
        print(out.stderr[-2000:], file=sys.stderr)
        return None
    return json.loads(out.stdout.strip().splitlines()[-1])


def plot(rows: list[dict], path: str, before: list[dict] | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["drones"] for r in rows]
    fig, ax = plt.subplots(figsize=(6, 4.2))
    if before:
        ax.loglog(
            [r["drones"] for r in before],
            [r["cpu_p50_ms"] for r in before],
            "v:",
            color="tab:red",
            label="before (NumPy, dense N x N): CPU p50",
        )
    ax.loglog(n, [r["cpu_p50_ms"] for r in rows], "o-", label="tick CPU p50")
    ax.loglog(
        n,
        [r["cpu_mean_ms"] for r in rows],
        "^-",
        alpha=0.6,
        label="tick CPU mean (incl. tree rebuilds)",
    )
    ax.scatter(
        [2000, 10000],
        [50, 500],
        marker="x",
        color="k",
        zorder=5,
        label="goals (2,000: 50 ms; 10,000: 500 ms)",
    )
    for r in rows:
        ax.annotate(
            f"{r['tasks']}",
            (r["drones"], r["cpu_p50_ms"]),
            textcoords="offset points",
            xytext=(4, -10),
            fontsize=7,
            color="0.4",
        )
    ax.set_xlabel("drones (tasks annotated)")
    ax.set_ylabel("planning tick, ms")
    ax.set_title("PhiIREMAN central tick against swarm size")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--sizes", nargs="+", type=int, default=list(TASKS))
    ap.add_argument("--ticks", type=int, default=20)
    ap.add_argument("--method", default="phireman-central")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--plot", default=None, help="write a log-log PNG of tick time against drones")
    ap.add_argument("--json", default=None, help="also write the rows as JSON")
    ap.add_argument(
        "--from-json", default=None, help="plot rows written by --json instead of measuring"
    )
    ap.add_argument(
        "--baseline-json",
        nargs="+",
        default=None,
        help="rows of an earlier code tree (--json run there) to draw as 'before'",
    )
    args = ap.parse_args()
    before = None
    if args.baseline_json:
        before = sorted(
            (r for f in args.baseline_json for r in json.load(open(f))), key=lambda r: r["drones"]
        )
    if args.from_json:
        plot(json.load(open(args.from_json)), args.plot, before)
        return
    print(
        f"{'drones':>7} {'tasks':>6} {'first ms':>9} {'cpu p50':>8} {'cpu mean':>9} {'wall p50':>9} "
        f"{'wall p95':>9} {'peak MB':>8}",
        flush=True,
    )
    rows = []
    for n in args.sizes:
        r = run(n, TASKS.get(n, max(1, n // 10)), args.ticks, args.method, args.seed)
        if r is None:
            continue
        rows.append(r)
        print(
            f"{n:7d} {r['tasks']:6d} {r['first_ms']:9.1f} {r['cpu_p50_ms']:8.1f} {r['cpu_mean_ms']:9.1f} "
            f"{r['wall_p50_ms']:9.1f} {r['wall_p95_ms']:9.1f} {r['peak_rss_mb']:8.0f}",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    if args.plot and rows:
        plot(rows, args.plot, before)


if __name__ == "__main__":
    main()

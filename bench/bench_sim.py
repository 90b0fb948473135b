"""Benchmark: time per run and peak memory of the in-process simulation, every size (default 1 %).

Each (size, information model) runs in a fresh subprocess with one BLAS thread, so that peak RSS is
its own; CPU time (process_time) is reported beside wall time because it is robust to other load.

    .venv/bin/python bench/bench_sim.py [--seeds 3] [--sizes XS S M L XL] [--method phireman] [--attrition 0.01]
                                        [--baseline /tmp/base] [--numpy-ref]

``--baseline DIR`` also runs every cell with the code tree at DIR (e.g. ``git archive <commit> | tar -x
-C DIR``), interleaved with this tree's runs in the same session, and prints the ratio old / new of
the CPU seconds per run. ``--numpy-ref`` does the same with this tree's NumPy reference paths
(``planner._kernels.ENABLED = False``) as "old".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time
from mission.experiments.sim import run_episode
from planner.problem import problem_preset
size, info, seeds, method, attrition = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], float(sys.argv[5])
if len(sys.argv) > 6 and sys.argv[6] == "numpy":
    from planner import _kernels
    _kernels.ENABLED = False
p = problem_preset(size, attrition)
params = {"info": info} if method.startswith("phireman") or method == "dccrs" else {}
run_episode(p, method, params, 10_000)  # warm-up (imports, caches)
times, cpu = [], []
for s in range(seeds):
    t0, c0 = time.perf_counter(), time.process_time()
    run_episode(p, method, params, s)
    times.append(time.perf_counter() - t0); cpu.append(time.process_time() - c0)
print(json.dumps({"size": size, "info": info, "s_per_run": sum(times) / len(times),
                  "cpu_s_per_run": sum(cpu) / len(cpu), "min_cpu_s": min(cpu),
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run_cell(
    size: str, info: str, args, tree: str | None = None, numpy_ref: bool = False
) -> dict | None:
    env = {
        "OMP_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "PATH": "/usr/bin:/bin",
        "HOME": os.environ.get("HOME", "/tmp"),
    }
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = tree or here
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            CHILD,
            size,
            info,
            str(args.seeds),
            args.method,
            str(args.attrition),
            "numpy" if numpy_ref else "fast",
        ],
        capture_output=True,
        text=True,
        env=env,
        cwd=tree or here,
    )
    if out.returncode:
        print(out.stderr[-2000:], file=sys.stderr)
        return None
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--sizes", nargs="+", default=["XS", "S", "M", "L", "XL"])
    ap.add_argument("--infos", nargs="+", default=["central", "async"])
    ap.add_argument("--method", default="phireman")
    ap.add_argument(
        "--attrition", type=float, default=0.01, help="per-step loss probability (0.01 = 1 %%)"
    )
    ap.add_argument(
        "--baseline", default=None, help="code tree to compare against (old / new ratios)"
    )
    ap.add_argument(
        "--numpy-ref", action="store_true", help="compare against this tree's NumPy paths"
    )
    args = ap.parse_args()
    compare = args.baseline is not None or args.numpy_ref
    # CPU time is the figure to quote on a shared machine; wall time is printed beside it.
    head = f"{'size':>4} {'info':>8} {'cpu s/run':>10} {'min cpu s':>10} {'wall s/run':>10} {'peak MB':>8}"
    print(head + (f" {'old cpu s':>10} {'old/new':>8}" if compare else ""), flush=True)
    for size in args.sizes:
        for info in args.infos:
            old = (
                run_cell(size, info, args, args.baseline, args.numpy_ref and args.baseline is None)
                if compare
                else None
            )
            r = run_cell(size, info, args)
            if r is None:
                continue
            line = (
                f"{size:>4} {info:>8} {r['cpu_s_per_run']:10.3f} {r['min_cpu_s']:10.3f} "
                f"{r['s_per_run']:10.3f} {r['peak_rss_mb']:8.0f}"
            )
            if old is not None:
                line += f" {old['cpu_s_per_run']:10.3f} {old['cpu_s_per_run'] / r['cpu_s_per_run']:8.2f}"
            print(line, flush=True)


if __name__ == "__main__":
    main()

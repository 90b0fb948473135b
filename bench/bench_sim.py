"""Benchmark: time per run and peak memory of the in-process simulation, every size (default 1 %).

Each (size, information model) runs in a fresh subprocess with one BLAS thread, so that peak RSS is
its own; CPU time (process_time) is reported beside wall time because it is robust to other load.

    .venv/bin/python bench/bench_sim.py [--seeds 3] [--sizes XS S M L XL] [--method phireman] [--attrition 0.01]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time
from mission.sim import run_episode
from planner.problem import problem_preset
size, info, seeds, method, attrition = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], float(sys.argv[5])
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--sizes", nargs="+", default=["XS", "S", "M", "L", "XL"])
    ap.add_argument("--infos", nargs="+", default=["central", "async"])
    ap.add_argument("--method", default="phireman")
    ap.add_argument("--attrition", type=float, default=0.01, help="per-step loss probability (0.01 = 1 %%)")
    args = ap.parse_args()
    # CPU time is the figure to quote on a shared machine; wall time is printed beside it.
    print(f"{'size':>4} {'info':>8} {'cpu s/run':>10} {'min cpu s':>10} {'wall s/run':>10} {'peak MB':>8}")
    for size in args.sizes:
        for info in args.infos:
            out = subprocess.run([sys.executable, "-c", CHILD, size, info, str(args.seeds), args.method,
                                  str(args.attrition)],
                                 capture_output=True, text=True, env={"OMP_NUM_THREADS": "1",
                                                                       "OPENBLAS_NUM_THREADS": "1",
                                                                       "PATH": "/usr/bin:/bin"})
            if out.returncode:
                print(out.stderr[-2000:], file=sys.stderr)
                continue
            r = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{size:>4} {info:>8} {r['cpu_s_per_run']:10.3f} {r['min_cpu_s']:10.3f} "
                  f"{r['s_per_run']:10.3f} {r['peak_rss_mb']:8.0f}")


if __name__ == "__main__":
    main()

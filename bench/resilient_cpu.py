"""Issue 28: CPU seconds per run of ``phireman-resilient`` (heard and oracle base) against ``phireman``.

One process runs, for every configuration and seed asked, the three planners one after the other
(``mission.experiments.sim.run_episode``, after a warm-up run of each for the imports and JIT caches) and
measures each run's CPU time (``time.process_time``): the three share the process, the machine's
load and the seed, so the ratios compare like with like. Prints a Markdown table per
configuration and the totals over the 25 configurations.

usage:
  python bench/resilient_cpu.py --seeds 0 1            # every configuration of Table II
  python bench/resilient_cpu.py --cells S:1 M:2 --seeds 0 1 2
"""

from __future__ import annotations

import argparse
import sys
import time

from mission.experiments.sim import run_episode
from planner.problem import problem_preset

VARIANTS = (
    ("phireman", "phireman", {}),
    ("heard", "phireman-resilient", {"base_view": "heard"}),
    ("oracle", "phireman-resilient", {"base_view": "oracle"}),
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--cells", nargs="+", default=None, metavar="SIZE:PCT")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    args = ap.parse_args(argv)
    cells = args.cells or [
        f"{s}:{p}" for s in ("XS", "S", "M", "L", "XL") for p in ("0", "0.5", "1", "2", "5")
    ]
    for _, method, params in VARIANTS:  # warm-up: imports, JIT caches
        run_episode(problem_preset("XS", 0.01), method, params, 10_000)
    print("| Size | p (%) | `phireman` s/run | heard base s/run (×) | oracle base s/run (×) | n |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    total = dict.fromkeys((v[0] for v in VARIANTS), 0.0)
    for cell in cells:
        size, pct = cell.split(":")
        problem = problem_preset(size.upper(), float(pct) / 100)
        cpu = dict.fromkeys((v[0] for v in VARIANTS), 0.0)
        for seed in args.seeds:
            for label, method, params in VARIANTS:
                c0 = time.process_time()
                run_episode(problem, method, params, seed)
                cpu[label] += time.process_time() - c0
        n = len(args.seeds)
        for k in cpu:
            total[k] += cpu[k] / n
        phi = cpu["phireman"] / n
        print(
            f"| {size.upper()} | {pct} | {phi:.3f} | {cpu['heard'] / n:.3f} "
            f"({cpu['heard'] / cpu['phireman']:.1f}×) | {cpu['oracle'] / n:.3f} "
            f"({cpu['oracle'] / cpu['phireman']:.1f}×) | {n} |",
            flush=True,
        )
    print(
        f"\nsum over the cells of the mean s/run: phireman {total['phireman']:.2f}, heard "
        f"{total['heard']:.2f} ({total['heard'] / total['phireman']:.1f}×), oracle "
        f"{total['oracle']:.2f} ({total['oracle'] / total['phireman']:.1f}×)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

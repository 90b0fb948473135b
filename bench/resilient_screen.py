"""Quick paired screen of planner variants (issue 15 tuning): in-process episodes, no store.

Runs every variant on the same seeds (common random numbers: same scenario, same attrition
draws) with a process pool and prints each variant's mean TU1 / TU2 and its paired difference to
the first variant (two-sided paired t-test on TU1). For the recorded search use ``phireman tune``
(resumable store, Markdown record); this is for the look before it.

usage:
  python bench/resilient_screen.py SIZE ATTRITION SEED0 NSEEDS 'JSON list of [method, params]'
  python bench/resilient_screen.py S 0.01 1000 20 \\
      '[["phireman-resilient",{}],["phireman-resilient",{"redundancy_gain":0.1}]]'
"""

from __future__ import annotations

import json
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from scipy.stats import ttest_rel

from mission.experiments.sim import run_episode
from planner.problem import problem_preset


def _one(job: tuple[str, float, str, dict, int]) -> tuple[float, float]:
    size, attrition, method, params, seed = job
    r = run_episode(problem_preset(size, attrition), method, params, seed)
    return r.tu1, r.tu2


def main(argv: list[str]) -> int:
    if len(argv) != 5:
        print(__doc__, file=sys.stderr)
        return 2
    size, attrition, seed0, n = argv[0], float(argv[1]), int(argv[2]), int(argv[3])
    variants = json.loads(argv[4])
    jobs = [(size, attrition, m, p, s) for m, p in variants for s in range(seed0, seed0 + n)]
    with ProcessPoolExecutor(2) as ex:
        res = np.array(list(ex.map(_one, jobs, chunksize=2))).reshape(len(variants), n, 2) * 100
    for i, (m, p) in enumerate(variants):
        d = res[i] - res[0]
        pv = ttest_rel(res[i, :, 0], res[0, :, 0]).pvalue if i else float("nan")
        print(
            f"{m} {p}: TU1 {res[i, :, 0].mean():.2f} TU2 {res[i, :, 1].mean():.2f}  "
            f"dTU1 {d[:, 0].mean():+.2f} (p {pv:.3f}) dTU2 {d[:, 1].mean():+.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

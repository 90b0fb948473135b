"""Benchmark: one ground-station control tick at XL (500 vehicles, 100 tasks), central PhiIREMAN.

Times :func:`gcs.control.tick` (planner + targets) on a fleet spread like a mid-mission XL swarm,
advancing the fleet by the planned displacement each tick. Goal: p95 <= 50 ms.

    .venv/bin/python bench/bench_gcs_tick.py --ticks 100
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from gcs.control import ControlConfig, Geofence, tick
from planner.methods import make_planner
from planner.problem import problem_preset


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    prob = problem_preset("XL", 0.01)
    w = prob.field_half_width_m
    planner = make_planner("phireman-central", prob, {}, rng)
    pos = np.column_stack(
        [rng.uniform(-w / 3, w / 3, (prob.n_drones, 2)), np.full(prob.n_drones, -30.0)]
    )
    tasks = rng.uniform(-w, w, (prob.n_tasks, 2))
    net = np.ones(prob.n_drones, bool)
    cfg = ControlConfig(geofence=Geofence.square(1.2 * w))
    times = []
    for t in range(args.ticks):
        tasks = np.clip(tasks + rng.normal(0, prob.task_walk_sigma_m, tasks.shape), -w, w)
        t0 = time.perf_counter()
        r = tick(pos, net, net, tasks, planner, t, cfg)
        times.append(time.perf_counter() - t0)
        pos[r.rows, :2] = r.target_ned_m[:, :2]
    ms = np.array(times) * 1e3
    print(
        json.dumps(
            {
                "vehicles": prob.n_drones,
                "tasks": prob.n_tasks,
                "ticks": args.ticks,
                "p50_ms": round(float(np.percentile(ms, 50)), 2),
                "p95_ms": round(float(np.percentile(ms, 95)), 2),
                "max_ms": round(float(ms.max()), 2),
                "first_ms": round(float(ms[0]), 2),
            }
        )
    )


if __name__ == "__main__":
    main()

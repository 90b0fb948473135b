"""Hazard awareness on a mission with hazard zones (docs/results/hazard.md): per-seed TU1 / TU2 and
the time drones spend inside active zones, played in process (mission.experiments.playback.run_inprocess, the
station's tick), then the paired comparison against ``phireman``.

    PYTHONPATH=$PWD .venv/bin/python bench/bench_hazard.py run mission/format/examples/hazard_zone.yaml \\
        --info central --seeds 0 10 \\
        --config phireman phireman '{}' \\
        --config avoid+push1 phireman-resilient '{"hazard_avoid": true, "hazard_push_gain": 1.0}' \\
        > runs.jsonl
    PYTHONPATH=$PWD .venv/bin/python bench/bench_hazard.py summary runs.jsonl

``inside`` is drone-seconds inside an active zone (alive drones), ``exp. losses`` the expected
number of zone losses (the sum of rate x dt over alive drones and steps), ``lost`` the drones lost
(background and zones).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import time

import numpy as np


def run(args: argparse.Namespace) -> None:
    from mission.format.load import load_mission
    from mission.experiments.playback import run_inprocess
    from mission.format.scenario import hazard_map
    from planner.hazard import hazard_rate_per_s

    m = load_mission(args.mission)
    hm = hazard_map(m.attrition)
    dt = m.run.control_period_s
    for name, method, params in args.config:
        spec = dataclasses.replace(
            m.planner, method=method, params=json.loads(params), info=args.info
        )
        for seed in range(*args.seeds):
            t0 = time.process_time()
            r = run_inprocess(dataclasses.replace(m, planner=spec), seed)
            rec = r.record
            tau = len(r.series.tu1_step)
            rate = np.stack([hazard_rate_per_s(hm, rec.pos_m[k], k * dt) for k in range(tau)])
            live = rec.alive[:tau]
            row = dict(
                name=name,
                info=args.info,
                seed=seed,
                tu1=r.tu1,
                tu2=r.tu2,
                lost=len(r.losses),
                exposure=float((rate * live).sum() * dt),
                inside_s=float(((rate > 0) & live).sum() * dt),
                cpu_s=time.process_time() - t0,
            )
            print(json.dumps(row), flush=True)


def summary(args: argparse.Namespace) -> None:
    from scipy.stats import ttest_rel

    rows = [json.loads(line) for f in args.files for line in open(f) if line.strip()]
    by: dict = collections.defaultdict(dict)
    for r in rows:
        by[(r["info"], r["name"])][r["seed"]] = r
    print(
        "| info | config | n | TU1 % | ΔTU1 | p | TU2 % | ΔTU2 | p | inside drone-s | exp. zone losses | lost |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (info, name), d in by.items():
        ref = by.get((info, args.reference), {})
        seeds = sorted(set(d) & set(ref))
        cols = []
        for key in ("tu1", "tu2"):
            a = np.array([d[s][key] for s in seeds])
            b = np.array([ref[s][key] for s in seeds])
            p = ttest_rel(a, b).pvalue if len(seeds) > 1 and np.any(a != b) else float("nan")
            cols += [f"{100 * a.mean():.2f}", f"{100 * (a - b).mean():+.2f}", f"{p:.3f}"]
        mean = {k: np.mean([d[s][k] for s in seeds]) for k in ("inside_s", "exposure", "lost")}
        print(
            f"| {info} | {name} | {len(seeds)} | {' | '.join(cols)} | {mean['inside_s']:.0f} "
            f"| {mean['exposure']:.1f} | {mean['lost']:.1f} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("mission")
    r.add_argument("--info", default="central", choices=("central", "async"))
    r.add_argument("--seeds", type=int, nargs=2, default=(0, 10), metavar=("FIRST", "STOP"))
    r.add_argument(
        "--config", nargs=3, action="append", required=True, metavar=("NAME", "METHOD", "JSON")
    )
    s = sub.add_parser("summary")
    s.add_argument("files", nargs="+")
    s.add_argument("--reference", default="phireman")
    args = ap.parse_args()
    run(args) if args.cmd == "run" else summary(args)


if __name__ == "__main__":
    main()

"""Issue 25: the cost of endurance in process — one ``wildfire_2h`` seed against the 200-s mission.

Plays the shipped ``wildfire`` mission (200 s, endless batteries) and ``wildfire_2h`` (two hours,
batteries and relay rotation) in this process, one after the other for each seed, and prints the
CPU seconds of each, the ratio, and the CPU per simulated hour. The goal is one ``wildfire_2h``
seed under 30 s on one core; the ratio against the 200-s mission measured in the same run is the
figure that travels between machines.

    .venv/bin/python bench/bench_endurance.py --seeds 0 1 2
    .venv/bin/python bench/bench_endurance.py --seeds 0 --rotation off
"""

from __future__ import annotations

import argparse
import time

from mission.experiments.playback import run_inprocess
from mission.format.examples import example_path
from mission.format.load import load_mission


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--rotation", choices=["mission", "on", "off"], default="mission")
    args = ap.parse_args()
    short = load_mission(example_path("wildfire"))
    long = load_mission(example_path("wildfire_2h"))
    run_inprocess(short, 10_000)  # warm-up: imports and the compiled kernels' caches
    rows = []
    for seed in args.seeds:
        c0 = time.process_time()
        a = run_inprocess(short, seed)
        c1 = time.process_time()
        b = run_inprocess(long, seed, rotation=args.rotation)
        c2 = time.process_time()
        rows.append((seed, c1 - c0, c2 - c1, a.tu1, b.tu1))
        print(
            f"seed {seed}: wildfire {c1 - c0:6.2f} s CPU (TU1 {100 * a.tu1:5.1f} %), "
            f"wildfire_2h {c2 - c1:6.2f} s CPU (TU1 {100 * b.tu1:5.1f} %), "
            f"ratio {(c2 - c1) / (c1 - c0):5.1f}x"
        )
    short_s = sum(r[1] for r in rows) / len(rows)
    long_s = sum(r[2] for r in rows) / len(rows)
    print(
        f"mean: wildfire {short_s:.2f} s, wildfire_2h {long_s:.2f} s CPU per seed "
        f"({long_s / 2:.2f} s per simulated hour; {long_s / short_s:.1f}x the 200-s mission for "
        f"36x the simulated time); goal: under 30 s per seed"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

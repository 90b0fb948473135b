"""The canyon mission terrain-blind vs terrain-aware, in process, over many seeds (issue 27).

    .venv/bin/python bench/terrain_canyon.py --seeds 100
    .venv/bin/python bench/terrain_canyon.py --seeds 100 --mission canyon_deep
    .venv/bin/python bench/terrain_canyon.py --seeds 100 --mission canyon_camp

Each seed is played three ways (mission.experiments.playback.TERRAIN_AWARE): 'off' (today's
system: the disc planner, one altitude above the base), 'altitude' (terrain following under the
ceiling, disc planner) and 'on' (that, with the planner's moves checked against the terrain
radio, planned in 3-D: altitudes per drone, relay search, tree edges relays can hold). Prints TU1
and TU2 (mean +- 95 % CI), paired differences with a paired t-test and a
Wilcoxon signed-rank test, crashes into the ground, the least clearance along every flight, the
highest height above the ground and how many drone-steps and drones were above the ceiling (a
legal flight has none), and the CPU time of each mode. Seeds share scenario and attrition streams (common random
numbers, docs/design/model.md §6.1), so the pairs are paired.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import numpy as np
from scipy import stats

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from mission.experiments.playback import TERRAIN_AWARE, run_inprocess  # noqa: E402
from mission.format.examples import example_path  # noqa: E402
from mission.format.load import load_mission  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--mission", default="canyon")
    ap.add_argument("--out", type=pathlib.Path, default=None, help="write per-seed rows (JSON)")
    ap.add_argument(
        "--modes",
        default=",".join(TERRAIN_AWARE),
        help="comma-separated --terrain-aware modes to fly (default: all)",
    )
    args = ap.parse_args()
    modes = tuple(m for m in args.modes.split(",") if m)
    if not modes or any(m not in TERRAIN_AWARE for m in modes):
        ap.error(f"--modes: choose from {', '.join(TERRAIN_AWARE)}")
    mission = load_mission(example_path(args.mission))
    seeds = list(range(args.seed, args.seed + args.seeds))
    rows: dict[str, list[dict]] = {m: [] for m in modes}
    cpu_of = dict.fromkeys(modes, 0.0)
    t0 = time.process_time()
    for s in seeds:
        for mode in modes:
            t1 = time.process_time()
            r = run_inprocess(mission, s, terrain_aware=mode)
            cpu_of[mode] += time.process_time() - t1
            assert r.terrain is not None  # a terrain mission
            rows[mode].append({"seed": s, "tu1": r.tu1, "tu2": r.tu2, **r.terrain})
    cpu = time.process_time() - t0
    print(f"{args.mission}: {len(seeds)} seeds ({seeds[0]}..{seeds[-1]}), {cpu:.0f} s CPU")
    for mode in modes:
        rs = rows[mode]
        line = f"  {mode:8s}"
        for k in ("tu1", "tu2"):
            v = 100 * np.array([r[k] for r in rs])
            half = stats.t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v))
            line += f"  {k.upper()} {v.mean():6.2f} +- {half:4.2f} %"
        line += (
            f"  crashes {sum(r['crashes'] for r in rs)}"
            f"  least clearance {min(r['min_clearance_m'] for r in rs):.1f} m"
            f"  flights below clearance {sum(r['flights_below_clearance'] for r in rs)}"
            f"  highest {max(r['max_agl_m'] for r in rs):.1f} m AGL"
            f"  above the ceiling: {sum(r['flights_above_ceiling'] for r in rs)} flights,"
            f" {sum(r['drones_above_ceiling'] for r in rs)} drones"
            f"  {cpu_of[mode]:.0f} s CPU"
        )
        print(line)
    for a, b in (("on", "off"), ("on", "altitude"), ("altitude", "off")):
        if a not in rows or b not in rows:
            continue
        for k in ("tu1", "tu2"):
            x = 100 * np.array([r[k] for r in rows[a]])
            y = 100 * np.array([r[k] for r in rows[b]])
            d = x - y
            half = stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d))
            t_p = stats.ttest_rel(x, y).pvalue if d.any() else 1.0
            w_p = stats.wilcoxon(x, y).pvalue if d.any() else 1.0
            print(
                f"  {a} - {b}: {k.upper()} {d.mean():+6.2f} +- {half:4.2f} points "
                f"(paired t p = {t_p:.2g}, Wilcoxon p = {w_p:.2g}, {int((d > 0).sum())} seeds "
                f"better, {int((d < 0).sum())} worse)"
            )
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

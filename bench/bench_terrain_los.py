"""Line of sight over terrain per tick: every candidate pair of a 500-drone swarm (issue 27).

    .venv/bin/python bench/bench_terrain_los.py [--drones 500] [--ticks 20]

The deep canyon's terrain and link budget (mission/format/examples/canyon_deep.yaml); drones spread
uniformly over +-900 m at 100 m above the ground. Per tick: the candidate pairs (within the
budget's range horizontally, planner.terrain.TerrainRadio.candidate_pairs), the compiled line of
sight / Fresnel test of every one (TerrainRadio.links_clear), and the truth's whole connectivity
(TerrainRadio.active_mask). Each case runs in a fresh subprocess with one BLAS thread; CPU time
per tick is reported beside wall time (architecture.md §9), after one warm-up tick (Numba's
compilation, cached on disk). ``--reference`` times the slow loop (links_clear_reference) on the
first 2000 pairs for scale.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys

CASE = r"""
import json, sys, time
import numpy as np
sys.path.insert(0, {root!r})
from mission.format.examples import example_path
from mission.format.load import load_mission
from mission.format.terrain import build_terrain
from planner.terrain import TerrainRadio, links_clear_reference
m = load_mission(example_path("canyon_deep"))
radio = TerrainRadio(build_terrain(m), m.radio.terrain_link.link_budget())
rng = np.random.default_rng(0)
n, ticks = {drones}, {ticks}
out = {{"drones": n, "range_m": radio.budget.max_range_m}}
def swarm():
    p = rng.uniform(-900, 900, (n, 2))
    return p, radio.terrain.height_m(p) + 100.0
p, h = swarm()
radio.active_mask(p, h, np.ones(n, bool), np.zeros(2), 2103.0)  # warm-up (compilation)
pairs_t = los_t = mask_t = 0.0
n_pairs = n_clear = 0
for _ in range(ticks):
    p, h = swarm()
    c0 = time.process_time()
    pairs = radio.candidate_pairs(p)
    c1 = time.process_time()
    p3 = np.column_stack([p, h])
    ok = radio.links_clear(p3[pairs[:, 0]], p3[pairs[:, 1]])
    c2 = time.process_time()
    radio.active_mask(p, h, np.ones(n, bool), np.zeros(2), 2103.0)
    c3 = time.process_time()
    pairs_t += c1 - c0; los_t += c2 - c1; mask_t += c3 - c2
    n_pairs += len(pairs); n_clear += int(ok.sum())
out.update(pairs_per_tick=n_pairs / ticks, clear_fraction=n_clear / max(n_pairs, 1),
           candidate_ms=1e3 * pairs_t / ticks, los_ms=1e3 * los_t / ticks,
           active_mask_ms=1e3 * mask_t / ticks)
if {reference}:
    k = min(2000, len(pairs))
    c0 = time.process_time()
    links_clear_reference(radio.terrain, radio.budget, p3[pairs[:k, 0]], p3[pairs[:k, 1]])
    out["reference_ms_per_1000_pairs"] = 1e3 * (time.process_time() - c0) / k * 1000
print(json.dumps(out))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drones", type=int, default=500)
    ap.add_argument("--ticks", type=int, default=20)
    ap.add_argument("--reference", action="store_true")
    args = ap.parse_args()
    root = str(pathlib.Path(__file__).resolve().parents[1])
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    code = CASE.format(
        root=root, drones=args.drones, ticks=args.ticks, reference=bool(args.reference)
    )
    res = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    r = json.loads(res.stdout.strip().splitlines()[-1])
    print(
        f"{r['drones']} drones, link range {r['range_m']:.0f} m: {r['pairs_per_tick']:.0f} candidate "
        f"pairs per tick ({100 * r['clear_fraction']:.0f} % clear)"
    )
    print(f"  candidate pairs      {r['candidate_ms']:7.2f} ms CPU per tick")
    print(f"  line of sight test   {r['los_ms']:7.2f} ms CPU per tick")
    print(f"  truth active_mask    {r['active_mask_ms']:7.2f} ms CPU per tick (all of it)")
    if "reference_ms_per_1000_pairs" in r:
        print(f"  reference loop       {r['reference_ms_per_1000_pairs']:7.1f} ms per 1000 pairs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

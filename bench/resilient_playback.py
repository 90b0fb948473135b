"""Issue 15: the flights' missions played in process (the station's control tick on the world
model, ``mission.experiments.playback.run_inprocess``), ``phireman`` vs ``phireman-resilient``, paired by seed.

The same comparison as ``bench/resilient_flights.py`` without the MAVLink loop: deterministic for
a seed, so the only difference between two arms is the planner, and cheap enough for 100 seeds.

    python bench/resilient_playback.py --seeds 11-110 \\
        --mission wildfire /work/flight/m/wildfire_phireman.yaml /work/flight/m/wildfire_resilient.yaml

Each --mission is NAME PHIREMAN_FILE RESILIENT_FILE (the shipped mission with only planner.method
changed). Prints one Markdown row per mission (Δ: sd of the differences, two-sided paired p).
"""

from __future__ import annotations

import argparse

import numpy as np
from resilient_flights import HEADER, paired_row  # bench/ is on sys.path when run as a script

from mission.format.load import load_mission
from mission.experiments.playback import run_inprocess


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="11-110", help="seed range, e.g. 11-110")
    ap.add_argument(
        "--mission",
        nargs=3,
        action="append",
        required=True,
        metavar=("NAME", "PHIREMAN_FILE", "RESILIENT_FILE"),
    )
    args = ap.parse_args(argv)
    lo, _, hi = args.seeds.partition("-")
    seeds = range(int(lo), int(hi or lo) + 1)
    print(HEADER)
    for name, *files in args.mission:
        arms = []
        for path in files:
            mission = load_mission(path)
            rows = []
            for s in seeds:
                r = run_inprocess(mission, s)
                rows.append((100 * r.tu1, 100 * r.tu2))
            arms.append(np.array(rows))
        print(paired_row(name, *arms), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

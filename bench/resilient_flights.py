"""Issue 15, point 3: ``phireman fly`` (emulated) with ``phireman`` and ``phireman-resilient``,
paired by seed, scored by the emulator's ground truth (``summary.json`` ``truth``).

Each mission file is flown once per planner and seed (``--runs`` holds the run directories; a
seed already flown there is read, not flown again, so an interrupted batch resumes). The missions
are the shipped ones with only ``planner.method`` changed (and ``info: central``, the station's
default): pass them as METHOD=PATH pairs per mission name.

    python bench/resilient_flights.py --runs /work/flight/runs --seeds 11-20 \\
        --mission wildfire phireman=/work/flight/m/wildfire_phireman.yaml \\
                           phireman-resilient=/work/flight/m/wildfire_resilient.yaml

Prints one Markdown row per mission: mean TU1 / TU2 of both planners and the paired difference
(sd of the differences, two-sided paired t-test p).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.stats import ttest_rel


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def fly(mission: Path, seed: int, out: Path) -> tuple[float, float]:
    """TU1, TU2 (%) from the truth of this mission and seed, flying it if not done yet."""
    tag = f"{mission.stem}-s{seed}"
    done = out / f"{tag}.json"
    if not done.exists():
        run_parent = out / tag
        run_parent.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "mission.cli", "fly", str(mission), "--seed", str(seed)]
        cmd += ["--out", str(run_parent), "--no-wait"]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        summary = sorted(run_parent.glob("*/summary.json"))[-1]
        done.write_text(json.dumps(json.loads(summary.read_text())["truth"]))
    truth = json.loads(done.read_text())
    return 100 * truth["tu1"], 100 * truth["tu2"]


HEADER = (
    "| mission | `phireman` TU1 / TU2 | `phireman-resilient` TU1 / TU2 | Δ TU1 (sd, p) | "
    "Δ TU2 (sd, p) | n |\n| --- | ---: | ---: | ---: | ---: | ---: |"
)


def paired_row(name: str, a: np.ndarray, b: np.ndarray) -> str:
    """One Markdown row: means of ``a`` (phireman) and ``b`` (resilient), (n, 2) TU1/TU2 in %
    paired by seed, and Δ = b - a with the sd of the differences and the two-sided paired p."""
    d = b - a
    cells = [
        f"{d[:, k].mean():+.2f} ({d[:, k].std(ddof=1):.2f}, {ttest_rel(b[:, k], a[:, k]).pvalue:.2g})"
        for k in (0, 1)
    ]
    return (
        f"| {name} | {a[:, 0].mean():.2f} / {a[:, 1].mean():.2f} | {b[:, 0].mean():.2f} / "
        f"{b[:, 1].mean():.2f} | {cells[0]} | {cells[1]} | {len(a)} |"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=Path, required=True, help="directory of run directories")
    ap.add_argument("--seeds", default="11-20", help="seed range, e.g. 11-20")
    ap.add_argument(
        "--mission",
        nargs="+",
        action="append",
        required=True,
        metavar="NAME METHOD=PATH",
        help="a mission name and its METHOD=PATH files",
    )
    args = ap.parse_args(argv)
    seeds = _seeds(args.seeds)
    args.runs.mkdir(parents=True, exist_ok=True)
    print(HEADER)
    for name, *pairs in args.mission:
        files = dict(p.split("=", 1) for p in pairs)
        res = {m: np.array([fly(Path(f), s, args.runs) for s in seeds]) for m, f in files.items()}
        print(paired_row(name, res["phireman"], res["phireman-resilient"]), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

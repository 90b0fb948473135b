"""In-process vs emulator backend on one mission: TU1/TU2 from ground truth, seed by seed.

    .venv/bin/python bench/compare_backends.py [MISSION] [--seeds 1-10] [--personality ardupilot px4]
                                               [--speedup 20] [--out DIR]

For each seed: ``mission.experiments.playback.run_inprocess`` (the world model) and ``phireman fly`` against
the emulator over loopback UDP (the station, lock-step paced, at ``--speedup``), same mission and
seed (same spawn, task tracks and attrition draws). Prints one row per seed and personality, the
mean difference (emulator - in-process, percentage points) and the achieved speed-up. Exit
status 1 if a mean |difference| exceeds ``--tolerance`` points (default 3).
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time

import numpy as np


def _seeds(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        if "-" in part:
            a, b = part.split("-")
            out += range(int(a), int(b) + 1)
        else:
            out.append(int(part))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("mission", nargs="?", default="wildfire")
    p.add_argument("--seeds", default="1-10")
    p.add_argument("--personality", nargs="+", default=["ardupilot", "px4"])
    p.add_argument("--speedup", type=float, default=20.0)
    p.add_argument("--tolerance", type=float, default=3.0, help="percentage points")
    p.add_argument("--out", default=None, help="run directories (default: a temporary one)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)

    from mission.commands.fly import _load
    from mission.experiments.playback import run_inprocess
    from mission.flight.runners import FlyOptions, fly_emulated

    mission = _load(args.mission)
    out = args.out or tempfile.mkdtemp(prefix="compare-backends-")
    seeds = _seeds(args.seeds)
    ref = {s: run_inprocess(mission, s) for s in seeds}
    status = 0
    print(
        f"mission {mission.name}: in-process vs emulator (station over loopback UDP, "
        f"{args.speedup:g}x requested); TU in %, truth"
    )
    for pers in args.personality:
        print(
            f"\n{pers}\n seed | in-proc TU1  TU2 | emulator TU1  TU2 |   dTU1   dTU2 | "
            f"speed-up  wall s  alive(in/emu)"
        )
        d1, d2, sp = [], [], []
        for s in seeds:
            r = ref[s]
            t = time.monotonic()
            res = fly_emulated(
                mission,
                FlyOptions(
                    seed=s, personality=pers, speedup=args.speedup, out_dir=out, end_wait=False
                ),
            )
            wall = time.monotonic() - t
            sm = res.summary
            tr = sm.get("truth") or {}
            if sm["phase"] == "refused" or tr.get("tu1") is None:
                print(f" {s:4d} | {100 * r.tu1:6.1f} {100 * r.tu2:5.1f} | FAILED ({sm['phase']})")
                status = 1
                continue
            e1, e2 = 100 * tr["tu1"], 100 * tr["tu2"]
            d1.append(e1 - 100 * r.tu1)
            d2.append(e2 - 100 * r.tu2)
            sp.append(sm["speedup_achieved"] or 0.0)
            print(
                f" {s:4d} | {100 * r.tu1:11.1f} {100 * r.tu2:5.1f} | {e1:12.1f} {e2:5.1f} | "
                f"{d1[-1]:+6.1f} {d2[-1]:+6.1f} | {sp[-1]:8.1f} {wall:7.1f}  "
                f"{int(r.record.alive[-1].sum())}/{tr.get('alive_end')}",
                flush=True,
            )
        if d1:
            m1, m2 = float(np.mean(d1)), float(np.mean(d2))
            print(
                f" mean difference (emulator - in-process): TU1 {m1:+.2f} pts, TU2 {m2:+.2f} "
                f"pts; mean |d|: {np.mean(np.abs(d1)):.2f} / {np.mean(np.abs(d2)):.2f}; "
                f"speed-up achieved: mean {np.mean(sp):.1f}x, min {np.min(sp):.1f}x"
            )
            if abs(m1) > args.tolerance or abs(m2) > args.tolerance:
                status = 1
    print(f"\nrun directories: {out}")
    return status


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: the full loop (emulator process <-> station over loopback UDP) with many vehicles.

500 emulated vehicles are split over 2 MAVLink networks (sysids are 8-bit), each its own UDP
link; the station runs discovery, audit, launch and the PhiIREMAN loop. Reports the control
tick rate sustained (ticks per wall second), the achieved speed-up and the CPU of both sides.

    .venv/bin/python bench/bench_fly_loop.py --vehicles 500 --duration-s 30 --speedup 1
"""

from __future__ import annotations

import argparse
import json
import tempfile

import numpy as np

from mission.runners import FlyOptions, fly_emulated
from mission.schema import paper_mission
import dataclasses


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, default=500)
    ap.add_argument("--duration-s", type=float, default=30.0)
    ap.add_argument("--speedup", type=float, default=1.0)
    ap.add_argument("--personality", default="ardupilot")
    args = ap.parse_args()
    m = paper_mission("XL", 0.0, seed=0)
    emu = dataclasses.replace(m.vehicles.emulated, count=args.vehicles)
    m = dataclasses.replace(
        m,
        vehicles=dataclasses.replace(m.vehicles, emulated=emu),
        planner=dataclasses.replace(m.planner, info="central"),
    )
    with tempfile.TemporaryDirectory() as out:
        r = fly_emulated(
            m,
            FlyOptions(
                speedup=args.speedup,
                duration_s=args.duration_s,
                out_dir=out,
                personality=args.personality,
                wave_size=100,
                end_wait=False,
                override_audit=True,
            ),
        )
        s = r.summary
        recs = r.operator.records
        t = np.array([x.t_s for x in recs])
        period = np.diff(t) if len(t) > 1 else np.array([np.nan])
        print(
            json.dumps(
                {
                    "vehicles": args.vehicles,
                    "networks": len(s["links"]),
                    "speedup": args.speedup,
                    "ticks": len(recs),
                    "mission_s": s["mission_s_flown"],
                    "wall_s": round(s["wall_s"], 1),
                    "speedup_achieved": round(s["speedup_achieved"], 2),
                    "tick_period_p50_s": round(float(np.median(period)), 3),
                    "tick_period_p95_s": round(float(np.percentile(period, 95)), 3),
                    "ticks_per_wall_s": round(len(recs) / max(1e-9, s["wall_s"]), 2),
                    "planned_last": recs[-1].planned if recs else 0,
                    "station_cpu_s": round(s["station_cpu_s"], 1),
                    "emulator_cpu_s": round(s["emulator"]["cpu_s"], 1),
                    "frames_in": sum(l["frames_in"] for l in s["links"]),
                }
            )
        )


if __name__ == "__main__":
    main()

"""Benchmark: does serving the live view slow the station's control loop?

The same 500-vehicle emulated flight (emulator process <-> station over loopback UDP, as
bench_fly_loop.py) is flown without and with ``--serve``; with it, a client reads the page's
Server-Sent Events stream the whole time (every frame built, encoded and sent). Reported: the
control tick period in wall seconds (median and mean over the run phase, from the wall time at
which each tick's record appeared) for both, and their ratio (goal: within 5 %). Runs alternate
(off, on, off, on, ...) so that a shared machine's drift hits both alike.

    nice .venv/bin/python bench/bench_serve.py --vehicles 500 --duration-s 40 --speedup 1 --pairs 2
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from mission.flight.runners import FlyOptions, fly_emulated
from mission.view.live import attach
from mission.format.schema import paper_mission


_READER = r"""
import sys, urllib.request
frames = nbytes = 0
try:
    with urllib.request.urlopen(sys.argv[1] + "api/stream", timeout=30) as r:
        for line in r:
            if line.startswith(b"data: "):
                frames += 1
                nbytes += len(line)
                print(frames, nbytes, flush=True)
except Exception:
    pass
"""


def _sse_reader(info: dict, stop: threading.Event, stats: dict) -> None:
    """The page's client in its own process (as a browser is), counting frames and bytes."""
    while "url" not in info and not stop.is_set():
        time.sleep(0.05)
    if stop.is_set():
        return
    proc = subprocess.Popen(
        [sys.executable, "-c", _READER, info["url"]], stdout=subprocess.PIPE, text=True
    )
    for line in proc.stdout:
        stats["frames"], stats["bytes"] = (int(x) for x in line.split())
        if stop.is_set():
            break
    proc.terminate()
    proc.wait(10)


def one_run(mission, args, serve: bool) -> dict:
    ticks: list[float] = []
    info: dict = {}
    stop = threading.Event()
    stats = {"frames": 0, "bytes": 0}

    def hook(op, world):
        if len(op.records) > len(ticks):
            ticks.extend([time.monotonic()] * (len(op.records) - len(ticks)))

    reader = None
    if serve:
        reader = threading.Thread(target=_sse_reader, args=(info, stop, stats), daemon=True)
        reader.start()
    with tempfile.TemporaryDirectory() as out:
        r = fly_emulated(
            mission,
            FlyOptions(
                speedup=args.speedup,
                duration_s=args.duration_s,
                out_dir=out,
                wave_size=100,
                end_wait=False,
                override_audit=True,
                on_operator=hook,
                serve="127.0.0.1:0" if serve else None,
                attach_view=attach,
                on_live=info.update,
            ),
        )
    stop.set()
    if reader is not None:
        reader.join(30)
    d = np.diff(np.array(ticks[2:]))  # the first ticks include the launch settling
    live = info.get("live")
    return {
        "period_median_s": float(np.median(d)),
        "period_mean_s": float(np.mean(d)),
        "ticks": len(ticks),
        "frames": stats["frames"],
        "mb": stats["bytes"] / 1e6,
        "frame_cpu_ms": (1e3 * live.frame_cpu_s / max(1, live.frames_built)) if live else None,
        "speedup_achieved": r.summary["speedup_achieved"],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, default=500)
    ap.add_argument("--duration-s", type=float, default=40.0)
    ap.add_argument("--speedup", type=float, default=1.0)
    ap.add_argument("--pairs", type=int, default=2)
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # per-vehicle warnings of 500 vehicles are not the point here
    m = paper_mission("XL", 0.0, seed=0)
    emu = dataclasses.replace(m.vehicles.emulated, count=args.vehicles)
    m = dataclasses.replace(
        m,
        vehicles=dataclasses.replace(m.vehicles, emulated=emu),
        planner=dataclasses.replace(m.planner, info="central"),
    )
    off, on = [], []
    for k in range(args.pairs):
        for serve, bucket in ((False, off), (True, on)):
            res = one_run(m, args, serve)
            bucket.append(res)
            print(
                f"pair {k + 1} {'serve' if serve else 'plain'}: tick period median "
                f"{res['period_median_s'] * 1e3:.1f} ms, mean {res['period_mean_s'] * 1e3:.1f} ms, "
                f"{res['ticks']} ticks"
                + (
                    f"; {res['frames']} frames to the client "
                    f"({res['mb']:.1f} MB), {res['frame_cpu_ms']:.1f} ms "
                    "CPU per frame"
                    if serve
                    else ""
                ),
                flush=True,
            )
    a = float(np.mean([r["period_mean_s"] for r in off]))
    b = float(np.mean([r["period_mean_s"] for r in on]))
    print(
        f"\n{args.vehicles} vehicles, speed-up {args.speedup}: control tick period "
        f"without --serve {a * 1e3:.1f} ms, with --serve (+ an SSE client) {b * 1e3:.1f} ms, "
        f"ratio {b / a:.3f} ({'within' if b / a <= 1.05 else 'NOT within'} 5 %); per pair "
        + ", ".join(f"{y['period_mean_s'] / x['period_mean_s']:.3f}" for x, y in zip(off, on))
    )


if __name__ == "__main__":
    main()

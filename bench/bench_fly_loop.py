"""Benchmark: the full loop (emulator process <-> station over loopback UDP) with many vehicles.

500 emulated vehicles are split over 2 MAVLink networks (sysids are 8-bit), each its own UDP
link; the station runs discovery, audit, launch and the PhiIREMAN loop (central information).
Reports, over the run phase only (first control tick to last):

* ``ticks_per_wall_s``: control ticks per wall second (the control period is 1 s of vehicle
  time, so at ``--speedup 10`` the goal is 10);
* ``tick_latency_ms`` p50 / p95 / max: wall time of the station's poll that ran a control tick
  (fleet snapshot, the planner's tick, setpoints queued), plus the sending of what it queued;
* ``tick_period_s`` p50 / p95: vehicle seconds between ticks (1.0 when the station keeps up);
* CPU seconds and share of one core of the station process and of the emulator process over
  the same window (the emulator's from /proc), and the load average.

``--baseline DIR`` (or ``--commit REV``, a ``git archive`` into a temp dir) runs the same flight
with that code tree in a child process first, then this tree, and prints the ratios. The
emulator process is spawned, so each tree's emulator runs its own code.

    .venv/bin/python bench/bench_fly_loop.py --vehicles 500 --duration-s 40 --speedup 10
    .venv/bin/python bench/bench_fly_loop.py --speedup 10 --commit 64a57d8 --repeat 2
    .venv/bin/python bench/bench_fly_loop.py --speedup 10 --profile /tmp/loop   # cProfile both sides
    .venv/bin/python bench/bench_fly_loop.py --vehicles 500 --extras-compare --repeat 2

``--tak`` publishes the mesh on TAK (to a UDP sink on loopback, one picture a second) and
``--serve`` serves the live page with one client reading its frame stream (``/api/stream``, as
the browser does). ``--extras-compare`` runs the flight without them and with both, alternated
``--repeat`` times in child processes, and prints the ratios (the cost of TAK and the page).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np


def _proc_cpu_s(pid: int) -> float:
    """utime + stime of process ``pid`` (Linux /proc), seconds."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def _profiled_emulator_main(*args) -> None:  # runs in the spawned emulator process
    import cProfile

    from mission.flight import emulator_host

    prof = cProfile.Profile()
    prof.enable()
    try:
        emulator_host._emulator_process_main(*args)
    finally:
        prof.disable()
        prof.dump_stats(os.environ["BENCH_FLY_LOOP_PROFILE"] + ".emulator.prof")


def run_once(args) -> dict:
    import multiprocessing as mp

    import mission.flight.emulator_host as emulator_host
    from gcs.operations import Operator
    from mission.flight.runners import FlyOptions, fly_emulated
    from mission.format.schema import paper_mission

    logging.getLogger().setLevel(logging.ERROR)
    ticks: list[tuple[float, float, float, float, float]] = []  # wall, latency, t_s, cpu, emu cpu
    emu_pid: list[int] = []
    orig_poll = Operator.poll

    run_prof = None
    if args.profile_run:
        import cProfile

        run_prof = cProfile.Profile()

    def timed_poll(self, now_s):
        w0 = time.perf_counter()
        rec = orig_poll(self, now_s)
        if rec is not None:
            w1 = time.perf_counter()
            if run_prof is not None and not ticks:
                run_prof.enable()
            if not emu_pid:
                kids = [p.pid for p in mp.active_children() if p.name == "phireman-emulator"]
                emu_pid.extend(kids[:1] or [0])
            ticks.append((w1, w1 - w0, now_s, time.process_time(), _proc_cpu_s(emu_pid[0])))
        return rec

    Operator.poll = timed_poll  # type: ignore[method-assign]
    if args.profile:
        os.environ["BENCH_FLY_LOOP_PROFILE"] = args.profile
        emulator_host._emulator_process_main = _profiled_emulator_main  # type: ignore[assignment]

    m = paper_mission("XL", 0.0, seed=0)
    emu = dataclasses.replace(m.vehicles.emulated, count=args.vehicles)
    m = dataclasses.replace(
        m,
        vehicles=dataclasses.replace(m.vehicles, emulated=emu),
        planner=dataclasses.replace(m.planner, info="central"),
    )
    extras: dict = {}
    extras_out: dict = {}
    stop = threading.Event()
    sink_bytes = [0]
    if args.tak:
        import socket

        from mission.view.tak import attach as attach_tak

        sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sink.bind(("127.0.0.1", 0))
        sink.settimeout(0.5)

        def drain() -> None:
            while not stop.is_set():
                try:
                    sink_bytes[0] += len(sink.recv(65536))
                except OSError:
                    pass

        threading.Thread(target=drain, daemon=True).start()
        extras.update(
            tak=(f"udp+wo://127.0.0.1:{sink.getsockname()[1]}",),
            attach_tak=attach_tak,
            on_tak=lambda info: extras_out.update(tak=info),
        )
    stream_bytes = [0]
    if args.serve:
        import urllib.request

        from mission.view.live import attach as attach_view

        def reader(url: str) -> None:  # the browser: the page's frame stream
            try:
                with urllib.request.urlopen(url + "api/stream", timeout=30) as r:
                    while not stop.is_set():
                        line = r.readline()
                        if not line:
                            break
                        stream_bytes[0] += len(line)
            except OSError:
                pass

        def on_live(info: dict) -> None:
            if info.get("url"):
                threading.Thread(target=reader, args=(info["url"],), daemon=True).start()

        extras.update(serve="127.0.0.1:0", attach_view=attach_view, on_live=on_live)
    load0 = os.getloadavg()
    prof = None
    if args.profile:
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
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
                emulator_in_process=args.in_process,
                **extras,
            ),
        )
    stop.set()
    if run_prof is not None:
        run_prof.disable()
        run_prof.dump_stats(args.profile_run)
    if prof is not None:
        prof.disable()
        prof.dump_stats(args.profile + ".station.prof")
    s = r.summary
    recs = r.operator.records
    arr = np.array(ticks) if ticks else np.full((1, 5), np.nan)
    # The run phase: from the second tick (the first one waits on launch) to the last.
    run = arr[1:] if len(arr) > 2 else arr
    wall = float(run[-1, 0] - run[0, 0]) if len(run) > 1 else float("nan")
    n_int = max(1, len(run) - 1)
    period = np.diff(arr[:, 2]) if len(arr) > 1 else np.array([np.nan])
    lat_ms = arr[:, 1] * 1e3
    station_cpu = float(run[-1, 3] - run[0, 3])
    emu_cpu = float(run[-1, 4] - run[0, 4])
    return {
        "vehicles": args.vehicles,
        "networks": len(s["links"]),
        "speedup": args.speedup,
        "ticks": len(recs),
        "ticks_per_wall_s": round(n_int / wall, 2),
        "tick_latency_ms": {
            "p50": round(float(np.median(lat_ms)), 1),
            "p95": round(float(np.percentile(lat_ms, 95)), 1),
            "max": round(float(lat_ms.max()), 1),
        },
        "tick_period_s": {
            "p50": round(float(np.median(period)), 3),
            "p95": round(float(np.percentile(period, 95)), 3),
        },
        "run_wall_s": round(wall, 2),
        "station_cpu_share": round(station_cpu / wall, 2),
        "emulator_cpu_share": round(emu_cpu / wall, 2),
        "station_cpu_s_per_tick": round(station_cpu / n_int, 3),
        "emulator_cpu_s_per_tick": round(emu_cpu / n_int, 3),
        "planned_last": recs[-1].planned if recs else 0,
        "whole_flight_wall_s": round(s["wall_s"], 1),
        "station_cpu_s_total": round(s["station_cpu_s"], 1),
        "emulator_cpu_s_total": round(s["emulator"]["cpu_s"], 1),
        "frames_in": sum(x["frames_in"] for x in s["links"]),
        # The emulator's paced clock over the whole flight: iterations that moved simulated
        # time, and how often the station's acknowledgement (lock-step) or the per-iteration
        # step limit held it back (mavedge.clock.PacedClock.stats).
        "pacing": s["emulator"].get("pacing", {}),
        "loadavg_before_after": [round(load0[0], 2), round(os.getloadavg()[0], 2)],
        "tak_bytes_received": sink_bytes[0],
        "tak_published": extras_out.get("tak", {}).get("published", {}),
        "page_stream_bytes": stream_bytes[0],
    }


def compare_extras(args, here: str) -> None:
    """The same flight without and with TAK publishing and the live page (alternated), and the
    ratios with / without of the station's CPU per tick and the tick latency."""
    argv = [
        f"--vehicles={args.vehicles}",
        f"--duration-s={args.duration_s}",
        f"--speedup={args.speedup}",
        f"--personality={args.personality}",
    ]
    res: dict[str, list[dict]] = {"plain": [], "tak+page": []}
    for _ in range(args.repeat):
        for name, extra in (("plain", []), ("tak+page", ["--tak", "--serve"])):
            r = _child(here, argv + extra)
            res[name].append(r)
            print(name, json.dumps(r), flush=True)

    def med(name: str, key: str, sub: str | None = None) -> float:
        return float(np.median([x[key][sub] if sub else x[key] for x in res[name]]))

    ratios = {
        "station_cpu_s_per_tick": med("tak+page", "station_cpu_s_per_tick")
        / med("plain", "station_cpu_s_per_tick"),
        "tick_latency_p50": med("tak+page", "tick_latency_ms", "p50")
        / med("plain", "tick_latency_ms", "p50"),
        "tick_latency_p95": med("tak+page", "tick_latency_ms", "p95")
        / med("plain", "tick_latency_ms", "p95"),
        "ticks_per_wall_s": med("tak+page", "ticks_per_wall_s") / med("plain", "ticks_per_wall_s"),
    }
    print(json.dumps({"with_over_without": {k: round(v, 3) for k, v in ratios.items()}}))


def _child(tree: str, argv: list[str]) -> dict:
    env = {**os.environ, "PYTHONPATH": tree}
    out = subprocess.run(
        [sys.executable, os.path.abspath(__file__), *argv, "--single"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tree,
    )
    if out.returncode:
        sys.exit(f"{tree}: {out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--vehicles", type=int, default=500)
    ap.add_argument("--duration-s", type=float, default=40.0)
    ap.add_argument("--speedup", type=float, default=10.0)
    ap.add_argument("--personality", default="ardupilot")
    ap.add_argument("--profile", help="write PREFIX.station.prof and PREFIX.emulator.prof")
    ap.add_argument(
        "--profile-run", help="cProfile the station process from the first tick to the end"
    )
    ap.add_argument("--in-process", action="store_true", help="the emulator on the station's loop")
    ap.add_argument("--baseline", help="root of the previous code tree")
    ap.add_argument("--commit", help="git archive this revision as the baseline")
    ap.add_argument("--repeat", type=int, default=1, help="runs per tree, alternated")
    ap.add_argument("--tak", action="store_true", help="publish the mesh on TAK (a UDP sink)")
    ap.add_argument("--serve", action="store_true", help="serve the live page, one reader")
    ap.add_argument(
        "--extras-compare",
        action="store_true",
        help="without / with --tak --serve, alternated, and the ratios",
    )
    ap.add_argument("--single", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if args.extras_compare:
        compare_extras(args, here)
        return
    if args.single or not (args.baseline or args.commit):
        for _ in range(1 if args.single else args.repeat):
            print(json.dumps(run_once(args)), flush=True)
        return
    tmp = None
    base = args.baseline
    if base is None:
        tmp = tempfile.mkdtemp(prefix="bench_fly_loop_")
        subprocess.run(
            f"git -C {here} archive {args.commit} | tar -x -C {tmp}", shell=True, check=True
        )
        base = tmp
    argv = [
        f"--vehicles={args.vehicles}",
        f"--duration-s={args.duration_s}",
        f"--speedup={args.speedup}",
        f"--personality={args.personality}",
    ]
    try:
        res: dict[str, list[dict]] = {"old": [], "new": []}
        for _ in range(args.repeat):
            for name, tree in (("old", base), ("new", here)):
                r = _child(tree, argv)
                res[name].append(r)
                print(name, json.dumps(r), flush=True)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)

    def med(name: str, key: str, sub: str | None = None) -> float:
        v = [x[key][sub] if sub else x[key] for x in res[name]]
        return float(np.median(v))

    print(
        json.dumps(
            {
                "old_over_new": {
                    "ticks_per_wall_s (new/old)": round(
                        med("new", "ticks_per_wall_s") / med("old", "ticks_per_wall_s"), 2
                    ),
                    "tick_latency_p50": round(
                        med("old", "tick_latency_ms", "p50") / med("new", "tick_latency_ms", "p50"),
                        2,
                    ),
                    "tick_latency_p95": round(
                        med("old", "tick_latency_ms", "p95") / med("new", "tick_latency_ms", "p95"),
                        2,
                    ),
                    "station_cpu_s_per_tick": round(
                        med("old", "station_cpu_s_per_tick") / med("new", "station_cpu_s_per_tick"),
                        2,
                    ),
                    "emulator_cpu_s_per_tick": round(
                        med("old", "emulator_cpu_s_per_tick")
                        / med("new", "emulator_cpu_s_per_tick"),
                        2,
                    ),
                }
            }
        )
    )


if __name__ == "__main__":
    main()

"""Issue 25: the cost of endurance through the station — ``wildfire_2h`` flown on the emulator
against the 200-s ``wildfire`` flown in the same run.

Flies the shipped ``wildfire`` mission (200 s, endless batteries) and then ``wildfire_2h`` (two
hours, batteries, relay rotation, ``--apply-failsafes``) through the ground station on the
emulator (loopback UDP, the emulator in its own process), each at ``--speedup``, and prints for
each flight: the simulated seconds, the wall seconds, the speed-up achieved (simulated / wall
over the run phase, as ``phireman fly`` reports it), the CPU seconds of the station process and
of the emulator process (resource.getrusage and the emulator's own count), CPU per simulated
hour, and the load average before and after. The machine may be shared: CPU time is the figure
that travels; the ratio of the two flights' CPU per simulated second says what the batteries and
the rotation cost per second flown.

The goal is the 2-hour mission at 50x or more (under 2.5 minutes of wall time): with two free
cores, that needs each process under 144 CPU seconds for the two hours.

    .venv/bin/python bench/bench_endurance_flight.py
    .venv/bin/python bench/bench_endurance_flight.py --duration-s 1200 --personality px4
    .venv/bin/python bench/bench_endurance_flight.py --duration-s 600 --profile /tmp/endfly
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import resource
import tempfile
import time


def _profiled_emulator_main(*args) -> None:  # runs in the spawned emulator process
    import cProfile

    from mission.flight import emulator_host

    prof = cProfile.Profile()
    prof.enable()
    try:
        emulator_host._emulator_process_main(*args)
    finally:
        prof.disable()
        prof.dump_stats(os.environ["BENCH_ENDURANCE_FLIGHT_PROFILE"] + ".emulator.prof")


def fly_once(name: str, duration_s: float | None, args, profile: str | None) -> dict:
    """Fly the shipped mission ``name``; returns the figures of one flight."""
    import mission.flight.emulator_host as emulator_host
    from mission.flight.runners import FlyOptions, fly_emulated
    from mission.format.examples import example_path
    from mission.format.load import load_mission

    m = load_mission(example_path(name))
    if args.seed is not None:
        m = dataclasses.replace(m, run=dataclasses.replace(m.run, seed=args.seed))
    prof = None
    if profile:
        import cProfile

        os.environ["BENCH_ENDURANCE_FLIGHT_PROFILE"] = profile
        emulator_host._emulator_process_main = _profiled_emulator_main  # type: ignore[assignment]
        prof = cProfile.Profile()
    load0 = os.getloadavg()[0]
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    w0 = time.perf_counter()
    if prof is not None:
        prof.enable()
    with tempfile.TemporaryDirectory() as out:
        r = fly_emulated(
            m,
            FlyOptions(
                speedup=args.speedup,
                duration_s=duration_s,
                out_dir=out,
                personality=args.personality,
                apply_failsafes=True,
                end_wait=False,
            ),
        )
    if prof is not None:
        prof.disable()
        prof.dump_stats(profile + ".station.prof")
    wall = time.perf_counter() - w0
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    s = r.summary
    station_cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    emu_cpu = float(s["emulator"]["cpu_s"])
    flown = float(s.get("mission_s_flown", s["duration_s"]))
    end = s.get("endurance") or {}
    return {
        "mission": name,
        "personality": args.personality,
        "simulated_s": round(flown, 1),
        "wall_s": round(wall, 1),
        "speedup_achieved": round(float(s["speedup_achieved"]), 1),
        "station_cpu_s": round(station_cpu, 1),
        "emulator_cpu_s": round(emu_cpu, 1),
        "cpu_s_per_sim_hour": {
            "station": round(3600.0 * station_cpu / flown, 1),
            "emulator": round(3600.0 * emu_cpu / flown, 1),
        },
        "tu1_station": round(100 * s["final"]["tu1_so_far"], 2),
        "rotations": end.get("rotations"),
        "no_spare": end.get("no_spare"),
        "loadavg_before_after": [round(load0, 2), round(os.getloadavg()[0], 2)],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speedup", type=float, default=50.0)
    ap.add_argument("--duration-s", type=float, default=None, help="wildfire_2h's length")
    ap.add_argument("--personality", choices=["ardupilot", "px4"], default="ardupilot")
    ap.add_argument("--seed", type=int, default=None, help="both flights' seed (the missions')")
    ap.add_argument(
        "--profile", help="cProfile wildfire_2h: PREFIX.station.prof, PREFIX.emulator.prof"
    )
    ap.add_argument("--skip-short", action="store_true", help="fly only wildfire_2h")
    args = ap.parse_args()
    logging.getLogger().setLevel(logging.ERROR)
    rows = []
    if not args.skip_short:
        rows.append(fly_once("wildfire", None, args, None))
        print(json.dumps(rows[-1]), flush=True)
    rows.append(fly_once("wildfire_2h", args.duration_s, args, args.profile))
    print(json.dumps(rows[-1]), flush=True)
    if len(rows) == 2:
        a, b = rows

        def per_s(r: dict) -> float:
            return (r["station_cpu_s"] + r["emulator_cpu_s"]) / r["simulated_s"]

        print(
            f"wildfire_2h: {b['simulated_s']:.0f} s flown in {b['wall_s']:.0f} s wall "
            f"({b['speedup_achieved']:.1f}x achieved, {args.speedup:.0f}x asked); CPU per "
            f"simulated second {per_s(b):.4f} s against {per_s(a):.4f} s for the 200-s wildfire "
            f"({per_s(b) / per_s(a):.2f}x); load average {b['loadavg_before_after']}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

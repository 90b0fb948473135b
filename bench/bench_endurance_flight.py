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

``--record FILE`` keeps every call the flight made on the emulator (the station's datagrams as
they arrived, the timer ticks, the host's start / poll / end) on the emulator's clock;
``--replay FILE`` flies nothing and feeds them to a fresh emulator of the current code, without
sockets, printing its CPU seconds and a fingerprint of all it sent and logged (equal
fingerprints: the same behaviour; ``--no-kernels``: its NumPy references instead of the compiled
kernels). Record with one tree, replay with two (``PYTHONPATH=<tree>``), and the emulator's cost
of one and the same flight is compared without the station's or the machine's pace in it.

    .venv/bin/python bench/bench_endurance_flight.py --skip-short --record /tmp/wildfire_2h.pkl
    .venv/bin/python bench/bench_endurance_flight.py --replay /tmp/wildfire_2h.pkl

Measured 2026-12-06 on the shared 2-core machine (load averages 3-9), ArduPilot, the 2 hours:
at b1c1dfe the emulator took 118.1 s of CPU (station 100.8 s); with the compiled kernels
(vehicle_emu/_kernels.py) 60.6 s (station 74.4 s); PX4 120.6 s -> 88.8 s. The replay of one
recorded ArduPilot flight: see docs/results/endurance.md ("The emulator's CPU, halved").
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


def _recording_emulator_main(conn, mission, seed, personality, speedup, sim, ack, params) -> None:
    """The emulator process, recording every call the adapter and the host make on its swarm
    and world (``--record``): the inputs :func:`replay` feeds a fresh emulator."""
    import pickle

    from mission.flight import emulator_host

    build = emulator_host.build_world
    calls: list = []
    head: dict = {"mission": mission, "seed": seed, "personality": personality}
    head.update(speedup=speedup, params=params)

    def recording_build_world(mission, seed, personality, clock, params):
        world = build(mission, seed, personality, clock, params)
        head["unix_time_at_zero_s"] = clock.unix_time_at_zero_s
        sw = world.swarm
        rx, tick, out = sw.receive_datagram, sw.handle_timer, sw.datagrams_to_send
        poll, start, stop, kill = world.poll, world.start, world.stop_attrition, sw.kill
        report = world.report
        starting = [False]

        def w_rx(endpoint, data, addr, now_s):
            calls.append(("rx", endpoint, bytes(data), addr, now_s))
            return rx(endpoint, data, addr, now_s)

        def w_tick(now_s):
            calls.append(("tick", now_s))
            return tick(now_s)

        def w_out(now_s):
            calls.append(("out", now_s))
            return out(now_s)

        def w_poll(now_s):
            if not starting[0]:
                calls.append(("poll", now_s))
            return poll(now_s)

        def w_start(t0_s):
            calls.append(("start", t0_s))
            starting[0] = True
            try:
                return start(t0_s)
            finally:
                starting[0] = False

        def w_stop():
            calls.append(("stop",))
            return stop()

        def w_kill(index, now_s, cause="scripted"):
            if cause == "injected":  # the host's; the swarm's own kills replay by themselves
                calls.append(("kill", index, now_s))
            return kill(index, now_s, cause)

        def w_report(duration_s):
            calls.append(("report", duration_s))
            return report(duration_s)

        sw.receive_datagram, sw.handle_timer, sw.datagrams_to_send = w_rx, w_tick, w_out
        world.poll, world.start, world.stop_attrition, sw.kill = w_poll, w_start, w_stop, w_kill
        world.report = w_report
        return world

    emulator_host.build_world = recording_build_world
    try:
        emulator_host._emulator_process_main(
            conn, mission, seed, personality, speedup, sim, ack, params
        )
    finally:
        with open(os.environ["BENCH_ENDURANCE_FLIGHT_RECORD"], "wb") as f:
            pickle.dump((head, calls), f, protocol=pickle.HIGHEST_PROTOCOL)


class _ReplayClock:
    def __init__(self, speedup: float, unix_time_at_zero_s: float) -> None:
        self.speedup = speedup
        self.unix_time_at_zero_s = unix_time_at_zero_s


def replay(path: str) -> dict:
    """Feed a fresh emulator the calls a flight made on it (``--record``), on their recorded
    clock, without sockets: the emulator's CPU seconds for that flight's work, and a
    fingerprint of everything it sent and reported (two code trees that behave the same print
    the same one)."""
    import hashlib
    import pickle

    from mission.flight.emulator_host import build_world

    with open(path, "rb") as f:
        head, calls = pickle.load(f)
    clock = _ReplayClock(head["speedup"], head["unix_time_at_zero_s"])
    world = build_world(head["mission"], head["seed"], head["personality"], clock, head["params"])
    sw = world.swarm
    digest = hashlib.sha256()
    n_out = n_events = 0
    report = None
    t0 = time.process_time()
    for call in calls:
        kind = call[0]
        if kind == "rx":
            sw.receive_datagram(*call[1:])
        elif kind == "tick":
            sw.handle_timer(call[1])
        elif kind == "out":
            for endpoint, data, addr in sw.datagrams_to_send(call[1]):
                digest.update(b"%d|%r|" % (endpoint, addr))
                digest.update(data)
                n_out += 1
            ev = sw.next_event()
            while ev is not None:
                digest.update(repr(ev).encode())
                n_events += 1
                ev = sw.next_event()
        elif kind == "poll":
            world.poll(call[1])
        elif kind == "start":
            world.start(call[1])
        elif kind == "stop":
            world.stop_attrition()
        elif kind == "kill":
            sw.kill(call[1], call[2], "injected")
        elif kind == "report":
            report = world.report(call[1])
    cpu = time.process_time() - t0
    if report is not None:
        digest.update(repr(report.get("tu1")).encode() + repr(report.get("tu2")).encode())
    return {
        "replay": path,
        "calls": len(calls),
        "emulator_cpu_s": round(cpu, 2),
        "datagrams_out": n_out,
        "events": n_events,
        "fingerprint": digest.hexdigest()[:16],
    }


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
    if args.record and name == "wildfire_2h":
        os.environ["BENCH_ENDURANCE_FLIGHT_RECORD"] = args.record
        emulator_host._emulator_process_main = _recording_emulator_main  # type: ignore[assignment]
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
        # The lock-step's own account (mavedge.clock.PacedClock.stats): simulated seconds the
        # emulator held back for the station's acknowledgement, or for its own step limit.
        "pacing": {
            k: round(float(v), 1)
            for k, v in (s["emulator"].get("pacing") or {}).items()
            if k.startswith("held_") or k.startswith("capped_")
        },
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
    ap.add_argument(
        "--record", metavar="FILE", help="record the emulator's inputs of wildfire_2h to FILE"
    )
    ap.add_argument(
        "--replay",
        metavar="FILE",
        help="fly nothing: replay a --record FILE into a fresh emulator, print its CPU seconds",
    )
    ap.add_argument(
        "--no-kernels",
        action="store_true",
        help="with --replay: the emulator's NumPy references instead of its compiled kernels",
    )
    args = ap.parse_args()
    logging.getLogger().setLevel(logging.ERROR)
    if args.replay:
        if args.no_kernels:
            import vehicle_emu._kernels

            vehicle_emu._kernels.ENABLED = False
        print(json.dumps(replay(args.replay)), flush=True)
        return 0
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

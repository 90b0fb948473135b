"""Benchmark: N emulated vehicles in one process, 10 Hz position telemetry, real time, UDP.

Reports the emulator's CPU share of one core, messages and datagrams per second, and whether
it keeps up with real time (tick lateness). The GCS side is a separate sink process that only
counts datagrams, so its CPU is not charged to the emulator.

    .venv/bin/python bench/bench_emulator.py --vehicles 500 --duration-s 10
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import socket
import time

import numpy as np

from vehicle_emu.clock import RealClock
from vehicle_emu.link import M_GLOBAL_POSITION_INT, M_LOCAL_POSITION_NED, M_SYS_STATUS
from vehicle_emu.radio import RadioConfig
from vehicle_emu.swarm import Swarm
from vehicle_emu.udp import EmulatorServer


def _sink(port_q: mp.Queue, result_q: mp.Queue, duration_s: float) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    sock.bind(("127.0.0.1", 0))
    port_q.put(sock.getsockname()[1])
    sock.settimeout(0.5)
    n = nbytes = 0
    end = time.monotonic() + duration_s + 5
    started = None
    while time.monotonic() < end:
        try:
            data = sock.recv(65535)
        except socket.timeout:
            if started is not None:
                break
            continue
        started = started or time.monotonic()
        n += 1
        nbytes += len(data)
    result_q.put((n, nbytes))


async def _bench(args) -> dict:
    port_q, result_q = mp.Queue(), mp.Queue()
    sink = mp.Process(target=_sink, args=(port_q, result_q, args.duration_s), daemon=True)
    sink.start()
    sink_port = port_q.get(timeout=10)
    rates = {M_GLOBAL_POSITION_INT: args.rate_hz, M_SYS_STATUS: 1.0}
    if args.local:
        rates[M_LOCAL_POSITION_NED] = args.rate_hz
    rng = np.random.default_rng(0)
    swarm = Swarm(args.vehicles, personality=args.personality, mux=not args.per_vehicle_ports,
                  spawn_spacing_m=30.0, radio=RadioConfig(radio_range_m=args.radio_range_m),
                  gcs_addrs=[("127.0.0.1", sink_port)], stream_rates_hz=rates, rng=rng)
    # Everyone airborne and flying to random points: physics and radio do real work.
    ph = swarm.physics
    ph.armed[:] = True
    for core in swarm.cores:
        core.armed = True
    targets = np.column_stack([rng.uniform(-400, 400, (swarm.n, 2)), np.full(swarm.n, -20.0)])
    ph.target_pos_ned_m[:] = targets
    ph.max_speed_h_m_s[:] = 5.0
    clock = RealClock(1.0)
    server = EmulatorServer(swarm, clock, "127.0.0.1", 0)
    await server.start()
    late = []
    orig = server._on_timer

    def timed():
        late.append(clock.now() - swarm.next_timer_s())
        orig()
    server._on_timer = timed
    msgs0 = swarm.core_stats()["messages_out"]
    cpu0, wall0 = time.process_time(), time.monotonic()
    await asyncio.sleep(args.duration_s)
    cpu1, wall1 = time.process_time(), time.monotonic()
    msgs1 = swarm.core_stats()["messages_out"]
    server.close()
    n_recv, n_bytes = result_q.get(timeout=30)
    sink.join(5)
    wall = wall1 - wall0
    late_arr = np.asarray(late[5:]) if len(late) > 5 else np.asarray(late)
    return {
        "vehicles": swarm.n, "networks": swarm.n_networks, "endpoints": swarm.n_endpoints,
        "rate_hz": args.rate_hz, "duration_s": round(wall, 2),
        "cpu_share_of_one_core": round((cpu1 - cpu0) / wall, 3),
        "messages_per_s": round((msgs1 - msgs0) / wall),
        "datagrams_sent_per_s": round(swarm.stats["datagrams_out"] / wall),
        "datagrams_received_by_sink": n_recv, "bytes_received_by_sink": n_bytes,
        "ticks_per_s": round(swarm.stats["ticks"] / wall, 1),
        "tick_lateness_p50_ms": round(float(np.median(late_arr)) * 1e3, 2),
        "tick_lateness_p99_ms": round(float(np.quantile(late_arr, 0.99)) * 1e3, 2),
        "active": int(swarm.active.sum()),
        "keeps_up": bool(np.quantile(late_arr, 0.99) < 0.05 and (cpu1 - cpu0) / wall < 1.0),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--vehicles", type=int, default=500)
    p.add_argument("--duration-s", type=float, default=10.0)
    p.add_argument("--rate-hz", type=float, default=10.0)
    p.add_argument("--local", action="store_true", help="also LOCAL_POSITION_NED at --rate-hz")
    p.add_argument("--personality", default="ardupilot")
    p.add_argument("--per-vehicle-ports", action="store_true", help="SITL-style, one socket each")
    p.add_argument("--radio-range-m", type=float, default=100.0)
    args = p.parse_args()
    print(json.dumps(asyncio.run(_bench(args)), indent=2))


if __name__ == "__main__":
    main()

"""What the live page's health streams cost the emulator: 500 emulated ArduPilot vehicles,
the station's stream rates without and with ``--serve`` (GPS_RAW_INT 1 Hz, SYS_STATUS 0.2 ->
1 Hz, EKF_STATUS_REPORT 1 Hz on top of GLOBAL_POSITION_INT 2 Hz), batched telemetry; CPU seconds
per simulated second of ``Swarm.handle_timer`` + ``datagrams_to_send``, alternated runs.

    nice .venv/bin/python bench/bench_health_streams.py
"""

from __future__ import annotations

import time

import numpy as np

from mavedge import mavlink
from vehicle_emu.swarm import Swarm

N, SIM_S, DT_S = 500, 30.0, 0.05
BASE = {
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 2.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 0.2,
}
HEALTH = {
    **BASE,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT: 1.0,
}


def run(rates: dict[int, float]) -> tuple[float, int]:
    sw = Swarm(
        N,
        personality="ardupilot",
        mux=True,
        spawn_spacing_m=25.0,
        gcs_addrs=[("gcs", 1)],
        rng=np.random.default_rng(5),
        telemetry="batch",
    )
    for c in sw.cores:
        for msg_id, hz in rates.items():
            c.set_stream_rate(msg_id, hz, 0.0)
    t0 = time.process_time()
    t = 0.0
    while t < SIM_S:
        sw.handle_timer(t)
        sw.datagrams_to_send(t)
        t += DT_S
    frames = sum(c.stats.messages_out for c in sw.cores)
    return (time.process_time() - t0) / SIM_S, frames


if __name__ == "__main__":
    res: dict[str, list[float]] = {"plain": [], "health": []}
    for _ in range(2):
        for name, rates in (("plain", BASE), ("health", HEALTH)):
            cpu, frames = run(rates)
            res[name].append(cpu)
            print(f"{name:7s}: {1000 * cpu:6.1f} ms CPU per simulated s, {frames} frames")
    p, h = np.mean(res["plain"]), np.mean(res["health"])
    print(
        f"{N} vehicles: plain {1000 * p:.1f} ms/s, with the health streams {1000 * h:.1f} ms/s "
        f"(x{h / p:.2f})"
    )

"""Benchmark: N emulated vehicles in one process, real time, UDP; telemetry built per vehicle
(the reference path) or per message type for the whole swarm (the batch path, default).

Two measurements, both implementations side by side in the same run:

* ``tick``: CPU per swarm tick (autopilot, physics, radio, telemetry, datagrams; no sockets) on
  a virtual clock, for each implementation, and the ratio reference / batch.
* ``realtime``: the swarm served over loopback UDP on the real clock for ``--duration-s``; the
  emulator's CPU share of one core, tick lateness, and the telemetry rate achieved per
  personality (frames the GCS sink counted, attributed by sender port and sysid) against PX4's /
  ArduPilot's default stream rates. The sink is a separate
  process that walks the frames of each datagram, so its CPU is not charged to the emulator.

    .venv/bin/python bench/bench_emulator.py --px4 1000 --ardupilot 1000 --duration-s 10

Without ``--px4`` / ``--ardupilot`` the older form still works (``--vehicles N --personality P``
with GLOBAL_POSITION_INT at ``--rate-hz``). ``--default-rates`` keeps each firmware's own
streams (PX4: 17.5 messages/s, ArduPilot: HEARTBEAT only, vehicle_emu.personality).

``--gcs-hb-hz`` / ``--setpoint-hz`` (tick measurement only) add a station's traffic: GCS
HEARTBEATs per network and a global position setpoint per vehicle, the vehicles in their guided
mode; ``--tick-s 0.1`` is the emulator tick at a 10x speed-up (mission/flight/emulator_host.py). The
``fingerprint`` hashes every datagram and event of the measured ticks: two code trees that
behave the same print the same one (compare with ``PYTHONPATH=<tree>``).

    PYTHONPATH=. .venv/bin/python bench/bench_emulator.py --vehicles 500 --no-realtime \
        --telemetry batch --tick-s 0.1 --gcs-hb-hz 5 --setpoint-hz 2

Measured 2026-12-02 (2 cores shared with firmware builds, load average 5.5-7, run under
``nice``; ``--duration-s 10 --ticks 100``), default rates, all vehicles flying:

==========================  ==============  ==============  ======
per personality             reference       batch           ratio
==========================  ==============  ==============  ======
500 + 500, CPU per tick     17.7 ms (0.35)  5.4 ms (0.11)   3.3
1000 + 1000, CPU per tick   43.2 ms (0.86)  11.2 ms (0.22)  3.9
==========================  ==============  ==============  ======

(in brackets: the share of one core at 20 ticks/s). Real time, 1000 + 1000, batch, 20 s:
PX4 17.5 of 17.5 messages/s per vehicle, ArduPilot 1.0 of 1.0, every frame delivered, 0.31 of
a core, tick lateness p50 2 ms / p99 113 ms (the p99 is the loaded host descheduling a niced
process; ``keeps_up`` asks for p99 < 50 ms). The reference path did not keep up there: 4.5
ticks/s, PX4 12.1 messages/s per vehicle.

2026-12-06, the compiled kernels (vehicle_emu/_kernels.py: physics with batteries, geodetic
update, hop counts, framing), ``--no-realtime --telemetry batch --tick-s 0.1 --gcs-hb-hz 5
--setpoint-hz 2 --ticks 200``, load average about 5: 50 vehicles 0.97 -> 0.52 ms per tick, 500
vehicles 4.77 -> 3.93 ms, the same fingerprints before and after.
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import json
import multiprocessing as mp
import socket
import time

import numpy as np

from vehicle_emu.clock import RealClock
from vehicle_emu.radio import RadioConfig
from vehicle_emu.swarm import Swarm
from vehicle_emu.telemetry import M_GLOBAL_POSITION_INT, M_LOCAL_POSITION_NED, M_SYS_STATUS
from vehicle_emu.udp import EmulatorServer


def _sink(port_q: mp.Queue, result_q: mp.Queue, duration_s: float) -> None:
    """Count datagrams, and frames per (sender port, sysid) by walking each datagram."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 32 << 20)
    sock.bind(("127.0.0.1", 0))
    port_q.put(sock.getsockname()[1])
    sock.settimeout(0.5)
    n = nbytes = 0
    frames: dict = {}
    end = time.monotonic() + duration_s + 5
    started = None
    last = 0.0
    while time.monotonic() < end:
        try:
            data, addr = sock.recvfrom(65535)
        except TimeoutError:
            # Done after 2.5 s of silence (ArduPilot's default is one HEARTBEAT a second, in
            # bursts: a shorter wait stopped counting after the first burst).
            if started is not None and time.monotonic() - last > 2.5:
                break
            continue
        last = time.monotonic()
        started = started or time.monotonic()
        n += 1
        nbytes += len(data)
        i, size = 0, len(data)
        while i + 10 <= size and data[i] == 0xFD:
            key = (addr[1], data[i + 5])
            frames[key] = frames.get(key, 0) + 1
            i += 12 + data[i + 1] + (13 if data[i + 2] & 1 else 0)
    result_q.put((n, nbytes, frames))


class _GcsTraffic:
    """What a station sends (``--gcs-hb-hz``, ``--setpoint-hz``): a GCS HEARTBEAT broadcast on
    every network and a SET_POSITION_TARGET_GLOBAL_INT (position, relative altitude) to every
    vehicle, frames coalesced into datagrams per network as the station does; fed to
    :meth:`Swarm.receive_datagram` before each tick (virtual clock only). Vehicles are switched
    to their guided mode (GUIDED / OFFBOARD) after the first round of setpoints."""

    def __init__(self, swarm: Swarm, hb_hz: float, sp_hz: float, rng) -> None:
        from mavedge.codec import VehicleCodec, coalesce_datagrams
        from mavedge.setpoints import position_target_global_int
        from vehicle_emu.wire import dialect as mavlink

        self.swarm, self.hb_hz, self.sp_hz = swarm, hb_hz, sp_hz
        self._coalesce = coalesce_datagrams
        codec = VehicleCodec(255, mavlink.MAV_COMP_ID_MISSIONPLANNER)
        hb = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )
        self._hb = [codec.encode(hb) for _ in range(swarm.n_networks)]
        lat0, lon0, _ = swarm.home_lla
        off = rng.uniform(-0.003, 0.003, (swarm.n, 2))
        self._sp = [
            codec.encode(
                position_target_global_int(
                    target_system=int(swarm.sysid_of_index[i]),
                    lat_deg=lat0 + off[i, 0],
                    lon_deg=lon0 + off[i, 1],
                    alt_m=20.0,
                )
            )
            for i in range(swarm.n)
        ]
        self._next_hb_s = self._next_sp_s = -1.0

    def send(self, t_s: float) -> None:
        swarm = self.swarm
        out = []
        if self.hb_hz > 0 and t_s >= self._next_hb_s - 1e-9:
            out += [(k, self._hb[k]) for k in range(swarm.n_networks)]
            self._next_hb_s = t_s + 1.0 / self.hb_hz
        if self.sp_hz > 0 and t_s >= self._next_sp_s - 1e-9:
            net = swarm.network_of_index
            out += [(int(net[i]), self._sp[i]) for i in range(swarm.n)]
            self._next_sp_s = t_s + 1.0 / self.sp_hz
        for endpoint, data in self._coalesce(out):
            swarm.receive_datagram(endpoint, data, ("127.0.0.1", 14550), t_s)

    def enter_guided(self, t_s: float) -> None:
        for core in self.swarm.cores:
            key = next(k for k, (_, beh) in core.pers.modes.items() if beh == "guided")
            core._set_mode(key, t_s, "command")


def _make_swarm(args, kind: str, sink_port: int | None) -> Swarm:
    rng = np.random.default_rng(0)
    if args.px4 or args.ardupilot:
        pers = ["px4"] * args.px4 + ["ardupilot"] * args.ardupilot
    else:
        pers = [args.personality] * args.vehicles
    rates = None
    if not args.default_rates:
        rates = {M_GLOBAL_POSITION_INT: args.rate_hz, M_SYS_STATUS: 1.0}
        if args.local:
            rates[M_LOCAL_POSITION_NED] = args.rate_hz
    swarm = Swarm(
        len(pers),
        personality=pers,
        mux=not args.per_vehicle_ports,
        spawn_spacing_m=30.0,
        radio=RadioConfig(radio_range_m=args.radio_range_m),
        gcs_addrs=[("127.0.0.1", sink_port or 9)],
        stream_rates_hz=rates,
        rng=rng,
        telemetry=kind,
        **({"tick_s": args.tick_s} if args.tick_s else {}),
    )
    # Everyone airborne and flying to random points: physics and radio do real work.
    ph = swarm.physics
    ph.armed[:] = True
    for core in swarm.cores:
        core.armed = True
    targets = np.column_stack([rng.uniform(-400, 400, (swarm.n, 2)), np.full(swarm.n, -20.0)])
    ph.target_pos_ned_m[:] = targets
    ph.max_speed_h_m_s[:] = 5.0
    return swarm


def _tick_cpu(args, kind: str) -> dict:
    """CPU per tick on a virtual clock (no sockets): median of 5 blocks of ``--ticks`` / 5."""
    swarm = _make_swarm(args, kind, None)
    gcs = None
    if args.gcs_hb_hz > 0 or args.setpoint_hz > 0:
        gcs = _GcsTraffic(swarm, args.gcs_hb_hz, args.setpoint_hz, np.random.default_rng(1))
        gcs.send(0.0)
        gcs.enter_guided(0.0)
    t = 0.0
    for _ in range(20):  # warm-up: every stream has fired once
        t = round(t + swarm.tick_s, 6)
        if gcs is not None:
            gcs.send(t)
        swarm.handle_timer(t)
        swarm.datagrams_to_send(t)
    blocks = []
    digest = hashlib.sha1()  # what the vehicles said and did: equal across equivalent trees
    m0 = swarm.core_stats()["messages_out"]
    per = max(1, args.ticks // 5)
    for _ in range(5):
        c0 = time.process_time()
        for _ in range(per):
            t = round(t + swarm.tick_s, 6)
            if gcs is not None:
                gcs.send(t)
            swarm.handle_timer(t)
            for endpoint, data, _ in swarm.datagrams_to_send(t):
                digest.update(endpoint.to_bytes(4, "little") + data)
        blocks.append((time.process_time() - c0) / per)
        while (e := swarm.next_event()) is not None:
            digest.update(repr(e).encode())
    msgs = swarm.core_stats()["messages_out"] - m0
    sim_s = 5 * per * swarm.tick_s
    cpu_tick = float(np.median(blocks))
    return {
        "cpu_per_tick_ms": round(cpu_tick * 1e3, 2),
        "cpu_share_at_real_time": round(cpu_tick / swarm.tick_s, 3),
        "messages_per_sim_s": round(msgs / sim_s),
        "fingerprint": digest.hexdigest()[:16],
    }


async def _realtime(args, kind: str) -> dict:
    port_q, result_q = mp.Queue(), mp.Queue()
    sink = mp.Process(target=_sink, args=(port_q, result_q, args.duration_s), daemon=True)
    sink.start()
    sink_port = port_q.get(timeout=10)
    swarm = _make_swarm(args, kind, sink_port)
    clock = RealClock(1.0)
    server = EmulatorServer(swarm, clock, "127.0.0.1", 0)
    await server.start()
    late = []
    orig = server._on_timer

    def timed():
        late.append(clock.now() - swarm.next_timer_s())
        orig()

    server._on_timer = timed
    px4 = np.array([c.personality == "px4" for c in swarm.cores])

    def sent():
        m = np.array([c.stats.messages_out for c in swarm.cores])
        return m[px4].sum(), m[~px4].sum()

    (p0, a0) = sent()
    cpu0, wall0 = time.process_time(), time.monotonic()
    await asyncio.sleep(args.duration_s)
    cpu1, wall1 = time.process_time(), time.monotonic()
    (p1, a1) = sent()
    server.close()
    n_recv, n_bytes, frames = result_q.get(timeout=60)
    sink.join(5)
    port_endpoint = {addr[1]: e for e, addr in enumerate(server.addresses)}
    f_px4 = f_ap = 0
    for (port, sysid), count in frames.items():
        e = port_endpoint.get(port)
        if e is None:
            continue
        i = swarm.index_of(e, sysid) if swarm.mux else e
        if swarm.cores[i].personality == "px4":
            f_px4 += count
        else:
            f_ap += count
    wall = wall1 - wall0
    late_arr = np.asarray(late[5:]) if len(late) > 5 else np.asarray(late)
    n_px4 = args.px4 if (args.px4 or args.ardupilot) else 0
    n_ap = args.ardupilot if (args.px4 or args.ardupilot) else 0
    out = {
        "vehicles": swarm.n,
        "networks": swarm.n_networks,
        "duration_s": round(wall, 2),
        "cpu_share_of_one_core": round((cpu1 - cpu0) / wall, 3),
        "messages_per_s": round((p1 - p0 + a1 - a0) / wall),
        "datagrams_sent_per_s": round(swarm.stats["datagrams_out"] / wall),
        "datagrams_received_by_sink": n_recv,
        "bytes_received_by_sink": n_bytes,
        "ticks_per_s": round(swarm.stats["ticks"] / wall, 1),
        "tick_lateness_p50_ms": round(float(np.median(late_arr)) * 1e3, 2),
        "tick_lateness_p99_ms": round(float(np.quantile(late_arr, 0.99)) * 1e3, 2),
        "keeps_up": bool(np.quantile(late_arr, 0.99) < 0.05 and (cpu1 - cpu0) / wall < 1.0),
    }
    # Achieved rate: frames sent per vehicle and second in the measured window; delivered: the
    # share of every frame sent in the server's life (boot burst included) the sink counted.
    p_all, a_all = sent()
    if n_px4:
        out["px4_msgs_per_vehicle_s"] = {
            "default": 17.5,
            "achieved": round((p1 - p0) / wall / n_px4, 2),
            "delivered": round(f_px4 / max(1, p_all), 4),
        }
    if n_ap:
        out["ardupilot_msgs_per_vehicle_s"] = {
            "default": 1.0,
            "achieved": round((a1 - a0) / wall / n_ap, 2),
            "delivered": round(f_ap / max(1, a_all), 4),
        }
    return out


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--px4", type=int, default=0, help="PX4 vehicles (with --ardupilot)")
    p.add_argument("--ardupilot", type=int, default=0, help="ArduPilot vehicles")
    p.add_argument("--vehicles", type=int, default=500)
    p.add_argument("--personality", default="ardupilot")
    p.add_argument(
        "--default-rates",
        action="store_true",
        help="each firmware's own default streams (implied by --px4/--ardupilot)",
    )
    p.add_argument("--duration-s", type=float, default=10.0)
    p.add_argument("--ticks", type=int, default=100, help="virtual-clock ticks per measurement")
    p.add_argument("--rate-hz", type=float, default=10.0)
    p.add_argument("--local", action="store_true", help="also LOCAL_POSITION_NED at --rate-hz")
    p.add_argument("--per-vehicle-ports", action="store_true", help="SITL-style, one socket each")
    p.add_argument("--radio-range-m", type=float, default=100.0)
    p.add_argument("--telemetry", choices=("both", "batch", "reference"), default="both")
    p.add_argument("--tick-s", type=float, default=None, help="swarm tick (default TICK_S)")
    p.add_argument(
        "--gcs-hb-hz", type=float, default=0.0, help="tick: GCS HEARTBEATs per network and s"
    )
    p.add_argument(
        "--setpoint-hz", type=float, default=0.0, help="tick: global setpoints per vehicle and s"
    )
    p.add_argument("--no-realtime", action="store_true", help="only the virtual-clock tick cost")
    args = p.parse_args()
    if args.px4 or args.ardupilot:
        args.default_rates = True
    kinds = ["reference", "batch"] if args.telemetry == "both" else [args.telemetry]
    result = {"tick": {k: _tick_cpu(args, k) for k in kinds}}
    if not args.no_realtime:
        result["realtime"] = {k: asyncio.run(_realtime(args, k)) for k in kinds}
    if len(kinds) == 2:
        ref, bat = result["tick"]["reference"], result["tick"]["batch"]
        result["ratio_reference_over_batch"] = {
            "cpu_per_tick": round(ref["cpu_per_tick_ms"] / bat["cpu_per_tick_ms"], 2)
        }
        if "realtime" in result:
            rr, rb = result["realtime"]["reference"], result["realtime"]["batch"]
            result["ratio_reference_over_batch"]["realtime_cpu_share"] = round(
                rr["cpu_share_of_one_core"] / rb["cpu_share_of_one_core"], 2
            )
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

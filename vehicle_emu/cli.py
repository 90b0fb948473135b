"""``phireman emulate``: run N emulated MAVLink vehicles on loopback UDP."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import socket

import numpy as np

from mavedge.clock import RealClock

from .telemetry import M_GLOBAL_POSITION_INT, M_LOCAL_POSITION_NED
from .radio import RadioConfig
from .swarm import PEER_TIMEOUT_S, Swarm
from .udp import EmulatorServer

__all__ = ["HELP", "DESCRIPTION", "add_arguments", "run"]

log = logging.getLogger(__name__)

HELP = "emulate N ArduPilot/PX4 vehicles over MAVLink/UDP (SITL-style ports)"
DESCRIPTION = """\
Emulate a swarm of multicopters that speak MAVLink 2 like ArduPilot Copter or PX4, in one
process: vehicle k (0-based) listens on UDP base-port + k (or, with --mux, one port per
MAVLink network of 254 vehicles). Vehicles send to every address they hear from and to the
--gcs addresses. Radio range and attrition decide who the ground station can hear.

Vehicle timers follow the vehicle clock: under --speedup K a GCS must heartbeat K times faster
or the GCS failsafe fires (as in SITL).

Examples:
  phireman emulate --vehicles 3 --personality ardupilot --home 47.3977,8.5456,488 \\
      --base-port 14550 --gcs udpout:127.0.0.1:14551
  phireman emulate --vehicles 500 --mux --radio-range-m 300 --attrition-per-s 0.0005
"""


def _home(text: str) -> tuple[float, float, float]:
    try:
        lat, lon, alt = (float(v) for v in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"expected LAT,LON,ALT in degrees and metres, got {text!r}"
        ) from exc
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise argparse.ArgumentTypeError(f"latitude/longitude out of range: {text!r}")
    return lat, lon, alt


def _gcs(text: str) -> tuple[str, int]:
    body = text.split(":", 1)[1] if text.startswith("udpout:") else text
    host, _, port = body.rpartition(":")
    try:
        return host or "127.0.0.1", int(port)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected udpout:HOST:PORT, got {text!r}") from exc


def _rate(text: str) -> tuple[int, float]:
    name, _, hz = text.partition("=")
    names = {
        "GLOBAL_POSITION_INT": M_GLOBAL_POSITION_INT,
        "LOCAL_POSITION_NED": M_LOCAL_POSITION_NED,
    }
    try:
        msg_id = names[name.upper()] if name.upper() in names else int(name)
        return msg_id, float(hz)
    except (ValueError, KeyError) as exc:
        raise argparse.ArgumentTypeError(f"expected MSG=HZ (name or id), got {text!r}") from exc


def _key(text: str) -> bytes:
    try:
        key = bytes.fromhex(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError("signing key must be 64 hex digits") from exc
    if len(key) != 32:
        raise argparse.ArgumentTypeError("signing key must be 32 bytes (64 hex digits)")
    return key


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--vehicles",
        type=int,
        required=True,
        metavar="N",
        help="number of vehicles (more than 254 use several MAVLink networks)",
    )
    parser.add_argument("--personality", choices=("ardupilot", "px4"), default="ardupilot")
    parser.add_argument(
        "--home",
        type=_home,
        default=(47.397742, 8.545594, 488.0),
        metavar="LAT,LON,ALT",
        help="base station position (deg, deg, m AMSL)",
    )
    parser.add_argument(
        "--base-port",
        type=int,
        default=14550,
        metavar="P",
        help="first UDP port (0 = ephemeral ports, printed at start)",
    )
    parser.add_argument("--bind", default="127.0.0.1", help="bind address (default loopback)")
    parser.add_argument(
        "--mux", action="store_true", help="one port per MAVLink network instead of one per vehicle"
    )
    parser.add_argument(
        "--speedup",
        type=float,
        default=1.0,
        metavar="K",
        help="simulation speed-up (SITL SIM_SPEEDUP)",
    )
    parser.add_argument(
        "--radio-range-m",
        type=float,
        default=float("inf"),
        metavar="R",
        help="drone-drone and drone-base radio range (default unlimited)",
    )
    parser.add_argument(
        "--base-range-m",
        type=float,
        default=None,
        metavar="R",
        help="drone-base range if different from --radio-range-m",
    )
    parser.add_argument("--latency-per-hop-s", type=float, default=0.0)
    parser.add_argument("--loss-per-hop", type=float, default=0.0)
    parser.add_argument(
        "--attrition-per-s",
        type=float,
        default=0.0,
        metavar="LAMBDA",
        help="failure rate of each vehicle per second of vehicle time",
    )
    parser.add_argument(
        "--kill",
        action="append",
        default=[],
        metavar="T:INDEX",
        help="scripted loss of vehicle INDEX at time T seconds (repeatable)",
    )
    parser.add_argument(
        "--spacing-m", type=float, default=3.0, help="spawn grid spacing around the base"
    )
    parser.add_argument(
        "--gcs",
        type=_gcs,
        action="append",
        default=[],
        metavar="udpout:HOST:PORT",
        help="always send to this address",
    )
    parser.add_argument(
        "--rate",
        type=_rate,
        action="append",
        default=[],
        metavar="MSG=HZ",
        help="stream a message from boot, e.g. GLOBAL_POSITION_INT=10",
    )
    parser.add_argument(
        "--signing-key",
        type=_key,
        default=None,
        metavar="HEX",
        help="MAVLink 2 signing key (64 hex digits)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="parameter override for every vehicle (native units)",
    )
    parser.add_argument(
        "--duration-s",
        type=float,
        default=None,
        help="stop after this much vehicle time (default: until Ctrl-C)",
    )
    parser.add_argument("--seed", type=int, default=0)


class UsageError(ValueError):
    """Bad command-line input: reported in one line, exit status 2 (mission.cli convention)."""


def _build(args) -> tuple[Swarm, RealClock]:
    UserError = UsageError  # noqa: N806
    if args.vehicles < 1:
        raise UserError("--vehicles must be >= 1")
    if args.base_port and not args.mux and args.base_port + args.vehicles - 1 > 65535:
        raise UserError("ports base-port .. base-port + N - 1 exceed 65535; use --mux")
    kills = []
    for k in args.kill:
        try:
            t, i = k.split(":")
            kills.append((float(t), int(i)))
        except ValueError as exc:
            raise UserError(f"--kill expects T:INDEX, got {k!r}") from exc
    params = {}
    for p in args.param:
        name, _, value = p.partition("=")
        try:
            params[name] = float(value)
        except ValueError as exc:
            raise UserError(f"--param expects NAME=VALUE, got {p!r}") from exc
    clock = RealClock(args.speedup)
    try:
        radio = RadioConfig(
            args.radio_range_m, args.base_range_m, args.latency_per_hop_s, args.loss_per_hop
        )
        swarm = Swarm(
            args.vehicles,
            personality=args.personality,
            home_lla=args.home,
            spawn_spacing_m=args.spacing_m,
            radio=radio,
            hazard_per_s=args.attrition_per_s,
            kills=kills,
            mux=args.mux,
            gcs_addrs=args.gcs,
            signing_key=args.signing_key,
            params=params,
            stream_rates_hz=dict(args.rate),
            rng=np.random.default_rng(args.seed),
            unix_time_at_zero_s=clock.unix_time_at_zero_s,
            # a third-party GCS sends in wall time: forget it after 30 WALL seconds
            peer_timeout_s=PEER_TIMEOUT_S * max(1.0, args.speedup),
        )
    except (ValueError, KeyError) as exc:
        raise UserError(str(exc)) from exc
    return swarm, clock


async def _serve(swarm: Swarm, clock: RealClock, args) -> None:
    server = EmulatorServer(swarm, clock, args.bind, args.base_port)
    await server.start()
    first, last = server.addresses[0], server.addresses[-1]
    log.warning(
        "emulating %d %s vehicle(s) in %d network(s) on udp %s:%d..%d (speed-up %g)",
        swarm.n,
        args.personality,
        swarm.n_networks,
        first[0],
        first[1],
        last[1],
        clock.speedup,
    )
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
        except (NotImplementedError, RuntimeError):
            pass
    try:
        if args.duration_s is None:
            await stop.wait()
        else:
            try:
                await asyncio.wait_for(stop.wait(), clock.wall_delay_s(args.duration_s))
            except TimeoutError:
                pass
    finally:
        server.close()
    log.warning(
        "stopped at t=%.1f s: %d alive, %d active; %s",
        clock.now(),
        int(swarm.alive.sum()),
        int(swarm.active.sum()),
        swarm.stats,
    )


def run(args) -> int:
    """Build and serve the swarm.

    Raises
    ------
    UsageError
        Bad input, or a port that cannot be bound (taken, privileged, bad --bind address): one
        line with the cause and the fix; the command line reports it with exit status 2.
    """
    import errno

    swarm, clock = _build(args)
    try:
        asyncio.run(_serve(swarm, clock, args))
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            last = args.base_port + (swarm.n_networks if args.mux else swarm.n) - 1
            raise UsageError(
                f"UDP port in {args.bind}:{args.base_port}..{last} is already in use (another "
                f"emulator, SITL or ground station?); choose another --base-port, or "
                f"--base-port 0 for free ports"
            ) from None
        if exc.errno in (errno.EACCES, errno.EPERM):
            raise UsageError(
                f"not allowed to bind {args.bind}:{args.base_port} (ports below 1024 need "
                f"privileges); choose --base-port 1024 or above"
            ) from None
        if exc.errno in (errno.EADDRNOTAVAIL, errno.EAFNOSUPPORT) or isinstance(
            exc, socket.gaierror
        ):
            raise UsageError(
                f"--bind {args.bind}: not an address of this machine ({exc.strerror or exc})"
            ) from None
        raise
    return 0

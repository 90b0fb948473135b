"""``phireman emulate``: run N emulated MAVLink vehicles on loopback UDP."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import socket
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mavedge.clock import RealClock

from .telemetry import M_GLOBAL_POSITION_INT, M_LOCAL_POSITION_NED
from .radio import RadioConfig
from .swarm import PEER_TIMEOUT_S, Swarm
from .udp import EmulatorServer

__all__ = [
    "HELP",
    "DESCRIPTION",
    "add_arguments",
    "run",
    "EmulateResult",
    "describe_start",
    "describe_end",
]

log = logging.getLogger(__name__)

HELP = "emulate N ArduPilot/PX4 vehicles over MAVLink/UDP (SITL-style ports)"
DESCRIPTION = """\
Emulate a swarm of multicopters that speak MAVLink 2 like ArduPilot Copter or PX4, in one
process: vehicle k (0-based) listens on UDP base-port + k (or, with --mux, one port per
MAVLink network of 254 vehicles). Vehicles send to every address they hear from and to the
--gcs addresses. Radio range and attrition decide who the ground station can hear.

The ground station's port must lie outside the vehicles' own ports (base-port .. base-port +
N - 1): a --gcs address inside them is refused, since the vehicles would send to each other.

Vehicle timers follow the vehicle clock: under --speedup K a GCS must heartbeat K times faster
or the GCS failsafe fires (as in SITL).

Prints the vehicles' ports at start and the traffic statistics at the end. Stops after
--duration-s or at Ctrl-C (exit status 130; SIGTERM 143).

Examples:
  phireman emulate --vehicles 10 --personality ardupilot --home 39.7596,-121.6219,540 \\
      --base-port 14560 --gcs udpout:127.0.0.1:14550
  phireman fly wildfire --connect udpin:127.0.0.1:14550 --vehicles 10   # another terminal
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
    parser.add_argument(
        "--personality",
        choices=("ardupilot", "px4"),
        default="ardupilot",
        help="autopilot the vehicles behave like: modes, parameters, failsafes (default ardupilot)",
    )
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
    parser.add_argument(
        "--latency-per-hop-s",
        type=float,
        default=0.0,
        metavar="S",
        help="radio delay added per relay hop, seconds of vehicle time (default 0)",
    )
    parser.add_argument(
        "--loss-per-hop",
        type=float,
        default=0.0,
        metavar="P",
        help="probability that a datagram is lost on each relay hop (default 0)",
    )
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
        help="the ground station: every vehicle always sends there (repeatable); a port "
        "outside the vehicles' own (base-port .. base-port + N - 1)",
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
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the random draws: attrition, radio loss (default 0)",
    )


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
    _check_gcs_ports(args, swarm.n_endpoints)
    return swarm, clock


def _local(host: str) -> str:
    return "127.0.0.1" if host in ("", "localhost") else host


def _check_gcs_ports(args, n_endpoints: int) -> None:
    """Refuse a ``--gcs`` address that is one of the vehicles' own sockets: they would send their
    ground-station traffic to a vehicle (with a station listening there, the bind fails; without
    one, the vehicles learn each other as peers until "more than 8 peers, dropped")."""
    if not args.base_port:
        return  # ephemeral ports: the system picks them at bind time, never one already bound
    first, last = args.base_port, args.base_port + n_endpoints - 1
    bind = _local(args.bind)
    for host, port in args.gcs:
        h = _local(host)
        # This machine's sockets: the bind address itself, any loopback address when bound to
        # every interface, and 0.0.0.0 as a destination (Linux delivers it locally).
        same_host = h in (bind, "0.0.0.0") or (bind == "0.0.0.0" and h.startswith("127."))
        if same_host and first <= port <= last:
            raise UsageError(
                f"--gcs udpout:{host}:{port} is one of the emulator's own ports (its vehicles "
                f"bind {args.bind}:{first}..{last}); give the ground station a port outside "
                f"them, e.g. --base-port {port + 10} --gcs udpout:{host}:{port} (then: "
                f"phireman fly MISSION --connect udpin:{host}:{port})"
            )


@dataclass
class EmulateResult:
    """How a ``phireman emulate`` session ended (the command prints it for people)."""

    t_s: float
    """Vehicle time at the stop, s."""
    n: int
    alive: int
    active: int
    stats: dict[str, int]
    """:attr:`vehicle_emu.swarm.Swarm.stats` at the stop."""
    stopped_by: str | None = None
    """'SIGINT' (Ctrl-C), 'SIGTERM', or None when ``--duration-s`` ran out."""


def describe_start(swarm: Swarm, args, addresses: list[tuple[str, int]], speedup: float) -> str:
    """One line for people: what is emulated and on which ports."""
    ports = [p for _, p in addresses]
    if ports == list(range(ports[0], ports[0] + len(ports))):
        where = f"{addresses[0][0]}:{ports[0]}" + (f"..{ports[-1]}" if len(ports) > 1 else "")
    else:  # ephemeral ports (--base-port 0): each one
        where = f"{addresses[0][0]} ports {', '.join(map(str, ports))}"
    gcs = ", ".join(f"{h}:{p}" for h, p in args.gcs) or "none (they answer whoever sends to them)"
    return (
        f"emulating {swarm.n} {args.personality} vehicle(s) in {swarm.n_networks} MAVLink "
        f"network(s) on udp {where} (speed-up {speedup:g}); ground station: {gcs}"
    )


def describe_end(result: EmulateResult) -> list[str]:
    """Lines for people: when and why the emulation stopped, and its traffic statistics."""
    why = {"SIGINT": " (Ctrl-C)", "SIGTERM": " (SIGTERM)", None: ""}[result.stopped_by]
    st = dict(result.stats)

    def take(key: str) -> int:
        return int(st.pop(key, 0))

    lines = [
        f"stopped at t = {result.t_s:.1f} s of vehicle time{why}: {result.alive} of "
        f"{result.n} vehicles alive, {result.active} active",
        f"datagrams: {take('datagrams_in')} in, {take('datagrams_out')} out; dropped: "
        f"{take('dropped_radio_in')} out of radio range inbound, {take('dropped_radio_out')} "
        f"outbound, {take('dropped_dead')} to dead vehicles, {take('unroutable')} unroutable",
        f"peers: {take('peers_learned')} learned, {take('peers_expired')} expired, "
        f"{take('peers_evicted')} evicted (over the limit per vehicle); {take('ticks')} ticks",
    ]
    if st:  # counters added later still show, one "name value" each
        lines.append("other: " + ", ".join(f"{k} {v}" for k, v in sorted(st.items())))
    return lines


async def _serve(
    swarm: Swarm, clock: RealClock, args, on_ready: Callable[[str], None] | None
) -> EmulateResult:
    server = EmulatorServer(swarm, clock, args.bind, args.base_port)
    await server.start()
    stop = asyncio.Event()
    stopped_by: list[str] = []
    loop = asyncio.get_running_loop()

    def on_signal(name: str) -> None:
        stopped_by.append(name)
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, on_signal, sig.name)
        except (NotImplementedError, RuntimeError):
            pass
    # Ready only now: a signal from whoever waits for this line finds its handler installed.
    line = describe_start(swarm, args, list(server.addresses), clock.speedup)
    log.info("%s", line)
    if on_ready is not None:
        on_ready(line)
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
    return EmulateResult(
        t_s=clock.now(),
        n=swarm.n,
        alive=int(swarm.alive.sum()),
        active=int(swarm.active.sum()),
        stats=dict(swarm.stats),
        stopped_by=stopped_by[0] if stopped_by else None,
    )


def run(args, on_ready: Callable[[str], None] | None = None) -> EmulateResult:
    """Build and serve the swarm until ``--duration-s`` or SIGINT / SIGTERM.

    ``on_ready`` is called once with a line for people when the ports are bound.

    Raises
    ------
    UsageError
        Bad input, or a port that cannot be bound (taken, privileged, bad --bind address): one
        line with the cause and the fix; the command line reports it with exit status 2.
    """
    import errno

    swarm, clock = _build(args)
    try:
        return asyncio.run(_serve(swarm, clock, args, on_ready))
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

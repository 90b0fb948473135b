"""``phireman sitl``: start a swarm of real-firmware SITL vehicles for ``phireman fly``."""

from __future__ import annotations

import argparse
import sys
import time

__all__ = ["HELP", "DESCRIPTION", "add_arguments", "run"]

HELP = "start N ArduCopter or PX4 SITL vehicles (your own build) around a mission's origin"
DESCRIPTION = """\
Start N instances of real autopilot firmware in software-in-the-loop simulation, placed on a row
around the mission's origin (5 m apart), each with its own system id and port, and print the
connection strings to fly them with. Runs until Ctrl-C, then stops exactly what it started.
phireman ships no firmware: point it at your own build.

A battery swap while it runs: type a vehicle's number (0 .. N-1) and Enter. That vehicle is
power-cycled: killed, and booted again as the same instance, with the same sysid, home and ports,
on its stored parameters and with a full battery. A relay-rotation flight (a mission with an
`endurance` section) takes it back as a spare.

  ArduCopter: your SITL build of an ArduPilot tree (see ArduPilot's SITL documentation)
              -> --binary build/sitl/bin/arducopter, or set PHIREMAN_ARDUCOPTER; the defaults
              file Tools/autotest/default_params/copter.parm is looked for beside the binary
              (or PHIREMAN_ARDUCOPTER_DEFAULTS). Vehicle i: sysid i+1, tcp:127.0.0.1:5760+10i.
  PX4 (SIH):  your SITL build of a PX4-Autopilot tree (see PX4's simulation documentation)
              -> --binary build/px4_sitl_default/bin/px4, or set PHIREMAN_PX4 (its etc
              directory is ../etc, or PHIREMAN_PX4_ETC). Vehicle i: sysid i+1; every
              vehicle on udpin:127.0.0.1:14550 (PX4's GCS port). Runs at 1x.

Examples:
  phireman sitl ardupilot --vehicles 3 --mission sitl_ardupilot
  phireman fly sitl_ardupilot --apply-failsafes        # in another terminal
  phireman sitl px4 --vehicles 3 --mission sitl_px4 --print-fly
  phireman sitl ardupilot --vehicles 3 --speedup 5     # then: phireman fly ... --speedup 5
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("firmware", choices=("ardupilot", "px4"), help="which firmware to start")
    p.add_argument(
        "--vehicles", type=int, default=3, metavar="N", help="number of instances (default 3)"
    )
    p.add_argument(
        "--binary",
        default=None,
        metavar="PATH",
        help="the SITL binary (default: $PHIREMAN_ARDUCOPTER or $PHIREMAN_PX4)",
    )
    p.add_argument(
        "--mission",
        default=None,
        metavar="MISSION",
        help="place the vehicles around this mission's origin (file or shipped "
        "example; default: the firmware's own SITL home)",
    )
    p.add_argument(
        "--speedup",
        type=float,
        default=1.0,
        metavar="K",
        help="ArduCopter only: run the vehicles' clock K times faster (fly with the "
        "same --speedup K)",
    )
    p.add_argument("--spacing-m", type=float, default=5.0, help="distance between homes (5 m)")
    p.add_argument(
        "--first-instance",
        type=int,
        default=0,
        metavar="I",
        help="instance number of the first vehicle (ports and sysids shift with it)",
    )
    p.add_argument(
        "--workdir",
        default=None,
        metavar="DIR",
        help="keep each instance's working directory (logs, eeprom) under DIR "
        "(default: a temporary directory removed at the end)",
    )
    p.add_argument(
        "--print-fly",
        action="store_true",
        help="print the whole 'phireman fly' command to run against them",
    )


def run(args) -> int:
    from pathlib import Path

    from mission.commands.options import UserError, writable_dir
    from mission.flight.sitl import DEFAULT_HOMES, SitlError, SitlSpec, SitlSwarm, find_binary

    if args.spacing_m <= 0:
        raise UserError(f"--spacing-m must be > 0, got {args.spacing_m}")
    if args.first_instance < 0:
        raise UserError(f"--first-instance must be >= 0, got {args.first_instance}")
    if args.workdir:
        writable_dir(args.workdir, "--workdir")
    origin = DEFAULT_HOMES[args.firmware]
    mission_name = None
    if args.mission:
        from mission.commands.fly import _load

        mission = _load(args.mission)
        o = mission.origin
        origin = (o.lat_deg, o.lon_deg, o.alt_amsl_m)
        mission_name = args.mission
    try:
        spec = SitlSpec(
            args.firmware,
            args.vehicles,
            find_binary(args.firmware, args.binary),
            origin,
            speedup=args.speedup,
            workdir=Path(args.workdir) if args.workdir else None,
            first_instance=args.first_instance,
            spacing_m=args.spacing_m,
        )
        swarm = SitlSwarm(spec).start()
    except SitlError as exc:
        raise UserError(str(exc)) from None
    import signal

    def _stop(signum, frame):
        raise KeyboardInterrupt

    # Ctrl-C, kill, a closed terminal: stop exactly what was started (SIGINT may arrive
    # ignored from a background job's shell; take it back).
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _stop)
    try:
        print(
            f"started {args.vehicles} {args.firmware} SITL vehicle(s) around "
            f"{origin[0]:.6f}, {origin[1]:.6f} ({origin[2]:g} m); working directories under "
            f"{swarm.workdir}"
        )
        for k in range(args.vehicles):
            print(f"  vehicle {k}: sysid {swarm.sysid(k)}  {swarm.connection(k)}")
        connects = " ".join(f"--connect {c}" for c in swarm.connections())
        speed = f" --speedup {args.speedup:g}" if args.speedup != 1.0 else ""
        hint = f"phireman fly {mission_name or 'MISSION'} {connects}{speed} --apply-failsafes"
        print(("fly them with:\n  " if args.print_fly else "e.g.: ") + hint)
        if args.firmware == "ardupilot":
            print(
                "(ArduCopter arms about 40 s after start, once its EKF uses GPS; PX4 SIH "
                "after a few seconds)"
                if args.speedup == 1.0
                else ""
            )
        print("Ctrl-C stops them; a vehicle's number and Enter power-cycles it (a battery swap).")
        sys.stdout.flush()
        crew = _Crew(swarm)
        while True:
            crew.wait(1.0)
            dead = [k for k, ok in enumerate(swarm.alive()) if not ok]
            if dead and len(dead) == len(swarm.procs):
                print(
                    "every SITL instance has exited; see console.log in its working "
                    f"directory under {swarm.workdir}",
                    file=sys.stderr,
                )
                return 1
    except KeyboardInterrupt:
        print("stopping the SITL vehicles", file=sys.stderr)
        return 130
    finally:
        swarm.stop()


class _Crew:
    """The ground crew at the terminal: a vehicle's number on standard input power-cycles it
    (:meth:`mission.flight.sitl.SitlSwarm.power_cycle`). Without a usable standard input (closed,
    at its end) it just waits."""

    def __init__(self, swarm) -> None:
        self.swarm = swarm
        self.buffer = ""
        try:
            self.fd: int | None = sys.stdin.fileno() if sys.stdin is not None else None
        except (OSError, ValueError):  # closed, or not a file
            self.fd = None

    def wait(self, timeout_s: float) -> None:
        import os
        import select

        if self.fd is None:
            time.sleep(timeout_s)
            return
        # The descriptor itself, not sys.stdin: its buffer would keep a second line unseen by
        # select() until more input came.
        ready, _, _ = select.select([self.fd], [], [], timeout_s)
        if not ready:
            return
        data = os.read(self.fd, 4096)
        if not data:  # end of input: nobody at the terminal
            self.fd = None
            return
        self.buffer += data.decode("utf-8", "replace")
        *lines, self.buffer = self.buffer.split("\n")
        for line in lines:
            self.handle(line.strip())

    def handle(self, text: str) -> None:
        from mission.flight.sitl import SitlError

        if not text:
            return
        n = len(self.swarm.procs)
        if not text.isdigit() or int(text) >= n:
            print(f"type a vehicle number 0 .. {n - 1} to power-cycle it", file=sys.stderr)
            return
        k = int(text)
        try:
            self.swarm.power_cycle(k)
        except SitlError as exc:
            print(f"vehicle {k}: {exc}", file=sys.stderr)
            return
        print(
            f"vehicle {k} (sysid {self.swarm.sysid(k)}) power-cycled: booting with a full battery"
        )
        sys.stdout.flush()

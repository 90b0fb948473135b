"""``phireman fly``: fly a mission with the ground station, against the emulator or real links."""

from __future__ import annotations

import argparse
import math
import sys

__all__ = ["HELP", "DESCRIPTION", "add_arguments", "run", "format_status",
           "format_param_changes"]

HELP = "fly a mission with the ground station (built-in emulator by default, or --connect)"
DESCRIPTION = """\
Fly PhiIREMAN from the ground station over MAVLink. By default the built-in emulator plays the
mission's vehicles on loopback UDP (its own process, same simulated clock as the station, at the
mission's run.speedup); with --connect the same station flies real links instead.

Sequence: discover vehicles -> pre-flight audit of lost-link parameters (refuses unsafe settings
unless fixed with --apply-failsafes or overridden with --override-audit) -> GUIDED/OFFBOARD, arm, take off in waves -> PhiIREMAN at the control
period -> RTL or LAND. Vehicles that come back from a failsafe are reclaimed.

Writes a run directory (mission, seed, code version, flight.tlog, events.jsonl, metrics.csv,
summary.json, truth.npz when emulated) and ends with TU1/TU2 as the station saw them and, when
emulated, from the emulator's ground truth.

Examples:
  phireman fly                          # the shipped 'wildfire' mission, emulated
  phireman fly wildfire --personality px4 --seed 3
  phireman fly mission.yaml --connect udpin:0.0.0.0:14550 --connect udpin:0.0.0.0:14560
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mission", nargs="?", default="wildfire", metavar="MISSION",
                   help="mission file or shipped example name (default: wildfire)")
    p.add_argument("--connect", action="append", default=[], metavar="URL",
                   help="fly real links instead of the emulator (udpin:H:P, udpout:H:P, tcp:H:P, "
                        "DEVICE,BAUD); repeat for several MAVLink networks")
    p.add_argument("--personality", choices=("ardupilot", "px4", "mixed"), default=None,
                   help="emulated autopilot (default: the mission's)")
    p.add_argument("--speedup", type=float, default=None, metavar="K",
                   help="simulated time / wall time (default: the mission's run.speedup; with "
                        "--connect only for vehicles whose clock runs K times faster, e.g. SITL)")
    p.add_argument("--seed", type=int, default=None, help="run seed (default: the mission's)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="parent directory of the run directory (default: the mission's output.dir)")
    p.add_argument("--end", choices=("rtl", "land"), default="rtl",
                   help="what the vehicles do at the end (default rtl)")
    p.add_argument("--override-audit", action="store_true",
                   help="fly even if the pre-flight audit finds unsafe lost-link settings")
    p.add_argument("--apply-failsafes", action="store_true",
                   help="during the audit, write the safe lost-link parameters it asks for "
                        "(ArduPilot FS_GCS_ENABLE=1 RTL and SYSID_MYGCS/MAV_GCS_SYSID = our "
                        "sysid; PX4 NAV_DLL_ACT=2 Return), each confirmed by the vehicle's "
                        "echo; without this flag no parameter is ever written")
    p.add_argument("--duration-s", type=float, default=None,
                   help="mission length in seconds (default: the mission's run.duration_s)")
    p.add_argument("--vehicles", type=int, default=None, metavar="N",
                   help="with --connect: start as soon as N vehicles are heard")
    p.add_argument("--wave-size", type=int, default=25, help="vehicles per take-off wave")
    p.add_argument("--no-wait", action="store_true",
                   help="do not wait for the vehicles to obey the end command")


def _load(spec: str):
    from pathlib import Path

    from mission.cli import UserError
    from mission.load import MissionError, load_mission

    path = Path(spec)
    if not path.exists():
        from mission.examples import example_path, list_examples

        try:
            path = example_path(spec)
        except KeyError:
            raise UserError(f"{spec!r} is neither a mission file nor a shipped example "
                            f"({', '.join(list_examples())})") from None
    try:
        return load_mission(path)
    except MissionError as exc:
        raise UserError(str(exc)) from None


def _pct(x) -> str:
    return "  -  " if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:5.1f}%"


def format_status(d: dict) -> str:
    """One status line for people."""
    modes = " ".join(f"{k}:{v}" for k, v in sorted(d["modes"].items(), key=lambda kv: -kv[1]))
    t = (f"t+{d['t_mission_s']:5.0f}/{d['duration_s']:.0f}s" if d["phase"] in ("run", "end", "done")
         else f"t={d['t_s']:5.0f}s")
    line = (f"[{d['phase']:8s}] {t} vehicles {d['fleet']:3d} (net {d['networked']}, "
            f"lost {d['lost']}, ret {d['returning']}) {modes} | tasks {d['tasks_covered']}/"
            f"{d['n_tasks']} | TU1 {_pct(d['tu1'])} TU2 {_pct(d['tu2'])}")
    return line


def format_param_changes(changes) -> list[str]:
    """Lines for people: what --apply-failsafes wrote, per vehicle."""
    out = []
    for c in changes:
        who = f"link {c['link_id']} sysid {c['sysid']}"
        prev = "?" if c.get("previous") is None else f"{c['previous']:g}"
        if c.get("ok"):
            out.append(f"set {who}: {c['name']} {prev} -> {c['value']:g} (confirmed)")
        else:
            want = c.get("requested", c.get("value"))
            out.append(f"FAILED to set {who}: {c['name']} {prev} -> {want:g}: "
                       f"{c.get('reason') or 'no answer'}")
    return out


class _Status:
    def __init__(self, stream=sys.stderr) -> None:
        self.stream = stream
        self.tty = stream.isatty()
        self.width = 0
        self.last_phase = None
        self.last_print_t = -math.inf

    def __call__(self, d: dict) -> None:
        line = format_status(d)
        if self.tty:
            pad = max(0, self.width - len(line))
            self.stream.write("\r" + line + " " * pad)
            self.width = len(line)
            self.stream.flush()
        elif d["phase"] != self.last_phase or d["t_s"] - self.last_print_t >= 30.0:
            # Not a terminal: a line per phase change and every 30 simulated seconds, no flood.
            self.stream.write(line + "\n")
            self.stream.flush()
            self.last_print_t = d["t_s"]
        self.last_phase = d["phase"]

    def close(self) -> None:
        if self.tty and self.width:
            self.stream.write("\n")
            self.stream.flush()


def run(args) -> int:
    from mission.cli import UserError
    from mission.runners import FlyOptions, RunnerError, fly

    mission = _load(args.mission)
    if args.speedup is not None and not args.speedup > 0:
        raise UserError(f"--speedup must be > 0, got {args.speedup}")
    if args.duration_s is not None and not args.duration_s > 0:
        raise UserError(f"--duration-s must be > 0, got {args.duration_s}")
    if args.wave_size < 1:
        raise UserError("--wave-size must be >= 1")
    if args.connect:
        from gcs.connection import parse_connection

        for c in args.connect:
            try:
                parse_connection(c)
            except ValueError as exc:
                raise UserError(f"--connect {c!r}: {exc}") from None
    status = _Status()
    opts = FlyOptions(seed=args.seed, personality=args.personality, speedup=args.speedup,
                      duration_s=args.duration_s, out_dir=args.out, end=args.end,
                      override_audit=args.override_audit,
                      apply_failsafes=args.apply_failsafes, connections=tuple(args.connect),
                      wave_size=args.wave_size, status=status,
                      expected_vehicles=args.vehicles, end_wait=not args.no_wait)
    print(mission.summary(), file=sys.stderr)
    try:
        result = fly(mission, opts)
    except RunnerError as exc:
        raise UserError(str(exc)) from None
    finally:
        status.close()
    s = result.summary
    op = result.operator
    for line in format_param_changes(op.param_changes):
        print(line, file=sys.stderr)
    if op.prearm:
        print(f"{len(op.prearm)} vehicle(s) refused to arm at first (not ready); last reason:",
              file=sys.stderr)
        for (link_id, sysid), (t_s, text) in sorted(op.prearm.items()):
            print(f"  link {link_id} sysid {sysid} at t={t_s:.0f} s: {text}", file=sys.stderr)
    if s["phase"] == "refused":
        if op.audit_report is not None and not op.audit_report.cleared_to_fly:
            print(op.audit_report.summary(), file=sys.stderr)
            hint = ("" if args.apply_failsafes else
                    " (--apply-failsafes writes the fixable ones)")
            print(f"phireman fly: the pre-flight audit refused the flight (see above); fix the "
                  f"parameters{hint} or pass --override-audit. Run directory: {result.run_dir}",
                  file=sys.stderr)
        else:
            print(f"phireman fly: refused to launch: {op.refusal or 'unknown reason'}. "
                  f"Run directory: {result.run_dir}", file=sys.stderr)
        return 1
    st = s["station"]
    print(f"run directory: {result.run_dir}")
    print(f"flown {s['mission_s_flown']:.0f} s of mission in {s['wall_s']:.1f} s wall "
          f"(speed-up {s['speedup_achieved']:.1f}x); {s['vehicles_discovered']} vehicles, "
          f"{s['reclaimed']} reclaims")
    print(f"TU1/TU2 as the station saw them:     {_pct(st['tu1'])} / {_pct(st['tu2'])}")
    if "truth" in s:
        tr = s["truth"]
        print(f"TU1/TU2 from the emulator's truth:   {_pct(tr['tu1'])} / {_pct(tr['tu2'])}"
              f"   ({tr['alive_end']} vehicles alive at the end)")
    return 0

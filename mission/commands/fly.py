"""``phireman fly``: fly a mission with the ground station, against the emulator or real links."""

from __future__ import annotations

import argparse
import math
import sys

from mission.flight.fly_options import FlyOptions as _FlyOptions

__all__ = [
    "HELP",
    "DESCRIPTION",
    "add_arguments",
    "run",
    "format_status",
    "status_layout",
    "planned_drop",
    "STATUS_DROP_ORDER",
    "format_param_changes",
    "format_pace",
    "format_tu",
    "format_rotation",
    "slow_pace_warning",
]

#: The defaults of the options (one place: FlyOptions; a light module, imported for --help).
FLY_DEFAULTS = _FlyOptions()

HELP = "fly a mission with the ground station (built-in emulator by default, or --connect)"
DESCRIPTION = """\
Fly PhiIREMAN from the ground station over MAVLink. By default the built-in emulator plays the
mission's vehicles on loopback UDP (its own process, same simulated clock as the station, at the
mission's run.speedup); with --connect the same station flies real links instead.

Sequence: discover vehicles -> pre-flight audit of lost-link parameters (refuses unsafe settings
unless fixed with --apply-failsafes or overridden with --override-audit) -> GUIDED/OFFBOARD, arm, take off in waves -> PhiIREMAN at the control
period -> RTL or LAND. Vehicles that come back from a failsafe are reclaimed. A vehicle heard
only after the audit is audited on its own and stays on the ground until it passes.

Writes a run directory (mission, seed, code version, flight.tlog, events.jsonl, metrics.csv,
summary.json, truth.npz when emulated) and ends with TU1/TU2 as the station saw them and, when
emulated, from the emulator's ground truth.

Examples:
  phireman fly                          # the shipped 'wildfire' mission, emulated
  phireman fly wildfire --personality px4 --seed 3
  phireman fly mission.yaml --connect udpin:0.0.0.0:14550 --connect udpin:0.0.0.0:14560
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "mission",
        nargs="?",
        default=None,
        metavar="MISSION",
        help="mission file or shipped example name (default: wildfire)",
    )
    p.add_argument(
        "--mission",
        dest="mission_option",
        default=None,
        metavar="MISSION",
        help="the same as the MISSION argument (as 'sim' and 'sitl' take it)",
    )
    p.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="URL",
        help="fly real links instead of the emulator (udpin:H:P, udpout:H:P, tcp:H:P, "
        "DEVICE,BAUD); repeat for several MAVLink networks",
    )
    p.add_argument(
        "--personality",
        choices=("ardupilot", "px4", "mixed"),
        default=None,
        help="emulated autopilot (default: the mission's)",
    )
    p.add_argument(
        "--speedup",
        type=float,
        default=None,
        metavar="K",
        help="simulated time / wall time. Emulated: default the mission's "
        "run.speedup. Real links (--connect or vehicles.real): default 1, the "
        "vehicles' own clock; give K only for vehicles that run K times faster "
        "(SITL --speedup K)",
    )
    p.add_argument("--seed", type=int, default=None, help="run seed (default: the mission's)")
    p.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="parent directory of the run directory (default: the mission's output.dir)",
    )
    p.add_argument(
        "--end",
        choices=("rtl", "land"),
        default="rtl",
        help="what the vehicles do at the end (default rtl)",
    )
    p.add_argument(
        "--override-audit",
        action="store_true",
        help="fly even if the pre-flight audit finds unsafe lost-link settings",
    )
    p.add_argument(
        "--apply-failsafes",
        action="store_true",
        help="during the audit, write the safe lost-link parameters it asks for "
        "(ArduPilot FS_GCS_ENABLE=1 RTL and MAV_GCS_SYSID/SYSID_MYGCS = our "
        "sysid; PX4 NAV_DLL_ACT=2 and NAV_RCL_ACT=2 Return, COM_OBL_RC_ACT=3 "
        "Return, the offboard bit of COM_DLL_EXCEPT cleared), each confirmed by "
        "the vehicle's echo; without this flag no failsafe parameter is written",
    )
    p.add_argument(
        "--duration-s",
        type=float,
        default=None,
        help="mission length in seconds (default: the mission's run.duration_s)",
    )
    p.add_argument(
        "--vehicles",
        type=int,
        default=None,
        metavar="N",
        help="with --connect: start as soon as N vehicles are heard",
    )
    p.add_argument(
        "--discover-timeout-s",
        type=float,
        default=None,
        metavar="S",
        help="how long discovery waits: with no vehicle heard by then the flight is refused "
        "(exit 1, the reason in summary.json); with some, it starts with those heard "
        f"(default {FLY_DEFAULTS.discover_timeout_s:g} s)",
    )
    p.add_argument("--wave-size", type=int, default=25, help="vehicles per take-off wave")
    p.add_argument(
        "--battery",
        choices=["mission", "unlimited"],
        default="mission",
        help="the mission's batteries (default), or 'unlimited' to fly a mission with batteries "
        "as if they were endless (the reference for relay rotation, as sim --battery)",
    )
    p.add_argument(
        "--rotation",
        choices=["mission", "on", "off"],
        default="mission",
        help="relay rotation through the base as the mission says (default), 'on', or 'off': "
        "every drone flies until its firmware's low-battery failsafe (as sim --rotation)",
    )
    p.add_argument(
        "--swap-confirm",
        choices=("auto", "manual"),
        default=FLY_DEFAULTS.swap_confirm,
        help="who ends a battery swap on a pad (a mission with batteries): 'auto' (default) "
        "the station, when the vehicle comes back powered and full, or the ground crew first "
        "with the live page's Confirm; 'manual' only the ground crew (--serve, Confirm)",
    )
    p.add_argument(
        "--no-wait",
        action="store_true",
        help="do not wait for the vehicles to land after the end command",
    )
    p.add_argument(
        "--on-interrupt",
        choices=("end", "hold", "rtl", "land"),
        default="end",
        help="what Ctrl-C tells every vehicle the station reaches: 'end' (default) "
        "the --end action, 'hold' hover where it is (still under the station's "
        "link failsafes), 'rtl' or 'land'; the records are closed either way",
    )
    p.add_argument(
        "--keep-firmware-limits",
        action="store_true",
        help="do not write the mission's speed and climb limits into the vehicles "
        "(ArduPilot WPNAV_SPEED / WPNAV_SPEED_UP, PX4 MPC_XY_VEL_MAX / "
        "MPC_XY_CRUISE / MPC_Z_VEL_MAX_UP); by default they are set at launch "
        "and confirmed by the vehicle",
    )
    p.add_argument(
        "--restore-params",
        action="store_true",
        help="after landing, write back every parameter the station changed "
        "(speed limits, failsafes)",
    )

    from mission.commands.live_view import add_fly_arguments

    add_fly_arguments(p)  # --serve(-actions), --tiles, --forward(-readonly, -overrides)
    from mission.commands.tak_args import add_tak_arguments

    add_tak_arguments(p)  # --tak URL, --tak-period-s, --tak-tls-*


def _mission_path(spec: str):
    from pathlib import Path

    from mission.commands.options import UserError

    path = Path(spec)
    if not path.exists():
        from mission.format.examples import example_path, list_examples

        try:
            path = example_path(spec)
        except KeyError:
            raise UserError(
                f"{spec!r} is neither a mission file nor a shipped example "
                f"({', '.join(list_examples())})"
            ) from None
    return path


def _mission_spec(args) -> str:
    """The mission to fly: the MISSION argument or ``--mission`` (one, or both naming the same
    file), else the shipped 'wildfire'."""
    from mission.commands.options import UserError

    given, option = args.mission, args.mission_option
    if given is not None and option is not None and given != option:
        if _mission_path(given).resolve() != _mission_path(option).resolve():
            raise UserError(
                f"two missions given: {given!r} and --mission {option!r}; give one "
                "(--mission is the same as the MISSION argument)"
            )
    return option or given or "wildfire"


def _load(spec: str):
    from mission.commands.options import UserError
    from mission.format.load import MissionError, load_mission

    path = _mission_path(spec)
    try:
        mission = load_mission(path)
    except MissionError as exc:
        raise UserError(str(exc)) from None
    return mission


def _pct(x) -> str:
    return "  -  " if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:5.1f}%"


def _pct0(x) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.0f}%"


_PHASE_WORDS = {
    "discover": "finding",
    "audit": "checking",
    "launch": "take-off",
    "run": "flying",
    "end": "landing",
    "done": "done",
    "refused": "refused",
}


def _status_fields(d: dict) -> list[tuple[str, str]]:
    """The status line's fields as (group, text), in the order shown."""
    if d["phase"] == "run":
        t = f"{d['t_mission_s']:.0f}/{d['duration_s']:.0f}s"
    elif d["phase"] in ("end", "done") and d.get("end_t0_s") is not None:
        t = f"+{d['t_s'] - d['end_t0_s']:.0f}s"
    else:
        t = f"{d['t_s']:.0f}s"
    covered = "-" if d.get("tasks_covered") is None else d["tasks_covered"]
    n_tasks = "-" if d.get("n_tasks") is None else d["n_tasks"]
    fields = [
        ("phase", _PHASE_WORDS.get(d["phase"], d["phase"])),
        ("clock", t),
        ("drones", f"{d['fleet']} drones:"),
        ("net", f"{d['networked']} net"),
        ("lost", f"{d['lost']} lost"),
        ("home", f"{d['returning']} home"),
        ("crews", f"crews {covered}/{n_tasks}"),
        ("tu", f"TU1 {_pct0(d['tu1'])} TU2 {_pct0(d['tu2'])}"),
    ]
    rot = d.get("rotation")
    if rot:
        fields.append(("rotation", _rotation_field(rot)))
    if d.get("reclaims"):
        fields.append(("reclaimed", f"{d['reclaims']} reclaimed"))
    modes = " ".join(f"{k}:{v}" for k, v in sorted(d["modes"].items(), key=lambda kv: -kv[1]))
    if modes:
        fields.append(("modes", modes))
    return fields


def _rotation_field(rot: dict) -> str:
    """The relay rotation on the status line: rotations done, the lowest battery seen in the air,
    and, when there are any, battery failsafes in the air and vehicles landed away from the
    base."""
    text = f"rot {rot['rotations']} min {_pct0(rot['min_battery_in_air'])}"
    if rot.get("battery_failsafes_in_air"):
        text += f" {rot['battery_failsafes_in_air']} batt fs"
    if rot.get("landed_away"):
        text += f" {rot['landed_away']} away"
    return text


#: The order in which fields leave a status line too wide for the terminal: the lesser first
#: ("50 drones: 40 net" shortens to "40/50 net" before the crews leave); TU1/TU2 never leave.
#: The relay rotation (a mission with batteries, beside TU: "TU1 95% TU2 97% rot 12 min 31%")
#: stays on an 80-column line of a two-hour mission, once the drones lost and home have left.
STATUS_DROP_ORDER = (
    "modes",
    "reclaimed",
    "home",
    "lost",
    "drones",
    "rotation",
    "crews",
    "net",
    "clock",
    "phase",
)

#: How the fields are grouped into the line's parts (``a b | c d e | ...``).
_STATUS_PARTS = (
    ("phase", "clock"),
    ("drones", "net", "lost", "home"),
    ("crews",),
    ("tu", "rotation"),
)


def _status_line(fields: list[tuple[str, str]], dropped: int) -> str:
    gone = set(STATUS_DROP_ORDER[:dropped])
    text = dict(f for f in fields if f[0] not in gone)
    if "drones" in text and "net" not in text:
        del text["drones"]
    elif "drones" not in text and "net" in text:
        # "40 net" alone would not say of how many: "40/50 net"
        text["net"] = f"{text['net'].split()[0]}/{dict(fields)['drones'].split()[0]} net"
    parts = [" ".join(text[k] for k in part if k in text) for part in _STATUS_PARTS]
    parts += [text[k] for k in ("reclaimed", "modes") if k in text]
    return " | ".join(p for p in parts if p)


def status_layout(d: dict, width: int = 80, dropped: int = 0) -> tuple[str, int]:
    """(line, fields left out) for :func:`format_status`: the fullest line of at most
    ``width - 1`` columns leaving out at least ``dropped`` fields (:data:`STATUS_DROP_ORDER`)."""
    fields = _status_fields(d)
    for k in range(dropped, len(STATUS_DROP_ORDER) + 1):
        line = _status_line(fields, k)
        if len(line) <= width - 1:
            return line, k
    return line, len(STATUS_DROP_ORDER)  # TU1/TU2 alone, even if wider than the terminal


def planned_drop(d: dict, width: int = 80) -> int:
    """Fields to leave out for the whole run so that its widest plausible line fits ``width``:
    every count at the expected fleet (``fleet_expected``, else the fleet heard so far), every
    crew connected, TU at 100 %, the mission clock at its end, the longest phase word. Reclaims
    and modes, at the end of the line, are not planned for: they show while there is room."""
    n = max(d["fleet"], d.get("fleet_expected") or 0)
    n_tasks = d.get("n_tasks") or 0
    base = dict(d, fleet=n, networked=n, lost=n, returning=n, tasks_covered=n_tasks)
    base.update(tu1=1.0, tu2=1.0, reclaims=0, modes={})
    if d.get("rotation"):
        # Hundreds of rotations; the lowest battery in the air has two digits once anything flew
        # (100 % only before the take-off, when the clock is shorter); the failsafes and
        # landings away are not planned for: they show while there is room.
        base["rotation"] = dict(
            d["rotation"], rotations=999, min_battery_in_air=0.99, battery_failsafes_in_air=0
        )
        base["rotation"]["landed_away"] = 0
    widest = [
        dict(base, phase="run", t_mission_s=d["duration_s"]),
        dict(base, phase="launch", t_s=max(d["t_s"], 999.0)),
        dict(base, phase="end", end_t0_s=0.0, t_s=999.0),
    ]
    return max(status_layout(w, width)[1] for w in widest)


def format_status(d: dict, width: int = 80, dropped: int = 0) -> str:
    """One status line for people within ``width - 1`` columns: phase and its clock, drones by
    state, crews connected (``-/10`` until the first control tick measured them), TU so far,
    then reclaims and modes when there is room. One format from finding to the end: on a narrow
    terminal whole fields are left out, the lesser first (:data:`STATUS_DROP_ORDER`), never the
    TU figures; the wording and separators never change."""
    return status_layout(d, width, dropped)[0]


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
            out.append(
                f"FAILED to set {who}: {c['name']} {prev} -> {want:g}: "
                f"{c.get('reason') or 'no answer'}"
            )
    return out


class _Status:
    """The live status line (rewritten in place on a terminal, a line per phase change and every
    30 s otherwise) and warnings, each printed once on its own line above it, when the flight
    degrades: the emulation far slower than asked, command failures, failsafes reported by
    vehicles, rally points a vehicle does not hold."""

    def __init__(self, stream=sys.stderr) -> None:
        import shutil

        self.stream = stream
        self.tty = stream.isatty()
        self.columns = shutil.get_terminal_size((80, 24)).columns if self.tty else 80
        self.width = 0
        self.dropped = 0  # fields left out so far: once out, out for the rest of the run
        self.last_phase = None
        self.last_print_t = -math.inf
        self._failures_warned = 0
        self._failsafes_warned = 0
        self._rally_warned = 0
        self._battery_fs_warned = 0
        self._away_warned = 0
        self._slow_warned = False
        self._pace: list[tuple[float, float]] = []

    def _warn(self, text: str) -> None:
        if self.tty and self.width:
            self.stream.write("\r" + " " * self.width + "\r")
            self.width = 0
        self.stream.write(f"warning: {text}\n")

    def _warnings(self, d: dict) -> None:
        # Links going down / up are logged by gcs.aio (one line per change).
        n = d.get("command_failures", 0)
        if n >= max(5, 2 * self._failures_warned) and n > self._failures_warned:
            self._warn(
                f"{n} commands failed or went unanswered so far (a vehicle refusing, or "
                "a lossy link; -v shows which)"
            )
            self._failures_warned = n
        k = d.get("failsafes", 0)
        if k > self._failsafes_warned and d.get("last_failsafe"):
            t_s, (link_id, sysid), text = d["last_failsafe"]
            more = (
                f" (+{k - self._failsafes_warned - 1} more)"
                if k - self._failsafes_warned > 1
                else ""
            )
            self._warn(f'link {link_id} sysid {sysid} reports "{text}"{more}')
            self._failsafes_warned = k
        rot = d.get("rotation") or {}
        fs, away = rot.get("battery_failsafes_in_air", 0), rot.get("landed_away", 0)
        if fs > self._battery_fs_warned:
            self._warn(
                f"battery failsafe in the air ({fs} so far): a vehicle's firmware sent it home "
                "on its own, before the rotation relieved it"
            )
            self._battery_fs_warned = fs
        if away > self._away_warned:
            self._warn(f"{away} vehicle(s) landed away from the base (lost to the mission)")
            self._away_warned = away
        r = d.get("rally_failures", 0)
        if r > self._rally_warned and d.get("last_rally_failure"):
            t_s, (link_id, sysid), why = d["last_rally_failure"]
            more = f" (+{r - self._rally_warned - 1} more)" if r - self._rally_warned > 1 else ""
            self._warn(f"link {link_id} sysid {sysid}: {why}{more}")
            self._rally_warned = r
        want = d.get("speedup")
        if want and want > 1 and not self._slow_warned and d["phase"] == "run":
            self._pace.append((d["wall_s"], d["t_s"]))
            self._pace = [p for p in self._pace if d["wall_s"] - p[0] <= 10.0]
            w0, t0 = self._pace[0]
            if d["wall_s"] - w0 >= 5.0:
                got = (d["t_s"] - t0) / (d["wall_s"] - w0)
                if got < 0.5 * want:
                    self._warn(
                        f"running at {got:.1f}x instead of {want:g}x (this machine is "
                        "too busy or the fleet too large; timings stay correct, but "
                        "results move with the pace)"
                    )
                    self._slow_warned = True

    def __call__(self, d: dict) -> None:
        self._warnings(d)
        # Fields left out are planned for the widest line of the run, and a field left out
        # once stays out: the line keeps one look from finding to the end.
        self.dropped = max(self.dropped, planned_drop(d, self.columns))
        line, self.dropped = status_layout(d, self.columns, self.dropped)
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
            self.width = 0


def _header(mission, args, real: bool) -> str:
    """What this run flies, with the options that change it (never the mission's words alone)."""
    v = mission.vehicles
    if real:
        links = list(args.connect) or list(v.real.connections if v.real else [])
        fleet = f"real vehicles on {len(links)} link(s)" + (
            f", starting with the first {args.vehicles} heard" if args.vehicles else ""
        )
        speed = f"vehicle clock x{args.speedup:g} (SITL)" if args.speedup else "vehicle clock (1x)"
    else:
        pers = args.personality or v.emulated.personality
        fleet = f"{v.emulated.count} emulated {pers} drones"
        speed = f"{args.speedup or mission.run.speedup:g}x real time"
    duration = args.duration_s or mission.run.duration_s
    return (
        f"{mission.name}: {fleet}; {mission.n_tasks} crews/tasks; planner "
        f"{mission.planner.method}; {duration:g} s of mission at {speed}"
    )


_EXPLAIN = (
    "TU1: the share of crews connected to the base through the drones, averaged over "
    "the mission.\nTU2: the same, counting at each moment only the crews the swarm had "
    "already reached once\n     (so the time to first reach a crew is not held against "
    "it). 100 % = always connected."
)


def _secs(x: float) -> str:
    """Seconds for people: whole when they are ("200"), else to a tenth ("107.6")."""
    return f"{x:.1f}".removesuffix(".0")


def format_pace(s: dict) -> list[str]:
    """How long the flight took, from ``summary.json``: the mission seconds flown over the wall
    seconds printed beside them, and the pace the mission itself was flown at (start-up,
    take-off and landing are in the wall time, not in the mission seconds)."""
    span, wall = s["mission_s_flown"], round(s["wall_s"], 1)
    # The ratio of the two numbers printed beside it, so that a reader's division agrees.
    overall = f"{span / wall:.1f}x" if wall > 0 else "-"
    line = f"flown {_secs(span)} s of mission in {wall:.1f} s wall ({overall} overall"
    if s.get("speedup_achieved") is not None:
        line += (
            f"; the mission itself ran at {s['speedup_achieved']:.1f}x, "
            f"{s['speedup_requested']:g}x asked"
        )
    return [line + ")"]


def slow_pace_warning(s: dict) -> str:
    """The warning when the mission ran at under half the speed-up asked (``speedup_slow``)."""
    return (
        f"the mission ran at {s['speedup_achieved']:.1f}x, under half the "
        f"{s['speedup_requested']:g}x asked (this machine was too busy or the fleet too large). "
        "The vehicles' timings stay correct, but results such as reclaims and TU move with "
        "the pace: compare runs flown at similar speed-ups (summary.json speedup_achieved), "
        "or ask for less (--speedup)"
    )


def format_tu(s: dict) -> list[str]:
    """TU1/TU2 as the station saw them and from the truth, both over the span flown (all of the
    mission, or up to Ctrl-C), saying which."""
    st = s["station"]
    span, duration = s["flown_span_s"], s["duration_s"]
    lines = [
        f"TU1/TU2 as the station saw them:     {_pct(st['tu1'])} / {_pct(st['tu2'])}"
        f"   ({st['ticks']} control ticks)"
    ]
    if "truth" in s:
        tr = s["truth"]
        lines.append(
            f"TU1/TU2 from the emulator's truth:   {_pct(tr['tu1'])} / {_pct(tr['tu2'])}"
            f"   ({tr['samples']} samples; {tr['alive_end']} vehicles alive at the end)"
        )
        emu = s.get("emulator") or {}
        if "least_agl_m" in emu:  # over terrain (docs/terrain.md §6)
            least, most = emu["least_agl_m"], emu.get("highest_agl_m")
            lines.append(
                f"over the terrain: {int(emu.get('terrain_crashes', 0))} crashes into the ground; "
                f"during the mission least height above it "
                f"{'-' if least is None else f'{least:.1f} m'}, highest "
                f"{'-' if most is None else f'{most:.0f} m'}"
            )
    terrain = s.get("terrain")
    if terrain is not None and terrain["reports"]:
        reps = terrain["reports"]
        loaded = [r for r in reps if r["pending"] == 0 and r["loaded"] > 0]
        lines.append(
            f"terrain served to the vehicles: {terrain['requests_answered']} TERRAIN_REQUEST "
            f"answered with {terrain['terrain_data_sent']} TERRAIN_DATA; "
            f"{len(loaded)} of {len(reps)} vehicles last reported their terrain loaded "
            "(pending 0)"
        )
    both = "both" if "truth" in s else "TU"
    if span >= duration - 1e-6:
        lines.append(f"{both} over the whole {_secs(duration)} s mission")
    elif s.get("interrupted") is not None:
        lines.append(
            f"{both} over the first {_secs(span)} s, flown before the interrupt "
            f"(of the {_secs(duration)} s mission)"
        )
    else:
        lines.append(
            f"{both} over the first {_secs(span)} s of the {_secs(duration)} s mission, "
            "where it stopped"
        )
    return lines


def format_rotation(e: dict) -> str:
    """The closing summary's relay rotation (``summary.json`` ``endurance``): the line ``sim``
    prints per seed, and the swaps with who confirmed them (docs/design/endurance.md §8)."""
    from mission.commands.options import endurance_line

    crew = e.get("swaps_confirmed_by_crew", 0)
    how = f"{e.get('swap_confirm', 'auto')} confirmation"
    if crew:
        how += f", {crew} confirmed by the ground crew"
    return f"relay rotation: {endurance_line(e)}; {e['swaps']} battery swaps ({how})"


def _group_report(items: list[dict], per_line: int = 12) -> list[str]:
    """One line per vehicle for small fleets; for large ones, one line per kind of answer
    (``told RTL; now RTL``, ``not heard``...) with the vehicles it applies to."""
    if len(items) <= per_line:
        return [f"link {i['link_id']} sysid {i['sysid']}: {i['state']}" for i in items]
    groups: dict[str, list[str]] = {}
    for i in items:
        kind = (
            i["state"].split("; last mode")[0] + ")"
            if "; last mode" in i["state"]
            else i["state"].split(" (mode")[0]
            if not i["confirmed"]
            else i["state"]
        )
        groups.setdefault(kind, []).append(f"{i['link_id']}:{i['sysid']}")
    out = []
    for kind, who in groups.items():
        shown = ", ".join(who[:per_line]) + (
            f" +{len(who) - per_line} more" if len(who) > per_line else ""
        )
        out.append(f"{len(who)} vehicle(s) {kind} [link:sysid {shown}]")
    return out


def run(args) -> int:
    from mission.commands.options import UserError
    from mission.flight.runners import FlyOptions, RunnerError, fly

    mission = _load(_mission_spec(args))
    if args.speedup is not None and not args.speedup > 0:
        raise UserError(f"--speedup must be > 0, got {args.speedup}")
    if args.duration_s is not None and not args.duration_s > 0:
        raise UserError(f"--duration-s must be > 0, got {args.duration_s}")
    if args.wave_size < 1:
        raise UserError("--wave-size must be >= 1")
    real = bool(args.connect) or mission.vehicles.real is not None
    if real and args.personality:
        raise UserError(
            "--personality applies to emulated vehicles only; real vehicles "
            "report their own autopilot"
        )
    if not real and args.vehicles is not None:
        raise UserError(
            "--vehicles applies to real links (--connect); the emulated fleet size "
            "is the mission's vehicles.emulated.count"
        )
    if args.vehicles is not None and args.vehicles < 1:
        raise UserError(f"--vehicles must be >= 1, got {args.vehicles}")
    if args.discover_timeout_s is not None and not args.discover_timeout_s > 0:
        raise UserError(f"--discover-timeout-s must be > 0, got {args.discover_timeout_s}")
    if args.connect:
        from gcs.connection import parse_connection

        for c in args.connect:
            try:
                parse_connection(c)
            except ValueError as exc:
                raise UserError(f"--connect {c!r}: {exc}") from None
    from mission.commands.options import writable_dir

    # Before the emulator starts or any link opens: a flight must not fail on its records.
    writable_dir(args.out or mission.output.dir, "--out" if args.out else "output.dir")
    status = _Status()
    opts = FlyOptions(
        seed=args.seed,
        personality=args.personality,
        speedup=args.speedup,
        duration_s=args.duration_s,
        out_dir=args.out,
        end=args.end,
        override_audit=args.override_audit,
        apply_failsafes=args.apply_failsafes,
        connections=tuple(args.connect),
        wave_size=args.wave_size,
        status=status,
        expected_vehicles=args.vehicles,
        end_wait=not args.no_wait,
        set_limits=not args.keep_firmware_limits,
        restore_params=args.restore_params,
        on_interrupt=args.on_interrupt,
        battery=args.battery,
        rotation=args.rotation,
        swap_confirm=args.swap_confirm,
    )
    if args.discover_timeout_s is not None:
        opts.discover_timeout_s = args.discover_timeout_s
    from mission.commands.live_view import fly_options

    opts = fly_options(opts, args)  # --serve / --forward (mission.view.live)
    from mission.commands.tak_args import tak_options

    opts = tak_options(opts, args)  # --tak (mission.view.tak)
    print(_header(mission, args, real), file=sys.stderr)
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
    for line in op.limit_warnings:
        print(f"warning: {line}", file=sys.stderr)
    for late in op.late_audit_summary():  # discovered after the fleet audit, audited alone
        if late["verdict"] in ("refused", "pending"):
            print(
                f"warning: link {late['link_id']} sysid {late['sysid']}, discovered after the "
                f"pre-flight audit, was kept on the ground ({late['verdict']}"
                + (f": {'; '.join(late['blocking'])}" if late["blocking"] else "")
                + ")",
                file=sys.stderr,
            )
    if op.prearm:
        print(
            f"{len(op.prearm)} vehicle(s) refused to arm at first (not ready); last reason:",
            file=sys.stderr,
        )
        for (link_id, sysid), (t_s, text) in sorted(op.prearm.items()):
            print(f"  link {link_id} sysid {sysid} at t={t_s:.0f} s: {text}", file=sys.stderr)
    if s["phase"] == "refused":
        if op.audit_report is not None and not op.audit_report.cleared_to_fly:
            print(op.audit_report.summary(), file=sys.stderr)
            hint = "" if args.apply_failsafes else " (--apply-failsafes writes the fixable ones)"
            print(
                f"phireman fly: the pre-flight audit refused the flight (see above); fix the "
                f"parameters{hint} or pass --override-audit. Run directory: {result.run_dir}",
                file=sys.stderr,
            )
        elif not s["vehicles_discovered"] and real:
            print(_nothing_heard(op.refusal, result.run_dir), file=sys.stderr)
        else:
            print(
                f"phireman fly: refused to launch: {op.refusal or 'unknown reason'}. "
                f"Run directory: {result.run_dir}",
                file=sys.stderr,
            )
        return 1
    if op.interrupted is not None and not s.get("interrupt_report"):
        print("interrupted before any vehicle was heard: nothing was commanded", file=sys.stderr)
    elif op.interrupted is not None:
        print(
            f"interrupted: every vehicle the station reached was told to "
            f"{op.interrupted if op.interrupted != 'end' else args.end.upper()}:",
            file=sys.stderr,
        )
        for line in _group_report(s.get("interrupt_report") or []):
            print(f"  {line}", file=sys.stderr)
    print(f"run directory: {result.run_dir}")
    for line in format_pace(s):
        print(line)
    n_rec = s["reclaimed"]
    print(
        f"{s['vehicles_discovered']} vehicles; {n_rec} reclaim{'s' if n_rec != 1 else ''} "
        "(a vehicle back from its own failsafe, taken into the plan again)"
    )
    refused: dict[int, int] = {}
    for link in s.get("links", []):
        for sysid, n in (link.get("refused_by_sysid") or {}).items():
            refused[int(sysid)] = refused.get(int(sysid), 0) + n
    if refused:
        who = ", ".join(f"{k} ({v})" for k, v in sorted(refused.items())[:8])
        more = f" and {len(refused) - 8} more" if len(refused) > 8 else ""
        print(
            f"ignored {sum(refused.values())} frame(s) from {len(refused)} system(s) that are "
            f"not this mission's vehicles: sysid (frames) {who}{more}"
        )
    bad = sum(link.get("bad_data", 0) for link in s.get("links", []))
    if bad:
        print(f"{bad} corrupt or unsigned frame(s) were dropped")
    end = s.get("end_status")
    if end and end.get("in_air"):
        print(
            f"{end['in_air']} vehicle(s) still in the air when the station stopped "
            "(returning on their own)"
        )
    for line in format_tu(s):
        print(line)
    if s.get("endurance"):
        print(format_rotation(s["endurance"]))
    if s.get("speedup_slow"):
        import textwrap

        warning = textwrap.fill(f"warning: {slow_pace_warning(s)}", 79, subsequent_indent="  ")
        print(warning, file=sys.stderr)
    print(_EXPLAIN)
    if op.interrupted is None:
        return 0
    return 143 if s.get("stopped_by") == "SIGTERM" else 130


def _nothing_heard(refusal: str | None, run_dir) -> str:
    """Why a real flight heard nobody: what was tried (in ``refusal``) and the usual causes."""
    return (
        f"phireman fly: {refusal or 'no vehicle heard'}. Usual causes:\n"
        "  - a wrong address or port (SITL: tcp:127.0.0.1:5760 for the first ArduCopter, "
        "udpin:0.0.0.0:14550 for a vehicle that sends to 14550; 'phireman sitl --print-fly' "
        "prints the right --connect)\n"
        "  - udpin vs udpout: udpin:H:P waits for vehicles that send to port P; udpout:H:P "
        "sends first, to a vehicle listening on P\n"
        "  - a firewall dropping the MAVLink traffic (UDP gives no error for it)\n"
        "  - the autopilot, SITL or 'phireman emulate' not started (yet): start it first, or "
        "wait longer with --discover-timeout-s\n"
        f"Run directory: {run_dir} (summary.json says why)"
    )

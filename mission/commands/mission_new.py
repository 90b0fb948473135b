"""``phireman mission new|show|list``: write the paper's configurations as missions, show missions."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from mission.commands.options import UserError, parse_rate, writable_file

HELP = "write the paper's configurations as mission files (new), show or list missions"
DESCRIPTION = """\
  phireman mission new --preset S --attrition 0.01 --unit-m 50 > m.yaml
      The paper's configuration (Table III, docs/design/model.md §5.5/§6.1) as a mission in SI units.
      One paper length unit becomes --unit-m metres and one paper step --step-s seconds; the
      per-step attrition p becomes rate_per_s = -ln(1 - p) / step_s. The file's header explains
      every conversion.
  phireman mission show MISSION
      The mission with every default filled in, as YAML.
  phireman mission list
      The shipped example missions (usable by name wherever a mission file is expected).
"""

SIZES = ("XS", "S", "M", "L", "XL")


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="mission_command", metavar="SUBCOMMAND")
    new = sub.add_parser(
        "new",
        help="write a paper configuration as a mission",
        description="Write the paper's configuration as a mission in SI units.",
    )
    new.add_argument(
        "--preset",
        default="S",
        type=str.upper,
        choices=SIZES,
        help="problem size from Table III (default: S)",
    )
    new.add_argument(
        "--attrition",
        default="0.01",
        metavar="P",
        help="per-drone, per-step loss probability in [0, 1), 0.01 or 1%% (default: 0.01 = 1 %%)",
    )
    new.add_argument(
        "--unit-m",
        type=float,
        default=50.0,
        metavar="M",
        help="metres per paper length unit (default: 50)",
    )
    new.add_argument(
        "--reading",
        choices=("scaled", "literal"),
        default="scaled",
        help="scaled: every length x half-width/5 (default); literal: lengths as printed",
    )
    new.add_argument(
        "--step-s",
        type=float,
        default=1.0,
        metavar="S",
        help="seconds per paper step = control period (default: 1)",
    )
    new.add_argument("--seed", type=int, default=0, help="run seed (default: 0)")
    new.add_argument("--out", metavar="FILE", help="write here instead of stdout")
    new.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    new.set_defaults(_mission_run=_run_new)

    show = sub.add_parser("show", help="print a mission with every default filled in")
    show.add_argument(
        "mission", metavar="MISSION", help="mission YAML file or shipped example name"
    )
    show.set_defaults(_mission_run=_run_show)

    lst = sub.add_parser("list", help="list the shipped example missions")
    lst.set_defaults(_mission_run=_run_list)


def run(args) -> int:
    handler = getattr(args, "_mission_run", None)
    if handler is None:
        raise UserError(
            "missing subcommand: one of new, show, list (see 'phireman mission --help')"
        )
    return handler(args)


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def header_for(args, size: str, half_width_units: float) -> str:
    """The comment block that explains how the paper's units became metres and seconds."""
    L, dt, p = args.unit_m, args.step_s, args.attrition
    scale = half_width_units / 5.0 if args.reading == "scaled" else 1.0
    u = L * scale  # metres per printed paper unit, after the scaled reading
    rate = -math.log1p(-p) / dt
    cmd = (
        f"phireman mission new --preset {size} --attrition {_fmt(p)} --unit-m {_fmt(L)} "
        f"--reading {args.reading} --step-s {_fmt(dt)} --seed {args.seed}"
    )
    hw = _fmt(half_width_units)
    rows = [
        (
            "1 paper length unit",
            f"= {_fmt(L)} m"
            + (
                f" x {_fmt(scale)} (scaled reading: half-width {hw} / 5) = {_fmt(u)} m"
                if scale != 1
                else ""
            ),
        ),
        ("1 paper step", f"= {_fmt(dt)} s = run.control_period_s"),
        ("200 steps", f"-> run.duration_s = {_fmt(200 * dt)}"),
        ("radio r = 2, R = 2", f"-> radio.range_m = radio.base_range_m = {_fmt(2 * u)}"),
        (
            "speed v = 0.15/step",
            f"-> vehicles.emulated.max_speed_m_s = 0.15 x {_fmt(u)} / {_fmt(dt)}"
            f" = {_fmt(0.15 * u / dt)}",
        ),
        ("ring 1, noise 0.2", f"-> spawn.ring.radius_m = {_fmt(u)}, noise_m = {_fmt(0.2 * u)}"),
        (
            f"field [-{hw}, {hw}]^2",
            f"-> tasks[0].random.field_half_width_m = {_fmt(half_width_units * L)}",
        ),
        (
            "walk sigma 0.1/step",
            f"-> sigma_m_per_sqrt_s = 0.1 x {_fmt(u)} / sqrt({_fmt(dt)})"
            f" = {_fmt(0.1 * u / math.sqrt(dt))}, border clip",
        ),
        (
            f"attrition p = {_fmt(p)}",
            f"-> attrition.rate_per_s = -ln(1 - p) / control_period_s = {rate:.6g}",
        ),
    ]
    table = "\n".join(f"  {left:<22}{right}" for left, right in rows)
    return (
        f"PhiIREMAN / RTNUA paper configuration {size} (Table III), {args.reading} reading, "
        f"attrition {_fmt(p * 100)} % per step.\n"
        f"Generated by: {cmd}\n\n"
        "How the paper's dimensionless model maps to this file (SI units):\n"
        f"{table}\n"
        "Not in the paper's 2-D model: flight layers (cruise_alt_m, layer_spacing_m), climb rate,\n"
        "radio latency and loss (0 here), and the origin (the ArduPilot SITL home by default).\n"
    )


def _run_new(args) -> int:
    from planner.problem import SIZES as PAPER_SIZES

    from mission.format.load import MissionError, dump_mission, validate_mission
    from mission.format.schema import paper_mission

    args.attrition = parse_rate(args.attrition)
    if not 0.0 <= args.attrition < 1.0:
        raise UserError(
            f"--attrition must be a per-step probability in [0, 1), got {args.attrition}"
        )
    if not (args.unit_m > 0 and math.isfinite(args.unit_m)):
        raise UserError(f"--unit-m must be a positive number of metres, got {args.unit_m}")
    if not (args.step_s > 0 and math.isfinite(args.step_s)):
        raise UserError(f"--step-s must be a positive number of seconds, got {args.step_s}")
    if args.seed < 0:
        raise UserError(f"--seed must be >= 0, got {args.seed}")
    try:
        mission = validate_mission(
            paper_mission(
                args.preset, args.attrition, args.unit_m, args.reading, args.step_s, args.seed
            )
        )
    except (ValueError, MissionError) as exc:
        raise UserError(f"cannot build this configuration: {exc}") from None
    text = dump_mission(mission, header=header_for(args, args.preset, PAPER_SIZES[args.preset][2]))
    if args.out:
        out = Path(args.out)
        if out.exists() and not args.force:
            raise UserError(f"{out} exists; use --force to overwrite")
        writable_file(out, "--out")
        out.write_text(text, encoding="utf-8")  # an OSError now: one line (mission.cli.main)
        print(f"wrote {out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def _run_show(args) -> int:
    from mission.commands.check import resolve_mission_path
    from mission.format.load import MissionError, dump_mission, load_mission

    path = resolve_mission_path(args.mission)
    try:
        mission = load_mission(path)
    except MissionError as exc:
        for line in exc.errors:
            print(f"{path}: {line}" if not line.startswith(f"{path}:") else line, file=sys.stderr)
        return 2
    sys.stdout.write(
        dump_mission(mission, header=f"{path} with every default filled in\n{mission.summary()}")
    )
    return 0


def _run_list(args) -> int:
    from mission.format.examples import example_path, list_examples
    from mission.format.load import load_mission

    for name in list_examples():
        try:
            line = load_mission(example_path(name)).summary()
        except Exception as exc:  # noqa: BLE001 - a broken example must not hide the others
            line = f"INVALID ({type(exc).__name__})"
        print(f"{name:22s} {line}")
    return 0

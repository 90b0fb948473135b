"""The ``phireman`` command line.

Each subcommand lives in ``mission/commands/<name>.py`` and exposes ``HELP`` (one line),
``DESCRIPTION`` (the long ``--help`` text), ``add_arguments(parser)`` and ``run(args) -> int``.
Modules are imported lazily so that ``phireman check`` does not pay for importing the planner.

Exit status: 0 success, 1 runtime failure, 2 bad input (the user's mistake; no traceback).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from mission.commands.options import (
    UserError,
    add_seed_arguments,
    add_workers_argument,
    default_workers,
    did_you_mean,
    parse_rate,
    positive_int,
    rate_arg,
    resolve_workers,
)

__all__ = [
    "main",
    "UserError",
    "COMMANDS",
    "parse_rate",
    "rate_arg",
    "positive_int",
    "add_workers_argument",
    "resolve_workers",
    "add_seed_arguments",
    "version_string",
    "did_you_mean",
    "default_workers",
]

#: subcommand name -> module under mission.commands (order = order in --help).
COMMANDS: dict[str, str] = {
    "fly": "fly",
    "sim": "sim",
    "sweep": "sweep",
    "report": "report",
    "tune": "tune",
    "emulate": "emulate",
    "check": "check",
    "mission": "mission_new",
    "replay": "replay",
    "sitl": "sitl",
}


def version_string() -> str:
    """The code version (:func:`mission.format.version.code_version`, as store rows and run directories
    record it): 'phireman 0.1.0 git 29588b621a73[+dirty] src 484d1b5b63d6'."""
    from mission.format.version import code_version

    return code_version()


def _load(name: str):
    return importlib.import_module(f"mission.commands.{COMMANDS[name]}")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="phireman",
        description=(
            "Keep tasks (fire crews, rovers) networked to a base station with a drone relay swarm "
            "that survives attrition. Simulate the paper's RTNUA problem, reproduce its evaluation, "
            "emulate MAVLink vehicles, and fly PhiIREMAN from a ground station."
        ),
        epilog="Run 'phireman COMMAND --help' for the options of one command.",
    )
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more log output (-v info, -vv debug)"
    )
    parser.add_argument(
        "--version", action="store_true", help="print the version (package and git) and exit"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        if only is not None and name != only:
            # Cheap placeholder so the top-level help lists every command without importing it.
            sub.add_parser(name, add_help=False)
            continue
        try:
            module = _load(name)
        except ModuleNotFoundError as exc:  # a command not built yet must not break the others
            if exc.name and exc.name.startswith("mission.commands"):
                continue
            raise
        p = sub.add_parser(
            name,
            help=module.HELP.replace("%", "%%"),
            description=module.DESCRIPTION,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    # Parallelism here is over runs (worker processes); BLAS threads on top would oversubscribe
    # the cores. Set before NumPy is first imported (commands import it lazily); users may override.
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    argv = list(sys.argv[1:] if argv is None else argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(only=first if first in COMMANDS else None)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=[logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)],
        format="%(levelname)s %(name)s: %(message)s",
    )
    if args.version:
        print(version_string())
        return 0
    module = getattr(args, "_module", None)
    if module is None:
        parser.print_help()
        return 0 if args.command is None else 2
    try:
        return int(module.run(args) or 0)
    except UserError as exc:
        print(f"phireman {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"phireman {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    # `python -m mission.cli` runs this file as __main__, a second copy of this module; UserError
    # is defined once, in mission.commands.options, so both copies catch the commands' errors.
    sys.exit(main())

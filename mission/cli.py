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
import pathlib
import sys

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
    "writable_dir",
    "writable_file",
    "os_error_text",
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


class UserError(Exception):
    """A mistake in the user's input: printed as one clear message, exit status 2, no traceback."""


# ----------------------------------------------------------------------------------------------
# One parser / one default for the options several commands share
# ----------------------------------------------------------------------------------------------


def parse_rate(text: str, option: str = "--attrition") -> float:
    """A probability given as a fraction (``0.01``) or a percent (``1%``): the one rate parser.

    Raises
    ------
    UserError
        Not a number, or outside [0, 1].
    """
    t = str(text).strip()
    try:
        value = float(t[:-1]) / 100 if t.endswith("%") else float(t)
    except ValueError:
        raise UserError(
            f"{option}: expected a fraction like 0.01 or a percent like 1%, got {text!r}"
        ) from None
    if not 0.0 <= value <= 1.0:
        raise UserError(f"{option}: {text} is not a probability in [0, 1] (0.01 = 1%)")
    return value


def rate_arg(text: str) -> float:
    """argparse ``type=`` for a single rate (0.01 or 1%)."""
    try:
        return parse_rate(text)
    except UserError as exc:
        raise argparse.ArgumentTypeError(str(exc).split(": ", 1)[-1]) from None


def positive_int(text: str) -> int:
    """argparse ``type=`` for a count that must be >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def default_workers() -> int:
    """The one default for --workers everywhere: the cores of this machine, at most 8."""
    return max(1, min(os.cpu_count() or 1, 8))


def add_workers_argument(p: argparse.ArgumentParser, what: str = "worker processes") -> None:
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        metavar="N",
        help=f"{what} (default: the number of cores, at most 8; here {default_workers()})",
    )


def resolve_workers(n: int | None) -> int:
    return default_workers() if n is None else int(n)


def add_seed_arguments(
    p: argparse.ArgumentParser, seeds_default: int | None, seeds_help: str
) -> None:
    """``--seed S`` (the first run's seed, as in ``phireman fly``; alias ``--seed-start``) and ``--seeds N``."""
    p.add_argument(
        "--seed",
        "--seed-start",
        dest="seed",
        type=int,
        default=None,
        metavar="S",
        help="seed of the first run (default 0; --seed-start is an alias); runs use S, S+1, ...",
    )
    p.add_argument(
        "--seeds", type=positive_int, default=seeds_default, metavar="N", help=seeds_help
    )


# ----------------------------------------------------------------------------------------------
# Output locations: checked before any work starts (one place for every command)
# ----------------------------------------------------------------------------------------------


def os_error_text(exc: OSError) -> str:
    """'Permission denied', or 'Not a directory: /a/file' when the failing path is another one."""
    text = exc.strerror or str(exc)
    return f"{text}: {exc.filename}" if exc.filename else text


def _dir_problem(p: pathlib.Path) -> str | None:
    """Why ``p`` cannot receive files, or None. Creates ``p`` (and its parents) if missing, then
    creates and removes a probe file in it (the only test that holds for root, ACLs and
    read-only mounts alike)."""
    import tempfile

    for parent in (p, *p.parents):  # the nearest existing one: a file there is the usual slip
        if parent.exists():
            if not parent.is_dir():
                return f"{parent} is a file, not a directory"
            break
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return os_error_text(exc)
    try:
        with tempfile.TemporaryFile(dir=p, prefix=".phireman-probe-"):
            pass
    except OSError as exc:
        return exc.strerror or str(exc)  # not the probe's random name
    return None


def writable_dir(path: str | os.PathLike, option: str = "--out") -> pathlib.Path:
    """Make sure the directory ``path`` can receive a command's outputs, before the work starts.

    Creates it (and its parents) if missing and writes (then removes) a probe file in it: a
    read-only file system, a missing permission or a parent that is a file fail here, at once,
    rather than after a long simulation or once a flight is under way.

    Raises
    ------
    UserError
        One line naming ``option``, the path and the reason.
    """
    p = pathlib.Path(path)
    problem = _dir_problem(p)
    if problem is not None:
        raise UserError(f"{option} {p}: cannot write there ({problem})")
    return p


def writable_file(
    path: str | os.PathLike, option: str, example_name: str | None = None
) -> pathlib.Path:
    """Make sure the file ``path`` can be written (created or replaced), before the work starts:
    its directory passes the same probe as :func:`writable_dir` and the file, if it exists, is a
    writable file. ``example_name``: a file name to suggest when ``path`` is a directory.

    Raises
    ------
    UserError
        One line naming ``option``, the path and the reason.
    """
    p = pathlib.Path(path)
    if p.is_dir():
        hint = f", e.g. {p / example_name}" if example_name else ""
        raise UserError(f"{option} {p}: is a directory; give a file{hint}")
    problem = _dir_problem(p.parent)
    if problem is None and p.exists() and not os.access(p, os.W_OK):
        problem = "Permission denied"
    if problem is not None:
        raise UserError(f"{option} {p}: cannot write there ({problem})")
    return p


def did_you_mean(word: str, choices) -> str:
    """' (did you mean X?)' for the closest of ``choices``, or ''."""
    import difflib

    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else ""


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
    except OSError as exc:
        if exc.filename is None:  # not a file (a socket, a process): a bug or the machine's
            raise
        # Writing (or reading) a file failed mid-run: a full disk, a directory removed or made
        # read-only after the up-front check (writable_dir). One line with the path, no traceback
        # (-vv logs it).
        logging.getLogger(__name__).debug("file error", exc_info=True)
        print(f"phireman {args.command}: error: {os_error_text(exc)}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    # `python -m mission.cli` runs this file as __main__; the commands import their errors from
    # mission.cli, so run *that* module's main (else UserError would be two classes and a user's
    # mistake would print a traceback).
    from mission.cli import main as _main

    sys.exit(_main())

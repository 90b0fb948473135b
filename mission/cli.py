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
import re
import sys
import textwrap

from mission.commands.options import (
    os_error_text,
    writable_dir,
    writable_file,
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
    "writable_dir",
    "writable_file",
    "os_error_text",
    "fit_text",
    "HelpFormatter",
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


# ----------------------------------------------------------------------------------------------
# Help pages that fit the terminal
# ----------------------------------------------------------------------------------------------

_TERM = re.compile(r"^(\s*)(\S.*?)\s{2,}(?=\S)")


def _indent_of(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def _wrap(text: str, width: int, first: str, rest: str) -> list[str]:
    """``text`` filled to ``width`` columns: the first line after ``first``, the others after
    ``rest`` (a word longer than a line stays whole rather than being cut)."""
    return textwrap.wrap(
        " ".join(text.split()),
        width=max(width, len(first) + 20),
        initial_indent=first,
        subsequent_indent=rest,
        break_long_words=False,
        break_on_hyphens=False,
    ) or [first.rstrip()]


def _fit_command(lines: list[str], width: int) -> list[str]:
    """An example command (``  phireman ... # what it does``, maybe already continued with
    ``\\``) too wide: cut before an option (an option stays with its values) with a shell
    continuation, so what is shown can still be pasted into a shell; a comment that no longer
    fits beside it goes on its own line below."""
    ind = " " * _indent_of(lines[0])
    comment = ""
    words: list[str] = []
    for raw in lines:
        body = raw.strip()
        m = re.search(r"\s{2,}#\s*", body)
        if m:
            body, comment = body[: m.start()], body[m.end() :]
        words += body.removesuffix("\\").split()
    groups: list[str] = []
    for w in words:  # "--size XS S" is one group: never cut between an option and its values
        if groups and not w.startswith("-") and groups[-1].startswith("-"):
            groups[-1] += " " + w
        else:
            groups.append(w)
    out: list[str] = []
    cur = ind
    for g in groups:
        if cur.strip() and len(cur) + 1 + len(g) + 2 > width:
            out.append(cur + " \\")
            cur = ind + "    " + g
        else:
            cur = cur + (" " if cur.strip() else "") + g
    if comment and len(cur) + 4 + len(comment) <= width:
        return [*out, f"{cur}  # {comment}"]
    out.append(cur)
    if comment:
        out += _wrap(comment, width, ind + "    # ", ind + "      ")
    return out


def _fit_item(head: str, body: list[str], width: int) -> list[str]:
    """One indented item (a head line and its deeper continuation lines) within ``width``."""
    if all(len(x) <= width for x in (head, *body)):
        return [head, *body]  # fits: keep the author's layout
    ind = _indent_of(head)
    if head[ind:].startswith("phireman "):
        if head.rstrip().endswith("\\"):  # the command goes on in the lines below
            return _fit_command([head, *body], width)
        out = _fit_command([head], width)
        if body:
            b = _indent_of(body[0])
            out += _wrap(" ".join(body), width, " " * b, " " * b)
        return out
    hang = _indent_of(body[0]) if body else None
    if hang is None:
        m = _TERM.match(head)
        hang = m.end() if m else None
    if hang is not None and hang < len(head) and head[hang - 1] == " " and hang <= width // 2:
        # A definition ("  term     what it is", continued under "what it is").
        return _wrap(" ".join([head[hang:], *body]), width, head[:hang], " " * hang)
    out = _wrap(head, width, " " * ind, " " * (ind + 4))
    if body:
        b = _indent_of(body[0])
        out += _wrap(" ".join(body), width, " " * b, " " * b)
    return out


def fit_text(text: str, width: int) -> str:
    """A hand-laid-out help text (a command's DESCRIPTION or epilog) fitted to ``width``
    columns, keeping the author's layout wherever it already fits.

    * Unindented lines are prose: a paragraph with a line too wide is filled again.
    * An indented line and the deeper-indented lines under it are one item: a definition
      (``  report.md    what it holds``) is filled under its text column, an example command
      (``  phireman ...  # comment``) is cut with shell continuations and its comment moved below.
    """
    out: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i].rstrip()
        if not line.strip():
            out.append("")
            i += 1
            continue
        if _indent_of(line) == 0:
            j = i + 1
            while j < len(lines) and lines[j].strip() and _indent_of(lines[j]) == 0:
                j += 1
            para = [x.rstrip() for x in lines[i:j]]
            if any(len(x) > width for x in para):
                out += _wrap(" ".join(para), width, "", "")
            else:
                out += para
            i = j
            continue
        ind = _indent_of(line)
        j = i + 1
        while j < len(lines) and lines[j].strip() and _indent_of(lines[j]) > ind:
            j += 1
        out += _fit_item(line, [x.rstrip() for x in lines[i + 1 : j]], width)
        i = j
    return "\n".join(out) + ("\n" if text.endswith("\n") else "")


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Every command's ``--help``: argparse's own layout for the options, and the hand-laid-out
    description and epilog fitted to the terminal (:func:`fit_text`; ``COLUMNS`` when not a
    terminal, as argparse does)."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "".join(indent + line for line in fit_text(text, width).splitlines(keepends=True))


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="phireman",
        formatter_class=HelpFormatter,
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
            formatter_class=HelpFormatter,
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
    # `python -m mission.cli` runs this file as __main__, a second copy of this module; UserError
    # is defined once, in mission.commands.options, so both copies catch the commands' errors.
    sys.exit(main())

"""What the subcommands share: the user's-mistake error and one parser / one default for the
options several commands take.

It sits below every ``mission/commands/*.py`` and below :mod:`mission.cli`, which loads the
commands by name and re-exports these: a command imports them from here, never from the CLI that
imports it (no circle of modules, ``tests/test_layering.py``).
"""

from __future__ import annotations

import argparse
import os
import pathlib

__all__ = [
    "UserError",
    "parse_rate",
    "rate_arg",
    "positive_int",
    "default_workers",
    "add_workers_argument",
    "resolve_workers",
    "add_seed_arguments",
    "did_you_mean",
    "writable_dir",
    "writable_file",
    "os_error_text",
    "endurance_line",
]


class UserError(Exception):
    """A mistake in the user's input: printed as one clear message, exit status 2, no traceback."""


def parse_rate(text: str, option: str = "--attrition") -> float:
    """A probability given as a fraction (``0.01``) or a percent (``1%``): the one rate parser
    of every command that takes one (sim, sweep, tune, mission new).

    A bare number must be a fraction below 1. ``1`` is refused as ambiguous (1 % or 100 %?)
    and so is any bare number above 1 (``2`` is not a probability; ``2%`` is): the message
    spells out both readings, so nobody runs 100 %/step by accident. 100 % is written ``100%``.

    Raises
    ------
    UserError
        Not a number, a bare number >= 1, or outside [0, 1].
    """
    at = f"{option}: " if option else ""
    t = str(text).strip()
    percent = t.endswith("%")
    try:
        value = float(t[:-1]) / 100 if percent else float(t)
    except ValueError:
        raise UserError(
            f"{at}expected a fraction like 0.01 or a percent like 1%, got {text!r}"
        ) from None
    if not percent and value == 1.0:
        raise UserError(
            f"{at}{text} is ambiguous: write 1% (or 0.01) for one percent, or 100% to "
            "lose every drone at every step"
        )
    if not percent and 1.0 < value <= 100.0:
        raise UserError(
            f"{at}{text} is not a probability (a fraction below 1); "
            f"did you mean {t}% (= {value / 100:g})?"
        )
    if not 0.0 <= value <= 1.0:
        raise UserError(f"{at}{text} is not a probability in [0, 1] (0.01 = 1%)")
    return value


def rate_arg(text: str) -> float:
    """argparse ``type=`` for a single rate (0.01 or 1%)."""
    try:
        return parse_rate(text, option="")  # argparse names the option itself
    except UserError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


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


def endurance_line(e: dict) -> str:
    """A run's relay rotation for people (``sim`` per seed, ``fly``'s closing summary), from its
    endurance summary (``summary.json`` ``endurance``): rotations, battery failsafes in the air,
    vehicles landed away from the base, the lowest battery seen in the air."""
    return (
        f"{e['rotations']} rotations, {e['battery_failsafes_in_air']} battery failsafes in the "
        f"air, {e['landed_away']} landed away from the base, min battery in the air "
        f"{100 * e['min_battery_in_air']:.0f} %"
    )

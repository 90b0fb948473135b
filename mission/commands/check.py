"""``phireman check MISSION.yaml``: validate a mission and report every problem at once."""

from __future__ import annotations

import sys
from pathlib import Path

from mission.cli import UserError

HELP = "validate a mission file and report every problem with its path"
DESCRIPTION = """\
Validate a mission file (YAML) against the mission schema without running anything.

Prints 'OK: <summary>' when the mission is valid. Otherwise prints every problem, one per line,
each with the path of the offending key (e.g. 'tasks[2].track[0].t_s: expected a number, got
'abc''), and exits with status 2.

MISSION may also be the name of a shipped example ('phireman mission list'), e.g. 'wildfire'.
"""


def add_arguments(parser) -> None:
    parser.add_argument("mission", metavar="MISSION", help="mission YAML file or shipped example name")


def resolve_mission_path(text: str) -> Path:
    """A mission argument as a path: an existing file, else a shipped example's name."""
    path = Path(text)
    if path.exists() or "/" in text or "\\" in text:
        return path
    from mission.examples import example_path

    try:
        return example_path(text)
    except KeyError:
        return path  # let the loader report "no such file"


def run(args) -> int:
    from mission.load import MissionError, load_mission

    path = resolve_mission_path(args.mission)
    try:
        mission = load_mission(path)
    except MissionError as exc:
        if len(exc.errors) == 1 and exc.errors[0].startswith(f"{path}:"):
            raise UserError(exc.errors[0]) from None  # missing / unreadable file
        for line in exc.errors:
            print(f"{path}: {line}", file=sys.stderr)
        return 2
    print(f"OK: {mission.summary()}")
    return 0

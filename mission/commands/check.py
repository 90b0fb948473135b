"""``phireman check MISSION.yaml``: validate a mission and report every problem at once."""

from __future__ import annotations

import sys
from pathlib import Path

from mission.commands.options import UserError

HELP = "validate a mission file and report every problem with its path"
DESCRIPTION = """\
Validate a mission file (YAML) against the mission schema without running anything.

Prints 'OK: <summary>' when the mission is valid. Otherwise prints every problem, one per line,
each with the path of the offending key (e.g. 'tasks[2].track[0].t_s: expected a number, got
'abc''), and exits with status 2.

MISSION may also be the name of a shipped example ('phireman mission list'), e.g. 'wildfire'.
"""


def add_arguments(parser) -> None:
    parser.add_argument(
        "mission", metavar="MISSION", help="mission YAML file or shipped example name"
    )


def resolve_mission_path(text: str) -> Path:
    """A mission argument as a path: an existing file, else a shipped example's name."""
    path = Path(text)
    if path.exists() or "/" in text or "\\" in text:
        return path
    from mission.format.examples import example_path

    try:
        return example_path(text)
    except KeyError:
        return path  # let the loader report "no such file"


def run(args) -> int:
    from mission.format.load import MissionError, load_mission

    path = resolve_mission_path(args.mission)
    try:
        mission = load_mission(path)
    except MissionError as exc:
        if len(exc.errors) == 1 and exc.errors[0].startswith(f"{path}:"):
            raise UserError(exc.errors[0]) from None  # missing / unreadable file
        for line in exc.errors:
            print(f"{path}: {line}", file=sys.stderr)
        return 2
    problem = rotation_problem(mission)
    if problem is not None:
        print(f"{path}: endurance: {problem}", file=sys.stderr)
        return 2
    print(f"OK: {mission.summary()}")
    for note in mission_notes(path, mission):
        print(f"note: {note}")
    return 0


def rotation_problem(mission) -> str | None:
    """Why the mission's relay rotation cannot be planned (None: it can, or there is none): the
    station's own rotation set-up (:func:`mission.flight.station_loop.rotation_setup`), so that
    what ``check`` accepts, ``fly`` flies (a battery too small to reach the posts and back)."""
    if mission.endurance.battery is None or not mission.endurance.rotation:
        return None
    from mission.flight.fly_options import RunnerError
    from mission.flight.mission_world import mission_scenario
    from mission.flight.station_loop import rotation_setup

    try:
        rotation_setup(mission, mission_scenario(mission, live_tasks=True))
    except RunnerError as exc:
        return str(exc)
    return None


def mission_notes(path: Path, mission) -> list[str]:
    """What the mission does that its file does not say: defaults that invent things."""
    import yaml

    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return []
    raw = raw if isinstance(raw, dict) else {}
    notes = []
    n_random = sum(t.count for t in mission.tasks if t.kind == "random")
    if "tasks" not in raw:
        w = next((t.random.field_half_width_m for t in mission.tasks if t.random is not None), None)
        notes.append(
            f"the file has no 'tasks:', so the default applies: {n_random} tasks placed at random "
            f"(uniform within ±{w:g} m of the base, random-walking) from seed {mission.run.seed}; "
            f"add 'tasks:' with tracks or random_walk starts to place your crews"
        )
    elif n_random:
        notes.append(
            f"{n_random} of the {mission.n_tasks} tasks are generated at random from seed "
            f"{mission.run.seed} (tasks: random); they move with the seed"
        )
    if "vehicles" not in raw:
        notes.append(
            f"the file has no 'vehicles:', so the default applies: {mission.vehicles.count} emulated drones"
        )
    if "origin" not in raw:
        notes.append(
            f"the file has no 'origin:', so the default applies ({mission.origin.lat_deg:.5f}, "
            f"{mission.origin.lon_deg:.5f}, the autopilots' SITL home); set it for real flights"
        )
    return notes

"""``phireman emulate``: see :mod:`vehicle_emu.cli` (its body); this command prints for people (the
ports at start, the statistics at the end) and turns bad input into a one-line error."""

import sys

from vehicle_emu.cli import DESCRIPTION, HELP, UsageError, add_arguments, describe_end
from vehicle_emu.cli import run as _run

__all__ = ["HELP", "DESCRIPTION", "add_arguments", "run"]

#: Exit status per stopping signal (128 + the signal's number, as a shell reports it).
_EXIT = {"SIGINT": 130, "SIGTERM": 143}


def run(args) -> int:
    from mission.commands.options import UserError

    def ready(line: str) -> None:
        print(line, flush=True)  # scripts wait for it: the ports are bound

    try:
        result = _run(args, on_ready=ready)
    except UsageError as exc:
        raise UserError(str(exc)) from None
    for line in describe_end(result):
        print(line)
    sys.stdout.flush()
    return _EXIT.get(result.stopped_by or "", 0)

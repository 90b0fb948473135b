"""``phireman emulate``: see :mod:`vehicle_emu.cli` (its body); bad input becomes a one-line error."""

from vehicle_emu.cli import DESCRIPTION, HELP, UsageError, add_arguments
from vehicle_emu.cli import run as _run

__all__ = ["HELP", "DESCRIPTION", "add_arguments", "run"]


def run(args) -> int:
    from mission.commands.options import UserError

    try:
        return _run(args)
    except UsageError as exc:
        raise UserError(str(exc)) from None

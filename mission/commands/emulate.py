"""``phireman emulate``: see :mod:`vehicle_emu.cli`."""
from vehicle_emu.cli import DESCRIPTION, HELP, add_arguments, run

__all__ = ["HELP", "DESCRIPTION", "add_arguments", "run"]

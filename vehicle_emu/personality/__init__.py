"""Autopilot personalities of the emulator: the firmware rules that differ between ArduPilot
Copter and PX4 (issue 13.2).

A :class:`~vehicle_emu.personality.base.Personality` is attached to one
:class:`vehicle_emu.link.VehicleCore` and holds the rules: mode table, arming checks, set_mode,
takeoff, GCS-loss and offboard-loss behaviour, which setpoints count, limits from parameters,
and the wire facts a GCS reads to tell the two apart (HEARTBEAT.autopilot, capabilities,
parameter encoding). The core keeps the link, the shared state and the dispatch.
"""

from __future__ import annotations

from .ardupilot import ARDUPILOT_MODES, ArduPilot
from .base import Personality, ap_check_latlng_e7, px4_map_project
from .px4 import PX4, PX4_MODES

__all__ = [
    "PERSONALITIES",
    "Personality",
    "ArduPilot",
    "PX4",
    "personality_for",
    "ARDUPILOT_MODES",
    "PX4_MODES",
    "ap_check_latlng_e7",
    "px4_map_project",
]

_CLASSES = {"ardupilot": ArduPilot, "px4": PX4}
PERSONALITIES = tuple(_CLASSES)


def personality_for(name: str, core) -> Personality:
    """The personality ``name`` bound to ``core``."""
    try:
        cls = _CLASSES[name]
    except KeyError:
        raise ValueError(f"personality must be one of {PERSONALITIES}, got {name!r}") from None
    return cls(core)

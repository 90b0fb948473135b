"""Autopilot mode numbers as they appear in HEARTBEAT.custom_mode (wire facts, no behaviour).

ArduCopter's table is pymavlink's own ``COPTER_MODE`` enum (ardupilotmega.xml, generated from
ArduCopter/mode.h ``Mode::Number``). PX4 packs a (main, sub) pair into custom_mode
(src/modules/commander/px4_custom_mode.h ``union px4_custom_mode``: main_mode in byte 2, sub_mode
in byte 3); pymavlink has no PX4 enum, so the table is written out from that header
(``PX4_CUSTOM_MAIN_MODE_*``, ``PX4_CUSTOM_SUB_MODE_AUTO_*``).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = [
    "ARDUCOPTER_MODES",
    "ARDUCOPTER_NAMES",
    "PX4_MODES",
    "PX4_NAMES",
    "px4_custom_mode",
    "px4_main_sub",
    "ARDUPILOT",
    "PX4",
]

ARDUPILOT = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA  # 3
PX4 = mavlink.MAV_AUTOPILOT_PX4  # 12

#: ArduCopter mode name -> HEARTBEAT.custom_mode, from pymavlink's COPTER_MODE enum.
ARDUCOPTER_MODES: dict[str, int] = {
    e.name.removeprefix("COPTER_MODE_"): int(v)
    for v, e in mavlink.enums["COPTER_MODE"].items()
    if not e.name.endswith("_ENUM_END")
}
ARDUCOPTER_NAMES: dict[int, str] = {v: k for k, v in ARDUCOPTER_MODES.items()}

#: PX4 mode name (as QGC / MAVSDK spell it) -> (main, sub), px4_custom_mode.h.
PX4_MODES: dict[str, tuple[int, int]] = {
    "MANUAL": (1, 0),
    "ALTCTL": (2, 0),
    "POSCTL": (3, 0),
    "AUTO.READY": (4, 1),
    "AUTO.TAKEOFF": (4, 2),
    "AUTO.LOITER": (4, 3),
    "AUTO.MISSION": (4, 4),
    "AUTO.RTL": (4, 5),
    "AUTO.LAND": (4, 6),
    "AUTO.RTGS": (4, 7),
    "AUTO.FOLLOW_TARGET": (4, 8),
    "AUTO.PRECLAND": (4, 9),
    "ACRO": (5, 0),
    "OFFBOARD": (6, 0),
    "STABILIZED": (7, 0),
    "RATTITUDE": (8, 0),
}
PX4_NAMES: dict[tuple[int, int], str] = {v: k for k, v in PX4_MODES.items()}


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """Pack PX4 (main, sub) into HEARTBEAT.custom_mode. OFFBOARD (6, 0) -> 393216."""
    return ((main & 0xFF) << 16) | ((sub & 0xFF) << 24)


def px4_main_sub(custom_mode: int) -> tuple[int, int]:
    """Unpack HEARTBEAT.custom_mode into PX4 (main, sub)."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF

"""Autopilot adapters: what differs between ArduPilot Copter and PX4, chosen from HEARTBEAT.autopilot.

An adapter is pure policy: mode tables, which command (with which params) does what, how often a
position target must be re-sent, and whether setpoints must stream before a mode change. The link
core (:mod:`gcs.link`) asks the adapter and does the sending. Sources: docs/design/mavlink.md §1.4, §1.5.
"""

from __future__ import annotations

from dataclasses import dataclass

from mavedge import mavlink
from mavedge.modes import (
    ARDUCOPTER_MODES,
    ARDUCOPTER_NAMES,
    PX4_MODES,
    PX4_NAMES,
    px4_custom_mode,
    px4_main_sub,
)

__all__ = [
    "CommandSpec",
    "Adapter",
    "ArduCopterAdapter",
    "PX4Adapter",
    "GenericAdapter",
    "adapter_for",
    "mode_name",
    "is_failsafe_mode",
    "UnsupportedCommand",
    "ARDUCOPTER_MODES",
    "PX4_MODES",
    "px4_custom_mode",
    "px4_main_sub",
    "ARDUPILOT",
    "PX4",
]

from mavedge.modes import ARDUPILOT, PX4  # noqa: E402  (3, 12)

_CMD_DO_SET_MODE = mavlink.MAV_CMD_DO_SET_MODE  # 176
_CMD_ARM_DISARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM  # 400
_CMD_NAV_TAKEOFF = mavlink.MAV_CMD_NAV_TAKEOFF  # 22
_CUSTOM_MODE_ENABLED = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED  # 1


class UnsupportedCommand(ValueError):
    """Local error: the adapter cannot do this (unknown mode name, unknown autopilot)."""


@dataclass(frozen=True)
class CommandSpec:
    """One COMMAND_LONG to send (params 1..7), with sequencing hints for the link core."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    after_prestream: bool = False
    """PX4: hold this command until position setpoints have streamed long enough (OFFBOARD rule)."""

    def __post_init__(self) -> None:
        if len(self.params) != 7:
            raise ValueError(f"COMMAND_LONG has 7 params, got {len(self.params)}")


def _cmd(command: int, *params: float, after_prestream: bool = False) -> CommandSpec:
    p = tuple(float(v) for v in params) + (0.0,) * (7 - len(params))
    return CommandSpec(command, p, after_prestream)  # type: ignore[arg-type]


# Mode tables and the PX4 custom_mode packing are wire facts shared with the emulator
# (mavedge.modes: ArduCopter from pymavlink's COPTER_MODE enum, PX4 from px4_custom_mode.h).
_ARDUCOPTER_NAMES = ARDUCOPTER_NAMES
_PX4_NAMES = PX4_NAMES


class Adapter:
    """Base adapter; subclasses fill the tables. All methods are pure."""

    name = "generic"
    autopilot = mavlink.MAV_AUTOPILOT_GENERIC
    guided_mode = ""
    rtl_mode = ""
    land_mode = ""
    failsafe_modes: frozenset[str] = frozenset()
    home_modes: frozenset[str] = frozenset()
    """Modes that take the vehicle home or down by themselves (a vehicle sent home in one is
    left in it)."""
    setpoint_frame = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    setpoint_period_s = 1.0
    """Re-send the current position target at least this often, even if unchanged."""
    prestream_s = 0.0
    """Setpoints must have streamed this long before ``after_prestream`` commands go out."""
    param_bytewise = False
    """PARAM_VALUE integers are byte-wise encoded (PX4) rather than C-cast (ArduPilot)."""
    takeoff_by_offboard_climb = False
    """Take off by climbing to a position target in the guided mode rather than NAV_TAKEOFF."""
    command_int_frame: int | None = None
    """The one frame COMMAND_INT goes in (altitudes converted), None: as the caller says."""

    def mode_name(self, custom_mode: int) -> str:
        return f"MODE({custom_mode})"

    def mode_number(self, name: str) -> int:
        raise UnsupportedCommand(f"{self.name}: no mode table")

    def set_mode(self, name: str) -> CommandSpec:
        raise UnsupportedCommand(f"{self.name}: cannot set mode {name!r}")

    def is_failsafe_mode(self, custom_mode: int) -> bool:
        return self.mode_name(custom_mode) in self.failsafe_modes

    def is_guided(self, custom_mode: int) -> bool:
        return bool(self.guided_mode) and self.mode_name(custom_mode) == self.guided_mode

    def arm(self) -> CommandSpec:
        # param2 = 0: never the 21196 force-arm magic in the product path (docs/design/mavlink.md §1.3).
        return _cmd(_CMD_ARM_DISARM, 1, 0)

    def disarm(self) -> CommandSpec:
        return _cmd(_CMD_ARM_DISARM, 0, 0)

    def takeoff(self, alt_above_home_m: float) -> CommandSpec | None:
        raise UnsupportedCommand(f"{self.name}: takeoff not supported")


class ArduCopterAdapter(Adapter):
    """ArduPilot Copter in GUIDED (ardupilot.org/dev/docs/copter-commands-in-guided-mode)."""

    name = "ardupilot"
    autopilot = ARDUPILOT
    guided_mode = "GUIDED"
    rtl_mode = "RTL"
    land_mode = "LAND"
    # What FS_GCS_ENABLE can leave the vehicle in; it stays there after the link recovers.
    failsafe_modes = frozenset({"RTL", "SMART_RTL", "LAND", "AUTO_RTL"})
    # Each flies home (SMART_RTL back along its path, AUTO_RTL to the mission's DO_LAND_START) or
    # lands (ArduCopter mode_smart_rtl.cpp, mode_auto.cpp jump_to_landing_sequence_auto_RTL).
    home_modes = failsafe_modes
    setpoint_period_s = 1.0  # position targets persist, but the wiki says re-send every second
    prestream_s = 0.0
    param_bytewise = False

    def mode_name(self, custom_mode: int) -> str:
        return _ARDUCOPTER_NAMES.get(custom_mode, f"MODE({custom_mode})")

    def mode_number(self, name: str) -> int:
        try:
            return ARDUCOPTER_MODES[name.upper()]
        except KeyError:
            raise UnsupportedCommand(
                f"unknown ArduCopter mode {name!r}; known: {', '.join(ARDUCOPTER_MODES)}"
            ) from None

    def set_mode(self, name: str) -> CommandSpec:
        # MAV_CMD_DO_SET_MODE param1 = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, param2 = custom mode.
        return _cmd(_CMD_DO_SET_MODE, _CUSTOM_MODE_ENABLED, self.mode_number(name))

    def takeoff(self, alt_above_home_m: float) -> CommandSpec:
        # NAV_TAKEOFF param7 = altitude above home; needs GUIDED + armed (ArduCopter takeoff.cpp).
        if not alt_above_home_m > 0:
            raise ValueError(f"takeoff altitude must be > 0 m above home, got {alt_above_home_m}")
        return _cmd(_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_above_home_m)


class PX4Adapter(Adapter):
    """PX4 multicopter in OFFBOARD (docs.px4.io flight_modes/offboard)."""

    name = "px4"
    autopilot = PX4
    guided_mode = "OFFBOARD"
    rtl_mode = "AUTO.RTL"
    land_mode = "AUTO.LAND"
    # Failsafe outcomes (failsafe.cpp checkModeFallback / checkStateAndMode): POSCTL (offboard
    # loss, COM_OBL_RC_ACT 0, with RC; without RC only PX4 v1.14 to 1.16.0), Hold, RTL, Land
    # (COM_OBL_RC_ACT 3-5; 0-2 without RC take NAV_RCL_ACT's action; NAV_DLL_ACT).
    failsafe_modes = frozenset({"POSCTL", "AUTO.LOITER", "AUTO.RTL", "AUTO.LAND"})
    home_modes = frozenset({"AUTO.RTL", "AUTO.LAND"})
    # Position targets in GLOBAL_INT (AMSL): PX4 mavlink_receiver.cpp
    # handle_message_set_position_target_global_int accepts frames 5, 6 and 11 only (others:
    # "invalid coordinate frame"), and for 6 computes z = home.alt - alt - ref_alt, which puts
    # the target 2 (home.alt - ref_alt) off whenever home is not at the EKF origin's altitude.
    # Frame 5 is z = ref_alt - alt: exact. The link converts "above home" with the home AMSL
    # from GLOBAL_POSITION_INT (alt - relative_alt = home.alt on PX4).
    setpoint_frame = mavlink.MAV_FRAME_GLOBAL_INT
    # COMMAND_INT: frame 5, z AMSL (gcs/link_commands.py send_command_int says why).
    command_int_frame = mavlink.MAV_FRAME_GLOBAL_INT
    setpoint_period_s = 0.1  # >= 10 Hz (PX4 needs > 2 Hz; MAVSDK streams at 20 Hz)
    prestream_s = 1.2  # "more than a second" of setpoints before OFFBOARD / arming
    param_bytewise = True
    takeoff_by_offboard_climb = True

    def mode_name(self, custom_mode: int) -> str:
        main, sub = px4_main_sub(custom_mode)
        if (main, sub) in _PX4_NAMES:
            return _PX4_NAMES[(main, sub)]
        if (main, 0) in _PX4_NAMES and main != 4:
            return _PX4_NAMES[(main, 0)]
        return f"MODE({main}.{sub})"

    def mode_number(self, name: str) -> int:
        try:
            return px4_custom_mode(*PX4_MODES[name.upper()])
        except KeyError:
            raise UnsupportedCommand(
                f"unknown PX4 mode {name!r}; known: {', '.join(PX4_MODES)}"
            ) from None

    def set_mode(self, name: str) -> CommandSpec:
        # DO_SET_MODE param2 = main mode, param3 = sub mode, UNPACKED: the packed HEARTBEAT word
        # truncates to 0 in Commander.cpp and can be ACKed while nothing changes.
        try:
            main, sub = PX4_MODES[name.upper()]
        except KeyError:
            raise UnsupportedCommand(
                f"unknown PX4 mode {name!r}; known: {', '.join(PX4_MODES)}"
            ) from None
        return _cmd(
            _CMD_DO_SET_MODE,
            _CUSTOM_MODE_ENABLED,
            main,
            sub,
            after_prestream=name.upper() == "OFFBOARD",
        )

    def arm(self) -> CommandSpec:
        # Arming for OFFBOARD needs the setpoint stream first, like the mode switch.
        return _cmd(_CMD_ARM_DISARM, 1, 0, after_prestream=True)

    def takeoff(self, alt_above_home_m: float) -> CommandSpec | None:
        # Climb in OFFBOARD to a position target (the link core does it): NAV_TAKEOFF's altitude
        # reference differs across PX4 versions (PX4-user_guide#3649).
        return None


class GenericAdapter(Adapter):
    """Unknown autopilot: modes are shown as numbers; commands are refused."""


_ADAPTERS: dict[int, Adapter] = {ARDUPILOT: ArduCopterAdapter(), PX4: PX4Adapter()}
_GENERIC = GenericAdapter()


def adapter_for(autopilot: int) -> Adapter:
    """The adapter for a HEARTBEAT.autopilot value (GenericAdapter when unknown)."""
    return _ADAPTERS.get(autopilot, _GENERIC)


def mode_name(autopilot: int, custom_mode: int) -> str:
    """Human mode name, e.g. ``mode_name(3, 4) == 'GUIDED'``, ``mode_name(12, 393216) == 'OFFBOARD'``."""
    return adapter_for(autopilot).mode_name(custom_mode)


def is_failsafe_mode(autopilot: int, custom_mode: int) -> bool:
    return adapter_for(autopilot).is_failsafe_mode(custom_mode)

"""Events of the vehicle emulator: frozen, validated, past-tense facts (docs/design/architecture.md §2.2).

They are produced by :class:`vehicle_emu.link.VehicleCore` and :class:`vehicle_emu.swarm.Swarm`
and drained with ``next_event()``. Only state changes and commands become events, never the
per-tick telemetry or per-setpoint traffic (hundreds of vehicles at 10-20 Hz would flood them);
counters live in ``stats``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = [
    "EmulatorEvent",
    "ModeChanged",
    "ArmingChanged",
    "CommandHandled",
    "FailsafeTriggered",
    "GcsLinkRegained",
    "ParamChanged",
    "SigningChanged",
    "TakeoffStarted",
    "VehicleKilled",
    "VehiclePoweredOff",
    "VehicleBooted",
]


@dataclass(frozen=True)
class EmulatorEvent:
    sysid: int
    """MAVLink system id of the vehicle (1..254)."""
    t_s: float
    """Vehicle clock time, seconds."""

    def __post_init__(self) -> None:
        if not isinstance(self.sysid, int) or not 1 <= self.sysid <= 255:
            raise ValueError(f"sysid must be an int in 1..255, got {self.sysid!r}")
        if not math.isfinite(self.t_s):
            raise ValueError(f"t_s must be finite, got {self.t_s!r}")


@dataclass(frozen=True)
class ModeChanged(EmulatorEvent):
    mode: str = ""
    """Mode name, e.g. 'GUIDED' or 'AUTO.RTL'."""
    custom_mode: int = 0
    """HEARTBEAT.custom_mode value."""
    reason: str = ""
    """'command', 'failsafe', 'takeoff_complete', ..."""


@dataclass(frozen=True)
class ArmingChanged(EmulatorEvent):
    armed: bool = False
    reason: str = ""


@dataclass(frozen=True)
class TakeoffStarted(EmulatorEvent):
    alt_above_home_m: float = 0.0


@dataclass(frozen=True)
class CommandHandled(EmulatorEvent):
    command: int = 0
    """MAV_CMD id (or message id 11 for SET_MODE)."""
    result: int = 0
    """MAV_RESULT sent in the COMMAND_ACK."""


@dataclass(frozen=True)
class FailsafeTriggered(EmulatorEvent):
    kind: str = ""
    """'gcs' (GCS heartbeat / data link lost), 'offboard' (PX4 setpoint stream lost),
    'battery_low', 'battery_critical' or 'battery_emergency' (PX4) (vehicle_emu.battery_monitor)."""
    action: str = ""
    """What the vehicle did: 'RTL', 'LAND', 'HOLD', 'DISARM', 'NONE', or a mode name."""


@dataclass(frozen=True)
class GcsLinkRegained(EmulatorEvent):
    pass


@dataclass(frozen=True)
class ParamChanged(EmulatorEvent):
    name: str = ""
    value: float = 0.0


@dataclass(frozen=True)
class SigningChanged(EmulatorEvent):
    enabled: bool = False


@dataclass(frozen=True)
class VehicleKilled(EmulatorEvent):
    network: int = 0
    index: int = 0
    cause: str = ""
    """'hazard' (random attrition) or 'scripted'."""


@dataclass(frozen=True)
class VehiclePoweredOff(EmulatorEvent):
    """The vehicle went silent for a battery swap (vehicle_emu.swarm, docs/design/endurance.md §6.4)."""

    network: int = 0
    index: int = 0
    boot_at_s: float = 0.0
    """When it powers up again, vehicle seconds."""


@dataclass(frozen=True)
class VehicleBooted(EmulatorEvent):
    """The vehicle powered up again with a full battery (time_boot_ms from 0)."""

    network: int = 0
    index: int = 0

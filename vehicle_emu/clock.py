"""The emulator's clocks, re-exported from :mod:`mavedge.clock` (where they live, so that the
station can use the same ones without importing the emulator); kept so that ``from
vehicle_emu.clock import RealClock`` keeps working."""

from mavedge.clock import Clock, PacedClock, PacedReader, RealClock, VirtualClock

__all__ = ["Clock", "VirtualClock", "RealClock", "PacedClock", "PacedReader"]

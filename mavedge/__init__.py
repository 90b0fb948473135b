"""One MAVLink edge for the ground station (:mod:`gcs`) and the emulator (:mod:`vehicle_emu`).

Everything that knows a wire integer or a wire byte lives here, once: SI <-> wire converters
(:mod:`mavedge.units`), parameter value encoding (:mod:`mavedge.params`), autopilot mode tables
(:mod:`mavedge.modes`), SET_POSITION_TARGET_* type masks (:mod:`mavedge.setpoints`), the
codec with the corrected signature check (:mod:`mavedge.codec`) and the one Clock protocol both
sides keep time with (:mod:`mavedge.clock`: its Unix anchor stamps signing and .tlog records).

This package imports nothing of ours (import-linter contract in ``pyproject.toml``); it sits
below ``gcs`` and ``vehicle_emu``, which stay independent of each other. The pymavlink dialect
is imported directly (``pymavlink.dialects.v20.ardupilotmega``), never through ``mavutil``:
mavutil reads ``MAVLINK20``/``MAVLINK_DIALECT`` from the environment at import time
(docs/design/mavlink.md §5.3).
"""

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["mavlink"]

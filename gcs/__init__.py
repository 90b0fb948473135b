"""gcs: the ground station.

Owns: what the station *believes* (``fleet``), the sans-I/O station-side MAVLink core (``link``),
its codec (``wire``), autopilot adapters, the control loop that calls ``planner``, records
(tlog, events, metrics) and thin asyncio adapters.
Must not import: ``vehicle_emu`` or ``mission``; it never sees ground truth, only telemetry.
"""

"""vehicle_emu: the ground truth and a SITL-style MAVLink emulator of many vehicles.

Owns: the paper's world model (``world``: state arrays, attrition, radio, task motion), vehicle
physics, the sans-I/O vehicle-side MAVLink core (``link``), its codec (``wire``), the multi-vehicle
router and the thin UDP adapter.
Must not import: ``gcs`` or ``mission``; of ``planner`` only its geometry and problem types.
"""

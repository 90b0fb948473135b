"""mission: the composition root.

Owns: the mission schema and loader, the runners that wire the planner, the emulator and the
ground station together, playback and replay, sweeps, reports and the ``phireman`` CLI.
Must not contain: algorithm logic (that is ``planner``) or protocol logic (``gcs``, ``vehicle_emu``).
"""

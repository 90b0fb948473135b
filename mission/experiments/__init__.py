"""The paper's experiments: the world loop (:mod:`.world_loop`), in-process simulation
(:mod:`.sim`) and mission playback (:mod:`.playback`), the paper's grids (:mod:`.paper`), sweeps
into a resumable store (:mod:`.sweep`, :mod:`.store`) and the reports drawn from it
(:mod:`.report`).

Independent of :mod:`mission.flight` (neither imports the other); only :mod:`mission.format`
below it (docs/design/architecture.md).
"""

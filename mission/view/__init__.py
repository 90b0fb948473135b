"""What people look at: the PNG figures (:mod:`.plots`), the replay of a recorded run
(:mod:`.replay`) and the operator's live page with its replay and GIS export (:mod:`.live`).

Above :mod:`mission.experiments` and :mod:`mission.flight`, below the command line
(docs/design/architecture.md).
"""

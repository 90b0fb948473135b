"""Flying a mission through the ground station: the runners (:mod:`.runners`, emulated or real
autopilots), the station's asyncio loop (:mod:`.station_loop`), the emulator process it talks to
(:mod:`.emulator_host`, :mod:`.mission_world`, :mod:`.ether`), real-firmware SITL launchers
(:mod:`.sitl`), the run directory (:mod:`.run_dir`) and the options of ``phireman fly``
(:mod:`.fly_options`).

Independent of :mod:`mission.experiments` (neither imports the other); only :mod:`mission.format`
below it. The live view is attached by the command (``FlyOptions.attach_view``): the flight room
never imports :mod:`mission.view` (docs/design/architecture.md).
"""

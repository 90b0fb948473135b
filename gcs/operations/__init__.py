"""Flight operations: launch, run, end and reclaim, on top of the station core and the fleet view.

Sans-I/O like everything under ``gcs``: the :class:`Operator` is fed link events
(:meth:`Operator.handle_event`) and polled with an explicit ``now_s`` (:meth:`Operator.poll`);
it calls the :class:`~gcs.station.Station`'s local API (which only queues frames). A driver (the
asyncio adapters, or an in-memory ether in tests) moves the bytes and calls :meth:`poll` at
:meth:`next_poll_s`. It never reads a clock and never sees ground truth.

Phases (``Operator.phase``, a :class:`Phase`: a ``str``-valued Enum, so ``op.phase == "run"``)::

    discover -> audit -> launch -> run -> end -> done
    discover / audit -> refused (no vehicle heard; a live task never heard; a blocking audit
                                 finding and no override)
    any phase -> done (interrupted); discover / audit / launch -> end (``begin_end``)

Every allowed transition, with its trigger, is in :data:`TRANSITIONS`
(:mod:`gcs.operations.phases`, laid out like h11's state table); the operator raises
:class:`IllegalTransition` on any other.

* **discover**: wait for ``expected_vehicles`` HEARTBEATs (or ``discover_timeout_s``, or
  ``discover_settle_s`` without a new vehicle when no count is expected), and for the first
  position of every live task tracker (:mod:`gcs.tasks`; refused after ``task_wait_timeout_s``).
  No vehicle at all by ``discover_timeout_s``: refused.
* **audit**: read the lost-link parameters of every vehicle (:mod:`gcs.audit`); refuse unless
  every vehicle is safe or ``override_audit``. With ``apply_failsafes`` (and only then: no
  failsafe parameter is ever written otherwise), every fixable blocking finding is first fixed by a
  PARAM_SET confirmed by the vehicle's PARAM_VALUE echo (:func:`gcs.audit.failsafe_fixes`), and
  the fleet re-audited with the echoed values; ``param_changes`` records every write. Then,
  with ``set_limits``, the mission's speed and climb limits are written into each vehicle's
  own parameters (:mod:`gcs.limits`), each confirmed by its echo.
* **late audit** (in the launch and run phases, no phase of its own): a vehicle first heard
  after the fleet audit's reads (a drone powered on late, a SITL instance slow to boot) is kept
  on the ground and out of the plan until it passed the same audit on its own (the same reads,
  rounds, timeouts, verdict, fixes, limits and rally settings,
  :mod:`~gcs.operations.late_audit`); cleared, the run's reclaim launches it. Refused (and no
  ``override_audit``), it stays on the ground for the whole flight, reported in the log, in
  ``events.jsonl`` (an :class:`OperatorAction` ``audit``) and in
  :meth:`Operator.late_audit_summary`. A vehicle that reboots (the same link and sysid) is not
  audited again: its parameters survive the power cycle.
* **launch**: in waves of ``wave_size``: GUIDED (ArduPilot) / pre-streamed OFFBOARD (PX4), arm,
  take off to the vehicle's layer; the next wave starts as soon as most of this one is off the
  ground (waves spread the command burst and the take-off, they do not wait for the climb);
  the run starts when most of the fleet has climbed. A vehicle that is armed and taking off is
  left alone (never re-armed or sent a second take-off), and a vehicle whose commands fail is
  retried with an exponential back-off, never in a tight loop.
* **run**: every ``control_period_s``, :func:`gcs.control.tick` plans for every vehicle the
  station hears that is armed and airborne; one SET_POSITION_TARGET_GLOBAL_INT each.
* **end**: RTL or LAND every vehicle heard; done when every vehicle heard has landed (disarmed),
  or after ``end_timeout_s`` (``end_status`` says how many were still in the air).

**Reclaim** runs in every phase after discovery: a vehicle heard again that is not in the guided
mode (back from a failsafe RTL, or found in RTL by a restarted station) is switched back to
GUIDED/OFFBOARD (PX4: after streaming setpoints at its current position) and rejoins the plan;
one that already landed and disarmed is armed and launched again. Vehicles are identified by
``(link_id, sysid)``, which :class:`~gcs.fleet.FleetView` maps to a stable row.

Layout (one 950-line module split along its seams; each module's docstring says why):
:mod:`~gcs.operations.phases` (the phases and the transition table), :mod:`~gcs.operations.config`
(configuration and records), :mod:`~gcs.operations.operator` (the machine: event and phase
dispatch, discovery, the run's control tick), and the steps it mixes in:
:mod:`~gcs.operations.audit` (parameter reads and writes), :mod:`~gcs.operations.late_audit`
(the audit of a vehicle discovered after it), :mod:`~gcs.operations.launch`
(take-off, retries, reclaim), :mod:`~gcs.operations.end` (RTL / LAND, restore) and
:mod:`~gcs.operations.actions` (operator actions, interrupt) and :mod:`~gcs.operations.rally`
(the planner's rally points kept on the vehicles, issue 15).
"""

from gcs.operations.config import OPERATOR_ACTIONS, OperationsConfig, OperatorAction, TickRecord
from gcs.operations.operator import Operator
from gcs.operations.phases import PHASES, TRANSITIONS, IllegalTransition, Phase, Trigger

__all__ = [
    "OperationsConfig",
    "Operator",
    "PHASES",
    "TickRecord",
    "OperatorAction",
    "OPERATOR_ACTIONS",
    "Phase",
    "Trigger",
    "TRANSITIONS",
    "IllegalTransition",
]

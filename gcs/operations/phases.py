"""The operator's phases and the table of allowed transitions (pure data, no operator state).

Laid out like h11's ``_state.py`` (``EVENT_TRIGGERED_TRANSITIONS``): per phase, a table of the
triggers it accepts and the phase each one leads to. :meth:`Operator._enter
<gcs.operations.Operator._enter>` looks every transition up here (:func:`next_phase`) and raises
:class:`IllegalTransition` for a trigger the current phase does not accept, so a transition the
table does not list cannot happen silently. What *decides* a transition (counts, timeouts, the
audit verdict) stays in the per-phase poll handlers; the table says only which moves exist::

    discover --found--------------> audit --cleared--> launch --launched--> run
    discover --found, audit off---------------------> launch
    discover --tasks unseen / nothing heard--> refused      audit --unsafe--> refused
    discover / audit / launch / run --end--> end --landed / end timeout--> done
    every phase --interrupt--> done   (Ctrl-C with hold / rtl / land; "end" before launch)

A vehicle discovered after the audit is audited on its own during launch and run
(:mod:`gcs.operations.late_audit`): per vehicle, not a phase of the operator.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["Phase", "Trigger", "TRANSITIONS", "PHASES", "IllegalTransition", "next_phase"]


class Phase(StrEnum):
    """``Operator.phase``. A ``str``: it compares, hashes, formats and serialises (JSON) as its
    value, so callers keep reading (and writing) the phase as a plain string."""

    DISCOVER = "discover"
    AUDIT = "audit"
    LAUNCH = "launch"
    RUN = "run"
    END = "end"
    DONE = "done"
    REFUSED = "refused"


#: The phase names, in order (the public tuple callers had before the Enum).
PHASES: tuple[str, ...] = tuple(p.value for p in Phase)


class Trigger(StrEnum):
    """Why the operator changes phase (the keys of :data:`TRANSITIONS`)."""

    FOUND = "found"
    """The expected fleet is discovered (or discovery settled / timed out), every live task has a
    position, and the audit is on."""
    FOUND_UNAUDITED = "found, audit off"
    """The same, with ``OperationsConfig.audit`` off: straight to the launch."""
    TASKS_UNSEEN = "tasks unseen"
    """A live task tracker was never heard within ``task_wait_timeout_s``."""
    NOTHING_HEARD = "nothing heard"
    """No vehicle at all was heard within ``discover_timeout_s``."""
    CLEARED = "cleared"
    """The audit cleared the fleet (or was overridden), fixes and limits confirmed."""
    UNSAFE = "unsafe"
    """The audit found a blocking lost-link setting and no override."""
    LAUNCHED = "launched"
    """Every wave started and most of the fleet climbed (or the climb timed out)."""
    END = "end"
    """``begin_end``: the mission's duration is over, or a caller / interrupt ends the flight."""
    LANDED = "landed"
    """Every vehicle heard is on the ground (and restored parameters echoed)."""
    END_TIMEOUT = "end timeout"
    """``end_timeout_s`` passed with vehicles still in the air."""
    INTERRUPT = "interrupt"
    """The operator stopped the flight (:meth:`Operator.interrupt`)."""


#: Per phase: trigger -> next phase. Nothing else is a legal transition.
TRANSITIONS: dict[Phase, dict[Trigger, Phase]] = {
    Phase.DISCOVER: {
        Trigger.FOUND: Phase.AUDIT,
        Trigger.FOUND_UNAUDITED: Phase.LAUNCH,
        Trigger.TASKS_UNSEEN: Phase.REFUSED,
        Trigger.NOTHING_HEARD: Phase.REFUSED,
        Trigger.END: Phase.END,
        Trigger.INTERRUPT: Phase.DONE,
    },
    Phase.AUDIT: {
        Trigger.CLEARED: Phase.LAUNCH,
        Trigger.UNSAFE: Phase.REFUSED,
        Trigger.END: Phase.END,
        Trigger.INTERRUPT: Phase.DONE,
    },
    Phase.LAUNCH: {
        Trigger.LAUNCHED: Phase.RUN,
        Trigger.END: Phase.END,
        Trigger.INTERRUPT: Phase.DONE,
    },
    Phase.RUN: {
        Trigger.END: Phase.END,
        Trigger.INTERRUPT: Phase.DONE,
    },
    Phase.END: {
        Trigger.LANDED: Phase.DONE,
        Trigger.END_TIMEOUT: Phase.DONE,
        Trigger.INTERRUPT: Phase.DONE,
    },
    # Final phases. A second interrupt (Ctrl-C twice) re-enters DONE; a refused flight the
    # operator interrupts is DONE, as it always was.
    Phase.DONE: {
        Trigger.INTERRUPT: Phase.DONE,
    },
    Phase.REFUSED: {
        Trigger.INTERRUPT: Phase.DONE,
    },
}


class IllegalTransition(RuntimeError):
    """A trigger the current phase does not accept (a bug in the operator, never the fleet's
    doing: every input only ever *decides* among the transitions the table allows)."""


def next_phase(phase: Phase, trigger: Trigger) -> Phase:
    """The phase ``trigger`` leads to from ``phase``; :class:`IllegalTransition` if none."""
    try:
        return TRANSITIONS[phase][trigger]
    except KeyError:
        raise IllegalTransition(
            f"phase {phase!s} does not accept {trigger!s}; it accepts "
            f"{', '.join(map(str, TRANSITIONS.get(phase, {}))) or 'nothing'}"
        ) from None

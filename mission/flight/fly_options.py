"""What ``phireman fly`` asks of the runners, and the error a runner raises when it cannot fly.

The lowest module of the flight path (:mod:`mission.flight.runners` and the modules it is cut into,
pyproject.toml's import-linter contracts): every other one imports it, it imports none of them.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # a type only: importing the operator costs seconds; `phireman fly --help` reads
    # the defaults below without it
    from gcs.operations import Operator

__all__ = ["FlyOptions", "RunnerError"]


class RunnerError(ValueError):
    """A mission or option this runner cannot fly (reported to the user as a UserError)."""


@dataclass
class FlyOptions:
    """What ``phireman fly`` passes to the runners."""

    seed: int | None = None
    personality: str | None = None
    speedup: float | None = None
    """None: the mission's ``run.speedup``."""
    duration_s: float | None = None
    out_dir: str | None = None
    end: str = "rtl"
    override_audit: bool = False
    apply_failsafes: bool = False
    """Write the safe lost-link parameters the audit asks for (PARAM_SET, echo-confirmed)."""
    connections: tuple[str, ...] = ()
    wave_size: int = 25
    status: Callable[[dict], None] | None = None
    """Called about twice a second (wall) with a status dict."""
    emulator_params: dict | None = None
    """Parameter overrides for every emulated vehicle (tests)."""
    discover_timeout_s: float = 30.0
    expected_vehicles: int | None = None
    end_wait: bool = True
    """After the mission, wait until the vehicles are down (or the end timeout)."""
    set_limits: bool = True
    """Write the mission's speed / climb limits into each vehicle's own parameters at launch."""
    restore_params: bool = False
    """After landing, write back every parameter the station changed."""
    battery: str = "mission"
    """'mission' (the mission's ``endurance.battery``) or 'unlimited' (fly it as if the batteries
    were endless: the reference for relay rotation, as ``phireman sim --battery``)."""
    rotation: str = "mission"
    """'mission', 'on' or 'off' (no rotation: every drone flies until its firmware's low-battery
    failsafe; ``phireman sim --rotation``)."""
    swap_confirm: str = "auto"
    """Who ends a battery swap on a pad: 'auto' (the station, when the vehicle comes back
    powered and full, or the ground crew first from the live page) or 'manual' (only the ground
    crew: the live page's Confirm, the operator action ``confirm_swap``); docs/design/endurance.md
    §8. The emulator's own crew always swaps by itself (a power cycle)."""
    on_interrupt: str = "end"
    """What Ctrl-C tells every reachable vehicle: 'end' (the mission's end action), 'hold',
    'rtl' or 'land'."""
    emulator_in_process: bool = False
    """Run the emulator on the station's event loop (tests: failure injection through
    ``world.swarm``) instead of its own process."""
    on_operator: Callable[[Operator, object], None] | None = None
    """Hook called on every poll with (operator, world or None) - tests inject failures here."""
    serve: str | None = None
    """``[HOST:]PORT``: serve the live web view there (:mod:`mission.view.live`)."""
    serve_actions: bool = True
    """Operator actions on the page (behind the key printed at start); False: read-only."""
    alert_crew_after_s: float | None = None
    """The page alerts on a crew cut off this long (None: the default of
    :data:`mission.view.live.alerts.DEFAULT_CREW_CUT_OFF_S`)."""
    tiles: str | None = None
    """Background imagery of the live view: an XYZ tile folder or a URL template."""
    forward: tuple[str, ...] = ()
    """MAVLink forwarding outputs (``udpout:H:P``, ``udpin:H:P``, ``tcpin:H:P``, gcs.forward)."""
    forward_readonly: bool = False
    forward_overrides: str = "honour"
    """What a forwarded client's override (a mode change, RTL, land, arm / disarm, reposition:
    gcs.forward.override_of) does to a vehicle the plan flies: ``honour`` (it leaves the plan, as
    held by the operator) or ``refuse`` (not passed on; the client is told why)."""
    on_live: Callable[[dict], None] | None = None
    """Called once with the live view's url and operator key, the forwarders' addresses."""
    attach_view: Callable[..., Awaitable[list]] | None = None
    """What serves ``serve`` and ``forward`` on the station's loop (:func:`mission.view.live.attach`,
    given by the command: the flight room never imports the view room above it)."""
    tak: tuple[str, ...] = ()
    """TAK connections (``phireman fly --tak URL``, pytak COT_URLs: ``udp://239.2.3.1:6969``,
    ``tcp://H:P``, ``tls://H:P``): crews' reports come in, the mesh's picture goes out
    (docs/tak.md)."""
    tak_tls: dict | None = None
    """pytak's ``PYTAK_TLS_*`` settings for ``tls://`` connections (client certificate, key, CA)."""
    tak_period_s: float = 1.0
    """Wall seconds between two pictures published on TAK (each uid at most once a period)."""
    attach_tak: Callable[..., Awaitable[list]] | None = None
    """What publishes the mesh on the TAK connections (:func:`mission.view.tak.attach`, given by
    the command: the flight room never imports the view room above it)."""
    on_tak: Callable[[dict], None] | None = None
    """Called with the TAK connections at start (``{"urls": [...]}``) and their counters at the
    end (``{"counters": {...}, "published": {cot type: count}}``)."""

"""The operator's live picture: a web view served by the station, its replay, MAVLink forwarding
and GIS export (issue 17; docs/live_view.md).

* :func:`attach` - called once by the runner (``mission.flight.station_loop.run_station``) when
  ``FlyOptions.serve`` or ``FlyOptions.forward`` is set, on the station's event loop after the
  links are open: starts the web server (:mod:`mission.view.live.server`) reading the operator
  (:mod:`mission.view.live.station`) and the MAVLink forwarder (:mod:`gcs.forward`).
* :mod:`mission.view.live.replay` - the same page for a recorded run directory.
* :mod:`mission.view.live.export` - GeoJSON / KML of a run at chosen times.
"""

from __future__ import annotations

import logging
import secrets
from collections.abc import Callable

__all__ = ["attach"]

log = logging.getLogger(__name__)


class _Closer:
    def __init__(self, *closers) -> None:
        self._closers = closers

    async def aclose(self) -> None:
        for c in self._closers:
            r = c()
            if hasattr(r, "__await__"):
                await r


async def attach(
    op,
    adapters,
    *,
    mission,
    opts,
    clock: Callable[[], float],
    records=None,
    listeners: list | None = None,
) -> list:
    """Start what ``opts`` asks for (serve, forward) around a running station.

    Returns objects with ``async aclose()``, to close before the links. ``opts.on_live``, if set,
    is called once with ``{"url", "key", "forward", "forward_outputs"}`` (the page's address, the
    operator key or None, the forwarding outputs' local addresses, and per output its kind, the
    text given, the remote ``(host, port)`` as given and the local address).
    """
    out: list = []
    info: dict = {"url": None, "key": None, "forward": []}
    # Operator actions reach events.jsonl through the runner's own ``op.on_action``; the live
    # view chains onto it (mission.view.live.station) and never replaces it.
    if getattr(opts, "forward", ()):
        from gcs.forward import Forwarder

        policy = getattr(opts, "forward_overrides", "honour")

        def on_override(ov) -> str | None:
            # The station's policy for a client's override (gcs.forward module docstring):
            # honour takes the vehicle out of the plan, refuse answers why not.
            return op.forwarded_override(ov, clock(), refuse=policy == "refuse")

        fwd = Forwarder(
            opts.forward,
            readonly=opts.forward_readonly,
            gcs_sysid=op.gcs_sysid,
            on_override=on_override,
        )
        for a in adapters:
            fwd.attach(a, datagram=a.spec.kind in ("udpin", "udpout"))
        await fwd.start()
        out.append(_Closer(fwd.close))
        info["forward"] = list(fwd.addresses)
        # What each output is (udpout: where it sends; udpin / tcpin: where it listens, the
        # bound port when 0 was asked): what the announcement names (--forward udpout:H:P ->
        # "to H:P", not our ephemeral source port).
        info["forward_outputs"] = [
            {"kind": spec.kind, "text": spec.text, "remote": (spec.host, spec.port), "local": local}
            for spec, local in zip(fwd.specs, fwd.addresses)
        ]
        info["forwarder"] = fwd
        log.info(
            "forwarding MAVLink to %s%s",
            ", ".join(opts.forward),
            " (read-only)" if opts.forward_readonly else f" (overrides: {policy})",
        )
    if getattr(opts, "serve", None):
        from mission.view.live.server import LiveServer, parse_serve, tiles_meta
        from mission.view.live.station import LiveStation

        host, port = parse_serve(opts.serve)
        tiles, tiles_dir = tiles_meta(getattr(opts, "tiles", None))
        actions = getattr(opts, "serve_actions", True)
        from mission.view.live.alerts import DEFAULT_CREW_CUT_OFF_S, AlertConfig

        after = getattr(opts, "alert_crew_after_s", None)
        battery = getattr(getattr(mission, "endurance", None), "battery", None)
        alert_config = AlertConfig(
            crew_cut_off_s=DEFAULT_CREW_CUT_OFF_S if after is None else float(after),
            **({"battery_low_frac": battery.low_frac} if battery is not None else {}),
        )
        live = LiveStation(
            op,
            mission,
            clock,
            adapters,
            actions=actions,
            tiles=tiles,
            alert_config=alert_config,
            log_event=None if records is None else records.events.write,
        )
        if listeners is not None:
            listeners.append(live.on_event)
        key = secrets.token_urlsafe(18) if actions else None
        server = await LiveServer(live, host, port, key=key, tiles_dir=tiles_dir).start()
        live.start(server)
        out.append(_Closer(live.aclose, server.aclose))
        info.update(url=server.url, key=key, server=server, live=live)
    if getattr(opts, "on_live", None) is not None:
        opts.on_live(info)
    return out

"""Command-line options of the live view, forwarding and export (``phireman fly``,
``phireman replay``); the commands call these so their own modules stay small."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from gcs.forward import OVERRIDE_POLICIES
from mission.flight.fly_options import FlyOptions

__all__ = ["add_fly_arguments", "fly_options", "add_replay_arguments", "run_replay"]

_SERVE_HELP = (
    "serve the operator's live web view at [HOST:]PORT (default host 127.0.0.1, "
    "this machine only; to let other machines in, give the address to listen on, "
    "e.g. --serve 0.0.0.0:8080 - actions still need the operator key)"
)


def add_fly_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("live view and MAVLink forwarding (docs/live_view.md)")
    g.add_argument("--serve", default=None, metavar="[HOST:]PORT", help=_SERVE_HELP)
    g.add_argument(
        "--serve-actions",
        choices=("on", "off"),
        default="on",
        help="per-vehicle and fleet actions on the page (hold, RTL, land, release, "
        "back to plan), behind a confirmation and the operator key printed at "
        "start (default on; off: read-only page)",
    )
    g.add_argument(
        "--tiles",
        default=None,
        metavar="DIR_OR_URL",
        help="imagery under the live map: a folder of XYZ tiles (Z/X/Y.png) or a URL "
        "template with {z}/{x}/{y} (fetched by the browser); default: an offline "
        "metric grid around the mission origin",
    )
    g.add_argument(
        "--alert-crew-after",
        type=float,
        default=None,
        metavar="SECONDS",
        help="alert on the page (banner and sound) when a crew has been cut off from "
        "the base this long during the mission (default 60)",
    )
    g.add_argument(
        "--forward",
        action="append",
        default=[],
        metavar="URL",
        help="forward every vehicle's MAVLink to another GCS, as MAVProxy --out: "
        "udpout:H:P (e.g. QGroundControl on udpout:127.0.0.1:14550), udpin:H:P "
        "or tcpin:H:P; what it sends back goes to the addressed vehicle. "
        "Repeatable. The GCS must not use sysid 255 (the station's)",
    )
    g.add_argument(
        "--forward-readonly",
        action="store_true",
        help="drop everything the --forward outputs send (they only watch)",
    )
    g.add_argument(
        "--forward-overrides",
        choices=OVERRIDE_POLICIES,
        default=FlyOptions.forward_overrides,
        help="when a --forward client changes the mode of a vehicle the plan flies (mode, "
        "RTL, land, arm/disarm, go to): honour = the vehicle leaves the plan as if held "
        "on the station, and the live page says who took it ('Return to plan' gives it "
        "back); refuse = not passed on, the client gets COMMAND_ACK DENIED and a "
        "STATUSTEXT saying why (hold the vehicle on the station first). Never undone "
        "silently (default %(default)s)",
    )


def _forward_line(out: dict) -> str:
    """One forwarding output for people: udpout names its destination (where QGC listens), not
    the local ephemeral port it sends from; udpin / tcpin name where they listen."""
    host, port = out["local"][0], out["local"][1]
    if out["kind"] == "udpout":
        rh, rp = out["remote"]
        return f"forwarding MAVLink to {rh}:{rp} (UDP, sent from local port {port})"
    proto = "UDP" if out["kind"] == "udpin" else "TCP"
    return f"forwarding MAVLink: listening on {proto} {host}:{port} ({out['text']})"


def _announce(info: dict) -> None:
    if info.get("url"):
        url = info["url"]
        if info.get("key"):
            print(
                f"\nlive view: {url}\n  operator key (actions): {info['key']}\n"
                f"  open with actions enabled: {url}#key={info['key']}",
                file=sys.stderr,
            )
        else:
            print(f"\nlive view (read-only): {url}", file=sys.stderr)
    for out in info.get("forward_outputs") or []:
        print(_forward_line(out), file=sys.stderr)
    sys.stderr.flush()


def fly_options(opts, args):
    """``opts`` (FlyOptions) with the live/forward options of ``args``; UserError if invalid."""
    from mission.commands.options import UserError
    from mission.view.live import attach

    if args.serve is not None:
        from mission.view.live.server import parse_serve, tiles_meta

        try:
            parse_serve(args.serve)
            tiles_meta(args.tiles)
        except ValueError as exc:
            raise UserError(f"--serve / --tiles: {exc}") from None
    elif args.tiles:
        raise UserError("--tiles needs --serve")
    alert_after = getattr(args, "alert_crew_after", None)
    if alert_after is not None:
        if args.serve is None:
            raise UserError("--alert-crew-after needs --serve")
        if not alert_after >= 0:
            raise UserError(f"--alert-crew-after must be >= 0 seconds, got {alert_after}")
    if args.forward:
        from gcs.forward import Forwarder

        try:
            Forwarder(args.forward)
        except ValueError as exc:
            raise UserError(f"--forward: {exc}") from None
    elif args.forward_readonly:
        raise UserError("--forward-readonly needs --forward")
    elif args.forward_overrides != FlyOptions.forward_overrides:
        raise UserError("--forward-overrides needs --forward")
    return dataclasses.replace(
        opts,
        serve=args.serve,
        serve_actions=args.serve_actions == "on",
        alert_crew_after_s=alert_after,
        tiles=args.tiles,
        forward=tuple(args.forward),
        forward_readonly=args.forward_readonly,
        forward_overrides=args.forward_overrides,
        on_live=_announce,
        attach_view=attach if (args.serve is not None or args.forward) else None,
    )


def add_replay_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "live page and GIS export of a run (docs/live_view.md)",
        "an in-process run ('phireman sim --mission M --out DIR') is served, not exported",
    )
    g.add_argument(
        "--serve",
        default=None,
        metavar="[HOST:]PORT",
        help="serve the run on the live page with a time slider, play/pause and "
        "speed (until Ctrl-C); host default 127.0.0.1",
    )
    g.add_argument(
        "--tiles",
        default=None,
        metavar="DIR_OR_URL",
        help="imagery under the map (as phireman fly --tiles)",
    )
    g.add_argument(
        "--export",
        choices=("geojson", "kml"),
        default=None,
        help="write tracks, crews, hazard zones, geofence, links and the task tree "
        "as GeoJSON or KML (export.geojson / export.kml in the run directory, "
        "or --out FILE)",
    )
    g.add_argument(
        "--at",
        type=float,
        action="append",
        default=[],
        metavar="T",
        help="mission time (s) for the export's snapshot of vehicles, crews and "
        "links; repeatable (default: start, middle and end)",
    )


def run_replay(args, run_dir) -> int | None:
    """``phireman replay --serve / --export`` of ``run_dir`` (the run directory found from
    ``args.run_dir``); None if neither was asked (plots as before)."""
    if args.serve is None and args.export is None:
        return None
    from mission.commands.options import UserError
    from mission.view.live.replay import ReplaySource
    from mission.view.live.replay_sim import SimReplaySource, is_sim_run

    if is_sim_run(run_dir) and args.export:
        raise UserError(
            f"{run_dir}: --export reads a 'phireman fly' run (flight.tlog); "
            "an in-process run is served with --serve"
        )
    try:
        src = SimReplaySource(run_dir) if is_sim_run(run_dir) else ReplaySource(run_dir)
    except (FileNotFoundError, ValueError) as exc:
        raise UserError(str(exc)) from None
    if args.export:
        from mission.view.live.export import export_run

        out = None
        if args.out is not None:
            out = args.out / f"export.{args.export}" if args.out.is_dir() else args.out
        path = export_run(src, args.export, args.at, out)
        print(f"wrote {path}")
    if args.serve is not None:
        import asyncio

        from mission.view.live.server import LiveServer, parse_serve, tiles_meta

        try:
            host, port = parse_serve(args.serve)
            src.tiles, tiles_dir = tiles_meta(args.tiles)
        except ValueError as exc:
            raise UserError(str(exc)) from None

        async def serve() -> None:
            server = await LiveServer(src, host, port, tiles_dir=tiles_dir).start()
            print(f"replay of {run_dir} at {server.url} (Ctrl-C to stop)", file=sys.stderr)
            try:
                await asyncio.Event().wait()
            finally:
                await server.aclose()

        try:
            asyncio.run(serve())
        except OSError as exc:
            raise UserError(f"--serve {args.serve}: {exc}") from None
        except KeyboardInterrupt:
            pass
    return 0

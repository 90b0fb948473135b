"""``phireman fly --tak URL``: the TAK options of the fly command (docs/tak.md)."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from mission.flight.tak_link import MAX_RATE_MSGS_S

__all__ = ["add_tak_arguments", "tak_options", "TLS_FLAGS"]

#: --tak-... flag -> pytak's configuration name (https://pytak.rtfd.io, "TLS").
TLS_FLAGS = {
    "tak_tls_client_cert": "PYTAK_TLS_CLIENT_CERT",
    "tak_tls_client_key": "PYTAK_TLS_CLIENT_KEY",
    "tak_tls_client_cafile": "PYTAK_TLS_CLIENT_CAFILE",
    "tak_tls_client_password": "PYTAK_TLS_CLIENT_PASSWORD",
}


def add_tak_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("TAK: crews from TAK phones, the mesh on TAK (docs/tak.md)")
    g.add_argument(
        "--tak",
        action="append",
        default=[],
        metavar="URL",
        help="a TAK connection, as pytak spells it: udp://239.2.3.1:6969 (ATAK mesh SA "
        "multicast), udp://HOST:PORT, tcp://HOST:PORT or tls://HOST:PORT (a TAK server); "
        "+ro / +wo after the scheme: receive / send only. The mission's 'tak' crews report "
        "on it, and the vehicles, base, radio links, task tree and crews' connectivity are "
        "published on it as Cursor on Target. Repeatable",
    )
    g.add_argument(
        "--tak-period-s",
        type=float,
        default=1.0,
        help="wall seconds between two published pictures (each uid once; default 1)",
    )
    g.add_argument(
        "--tak-max-rate",
        type=float,
        default=MAX_RATE_MSGS_S,
        metavar="MSGS_PER_S",
        help="messages a second per TAK connection, at most (default %(default)g: what "
        "FreeTAKServer relayed here without falling behind). Unchanged items are sent only "
        "to refresh them; when a picture is over budget the crews' markers, the base and the "
        "drones go first and the lines wait",
    )
    for flag, name in TLS_FLAGS.items():
        g.add_argument(
            "--" + flag.replace("_", "-"),
            default=None,
            metavar="PATH" if "password" not in flag else "TEXT",
            help=f"tls://: pytak's {name}",
        )
    g.add_argument(
        "--tak-tls-dont-verify",
        action="store_true",
        help="tls://: do not verify the server's certificate (pytak's PYTAK_TLS_DONT_VERIFY)",
    )
    g.add_argument(
        "--tak-tls-dont-check-hostname",
        action="store_true",
        help="tls://: do not check the server's host name (PYTAK_TLS_DONT_CHECK_HOSTNAME)",
    )


def _announce(info: dict) -> None:
    if "urls" in info:
        print(f"TAK: {', '.join(info['urls'])}", file=sys.stderr)
    if "published" in info:
        pub = ", ".join(f"{t} {n}" for t, n in sorted(info["published"].items()))
        c = info.get("counters", {})
        crews = info.get("crews", {})
        print(
            f"TAK published {info.get('batches', 0)} pictures: {pub or 'nothing'}; "
            f"{info.get('deferred', 0)} deferred (rate limit); sent {c.get('sent', 0)}, "
            f"dropped {c.get('dropped', 0)}; received "
            f"{c.get('received', 0)} ({c.get('reports', 0)} reports, {c.get('bad', 0)} bad); "
            f"crews: {crews.get('reports', 0)} reports used, {crews.get('expired', 0)} went "
            f"stale, {crews.get('joined', 0)} joined",
            file=sys.stderr,
        )
    sys.stderr.flush()


def tak_options(opts, args):
    """``opts`` (FlyOptions) with the TAK options of ``args``; UserError if invalid."""
    from mission.commands.options import UserError
    from mission.format.schema import tak_url_problem
    from mission.view.tak import attach

    for url in args.tak:
        msg = tak_url_problem(url)
        if msg:
            raise UserError(f"--tak: {msg}")
    if not args.tak_period_s > 0:
        raise UserError(f"--tak-period-s must be > 0, got {args.tak_period_s}")
    if not args.tak_max_rate * args.tak_period_s >= 1:
        raise UserError(
            f"--tak-max-rate {args.tak_max_rate:g} x --tak-period-s {args.tak_period_s:g} "
            "must allow at least one message a picture"
        )
    tls = {name: getattr(args, flag) for flag, name in TLS_FLAGS.items() if getattr(args, flag)}
    if args.tak_tls_dont_verify:
        tls["PYTAK_TLS_DONT_VERIFY"] = "1"
    if args.tak_tls_dont_check_hostname:
        tls["PYTAK_TLS_DONT_CHECK_HOSTNAME"] = "1"
    if tls and not any(u.lower().startswith("tls") for u in args.tak):
        raise UserError("--tak-tls-* options need a --tak tls://HOST:PORT connection")
    return dataclasses.replace(
        opts,
        tak=tuple(args.tak),
        tak_tls=tls or None,
        tak_period_s=args.tak_period_s,
        tak_max_rate_msgs_s=args.tak_max_rate,
        attach_tak=attach if args.tak else None,
        on_tak=_announce,
    )

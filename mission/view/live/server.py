"""The web server of the live view and of the replay: one page, a JSON API, Server-Sent Events.

Runs on the station's own asyncio loop (aiohttp), so every read of the operator's state and every
operator action happens on that loop, between two polls of the station, never from a thread. A
recorded run, which shares nothing with a station, may be served from a thread of its own
(:func:`serve_in_thread`, for a script or a test that drives the page meanwhile).

Routes::

    GET  /                 the page (static/index.html; Leaflet vendored under static/leaflet)
    GET  /api/meta         what does not change (mission, base, crews, zones, fence, mode)
    GET  /api/frame        the current frame (live) or ?i=K, the K-th recorded frame (replay);
                           &truth=1 adds the emulator's truth (replay of an emulated run only;
                           404 with a JSON {"error": ...} where there is none, as live)
    GET  /api/stream       live: Server-Sent Events, one frame per message, several a second
    POST /api/action       live: {"action": "rtl", "vehicle": "0:7" | "all"}, header
                           X-Operator-Key: the key the station printed; 403 without it
    POST /api/ack          live: {"alert": 3 | "all"}: the operator acknowledges an alert
                           (same key; logged to events.jsonl, mission.view.live.alerts)
    GET  /tiles/{z}/{x}/{y}.{ext}   --tiles DIR: the XYZ tiles of that folder
    GET  /api/terrain.png  a terrain mission: shaded relief and contours (bounds in meta.terrain)
    GET  /api/profile?a=N,E,H&b=N,E,H   a terrain mission: the profile of the link between two
                           antennas (north, east metres, height AMSL metres) as JSON
                           (mission.view.live.terrain; 404 for a mission without terrain)

Security: loopback by default; actions need the operator key (a random secret printed at start,
compared in constant time) or are off (``--serve-actions off``); the key travels in a header,
which a page of another origin cannot set without a CORS pre-flight that this server never
allows, so a malicious page open in the same browser cannot command vehicles. Every action is
logged with the client's address.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import json
import logging
import re
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

from aiohttp import web

__all__ = [
    "LiveServer",
    "parse_serve",
    "serve_in_thread",
    "STATIC_DIR",
    "tiles_meta",
    "TruthUnavailable",
]

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).resolve().parent / "static"


class Source(Protocol):
    """What the server shows: a live station (:class:`mission.view.live.station.LiveStation`) or a
    recorded run (:class:`mission.view.live.replay.ReplaySource`).

    ``frame(index, truth=True)`` raises :class:`TruthUnavailable` when the source has no truth
    (always live: the station never sees the emulator's truth; a replay without truth.npz)."""

    def meta(self) -> dict: ...

    def frame(self, index: int | None = None, truth: bool = False) -> dict: ...


class TruthUnavailable(LookupError):
    """The emulator's truth was asked of a source that has none (-> HTTP 404)."""


def _json_error(cls, text: str) -> web.HTTPException:
    """An HTTP error whose body is ``{"error": text}`` (what the API answers on failure)."""
    return cls(text=json.dumps({"error": text}), content_type="application/json")


def parse_serve(text: str | int) -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); the host defaults to loopback (127.0.0.1)."""
    s = str(text).strip()
    m = re.fullmatch(r"(?:\[(?P<h6>[^\]]+)\]:|(?P<h>[^:\[\]]*):)?(?P<p>\d+)", s)
    if not m:
        raise ValueError(
            f"expected [HOST:]PORT, e.g. 8080, 127.0.0.1:8080 or 0.0.0.0:8080, got {text!r}"
        )
    host = m.group("h6") or m.group("h") or "127.0.0.1"
    port = int(m.group("p"))
    if not 0 <= port <= 65535:
        raise ValueError(f"port {port} out of range")
    return host, port


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def tiles_meta(tiles: str | None) -> tuple[dict | None, Path | None]:
    """``--tiles`` -> (what the page needs, the local folder to serve or None).

    A folder holds XYZ tiles ``Z/X/Y.png`` (or .jpg/.jpeg/.webp); anything with ``{z}``,
    ``{x}`` and ``{y}`` is a URL template the browser fetches itself (the station does not)."""
    if not tiles:
        return None, None
    if all(k in tiles for k in ("{z}", "{x}", "{y}")):
        return {"url": tiles, "source": "template"}, None
    folder = Path(tiles).expanduser()
    if not folder.is_dir():
        raise ValueError(
            f"--tiles {tiles!r}: neither a folder of XYZ tiles (Z/X/Y.png) nor a "
            "URL template with {z}, {x} and {y}"
        )
    ext = "png"
    for f in folder.rglob("*"):
        if f.is_file() and f.suffix.lower() in (".png", ".jpg", ".jpeg", ".webp"):
            ext = f.suffix.lower()[1:]
            break
    zooms = sorted(int(p.name) for p in folder.iterdir() if p.is_dir() and p.name.isdigit())
    return {
        "url": f"/tiles/{{z}}/{{x}}/{{y}}.{ext}",
        "source": "folder",
        "min_zoom": zooms[0] if zooms else 0,
        "max_zoom": zooms[-1] if zooms else 19,
    }, folder


class LiveServer:
    """Serve ``source`` on ``host:port`` (port 0: an ephemeral port, see :attr:`url`).

    ``key``: the operator key for actions (None: read-only). Frames are pushed with
    :meth:`publish` (live); replay sources answer :meth:`Source.frame` per request."""

    def __init__(
        self,
        source,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        key: str | None = None,
        tiles_dir: Path | None = None,
    ) -> None:
        self.source = source
        self.host, self.port = host, int(port)
        self.key = key
        self.tiles_dir = tiles_dir
        self._latest: tuple[int, bytes] = (0, b"")
        self._changed = asyncio.Event()
        self.clients = 0
        self._runner: web.AppRunner | None = None
        self._closing = False
        app = web.Application(middlewares=[_no_cache])
        app.router.add_get("/", self._index)
        app.router.add_get("/api/meta", self._meta)
        app.router.add_get("/api/frame", self._frame)
        app.router.add_get("/api/stream", self._stream)
        app.router.add_post("/api/action", self._action)
        app.router.add_get("/api/terrain.png", self._terrain_png)
        app.router.add_get("/api/profile", self._profile)
        app.router.add_post("/api/ack", self._ack)
        app.router.add_get(r"/tiles/{z:\d+}/{x:\d+}/{y:\d+}.{ext:(png|jpg|jpeg|webp)}", self._tile)
        app.router.add_static("/static", STATIC_DIR, follow_symlinks=False)
        self.app = app

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        if host in ("0.0.0.0", "[::]"):
            host = "127.0.0.1"
        return f"http://{host}:{self.port}/"

    async def start(self) -> LiveServer:
        self._runner = web.AppRunner(self.app, access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port, reuse_address=True)
        await site.start()
        sock = site._server.sockets[0]  # type: ignore[union-attr]  # the bound port (0 -> ephemeral)
        self.port = sock.getsockname()[1]
        if not is_loopback(self.host):
            log.warning(
                "live view served on %s:%d: reachable from other machines%s",
                self.host,
                self.port,
                "" if self.key is None else " (actions still need the operator key)",
            )
        return self

    async def aclose(self) -> None:
        self._closing = True
        self._changed.set()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    # ------------------------------------------------------------------ live push

    def publish(self, frame: dict | bytes) -> None:
        data = (
            frame
            if isinstance(frame, bytes)
            else json.dumps(frame, allow_nan=False, separators=(",", ":")).encode()
        )
        self._latest = (self._latest[0] + 1, data)
        ev, self._changed = self._changed, asyncio.Event()
        ev.set()

    # ------------------------------------------------------------------ handlers

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC_DIR / "index.html")

    async def _meta(self, request: web.Request) -> web.Response:
        meta = dict(self.source.meta())
        meta["actions"] = bool(meta.get("actions")) and self.key is not None
        terrain = getattr(self.source, "terrain", None)
        meta["terrain"] = None if terrain is None else terrain.meta()
        return web.json_response(meta)

    def _terrain(self):
        terrain = getattr(self.source, "terrain", None)
        if terrain is None:
            raise _json_error(web.HTTPNotFound, "this mission has no terrain (radio.model: disc)")
        return terrain

    async def _terrain_png(self, request: web.Request) -> web.Response:
        terrain = self._terrain()
        # Rendered once, in a worker thread: the station's loop keeps polling meanwhile.
        png = await asyncio.get_running_loop().run_in_executor(None, terrain.png)
        return web.Response(body=png, content_type="image/png")

    async def _profile(self, request: web.Request) -> web.Response:
        from mission.view.live.terrain import parse_end

        terrain = self._terrain()
        try:
            a, b = parse_end(request.query["a"]), parse_end(request.query["b"])
        except (KeyError, ValueError) as exc:
            raise _json_error(
                web.HTTPBadRequest, f"expected ?a=N,E,H&b=N,E,H (metres, heights AMSL): {exc}"
            ) from None
        return web.json_response(terrain.profile(a, b))

    async def _frame(self, request: web.Request) -> web.Response:
        i = request.query.get("i")
        truth = request.query.get("truth", "0") not in ("", "0", "false", "no")
        try:
            index = None if i is None else int(i)
        except ValueError:
            raise _json_error(web.HTTPBadRequest, f"i must be a frame number, got {i!r}") from None
        try:
            frame = self.source.frame(index, truth=truth)
        except TruthUnavailable as exc:
            raise _json_error(web.HTTPNotFound, str(exc)) from None
        except (ValueError, IndexError) as exc:
            raise _json_error(web.HTTPBadRequest, str(exc)) from None
        return web.json_response(frame, dumps=lambda o: json.dumps(o, allow_nan=False))

    async def _stream(self, request: web.Request) -> web.StreamResponse:
        resp = web.StreamResponse(
            headers={
                "Content-Type": "text/event-stream",
                "Cache-Control": "no-cache",
                "X-Accel-Buffering": "no",
            }
        )
        await resp.prepare(request)
        self.clients += 1
        seen = -1
        try:
            while not self._closing:
                seq, data = self._latest
                if seq == seen or not data:
                    try:
                        await asyncio.wait_for(self._changed.wait(), 15.0)
                    except TimeoutError:
                        await resp.write(b": keep-alive\n\n")
                    continue
                seen = seq
                await resp.write(b"data: " + data + b"\n\n")
        except (ConnectionResetError, asyncio.CancelledError, RuntimeError):
            pass
        finally:
            self.clients -= 1
        return resp

    def _check_key(self, request: web.Request) -> None:
        """403 unless the request carries the operator key."""
        assert self.key is not None  # the callers refuse first when actions are off
        # Header values arrive as str decoded from bytes; a key with bytes that are not UTF-8
        # (surrogate escapes) cannot be encoded back: it is simply not the key (403, not 500).
        try:
            given = request.headers.get("X-Operator-Key", "").encode("utf-8", "surrogateescape")
        except UnicodeError:
            given = b""
        if not given or not hmac.compare_digest(given, self.key.encode()):
            log.warning("web action refused: wrong or missing operator key from %s", request.remote)
            raise web.HTTPForbidden(text="wrong or missing operator key")

    async def _operator(
        self,
        request: web.Request,
        method: str,
        refused: str,
        expected: str,
        args,
        errors: tuple[type[Exception], ...] = (ValueError, KeyError, LookupError),
    ) -> web.Response:
        """An operator's POST: the source's ``method`` called with ``args(body)`` and the
        client's address. 403 saying ``refused`` on a read-only view (no such method, or no
        key), 403 without the right key, 400 saying ``expected`` for a body that does not parse,
        400 with the source's own words when it raises one of ``errors``."""
        call = getattr(self.source, method, None)
        if call is None or self.key is None:
            raise web.HTTPForbidden(text=refused)
        self._check_key(request)
        try:
            given = args(await request.json())
        except (ValueError, KeyError, TypeError):
            raise web.HTTPBadRequest(text=expected) from None
        try:
            done = call(*given, f"web {request.remote}")
        except errors as exc:
            raise web.HTTPBadRequest(text=str(exc)) from None
        return web.json_response({"done": done})

    async def _ack(self, request: web.Request) -> web.Response:
        return await self._operator(
            request,
            "acknowledge",
            "acknowledging needs the operator key: read-only view",
            'expected {"alert": ID | "all"}',
            lambda body: (str(body["alert"]),),
            errors=(ValueError, KeyError),
        )

    async def _action(self, request: web.Request) -> web.Response:
        return await self._operator(
            request,
            "act",
            "actions are off: this view is read-only",
            'expected {"action": ..., "vehicle": "L:S" | "all"}',
            lambda body: (str(body["action"]), str(body.get("vehicle", ""))),
        )

    async def _tile(self, request: web.Request) -> web.StreamResponse:
        if self.tiles_dir is None:
            raise web.HTTPNotFound()
        m = request.match_info
        path = self.tiles_dir / m["z"] / m["x"] / f"{m['y']}.{m['ext']}"
        if not path.is_file():
            raise web.HTTPNotFound()
        return web.FileResponse(path)


@contextlib.contextmanager
def serve_in_thread(source: Source, host: str = "127.0.0.1", port: int = 0) -> Iterator[str]:
    """Serve a recorded run (a replay source: read-only, nothing shared with a station's loop)
    from a background thread with its own event loop, for a script or a test that drives the
    page from this thread; yields the page's URL, closes the server on leaving.

    Raises
    ------
    OSError
        The server could not listen on ``host:port``.
    TimeoutError
        It did not start within a minute.
    """
    box: dict = {}
    ready = threading.Event()

    async def main() -> None:
        try:
            server = await LiveServer(source, host, port).start()
        except Exception as exc:  # raised again in the caller's thread
            box["error"] = exc
            ready.set()
            return
        box.update(url=server.url, stop=asyncio.Event(), loop=asyncio.get_running_loop())
        ready.set()
        await box["stop"].wait()
        await server.aclose()

    th = threading.Thread(target=asyncio.run, args=(main(),), name="live-page", daemon=True)
    th.start()
    if not ready.wait(60.0):
        raise TimeoutError(f"the page did not start on {host}:{port} within a minute")
    if "error" in box:
        raise box["error"]
    try:
        yield box["url"]
    finally:
        box["loop"].call_soon_threadsafe(box["stop"].set)
        th.join(30.0)


@web.middleware
async def _no_cache(request, handler):
    resp = await handler(request)
    if not request.path.startswith("/tiles/"):
        resp.headers.setdefault("Cache-Control", "no-cache")
    resp.headers.setdefault("X-Content-Type-Options", "nosniff")
    return resp

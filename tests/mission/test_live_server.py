"""The live page's server without a browser: the operator's POSTs (actions, acknowledgements)
in memory, and a replay served from a background thread (loopback, port 0)."""

from __future__ import annotations

import asyncio
import json
import socket
import urllib.request

import pytest
from browser import get_json

from mission.view.live.server import LiveServer, serve_in_thread

KEY = "s3cret"


class _Source:
    """A live source that records what the operator asked and refuses what it cannot do."""

    terrain = None

    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def meta(self) -> dict:
        return {"mode": "live", "actions": True}

    def frame(self, index=None, truth=False) -> dict:
        if index is not None and index > 3:
            raise IndexError(f"frame {index} out of range 0..3")
        return {"i": 3 if index is None else index}

    def act(self, action: str, vehicle: str, source: str) -> str:
        if vehicle == "0:99":
            raise LookupError("no vehicle 0:99")
        self.calls.append(("act", action, vehicle, source))
        return f"{action} sent to {vehicle}"

    def acknowledge(self, alert: str, source: str) -> int:
        if alert == "7":
            raise KeyError("no alert 7")
        self.calls.append(("ack", alert, source))
        return 2


class _ReadOnly:
    terrain = None

    def meta(self) -> dict:
        return {"mode": "replay"}

    def frame(self, index=None, truth=False) -> dict:
        return {}


def _post_all(source, key: str | None, posts: list[tuple[str, object, str | None]]) -> list:
    """(status, text) of each POST (path, body, key header) to a server of ``source``."""
    from aiohttp.test_utils import TestClient, TestServer

    async def go():
        out = []
        async with TestClient(TestServer(LiveServer(source, key=key).app)) as c:
            for path, body, given in posts:
                headers = {} if given is None else {"X-Operator-Key": given}
                data = body if isinstance(body, bytes) else json.dumps(body).encode()
                r = await c.post(path, data=data, headers=headers)
                out.append((r.status, await r.text()))
        return out

    return asyncio.run(go())


def test_operator_posts_need_the_key_and_a_body_that_parses():
    src = _Source()
    got = _post_all(
        src,
        KEY,
        [
            ("/api/action", {"action": "rtl", "vehicle": "0:3"}, KEY),
            ("/api/action", {"action": "rtl", "vehicle": "0:3"}, None),
            ("/api/action", {"action": "rtl", "vehicle": "0:3"}, "wrong"),
            ("/api/action", {"vehicle": "0:3"}, KEY),
            ("/api/action", b"not json", KEY),
            ("/api/action", {"action": "hold", "vehicle": "0:99"}, KEY),
            ("/api/ack", {"alert": "all"}, KEY),
            ("/api/ack", {"alert": "all"}, "wrong"),
            ("/api/ack", {"id": 3}, KEY),
            ("/api/ack", {"alert": 7}, KEY),
        ],
    )
    assert got[0] == (200, json.dumps({"done": "rtl sent to 0:3"}))
    assert got[1][0] == got[2][0] == 403 and "operator key" in got[1][1]
    assert got[3] == got[4] == (400, 'expected {"action": ..., "vehicle": "L:S" | "all"}')
    assert got[5] == (400, "no vehicle 0:99")
    assert got[6] == (200, json.dumps({"done": 2}))
    assert got[7][0] == 403
    assert got[8] == (400, 'expected {"alert": ID | "all"}')
    assert got[9] == (400, "'no alert 7'")
    # Only what passed the key and the parse reached the source, with the client's address.
    assert [c[:-1] for c in src.calls] == [("act", "rtl", "0:3"), ("ack", "all")]
    assert all(c[-1].startswith("web 127.0.0.1") for c in src.calls)


def test_a_read_only_view_refuses_every_operator_post():
    for source, key in ((_ReadOnly(), KEY), (_Source(), None)):
        got = _post_all(
            source,
            key,
            [
                ("/api/action", {"action": "rtl", "vehicle": "all"}, KEY),
                ("/api/ack", {"alert": "all"}, KEY),
            ],
        )
        assert got == [
            (403, "actions are off: this view is read-only"),
            (403, "acknowledging needs the operator key: read-only view"),
        ]


@pytest.mark.udp
def test_serve_in_thread_answers_from_its_thread_and_stops():
    with serve_in_thread(_Source()) as url:
        assert url.startswith("http://127.0.0.1:") and not url.endswith(":0/")
        assert get_json(url + "api/frame?i=2") == (200, {"i": 2})
        code, body = get_json(url + "api/frame?i=9")
        assert code == 400 and "out of range" in body["error"]
    with pytest.raises(OSError):
        urllib.request.urlopen(url + "api/frame", timeout=10)


@pytest.mark.udp
def test_serve_in_thread_raises_when_it_cannot_listen():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(OSError), serve_in_thread(_ReadOnly(), port=port):
            pass

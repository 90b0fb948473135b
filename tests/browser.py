"""The real headless browser the page tests drive (Debian chromium + chromedriver, selenium):
the ``browser`` fixture (one per test module), ``_wait``, and ``live_flight``: an emulated flight
with its live page on loopback port 0, from a background thread (a replay is served likewise by
``mission.view.live.server.serve_in_thread``); ``get_json`` and ``post_json`` ask the page's API
directly. Skipped, loudly, when chromium or chromedriver is missing
(``apt-get install -y chromium chromium-driver``)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
import threading
import time
import urllib.error
import urllib.request

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    if not (CHROMIUM and CHROMEDRIVER):
        pytest.skip(
            "BROWSER TEST SKIPPED: chromium / chromedriver not installed "
            "(apt-get install -y chromium chromium-driver)"
        )
    webdriver = pytest.importorskip(
        "selenium.webdriver", reason="BROWSER TEST SKIPPED: no selenium"
    )
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    for a in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--window-size=1400,900",
        f"--user-data-dir={tmp_path_factory.mktemp('chrome-profile')}",
    ):
        opts.add_argument(a)
    opts.binary_location = CHROMIUM
    drv = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    yield drv
    drv.quit()


def _wait(cond, timeout_s: float, what: str):
    end = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < end:
        try:
            last = cond()
            if last:
                return last
        except Exception as exc:  # noqa: BLE001 - page still loading
            last = exc
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what} (last: {last!r})")


@contextlib.contextmanager
def live_flight(mission, out_dir, hook=None, *, box=None, join_s: float = 180.0, **options):
    """Fly ``mission`` emulated (in process unless ``options`` say otherwise) from a thread,
    the live page served on loopback port 0; ``options`` are more :class:`FlyOptions`.

    Yields ``(info, box)`` once the page is up: ``info`` what the flight announced (``url``,
    ``key``), ``box`` (the one given, or a new dict) gets ``result`` (the flight's result) or
    ``error`` when the flight ends. ``hook(op, world)`` runs at every operator tick. On leaving,
    the flight is told to end (phase ``done``) and its thread joined; then its error, if any,
    fails the test."""
    from mission.flight.runners import FlyOptions, fly_emulated_async
    from mission.view.live import attach

    info: dict = {}
    box = {} if box is None else box
    stop = threading.Event()

    def on_operator(op, world):
        if hook is not None:
            hook(op, world)
        if stop.is_set():
            op.phase = "done"

    opts = FlyOptions(
        **{"emulator_in_process": True, **options},
        out_dir=str(out_dir),
        serve="127.0.0.1:0",
        attach_view=attach,
        on_live=info.update,
        on_operator=on_operator,
    )

    def run():
        try:
            box["result"] = asyncio.run(fly_emulated_async(mission, opts))
        except BaseException as exc:  # noqa: BLE001 - reported by the test's thread
            box["error"] = exc

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        _wait(lambda: info.get("url") or "error" in box, 120, "the live view to start")
        if "error" in box:
            raise box["error"]
        yield info, box
    finally:
        stop.set()
        th.join(join_s)
    assert "error" not in box, box.get("error")


def get_json(url: str) -> tuple[int, dict]:
    """The HTTP status and JSON body of a GET (an error's too)."""
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read())


def post_json(url: str, body: dict, key: str | None = None) -> tuple[int, bytes]:
    """The HTTP status and body of a JSON POST, with the operator key if given."""
    headers = {"Content-Type": "application/json"}
    if key is not None:
        headers["X-Operator-Key"] = key
    req = urllib.request.Request(
        url, data=json.dumps(body).encode(), method="POST", headers=headers
    )
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as err:
        return err.code, err.read()

"""A real TAK server in the loop (FreeTAKServer), when one is installed: two TAK clients on TCP
exchange Cursor-on-Target through it. FreeTAKServer is not a dependency of phireman (docs/tak.md
says why): point PHIREMAN_FTS_PYTHON at the python of a venv where it runs, else this skips,
saying so."""

from __future__ import annotations

import asyncio
import os
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest

from gcs.cot import CotStream, cot_xml, parse_cot

pytestmark = pytest.mark.udp

FTS_PYTHON = os.environ.get("PHIREMAN_FTS_PYTHON")
SKIP_REASON = (
    "no TAK server: FreeTAKServer 2.2.1 (PyPI) runs headless here only in its own venv with "
    "opentelemetry-sdk==1.16.0 pinned (its unpinned 1.4x breaks it), writes to the hard-coded "
    "/opt/fts and binds fixed ports (8080, 8089, 8443, 19023 on 0.0.0.0; 19030-19034), so it is "
    "not installed by phireman; OpenTAKServer needs PostgreSQL and RabbitMQ services. Set "
    "PHIREMAN_FTS_PYTHON to such a venv's python to run this (docs/tak.md). The plain-UDP "
    "end-to-end test (tests/integration/test_tak_udp.py) covers the station without a server."
)


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.skipif(not FTS_PYTHON, reason=SKIP_REASON)
def test_two_tak_clients_through_freetakserver(tmp_path):
    port = _free_tcp_port()
    env = dict(os.environ, FTS_FIRST_START="false")
    proc = subprocess.Popen(
        [
            FTS_PYTHON,
            "-m",
            "FreeTAKServer.controllers.services.FTS",
            "-CoTPort",
            str(port),
            "-CoTIP",
            "127.0.0.1",
            "-AutoStart",
            "True",
        ],
        cwd=tmp_path,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own process group: FTS forks service processes
    )
    try:
        deadline = time.monotonic() + 90
        while True:  # the server's CoT port accepts connections
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert proc.poll() is None, "FreeTAKServer exited at start"
                assert time.monotonic() < deadline, "FreeTAKServer CoT port never opened"
                time.sleep(0.5)

        async def exchange():
            ra, wa = await asyncio.open_connection("127.0.0.1", port)
            rb, wb = await asyncio.open_connection("127.0.0.1", port)
            for w, uid, cs in ((wa, "ANDROID-a", "ALPHA"), (wb, "ANDROID-e7", "ENGINE-7")):
                w.write(
                    cot_xml(
                        uid=uid,
                        type="a-f-G-U-C",
                        lat_deg=-35.36,
                        lon_deg=149.16,
                        now_unix_s=time.time(),
                        stale_after_s=60,
                        callsign=cs,
                    )
                )
                await w.drain()
            await asyncio.sleep(1.0)
            wa.write(
                cot_xml(
                    uid="ANDROID-a",
                    type="a-f-G-U-C",
                    lat_deg=-35.361,
                    lon_deg=149.16,
                    now_unix_s=time.time(),
                    stale_after_s=60,
                    callsign="ALPHA",
                )
            )
            await wa.drain()
            stream, got = CotStream(), []
            try:
                while "ANDROID-a" not in got:
                    data = await asyncio.wait_for(rb.read(65536), 10)
                    if not data:
                        break
                    got += [parse_cot(m).uid for m in stream.feed(data)]
            except TimeoutError:
                pass
            for w in (wa, wb):
                w.close()
            return got

        assert "ANDROID-a" in asyncio.run(exchange())
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)  # the server and every service it forked
            proc.wait(10)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        if Path("/opt/fts").exists() and os.environ.get("PHIREMAN_FTS_CLEAN") == "1":
            shutil.rmtree("/opt/fts", ignore_errors=True)

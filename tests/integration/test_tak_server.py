"""A real TAK server in the loop (FreeTAKServer), when one is installed: two TAK clients on TCP
exchange Cursor-on-Target through it. FreeTAKServer is not a dependency of phireman (docs/tak.md
says why): point PHIREMAN_FTS_PYTHON at the python of a venv where it runs, else this skips,
saying so."""

from __future__ import annotations

import asyncio
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gcs.cot import CotStream, cot_xml, parse_cot
from tak_clients import CrewPhone, tak_mission

pytestmark = pytest.mark.udp

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]

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


@pytest.fixture(scope="module")
def fts_port(tmp_path_factory):
    """A FreeTAKServer with its CoT TCP port on loopback (the module's tests share it)."""
    if not FTS_PYTHON:
        pytest.skip(SKIP_REASON)
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
        cwd=tmp_path_factory.mktemp("fts"),
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own process group: FTS forks service processes
    )
    try:
        deadline = time.monotonic() + 120
        while True:  # the server's CoT port accepts connections
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert proc.poll() is None, "FreeTAKServer exited at start"
                assert time.monotonic() < deadline, "FreeTAKServer CoT port never opened"
                time.sleep(0.5)
        yield port
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


def test_two_tak_clients_through_freetakserver(fts_port):
    port = fts_port

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


def test_phireman_fly_through_freetakserver(fts_port, tmp_path):
    """``phireman fly --tak tcp://`` through the server, with two crews' phones on it: the
    station plans for the crews the server relays, and both phones see the vehicles, the links
    and their crews' connectivity; Alpha moves and its marker follows (the latency is printed);
    Engine falls silent and is shown as unknown."""
    url = f"tcp://127.0.0.1:{fts_port}"
    path = tak_mission(tmp_path / "tak.yaml", duration_s=60.0, speedup=2.0)
    moved_ne = (60.0, 60.0)
    # Times from when each phone first hears the station. Alpha stands 60 m north, then after
    # 12 s steps 60 m east (to a fixed new spot); Engine 7
    # stands 60 m south and falls silent after 15 s (its last report stale 2 s later).
    alpha = CrewPhone("ANDROID-alpha", "ALPHA", lambda t: (60.0, 0.0) if t < 12.0 else moved_ne)
    engine = CrewPhone("ANDROID-e7", "ENGINE-7", lambda t: (-60.0, 0.0), stop_after_s=15.0)
    cmd = [*PHIREMAN, "fly", str(path), "--out", str(tmp_path / "runs"), "--tak", url]
    cmd += ["--tak-period-s", "0.5"]

    async def main():
        done = asyncio.Event()
        clients = asyncio.gather(alpha.run(url, url, done), engine.run(url, url, done))
        await asyncio.sleep(1.0)  # the phones are on the server before the station
        proc = await asyncio.create_subprocess_exec(
            *cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
        try:
            out, err = await asyncio.wait_for(proc.communicate(), 300)
        finally:
            done.set()
            await clients
            if proc.returncode is None:
                proc.kill()
        return proc.returncode, out.decode(), err.decode()

    rc, out, err = asyncio.run(main())
    assert rc == 0, err[-3000:]
    print(err[-1200:])
    for phone in (alpha, engine):
        print(f"client {phone.callsign} received by CoT type:", dict(phone.got))
        print(f"client {phone.callsign} crew markers:", dict(phone.markers))
    latency_s = alpha.marker_latency_s("Alpha", moved_ne, tol_m=1.0)
    print(f"Alpha moved: its marker moved on the phone {latency_s:.2f} s later (wall)")
    for phone in (alpha, engine):  # what the server relayed from the station
        g = phone.got
        assert g["a-f-A-M-H-Q"] >= 6 and g["a-f-G-I"] >= 1, dict(g)
        assert g["u-d-f"] > 0 and g["b-m-p-s-m"] > 0 and g["bad"] == 0, dict(g)
    assert "Alpha: mesh OK" in alpha.markers
    assert "Engine: UNKNOWN" in alpha.markers  # silent: stale, shown as unknown
    # The crew marker is drawn where the station plans the crew: it followed Alpha's move.
    assert math.isfinite(latency_s), alpha.marker_log[-5:]
    run = next((tmp_path / "runs").iterdir())
    reports = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    callsigns = {r["callsign"] for r in reports if r["type"] == "TakContactReported"}
    assert callsigns == {"ALPHA", "ENGINE-7"}
    assert "1 went stale" in err and "1 joined" in err

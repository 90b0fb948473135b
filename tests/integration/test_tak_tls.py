"""``phireman fly --tak tls://`` with a client certificate, as a TAK server's TLS port wants it.

The server here is a small CoT relay written in this test (asyncio with Python's ``ssl``): it
requires a client certificate signed by its CA, as a TAK server does, records who connected and
what the station published, and sends one crew's reports to the station. Certificates are made
with the ``openssl`` command line (skipped when it is missing). A client certificate from
another CA is refused, and ``phireman fly`` says so in one line."""

from __future__ import annotations

import asyncio
import collections
import json
import shutil
import ssl
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gcs.cot import CotError, CotStream, cot_xml, parse_cot
from planner.geometry import ned_to_geodetic
from tak_clients import ORIGIN, tak_mission

pytestmark = [
    pytest.mark.udp,
    pytest.mark.skipif(shutil.which("openssl") is None, reason="no openssl command to make certs"),
]

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


def _ca(d: Path, name: str) -> None:
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}.key",
             "-out", f"{name}.pem", "-days", "2", "-subj", f"/CN={name}", cwd=d)  # fmt: skip


def _cert(d: Path, name: str, ca: str, cn: str) -> None:
    _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}.key", "-out",
             f"{name}.csr", "-subj", f"/CN={cn}", cwd=d)  # fmt: skip
    (d / f"{name}.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
             "-CAcreateserial", "-out", f"{name}.pem", "-days", "2", "-extfile",
             f"{name}.ext", cwd=d)  # fmt: skip


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("certs")
    _ca(d, "ca")
    _ca(d, "rogue-ca")
    _cert(d, "server", "ca", "localhost")
    _cert(d, "station", "ca", "phireman-station")
    _cert(d, "rogue", "rogue-ca", "phireman-station")
    return d


class Relay:
    """A TLS CoT endpoint that requires a client certificate from ``ca.pem``."""

    def __init__(self, certs: Path) -> None:
        self.ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        self.ctx.load_cert_chain(certs / "server.pem", certs / "server.key")
        self.ctx.load_verify_locations(certs / "ca.pem")
        self.ctx.verify_mode = ssl.CERT_REQUIRED
        self.got: collections.Counter[str] = collections.Counter()
        self.peers: list[str] = []
        self.refused = 0

    async def handle(self, reader, writer) -> None:
        cert = writer.get_extra_info("peercert") or {}
        self.peers.append(dict(x[0] for x in cert.get("subject", ()))["commonName"])
        stream = CotStream()

        async def crew() -> None:  # Alpha's phone, reporting through the server
            lat, lon, _ = ned_to_geodetic(np.array([60.0, 0.0, 0.0]), *ORIGIN)
            while True:
                writer.write(
                    cot_xml(
                        uid="ANDROID-alpha",
                        type="a-f-G-U-C",
                        lat_deg=float(lat),
                        lon_deg=float(lon),
                        now_unix_s=time.time(),
                        stale_after_s=5.0,
                        callsign="ALPHA",
                    )  # fmt: skip
                )
                await writer.drain()
                await asyncio.sleep(0.5)

        task = asyncio.create_task(crew())
        try:
            while data := await reader.read(65536):
                for m in stream.feed(data):
                    try:
                        self.got[parse_cot(m).type] += 1
                    except CotError:
                        self.got["bad"] += 1
        except (ConnectionError, ssl.SSLError):
            pass
        finally:
            task.cancel()
            writer.close()


def _fly(certs: Path, tmp_path: Path, client: str) -> tuple[int, str, Relay]:
    relay = Relay(certs)
    path = tak_mission(tmp_path / "tak.yaml", duration_s=20.0, speedup=2.0)

    async def main():
        server = await asyncio.start_server(relay.handle, "127.0.0.1", 0, ssl=relay.ctx)
        port = server.sockets[0].getsockname()[1]
        cmd = [*PHIREMAN, "fly", str(path), "--out", str(tmp_path / "runs"),
               "--tak", f"tls://127.0.0.1:{port}", "--tak-tls-client-cert",
               str(certs / f"{client}.pem"), "--tak-tls-client-key", str(certs / f"{client}.key"),
               "--tak-tls-client-cafile", str(certs / "ca.pem"), "--tak-period-s", "0.5"]  # fmt: skip
        proc = await asyncio.create_subprocess_exec(
            *cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
        try:
            _, err = await asyncio.wait_for(proc.communicate(), 300)
        finally:
            if proc.returncode is None:
                proc.kill()
            server.close()
        return proc.returncode, err.decode()

    rc, err = asyncio.run(main())
    return rc, err, relay


def test_phireman_fly_over_tls_with_a_client_certificate(certs, tmp_path):
    rc, err, relay = _fly(certs, tmp_path, "station")
    print(err[-800:])
    print("TLS server received by CoT type:", dict(relay.got), "from", relay.peers)
    assert rc == 0, err[-3000:]
    assert relay.peers and set(relay.peers) == {"phireman-station"}
    assert relay.got["a-f-A-M-H-Q"] >= 6 and relay.got["b-m-p-s-m"] > 0
    assert relay.got["bad"] == 0
    run = next((tmp_path / "runs").iterdir())
    events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    assert any(e["type"] == "TakContactReported" and e["callsign"] == "ALPHA" for e in events)


def test_a_client_certificate_the_server_does_not_trust_is_one_clear_error(certs, tmp_path):
    rc, err, relay = _fly(certs, tmp_path, "rogue")
    assert rc != 0
    assert "Traceback" not in err, err[-3000:]
    assert "tls://127.0.0.1" in err, err[-2000:]
    assert relay.got["a-f-A-M-H-Q"] == 0

"""TAK end to end over loopback UDP: two pytak clients (one per crew) and ``phireman fly --tak``
as a user runs it. The crews report Cursor on Target, the station plans for them and publishes
the mesh; one crew falls silent and must be shown as unknown (stale). Ports are chosen free on
127.0.0.1 (never multicast in tests: a multicast datagram leaves on the machine's network)."""

from __future__ import annotations

import asyncio
import json
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tak_clients import CrewPhone, tak_mission

pytestmark = pytest.mark.udp

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_tak_crews_over_udp_with_phireman_fly(tmp_path):
    path = tak_mission(tmp_path / "tak.yaml", duration_s=40.0, speedup=2.0)
    p_in, p1, p2 = _free_udp_port(), _free_udp_port(), _free_udp_port()
    cmd = [
        *PHIREMAN,
        "fly",
        str(path),
        "--out",
        str(tmp_path / "runs"),
        "--tak",
        f"udp+ro://127.0.0.1:{p_in}",
        "--tak",
        f"udp+wo://127.0.0.1:{p1}",
        "--tak",
        f"udp+wo://127.0.0.1:{p2}",
        "--tak-period-s",
        "0.5",
    ]
    # From when each phone first hears the station: Alpha walks north from 60 m to 140 m over
    # 40 s (beyond the base's 100 m); Engine 7 stands
    # 60 m south and falls silent after 15 s (its last report stale 2 s later).
    alpha = CrewPhone("ANDROID-alpha", "ALPHA", lambda t: (60.0 + 2.0 * min(t, 40.0), 0.0))
    engine = CrewPhone("ANDROID-e7", "ENGINE-7", lambda t: (-60.0, 0.0), stop_after_s=15.0)

    async def main():
        proc = await asyncio.create_subprocess_exec(
            *cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
        done = asyncio.Event()
        clients = asyncio.gather(
            alpha.run(f"udp+ro://127.0.0.1:{p1}", f"udp+wo://127.0.0.1:{p_in}", done),
            engine.run(f"udp+ro://127.0.0.1:{p2}", f"udp+wo://127.0.0.1:{p_in}", done),
        )
        try:
            out, err = await asyncio.wait_for(proc.communicate(), 240)
        finally:
            done.set()
            await clients
            if proc.returncode is None:
                proc.kill()
        return proc.returncode, out.decode(), err.decode()

    rc, out, err = asyncio.run(main())
    assert rc == 0, err[-3000:]
    run = next((tmp_path / "runs").iterdir())
    print(err[-1500:])
    print("client ALPHA received:", dict(alpha.got))
    print("client ENGINE-7 received:", dict(engine.got))
    print("crew markers ALPHA client saw:", dict(alpha.markers))
    # Both clients received vehicles, the base, the links and the crews' connectivity.
    for g in (alpha.got, engine.got):
        assert g["a-f-A-M-H-Q"] >= 6 and g["a-f-G-I"] >= 1
        assert g["u-d-f"] > 0 and g["b-m-p-s-m"] > 0 and g["bad"] == 0
    labels = set(alpha.markers)
    assert "Alpha: mesh OK" in labels
    assert "Engine: UNKNOWN" in labels  # silent after 15 s: stale, shown as unknown
    # The station used both crews' reports and saw Engine 7 go stale.
    reports = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    reports = [r for r in reports if r["type"] == "TakContactReported"]
    assert {r["callsign"] for r in reports} == {"ALPHA", "ENGINE-7"}
    assert "1 went stale" in err and "1 joined" in err
    # The planner followed Alpha north: at the end a vehicle is within radio range of it.
    truth = np.load(run / "truth.npz")
    s = json.loads((run / "summary.json").read_text())
    assert s["phase"] == "done"
    last_alpha = max((r for r in reports if r["callsign"] == "ALPHA"), key=lambda r: r["t_s"])
    print("summary station TU:", s["station"])
    assert last_alpha["lat_deg"] > -35.36326
    del truth

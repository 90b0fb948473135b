"""TAK end to end over loopback UDP: two pytak clients (one per crew) and ``phireman fly --tak``
as a user runs it. The crews report Cursor on Target, the station plans for them and publishes
the mesh; one crew falls silent and must be shown as unknown (stale). Ports are chosen free on
127.0.0.1 (never multicast in tests: a multicast datagram leaves on the machine's network)."""

from __future__ import annotations

import asyncio
import collections
import configparser
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mission.format.load import dump_mission

pytestmark = pytest.mark.udp

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _mission(tmp_path: Path) -> Path:
    from mission.format.schema import RunSpec, TakSource, Task
    from small_mission import small_mission

    m = small_mission(
        "tak",
        RunSpec(duration_s=40.0, seed=3, speedup=2.0),
        count=6,
        tasks=(
            Task(name="Alpha", tak=TakSource(callsign="ALPHA")),
            Task(name="Engine", tak=TakSource(callsign_pattern="ENGINE-*")),
        ),
    )
    path = tmp_path / "tak.yaml"
    path.write_text(dump_mission(m))
    return path


async def _client(
    cfg_in: str,
    cfg_out: str,
    uid: str,
    callsign: str,
    track,
    stop_after_s: float,
    done: asyncio.Event,
    got: collections.Counter,
    seen: dict,
) -> None:
    import pytak

    from gcs.cot import CotError, cot_xml, parse_cot
    from planner.geometry import ned_to_geodetic

    def cfg(url):
        c = configparser.ConfigParser()
        c["c"] = {"COT_URL": url}
        return c["c"]

    _, writer = await pytak.protocol_factory(cfg(cfg_out))
    reader, _ = await pytak.protocol_factory(cfg(cfg_in))

    async def rx():
        while True:
            data, _ = await reader.recv()
            try:
                ev = parse_cot(data)
            except CotError:
                got["bad"] += 1
                continue
            got[ev.type] += 1
            if ev.type == "b-m-p-s-m":
                seen.setdefault(ev.callsign, 0)
                seen[ev.callsign] += 1

    task = asyncio.create_task(rx())
    t0 = time.monotonic()
    while not done.is_set():
        t = time.monotonic() - t0
        if t < stop_after_s:
            n, e = track(t)
            lat, lon, _ = ned_to_geodetic(np.array([n, e, 0.0]), -35.36326, 149.16523, 584.0)
            msg = cot_xml(
                uid=uid,
                type="a-f-G-U-C",
                lat_deg=float(lat),
                lon_deg=float(lon),
                hae_m=600.0,
                now_unix_s=time.time(),
                stale_after_s=2.0,
                callsign=callsign,
            )
            try:
                await writer.send(msg)
            except OSError:  # the station is not listening yet (ICMP port unreachable)
                got["refused"] += 1
        await asyncio.sleep(0.25)
    task.cancel()
    writer.close()
    reader.close()


def test_tak_crews_over_udp_with_phireman_fly(tmp_path):
    path = _mission(tmp_path)
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
    got = [collections.Counter(), collections.Counter()]
    seen: list[dict] = [{}, {}]

    async def main():
        proc = await asyncio.create_subprocess_exec(
            *cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
        done = asyncio.Event()
        # Alpha walks north from 60 m to 140 m over 40 s (beyond the base's 100 m); Engine 7
        # stands 60 m south and falls silent after 15 s (its last report stale 2 s later).
        alpha = _client(
            f"udp+ro://127.0.0.1:{p1}",
            f"udp+wo://127.0.0.1:{p_in}",
            "ANDROID-alpha",
            "ALPHA",
            lambda t: (60.0 + 2.0 * min(t, 40.0), 0.0),
            1e9,
            done,
            got[0],
            seen[0],
        )
        engine = _client(
            f"udp+ro://127.0.0.1:{p2}",
            f"udp+wo://127.0.0.1:{p_in}",
            "ANDROID-e7",
            "ENGINE-7",
            lambda t: (-60.0, 0.0),
            15.0,
            done,
            got[1],
            seen[1],
        )
        clients = asyncio.gather(alpha, engine)
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
    print("client ALPHA received:", dict(got[0]))
    print("client ENGINE-7 received:", dict(got[1]))
    print("crew markers ALPHA client saw:", seen[0])
    # Both clients received vehicles, the base, the links and the crews' connectivity.
    for g in got:
        assert g["a-f-A-M-H-Q"] >= 6 and g["a-f-G-I"] >= 1
        assert g["u-d-f"] > 0 and g["b-m-p-s-m"] > 0 and g["bad"] == 0
    labels = set(seen[0])
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

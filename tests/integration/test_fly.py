"""`phireman fly` over loopback UDP: the CLI end to end, the tlog read back, and a SIGKILLed
station restarted on the same links (port 0 only, deadlines, no fixed sleeps)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mission.format.load import dump_mission

pytestmark = pytest.mark.udp

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]


def _mission_file(tmp_path, count=6, duration_s=40.0, speedup=20.0):
    from mission.format.schema import RunSpec
    from small_mission import small_mission

    m = small_mission(
        "udp", RunSpec(duration_s=duration_s, seed=2, speedup=speedup), count=count, latency_s=0.01
    )
    path = tmp_path / "m.yaml"
    path.write_text(dump_mission(m))
    return path


def _phireman(*args, **kw):
    return subprocess.run([*PHIREMAN, *args], capture_output=True, text=True, cwd=ROOT, **kw)


def test_fly_cli_emulated_and_tlog_reads_back(tmp_path):
    path = _mission_file(tmp_path)
    out = _phireman("fly", str(path), "--out", str(tmp_path / "runs"), timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "TU1/TU2 from the emulator's truth" in out.stdout
    run = next((tmp_path / "runs").iterdir())
    s = json.loads((run / "summary.json").read_text())
    assert s["phase"] == "done" and s["truth"]["tu1"] > 0.8 and s["station"]["tu1"] > 0.8
    for name in ("mission.yaml", "run.json", "events.jsonl", "metrics.csv", "truth.npz"):
        assert (run / name).stat().st_size > 0
    # The .tlog reads back with pymavlink, message for message.
    from pymavlink import mavutil

    raw = (run / "flight.tlog").read_bytes()
    n_frames, off = 0, 0
    while off < len(raw):
        ln = raw[off + 9]
        off += 8 + 12 + ln + (13 if raw[off + 10] & 1 else 0)
        n_frames += 1
    assert off == len(raw)
    conn = mavutil.mavlink_connection(str(run / "flight.tlog"))
    n = 0
    while conn.recv_msg() is not None:
        n += 1
    assert n == n_frames and n > 1000
    # The run directory replays: emulator truth (mission interval only) drawn as PNGs.
    from mission.view.replay import load_run, replay

    data = load_run(run)
    assert 0.0 <= data.t_s[0] < 1.0 and data.pos_m.shape[2] == 2
    files = replay(run, tmp_path / "plots", animation="none")
    assert [f.name for f in files] == ["fig2_timeseries.png", "frames.png"]


def test_bad_input_is_a_user_error(tmp_path):
    out = _phireman("fly", "no-such-mission")
    assert out.returncode == 2 and "neither a mission file" in out.stderr
    out = _phireman("fly", "--speedup", "-1")
    assert out.returncode == 2


def _wait(cond, timeout_s, what):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_station_sigkilled_and_restarted_reclaims_every_live_vehicle(tmp_path):
    from mission.format.load import load_mission
    from mission.flight.runners import build_swarm, mission_scenario
    from vehicle_emu.udp import run_in_thread

    speedup = 10.0
    path = _mission_file(tmp_path, count=4, duration_s=400.0, speedup=speedup)
    mission = load_mission(path)
    swarm = build_swarm(mission, mission_scenario(mission, 2), seed=2)
    emu = run_in_thread(swarm, speedup=speedup)
    try:
        ((host, port),) = emu.addresses
        args = [
            "fly",
            str(path),
            "--connect",
            f"udpout:{host}:{port}",
            "--vehicles",
            "4",
            "--speedup",
            str(speedup),
            "--out",
            str(tmp_path / "runs"),
        ]
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        first = subprocess.Popen(
            [*PHIREMAN, *args],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
        )

        def guided():
            return emu.call(lambda: all(c.custom_mode == 4 and c.armed for c in swarm.cores))

        _wait(guided, 90, "first station to fly all 4 vehicles")
        first.send_signal(signal.SIGKILL)
        first.wait(10)
        # FS_GCS_TIMEOUT (5 s of vehicle time): every vehicle fails safe to RTL.
        _wait(
            lambda: emu.call(lambda: all(c.custom_mode == 6 for c in swarm.cores)),
            30,
            "vehicles to fail safe (RTL)",
        )
        t_restart = time.monotonic()
        second = subprocess.Popen(
            [*PHIREMAN, *args],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
        )
        try:
            _wait(guided, 90, "restarted station to reclaim every vehicle")
            wall = time.monotonic() - t_restart
            print(
                f"\nrestart -> every live vehicle reclaimed: {wall:.1f} s wall "
                f"({wall * speedup:.0f} s vehicle time)"
            )
            # The plan resumes: the vehicles receive fresh position targets.
            n0 = emu.call(lambda: sum(c.stats.setpoints for c in swarm.cores))
            _wait(
                lambda: emu.call(lambda: sum(c.stats.setpoints for c in swarm.cores)) > n0 + 8,
                30,
                "setpoints after the restart",
            )
        finally:
            second.send_signal(signal.SIGKILL)
            second.wait(10)
        assert all(c.alive for c in swarm.cores)
    finally:
        emu.stop()


def test_ctrl_c_ends_the_flight_deliberately_and_the_run_replays(tmp_path):
    # Ctrl-C (SIGINT) during the mission: every vehicle is told the end action (RTL), the
    # report says what each was told, summary.json and truth.npz are written, exit 130, and no
    # traceback (the emulator child ignores SIGINT: the station ends the flight).
    path = _mission_file(tmp_path, count=4, duration_s=400.0, speedup=10.0)
    out_dir = tmp_path / "runs"
    proc = subprocess.Popen(
        [*PHIREMAN, "fly", str(path), "--out", str(out_dir)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    try:

        def flying():
            runs = list(out_dir.glob("*/metrics.csv"))
            return bool(runs) and len(runs[0].read_text().splitlines()) >= 4

        _wait(flying, 120, "the mission to start")
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out
    assert "Traceback" not in out and "KeyboardInterrupt" not in out, out
    assert "told to RTL" in out
    (run,) = out_dir.iterdir()
    summary = json.loads((run / "summary.json").read_text())
    assert summary["interrupted"] == "end"
    told = summary["interrupt_report"]
    assert len(told) == 4 and sum(t["confirmed"] for t in told) >= 3
    assert (run / "truth.npz").exists()

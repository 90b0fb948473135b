"""Lock-step pacing of the emulated backend: a stalled station slows simulated time down instead
of tripping every vehicle's GCS failsafe (mission.flight.runners, mavedge.clock.PacedClock)."""

from __future__ import annotations

import json
import time

import pytest

from mavedge.clock import PacedClock, PacedReader


class _V:
    def __init__(self, v=0.0):
        self.value = v


class _Wall:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_paced_clock_never_outruns_the_station_nor_jumps():
    sim, ack, wall = _V(), _V(), _Wall()
    emu = PacedClock(20.0, sim, ack, max_step_s=0.2, slack_s=0.5, time_fn=wall)
    station = PacedReader(20.0, sim, ack)
    # Normal running: wall x speed-up, station acknowledging as it goes.
    for _ in range(100):
        wall.t += 0.005
        emu.advance()
        station.acknowledge(station.now())
    assert sim.value == pytest.approx(10.0, abs=1e-6)
    # The station stalls for 10 x FS_GCS_TIMEOUT of wall time: simulated time waits for it.
    t_stall = station.now()
    for _ in range(10_000):
        wall.t += 0.005
        emu.advance()
    assert sim.value <= t_stall + 0.5 + 1e-9
    # The emulator itself stalls (one iteration 10 s of wall late): at most one bounded step.
    station.acknowledge(station.now())
    before = sim.value
    wall.t += 10.0
    emu.advance()
    assert sim.value - before <= 0.2 + 1e-9


def _mission(tmp_path, speedup):
    from mission.format.schema import RunSpec
    from small_mission import small_mission

    return small_mission(
        "pacing", RunSpec(duration_s=30.0, seed=2, speedup=speedup), latency_s=0.01
    )


@pytest.mark.udp
def test_a_stalled_station_does_not_trip_the_gcs_failsafe(tmp_path):
    from mission.flight.runners import FlyOptions, fly_emulated

    speedup = 50.0
    fs_gcs_timeout_s = 5.0
    stalled = {}

    def stall(op, world):
        if (
            op.phase == "run"
            and op.t_mission_s(op.records[-1].t_s if op.records else 0) >= 5
            and not stalled
        ):
            t = time.monotonic()
            time.sleep(10 * fs_gcs_timeout_s / speedup)  # blocks the station's whole process
            stalled["wall_s"] = time.monotonic() - t

    res = fly_emulated(
        _mission(tmp_path, speedup),
        FlyOptions(speedup=speedup, out_dir=str(tmp_path), end_wait=False, on_operator=stall),
    )
    assert stalled["wall_s"] >= 10 * fs_gcs_timeout_s / speedup
    s = res.summary
    assert s["phase"] == "done" and s["counters"]["lost"] == 0
    events = [json.loads(line) for line in open(res.run_dir / "events.jsonl")]
    end_t = res.operator.end_t0_s
    rtl = [
        e for e in events if e["type"] == "ModeChanged" and e["mode"] == "RTL" and e["t_s"] < end_t
    ]
    assert not rtl, rtl
    assert not [e for e in events if e["type"] == "StatusText" and "Failsafe" in e["text"]]
    assert s["truth"]["tu1"] > 0.8

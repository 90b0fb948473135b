"""`phireman fly` as a user runs it (issue 28, points 4-6): an interrupted flight's two TU
figures cover the same span and say so; the closing line's speed-up is its own numbers
divided, the pace asked and achieved are in summary.json and a slow pace is warned about;
the crews are counted from the start; --mission names the mission. Port 0 only, deadlines."""

from __future__ import annotations

import json
import os
import re
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


def _mission_file(tmp_path, duration_s, speedup):
    from mission.format.schema import RunSpec
    from small_mission import small_mission

    m = small_mission(
        "span", RunSpec(duration_s=duration_s, seed=2, speedup=speedup), count=4, latency_s=0.01
    )
    path = tmp_path / "m.yaml"
    path.write_text(dump_mission(m))
    return path


def _wait(cond, timeout_s, what):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def _pace_line(out: str) -> tuple[float, float, float]:
    m = re.search(r"flown ([\d.]+) s of mission in ([\d.]+) s wall \(([\d.]+)x overall", out)
    assert m, out
    return float(m[1]), float(m[2]), float(m[3])


def test_an_interrupted_flight_reports_both_tu_over_the_span_flown(tmp_path):
    path = _mission_file(tmp_path, duration_s=400.0, speedup=10.0)
    out_dir = tmp_path / "runs"
    proc = subprocess.Popen(
        [*PHIREMAN, "fly", "--mission", str(path), "--out", str(out_dir)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    try:

        def flying():
            runs = list(out_dir.glob("*/metrics.csv"))
            return bool(runs) and len(runs[0].read_text().splitlines()) >= 8

        _wait(flying, 120, "the mission to start")
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out
    assert "Traceback" not in out
    # the mission's one crew is counted from the first status line (was "crews 0/0")
    first = next(line for line in out.splitlines() if line.startswith("finding"))
    assert "crews -/1" in first, first
    (run,) = out_dir.iterdir()
    s = json.loads((run / "summary.json").read_text())
    span = s["flown_span_s"]
    assert 7 <= span < 400 and s["interrupted"] == "end"
    # the same span on both sides, and the same number of steps (was 108 ticks vs 200 samples)
    assert s["station"]["span_s"] == s["truth"]["span_s"] == span
    assert s["station"]["ticks"] == s["truth"]["samples"] == round(span)
    assert span - 1 <= s["interrupted_at_s"] <= span + 1
    m = re.search(r"as the station saw them: .*\((\d+) control ticks\)", out)
    t = re.search(r"from the emulator's truth: .*\((\d+) samples;", out)
    assert m and t and int(m[1]) == int(t[1]) == s["station"]["ticks"], out
    assert f"both over the first {span:g} s, flown before the interrupt (of the 400 s" in out
    mission_s, wall_s, x = _pace_line(out)
    assert mission_s == pytest.approx(span, abs=0.05)
    assert x == pytest.approx(mission_s / wall_s, abs=0.051)
    # the replay draws from this run directory, interrupt marked (mark_interrupt's input)
    from mission.view.replay import load_run

    assert load_run(run).summary["interrupted_at_s"] == s["interrupted_at_s"]


def test_a_pace_far_below_the_one_asked_is_warned_about_and_recorded(tmp_path):
    # 1000x cannot be kept by any machine with a Python emulator: the pace achieved is far
    # below half of it, whatever the machine.
    path = _mission_file(tmp_path, duration_s=20.0, speedup=10.0)
    out = subprocess.run(
        [*PHIREMAN, "fly", str(path), "--speedup", "1000", "--out", str(tmp_path / "runs")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    (run,) = (tmp_path / "runs").iterdir()
    s = json.loads((run / "summary.json").read_text())
    assert s["speedup_requested"] == 1000.0
    assert 0 < s["speedup_achieved"] < 500 and s["speedup_slow"] is True
    assert s["flown_span_s"] == s["mission_s_flown"] == 20.0
    assert s["station"]["ticks"] == s["truth"]["samples"] == 20
    mission_s, wall_s, x = _pace_line(out.stdout)
    assert mission_s == 20.0 and wall_s == pytest.approx(s["wall_s"], abs=0.05)
    assert x == pytest.approx(mission_s / wall_s, abs=0.051)
    assert f"the mission itself ran at {s['speedup_achieved']:.1f}x, 1000x asked" in out.stdout
    assert "both over the whole 20 s mission" in out.stdout
    warning = " ".join(out.stderr.split())
    assert f"warning: the mission ran at {s['speedup_achieved']:.1f}x, under half the 1000x" in (
        warning
    ), out.stderr

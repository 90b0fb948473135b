"""The TAK command lines of docs/tak.md as a user runs them: 'phireman check' of a mission with
TAK crews, and 'phireman fly --tak' refusing bad URLs and TLS options without tls://."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]

MISSION = """\
name: tak-doc
vehicles:
  emulated: {count: 4}
tasks:
  - name: Alpha
    tak: {callsign: ALPHA}
  - name: Bravo
    tak: {uid: ANDROID-4f2a0c1d9e}
  - name: Engine
    tak: {callsign_pattern: "ENGINE-*", slots: 3}
  - name: Hand crew
    tak: {callsign_regex: "HAND-[0-9]+", url: "tcp://tak.example:8087"}
  - track: [{t_s: 0, north_m: 50, east_m: 0}]
"""


def _run(*args):
    return subprocess.run([*PHIREMAN, *args], capture_output=True, text=True, cwd=ROOT, timeout=120)


def test_check_accepts_the_documented_tak_mission(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(MISSION)
    out = _run("check", str(path))
    assert out.returncode == 0, out.stderr
    assert "7 tasks" in out.stdout and "tak" in out.stdout


def test_check_names_the_bad_tak_keys(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(
        "tasks:\n  - tak: {callsign: A, uid: B}\n  - tak: {callsign_regex: 'E(', slots: 2}\n"
        "  - tak: {callsign: X, slots: 3, url: 'http://x'}\n"
    )
    out = _run("check", str(path))
    assert out.returncode != 0
    err = out.stderr + out.stdout
    assert "tasks[0].tak: must have exactly one of uid, callsign" in err
    assert "tasks[1].tak.callsign_regex: 'E(' is not a regular expression" in err
    assert "tasks[2].tak.slots: only with callsign_pattern or callsign_regex" in err
    assert "tasks[2].tak.url: 'http://x': scheme 'http' is not one of" in err


def test_fly_refuses_a_bad_tak_url_and_tls_without_tls(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(MISSION)
    out = _run("fly", str(path), "--tak", "http://tak.example:8080")
    assert out.returncode != 0 and "--tak: 'http://tak.example:8080': scheme 'http'" in out.stderr
    out = _run("fly", str(path), "--tak", "udp://127.0.0.1:4242", "--tak-tls-client-cert", "me.pem")
    assert out.returncode != 0 and "need a --tak tls://HOST:PORT" in out.stderr
    out = _run("fly", "--help")
    assert "--tak URL" in out.stdout and "--tak-tls-client-cafile" in out.stdout

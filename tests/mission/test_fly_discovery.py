"""Issue 28 (3): ``phireman fly --connect`` with nothing answering stops at the discovery deadline
(``--discover-timeout-s``) with what it tried and the usual causes, exit 1, and summary.json says
why; a flight stopped by Ctrl-C or SIGTERM while discovering leaves a summary.json too. Driven as
a user does, in a subprocess.

The address nobody answers on is a loopback port the system just handed out (bound on port 0,
then closed): no fixed port.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

PHIREMAN = [sys.executable, "-m", "mission.cli"]

pytestmark = pytest.mark.udp


def _silent_port(kind: int) -> int:
    """A loopback port nobody listens on (picked by the system, then released)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _summary(out: Path) -> dict:
    runs = sorted(out.glob("*/summary.json"))
    assert len(runs) == 1, list(out.rglob("*"))
    return json.loads(runs[0].read_text())


@pytest.mark.parametrize("scheme", ["udpout", "tcp"])
def test_fly_with_nothing_answering_stops_at_the_discovery_deadline(scheme, tmp_path):
    port = _silent_port(socket.SOCK_DGRAM if scheme == "udpout" else socket.SOCK_STREAM)
    url = f"{scheme}:127.0.0.1:{port}"
    out = tmp_path / "runs"
    proc = subprocess.run(
        PHIREMAN + ["fly", "--connect", url, "--discover-timeout-s", "2", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=180,  # without a deadline the flight waits for ever: fail, not hang
    )
    assert proc.returncode == 1, proc.stderr
    err = proc.stderr
    assert "Traceback" not in err
    assert "no vehicle heard within 2 s" in err
    assert f"tried link 0 {url}" in err  # what was tried
    for cause in ("wrong address or port", "udpin vs udpout", "firewall", "not started"):
        assert cause in err, err
    s = _summary(out)
    assert s["phase"] == "refused" and s["vehicles_discovered"] == 0
    assert s["refusal"].startswith("no vehicle heard within 2 s; tried link 0 " + url)
    if scheme == "tcp":
        assert "down: " in s["refusal"]  # the TCP link's own reason (connection refused)


def test_fly_discover_timeout_must_be_positive(tmp_path):
    proc = subprocess.run(
        PHIREMAN + ["fly", "--connect", "udpout:127.0.0.1:9", "--discover-timeout-s", "0"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert proc.returncode == 2 and "--discover-timeout-s must be > 0" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "runs").exists()


class _Lines:
    """The stderr of a process, read by a thread; :meth:`wait_for` a line containing a text."""

    def __init__(self, stream) -> None:
        self.text = ""
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def finish(self, timeout_s: float) -> str:
        """Everything, once the stream has ended."""
        self._thread.join(timeout_s)
        return self.text

    def _read(self, stream) -> None:
        for line in stream:
            with self._cond:
                self.text += line
                self._cond.notify_all()

    def wait_for(self, needle: str, timeout_s: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: needle in self.text, timeout_s)


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_fly_stopped_while_discovering_leaves_a_summary(sig, code, tmp_path):
    port = _silent_port(socket.SOCK_DGRAM)
    out = tmp_path / "runs"
    proc = subprocess.Popen(
        PHIREMAN + ["fly", "--connect", f"udpout:127.0.0.1:{port}", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        assert proc.stderr is not None
        err = _Lines(proc.stderr)
        # the status line of the discovery phase: the station's loop is running
        assert err.wait_for("finding", 120), err.text
        proc.send_signal(sig)
        proc.wait(timeout=60)
        text = err.finish(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        assert proc.stdout is not None
        proc.stdout.close()
    assert proc.returncode == code, text
    assert "Traceback" not in text
    assert "interrupted before any vehicle was heard" in text
    s = _summary(out)
    assert s["phase"] == "done" and s["interrupted"] == "end" and s["vehicles_discovered"] == 0
    assert s.get("stopped_by") == (None if sig == signal.SIGINT else "SIGTERM")


def test_fly_interrupted_while_starting_leaves_a_summary(tmp_path):
    """Ctrl-C as soon as the run directory exists (the station still warming its planner up and
    opening its links, before its loop): summary.json says the flight was stopped."""
    port = _silent_port(socket.SOCK_DGRAM)
    out = tmp_path / "runs"
    proc = subprocess.Popen(
        PHIREMAN + ["fly", "--connect", f"udpout:127.0.0.1:{port}", "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        made = threading.Event()

        def watch() -> None:
            while proc.poll() is None and not made.is_set():
                if out.is_dir() and any(out.iterdir()):
                    made.set()
                made.wait(0.01)

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        watcher.join(120)
        assert made.is_set(), "no run directory was made"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    s = _summary(out)
    # stopped before the loop ran ("stopped"), or, on a fast machine, within it ("done")
    assert s["phase"] in ("stopped", "done"), s
    if s["phase"] == "stopped":
        assert s["stopped"] == "interrupted (Ctrl-C or SIGTERM)"

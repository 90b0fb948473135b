"""Optional smoke test: real MAVProxy against the emulator over loopback UDP (ephemeral port).

MAVProxy is not a test dependency: the test skips unless ``mavproxy.py`` is on PATH or the
``MAVPROXY`` environment variable names it (e.g. a separate venv's
``/tmp/mpvenv/bin/mavproxy.py``, see docs/results/interop.md).
"""

import os
import shutil
import subprocess
import threading
import time

import pytest

from vehicle_emu.swarm import Swarm
from vehicle_emu.udp import run_in_thread

pytestmark = pytest.mark.udp

MAVPROXY = os.environ.get("MAVPROXY") or shutil.which("mavproxy.py")


class _Lines:
    def __init__(self, stream):
        self.lines: list[str] = []
        self._cv = threading.Condition()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream):
        for line in stream:
            with self._cv:
                self.lines.append(line.rstrip())
                self._cv.notify_all()

    def wait_for(self, text: str, deadline: float) -> bool:
        with self._cv:
            while not any(text in ln for ln in self.lines):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cv.wait(left)
            return True


@pytest.mark.skipif(MAVPROXY is None, reason="MAVProxy not installed (optional)")
def test_mavproxy_params_plans_and_takeoff(tmp_path):
    swarm = Swarm(1, personality="ardupilot", home_lla=(47.3977, 8.5456, 488.0))
    deadline = time.monotonic() + 18.0
    with run_in_thread(swarm) as emu:
        host, port = emu.addresses[0]
        proc = subprocess.Popen(
            [
                MAVPROXY,
                f"--master=udpout:{host}:{port}",
                "--nowait",
                "--default-modules=param,wp,fence,rally,mode,arm,cmdlong",
                f"--state-basedir={tmp_path}",
            ],
            cwd=tmp_path,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
        )
        out = _Lines(proc.stdout)

        def cmd(text):
            proc.stdin.write(text + "\n")
            proc.stdin.flush()

        try:
            # MAVProxy's heartbeats make the emulator learn its address; the vehicle answers.
            assert out.wait_for("Received 14 parameters", deadline), out.lines
            for command, reply in (
                ("wp list", "Requesting 1 waypoints"),
                ("fence list", "Requesting 0 fence items"),
                ("rally list", "Requesting 0 rally items"),
                ("mode GUIDED", "DO_SET_MODE: ACCEPTED"),
                ("arm throttle", "COMPONENT_ARM_DISARM: ACCEPTED"),
                ("takeoff 10", "NAV_TAKEOFF: ACCEPTED"),
            ):
                cmd(command)
                assert out.wait_for(reply, deadline), (command, out.lines)
            assert not any("fence breach" in ln for ln in out.lines)
        finally:
            proc.kill()
            proc.wait(5)

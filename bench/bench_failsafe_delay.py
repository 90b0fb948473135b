"""How long after the station dies a real autopilot acts, and what it does (SITL, 1x).

One vehicle of each firmware (your own builds, ``PHIREMAN_ARDUCOPTER`` / ``PHIREMAN_PX4``; see
mission/flight/sitl.py) is flown by ``phireman fly --apply-failsafes``; once the plan runs, the station
is SIGKILLed, and a silent observer on a second MAVLink port of the vehicle (ArduCopter SERIAL1,
TCP 5762; PX4's onboard link, UDP 14540) timestamps the mode change. The observer never sends a
HEARTBEAT, so it cannot keep the GCS failsafe from firing. Then a new station is started and the
time until the vehicle is back in GUIDED / OFFBOARD is measured the same way.

    python bench/bench_failsafe_delay.py ardupilot px4
"""

from __future__ import annotations

import argparse
import csv
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class _Observer(threading.Thread):
    """Records (monotonic time, mode name, armed) from the vehicle's heartbeats."""

    def __init__(self, url: str, autopilot_name: str) -> None:
        super().__init__(daemon=True)
        from pymavlink import mavutil

        self.conn = mavutil.mavlink_connection(url, source_system=201, source_component=1)
        self.modes: list[tuple[float, str, bool]] = []
        self.stop = False
        self.name = autopilot_name

    def run(self) -> None:
        from gcs.autopilot import mode_name

        last_req = 0.0
        while not self.stop:
            now = time.monotonic()
            if self.name == "ardupilot" and now - last_req > 5.0:
                # SERIAL1 streams nothing until asked; HEARTBEATs flow regardless.
                self.conn.mav.request_data_stream_send(1, 1, 0, 1, 1)
                last_req = now
            m = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            if m is None or m.get_srcSystem() != 1 or m.get_srcComponent() != 1:
                continue
            mode = mode_name(m.autopilot, m.custom_mode)
            armed = bool(m.base_mode & 128)
            if not self.modes or self.modes[-1][1:] != (mode, armed):
                self.modes.append((time.monotonic(), mode, armed))


def _flying(out: Path) -> bool:
    runs = list(out.glob("*/metrics.csv"))
    if not runs:
        return False
    with open(runs[0]) as f:
        return len(list(csv.reader(f))) >= 4


def measure(firmware: str) -> None:
    from mission.commands.fly import _load
    from mission.flight.sitl import SitlSpec, SitlSwarm, find_binary

    mission = "sitl_ardupilot" if firmware == "ardupilot" else "sitl_px4"
    guided = "GUIDED" if firmware == "ardupilot" else "OFFBOARD"
    m = _load(mission)
    o = m.origin
    tmp = Path(tempfile.mkdtemp(prefix=f"bench-fs-{firmware}-"))
    spec = SitlSpec(
        firmware,
        1,
        find_binary(firmware),
        (o.lat_deg, o.lon_deg, o.alt_amsl_m),
        workdir=tmp / "sitl",
    )
    phireman = str(Path(sys.executable).with_name("phireman"))
    with SitlSwarm(spec) as sitl:
        time.sleep(2.0)
        obs = _Observer(
            "tcp:127.0.0.1:5762" if firmware == "ardupilot" else "udpin:127.0.0.1:14540", firmware
        )
        obs.start()
        cmd = [
            phireman,
            "fly",
            mission,
            "--connect",
            sitl.connection(0),
            "--apply-failsafes",
            "--duration-s",
            "600",
        ]
        st = subprocess.Popen(
            [*cmd, "--out", str(tmp / "s1")],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        t_start = time.monotonic()
        while not _flying(tmp / "s1"):
            time.sleep(0.2)
            if time.monotonic() - t_start > 300:
                raise SystemExit(f"{firmware}: the station never reached the run phase")
        time.sleep(5.0)
        t_kill = time.monotonic()
        st.send_signal(signal.SIGKILL)
        st.wait()
        while not any(t > t_kill and mode != guided for t, mode, _ in obs.modes):
            time.sleep(0.05)
            if time.monotonic() - t_kill > 60:
                break
        fs = next(((t, mode) for t, mode, _ in obs.modes if t > t_kill and mode != guided), None)
        t_restart = time.monotonic()
        st2 = subprocess.Popen(
            [*cmd, "--out", str(tmp / "s2")],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        while not any(t > t_restart and mode == guided for t, mode, _ in obs.modes):
            time.sleep(0.05)
            if time.monotonic() - t_restart > 120:
                break
        back = next((t for t, mode, _ in obs.modes if t > t_restart and mode == guided), None)
        st2.send_signal(signal.SIGKILL)
        st2.wait()
        obs.stop = True
    print(
        f"{firmware}: station SIGKILLed -> "
        + (f"{fs[1]} after {fs[0] - t_kill:.2f} s" if fs else "no failsafe within 60 s")
        + "; restarted station -> "
        + (
            f"{guided} again {back - t_restart:.1f} s after its start"
            if back
            else "not reclaimed within 120 s"
        )
    )
    print(
        "  modes seen: "
        + ", ".join(
            f"{t - t_start:.1f}s {mode}{'' if a else ' (disarmed)'}" for t, mode, a in obs.modes
        )
    )


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("firmware", nargs="+", choices=("ardupilot", "px4"))
    for fw in ap.parse_args().firmware:
        measure(fw)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""SitlSwarm.power_cycle (mission/flight/sitl.py), the battery swap of the real-firmware rotation
test, on a stand-in binary (a shell script that prints its command line and waits): the same
instance boots again in the same directory with the same arguments, ArduPilot without ``-w``
(its eeprom is kept), PX4 with the same boot parameters; the other vehicles are untouched."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from mission.flight.sitl import SitlSpec, SitlSwarm

_FAKE = """#!/bin/sh
echo "ARGS $*"
echo "LAT0 ${PX4_PARAM_SIH_LOC_LAT0:-none} DRAIN ${PX4_PARAM_SIM_BAT_DRAIN:-none}"
exec sleep 120
"""


def _binary(tmp_path: Path) -> Path:
    path = tmp_path / "bin" / "fake-autopilot"
    path.parent.mkdir()
    path.write_text(_FAKE)
    path.chmod(0o755)
    (tmp_path / "etc").mkdir()  # PX4's ROMFS etc directory (checked to exist)
    return path


def _lines(log: Path, prefix: str, count: int) -> list[str]:
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        got = (
            [l for l in log.read_text().splitlines() if l.startswith(prefix)]
            if log.exists()
            else []
        )
        if len(got) >= count:
            return got
        time.sleep(0.05)
    raise AssertionError(f"{log}: fewer than {count} lines {prefix!r}")


@pytest.mark.parametrize("firmware", ["ardupilot", "px4"])
def test_power_cycle_boots_the_same_instance_again(tmp_path, firmware):
    spec = SitlSpec(
        firmware,
        2,
        _binary(tmp_path),
        (47.0, 8.0, 500.0),
        workdir=tmp_path / "sitl",
        first_instance=40,  # PX4's /tmp/px4-sock-<i> of no real instance
        params={"SIM_BAT_DRAIN": 300.0},
        px4_etc=tmp_path / "etc",
    )
    with SitlSwarm(spec) as sitl:
        logs = [sitl.workdir / f"{firmware}-{sitl.instance(k)}" / "console.log" for k in (0, 1)]
        first = [_lines(log, "ARGS", 1)[0] for log in logs]
        old = [p.pid for p in sitl.procs]
        sitl.power_cycle(1)
        assert sitl.procs[0].pid == old[0] and sitl.alive() == [True, True]
        assert sitl.procs[1].pid != old[1]
        with pytest.raises(ProcessLookupError):
            os.kill(old[1], 0)  # the power was cut: the old process is gone
        again = _lines(logs[1], "ARGS", 2)[1]
        assert len(_lines(logs[0], "ARGS", 1)) == 1
        envs = _lines(logs[1], "LAT0", 2)
    if firmware == "ardupilot":
        assert " -w " in f" {first[1]} " and " -w " not in f" {again} "
        assert again.split() == [a for a in first[1].split() if a != "-w"]
        assert "--sysid 42" in again and "-I 41" in again
    else:
        assert again == first[1] == "ARGS -i 41 -d " + str(tmp_path / "etc")
        assert envs[0] == envs[1] and "DRAIN 300" in envs[1]


def test_phireman_sitl_power_cycles_the_vehicle_typed_at_the_terminal(tmp_path):
    """``phireman sitl``: a vehicle's number and Enter is the crew's battery swap; anything else
    is refused with a line, and the swarm runs on."""
    import signal
    import subprocess
    import sys

    phireman = str(Path(sys.executable).with_name("phireman"))
    out = tmp_path / "out.txt"
    work = tmp_path / "sitl"
    with open(out, "w") as f:
        proc = subprocess.Popen(
            [
                phireman,
                "sitl",
                "ardupilot",
                "--vehicles",
                "2",
                "--binary",
                str(_binary(tmp_path)),
                "--first-instance",
                "42",
                "--workdir",
                str(work),
            ],
            stdin=subprocess.PIPE,
            stdout=f,
            stderr=subprocess.STDOUT,
            text=True,
        )
    try:
        _lines(out, "Ctrl-C stops them", 1)
        log = work / "ardupilot-43" / "console.log"
        _lines(log, "ARGS", 1)
        assert proc.stdin is not None
        proc.stdin.write("5\n1\n")
        proc.stdin.flush()
        _lines(out, "vehicle 1 (sysid 44) power-cycled", 1)
        args = _lines(log, "ARGS", 2)
        assert " -w " in f" {args[0]} " and " -w " not in f" {args[1]} "
        assert len(_lines(work / "ardupilot-42" / "console.log", "ARGS", 1)) == 1
        assert _lines(out, "type a vehicle number 0 .. 1", 1)
        assert proc.poll() is None  # the swarm runs on
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)

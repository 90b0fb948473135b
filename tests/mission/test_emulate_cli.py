"""Issue 28 (2, 8): ``phireman emulate`` as a user meets it, in a subprocess. A ground-station
address inside the emulator's own ports is refused; the documented example is consistent with
``fly --connect``; information is printed (not logged as WARNING), the final statistics are
readable lines, Ctrl-C exits 130, every option has help. UDP on port 0 only (``--base-port 0``);
the refused commands never bind."""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from mission.cli import build_parser

PHIREMAN = [sys.executable, "-m", "mission.cli"]
README = Path(__file__).resolve().parents[2] / "README.md"


def phireman(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(PHIREMAN + list(args), capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize(
    "args",
    [
        # the README's old example: vehicles on 14550..14559, station on 14551
        ["--vehicles", "10", "--base-port", "14550", "--gcs", "udpout:127.0.0.1:14551"],
        ["--vehicles", "3", "--base-port", "20000", "--gcs", "udpout:localhost:20002"],
        # bound to every interface: a loopback station address is still one of its ports
        ["--vehicles", "2", "--bind", "0.0.0.0", "--base-port", "20000", "--gcs", "20001"],
        # --mux: one port per MAVLink network (300 vehicles = 2 networks: 20000 and 20001)
        ["--vehicles", "300", "--mux", "--base-port", "20000", "--gcs", "udpout:127.0.0.1:20001"],
    ],
)
def test_emulate_refuses_a_gcs_address_inside_its_own_ports(args):
    # --duration-s: a build without the check ends on its own instead of serving for ever
    proc = phireman("emulate", *args, "--duration-s", "0.5")
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    assert "one of the emulator's own ports" in proc.stderr
    assert "--base-port" in proc.stderr and "--connect udpin:" in proc.stderr  # the fix
    assert "emulating" not in proc.stdout  # refused before binding anything


def test_emulate_accepts_a_gcs_address_outside_its_ports():
    """Not every --gcs is refused: a port below the range, and a remote host on a port number
    the vehicles use locally (bound to loopback only)."""
    from vehicle_emu.cli import _check_gcs_ports

    parser = build_parser(only="emulate")
    for extra in (
        ["--base-port", "14560", "--gcs", "udpout:127.0.0.1:14550"],
        ["--base-port", "14560", "--gcs", "udpout:10.1.2.3:14561"],
    ):
        args = parser.parse_args(["emulate", "--vehicles", "10", *extra])
        _check_gcs_ports(args, 10)  # raises UsageError when refused


def _emulate_examples(text: str) -> list[list[str]]:
    """The argument lists of every ``phireman emulate`` example in ``text`` (with ``\\``
    continuations joined)."""
    text = re.sub(r"\\\s*\n\s*", " ", text)
    return [
        shlex.split(m.group(1).split("#")[0])
        for m in re.finditer(r"phireman emulate (--[^\n`]*)", text)
    ]


def _fly_connects(text: str) -> set[int]:
    return {int(p) for p in re.findall(r"phireman fly [^\n`]*--connect udpin:[\d.]+:(\d+)", text)}


@pytest.mark.parametrize("where", ["README.md", "emulate --help"])
def test_the_documented_emulator_examples_keep_the_station_outside_the_vehicles_ports(where):
    """Each documented example passes the emulator's own check, and its station port is the one
    the documented ``fly --connect udpin:`` listens on."""
    from vehicle_emu.cli import _check_gcs_ports

    if where == "README.md":
        text = README.read_text(encoding="utf-8")
    else:
        proc = phireman("emulate", "--help")
        assert proc.returncode == 0
        text = proc.stdout
    examples = _emulate_examples(text)
    assert examples, f"no 'phireman emulate' example in {where}"
    parser = build_parser(only="emulate")
    connects = _fly_connects(text)
    for example in examples:
        args = parser.parse_args(["emulate", *example])
        n_endpoints = -(-args.vehicles // 254) if args.mux else args.vehicles
        _check_gcs_ports(args, n_endpoints)
        for _, port in args.gcs:
            assert port in connects, (
                f"{where}: no 'fly --connect udpin:...:{port}' beside {example}"
            )


def test_emulate_prints_information_and_readable_statistics():
    proc = phireman("emulate", "--vehicles", "2", "--base-port", "0", "--duration-s", "1")
    assert proc.returncode == 0, proc.stderr
    assert "WARNING" not in proc.stderr  # ordinary information is not a warning
    out = proc.stdout
    assert re.search(r"emulating 2 ardupilot vehicle\(s\) in 1 MAVLink network\(s\) on udp ", out)
    assert re.search(r"stopped at t = [\d.]+ s of vehicle time: 2 of 2 vehicles alive", out)
    assert re.search(r"datagrams: \d+ in, \d+ out; dropped:", out)
    assert re.search(r"peers: \d+ learned", out)
    assert "{" not in out and "'datagrams_in'" not in out  # not a Python dict


def _first_line(proc: subprocess.Popen, timeout_s: float = 60) -> str:
    """The first line of ``proc``'s stdout, or '' if none comes (a reader thread: the test fails
    instead of hanging when the line never comes)."""
    got: list[str] = []
    assert proc.stdout is not None
    reader = threading.Thread(target=lambda: got.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout_s)
    return got[0] if got else ""


def _start(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        PHIREMAN + ["emulate", *args, "--base-port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def test_emulate_ctrl_c_exits_130():
    proc = _start("--vehicles", "2")
    try:
        first = _first_line(proc)  # printed once the ports are bound
        assert first.startswith("emulating 2"), first
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        _stop(proc)
    assert proc.returncode == 130, err
    assert "(Ctrl-C)" in out and "Traceback" not in err


def test_emulate_sigterm_exits_143():
    proc = _start("--vehicles", "1")
    try:
        assert _first_line(proc).startswith("emulating 1")
        proc.terminate()
        out, err = proc.communicate(timeout=30)
    finally:
        _stop(proc)
    assert proc.returncode == 143, err
    assert "(SIGTERM)" in out and "datagrams:" in out


def test_every_emulate_option_has_help():
    parser = build_parser(only="emulate")
    sub = next(a for a in parser._actions if a.dest == "command")
    emulate = sub.choices["emulate"]  # type: ignore[index]
    missing = [a.option_strings[0] for a in emulate._actions if a.option_strings and not a.help]
    assert not missing, f"options without help: {missing}"
    proc = phireman("emulate", "--help")
    for option in ("--personality", "--latency-per-hop-s", "--loss-per-hop", "--seed"):
        block = proc.stdout.split(option, 1)[1].split("\n  -", 1)[0]
        assert len(block.split()) > 2, f"{option}: no help text in --help"

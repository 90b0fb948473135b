"""Options as a new user types them (issue 28, point 6): ``fly --mission`` like ``sim`` and
``sitl``, and one meaning for a bare ``1`` as a rate in every command that takes one."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mission.cli import UserError, parse_rate

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = str(Path(sys.executable).with_name("phireman"))


def _run(*args, cwd=ROOT):
    return subprocess.run([PHIREMAN, *args], capture_output=True, text=True, cwd=cwd)


@pytest.mark.parametrize(
    "cmd",
    [
        ["sim", "--size", "XS", "--seeds", "1"],
        ["sweep", "--grid", "custom", "--size", "XS", "--dry-run", "--store", "{tmp}/s.sqlite"],
        ["tune", "--method", "phireman", "--grid", "step_size=0.1", "--store", "{tmp}/t.sqlite"],
        ["mission", "new"],
    ],
    ids=lambda c: c[0],
)
def test_a_bare_1_as_a_rate_is_refused_with_both_readings(cmd, tmp_path):
    cmd = [c.replace("{tmp}", str(tmp_path)) for c in cmd]
    out = _run(*cmd, "--attrition", "1")
    assert out.returncode == 2, out.stdout + out.stderr
    assert "Traceback" not in out.stderr
    assert "1 is ambiguous" in out.stderr and "1%" in out.stderr and "100%" in out.stderr
    out = _run(*cmd, "--attrition", "2")
    assert out.returncode == 2 and "did you mean 2% (= 0.02)" in out.stderr, out.stderr


def test_parse_rate_readings():
    assert parse_rate("1%") == pytest.approx(0.01)
    assert parse_rate("100%") == 1.0
    assert parse_rate("0.99") == pytest.approx(0.99)
    assert parse_rate("0") == 0.0
    for bad in ("1", "1.0", "2", "50", "150%"):
        with pytest.raises(UserError):
            parse_rate(bad)


def test_fly_takes_mission_as_an_option(tmp_path):
    # The mission given by --mission is the one flown: a flag that only applies to real links
    # is refused for *this* (emulated) mission, as with the positional argument.
    out = _run("fly", "--mission", "wildfire", "--vehicles", "3")
    assert out.returncode == 2 and "--vehicles applies to real links" in out.stderr, out.stderr
    out = _run("fly", "--mission", "no-such-mission")
    assert out.returncode == 2 and "neither a mission file nor a shipped example" in out.stderr


def test_fly_refuses_two_different_missions_but_not_the_same_one_twice(tmp_path):
    out = _run("fly", "wildfire", "--mission", "hazard_zone")
    assert out.returncode == 2 and "two missions given" in out.stderr, out.stderr
    assert "Traceback" not in out.stderr
    from mission.format.examples import example_path

    # the same mission named twice (by name and by path) is one mission: refused only for
    # the flag that cannot apply
    path = str(example_path("wildfire"))
    out = _run("fly", "wildfire", "--mission", path, "--vehicles", "3")
    assert out.returncode == 2 and "--vehicles applies to real links" in out.stderr, out.stderr

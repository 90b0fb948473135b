"""Issue 28 (1): every command that writes files checks its output location *before* the work
starts, and a location it cannot write is one line naming the option and the path, exit 2, no
traceback. Driven as a user does: ``python -m mission.cli ...`` in a subprocess.

An unwritable location that fails for root too (the tests may run as root, for whom chmod does
not block writes): a path *under a regular file*.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

PHIREMAN = [sys.executable, "-m", "mission.cli"]
FAST = ["--size", "XS", "--set", "n_steps=20", "--no-progress"]


def phireman(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        PHIREMAN + list(args), cwd=cwd, capture_output=True, text=True, timeout=timeout
    )


def assert_refused(proc: subprocess.CompletedProcess, option: str, path: Path) -> None:
    """Exit 2, one line on stderr naming the option and the path, no traceback."""
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if "error:" in line]
    assert len(lines) == 1, proc.stderr
    assert f"{option} {path}: cannot write there" in lines[0], proc.stderr


@pytest.fixture()
def blocked(tmp_path) -> Path:
    """A directory path nobody can create: its parent is a regular file."""
    (tmp_path / "file").write_text("not a directory\n")
    return tmp_path / "file" / "sub"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A run directory to replay (the shipped wildfire mission, played in-process)."""
    out = tmp_path_factory.mktemp("replay") / "wf"
    proc = phireman("sim", "--mission", "wildfire", "--out", str(out), cwd=out.parent)
    assert proc.returncode == 0, proc.stderr
    return out


def test_fly_refuses_an_unwritable_out_before_flying(blocked, tmp_path):
    proc = phireman("fly", "--out", str(blocked), "--duration-s", "5", cwd=tmp_path)
    assert_refused(proc, "--out", blocked)
    assert "is a file, not a directory" in proc.stderr
    # refused before the header of the flight and its emulator: nothing flew
    assert "emulated" not in proc.stderr and "run directory" not in proc.stdout


def test_sim_refuses_an_unwritable_out_before_the_runs(blocked, tmp_path):
    proc = phireman("sim", "--seeds", "3", "--out", str(blocked), *FAST, cwd=tmp_path)
    assert_refused(proc, "--out", blocked)
    assert "TU1" not in proc.stdout  # no results printed, then a failure


def test_sim_mission_refuses_an_unwritable_out_before_the_simulation(blocked, tmp_path):
    proc = phireman("sim", "--mission", "wildfire", "--out", str(blocked), cwd=tmp_path)
    assert_refused(proc, "--out", blocked)
    assert "seed 1:" not in proc.stdout


def test_replay_refuses_an_unwritable_out(run_dir, blocked, tmp_path):
    proc = phireman(
        "replay", str(run_dir), "--out", str(blocked), "--animation", "none", cwd=tmp_path
    )
    assert_refused(proc, "--out", blocked)


def test_report_refuses_an_unwritable_out(blocked, tmp_path):
    import sqlite3

    from mission.experiments.store import ResultStore

    store = tmp_path / "s.sqlite"
    ResultStore(store).close()  # an empty, valid store
    assert sqlite3.connect(store).execute("select count(*) from sqlite_master").fetchone()[0]
    proc = phireman("report", str(store), "--out", str(blocked), "--no-progress", cwd=tmp_path)
    assert_refused(proc, "--out", blocked)


SWEEP = ["--grid", "custom", "--size", "XS", "--attrition", "0", "--method", "phireman"]


def test_sweep_refuses_an_unwritable_store_before_running(blocked, tmp_path):
    store = blocked / "s.sqlite"
    proc = phireman("sweep", *SWEEP, "--seeds", "1", "--store", str(store), cwd=tmp_path)
    assert_refused(proc, "--store", store)


@pytest.mark.parametrize("what", ["store", "out-dir", "out-md"])
def test_tune_refuses_an_unwritable_store_or_out_before_the_search(what, blocked, tmp_path):
    store, out = tmp_path / "t.sqlite", None
    if what == "store":
        store = blocked / "t.sqlite"
    else:
        out = blocked / "x.md" if what == "out-md" else blocked
    args = ["tune", "--method", "phireman", "--grid", "step_size=0.1,0.2", "--seeds", "2"]
    args += ["--size", "XS", "--set", "n_steps=20", "--store", str(store), "--no-progress"]
    if out is not None:
        args += ["--out", str(out)]
    proc = phireman(*args, cwd=tmp_path)
    assert_refused(proc, "--store" if what == "store" else "--out", out or store)
    assert not store.exists()  # nothing was run or stored


def test_mission_new_refuses_an_unwritable_out(blocked, tmp_path):
    out = blocked / "m.yaml"
    proc = phireman("mission", "new", "--preset", "S", "--out", str(out), cwd=tmp_path)
    assert_refused(proc, "--out", out)


def test_sitl_refuses_an_unwritable_workdir_before_starting(blocked, tmp_path):
    proc = phireman("sitl", "ardupilot", "--workdir", str(blocked), cwd=tmp_path)
    assert_refused(proc, "--workdir", blocked)


def test_fly_checks_the_missions_own_output_dir(tmp_path):
    """No --out: the mission's output.dir is checked the same way."""
    (tmp_path / "runs").write_text("a file where the mission wants its runs directory\n")
    mission = tmp_path / "m.yaml"
    proc = phireman("mission", "show", "wildfire", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    assert "output:" in text
    mission.write_text(text)
    from mission.format.load import load_mission

    assert load_mission(mission).output.dir == "runs"  # the default this test relies on
    proc = phireman("fly", str(mission), "--duration-s", "5", cwd=tmp_path)
    assert_refused(proc, "output.dir", Path("runs"))


def test_a_file_error_after_the_check_is_one_line(tmp_path):
    """A write that fails after the up-front check (here: --out is a dangling symbolic link, so
    the file cannot be created although its directory is writable) is one line with the path,
    non-zero exit, no traceback (mission.cli.main)."""
    out = tmp_path / "m.yaml"
    out.symlink_to(tmp_path / "gone" / "m.yaml")
    proc = phireman("mission", "new", "--preset", "S", "--out", str(out), cwd=tmp_path)
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and str(out) in proc.stderr, proc.stderr


@pytest.mark.skipif(
    hasattr(os, "geteuid") and os.geteuid() == 0,
    reason="root writes into a chmod 0o555 directory (the tests above use a path under a file)",
)
def test_sim_refuses_a_read_only_directory(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        proc = phireman("sim", "--seeds", "2", "--out", str(ro), *FAST, cwd=tmp_path)
    finally:
        ro.chmod(0o755)
    assert_refused(proc, "--out", ro)
    assert "Permission denied" in proc.stderr

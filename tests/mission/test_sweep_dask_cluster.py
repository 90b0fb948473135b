"""The Dask path of ``phireman sweep`` on a real cluster: a scheduler and two workers started as
separate processes on loopback, with the very commands ``phireman sweep --help`` documents.

Ports are chosen by the system (``--port 0``, ``--dashboard-address 127.0.0.1:0``); the scheduler
writes its address to ``sched.json``, which ``--scheduler`` reads. Every wait polls with a deadline
(no timed assertions), and every process started here is killed in ``finally``.
"""

from __future__ import annotations

import json
import os
import shlex
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mission.commands.sweep import DESCRIPTION


PHIREMAN = [sys.executable, "-m", "mission.cli"]
DASK = [sys.executable, "-m", "dask"]  # the `dask` command of this interpreter
#: Generous: a cold Numba cache makes a worker's first run take minutes on a loaded 2-core machine.
DEADLINE_S = 300.0


def _documented(*needles: str) -> list[str]:
    """The one command line of the sweep's --help containing every needle, as argv."""
    lines = [line.split("  #")[0].strip() for line in DESCRIPTION.splitlines()]
    found = [line for line in lines if all(n in line for n in needles)]
    assert len(found) == 1, (needles, found)
    argv = shlex.split(found[0])
    head = {"dask": DASK, "phireman": PHIREMAN}[argv[0]]
    return head + argv[1:]


def _without(argv: list[str], option: str) -> list[str]:
    i = argv.index(option)
    return argv[:i] + argv[i + 2 :]


def _rows(path: Path) -> dict[tuple, tuple]:
    """(config, method, seed) -> the outcome, TU1/TU2 as stored (exact floats)."""
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        rows = db.execute(
            "SELECT run_key, config_key, method, seed, status, tu1, tu2, final_alive, final_active "
            "FROM runs"
        ).fetchall()
    finally:
        db.close()
    keys = [r[0] for r in rows]
    assert len(keys) == len(set(keys)), "duplicate run keys"
    out = {(c, m, s): rest for _, c, m, s, *rest in rows}
    assert len(out) == len(rows), "duplicate (config, method, seed)"
    return out


def _count(path: Path) -> int:
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=5)
        try:
            return int(db.execute("SELECT COUNT(*) FROM runs").fetchone()[0])
        finally:
            db.close()
    except sqlite3.OperationalError:  # not created yet
        return 0


def _log(path: Path) -> str:
    return path.read_text(errors="replace")[-3000:] if path.exists() else "(no log)"


class _Procs:
    """Processes started here, each in its own session (a worker is its nanny and its child)."""

    def __init__(self, cwd: Path) -> None:
        self.cwd = cwd
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, argv: list[str]) -> subprocess.Popen:
        log = open(self.cwd / f"{name}.log", "wb")  # noqa: SIM115 - closed with the process
        try:
            proc = subprocess.Popen(
                argv, cwd=self.cwd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
            )
        finally:
            log.close()  # the child holds its own copy
        self.procs[name] = proc
        return proc

    def kill(self, name: str) -> None:
        proc = self.procs[name]
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)

    def kill_all(self) -> None:
        for name in reversed(list(self.procs)):
            try:
                os.killpg(self.procs[name].pid, signal.SIGKILL)  # the group outlives its leader
            except ProcessLookupError:
                pass
            self.procs[name].wait(timeout=60)

    def alive_or_fail(self, name: str) -> None:
        if self.procs[name].poll() is not None:
            pytest.fail(
                f"{name} exited ({self.procs[name].returncode}):\n{_log(self.cwd / f'{name}.log')}"
            )


def _poll(what: str, ready, procs: _Procs, watch: list[str]) -> None:
    deadline = time.monotonic() + DEADLINE_S
    while not ready():
        for name in watch:
            procs.alive_or_fail(name)
        if time.monotonic() > deadline:
            pytest.fail(f"no {what} within {DEADLINE_S:.0f} s")
        time.sleep(0.01)


def _scheduler_address(path: Path) -> str | None:
    try:
        return str(json.loads(path.read_text())["address"])
    except (OSError, ValueError, KeyError):  # not written yet, or half-written
        return None


@pytest.mark.cluster
def test_sweep_on_a_scheduler_and_two_worker_processes_survives_a_killed_worker(tmp_path):
    from distributed import Client

    scheduler = _documented("dask scheduler", "--scheduler-file sched.json")
    worker = _documented("dask worker", "--scheduler-file sched.json")
    sweep = _documented("phireman sweep", "--scheduler sched.json") + ["--no-progress"]
    assert "--port" in scheduler and scheduler[scheduler.index("--port") + 1] == "0"

    # The reference: the same grid on the local process pool (this also warms Numba's disk cache).
    local = tmp_path / "local.sqlite"
    ref = subprocess.run(
        _without(_without(sweep, "--scheduler"), "--store")
        + ["--workers", "2", "--store", str(local)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=DEADLINE_S,
    )
    assert ref.returncode == 0, ref.stderr
    expected = _rows(local)
    total = len(expected)
    assert total >= 8, total  # enough runs that a worker can be killed before the end

    procs = _Procs(tmp_path)
    try:
        procs.start("scheduler", scheduler)
        _poll(
            "scheduler file",
            lambda: _scheduler_address(tmp_path / "sched.json"),
            procs,
            ["scheduler"],
        )
        procs.start("worker-a", worker)
        procs.start("worker-b", worker)
        with Client(scheduler_file=str(tmp_path / "sched.json"), timeout=60) as client:
            _poll(
                "two workers joined",
                lambda: len(client.scheduler_info()["workers"]) >= 2,
                procs,
                ["scheduler", "worker-a", "worker-b"],
            )
            # worker address -> its process group, i.e. the `dask worker` command started here
            pgids = client.run(os.getpgid, 0)
            by_pgid = {procs.procs[n].pid: n for n in ("worker-a", "worker-b")}
            assert sorted(by_pgid[g] for g in pgids.values()) == ["worker-a", "worker-b"]

            # 1. A clean sweep on the cluster: the local pool's rows, exactly.
            clean = subprocess.run(
                sweep, cwd=tmp_path, capture_output=True, text=True, timeout=DEADLINE_S
            )
            assert clean.returncode == 0, clean.stderr
            assert f"0 present, {total} completed now (0 errors), 0 remaining" in clean.stdout
            assert _rows(tmp_path / "cluster.sqlite") == expected

            # 2. The same command into a new store; once some rows are stored, SIGKILL a worker
            # that holds tasks (its nanny and its process: the machine is gone). The scheduler
            # runs those tasks again on the other worker and the command finishes with every row.
            killed = tmp_path / "killed.sqlite"
            proc = procs.start("sweep", _without(sweep, "--store") + ["--store", str(killed)])
            _poll("stored row", lambda: _count(killed) >= 1 or proc.poll() is not None, procs, [])
            busy = [addr for addr, keys in client.processing().items() if keys]
            at_kill = _count(killed)
            assert proc.poll() is None and busy, (
                f"the sweep ended before a worker was killed:\n{_log(tmp_path / 'sweep.log')}"
            )
            victim = by_pgid[pgids[busy[0]]]
            procs.kill(victim)
            assert 1 <= at_kill < total, (at_kill, total)
            try:
                rc = proc.wait(timeout=DEADLINE_S)
            except subprocess.TimeoutExpired:
                pytest.fail(
                    f"the sweep did not finish after the kill:\n{_log(tmp_path / 'sweep.log')}"
                )
            out = _log(tmp_path / "sweep.log")
            assert rc == 0, out
            assert f"0 present, {total} completed now (0 errors), 0 remaining" in out
            assert _rows(killed) == expected
            procs.alive_or_fail({"worker-a": "worker-b", "worker-b": "worker-a"}[victim])
    finally:
        procs.kill_all()


def test_lost_runs_exit_1_with_a_message_and_the_same_command_finishes(
    tmp_path, capsys, monkeypatch
):
    """What a sweep does when its scheduler goes: the runs in flight are lost, not stored."""
    from mission.cli import main
    from mission.experiments import sweep as sweep_mod

    argv = ["sweep", "--grid", "custom", "--size", "XS", "--attrition", "0", "--method", "phireman"]
    argv += ["--seeds", "2", "--set", "n_steps=5", "--chunk", "1", "--no-progress"]
    argv += ["--store", str(tmp_path / "lost.sqlite")]
    real_run = sweep_mod.LocalExecutor.run

    def lose_the_first_chunk(self, chunks):
        it = real_run(self, chunks)
        chunk, _ = next(it)
        yield chunk, OSError("scheduler gone")
        yield from it

    monkeypatch.setattr(sweep_mod.LocalExecutor, "run", lose_the_first_chunk)
    assert main(argv + ["--workers", "1"]) == 1
    out, err = capsys.readouterr()
    assert "1 completed now (0 errors), 1 remaining" in out
    assert "1 runs lost to executor failures; rerun the same command" in err
    monkeypatch.setattr(sweep_mod.LocalExecutor, "run", real_run)
    assert main(argv + ["--workers", "1"]) == 0
    assert "1 present, 1 completed now (0 errors), 0 remaining" in capsys.readouterr().out
    assert _count(tmp_path / "lost.sqlite") == 2


def test_scheduler_option_reads_a_scheduler_file(tmp_path, capsys):
    from mission.cli import main
    from mission.commands.sweep import scheduler_address

    f = tmp_path / "sched.json"
    f.write_text(json.dumps({"type": "Scheduler", "address": "tcp://127.0.0.1:40757"}))
    assert scheduler_address(str(f)) == "tcp://127.0.0.1:40757"
    assert scheduler_address("tcp://10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    assert scheduler_address("10.0.0.5:8786") == "10.0.0.5:8786"
    assert scheduler_address(None) is None
    argv = ["sweep", "--grid", "custom", "--size", "XS", "--attrition", "0", "--method", "phireman"]
    argv += ["--seeds", "1", "--store", str(tmp_path / "s.sqlite"), "--no-progress"]
    assert main(argv + ["--scheduler", str(tmp_path / "missing.json")]) == 2
    assert "not a readable Dask scheduler file" in capsys.readouterr().err
    f.write_text("{}")
    assert main(argv + ["--scheduler", str(f)]) == 2
    assert "not a readable Dask scheduler file" in capsys.readouterr().err

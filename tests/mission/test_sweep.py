"""Sweeps: resumable store, kill -9 and resume, local pool vs Dask, error rows, the paper grids."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time

import pytest

from mission.cli import main
from mission.experiments.store import ResultStore
from mission.experiments.sweep import (
    ConfigSpec,
    Grid,
    custom_grid,
    paper_ablations_grid,
    paper_table_grid,
    resolve,
    run_sweep,
)

PHIREMAN = [sys.executable, "-m", "mission.cli"]
FAST = {"n_steps": 20}


def _keys(grid: Grid) -> set[str]:
    out = set()
    for spec in grid.configs:
        rc = resolve(spec)
        out |= {rc.run_key(s) for s in grid.seeds}
    return out


def _results(path) -> dict[str, tuple]:
    """run_key -> what must not depend on how the run was executed."""
    with ResultStore(path, readonly=True) as store:
        return {
            r["run_key"]: (
                r["status"],
                r["seed"],
                r["method"],
                r["tu1"],
                r["tu2"],
                r["final_alive"],
                r["final_active"],
            )
            for r in store.runs()
        }


def _count(path) -> int:
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=5)
        try:
            return db.execute("SELECT COUNT(*) FROM runs").fetchone()[0]
        finally:
            db.close()
    except sqlite3.OperationalError:  # not created yet
        return 0


def test_kill_midway_and_resume_stores_every_run_exactly_once(tmp_path):
    store = tmp_path / "killed.sqlite"
    args = [
        "sweep",
        "--grid",
        "custom",
        "--sizes",
        "XS",
        "--attrition",
        "0",
        "0.005",
        "0.01",
        "0.02",
        "0.05",
        "--methods",
        "phireman",
        "--seeds",
        "4",
        "--set",
        "n_steps=20",
        "--chunk",
        "1",
        "--no-progress",
    ]
    grid = custom_grid(
        ["XS"], [0, 0.005, 0.01, 0.02, 0.05], ["phireman"], range(4), problem_overrides=FAST
    )
    total = grid.n_runs

    proc = subprocess.Popen(
        PHIREMAN + args + ["--store", str(store), "--workers", "2"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 60
        n = 0
        while time.monotonic() < deadline:
            n = _count(store)
            if n >= 1 or proc.poll() is not None:
                break
            time.sleep(0.005)
        assert proc.poll() is None, (
            f"sweep ended before it could be killed: {proc.stderr.read().decode()}"
        )
        assert 1 <= n < total, n
        os.killpg(proc.pid, signal.SIGKILL)  # the sweep, its forkserver and pool workers
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        proc.stderr.close()
    killed_at = _count(store)
    assert 1 <= killed_at < total

    # Rerun the very same command: it completes the grid without duplicating anything.
    done = subprocess.run(
        PHIREMAN + args + ["--store", str(store), "--workers", "1"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert f"{killed_at} present" in done.stdout
    with ResultStore(store, readonly=True) as s:
        keys = [r["run_key"] for r in s.runs()]
        sweeps = s.sweeps()
    assert len(keys) == len(set(keys)) == total
    assert set(keys) == _keys(grid)
    assert (
        sweeps[0]["finished_utc"] is None and sweeps[1]["finished_utc"] is not None
    )  # the kill, the resume

    # The same rows as a sweep that was never interrupted.
    clean = tmp_path / "clean.sqlite"
    with ResultStore(clean) as s:
        summary = run_sweep(grid, s, workers=1, progress=False)
    assert summary.completed == total and not summary.interrupted
    assert _results(store) == _results(clean)


def test_local_pool_and_dask_localcluster_give_identical_rows(tmp_path):
    pytest.importorskip("dask.distributed")
    grid = custom_grid(
        ["XS"], [0.0, 0.01], ["phireman", "phireman-nodes-only"], range(2), problem_overrides=FAST
    )
    local, dask = tmp_path / "local.sqlite", tmp_path / "dask.sqlite"
    with ResultStore(local) as s:
        a = run_sweep(grid, s, executor="local", workers=2, chunk=1, progress=False)
    with ResultStore(dask) as s:
        b = run_sweep(grid, s, executor="dask", workers=2, chunk=1, progress=False)
    assert a.completed == b.completed == grid.n_runs
    assert a.errors == b.errors == 0 and a.lost == b.lost == 0
    ra, rb = _results(local), _results(dask)
    assert ra == rb and len(ra) == grid.n_runs


def test_failed_runs_are_recorded_and_the_sweep_goes_on(tmp_path):
    path = tmp_path / "errors.sqlite"
    bad = Grid(
        "custom",
        [
            ConfigSpec(
                "XS",
                0.01,
                "phireman",
                params={"step_size": -1},
                problem_overrides=FAST,
                label="bad value",
            ),
            ConfigSpec(
                "XS",
                0.01,
                "phireman",
                params={"no_such_param": 1},
                problem_overrides=FAST,
                label="bad key",
            ),
            ConfigSpec("XS", 0.01, "phireman", problem_overrides=FAST, label="fine"),
        ],
        list(range(2)),
    )
    with ResultStore(path) as s:
        summary = run_sweep(bad, s, workers=1, progress=False)
        rows = {(r["label"], r["seed"]): r for r in s.runs()}
    assert summary.completed == 6 and summary.errors == 4
    assert set(summary.resolve_errors) == {"bad value", "bad key"}
    for seed in range(2):
        assert rows[("bad value", seed)]["status"] == "error"
        assert rows[("bad value", seed)]["error"].startswith("ValueError: step_size must be > 0")
        assert rows[("bad key", seed)]["error"].startswith(
            "ValueError: unknown parameter(s) no_such_param"
        )
        assert rows[("bad key", seed)]["tu1"] is None
        ok = rows[("fine", seed)]
        assert ok["status"] == "ok" and 0.0 <= ok["tu1"] <= 1.0 and ok["error"] is None

    # Through the command line: error rows make the exit status 1, a rerun skips them,
    # --retry-errors runs them again (and they fail again, deterministically).
    argv = [
        "sweep",
        "--grid",
        "custom",
        "--sizes",
        "XS",
        "--attrition",
        "1%",
        "--methods",
        "phireman",
        "--seeds",
        "2",
        "--set",
        "n_steps=20",
        "--set",
        "step_size=-1",
        "--store",
        str(path),
        "--workers",
        "1",
        "--no-progress",
    ]
    assert main(argv) == 1
    with ResultStore(path, readonly=True) as s:
        assert s.count() == 6  # the same configuration as 'bad value': nothing new
    assert main(argv + ["--retry-errors"]) == 1
    with ResultStore(path, readonly=True) as s:
        assert s.count() == 6 and s.count("error") == 4


def test_store_is_resumable_and_ignores_duplicates(tmp_path):
    grid = custom_grid(["XS"], [0.0], ["phireman"], range(3), problem_overrides=FAST)
    path = tmp_path / "s.sqlite"
    seen = []
    with ResultStore(path) as s:
        first = run_sweep(grid, s, workers=1, chunk=2, progress=False, on_rows=seen.append)
        again = run_sweep(grid, s, workers=1, progress=False)
        rows = s.runs()
        assert s.insert_runs([{k: v for k, v in rows[0].items() if k != "id"}]) == 0  # UNIQUE key
        mode = s.db.execute("PRAGMA journal_mode").fetchone()[0]
    assert mode == "wal"
    assert [len(b) for b in seen] == [2, 1]  # one transaction per chunk
    assert first.completed == 3 and again.present == 3 and again.completed == 0
    r = rows[0]
    assert r["code_version"].startswith("phireman ") and " src " in r["code_version"]
    import json

    config = json.loads(r["config_json"])
    assert config["problem"]["n_steps"] == 20 and config["params_resolved"] is True
    assert config["params"]["step_size"] > 0  # resolved defaults, not just the overrides
    assert r["created_utc"] and r["wall_s"] > 0 and r["final_alive"] >= r["final_active"]


def test_paper_grids():
    table = paper_table_grid()
    assert table.n_runs == 7500 and len(table.configs) == 75
    assert {c.method for c in table.configs} == {"phireman", "dccrs", "mccst"}
    abl = paper_ablations_grid()
    assert abl.n_runs == 700
    by_label = {c.label: c for c in abl.configs}
    assert by_label["v = 0.1"].problem().max_speed_m_s == pytest.approx(0.1)
    assert by_label["σ = 0.2"].problem().task_walk_sigma_m == pytest.approx(0.2)
    assert by_label["Þ = 0"].method == "phireman-no-task"
    assert by_label["nodes only"].method == "phireman-nodes-only"
    # The ablations' default is the table's ΦIREMAN S / 1 % configuration: stored once, run once.
    table_default = next(
        c for c in table.configs if (c.size, c.attrition, c.method) == ("S", 0.01, "phireman")
    )
    assert resolve(by_label["default"]).config_key == resolve(table_default).config_key
    assert by_label["default"].spec_key == table_default.spec_key
    # Different configurations never share a key.
    keys = {resolve(c).config_key for c in table.configs}
    assert len(keys) == 75


def test_cli_rejects_bad_grids(tmp_path, capsys):
    store = str(tmp_path / "x.sqlite")
    assert (
        main(
            [
                "sweep",
                "--grid",
                "custom",
                "--sizes",
                "XXL",
                "--attrition",
                "0",
                "--methods",
                "phireman",
                "--store",
                store,
            ]
        )
        == 2
    )
    assert "unknown size" in capsys.readouterr().err
    assert (
        main(
            [
                "sweep",
                "--grid",
                "custom",
                "--sizes",
                "XS",
                "--attrition",
                "0",
                "--methods",
                "nope",
                "--store",
                store,
            ]
        )
        == 2
    )
    assert "valid methods" in capsys.readouterr().err
    assert main(["sweep", "--grid", "paper-ablations", "--sizes", "S", "--store", store]) == 2
    assert (
        main(
            [
                "sweep",
                "--grid",
                "custom",
                "--sizes",
                "XS",
                "--attrition",
                "0",
                "--methods",
                "phireman",
                "--set",
                "n_steps=0",
                "--store",
                store,
            ]
        )
        == 2
    )
    assert "n_steps must be >= 1" in capsys.readouterr().err


def test_tune_ranks_settings_and_records_the_search(tmp_path, capsys):
    out = tmp_path / "tuning"
    argv = [
        "tune",
        "--method",
        "phireman",
        "--grid",
        "step_size=0.05,0.3",
        "--size",
        "XS",
        "--seeds",
        "2",
        "--set",
        "n_steps=20",
        "--store",
        str(tmp_path / "tune.sqlite"),
        "--workers",
        "1",
        "--no-progress",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "(defaults)" in printed and "step_size=0.05" in printed and "step_size=0.3" in printed
    assert "best:" in printed
    md = (out / "phireman_XS_1pct.md").read_text()
    assert (
        "phireman tune --method phireman --grid step_size=0.05,0.3 --size XS --attrition 0.01 --seeds 2"
        in md
    )
    assert md.count("| 1 |") == 1 and "| 3 |" in md  # three settings ranked: defaults + 2
    with ResultStore(tmp_path / "tune.sqlite", readonly=True) as s:
        assert s.count() == 6 and {r["grid"] for r in s.runs()} == {"tune"}
    # rerunning the search runs nothing new
    assert main(argv) == 0
    with ResultStore(tmp_path / "tune.sqlite", readonly=True) as s:
        assert s.count() == 6

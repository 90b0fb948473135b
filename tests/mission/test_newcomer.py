"""Issue 14: every command as a newcomer meets it. No silent surprises (every flag honoured or
refused with the reason), no tracebacks (one-line cause and fix, exit 2 for bad input, 130 for
Ctrl-C), one vocabulary for the options commands share."""

from __future__ import annotations

import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time

import pytest

from mission.cli import main, parse_rate, UserError

PHIREMAN = [sys.executable, "-m", "mission.cli"]
FAST = ["--set", "n_steps=20"]


def _err(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


# -- sim --mission: flags that describe a paper preset are refused, not ignored ------------------


@pytest.mark.parametrize(
    "flags, named",
    [
        (["--attrition", "0.05", "--method", "mccst"], ["--attrition", "--method"]),
        (["--size", "XL"], ["--size"]),
        (["--set", "nonsense=1"], ["--set"]),
        (["--reading", "literal"], ["--reading"]),
        (["--workers", "2"], ["--workers"]),
    ],
)
def test_sim_mission_refuses_preset_flags(flags, named, capsys):
    assert main(["sim", "--mission", "wildfire", *flags]) == 2
    err = _err(capsys)
    assert "do" in err and "not apply with --mission" in err
    for flag in named:
        assert flag in err
    assert "mission show wildfire" in err  # the fix
    assert "TU1" not in capsys.readouterr().out


def test_sim_mission_honours_seed_and_seeds(capsys):
    assert (
        main(["sim", "--mission", "wildfire", "--seed", "5", "--seeds", "2", "--no-progress"]) == 0
    )
    out = capsys.readouterr().out
    assert "seed 5:" in out and "seed 6:" in out and "seed 1:" not in out


# -- one parser for rates, one meaning for --seed, one --workers ------------------------------------


def test_parse_rate_accepts_fractions_and_percents():
    assert parse_rate("0.01") == pytest.approx(0.01)
    assert parse_rate("1%") == pytest.approx(0.01)
    assert parse_rate("0.5 %".replace(" ", "")) == pytest.approx(0.005)
    for bad in ("abc", "150%", "-0.1", "2"):
        with pytest.raises(UserError):
            parse_rate(bad)


def test_sim_accepts_percent_attrition_and_seed_alias(capsys, tmp_path):
    a = tmp_path / "a"
    b = tmp_path / "b"
    common = ["sim", "--size", "XS", "--seeds", "2", "--workers", "1", "--no-progress", *FAST]
    assert main(common + ["--attrition", "2%", "--seed", "7", "--out", str(a)]) == 0
    assert main(common + ["--attrition", "0.02", "--seed-start", "7", "--out", str(b)]) == 0
    out = capsys.readouterr().out
    assert "TU1 = " in out
    assert (a / "runs.csv").read_text().splitlines()[1].startswith("7,")
    strip = lambda p: [line.split(",")[:4] for line in (p / "runs.csv").read_text().splitlines()]  # noqa: E731
    assert strip(a) == strip(b)


@pytest.mark.parametrize(
    "cmd",
    [["sim"], ["sweep", "--dry-run"], ["tune", "--method", "phireman", "--grid", "step_size=0.1"]],
)
def test_workers_zero_is_refused_everywhere(cmd, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*cmd, "--workers", "0"])
    assert exc.value.code == 2
    assert "--workers: must be >= 1" in capsys.readouterr().err


def test_workers_default_is_one_place():
    from mission import cli
    from mission.commands import sweep

    p = cli.build_parser("sweep")
    args = p.parse_args(["sweep"])
    assert args.workers is None  # resolved by mission.cli.resolve_workers, not frozen at import
    assert cli.resolve_workers(None) == cli.default_workers()
    assert sweep  # imported


def test_sweep_accepts_both_spellings(tmp_path, capsys):
    store = tmp_path / "s.sqlite"
    base = [
        "sweep",
        "--grid",
        "custom",
        "--attrition",
        "1%",
        "--seeds",
        "1",
        "--dry-run",
        "--store",
        str(store),
    ]
    assert main(base + ["--size", "XS", "S", "--method", "phireman", "mccst"]) == 0
    new = capsys.readouterr().out
    assert main(base + ["--sizes", "XS", "S", "--methods", "phireman", "mccst"]) == 0
    assert capsys.readouterr().out == new
    assert "4 runs" in new


def test_version(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("phireman ") and any(ch.isdigit() for ch in out)


# -- tracebacks become one-line causes with the fix ------------------------------------------------


def test_sweep_store_that_is_a_directory(tmp_path, capsys):
    assert (
        main(
            [
                "sweep",
                "--grid",
                "custom",
                "--size",
                "XS",
                "--attrition",
                "0",
                "--method",
                "phireman",
                "--seeds",
                "1",
                "--store",
                str(tmp_path),
                "--no-progress",
                *FAST,
            ]
        )
        == 2
    )
    err = _err(capsys)
    assert "is a directory" in err and "results.sqlite" in err


def test_report_on_a_file_that_is_not_a_store(tmp_path, capsys):
    f = tmp_path / "README.md"
    f.write_text("# not a database\n" * 100)
    assert main(["report", str(f), "--out", str(tmp_path / "r")]) == 2
    err = _err(capsys)
    assert "not a phireman results store" in err and "phireman sweep --store" in err
    assert main(["report", str(tmp_path / "missing.sqlite"), "--out", str(tmp_path / "r")]) == 2
    assert "no results store" in _err(capsys)


def test_report_on_an_sqlite_file_of_something_else(tmp_path, capsys):
    f = tmp_path / "other.sqlite"
    db = sqlite3.connect(f)
    db.execute("CREATE TABLE t (x)")
    db.commit()
    db.close()
    assert main(["report", str(f), "--out", str(tmp_path / "r")]) == 2
    assert "not a phireman results store" in _err(capsys)


def test_emulate_port_in_use(capsys):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    try:
        port = s.getsockname()[1]
        assert (
            main(["emulate", "--vehicles", "1", "--base-port", str(port), "--duration-s", "0.1"])
            == 2
        )
    finally:
        s.close()
    err = _err(capsys)
    assert "already in use" in err and "--base-port" in err


# -- unknown --set parameters are refused before anything runs -------------------------------------


def test_sweep_unknown_parameter_refused_with_suggestion(tmp_path, capsys):
    store = tmp_path / "s.sqlite"
    assert (
        main(
            [
                "sweep",
                "--grid",
                "custom",
                "--size",
                "XS",
                "--attrition",
                "0",
                "--method",
                "phireman",
                "--seeds",
                "1",
                "--set",
                "step_sise=0.2",
                "--store",
                str(store),
                "--no-progress",
            ]
        )
        == 2
    )
    err = _err(capsys)
    assert "step_sise" in err and "did you mean step_size?" in err
    assert not store.exists()  # nothing ran, nothing stored


def test_sweep_parameter_of_one_method_only(tmp_path, capsys):
    assert (
        main(
            [
                "sweep",
                "--grid",
                "custom",
                "--size",
                "XS",
                "--attrition",
                "0",
                "--method",
                "phireman",
                "mccst",
                "--seeds",
                "1",
                "--set",
                "thorn=0.5",
                "--dry-run",
                "--store",
                str(tmp_path / "s.sqlite"),
            ]
        )
        == 2
    )
    err = _err(capsys)
    assert "not a parameter of mccst" in err and "only phireman" in err


def test_tune_unknown_grid_key_refused(tmp_path, capsys):
    store = tmp_path / "t.sqlite"
    assert (
        main(
            [
                "tune",
                "--method",
                "phireman",
                "--grid",
                "stepsize=0.1,0.2",
                "--seeds",
                "2",
                "--store",
                str(store),
                "--no-progress",
            ]
        )
        == 2
    )
    assert "did you mean step_size?" in _err(capsys)
    assert not store.exists()


# -- the time estimate comes from measured costs ---------------------------------------------------


def test_dry_run_estimate_uses_measured_costs_and_the_store(tmp_path, capsys):
    from mission.experiments.sweep import estimate_run_s, measured_costs
    from planner.problem import problem_preset

    xl, xs = problem_preset("XL", 0.01), problem_preset("XS", 0.01)
    assert estimate_run_s(xl) > 5 * estimate_run_s(xs)
    from mission.experiments.sweep import METHOD_COST_FACTOR

    assert estimate_run_s(xl, "mccst") == pytest.approx(
        METHOD_COST_FACTOR["mccst"] * estimate_run_s(xl, "phireman")
    )
    # the paper table: 7,500 runs measured at 13.7 min on 2 workers (main 855fc95)
    assert (
        main(
            [
                "sweep",
                "--grid",
                "paper-table",
                "--dry-run",
                "--workers",
                "2",
                "--store",
                str(tmp_path / "none.sqlite"),
            ]
        )
        == 0
    )
    last = capsys.readouterr().out.strip().splitlines()[-1]
    minutes = int(last.split("about ")[1].split(" min")[0])
    assert 10 <= minutes <= 18, last
    # the store's own durations win when it has the size and method
    rows = [
        {
            "status": "ok",
            "wall_s": 10.0,
            "size": "XS",
            "method": "phireman",
            "config_json": '{"problem": {"n_steps": 100}}',
        }
    ] * 3
    measured = measured_costs(rows)
    assert measured[("XS", "phireman")] == pytest.approx(20.0)
    assert estimate_run_s(xs, "phireman", measured) == pytest.approx(20.0)


# -- confidence intervals stay inside [0, 100] -----------------------------------------------------


def test_ci_wider_than_the_range_is_clipped_and_explained():
    from mission.experiments.report import _fmt
    from mission.experiments.sim import format_pct_ci, mean_ci95

    mean, half = mean_ci95([60.0, 100.0])
    assert half > 100
    text, clipped = format_pct_ci(mean, half)
    assert clipped and "clipped" in text and "0.00–100.00" in text and "±" not in text
    assert _fmt(mean, half) == text
    assert format_pct_ci(50.0, 1.5) == ("50.00 ± 1.50", False)


def test_sim_notes_too_few_seeds(capsys):
    assert (
        main(["sim", "--size", "XS", "--seeds", "2", "--workers", "1", "--no-progress", *FAST]) == 0
    )
    err = _err(capsys)
    assert "2 run(s): too few" in err


# -- check says what it invented -------------------------------------------------------------------


def test_check_notes_invented_tasks(tmp_path, capsys):
    f = tmp_path / "bare.yaml"
    f.write_text("name: bare\n")
    assert main(["check", str(f)]) == 0
    out = capsys.readouterr().out
    assert "OK:" in out and "no 'tasks:'" in out and "at random" in out
    assert main(["check", "wildfire"]) == 0
    assert "no 'tasks:'" not in capsys.readouterr().out


# -- Ctrl-C: exit 130, no traceback from the workers, the sweep keeps what it stored ---------------


def _interrupt(args, ready, timeout=90):
    proc = subprocess.Popen(
        PHIREMAN + args,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and proc.poll() is None and not ready():
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()[1]
        os.killpg(proc.pid, signal.SIGINT)  # as the terminal does: the whole process group
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, out, err


def test_ctrl_c_during_sim_exits_130_without_tracebacks():
    # a worker pool that is busy long enough to be interrupted
    args = ["sim", "--size", "S", "--seeds", "400", "--workers", "2", "--no-progress"]
    t0 = time.monotonic()
    code, out, err = _interrupt(args, lambda: time.monotonic() - t0 > 4)
    assert code == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    assert "interrupted after" in err and "of 400 runs; nothing was written" in err
    assert "TU1" not in out


def test_ctrl_c_during_sweep_keeps_what_it_stored(tmp_path):
    store = tmp_path / "s.sqlite"
    args = [
        "sweep",
        "--grid",
        "custom",
        "--size",
        "XS",
        "--attrition",
        "0",
        "1%",
        "--method",
        "phireman",
        "--seeds",
        "60",
        "--chunk",
        "1",
        "--workers",
        "2",
        "--no-progress",
        "--store",
        str(store),
    ]

    def some_rows():
        try:
            db = sqlite3.connect(f"file:{store}?mode=ro", uri=True, timeout=1)
            try:
                return db.execute("SELECT COUNT(*) FROM runs").fetchone()[0] >= 2
            finally:
                db.close()
        except sqlite3.Error:
            return False

    code, out, err = _interrupt(args, some_rows)
    assert code == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    assert "rerun the same command" in err
    db = sqlite3.connect(store)
    n = db.execute("SELECT COUNT(*) FROM runs").fetchone()[0]
    db.close()
    assert 2 <= n < 120


# -- report leads with the user's own configurations and grades only the paper's ------------------


@pytest.fixture(scope="module")
def custom_store(tmp_path_factory):
    path = tmp_path_factory.mktemp("custom") / "custom.sqlite"
    assert (
        main(
            [
                "sweep",
                "--grid",
                "custom",
                "--size",
                "XS",
                "--attrition",
                "0",
                "1%",
                "--method",
                "phireman",
                "mccst",
                "--seeds",
                "3",
                "--set",
                "n_steps=20",
                "--workers",
                "1",
                "--no-progress",
                "--store",
                str(path),
            ]
        )
        == 0
    )
    return path


def test_report_on_a_custom_store_leads_with_it(custom_store, tmp_path, capsys):
    capsys.readouterr()
    assert main(["report", str(custom_store), "--out", str(tmp_path / "r"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "leads with your 4 configurations" in out and "0 of 20" not in out
    md = (tmp_path / "r" / "report.md").read_text()
    lines = md.splitlines()
    first_section = next(line for line in lines if line.startswith("## "))
    assert first_section == "## Your configurations"
    assert md.count("n_steps=20") >= 4
    assert "## Table II" not in md and "| – | – |" not in md  # no rows of dashes
    assert len(lines) < 40


def test_report_with_overrides_does_not_grade_against_the_paper(custom_store, tmp_path, capsys):
    capsys.readouterr()
    assert (
        main(
            [
                "report",
                str(custom_store),
                "--out",
                str(tmp_path / "r"),
                "--set",
                "n_steps=20",
                "--no-progress",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "not compared with the paper" in out and "within 3 pp" not in out
    md = (tmp_path / "r" / "report.md").read_text()
    assert "n_steps=20 (the paper's: 200)" in md
    assert "## Ours against the paper" not in md and " vs " not in md.split("## Table II")[1]
    assert "## Table II (ours)" in md and "| XS | 1 |" in md and "| S |" not in md


def test_compared_heatmap_panels_share_one_colour_scale(monkeypatch, tmp_path):
    from mission.experiments import report
    from mission.experiments.report import figures

    calls = []
    real = figures._heatmap

    def spy(ax, z, marks, sizes, levels, title, vmax=None, **kw):
        calls.append((title, vmax))
        return real(ax, z, marks, sizes, levels, title, vmax, **kw)

    monkeypatch.setattr(figures, "_heatmap", spy)
    cell = report.Cell("S", 0.01, {m: None for m in ("phireman", "dccrs", "mccst")})
    s = report.Sample(report.ConfigSpec("S", 0.01, "phireman"))
    s.by_seed = {"tu1": {0: 70.0, 1: 72.0}, "tu2": {0: 80.0, 1: 81.0}}
    b = report.Sample(report.ConfigSpec("S", 0.01, "dccrs"))
    b.by_seed = {"tu1": {0: 40.0, 1: 42.0}, "tu2": {0: 79.0, 1: 80.0}}
    cell.samples.update(phireman=s, dccrs=b)
    for metric in ("tu1", "tu2"):
        cell.unpaired[metric] = report.best_of(cell.samples, metric)
    report.heatmaps([cell], tmp_path)
    fig3 = [v for t, v in calls if "max(DCCRS, MCCST)" in t]
    assert (
        len(fig3) == 4 and len(set(fig3)) == 1 and fig3[0] >= 29
    )  # ours (+29) and paper (+2.6) alike


# -- replay: parent directories, hints, encoders checked up front, pictures that explain themselves


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "wf"
    assert main(["sim", "--mission", "hazard_zone", "--out", str(out)]) == 0
    return out


def test_replay_parent_directory_picks_the_newest(run_dir, tmp_path, capsys):
    import shutil

    parent = tmp_path / "runs"
    older, newer = parent / "20260101-000000-a", parent / "20260102-000000-b"
    shutil.copytree(run_dir, older)
    shutil.copytree(run_dir, newer)
    os.utime(older / "truth.npz", (1, 1))
    capsys.readouterr()
    assert main(["replay", str(parent), "--animation", "none", "--out", str(tmp_path / "o")]) == 0
    err = _err(capsys)
    assert "holds 2 run directories" in err and newer.name in err
    assert (tmp_path / "o" / "frames.png").is_file()


def test_replay_hint_when_there_is_no_truth(tmp_path, capsys):
    assert main(["replay", str(tmp_path)]) == 2
    err = _err(capsys)
    assert "no truth.npz" in err and "phireman sim --mission" in err
    (tmp_path / "summary.json").write_text("{}")
    assert main(["replay", str(tmp_path)]) == 2
    assert "real vehicles" in _err(capsys)


def test_replay_mp4_without_ffmpeg_fails_up_front(run_dir, tmp_path, monkeypatch, capsys):
    import shutil

    from matplotlib.animation import FFMpegWriter

    import mission.view.replay as replay_mod

    monkeypatch.setattr(shutil, "which", lambda name, *a, **k: None)
    monkeypatch.setattr(FFMpegWriter, "isAvailable", classmethod(lambda cls: False))
    called = []
    monkeypatch.setattr(replay_mod, "load_run", lambda *a, **k: called.append(1))
    assert main(["replay", str(run_dir), "--animation", "mp4", "--out", str(tmp_path)]) == 2
    err = _err(capsys)
    assert "needs ffmpeg" in err and "--animation gif" in err
    assert not called and not list(tmp_path.iterdir())  # nothing rendered before refusing


def test_legend_is_complete():
    from mission.view.plots import Scene, legend_handles

    labels = [
        h.get_label() for h in legend_handles(Scene(100, 80, 300, [lambda ax: None], unit="m"))
    ]
    for needle in (
        "base station",
        "base radio range (80 m)",
        "radio link",
        "drone lost",
        "cut off",
        "drone serving a crew",
        "task tree",
        "Steiner",
        "hazard zone",
    ):
        assert any(needle in label for label in labels), needle
    paper = [h.get_label() for h in legend_handles(Scene(2, 2, 5, unit="paper length units"))]
    assert not any("hazard" in label for label in paper) and any(
        "paper length units" in label for label in paper
    )


def test_frame_shows_names_links_and_a_tree_without_recorded_trees(run_dir):
    import matplotlib.pyplot as plt

    from mission.view.plots import FrameView
    from mission.view.replay import _scene, load_run, tree_at

    (run_dir / "trees.json").rename(run_dir / "trees.json.bak")
    try:
        run = load_run(run_dir)
        assert not run.trees
        k = len(run.t_s) // 2
        tree = tree_at(run, k)  # rebuilt from the recorded positions
        assert tree is not None and tree.n_tasks == run.task_pos_m.shape[1]
        scene = _scene(run)
        assert scene.tree_recomputed and scene.hazard_zones and scene.task_names
        fig, ax = plt.subplots()
        view = FrameView(ax, scene, clock=True)
        view.update(
            run.pos_m[k],
            run.alive[k],
            run.active[k],
            run.task_pos_m[k],
            run.connected[k],
            tree,
            "t = 1 s",
        )
        assert len(view.tree.get_segments()) == len(tree.nodes_m) - 1
        assert (
            len(view.crew.get_segments()) == run.connected[k].sum()
        )  # one serving drone per connected crew
        assert [t.get_text() for t in view.labels] == [n.split(" (")[0] for n in scene.task_names]
        assert ax.get_xlabel() == "east (m)" and ax.get_ylabel() == "north (m)"
        assert view.clock.get_text() == "t = 1 s"
        plt.close(fig)
    finally:
        (run_dir / "trees.json.bak").rename(run_dir / "trees.json")


def test_animation_has_the_frames_asked_for(run_dir, tmp_path):
    from PIL import Image

    from mission.view.replay import replay

    files = replay(run_dir, tmp_path, "gif", max_frames=12)
    gif = next(f for f in files if f.suffix == ".gif")
    with Image.open(gif) as im:
        assert im.n_frames == 12 and im.size[0] > 500

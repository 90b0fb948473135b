"""The command line teaches: every --help renders, bad input exits 2 without a traceback."""

import pytest

from mission.cli import COMMANDS, main


def test_top_level_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert name in out


@pytest.mark.parametrize("name", list(COMMANDS))
def test_each_command_help_renders(name, capsys):
    with pytest.raises(SystemExit) as exc:
        main([name, "--help"])
    assert exc.value.code == 0
    assert "usage: phireman" in capsys.readouterr().out


def test_sim_rejects_bad_input_cleanly(capsys):
    assert main(["sim", "--method", "nope", "--seeds", "1"]) == 2
    err = capsys.readouterr().err
    assert "valid methods" in err and "Traceback" not in err
    assert main(["sim", "--set", "step_size", "--seeds", "1"]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err


def test_sim_runs_and_prints_uptime(capsys, tmp_path):
    code = main(
        [
            "sim",
            "--size",
            "XS",
            "--seeds",
            "2",
            "--workers",
            "1",
            "--no-progress",
            "--set",
            "n_steps=20",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "TU1 = " in out and "TU2 = " in out
    assert (tmp_path / "runs.csv").read_text().count("\n") == 3
    assert (tmp_path / "fig2_timeseries.png").stat().st_size > 1000


def test_sim_info_follows_the_methods_models(capsys):
    # MCCST plans centrally only: --info central is its own model, --info async a clean refusal.
    assert (
        main(["sim", "--size", "XS", "--method", "mccst", "--info", "async", "--seeds", "1"]) == 2
    )
    err = capsys.readouterr().err
    assert "central information only" in err and "Traceback" not in err
    assert (
        main(
            [
                "sim",
                "--size",
                "XS",
                "--method",
                "mccst",
                "--info",
                "central",
                "--seeds",
                "1",
                "--workers",
                "1",
                "--no-progress",
                "--set",
                "n_steps=5",
            ]
        )
        == 0
    )


def test_python_dash_m_reports_user_errors_without_a_traceback():
    import subprocess
    import sys

    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "mission.cli",
            "sim",
            "--method",
            "mccst",
            "--info",
            "async",
            "--seeds",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "central information only" in out.stderr

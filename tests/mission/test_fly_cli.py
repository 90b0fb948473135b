"""`phireman fly` for people: the status line fits 80 columns in plain words, degradation is
shown as it happens (warnings), and flags that cannot apply are refused (no silent surprises)."""

from __future__ import annotations

import io

import pytest
from status_rows import status_row

from mission.cli import main
from mission.commands.fly import _EXPLAIN, _group_report, _Status, format_status


def _status(**kw):
    """A status row before the expected fleet is known (counts out of the fleet heard)."""
    return status_row(**{"fleet_expected": None, **kw})


@pytest.mark.parametrize("fleet", [6, 50, 500, 5000])
@pytest.mark.parametrize("phase", ["discover", "audit", "launch", "run", "end", "done"])
def test_the_status_line_fits_80_columns_in_plain_words(fleet, phase):
    line = format_status(
        _status(fleet=fleet, networked=fleet - 10, lost=10, phase=phase, end_t0_s=100.0), 80
    )
    assert len(line) <= 79
    assert "TU1" in line and "crews" in line and "net" in line and "lost" in line
    wide = format_status(_status(fleet=fleet, phase=phase, end_t0_s=100.0), 160)
    assert "reclaimed" in wide and "GUIDED:40" in wide  # more detail when there is room


def test_degradation_is_shown_as_warnings_once_each():
    out = io.StringIO()
    st = _Status(out)
    st(_status(phase="launch", command_failures=7))
    st(_status(phase="launch", command_failures=8))  # not repeated for one more
    st(
        _status(
            phase="launch",
            failsafes=2,
            last_failsafe=(3.0, (0, 5), "Failsafe activated: No offboard signal"),
        )
    )
    # 20x requested, the clock advances 2x wall: "running at 2.0x instead of 20x"
    for k in range(12):
        st(_status(wall_s=float(k), t_s=100.0 + 2.0 * k))
    text = out.getvalue()
    assert text.count("commands failed") == 1
    assert 'sysid 5 reports "Failsafe activated: No offboard signal" (+1 more)' in text
    assert "running at 2.0x instead of 20x" in text


def test_the_closing_words_explain_tu1_and_tu2():
    assert "TU1:" in _EXPLAIN and "TU2:" in _EXPLAIN and "reached once" in _EXPLAIN


def test_interrupt_report_groups_large_fleets():
    items = [dict(link_id=0, sysid=k, confirmed=True, state="told RTL; now RTL") for k in range(30)]
    lines = _group_report(items)
    assert lines == [
        f"30 vehicle(s) told RTL; now RTL [link:sysid "
        f"{', '.join(f'0:{k}' for k in range(12))} +18 more]"
    ]
    assert len(_group_report(items[:3])) == 3


@pytest.mark.parametrize(
    "args,words",
    [
        (["fly", "sitl_ardupilot", "--personality", "px4"], "--personality applies to emulated"),
        (["fly", "wildfire", "--vehicles", "3"], "--vehicles applies to real links"),
        (["fly", "wildfire", "--speedup", "0"], "--speedup must be > 0"),
        (["fly", "nonexistent_mission"], "neither a mission file nor a shipped example"),
        (["fly", "wildfire", "--forward-overrides", "refuse"], "--forward-overrides needs"),
    ],
)
def test_flags_that_cannot_apply_are_refused(capsys, args, words):
    assert main(args) == 2
    assert words in capsys.readouterr().err

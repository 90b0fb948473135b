"""The live status line of ``phireman fly`` (issue 28, points 6 and 7): one format from finding
to the end, the mission's crew count from the start, and on a narrow terminal the lesser
fields leave first while TU1/TU2 stay."""

from __future__ import annotations

import io

import pytest
from status_rows import status_row

from mission.commands.fly import (
    STATUS_DROP_ORDER,
    _Status,
    format_status,
    planned_drop,
    status_layout,
)


def _finding(**kw):
    d = dict(
        phase="discover",
        t_s=2.0,
        fleet=0,
        networked=0,
        lost=0,
        returning=0,
        tasks_covered=None,
        tu1=None,
        tu2=None,
        modes={},
        reclaims=0,
    )
    d.update(kw)
    return status_row(**d)


def test_the_crews_of_the_mission_show_before_they_are_measured():
    line = format_status(_finding(), 80)
    assert "crews -/10" in line and "0/0" not in line


@pytest.mark.parametrize("width", [20, 30, 40, 50, 60, 70, 80, 100, 140])
def test_tu_stays_visible_at_every_width_and_the_lesser_fields_leave_first(width):
    line, dropped = status_layout(status_row(), width)
    assert len(line) <= width - 1 or line == "TU1 71% TU2 77%"
    assert "TU1 71% TU2 77%" in line
    gone = STATUS_DROP_ORDER[:dropped]
    # what is left out is exactly the first `dropped` fields of the order, nothing else
    words = {
        "modes": "GUIDED:40",
        "reclaimed": "reclaimed",
        "home": "home",
        "lost": "lost",
        "drones": "drones:",
        "crews": "crews",
        "clock": "100/200s",
        "phase": "flying",
    }
    for field, word in words.items():
        assert (word in line) == (field not in gone), (field, line)


def test_at_60_columns_the_tu_figures_and_the_networked_drones_stay():
    # planned for the run's widest line ("flying 200/200s | 50/50 net | crews 10/10 | TU1 100%
    # TU2 100%" is 61 columns): the crews leave at 60, stay at 66
    line = format_status(status_row(), 60, planned_drop(status_row(), 60))
    assert line == "flying 100/200s | 40/50 net | TU1 71% TU2 77%"
    line = format_status(status_row(), 66, planned_drop(status_row(), 66))
    assert line == "flying 100/200s | 40/50 net | crews 9/10 | TU1 71% TU2 77%"
    assert (
        format_status(status_row(), 40, planned_drop(status_row(), 40))
        == "flying 100/200s | TU1 71% TU2 77%"
    )


@pytest.mark.parametrize("width", [60, 80, 100, 140])
def test_one_look_from_finding_to_the_end(width):
    # A tty status line through a whole flight: the same fields, words and separators in every
    # phase (the old line switched to another format once the numbers grew, at 80 columns).
    out = io.StringIO()
    out.isatty = lambda: True  # type: ignore[method-assign]
    st = _Status(out)
    st.columns = width
    phases = [
        _finding(),
        _finding(phase="audit", fleet=50, networked=50, modes={"STABILIZE": 50}),
        status_row(phase="launch", t_s=30.0, tasks_covered=None, tu1=None, tu2=None, reclaims=0),
        status_row(
            t_mission_s=5.0, networked=50, lost=0, returning=0, tu1=1.0, tu2=1.0, reclaims=0
        ),
        status_row(t_mission_s=199.0, networked=38, lost=11, returning=1, tasks_covered=10),
        status_row(phase="end", end_t0_s=320.0, t_s=330.0),
        status_row(phase="done", end_t0_s=320.0, t_s=390.0),
    ]
    shapes = set()
    for d in phases:
        st(d)
        line = out.getvalue().rsplit("\r", 1)[-1].rstrip()
        assert len(line) <= width - 1, line
        assert "TU1" in line and "TU2" in line
        # the shape: which labels appear, and where TU is (reclaims and modes may trail it
        # while there is room)
        parts = line.split(" | ")
        tu_at = next(k for k, p in enumerate(parts) if p.startswith("TU1"))
        shapes.add((tu_at, *(w in line for w in ("drones:", "net", "lost", "home", "crews"))))
    assert len(shapes) == 1, shapes

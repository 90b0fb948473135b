"""The closing lines of ``phireman fly`` (issue 28, points 4 and 5): the printed speed-up is
the printed mission seconds over the printed wall seconds, the pace the mission was flown at
is named beside the one asked, a slow pace is warned about, and both TU figures say the span
they cover; the replay marks an interrupt."""

from __future__ import annotations

import re

import pytest

from mission.commands.fly import format_pace, format_tu, slow_pace_warning


def _summary(**kw):
    s = dict(
        mission_s_flown=201.0,
        flown_span_s=201.0,
        duration_s=201.0,
        wall_s=84.5,
        speedup_requested=4.0,
        speedup_achieved=3.6,
        speedup_overall=201.0 / 84.5,
        speedup_slow=False,
        interrupted=None,
        station={"tu1": 0.672, "tu2": 0.70, "ticks": 201},
        truth={"tu1": 0.66, "tu2": 0.69, "samples": 201, "alive_end": 30},
    )
    s.update(kw)
    return s


def _pace_numbers(line: str) -> tuple[float, float, float]:
    m = re.match(r"flown ([\d.]+) s of mission in ([\d.]+) s wall \(([\d.]+)x overall", line)
    assert m, line
    return float(m[1]), float(m[2]), float(m[3])


@pytest.mark.parametrize("span, wall", [(201.0, 84.5), (400.0, 115.5), (107.6, 30.2)])
def test_the_printed_speed_up_is_the_printed_seconds_divided(span, wall):
    (line,) = format_pace(_summary(mission_s_flown=span, wall_s=wall))
    mission_s, wall_s, x = _pace_numbers(line)
    assert x == pytest.approx(mission_s / wall_s, abs=0.051)
    # the other number is named for what it is, beside the one asked
    assert "the mission itself ran at 3.6x, 4x asked" in line


def test_the_issue_line_no_longer_says_4x_for_201_s_in_84_5_s():
    (line,) = format_pace(_summary())
    assert "(2.4x overall" in line and "(speed-up 4.0x)" not in line


def test_a_slow_pace_is_named_with_both_numbers():
    text = slow_pace_warning(_summary(speedup_achieved=2.4, speedup_requested=20.0))
    assert "2.4x" in text and "20x" in text and "speedup_achieved" in text


def test_both_tu_figures_say_their_span():
    whole = format_tu(_summary())
    assert whole[-1] == "both over the whole 201 s mission"
    assert "(201 control ticks)" in whole[0] and "(201 samples;" in whole[1]
    cut = format_tu(
        _summary(
            interrupted="end",
            flown_span_s=107.6,
            duration_s=200.0,
            station={"tu1": 0.86, "tu2": 0.977, "ticks": 108},
            truth={"tu1": 0.85, "tu2": 0.96, "samples": 108, "alive_end": 40},
        )
    )
    assert (
        cut[-1] == "both over the first 107.6 s, flown before the interrupt (of the 200 s mission)"
    )


def test_the_replay_chart_marks_the_interrupt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mission.view.replay import mark_interrupt

    fig, ax = plt.subplots()
    try:
        assert mark_interrupt(ax, {"interrupted": None, "interrupted_at_s": None}) is None
        line = mark_interrupt(ax, {"interrupted": "end", "interrupted_at_s": 107.6})
        assert line is not None and list(line.get_xdata()) == [107.6, 107.6]
        assert "interrupted" in line.get_label() and "108 s" in line.get_label()
    finally:
        plt.close(fig)

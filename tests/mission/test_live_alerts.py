"""The alert model of the live page (mission.view.live.alerts): in memory, explicit time."""

from __future__ import annotations

import math

import pytest

from mission.view.live.alerts import AlertBook, AlertConfig


def step(book, t, states, modes=None, **kw):
    ids = [f"0:{k + 1}" for k in range(len(states))]
    return book.update(
        t, vehicles=ids, states=states, modes=modes or ["GUIDED"] * len(states), **kw
    )


def test_failsafe_raised_once_on_the_edge_and_not_when_commanded():
    book = AlertBook()
    assert step(book, 0.0, ["networked", "networked"]) == []
    out = step(book, 1.0, ["returning", "networked"], ["RTL", "GUIDED"])
    assert [(a.kind, a.subject) for a in out] == [("failsafe", "0:1")]
    assert "RTL" in out[0].text
    assert step(book, 2.0, ["returning", "networked"], ["RTL", "GUIDED"]) == []  # not again
    # Vehicle 2 sent home by the station: no alert.
    out = step(book, 3.0, ["returning", "returning"], ["RTL", "RTL"], commanded={"0:2"})
    assert out == []
    assert [a["subject"] for a in book.unacknowledged()] == ["0:1"]


def test_lost_only_for_a_vehicle_that_was_flying():
    book = AlertBook()
    step(book, 0.0, ["networked", "landed"])
    out = step(book, 5.0, ["lost", "lost"])
    assert [(a.kind, a.subject) for a in out] == [("lost", "0:1")]
    # Recovered, then lost again: a second alert.
    step(book, 6.0, ["networked", "lost"])
    out = step(book, 9.0, ["lost", "lost"])
    assert [a.kind for a in out] == ["lost"] and out[0].alert_id != 1


def test_crew_cut_off_after_the_threshold_only():
    book = AlertBook(AlertConfig(crew_cut_off_s=30.0))
    kw = {"crews": ["Engine 7"], "mission_running": True}
    assert step(book, 0.0, [], crews_connected=[False], **kw) == []
    assert step(book, 29.9, [], crews_connected=[False], **kw) == []
    out = step(book, 30.0, [], crews_connected=[False], **kw)
    assert [(a.kind, a.subject) for a in out] == [("crew", "Engine 7")]
    assert "30 s" in out[0].text
    # Connected again resets the clock: 20 s cut off later is no alert.
    step(book, 31.0, [], crews_connected=[True], **kw)
    assert step(book, 51.0, [], crews_connected=[False], **kw) == []
    assert step(book, 71.0, [], crews_connected=[False], **kw) == []
    assert len(step(book, 81.0, [], crews_connected=[False], **kw)) == 1
    # Not while the mission is not running.
    book2 = AlertBook(AlertConfig(crew_cut_off_s=0.0))
    assert step(book2, 0.0, [], crews=["A"], crews_connected=[False], mission_running=False) == []


def test_low_battery_by_level_or_charge_state():
    book = AlertBook(AlertConfig(battery_low_frac=0.3))
    out = step(
        book,
        0.0,
        ["networked"] * 3,
        battery_frac=[0.5, 0.29, math.nan],
        charge_state=[0, 0, 2],
    )
    assert sorted(a.subject for a in out) == ["0:2", "0:3"]
    assert "29 %" in next(a.text for a in out if a.subject == "0:2")
    # Landed at the base (its swap pending): expected, not an alert; armed again and low: one.
    book2 = AlertBook(AlertConfig(battery_low_frac=0.3))
    assert step(book2, 0.0, ["landed"], battery_frac=[0.1]) == []
    assert len(step(book2, 1.0, ["networked"], battery_frac=[0.1])) == 1


def test_acknowledge_one_and_all_and_records():
    book = AlertBook()
    step(book, 0.0, ["networked", "networked"])
    step(book, 1.0, ["lost", "lost"])
    ids = [a["id"] for a in book.unacknowledged()]
    assert len(ids) == 2
    recs = book.acknowledge(ids[0], 2.0, "web 127.0.0.1")
    assert [(r.alert_id, r.source, r.t_s) for r in recs] == [(ids[0], "web 127.0.0.1", 2.0)]
    assert [a["id"] for a in book.unacknowledged()] == [ids[1]]
    assert book.acknowledge(ids[0], 3.0, "x") == []  # already acknowledged
    assert [r.alert_id for r in book.acknowledge("all", 4.0, "x")] == [ids[1]]
    assert book.unacknowledged() == []
    assert [a["acked"] for a in book.recent()] == [True, True]
    with pytest.raises(KeyError):
        book.acknowledge(99, 5.0, "x")


def test_cleared_alert_stays_until_acknowledged():
    book = AlertBook()
    step(book, 0.0, ["networked"])
    step(book, 1.0, ["lost"])
    step(book, 2.0, ["networked"])  # heard again: cleared, still on the banner
    (a,) = book.unacknowledged()
    assert a["cleared"] and not a["acked"]


def test_config_is_validated():
    with pytest.raises(ValueError):
        AlertConfig(crew_cut_off_s=-1)
    with pytest.raises(ValueError):
        AlertConfig(battery_low_frac=1.5)

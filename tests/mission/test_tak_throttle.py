"""The TAK publisher's throttle (mission/view/tak.py ``Throttle``): what a picture sends, in
memory with explicit time."""

from __future__ import annotations

import pytest

from mission.view.tak import CotItem, Throttle


def item(uid: str, kind: str = "uav", key: tuple = (0, 0)) -> CotItem:
    return CotItem("a-f-A-M-H-Q", uid, kind, key, uid.encode)


def uids(items: list[CotItem]) -> list[str]:
    return [it.uid for it in items]


def test_unchanged_items_wait_for_their_refresh_and_changed_ones_go_at_once():
    th = Throttle(budget=10, refresh_s=2.5)
    assert uids(th.select([item("a"), item("b")], 0.0)) == ["a", "b"]  # new
    assert th.select([item("a"), item("b")], 1.0) == []  # unchanged, not due
    assert uids(th.select([item("a", key=(1, 0)), item("b")], 2.0)) == ["a"]  # a moved
    assert uids(th.select([item("a", key=(1, 0)), item("b")], 2.5)) == ["b"]  # b's refresh
    assert uids(th.select([item("a", key=(1, 0)), item("b")], 4.5)) == ["a"]
    assert th.deferred == 0


def test_over_budget_the_crews_go_first_and_the_rest_take_turns():
    th = Throttle(budget=3, refresh_s=100.0)
    pic = [item(f"r{k}", "radio") for k in range(4)] + [item("u", "uav"), item("c", "crew")]
    first = uids(th.select(pic, 0.0))
    assert first[:2] == ["c", "u"] and first[2].startswith("r")
    assert th.deferred == 3
    # The lines that waited go next (never sent before the ones sent once); nothing starves.
    second = uids(th.select(pic, 1.0))
    assert len(second) == 3 and set(second).isdisjoint(first)
    third = uids(th.select(pic, 2.0))
    assert third == [] and th.deferred == 3  # everything sent once, nothing changed


def test_a_changed_crew_marker_goes_first_and_the_rest_by_how_long_they_waited():
    th = Throttle(budget=1, refresh_s=10.0)
    th.select([item("c", "crew")], 0.0)
    th.select([item("u", "uav")], 0.0)
    th.select([item("r", "radio")], 5.0)
    moved = [item("r", "radio", key=(9,)), item("u", "uav", key=(5, 5)), item("c", "crew", ("x",))]
    assert uids(th.select(moved, 6.0)) == ["c"]  # its state changed: urgent
    assert uids(th.select(moved, 7.0)) == ["u"]  # waited since 0
    assert uids(th.select(moved, 8.0)) == ["r"]  # waited since 5


def test_crews_that_never_change_are_still_refreshed_among_many_moving_drones():
    # 40 drones moving every picture, 5 still crews, 10 messages a picture: every crew's marker
    # is sent again within its refresh time plus a few pictures (aging, no starvation).
    th = Throttle(budget=10, refresh_s=5.0)
    last_sent = {f"c{k}": 0.0 for k in range(5)}
    for t in range(1, 60):
        pic = [item(f"u{i}", "uav", key=(t, i)) for i in range(40)]
        pic += [item(f"c{k}", "crew") for k in range(5)]
        for it in th.select(pic, float(t)):
            if it.uid in last_sent:
                last_sent[it.uid] = float(t)
        assert all(t - s <= 5.0 + 2.0 for s in last_sent.values()), (t, last_sent)


def test_a_budget_below_one_message_is_refused():
    with pytest.raises(ValueError, match="budget"):
        Throttle(budget=0, refresh_s=1.0)

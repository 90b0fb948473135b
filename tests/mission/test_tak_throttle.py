"""The TAK publisher's throttle (mission/view/tak.py ``Throttle``): what a picture sends, in
memory with explicit time."""

from __future__ import annotations

import pytest

from mission.view.tak import CotItem, Throttle


def item(uid: str, kind: str = "uav", key: tuple = (0, 0)) -> CotItem:
    return CotItem("a-f-A-M-H-Q", uid, kind, key, uid.encode())


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


def test_a_moving_drone_outranks_a_line_but_not_a_crew():
    th = Throttle(budget=1, refresh_s=100.0)
    th.select([item("c", "crew")], 0.0)
    th.select([item("u", "uav")], 0.0)
    moved = [item("r", "radio"), item("u", "uav", key=(5, 5)), item("c", "crew", key=("x",))]
    assert uids(th.select(moved, 1.0)) == ["c"]
    assert uids(th.select(moved, 2.0)) == ["u"]
    assert uids(th.select(moved, 3.0)) == ["r"]


def test_a_budget_below_one_message_is_refused():
    with pytest.raises(ValueError, match="budget"):
        Throttle(budget=0, refresh_s=1.0)

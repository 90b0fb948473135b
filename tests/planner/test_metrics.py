"""TU1/TU2 on hand-built records whose values are computed by hand."""

import numpy as np
import pytest

from planner.metrics import task_uptime, task_uptime_reference, uptime_series


def test_hand_computed_two_tasks_four_steps():
    # t:      0      1      2      3
    # task0:  0      1      1      0
    # task1:  0      0      1      1
    a = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=bool)
    tu1, tu2 = task_uptime(a)
    # TU1 = (0 + 1/2 + 2/2 + 1/2) / 4
    assert tu1 == pytest.approx((0 + 0.5 + 1 + 0.5) / 4)
    # TU2: t0 0/0 -> 0; t1 1/1; t2 2/2; t3 1/2 (both ever connected)
    assert tu2 == pytest.approx((0 + 1 + 1 + 0.5) / 4)


def test_zero_over_zero_variants():
    a = np.array([[0], [0], [1], [1]], dtype=bool)
    assert task_uptime(a, "zero") == pytest.approx((0.5, 0.5))
    assert task_uptime(a, "one")[1] == pytest.approx(1.0)
    assert task_uptime(a, "skip")[1] == pytest.approx(1.0)
    with pytest.raises(ValueError):
        task_uptime(a, "bogus")


def test_inclusive_window_keeps_tu2_at_most_one(rng):
    a = rng.random((50, 7)) < 0.3
    s = uptime_series(a)
    assert (s.tu2_step <= 1.0).all() and (s.tu2_step >= s.tu1_step - 1e-12).all()


def test_matches_reference_on_random_records(rng):
    for _ in range(20):
        a = rng.random((int(rng.integers(1, 40)), int(rng.integers(1, 9)))) < rng.random()
        assert np.allclose(task_uptime(a), task_uptime_reference(a))


def test_bad_shape_is_rejected():
    with pytest.raises(ValueError, match="tau, m"):
        uptime_series(np.zeros(5, dtype=bool))

"""The clocks of mavedge.clock, each with injected time (no wall-clock reads in the assertions)."""

from __future__ import annotations

import pytest

from mavedge.clock import Clock, PacedClock, PacedReader, RealClock, VirtualClock


class _Value:
    """Stands in for multiprocessing.RawValue('d')."""

    def __init__(self, value: float = 0.0) -> None:
        self.value = value


class _Wall:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


UNIX_S = 1.75e9


def test_every_clock_is_a_clock():
    sim, ack = _Value(), _Value()
    clocks = [
        VirtualClock(),
        RealClock(2.0, _Wall(), unix_time_fn=lambda: UNIX_S),
        PacedClock(2.0, sim, ack, time_fn=_Wall(), unix_time_fn=lambda: UNIX_S),
        PacedReader(2.0, sim, ack, unix_time_fn=lambda: UNIX_S),
    ]
    for clock in clocks:
        assert isinstance(clock, Clock)
    assert not isinstance(lambda: 0.0, Clock)  # a bare now() is not a Clock


def test_virtual_clock_moves_only_when_told():
    clock = VirtualClock(5.0, unix_time_at_zero_s=UNIX_S)
    assert clock.now() == 5.0
    assert clock.advance(0.25) == 5.25 and clock.now() == 5.25
    assert clock.wall_delay_s(10.0) == 0.0
    assert clock.unix_time_at_zero_s == UNIX_S
    with pytest.raises(ValueError):
        clock.advance(-0.1)
    assert clock.now() == 5.25


def test_real_clock_scales_wall_time_and_anchors_unix_time():
    wall = _Wall(100.0)
    clock = RealClock(4.0, wall, unix_time_fn=lambda: UNIX_S)
    assert clock.now() == 0.0
    wall.t += 2.5
    assert clock.now() == pytest.approx(10.0)
    assert clock.wall_delay_s(8.0) == pytest.approx(2.0)
    assert clock.wall_delay_s(-1.0) == 0.0
    assert clock.unix_time_at_zero_s == UNIX_S
    # t0_s: the clock reads t0_s now, so clock time 0 was t0_s / speedup wall seconds ago.
    later = RealClock(4.0, wall, t0_s=20.0, unix_time_fn=lambda: UNIX_S)
    assert later.now() == pytest.approx(20.0)
    assert later.unix_time_at_zero_s == pytest.approx(UNIX_S - 5.0)
    with pytest.raises(ValueError):
        RealClock(0.0, wall)


def test_real_clocks_given_one_anchor_read_one_time():
    # Two processes (here two clocks) on one monotonic clock and one wall0_s read the same time,
    # whenever each was built; the later one's Unix anchor still means its clock time 0.
    wall = _Wall(100.0)
    first = RealClock(10.0, wall, unix_time_fn=lambda: UNIX_S)
    wall.t += 3.0
    second = RealClock(10.0, wall, wall0_s=first.wall0_s, unix_time_fn=lambda: UNIX_S + 3.0)
    assert second.now() == pytest.approx(first.now()) == pytest.approx(30.0)
    assert second.unix_time_at_zero_s == pytest.approx(first.unix_time_at_zero_s)


def test_paced_clock_is_held_back_by_the_station_and_never_jumps():
    sim, ack, wall = _Value(), _Value(), _Wall()
    emu = PacedClock(
        10.0,
        sim,
        ack,
        max_step_s=0.2,
        slack_s=0.5,
        catch_up_wall_s=0.0,
        time_fn=wall,
        unix_time_fn=lambda: UNIX_S,
    )
    station = PacedReader(10.0, sim, ack, unix_time_fn=lambda: UNIX_S)
    assert emu.unix_time_at_zero_s == station.unix_time_at_zero_s == UNIX_S
    wall.t += 0.01
    assert emu.advance() == pytest.approx(0.1)
    assert station.now() == emu.now() == pytest.approx(0.1)
    # No acknowledgement: at most slack_s ahead of the last one (0).
    for _ in range(100):
        wall.t += 0.01
        emu.advance()
    assert emu.now() == pytest.approx(0.5)
    assert emu.stats["capped_by_ack"] > 0
    # 10 simulated seconds of wall time passed, 0.4 became simulated time: 9.6 held back.
    assert emu.stats["held_by_ack_s"] == pytest.approx(9.6)
    # The station acknowledges; a 10 s wall stall of the emulator moves by max_step_s only.
    station.acknowledge(station.now())
    assert ack.value == pytest.approx(0.5)
    wall.t += 10.0
    assert emu.advance() == pytest.approx(0.7)
    assert emu.stats["capped_by_step"] == 1
    assert emu.stats["held_by_step_s"] == pytest.approx(100.0 - 0.2)
    # Wall time going backwards never moves simulated time back.
    wall.t -= 5.0
    assert emu.advance() == pytest.approx(0.7)
    assert emu.wall_delay_s(1.0) == station.wall_delay_s(1.0) == pytest.approx(0.1)


def test_paced_clock_catches_up_a_slow_iteration_but_not_a_stall():
    # 10x, 0.1 s steps every 10 ms of wall time; the station keeps acknowledging.
    sim, ack, wall = _Value(), _Value(), _Wall()
    emu = PacedClock(
        10.0, sim, ack, max_step_s=0.25, slack_s=0.25, catch_up_wall_s=0.1, time_fn=wall
    )
    assert emu.max_debt_s == pytest.approx(1.0)

    def iteration(wall_s: float) -> float:
        wall.t += wall_s
        t = emu.advance()
        ack.value = t  # a station that keeps up
        return t

    assert iteration(0.01) == pytest.approx(0.1)
    # One 40 ms iteration (0.4 s of simulated time): one step of 0.25 s now, the rest (0.15 s)
    # in the next iterations, each still at most max_step_s.
    assert iteration(0.04) == pytest.approx(0.35)
    assert iteration(0.001) == pytest.approx(0.51)
    assert iteration(0.01) == pytest.approx(0.61)
    assert emu.stats["held_by_step_s"] == 0.0
    # A 10 s stall: 100 s of simulated time; 0.25 now, 1.0 caught up later, the rest lost.
    assert iteration(10.0) == pytest.approx(0.86)
    assert emu.stats["capped_by_step"] == 1
    assert emu.stats["held_by_step_s"] == pytest.approx(100.0 - 0.25 - 1.0)
    for _ in range(4):
        iteration(0.0)
    assert emu.now() == pytest.approx(0.86 + 1.0)
    assert iteration(0.0) == pytest.approx(1.86)  # the debt is paid: no more steps
    # Time the station withholds is owed like a slow iteration's, under the same clamp: a
    # silent station caps the clock at ack + slack; once it acknowledges, what it held is
    # caught up, each iteration still within max_step_s and the new ack + slack.
    wall.t += 0.04
    assert emu.advance() == pytest.approx(1.86 + 0.25)
    ack_limit = ack.value + 0.25
    wall.t += 0.04
    assert emu.advance() == pytest.approx(ack_limit)
    assert emu.stats["capped_by_ack"] == 1
    ack.value = emu.now()
    assert iteration(0.0) == pytest.approx(ack_limit + 0.25)
    assert iteration(0.0) == pytest.approx(ack_limit + 0.5)
    assert iteration(0.0) == pytest.approx(ack_limit + 0.55)  # 0.8 s of wall x 10 in all
    assert iteration(0.0) == pytest.approx(ack_limit + 0.55)  # the debt is paid
    assert emu.stats["held_by_ack_s"] == 0.0
    # A station silent for 2 s of wall (20 s of simulated time): the clock waits at
    # ack + slack; beyond the clamp (1 s) what it withheld is lost and counted.
    t_ack = emu.now()
    for _ in range(50):
        wall.t += 0.04
        assert emu.advance() <= t_ack + 0.25 + 1e-12
    assert emu.now() == pytest.approx(t_ack + 0.25)
    assert emu.stats["held_by_ack_s"] == pytest.approx(20.0 - 0.25 - 1.0)
    ack.value = emu.now()
    for _ in range(4):
        iteration(0.0)
    assert emu.now() == pytest.approx(t_ack + 0.25 + 1.0)


def test_paced_reader_acknowledges_only_forward():
    sim, ack = _Value(3.0), _Value(2.0)
    station = PacedReader(2.0, sim, ack, unix_time_fn=lambda: UNIX_S)
    assert station.unix_time_at_zero_s == pytest.approx(UNIX_S - 1.5)
    station.acknowledge(1.0)
    assert ack.value == 2.0
    station.acknowledge(3.0)
    assert ack.value == 3.0
    with pytest.raises(ValueError):
        PacedReader(-1.0, sim, ack)

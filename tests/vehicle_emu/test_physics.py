import numpy as np
from hypothesis import given, settings, strategies as st

from vehicle_emu.physics import CTRL_VEL, Physics


def _airborne(n, rng):
    ph = Physics(np.zeros((n, 3)), max_speed_h_m_s=5.0, climb_rate_m_s=2.0, descent_rate_m_s=1.0)
    ph.armed[:] = True
    ph.pos_ned_m[:, 2] = -20.0
    ph.target_pos_ned_m = np.column_stack([rng.uniform(-200, 200, (n, 2)), rng.uniform(-60, -5, n)])
    return ph


def test_limits_hold_at_every_step_and_targets_are_reached(rng):
    ph = _airborne(200, rng)
    for _ in range(2400):  # 120 s at 20 Hz
        ph.step(0.05)
        v = ph.vel_ned_m_s
        assert np.all(np.hypot(v[:, 0], v[:, 1]) <= 5.0 + 1e-9)
        assert np.all(v[:, 2] >= -2.0 - 1e-9) and np.all(v[:, 2] <= 1.0 + 1e-9)
    assert np.allclose(ph.pos_ned_m, ph.target_pos_ned_m, atol=0.05)


@settings(max_examples=15)
@given(st.floats(0.01, 3.0))
def test_step_size_independence(dt):
    """Big virtual-clock jumps integrate like small ticks (sub-stepping)."""
    rng = np.random.default_rng(1)
    a, b = _airborne(5, rng), _airborne(5, np.random.default_rng(1))
    t = 0.0
    while t < 6.0:
        a.step(dt)
        t += dt
    for _ in range(int(round(t / 0.05))):
        b.step(0.05)
    b.step(t - 0.05 * int(round(t / 0.05)))
    assert np.allclose(a.pos_ned_m, b.pos_ned_m, atol=0.3)


def test_landed_vehicles_do_not_slide_and_dead_ones_freeze(rng):
    ph = Physics(np.zeros((3, 3)))
    ph.armed[:] = True
    ph.target_pos_ned_m[:] = [[50, 0, 0], [50, 0, -10], [0, 0, -10]]
    ph.alive[2] = False
    ph.step(2.0)
    assert np.allclose(ph.pos_ned_m[0], 0) and ph.landed[0]  # on the ground: no sliding
    assert ph.pos_ned_m[1, 2] < -1 and not ph.landed[1]  # climbs, then moves
    assert np.allclose(ph.pos_ned_m[2], 0)  # dead: frozen
    ph.ctrl[1] = CTRL_VEL
    ph.target_vel_ned_m_s[1] = [0, 0, 5.0]
    ph.step(30.0)
    assert ph.pos_ned_m[1, 2] == 0.0 and ph.landed[1]  # never below ground

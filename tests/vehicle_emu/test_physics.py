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


def _land_descent_reference(ph: Physics) -> np.ndarray:
    """The landing descent of each vehicle, one at a time (Physics.land_descent_m_s)."""
    out = np.empty(ph.n)
    for i in range(ph.n):
        h = ph.ground_down_m[i] - ph.pos_ned_m[i, 2]
        lo, hi = ph.land_crawl_alt_m[i], ph.land_slow_alt_m[i]
        fast = max(ph.land_fast_m_s[i], ph.land_speed_m_s[i])
        if h >= hi:
            out[i] = fast
        elif h <= lo:
            out[i] = ph.land_speed_m_s[i]
        else:
            out[i] = ph.land_speed_m_s[i] + (h - lo) / (hi - lo) * (fast - ph.land_speed_m_s[i])
    return out


def test_land_descent_matches_its_reference_and_the_firmware_profiles(rng):
    n = 300
    ph = Physics(np.zeros((n, 3)), descent_rate_m_s=1.5)
    ph.pos_ned_m[:, 2] = -rng.uniform(0.0, 60.0, n)
    ph.land_speed_m_s[:] = rng.uniform(0.3, 1.0, n)
    kind = rng.integers(0, 3, n)  # 0 the old default (inf), 1 ArduCopter step, 2 PX4 ramp
    ph.land_slow_alt_m[kind == 1] = ph.land_crawl_alt_m[kind == 1] = 10.0
    ph.land_slow_alt_m[kind == 2], ph.land_crawl_alt_m[kind == 2] = 10.0, 5.0
    v = ph.land_descent_m_s()
    assert np.allclose(v, _land_descent_reference(ph))
    h = -ph.pos_ned_m[:, 2]
    assert np.allclose(v[kind == 0], ph.land_speed_m_s[kind == 0])  # the whole way slow
    high = (kind > 0) & (h > 10.0)
    assert np.allclose(v[high], 1.5)
    low = (kind > 0) & (h < 5.0)
    assert np.allclose(v[low], ph.land_speed_m_s[low])


def test_an_ardupilot_landing_from_50_m_takes_the_two_stage_time():
    """WPNAV_SPEED_DN 1.5 m/s to LAND_ALT_LOW 10 m, then LAND_SPEED 0.5 m/s: about 47 s."""
    from vehicle_emu.physics import CTRL_LAND

    ph = Physics(np.zeros((1, 3)), descent_rate_m_s=1.5)
    ph.armed[:] = True
    ph.pos_ned_m[0, 2] = -50.0
    ph.target_pos_ned_m[0] = ph.pos_ned_m[0]
    ph.land_slow_alt_m[0] = ph.land_crawl_alt_m[0] = 10.0
    ph.command_land(0)
    assert ph.ctrl[0] == CTRL_LAND
    t = 0.0
    while not (ph.pos_ned_m[0, 2] >= -1e-6) and t < 200.0:
        ph.step(0.1)
        t += 0.1
    assert 45.0 <= t <= 50.0

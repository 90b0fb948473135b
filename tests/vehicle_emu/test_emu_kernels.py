"""The emulator's compiled kernels (vehicle_emu._kernels) against their references: the physics
and batteries, the geodetic update, the radio's hop counts and the telemetry framing."""

import numpy as np
import pytest

from planner.geometry import ned_to_geodetic as ned_to_geodetic_pymap3d
from vehicle_emu import _kernels
from vehicle_emu.battery import BatteryConfig
from vehicle_emu.physics import CTRL_LAND, CTRL_POS, CTRL_VEL, Physics
from vehicle_emu.radio import Radio, RadioConfig
from vehicle_emu.swarm import Swarm
from vehicle_emu.telemetry_batch import (
    BATCHED_TYPES,
    _layout,
    pack_frames,
    pack_frames_reference,
)

pytestmark = pytest.mark.skipif(not _kernels.NUMBA, reason="Numba is not installed")

ORIGIN = (47.397742, 8.545594, 488.0)


def _random_physics(n: int, seed: int, battery: bool) -> Physics:
    """Vehicles in every state the step distinguishes: each control kind, on the ground and in
    the air, disarmed (in the air too), dead, landing with and without the slow-down heights."""
    r = np.random.default_rng(seed)
    pos = np.column_stack([r.uniform(-300, 300, (n, 2)), np.zeros(n)])
    ph = Physics(pos, max_speed_h_m_s=8.0, origin_lla=ORIGIN)
    if battery:
        ph.enable_battery(BatteryConfig(capacity_mah=3000.0, cells=4, hover_endurance_s=900.0))
        ph.battery.consumed_mah[:] = r.uniform(0, 3100, n)  # some packs past empty
    ph.armed[:] = r.random(n) < 0.8
    ph.alive[:] = r.random(n) < 0.9
    ph.pos_ned_m[:, 2] = np.where(r.random(n) < 0.6, -r.uniform(0, 80, n), 0.0)
    ph.vel_ned_m_s = r.normal(0, 4, (n, 3))
    ph.yaw_rad = r.uniform(-np.pi, np.pi, n)
    ph.target_pos_ned_m = np.column_stack([r.uniform(-500, 500, (n, 2)), r.uniform(-90, 5, n)])
    ph.target_vel_ned_m_s = r.normal(0, 2, (n, 3)) * (r.random((n, 1)) < 0.4)
    ph.ctrl[:] = r.choice([CTRL_POS, CTRL_VEL, CTRL_LAND], n)
    ph.max_speed_h_m_s[:] = r.uniform(2, 15, n)
    ph.land_slow_alt_m[:] = np.where(r.random(n) < 0.5, 10.0, np.inf)
    ph.land_crawl_alt_m[:] = np.where(r.random(n) < 0.5, 1.0, np.inf)
    # the landing's fast stage has its own speed (ArduCopter LAND_SPEED_HIGH, PX4 MPC_Z_V_AUTO_DN)
    ph.land_fast_m_s[:] = r.uniform(0.5, 4.0, n)
    ph.landed[:] = ph.pos_ned_m[:, 2] >= 0
    return ph


@pytest.mark.parametrize("battery", [False, True])
def test_physics_step_matches_its_reference(battery):
    fast, slow = _random_physics(400, 3, battery), _random_physics(400, 3, battery)
    for k in range(300):
        dt = (0.1, 0.25, 0.03, 0.05, 1.7)[k % 5]
        fast.step(dt)
        slow.step_reference(dt)
    # Arithmetic and hypot: the same bits. The heading is NumPy's arctan2 against the C
    # library's: an ulp apart at most.
    for name in ("pos_ned_m", "vel_ned_m_s", "landed", "battery_frac"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
    np.testing.assert_allclose(fast.yaw_rad, slow.yaw_rad, rtol=0, atol=1e-14)
    assert 0 < fast.landed.sum() < fast.n and (np.abs(fast.vel_ned_m_s) > 0.1).any()
    if battery:
        for name in ("consumed_mah", "energy_wh", "current_a", "voltage_v"):
            a, b = getattr(fast.battery, name), getattr(slow.battery, name)
            np.testing.assert_array_equal(a, b, err_msg=name)
        assert (fast.battery.current_a > 0).any()


def test_physics_without_the_kernels_runs_the_reference(monkeypatch):
    a, b = _random_physics(30, 4, True), _random_physics(30, 4, True)
    monkeypatch.setattr(_kernels, "ENABLED", False)
    a.step(0.3)
    b.step_reference(0.3)
    np.testing.assert_array_equal(a.pos_ned_m, b.pos_ned_m)
    np.testing.assert_array_equal(a.yaw_rad, b.yaw_rad)


def test_geodetic_matches_pymap3d(rng):
    ned = np.vstack(
        [
            rng.uniform(-50e3, 50e3, (500, 3)),
            rng.uniform(-50, 50, (500, 3)),
            [[0.0, 0.0, 0.0], [0.0, 0.0, 6.4e6], [1e7, -3e6, 2e5]],  # the origin, far away
        ]
    )
    for origin in (ORIGIN, (-33.9, 151.2, 20.0), (89.9, 0.0, 0.0), (0.0, -179.9, -50.0)):
        lat, lon, alt = _kernels.ned_to_geodetic(ned, *origin)
        ref = ned_to_geodetic_pymap3d(ned, *origin)
        # The same formulas in the same order; sine, cosine and arc tangents from the C library
        # against NumPy's (an ulp or two); the height cancels two Earth radii (its ulp, 1e-9 m).
        np.testing.assert_allclose(lat, ref[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(lon, ref[1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(alt, ref[2], rtol=1e-12, atol=1e-6)
    one = _kernels.ned_to_geodetic(ned[0], *ORIGIN)  # one position: 0-d arrays, as pymap3d
    assert all(np.ndim(v) == 0 for v in one)
    np.testing.assert_allclose(one, ned_to_geodetic_pymap3d(ned[0], *ORIGIN), atol=1e-12)


@pytest.mark.parametrize("planar", [True, False])
@pytest.mark.parametrize("n", [1, 60, 700])
def test_hop_counts_match_the_breadth_first_search(planar, n):
    rng = np.random.default_rng(n + planar)
    cfg = RadioConfig(radio_range_m=90.0, base_range_m=150.0, latency_per_hop_s=0.01, planar=planar)
    radio = Radio(cfg, np.zeros(3), rng)
    spread = 25.0 * np.sqrt(n) + 50.0
    pos = np.column_stack([rng.uniform(-spread, spread, (n, 2)), rng.uniform(-60, 0, n)])
    alive = rng.random(n) < 0.9
    radio.update(pos, alive)
    p, base = (pos[:, :2], np.zeros(2)) if planar else (pos, np.zeros(3))
    fast = radio._hop_counts(p, base, 150.0)
    slow = radio._hop_counts_reference(p, base, 150.0)
    np.testing.assert_array_equal(fast, slow)
    assert fast.dtype == slow.dtype
    if n == 700:
        assert fast.max() >= 4 and radio.active.sum() > 300  # a real mesh: many hops


@pytest.mark.parametrize("msg_id", sorted(BATCHED_TYPES))
def test_frames_match_the_reference_framing(msg_id):
    """Random payload bytes (every truncation length, all-zero rows too) framed both ways."""
    cls, _ = BATCHED_TYPES[msg_id]
    lay = _layout(cls)
    rng = np.random.default_rng(msg_id)
    k = 40
    raw = rng.integers(0, 256, (k, lay.plen), dtype=np.uint8)
    cut = rng.integers(0, lay.plen + 1, k)
    raw[np.arange(lay.plen)[None, :] >= cut[:, None]] = 0
    rec = raw.copy().view(lay.dtype).reshape(k)
    fields = {name: rec[name] for name in lay.dtype.names}
    seq, sysid = rng.integers(0, 256, k), rng.integers(1, 255, k)
    assert pack_frames(cls, fields, seq, sysid, 1) == pack_frames_reference(
        cls, fields, seq, sysid, 1
    )


def test_swarm_behaves_the_same_without_the_kernels(monkeypatch):
    """Flights of a small swarm, compiled and by the references: the same datagrams (the
    headings of the two may differ by an ulp, never by a hundredth of a degree here)."""

    def fly(enabled: bool) -> list:
        monkeypatch.setattr(_kernels, "ENABLED", enabled)
        from vehicle_emu.telemetry import M_GLOBAL_POSITION_INT, M_POSITION_TARGET_GLOBAL_INT

        sw = Swarm(
            6,
            personality=["ardupilot", "px4"] * 3,
            radio=RadioConfig(radio_range_m=40.0, latency_per_hop_s=0.02),
            battery=BatteryConfig(),
            stream_rates_hz={M_GLOBAL_POSITION_INT: 5.0, M_POSITION_TARGET_GLOBAL_INT: 2.0},
            mux=True,
            gcs_addrs=[("gcs", 1)],
            tick_s=0.1,
        )
        ph = sw.physics
        out = []
        for k in range(200):
            t = 0.1 * k
            if k == 5:  # armed and flying outwards, without a station
                for c in sw.cores:
                    c._arm(t)
                ph.target_pos_ned_m[:] = [[30.0 * i, 5.0 * i, -20.0] for i in range(5)] + [
                    [0.0, 400.0, -20.0]  # out of the others' range
                ]
            sw.handle_timer(t)
            out.extend(sw.datagrams_to_send(t))
        assert ph.pos_ned_m[:, 1].max() > 90 and (ph.battery.consumed_mah > 0).all()
        assert 0 < sw.radio.active.sum() < 6  # some out of range: hop counts, delays, drops
        return out

    assert fly(True) == fly(False)

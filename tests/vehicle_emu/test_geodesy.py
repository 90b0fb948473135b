"""vehicle_emu/geodesy.py against its reference, planner.geometry.geodetic_to_ned_m (pymap3d):
the same bits, on random points near and far from random origins."""

import random

import numpy as np

from planner.geometry import geodetic_to_ned_m
from vehicle_emu.geodesy import NedOrigin, ned_origin


def test_ned_origin_matches_pymap3d_bit_for_bit():
    rng = random.Random(5)
    n = 0
    for _ in range(40):
        origin = (rng.uniform(-89, 89), rng.uniform(-180, 180), rng.uniform(-100, 3000))
        o = NedOrigin(*origin)
        for _ in range(100):
            span = rng.choice([0.001, 0.05, 2.0, 90.0])
            lat = max(-90.0, min(90.0, origin[0] + rng.uniform(-span, span)))
            lon = origin[1] + rng.uniform(-span, span)
            alt = rng.uniform(-500, 10000)
            if rng.random() < 0.1:  # the wire's degE7 grid, as the setpoints arrive
                lat, lon = round(lat * 1e7) / 1e7, round(lon * 1e7) / 1e7
            got = o.ned_m(lat, lon, alt)
            ref = geodetic_to_ned_m(lat, lon, alt, *origin)
            assert got.dtype == ref.dtype and got.shape == ref.shape == (3,)
            assert got.tobytes() == ref.tobytes(), (origin, lat, lon, alt, got, ref)
            n += 1
    assert n == 4000


def test_non_finite_inputs_follow_the_reference():
    o = NedOrigin(47.4, 8.5, 400.0)
    with np.errstate(all="ignore"):
        for p in ((np.nan, 8.5, 10.0), (47.4, np.inf, 10.0), (47.4, 8.5, -np.inf)):
            got, ref = o.ned_m(*p), geodetic_to_ned_m(*p, 47.4, 8.5, 400.0)
            assert np.array_equal(got, ref, equal_nan=True)


def test_ned_origin_is_shared():
    assert ned_origin(1.0, 2.0, 3.0) is ned_origin(1.0, 2.0, 3.0)

"""ArduPilot's terrain grid (mavedge.terrain_grid) against the firmware's definitions
(libraries/AP_Terrain AP_Terrain.h, TerrainUtil.cpp calculate_grid_info / grid_bitnum,
TerrainGCS.cpp handle_terrain_data)."""

import numpy as np
import pytest

from mavedge import terrain_grid as tg


def test_block_constants_are_the_firmwares():
    # AP_Terrain.h: 4x4 per message, 7x8 messages per block, 28x32 posts, blocks every 24x28.
    assert (tg.BLOCK_SIZE_X, tg.BLOCK_SIZE_Y) == (28, 32)
    assert (tg.BLOCK_SPACING_X, tg.BLOCK_SPACING_Y) == (24, 28)
    assert tg.BITS_PER_BLOCK == 56 and tg.FULL_MASK == (1 << 56) - 1


def test_every_post_of_a_block_has_one_bit_and_bits_round_trip():
    seen = {}
    for x in range(tg.BLOCK_SIZE_X):
        for y in range(tg.BLOCK_SIZE_Y):
            bit = tg.grid_bitnum(x, y)
            # TerrainUtil.cpp grid_bitnum: subgrid_y + TERRAIN_GRID_BLOCK_MUL_Y * subgrid_x
            assert bit == y // 4 + 8 * (x // 4)
            seen.setdefault(bit, []).append((x, y))
    assert sorted(seen) == list(range(56))
    for bit, posts in seen.items():
        x0, y0 = tg.bit_posts(bit)
        assert min(posts) == (x0, y0) and len(posts) == 16
        # handle_terrain_data: data[i*4+j] is post (idx_x+i, idx_y+j)
        offs = tg.post_offsets_m(bit, 10.0)
        assert offs[1].tolist() == [x0 * 10.0, (y0 + 1) * 10.0]
        assert offs[4].tolist() == [(x0 + 1) * 10.0, y0 * 10.0]
    with pytest.raises(ValueError):
        tg.grid_bitnum(28, 0)
    with pytest.raises(ValueError):
        tg.bit_posts(56)


@pytest.mark.parametrize("lat, lon", [(36.0544, -112.1401), (-35.363261, 149.165230), (0.5, 0.5)])
@pytest.mark.parametrize("spacing", [10, 30, 100])
def test_grid_info_puts_a_point_inside_its_block(lat, lon, spacing):
    rng = np.random.default_rng(1)
    for _ in range(50):
        la = int(round((lat + rng.uniform(-0.02, 0.02)) * 1e7))
        lo = int(round((lon + rng.uniform(-0.02, 0.02)) * 1e7))
        info = tg.grid_info(la, lo, spacing)
        assert 0 <= info.idx_x < tg.BLOCK_SPACING_X and 0 <= info.idx_y < tg.BLOCK_SPACING_Y
        assert 0 <= info.frac_x < 1 and 0 <= info.frac_y < 1
        # the corner is south-west of the point, the point (idx + frac) spacings north of it;
        # east, the firmware measures from the integer degree with the longitude scale at the
        # mid latitude of that longer span, so the corner's own east distance differs by up
        # to a few metres per hundredth of a degree: inside the block all the same
        n, e = tg.distance_ne_m(info.grid_lat_e7, info.grid_lon_e7, la, lo)
        assert n == pytest.approx((info.idx_x + info.frac_x) * spacing, abs=0.05)
        assert 0 <= e < (tg.BLOCK_SIZE_Y - 1) * spacing
        # the four posts around it are in the block (the one-sub-grid overlap)
        assert tg.grid_bitnum(info.idx_x + 1, info.idx_y + 1) < 56


def test_negative_coordinates_round_to_the_degree_south_west():
    # calculate_grid_info subtracts 9999999 from a negative value before the C division
    info = tg.grid_info(-353632610, 1491652300, 100)
    n, e = tg.distance_ne_m(-360000000, 1490000000, info.grid_lat_e7, info.grid_lon_e7)
    assert n >= 0 and e >= 0
    assert n == pytest.approx(round(n / 2400) * 2400, abs=0.05)  # a whole number of blocks


def test_offset_is_the_firmwares_integer_maths():
    # Location::offset_latlng: dlat truncated, longitude scale at lat + dlat / 2
    lat, lon = tg.offset_e7(360000000, -1120000000, 1000.0, 1000.0)
    dlat = int(1000.0 / tg.LOCATION_SCALING_FACTOR_M)
    assert lat == 360000000 + dlat
    scale = np.cos(np.radians((360000000 + dlat // 2) * 1e-7))
    assert lon == -1120000000 + int(1000.0 / tg.LOCATION_SCALING_FACTOR_M / scale)


def test_vectorised_post_locations_match_one_offset_per_post():
    lat0, lon0 = 360500000, -1121400000
    bits = [0, 7, 8, 30, 55]
    la, lo = tg.post_locations_e7(lat0, lon0, 30.0, bits)
    assert la.shape == (5, 16)
    for k, bit in enumerate(bits):
        for p, (n, e) in enumerate(tg.post_offsets_m(bit, 30.0).tolist()):
            a, b = tg.offset_e7(lat0, lon0, n, e)
            assert round(la[k, p] * 1e7) == a and round(lo[k, p] * 1e7) == b

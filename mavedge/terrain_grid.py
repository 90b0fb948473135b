"""ArduPilot's terrain grid: the block and bit maths of the MAVLink terrain protocol.

Both sides of the protocol use it: the station answers TERRAIN_REQUEST with TERRAIN_DATA
(:mod:`gcs.terrain`), the emulated ArduPilot asks and stores (:mod:`vehicle_emu.terrain`).
Everything follows ArduPilot's libraries/AP_Terrain (AP_Terrain.h constants,
TerrainUtil.cpp ``calculate_grid_info`` and ``grid_bitnum``, TerrainGCS.cpp
``handle_terrain_data``) and its flat-earth ``Location`` maths (libraries/AP_Common/Location.cpp
``offset`` and ``get_distance_NE``), in integer degE7 as the firmware keeps positions:

* posts (heights) lie ``grid_spacing`` metres apart, index x to the north, y to the east;
* a *block* is 28 x 32 posts (x, y) whose south-west post is at a multiple of 24 x 28 posts from
  the integer degree south-west of it (blocks overlap by 4 posts, so a height between posts is
  always inside one block);
* a block is sent as 56 4 x 4 sub-grids; sub-grid (bx, by) is ``bit = by + 8 * bx`` in the
  TERRAIN_REQUEST mask, and TERRAIN_DATA ``data[4 * i + j]`` is post (4 bx + i, 4 by + j).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "MAVLINK_SIZE",
    "BLOCK_MUL_X",
    "BLOCK_MUL_Y",
    "BLOCK_SIZE_X",
    "BLOCK_SIZE_Y",
    "BLOCK_SPACING_X",
    "BLOCK_SPACING_Y",
    "BITS_PER_BLOCK",
    "FULL_MASK",
    "LOCATION_SCALING_FACTOR_M",
    "GridInfo",
    "longitude_scale",
    "offset_e7",
    "distance_ne_m",
    "grid_info",
    "grid_bitnum",
    "bit_posts",
    "post_offsets_m",
    "post_locations_e7",
]

#: TERRAIN_GRID_MAVLINK_SIZE: a TERRAIN_DATA message carries 4 x 4 posts.
MAVLINK_SIZE = 4
#: TERRAIN_GRID_BLOCK_MUL_X / _Y: a block holds 7 x 8 of those sub-grids.
BLOCK_MUL_X = 7
BLOCK_MUL_Y = 8
#: TERRAIN_GRID_BLOCK_SIZE_X / _Y: 28 x 32 posts per block.
BLOCK_SIZE_X = MAVLINK_SIZE * BLOCK_MUL_X
BLOCK_SIZE_Y = MAVLINK_SIZE * BLOCK_MUL_Y
#: TERRAIN_GRID_BLOCK_SPACING_X / _Y: blocks start every 24 x 28 posts (one sub-grid overlap).
BLOCK_SPACING_X = (BLOCK_MUL_X - 1) * MAVLINK_SIZE
BLOCK_SPACING_Y = (BLOCK_MUL_Y - 1) * MAVLINK_SIZE
#: Sub-grids per block (the 56 bits of TERRAIN_REQUEST.mask).
BITS_PER_BLOCK = BLOCK_MUL_X * BLOCK_MUL_Y
FULL_MASK = (1 << BITS_PER_BLOCK) - 1
#: Metres per 1e-7 degree of latitude (AP_Math definitions.h LOCATION_SCALING_FACTOR).
LOCATION_SCALING_FACTOR_M = 0.011131884502145034


def longitude_scale(lat_e7: int) -> float:
    """cos(latitude), at least 0.01 (Location::longitude_scale)."""
    return min(1.0, max(0.01, math.cos(math.radians(lat_e7 * 1e-7))))


def offset_e7(lat_e7: int, lon_e7: int, north_m: float, east_m: float) -> tuple[int, int]:
    """The point ``north_m`` / ``east_m`` from (lat, lon), degE7 (Location.cpp
    ``offset_latlng``: the offsets truncated to integers, the longitude scale at the mid
    latitude)."""
    dlat = int(north_m / LOCATION_SCALING_FACTOR_M)  # int32_t: truncated toward zero
    dlng = int((east_m / LOCATION_SCALING_FACTOR_M) / longitude_scale(lat_e7 + int(dlat / 2)))
    return lat_e7 + dlat, lon_e7 + dlng


def distance_ne_m(lat1_e7: int, lon1_e7: int, lat2_e7: int, lon2_e7: int) -> tuple[float, float]:
    """North / east metres from point 1 to point 2 (Location::get_distance_NE: the longitude
    scale at the mid latitude)."""
    scale = longitude_scale(int((lat1_e7 + lat2_e7) / 2))
    return (
        (lat2_e7 - lat1_e7) * LOCATION_SCALING_FACTOR_M,
        (lon2_e7 - lon1_e7) * LOCATION_SCALING_FACTOR_M * scale,
    )


@dataclass(frozen=True)
class GridInfo:
    """Where a location falls in ArduPilot's grid (AP_Terrain ``grid_info``)."""

    grid_lat_e7: int
    """South-west post of the block, degE7 (TERRAIN_REQUEST.lat)."""
    grid_lon_e7: int
    idx_x: int
    """Post index north within the block (0 .. 23)."""
    idx_y: int
    """Post index east within the block (0 .. 27)."""
    frac_x: float
    """Fraction of a spacing north of post idx_x (0 .. 1)."""
    frac_y: float


def _degrees_floor(v_e7: int) -> int:
    # C integer division truncates toward zero: the firmware subtracts 9999999 from a negative
    # value first, so that it rounds down to the integer degree south / west of the point.
    v = v_e7 - 9_999_999 if v_e7 < 0 else v_e7
    return int(v / 10_000_000)


def grid_info(lat_e7: int, lon_e7: int, spacing_m: int) -> GridInfo:
    """The block and post of a location (AP_Terrain TerrainUtil.cpp ``calculate_grid_info``)."""
    ref_lat = _degrees_floor(lat_e7) * 10_000_000
    ref_lon = _degrees_floor(lon_e7) * 10_000_000
    off_n, off_e = distance_ne_m(ref_lat, ref_lon, lat_e7, lon_e7)
    idx_x, idx_y = int(off_n / spacing_m), int(off_e / spacing_m)
    gx, gy = idx_x // BLOCK_SPACING_X, idx_y // BLOCK_SPACING_Y
    glat, glon = offset_e7(
        ref_lat,
        ref_lon,
        gx * BLOCK_SPACING_X * float(spacing_m),
        gy * BLOCK_SPACING_Y * float(spacing_m),
    )
    return GridInfo(
        glat,
        glon,
        idx_x % BLOCK_SPACING_X,
        idx_y % BLOCK_SPACING_Y,
        (off_n - idx_x * spacing_m) / spacing_m,
        (off_e - idx_y * spacing_m) / spacing_m,
    )


def grid_bitnum(idx_x: int, idx_y: int) -> int:
    """The mask bit of the sub-grid holding post (idx_x, idx_y) (TerrainUtil.cpp ``grid_bitnum``)."""
    if not (0 <= idx_x < BLOCK_SIZE_X and 0 <= idx_y < BLOCK_SIZE_Y):
        raise ValueError(f"post ({idx_x}, {idx_y}) is outside a 28 x 32 block")
    return idx_y // MAVLINK_SIZE + BLOCK_MUL_Y * (idx_x // MAVLINK_SIZE)


def bit_posts(bit: int) -> tuple[int, int]:
    """(x, y) of the south-west post of sub-grid ``bit`` (TerrainGCS.cpp ``handle_terrain_data``:
    ``idx_x = bit / 8 * 4``, ``idx_y = bit % 8 * 4``)."""
    if not 0 <= bit < BITS_PER_BLOCK:
        raise ValueError(f"gridbit must be 0..{BITS_PER_BLOCK - 1}, got {bit}")
    return (bit // BLOCK_MUL_Y) * MAVLINK_SIZE, (bit % BLOCK_MUL_Y) * MAVLINK_SIZE


def post_offsets_m(bit: int, spacing_m: float) -> np.ndarray:
    """(16, 2) north / east metres from the block's south-west post to the posts of sub-grid
    ``bit``, in TERRAIN_DATA ``data`` order (``data[4 * i + j]``: i north, j east)."""
    x0, y0 = bit_posts(bit)
    i, j = np.divmod(np.arange(MAVLINK_SIZE * MAVLINK_SIZE), MAVLINK_SIZE)
    return np.column_stack([(x0 + i) * float(spacing_m), (y0 + j) * float(spacing_m)])


def post_locations_e7(
    grid_lat_e7: int, grid_lon_e7: int, spacing_m: float, bits: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """(B, 16) latitudes and longitudes (degrees) of the posts of the sub-grids ``bits`` of the
    block at (grid_lat, grid_lon), in ``data`` order: each post one ``Location::offset`` from
    the block's corner (vectorised :func:`offset_e7`, the same integer maths)."""
    offs = np.stack([post_offsets_m(b, spacing_m) for b in bits]).reshape(-1, 2)
    dlat = np.trunc(offs[:, 0] / LOCATION_SCALING_FACTOR_M)
    mid = grid_lat_e7 + np.trunc(dlat / 2)
    scale = np.clip(np.cos(np.radians(mid * 1e-7)), 0.01, 1.0)
    dlng = np.trunc((offs[:, 1] / LOCATION_SCALING_FACTOR_M) / scale)
    shape = (len(bits), MAVLINK_SIZE * MAVLINK_SIZE)
    return (
        ((grid_lat_e7 + dlat) * 1e-7).reshape(shape),
        ((grid_lon_e7 + dlng) * 1e-7).reshape(shape),
    )

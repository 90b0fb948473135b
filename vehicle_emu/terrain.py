"""The ground under the emulated vehicles, and ArduPilot's terrain database.

Two things, both for a mission with ``radio.model: terrain`` (docs/terrain.md §5):

* :class:`Ground`, the truth: the mission's DEM (:class:`planner.terrain.Terrain`, the map the
  planner also holds) and its radio (:class:`planner.terrain.TerrainRadio`: links need line of
  sight over it, the same model the in-process world uses). The swarm keeps each vehicle on or
  above it: a vehicle that descends onto the ground lands there; one carried into it while
  flying (the ground under it rises more than :data:`CRASH_DEPTH_M` above it within a tick, or
  it touches the ground moving faster than :data:`TOUCHDOWN_SPEED_H_M_S`) has crashed and is
  lost.
* :class:`TerrainDatabase`, what an emulated ArduPilot knows of the ground: the blocks of 28 x 32
  posts it asked its ground station for with TERRAIN_REQUEST and the 4 x 4 sub-grids that came
  back in TERRAIN_DATA (libraries/AP_Terrain/TerrainGCS.cpp ``send_request``,
  ``request_missing``, ``handle_terrain_data``, ``get_statistics``; grid maths in
  :mod:`mavedge.terrain_grid`). Heights between posts are bilinear from the four posts around
  (AP_Terrain.cpp ``height_amsl``). Sans-I/O: times are arguments.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from mavedge import terrain_grid as tg
from planner.terrain import TerrainRadio

__all__ = [
    "Ground",
    "TerrainDatabase",
    "CRASH_DEPTH_M",
    "TOUCHDOWN_SPEED_H_M_S",
    "REQUEST_PERIOD_S",
    "CACHE_BLOCKS",
]

#: A flying vehicle more than this below the ground after a tick has flown into it, metres.
CRASH_DEPTH_M = 0.5
#: A flying vehicle that touches the ground moving faster than this has flown into it (a copter
#: lands vertically), m/s.
TOUCHDOWN_SPEED_H_M_S = 1.0
#: A vehicle's radio antenna above the ground under it when it stands on the ground (on top of the
#: airframe, above the landing gear), metres. In flight the antenna is where the vehicle is; on a
#: pad, at 0 m, every link of more than a few metres would graze the ground inside the first
#: Fresnel zone and be cut (the link model has no diffraction loss, docs/terrain.md §5), and a
#: fleet waiting on the pads 60 m from the base's mast would not be heard at all.
VEHICLE_ANTENNA_AGL_M = 0.3
#: ArduPilot asks again at most every 2 s (TerrainGCS.cpp ``send_request``).
REQUEST_PERIOD_S = 2.0
#: Blocks held in memory (AP_Terrain.h TERRAIN_GRID_BLOCK_CACHE_SIZE).
CACHE_BLOCKS = 12
#: The neighbours ``send_request`` also fills: blocks 0.7 of a block away in each direction.
_NEIGHBOUR_FRACTION = 0.7


@dataclass(frozen=True)
class Ground:
    """The terrain truth of an emulated mission."""

    radio: TerrainRadio
    """The DEM and the link model over it."""
    origin_amsl_m: float
    """Altitude of the world frame's origin (the base; NED down = 0), metres AMSL."""
    base_antenna_agl_m: float = 1.5
    """The base's antenna above its ground, metres."""
    crew_antenna_agl_m: float = 1.5
    """A crew's radio above its ground, metres."""

    def height_amsl_m(self, ne_m: np.ndarray) -> np.ndarray:
        """(...) ground AMSL at (..., 2) north / east world metres."""
        return np.asarray(self.radio.terrain.height_m(ne_m))

    def ground_down_m(self, ne_m: np.ndarray) -> np.ndarray:
        """(...) the ground's DOWN coordinate in the world NED frame."""
        return self.origin_amsl_m - self.height_amsl_m(ne_m)

    def antenna_amsl_m(self, pos_ned_m: np.ndarray) -> np.ndarray:
        """(N,) each vehicle's antenna AMSL: where it is, and at least
        :data:`VEHICLE_ANTENNA_AGL_M` above the ground under it."""
        pos = np.asarray(pos_ned_m, dtype=float)
        floor = self.height_amsl_m(pos[:, :2]) + VEHICLE_ANTENNA_AGL_M
        return np.maximum(self.origin_amsl_m - pos[:, 2], floor)

    def base_antenna_amsl_m(self, base_ne_m: np.ndarray) -> float:
        return float(self.height_amsl_m(np.asarray(base_ne_m, float)[None, :2])[0]) + (
            self.base_antenna_agl_m
        )

    def active_mask(self, pos_ned_m: np.ndarray, alive: np.ndarray, base_ned_m) -> np.ndarray:
        """(N,) bool: alive vehicles joined to the base by links that clear the terrain."""
        pos = np.asarray(pos_ned_m, dtype=float)
        base = np.asarray(base_ned_m, dtype=float)
        return self.radio.active_mask(
            pos[:, :2],
            self.antenna_amsl_m(pos),
            alive,
            base[:2],
            self.base_antenna_amsl_m(base),
        )

    def link_pairs(self, pos_ned_m: np.ndarray) -> np.ndarray:
        """(K, 2) pairs i < j of the given vehicles whose link closes."""
        pos = np.asarray(pos_ned_m, dtype=float)
        return self.radio.link_pairs(pos[:, :2], self.antenna_amsl_m(pos))

    def links_to_base(self, pos_ned_m: np.ndarray, base_ned_m) -> np.ndarray:
        """(N,) bool: each vehicle's link to the base's antenna closes."""
        pos = np.asarray(pos_ned_m, dtype=float)
        base = np.asarray(base_ned_m, dtype=float)
        b3 = np.array([base[0], base[1], self.base_antenna_amsl_m(base)])
        a3 = np.column_stack([pos[:, :2], self.antenna_amsl_m(pos)])
        return self.radio.links_clear(a3, np.broadcast_to(b3, a3.shape))

    def tasks_connected(
        self, task_ne_m: np.ndarray, pos_ned_m: np.ndarray, active: np.ndarray
    ) -> np.ndarray:
        """(M,) bool: an active vehicle's link to each crew's radio closes."""
        task = np.asarray(task_ne_m, dtype=float).reshape(-1, 2)
        pos = np.asarray(pos_ned_m, dtype=float)
        return self.radio.tasks_connected(
            task,
            self.height_amsl_m(task) + self.crew_antenna_agl_m,
            pos[:, :2],
            self.antenna_amsl_m(pos),
            active,
        )


class _Block:
    __slots__ = ("lat_e7", "lon_e7", "bitmap", "height", "last_access_s")

    def __init__(self, lat_e7: int, lon_e7: int, now_s: float) -> None:
        self.lat_e7 = lat_e7
        self.lon_e7 = lon_e7
        self.bitmap = 0
        self.height = np.zeros((tg.BLOCK_SIZE_X, tg.BLOCK_SIZE_Y), dtype=np.int16)
        self.last_access_s = now_s


class TerrainDatabase:
    """An ArduPilot's terrain cache, filled over MAVLink (sans-I/O).

    Parameters
    ----------
    spacing_m : TERRAIN_SPACING, metres between posts (ArduPilot's default 100)
    """

    def __init__(self, spacing_m: int = 100) -> None:
        if not 1 <= int(spacing_m) <= 65535:
            raise ValueError(f"terrain spacing must be 1..65535 m, got {spacing_m}")
        self.spacing_m = int(spacing_m)
        self._blocks: OrderedDict[tuple[int, int], _Block] = OrderedDict()
        self._last_request_s = -np.inf

    # -- the cache -----------------------------------------------------------------------------

    def _block(self, lat_e7: int, lon_e7: int, now_s: float) -> _Block:
        """The block with this corner, made (evicting the least recently used) if absent
        (TerrainUtil.cpp ``find_grid_cache``)."""
        key = (lat_e7, lon_e7)
        b = self._blocks.get(key)
        if b is None:
            if len(self._blocks) >= CACHE_BLOCKS:
                self._blocks.popitem(last=False)
            b = self._blocks[key] = _Block(lat_e7, lon_e7, now_s)
        self._blocks.move_to_end(key)
        b.last_access_s = now_s
        return b

    def request(self, lat_e7: int, lon_e7: int, now_s: float) -> tuple[int, int, int, int] | None:
        """The TERRAIN_REQUEST to send now, as (lat_e7, lon_e7, spacing_m, mask), or None.

        As ``send_request``: not within :data:`REQUEST_PERIOD_S` of the last; the block under
        the vehicle first, then the 3 x 3 blocks 0.7 of a block around it."""
        if now_s - self._last_request_s < REQUEST_PERIOD_S:
            return None
        sp = self.spacing_m
        here = tg.grid_info(lat_e7, lon_e7, sp)
        candidates = [here]
        for x in (-1, 0, 1):
            for y in (-1, 0, 1):
                la, lo = tg.offset_e7(
                    lat_e7,
                    lon_e7,
                    x * tg.BLOCK_SIZE_X * _NEIGHBOUR_FRACTION * sp,
                    y * tg.BLOCK_SIZE_Y * _NEIGHBOUR_FRACTION * sp,
                )
                candidates.append(tg.grid_info(la, lo, sp))
        for info in candidates:
            b = self._block(info.grid_lat_e7, info.grid_lon_e7, now_s)
            missing = tg.FULL_MASK & ~b.bitmap
            if missing:
                self._last_request_s = now_s
                return b.lat_e7, b.lon_e7, sp, missing
        return None

    def on_data(self, lat_e7: int, lon_e7: int, spacing_m: int, gridbit: int, data) -> bool:
        """Store one TERRAIN_DATA; False (ignored) for a block not in the cache, another
        spacing or a bit out of range (``handle_terrain_data``)."""
        b = self._blocks.get((int(lat_e7), int(lon_e7)))
        if b is None or int(spacing_m) != self.spacing_m or not 0 <= gridbit < tg.BITS_PER_BLOCK:
            return False
        x0, y0 = tg.bit_posts(int(gridbit))
        n = tg.MAVLINK_SIZE
        b.height[x0 : x0 + n, y0 : y0 + n] = np.asarray(data, dtype=np.int16).reshape(n, n)
        b.bitmap |= 1 << int(gridbit)
        return True

    def statistics(self) -> tuple[int, int]:
        """(pending, loaded) sub-grids over the cached blocks (``get_statistics``)."""
        pending = loaded = 0
        for b in self._blocks.values():
            bits = bin(b.bitmap).count("1")
            pending += tg.BITS_PER_BLOCK - bits
            loaded += bits
        return pending, loaded

    def height_amsl_m(self, lat_e7: int, lon_e7: int) -> float | None:
        """Ground AMSL at a point, or None without the four posts around it (AP_Terrain.cpp
        ``height_amsl``: bilinear in the block's grid)."""
        info = tg.grid_info(int(lat_e7), int(lon_e7), self.spacing_m)
        b = self._blocks.get((info.grid_lat_e7, info.grid_lon_e7))
        if b is None:
            return None
        x, y = info.idx_x, info.idx_y
        for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
            if not b.bitmap >> tg.grid_bitnum(x + dx, y + dy) & 1:
                return None
        h = b.height.astype(float)
        fx, fy = info.frac_x, info.frac_y
        h00, h01, h10, h11 = h[x, y], h[x, y + 1], h[x + 1, y], h[x + 1, y + 1]
        return float(
            (1 - fx) * (1 - fy) * h00 + (1 - fx) * fy * h01 + fx * (1 - fy) * h10 + fx * fy * h11
        )

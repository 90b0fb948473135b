"""The station's side of ArduPilot's terrain protocol (TERRAIN_REQUEST, TERRAIN_DATA, TERRAIN_REPORT).

ArduPilot with ``TERRAIN_ENABLE=1`` and no terrain files asks its ground station for the ground
around it: every second or so (libraries/AP_Terrain/TerrainGCS.cpp ``send_request``, at most one
request per 2 s) it sends TERRAIN_REQUEST naming a block (the south-west corner of 28 x 32 posts,
``grid_spacing`` = ``TERRAIN_SPACING`` metres apart) and a 56-bit mask of the 4 x 4 sub-grids it
lacks. The ground station answers with one TERRAIN_DATA per bit: the 16 heights (int16 metres
AMSL) of that sub-grid, ``data[4 i + j]`` the post i spacings north and j east of the sub-grid's
corner (TerrainGCS.cpp ``handle_terrain_data``). MAVProxy answers this way from SRTM
(modules/mavproxy_terrain.py ``send_terrain_data_bit``: the sub-grid's corner offset from the
block's by 4 spacings per bit, then each post from it); QGroundControl's TerrainProtocolHandler and
Mission Planner serve the same protocol. The vehicle streams
TERRAIN_REPORT (``send_terrain_report``): ``pending`` sub-grids still wanted, ``loaded`` held.

Here the heights come from the mission's DEM (:class:`planner.terrain.Terrain`, in the mission's
local frame): :class:`TerrainServer` converts each post to that frame and samples it. Posts outside
the DEM get the height of its nearest edge (``Terrain.height_m``), as the mission has no better
knowledge there.

Sans-I/O (docs/design/architecture.md §2.1): :meth:`TerrainServer.answer` turns a request into the
messages to send; :class:`gcs.link.StationLink` calls it and records the reports.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from mavedge import mavlink
from mavedge import terrain_grid as tg
from planner.geometry import geodetic_to_ned_m
from planner.terrain import Terrain

__all__ = [
    "TerrainReport",
    "TerrainServer",
    "HeightFn",
    "mission_heights",
    "report_from_message",
]

#: Heights AMSL (metres) at arrays of latitudes and longitudes (degrees).
HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class TerrainReport:
    """One TERRAIN_REPORT (common.xml): what the vehicle holds of the terrain."""

    t_s: float
    lat_deg: float
    lon_deg: float
    spacing_m: int
    """0: the vehicle has no terrain at its position yet."""
    terrain_height_m: float
    """Ground AMSL under the vehicle, metres."""
    current_height_m: float
    """The vehicle's height above that ground, metres."""
    pending: int
    """4 x 4 sub-grids the vehicle still waits for."""
    loaded: int
    """4 x 4 sub-grids it holds."""


def mission_heights(
    terrain: Terrain, origin_lat_deg: float, origin_lon_deg: float, origin_alt_amsl_m: float
) -> HeightFn:
    """A :data:`HeightFn` over a mission's DEM, whose local frame is around the origin."""

    def heights(lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
        ned = geodetic_to_ned_m(
            lat_deg, lon_deg, origin_alt_amsl_m, origin_lat_deg, origin_lon_deg, origin_alt_amsl_m
        )
        return np.asarray(terrain.height_m(ned[..., :2]))

    return heights


class TerrainServer:
    """Answers TERRAIN_REQUEST from a height function (sans-I/O)."""

    def __init__(self, heights: HeightFn) -> None:
        self._heights = heights
        self.requests = 0
        self.data_sent = 0

    def heights_of_bits(
        self, lat_e7: int, lon_e7: int, spacing_m: int, bits: list[int]
    ) -> npt.NDArray[np.int16]:
        """(B, 16) int16 heights of the sub-grids ``bits`` of the block at (lat, lon), ``data``
        order, rounded to the nearest metre (clamped to int16)."""
        lat, lon = tg.post_locations_e7(lat_e7, lon_e7, float(spacing_m), bits)
        h = np.asarray(self._heights(lat.ravel(), lon.ravel()), dtype=float).reshape(lat.shape)
        return np.clip(np.rint(h), -32768, 32767).astype(np.int16)

    def answer(self, msg: Any) -> list[object]:
        """The TERRAIN_DATA messages for one TERRAIN_REQUEST, one per bit of its mask (in bit
        order). A request with spacing 0 or an empty mask gets none."""
        lat = int(msg.lat)
        lon = int(msg.lon)
        spacing = int(msg.grid_spacing)
        mask = int(msg.mask) & tg.FULL_MASK
        self.requests += 1
        bits = [b for b in range(tg.BITS_PER_BLOCK) if mask >> b & 1]
        if spacing <= 0 or not bits:
            return []
        data = self.heights_of_bits(lat, lon, spacing, bits).tolist()
        out: list[object] = [
            mavlink.MAVLink_terrain_data_message(lat, lon, spacing, b, d)
            for b, d in zip(bits, data)
        ]
        self.data_sent += len(out)
        return out


def report_from_message(msg: Any, now_s: float) -> TerrainReport:
    """A :class:`TerrainReport` from a decoded TERRAIN_REPORT."""
    return TerrainReport(
        now_s,
        msg.lat * 1e-7,
        msg.lon * 1e-7,
        int(msg.spacing),
        float(msg.terrain_height),
        float(msg.current_height),
        int(msg.pending),
        int(msg.loaded),
    )

"""A mission's ground as a :class:`planner.terrain.Terrain`: a synthetic scene, or a GeoTIFF read
with rasterio and resampled onto a grid in the mission's local north/east frame
(docs/terrain.md §4).

The local frame is the origin's tangent plane (``planner.geometry.ned_to_geodetic``): each post of
the local grid is converted to latitude and longitude, then into the DEM's CRS (projected or
geographic, whatever the file says), and the DEM is sampled there bilinearly
(``rasterio.warp.transform`` and the raster's inverse affine transform). Heights are taken as
metres above mean sea level, as USGS 3DEP and SRTM give them.
"""

from __future__ import annotations

import numpy as np

from gcs.control import FIRMWARE_DESCENT_RATE_M_S
from mission.format.schema import GeoTiffTerrain, Mission, SyntheticTerrain, TerrainSpec
from planner.geometry import ned_to_geodetic
from planner.methods import Planner
from planner.terrain import Canyon, Hill, Ridge, Terrain, TerrainRadio, synthetic_terrain
from planner.terrain_aware import TerrainAwarePlanner
from planner.terrain_heights import HeightRule

__all__ = [
    "build_terrain",
    "terrain_radio",
    "synthetic_from_spec",
    "terrain_from_geotiff",
    "descent_rate_m_s",
    "terrain_aware_planner",
]


def descent_rate_m_s(mission: Mission) -> float:
    """The speed at which the mission's vehicles descend, m/s: ``vehicles.descent_rate_m_s``,
    which the station writes to them (gcs.limits), or else the firmwares' default
    (:data:`gcs.control.FIRMWARE_DESCENT_RATE_M_S`). The one place the station's descent steps
    (``TerrainAltitude.descent_step_m``), the 3-D planner's :class:`HeightRule` and the in-process
    world's :class:`vehicle_emu.world.TerrainFlight` read it from (docs/terrain.md §3)."""
    return mission.vehicles.limits.descent_rate_m_s or FIRMWARE_DESCENT_RATE_M_S


def synthetic_from_spec(spec: SyntheticTerrain, plane_amsl_m: float) -> Terrain:
    """The scene of a ``terrain.synthetic`` section, on the plane at ``plane_amsl_m``."""
    feats: list[Ridge | Canyon | Hill] = []
    for r in spec.ridges:
        feats.append(Ridge([(p.north_m, p.east_m) for p in r.path], r.height_m, r.half_width_m))
    for c in spec.canyons:
        feats.append(
            Canyon(
                [(p.north_m, p.east_m) for p in c.path],
                c.depth_m,
                c.floor_half_width_m,
                c.rim_half_width_m,
            )
        )
    for h in spec.hills:
        feats.append(Hill((h.center.north_m, h.center.east_m), h.height_m, h.radius_m))
    return synthetic_terrain(feats, spec.half_width_m, spec.spacing_m, plane_amsl_m)


def terrain_from_geotiff(
    spec: GeoTiffTerrain, origin_lat_deg: float, origin_lon_deg: float, origin_alt_amsl_m: float
) -> Terrain:
    """Resample a GeoTIFF DEM onto the local grid of ``spec`` around the origin.

    Raises
    ------
    ValueError
        The file cannot be read, or the local grid reaches outside the DEM or onto its voids.
    """
    import rasterio
    from rasterio.warp import transform as warp_transform

    n = int(np.ceil(2 * spec.half_width_m / spec.spacing_m)) + 1
    axis = -spec.half_width_m + spec.spacing_m * np.arange(n)
    nn, ee = np.meshgrid(axis, axis, indexing="ij")
    ned = np.stack([nn.ravel(), ee.ravel(), np.zeros(nn.size)], axis=1)
    lat, lon, _ = ned_to_geodetic(ned, origin_lat_deg, origin_lon_deg, origin_alt_amsl_m)
    try:
        with rasterio.open(spec.path) as src:
            xs, ys = warp_transform("EPSG:4326", src.crs, lon.tolist(), lat.tolist())
            band = src.read(spec.band, masked=True).astype(float)
            inv = ~src.transform  # map -> pixel coordinates, pixel edges at integers
            x, y = np.asarray(xs), np.asarray(ys)
            cols = inv.a * x + inv.b * y + inv.c
            rows = inv.d * x + inv.e * y + inv.f
    except rasterio.errors.RasterioError as exc:
        raise ValueError(f"terrain.geotiff.path {spec.path}: {exc}") from None
    # Pixel centres sit at +0.5: bilinear between the four centres around each point.
    fr, fc = np.asarray(rows) - 0.5, np.asarray(cols) - 0.5
    h_px, w_px = band.shape
    if fr.min() < 0 or fc.min() < 0 or fr.max() > h_px - 1 or fc.max() > w_px - 1:
        raise ValueError(
            f"terrain.geotiff: the local grid (+-{spec.half_width_m:g} m around the origin) "
            f"reaches outside {spec.path}; use a larger tile or a smaller half_width_m"
        )
    r0 = np.minimum(np.floor(fr).astype(int), h_px - 2)
    c0 = np.minimum(np.floor(fc).astype(int), w_px - 2)
    t, u = fr - r0, fc - c0
    vals = np.ma.getdata(band)
    void = np.ma.getmaskarray(band)
    corners = [(r0, c0), (r0, c0 + 1), (r0 + 1, c0), (r0 + 1, c0 + 1)]
    if any(void[r, c].any() for r, c in corners):
        raise ValueError(f"terrain.geotiff: {spec.path} has voids (nodata) under the local grid")
    h = (1 - t) * ((1 - u) * vals[r0, c0] + u * vals[r0, c0 + 1]) + t * (
        (1 - u) * vals[r0 + 1, c0] + u * vals[r0 + 1, c0 + 1]
    )
    return Terrain(h.reshape(n, n), float(axis[0]), float(axis[0]), float(spec.spacing_m))


def build_terrain(mission: Mission) -> Terrain | None:
    """The mission's ground (None: a flat earth)."""
    spec: TerrainSpec | None = mission.terrain
    if spec is None:
        return None
    o = mission.origin
    if spec.synthetic is not None:
        return synthetic_from_spec(spec.synthetic, o.alt_amsl_m)
    assert spec.geotiff is not None  # one of synthetic or geotiff (validated)
    return terrain_from_geotiff(spec.geotiff, o.lat_deg, o.lon_deg, o.alt_amsl_m)


def terrain_radio(mission: Mission) -> TerrainRadio | None:
    """The radio of a ``radio.model: terrain`` mission: its ground and its ``radio.link`` budget
    (None: the disc radio)."""
    if mission.radio.model != "terrain":
        return None
    ground = build_terrain(mission)
    assert ground is not None  # radio.model terrain needs a terrain section (validated)
    return TerrainRadio(ground, mission.radio.terrain_link.link_budget())


def terrain_aware_planner(
    planner: Planner, mission: Mission, radio: TerrainRadio, max_step_m: float
) -> TerrainAwarePlanner:
    """``planner`` planning in 3-D over ``mission``'s terrain (docs/terrain.md §3):
    :class:`planner.terrain_aware.TerrainAwarePlanner` with a
    :class:`planner.terrain_heights.HeightRule` (altitudes per drone between the clearance and the
    ceiling, moves checked against the terrain radio, relay positions searched). The one place
    both the in-process world (``--terrain-aware on``) and the station (docs/terrain.md §6.2)
    build it. ``radio``: the mission's :func:`terrain_radio`; ``max_step_m``: the longest
    horizontal move in one step, metres."""
    spec = mission.terrain
    assert spec is not None  # radio.model terrain needs a terrain section (validated)
    link = mission.radio.terrain_link
    return TerrainAwarePlanner(
        planner,
        radio,
        spec.cruise_agl_m,
        link.crew_antenna_agl_m,
        link.base_antenna_agl_m,
        heights=HeightRule(
            clearance_m=spec.clearance_m,
            ceiling_agl_m=spec.ceiling_agl_m,
            max_climb_m=mission.vehicles.limits.climb_rate_m_s * mission.run.control_period_s,
            max_descent_m=descent_rate_m_s(mission) * mission.run.control_period_s,
            max_step_m=max_step_m,
        ),
    )

"""Terrain missions: GeoTIFF DEMs into the local frame, the canyon example, the CLI."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from mission.experiments.playback import run_inprocess
from mission.format.examples import example_path
from mission.format.load import MissionError, load_mission, loads_mission
from mission.format.schema import GeoTiffTerrain
from mission.format.terrain import build_terrain, terrain_from_geotiff
from planner.geometry import ned_to_geodetic

rasterio = pytest.importorskip("rasterio")
from rasterio.transform import from_origin  # noqa: E402
from rasterio.warp import transform as warp_transform  # noqa: E402

ORIGIN = (36.0544, -112.1401, 2100.0)


def _write_dem(path, crs: str, x0: float, y0: float, res: float, size: int, f) -> None:
    """A GeoTIFF whose pixel (r, c) centre at map coordinates (x, y) holds f(x, y)."""
    xs = x0 + res * (np.arange(size) + 0.5)
    ys = y0 - res * (np.arange(size) + 0.5)
    xx, yy = np.meshgrid(xs, ys)
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=size,
        width=size,
        count=1,
        dtype="float32",
        crs=crs,
        transform=from_origin(x0, y0, res, res),
    ) as dst:
        dst.write(f(xx, yy).astype("float32"), 1)


def _local_in(crs: str, ne_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lat, lon, _ = ned_to_geodetic(np.column_stack([ne_m, np.zeros(len(ne_m))]), *ORIGIN)
    xs, ys = warp_transform("EPSG:4326", crs, lon.tolist(), lat.tolist())
    return np.asarray(xs), np.asarray(ys)


def _plane(xx, yy):
    return 2000.0 + 0.05 * (xx - xx.mean()) - 0.02 * (yy - yy.mean())


@pytest.mark.parametrize("crs", ["EPSG:32612", "EPSG:4326"])  # UTM 12N (projected), geographic
def test_geotiff_is_resampled_into_the_local_frame(tmp_path, crs):
    cx, cy = _local_in(crs, np.zeros((1, 2)))
    res = 30.0 if crs != "EPSG:4326" else 1.0 / 3600.0  # 1 arc-second, as SRTM
    size = 200

    def f(x, y):  # a plane in map coordinates: bilinear resampling is exact on it
        return (
            2000.0
            + 0.05 * (x - cx[0]) / (1 if crs != "EPSG:4326" else 1e-5)
            - 0.02 * (y - cy[0]) / (1 if crs != "EPSG:4326" else 1e-5)
        )

    x0, y0 = cx[0] - res * size / 2, cy[0] + res * size / 2
    path = tmp_path / "dem.tif"
    _write_dem(path, crs, x0, y0, res, size, f)
    spec = GeoTiffTerrain(path=str(path), half_width_m=1000.0, spacing_m=50.0)
    t = terrain_from_geotiff(spec, *ORIGIN)
    pts = np.random.default_rng(0).uniform(-1000.0, 1000.0, (50, 2))
    xs, ys = _local_in(crs, pts)
    # The local grid is bilinear between posts 50 m apart: exact on a plane up to the frame's
    # slight curvature (metres of map against metres of tangent plane), well under 1 m here.
    np.testing.assert_allclose(t.height_m(pts), f(xs, ys), atol=0.5)
    assert t.height_m(np.zeros((1, 2)))[0] == pytest.approx(2000.0, abs=0.5)


def test_geotiff_too_small_for_the_grid_is_refused(tmp_path):
    cx, cy = _local_in("EPSG:32612", np.zeros((1, 2)))
    path = tmp_path / "small.tif"
    _write_dem(path, "EPSG:32612", cx[0] - 300, cy[0] + 300, 30.0, 20, _plane)
    with pytest.raises(ValueError, match="reaches outside"):
        terrain_from_geotiff(GeoTiffTerrain(path=str(path), half_width_m=1000.0), *ORIGIN)


def test_mission_with_a_geotiff_builds_its_terrain(tmp_path):
    cx, cy = _local_in("EPSG:32612", np.zeros((1, 2)))
    path = tmp_path / "dem.tif"
    _write_dem(path, "EPSG:32612", cx[0] - 3000, cy[0] + 3000, 30.0, 200, _plane)
    m = loads_mission(
        f"""
origin: {{lat_deg: {ORIGIN[0]}, lon_deg: {ORIGIN[1]}, alt_amsl_m: {ORIGIN[2]}}}
terrain:
  geotiff: {{path: {path}, half_width_m: 1500, spacing_m: 30}}
radio: {{model: terrain}}
"""
    )
    t = build_terrain(m)
    assert t is not None and t.height_amsl_m.shape == (101, 101)


def test_terrain_radio_needs_a_terrain_and_one_source():
    with pytest.raises(MissionError, match="needs a terrain"):
        loads_mission("radio: {model: terrain}")
    with pytest.raises(MissionError, match="exactly one of"):
        loads_mission("terrain: {}")
    with pytest.raises(MissionError, match="link budget"):
        loads_mission("radio: {link: {tx_power_dbm: -30, sensitivity_dbm: -10}}")


def test_canyon_has_a_canyon_a_ridge_and_crews_on_and_behind_them():
    m = load_mission(example_path("canyon"))
    t = build_terrain(m)
    assert t is not None and m.radio.model == "terrain"
    base = t.height_m(np.zeros((1, 2)))[0]
    assert base == pytest.approx(m.origin.alt_amsl_m)  # the base on the rim
    floor_crews = np.array([[450.0, 300.0], [-150.0, 375.0], [-450.0, 375.0]])
    np.testing.assert_allclose(t.height_m(floor_crews), base - 80.0)
    # The ridge crews are on its far flank: the crest stands between them and the base.
    ridge_crews = np.array([[250.0, 680.0], [-300.0, 690.0]])
    crests = np.array([[250.0, 618.3], [-300.0, 622.0]])
    assert (t.height_m(crests) > t.height_m(ridge_crews) + 15.0).all()


def test_canyon_one_altitude_is_legal_over_the_whole_fence():
    """Today's system (one altitude, ``vehicles.cruise_alt_m`` above the base) stays between the
    clearance and the ceiling over every post of the geofence (docs/terrain.md §3), and flies so:
    no drone-step above the ceiling, none below the clearance (seed 1)."""
    m = load_mission(example_path("canyon"))
    t = build_terrain(m)
    assert t is not None and m.terrain is not None
    w = m.geofence.half_width_m
    ax = np.arange(-w, w + 1.0, t.spacing_m / 2)
    nn, ee = np.meshgrid(ax, ax, indexing="ij")
    ground = t.height_m(np.column_stack([nn.ravel(), ee.ravel()]))
    alt = m.origin.alt_amsl_m + m.vehicles.limits.cruise_alt_m
    assert alt - ground.max() >= m.terrain.clearance_m
    assert alt - ground.min() <= m.terrain.ceiling_agl_m
    assert ground.max() - ground.min() > 90.0  # the relief is not flat: 100 m
    off = run_inprocess(m, 1, terrain_aware="off")
    assert off.terrain is not None
    assert off.terrain["crashes"] == 0 and off.terrain["min_clearance_m"] >= m.terrain.clearance_m
    assert off.terrain["flights_above_ceiling"] == 0 and off.terrain["drones_above_ceiling"] == 0
    assert off.terrain["max_agl_m"] <= m.terrain.ceiling_agl_m


def test_canyon_deep_breaks_the_ceiling_when_flown_blind():
    """The deep canyon (250 m): one altitude 80 m above the base is 330 m above its floor."""
    m = load_mission(example_path("canyon_deep"))
    t = build_terrain(m)
    assert t is not None and m.terrain is not None
    base = t.height_m(np.zeros((1, 2)))[0]
    assert base == pytest.approx(m.origin.alt_amsl_m)  # the base on the rim
    floor_crews = np.array([[450.0, 345.0], [0.0, 355.0], [-450.0, 360.0]])
    ridge_crews = np.array([[250.0, 795.0], [-300.0, 810.0]])
    assert (t.height_m(floor_crews) < base - 240).all()
    assert (t.height_m(ridge_crews) > base + 50).all()
    off = run_inprocess(m, 1, terrain_aware="off")
    assert off.terrain is not None and off.terrain["crashes"] == 0
    assert off.terrain["max_agl_m"] > 300.0 and off.terrain["drones_above_ceiling"] > 0


def test_canyon_camp_has_its_base_on_the_floor_below_a_bend():
    m = load_mission(example_path("canyon_camp"))
    t = build_terrain(m)
    assert t is not None and m.radio.model == "terrain"
    base = t.height_m(np.zeros((1, 2)))[0]
    assert base == pytest.approx(m.origin.alt_amsl_m - 200.0)  # on the floor
    inner_bend = np.array([[150.0, 300.0], [80.0, 300.0]])  # the plateau inside the bend
    assert (t.height_m(inner_bend) > base + 190).all()
    floor_crews = np.array([[300.0, 450.0], [290.0, 1000.0], [-500.0, 10.0]])
    assert (np.abs(t.height_m(floor_crews) - base) < 1.0).all()
    # One altitude above the base is under the ceiling over the floor, under the rims elsewhere.
    assert m.vehicles.limits.cruise_alt_m <= m.terrain.ceiling_agl_m  # type: ignore[union-attr]
    assert m.vehicles.limits.cruise_alt_m < 200.0


def test_planning_in_3d_flies_each_drone_at_its_own_height_within_the_band():
    """'on' over the canyon: heights chosen per drone between the clearance and the ceiling, no
    flight below the clearance, and no worse than terrain following at one height (seed 1)."""
    m = load_mission(example_path("canyon"))
    on = run_inprocess(m, 1, terrain_aware="on")
    alt = run_inprocess(m, 1, terrain_aware="altitude")
    assert on.terrain is not None and alt.terrain is not None
    assert on.terrain["crashes"] == 0 and on.terrain["flights_below_clearance"] == 0
    assert on.terrain["max_agl_m"] <= m.terrain.ceiling_agl_m + 1e-6  # type: ignore[union-attr]
    assert on.terrain["flights_above_ceiling"] == 0
    ground = build_terrain(m)
    assert ground is not None and on.record.alt_amsl_m is not None
    agl = on.record.alt_amsl_m - ground.height_m(on.record.pos_m)
    flying = on.record.alive[1:]
    flown = np.where(flying, agl[1:], np.nan)
    spread = np.nanmax(flown, axis=1) - np.nanmin(flown, axis=1)
    assert spread.max() > 50.0  # not one cruise height: some low, some high
    assert on.tu1 >= alt.tu1


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mission.cli", *args], capture_output=True, text=True, timeout=600
    )


def test_documented_canyon_commands_run():
    """The command lines of canyon.yaml and docs/terrain.md, as a user runs them."""
    out = _cli("check", "canyon")
    assert out.returncode == 0 and "OK: canyon" in out.stdout
    off = _cli("sim", "--mission", "canyon", "--terrain-aware", "off")
    assert off.returncode == 0, off.stderr
    assert "terrain-aware off: 0 crashes" in off.stdout and "TU1 = " in off.stdout
    assert "0 drones above the ceiling" in off.stdout
    on = _cli("sim", "--mission", "canyon", "--seeds", "3")
    assert on.returncode == 0, on.stderr
    assert on.stdout.count("terrain-aware on") == 3 and "TU2 = " in on.stdout
    off3 = _cli("sim", "--mission", "canyon", "--seeds", "3", "--terrain-aware", "off")
    assert off3.returncode == 0 and off3.stdout.count("terrain-aware off") == 3
    alt = _cli("sim", "--mission", "canyon", "--terrain-aware", "altitude")
    assert alt.returncode == 0 and "terrain-aware altitude" in alt.stdout


def test_terrain_aware_is_refused_without_a_terrain_mission():
    out = _cli("sim", "--mission", "wildfire", "--terrain-aware", "off")
    assert out.returncode == 2 and "disc radio" in out.stderr and "Traceback" not in out.stderr

"""The ground as the operator sees it: hillshade, the relief PNG, link status in the live frame,
the profile endpoint, and an in-process terrain run on the live page's replay."""

from __future__ import annotations

import asyncio
import dataclasses
import math

import numpy as np
import pytest

from mission.view.terrain import contour_step_m, hillshade, terrain_png
from planner.terrain import (
    LINK_BLOCKED,
    LINK_OK,
    LINK_OUT_OF_RANGE,
    LinkBudget,
    Ridge,
    Terrain,
    TerrainRadio,
    link_profile,
    synthetic_terrain,
)


def _plane(slope_deg: float, facing_deg: float, n: int = 9, spacing_m: float = 10.0) -> Terrain:
    """A plane falling at ``slope_deg`` towards azimuth ``facing_deg`` (from north, clockwise)."""
    axis = spacing_m * np.arange(n)
    nn, ee = np.meshgrid(axis, axis, indexing="ij")
    f = math.radians(facing_deg)
    h = -(ee * math.sin(f) + nn * math.cos(f)) * math.tan(math.radians(slope_deg))
    return Terrain(h + 500.0, 0.0, 0.0, spacing_m)


@pytest.mark.parametrize(
    ("slope_deg", "facing_deg", "sun_az", "sun_alt", "want"),
    [
        (0.0, 0.0, 315.0, 45.0, math.sin(math.radians(45.0))),  # flat: sin(altitude)
        (45.0, 315.0, 315.0, 45.0, 1.0),  # facing the sun, normal on the sun
        (45.0, 135.0, 315.0, 45.0, 0.0),  # facing away at 45 degrees: grazing light
        (60.0, 135.0, 315.0, 45.0, 0.0),  # steeper away: in its own shadow (clipped)
        # facing east at 30 degrees, sun from the north at 30 degrees: cos(angle) between
        # n = (sin30, 0, cos30) and s = (0, cos30, sin30) (east, north, up) = cos30 sin30
        (30.0, 90.0, 0.0, 30.0, math.cos(math.radians(30)) * math.sin(math.radians(30))),
        # facing south at 20 degrees, sun from the south at 50 degrees: cos(40 - 20)... the
        # normal leans 20 degrees south, the sun is 40 degrees from the zenith: cos(20)
        (20.0, 180.0, 180.0, 50.0, math.cos(math.radians(20.0))),
    ],
)
def test_hillshade_of_planes_is_the_cosine_to_the_sun(slope_deg, facing_deg, sun_az, sun_alt, want):
    t = _plane(slope_deg, facing_deg)
    hs = hillshade(t.height_amsl_m, t.spacing_m, sun_az, sun_alt)
    assert hs.shape == t.height_amsl_m.shape
    np.testing.assert_allclose(hs, want, atol=1e-9)


def test_hillshade_lights_the_sunny_flank_of_a_ridge():
    ridge = synthetic_terrain([Ridge([(0.0, -400.0), (0.0, 400.0)], 80.0, 150.0)], 400.0, 10.0)
    hs = hillshade(ridge.height_amsl_m, ridge.spacing_m)  # sun from the north-west
    r, c = ridge.height_amsl_m.shape
    north_flank = hs[r // 2 + 7, c // 2]  # 70 m north of the crest, facing north
    south_flank = hs[r // 2 - 7, c // 2]
    assert north_flank > math.sin(math.radians(45.0)) > south_flank


def test_contour_steps_are_round():
    assert contour_step_m(310.0) == 25.0
    assert contour_step_m(60.0) == 5.0
    assert contour_step_m(1000.0) == 100.0


def test_terrain_png_covers_the_grid_cells():
    t = synthetic_terrain([Ridge([(0.0, -400.0), (0.0, 400.0)], 80.0, 150.0)], 400.0, 20.0, 900.0)
    png, b = terrain_png(t, max_px=200)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert (b["n_min"], b["n_max"], b["e_min"], b["e_max"]) == (-410.0, 410.0, -410.0, 410.0)
    assert b["h_min_m"] == pytest.approx(900.0) and b["h_max_m"] == pytest.approx(980.0)
    from PIL import Image
    import io

    img = Image.open(io.BytesIO(png))
    assert img.size == (200, 200)


def test_terrain_png_is_north_up_east_right():
    from PIL import Image
    import io

    from planner.terrain import Hill

    hill = synthetic_terrain([Hill((250.0, 250.0), 120.0, 40.0)], 400.0, 10.0, 500.0)
    png, _ = terrain_png(hill, max_px=200)
    a = np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=float)
    quad = {  # image rows go down (south), columns right (east)
        "ne": a[:100, 100:],
        "nw": a[:100, :100],
        "se": a[100:, 100:],
        "sw": a[100:, :100],
    }
    spread = {k: float(v.std()) for k, v in quad.items()}
    # the hill, its shading and its contours are in the north-east quarter only
    assert spread["ne"] > 10.0
    assert max(spread["nw"], spread["se"], spread["sw"]) < 0.1 * spread["ne"]


# ------------------------------------------------------------------ the live frame's links


def _view():
    from mission.view.live.terrain import TerrainView

    wall = synthetic_terrain([Ridge([(0.0, -600.0), (0.0, 600.0)], 60.0, 10.0)], 600.0, 5.0, 1000.0)
    return TerrainView(TerrainRadio(wall, LinkBudget(fade_margin_db=20.0)), 1000.0, 1.5, 3.0)


def test_frame_links_classify_with_the_planner_model():
    view = _view()
    rng = view.radio.budget.max_range_m  # about 498 m
    # 0: south of the wall, 1: north of it (the wall cuts 0-1 at 20 m up), 2: far east of 0 on
    # its side but beyond the budget's range slant, 3: high above 1 (sees over the wall to 0).
    ne = np.array([[-100.0, 0.0], [100.0, 0.0], [-100.0, rng - 5.0], [100.0, 10.0]])
    amsl = np.array([1020.0, 1020.0, 1500.0, 1200.0])
    heard = np.ones(4, bool)
    crews = np.array([[-150.0, 30.0], [150.0, -30.0], [np.nan, np.nan]])
    out = view.frame_links(ne, amsl, heard, crews, radio_range_m=250.0, base_range_m=250.0)
    pairs = np.asarray(out["vv"]).reshape(-1, 2)
    got = {tuple(sorted(p)): s for p, s in zip(pairs.tolist(), out["vv_status"])}
    assert got[(0, 1)] == LINK_BLOCKED
    assert got[(0, 2)] == LINK_OUT_OF_RANGE  # slant sqrt(493^2 + 480^2) > 498
    assert got[(0, 3)] == LINK_OK
    # every status is what the radio says for the same antennas
    p3 = np.column_stack([ne, amsl])
    want = view.radio.link_status(p3[pairs[:, 0]], p3[pairs[:, 1]])
    assert out["vv_status"] == want.tolist()
    # crews: antenna 1.5 m above the ground; crew 0 sees drone 0 on its side, crew 1 drone 1
    assert out["crew_amsl"][:2].tolist() == pytest.approx([1001.5, 1001.5])
    assert out["connected"].tolist() == [True, True, False]
    vc = np.asarray(out["vc"]).reshape(-1, 2)
    st = dict(zip(map(tuple, vc.tolist()), out["vc_status"]))
    assert st[(1, 0)] == LINK_BLOCKED and st[(0, 0)] == LINK_OK
    # the base (antenna 3 m up at the origin, on the wall's crest 60 m up): in the frame too
    assert out["base_amsl"] == pytest.approx(1063.0)
    assert sorted(out["vb"]) == [0, 1, 3]  # 2 is beyond the base's reach horizontally


def test_profile_endpoint_is_the_planner_profile():
    from aiohttp.test_utils import TestClient, TestServer

    from mission.view.live.server import LiveServer

    view = _view()

    class Src:
        terrain = view

        def meta(self):
            return {"mode": "replay"}

        def frame(self, index=None, truth=False):
            return {}

    class Disc(Src):
        terrain = None

    async def go():
        async with TestClient(TestServer(LiveServer(Src()).app)) as c:
            meta = await (await c.get("/api/meta")).json()
            assert meta["terrain"]["url"] == "/api/terrain.png"
            assert meta["terrain"]["status_names"][LINK_BLOCKED] == "blocked by terrain"
            r = await c.get("/api/terrain.png")
            assert r.status == 200 and r.content_type == "image/png"
            r = await c.get("/api/profile?a=-100,0,1020&b=100,0,1020")
            prof = await r.json()
            bad = await c.get("/api/profile?a=-100,0&b=100,0,1020")
            assert bad.status == 400 and "N,E,H" in (await bad.json())["error"]
        async with TestClient(TestServer(LiveServer(Disc()).app)) as c:
            assert (await (await c.get("/api/meta")).json())["terrain"] is None
            assert (await c.get("/api/profile?a=0,0,0&b=1,1,1")).status == 404
        return prof

    prof = asyncio.run(go())
    want = link_profile(view.radio.terrain, view.radio.budget, (-100, 0, 1020), (100, 0, 1020))
    assert prof["status"] == want.status == LINK_BLOCKED
    assert prof["status_name"] == "blocked by terrain"
    assert prof["d"] == pytest.approx(want.distance_m.tolist(), abs=0.05)
    assert prof["margin"][prof["worst"]] == pytest.approx(want.margin_m[want.worst], abs=0.01)
    assert prof["d"][prof["worst"]] == pytest.approx(100.0)  # the wall


# ------------------------------------------------------------------ an in-process terrain run


@pytest.fixture(scope="module")
def canyon_run(tmp_path_factory):
    """A short run of the canyon mission (12 drones, 40 s), recorded as sim --out writes it."""
    from mission.experiments.playback import run_inprocess, write_run_dir
    from mission.format.examples import example_path
    from mission.format.load import load_mission

    m = load_mission(example_path("canyon"))
    m = dataclasses.replace(
        m,
        vehicles=dataclasses.replace(
            m.vehicles, emulated=dataclasses.replace(m.vehicles.emulated, count=12)
        ),
        run=dataclasses.replace(m.run, duration_s=40.0),
    )
    out = tmp_path_factory.mktemp("canyon")
    write_run_dir(m, run_inprocess(m, 1), out)
    return out


def test_sim_run_frames_carry_terrain_status(canyon_run):
    from mission.view.live.replay_sim import SimReplaySource, is_sim_run

    assert is_sim_run(canyon_run)
    src = SimReplaySource(canyon_run)
    meta = src.meta()
    assert meta["mode"] == "replay" and len(meta["replay"]["t"]) == 41
    f = src.frame(40)
    links = f["links"]
    assert len(links["vv_status"]) == len(links["vv"]) // 2 > 0
    # Recomputed with the radio for the frame's antennas: the same statuses.
    z = np.load(canyon_run / "truth.npz")
    pos = z["pos_ne_m"][40]
    alt = z["alt_amsl_m"][40]
    p3 = np.column_stack([pos, alt])
    pairs = np.asarray(links["vv"]).reshape(-1, 2)
    want = src.terrain.radio.link_status(p3[pairs[:, 0]], p3[pairs[:, 1]])
    assert links["vv_status"] == want.tolist()
    # a drone alive is heard at its height; one attrited is lost, with no antenna
    for x, a, alive in zip(f["v"]["amsl"], alt, z["alive"][40]):
        assert (x is None) if not alive else x == pytest.approx(a, abs=0.05)
    assert not all(z["alive"][40]) or len(f["v"]["amsl"]) == 12
    # a crew the truth saw connected is connected on the page too (same radio, same drones)
    truth_conn = z["task_connected"][40]
    page_conn = np.asarray(f["crews"]["connected"])
    assert (page_conn | ~truth_conn).all()


def test_replay_figures_of_a_terrain_run(canyon_run, tmp_path):
    from PIL import Image

    from mission.view.replay import load_run, replay

    written = replay(canyon_run, tmp_path, "none")
    assert sorted(p.name for p in written) == [
        "fig2_timeseries.png",
        "frames.png",
        "link_profiles.png",
    ]
    assert Image.open(tmp_path / "link_profiles.png").size[1] > 300
    run = load_run(canyon_run)
    assert run.alt_amsl_m is not None and run.alt_amsl_m.shape == run.alive.shape


# ------------------------------------------------------------------ the page, in Chromium

# The page tests' headless Chromium (skipped, loudly, without chromium / chromedriver).
from browser import _wait  # noqa: E402 - the ``browser`` fixture: tests/conftest.py

# A link whose midpoint is unambiguous on screen: no other drawn link within 12 px, no vehicle
# within 14 px, on the map itself (not under a control). Blocked links first.
_FIND_LINK_JS = """
const f = window.phiremanFrame, M = window.phiremanMap.map, L = f.links, V = f.v;
const px = (n, e) => M.latLngToContainerPoint(window.L.latLng(n, e));
const segs = [];
const add = (kind, k, st, a, b) => segs.push({kind, k, st, a, b, pa: px(a[0], a[1]), pb: px(b[0], b[1])});
for (let k = 0; k < L.vv.length; k += 2) { const i = L.vv[k], j = L.vv[k + 1];
  if (V.n[i] !== null && V.n[j] !== null) add("vv", k / 2, L.vv_status[k / 2], [V.n[i], V.e[i], V.amsl[i]], [V.n[j], V.e[j], V.amsl[j]]); }
L.vb.forEach((i, j) => V.n[i] !== null && add("vb", j, L.vb_status[j], [V.n[i], V.e[i], V.amsl[i]], [0, 0, L.base_amsl]));
const dist = (p, a, b) => { const dx = b.x - a.x, dy = b.y - a.y, l2 = dx * dx + dy * dy;
  const t = l2 ? Math.max(0, Math.min(1, ((p.x - a.x) * dx + (p.y - a.y) * dy) / l2)) : 0;
  return Math.hypot(p.x - a.x - t * dx, p.y - a.y - t * dy); };
const mapRect = document.getElementById("map").getBoundingClientRect();
const order = segs.slice().sort((x, y) => (y.st === 1) - (x.st === 1));
for (const s of order) {
  const m = {x: (s.pa.x + s.pb.x) / 2, y: (s.pa.y + s.pb.y) / 2};
  if (segs.some((o) => o !== s && dist(m, o.pa, o.pb) < 12)) continue;
  if (V.n.some((n, i) => n !== null && px(n, V.e[i]).distanceTo(m) < 14)) continue;
  if (px(0, 0).distanceTo(m) < 14) continue;
  const el = document.elementFromPoint(mapRect.left + m.x, mapRect.top + m.y);
  if (!el || el.closest(".leaflet-control") || !el.closest("#map")) continue;
  return {x: m.x, y: m.y, w: mapRect.width, h: mapRect.height, st: s.st, a: s.a, b: s.b};
}
return null;"""


# Two vehicles far from any other vehicle on screen, on the map (not under a control).
_FIND_VEHICLES_JS = """
const f = window.phiremanFrame, M = window.phiremanMap.map, V = f.v;
const mapRect = document.getElementById("map").getBoundingClientRect(), out = [];
const pts = V.n.map((n, i) => n === null || V.amsl[i] === null ? null : M.latLngToContainerPoint(window.L.latLng(n, V.e[i])));
for (let i = 0; i < pts.length && out.length < 2; i++) {
  const p = pts[i];
  if (!p || pts.some((q, j) => q && j !== i && q.distanceTo(p) < 20)) continue;
  const el = document.elementFromPoint(mapRect.left + p.x, mapRect.top + p.y);
  if (!el || el.closest(".leaflet-control") || !el.closest("#map")) continue;
  out.push({x: p.x, y: p.y, label: V.label[i], p: [Math.round(V.n[i] * 10) / 10, Math.round(V.e[i] * 10) / 10, Math.round(V.amsl[i] * 10) / 10]});
}
return out.length === 2 ? {v: out, w: mapRect.width, h: mapRect.height} : null;"""


@pytest.mark.udp
def test_page_draws_the_relief_and_opens_a_link_profile(browser, canyon_run):  # noqa: F811
    from selenium.webdriver.common.action_chains import ActionChains

    from mission.view.live.replay_sim import SimReplaySource
    from mission.view.live.server import serve_in_thread

    src = SimReplaySource(canyon_run)
    drv = browser
    with serve_in_thread(src) as url:
        drv.get(url)
        # The relief: an image overlay that loaded (decoded, not a broken image).
        size = _wait(
            lambda: drv.execute_script(
                "const i = document.querySelector('img.terrain-relief');"
                "return i && i.complete && i.naturalWidth ? [i.naturalWidth, i.naturalHeight] : null"
            ),
            60,
            "the terrain relief image",
        )
        assert size[0] > 500 and size[1] > 500
        assert "blocked by terrain" in drv.find_element("css selector", ".terrain-legend").text
        last = len(src.meta()["replay"]["t"]) - 1
        drv.execute_script(
            "const s = document.getElementById('slider'); s.value = arguments[0];"
            "s.dispatchEvent(new Event('input'));",
            last,
        )
        _wait(
            lambda: drv.execute_script("return window.phiremanFrame.t_mission_s") == 40.0,
            30,
            "the last frame",
        )
        # The statuses the page holds are the server's; the blocked ones are drawn apart.
        frame = src.frame(last)
        page = drv.execute_script("return window.phiremanFrame.links")
        assert page["vv_status"] == frame["links"]["vv_status"]
        every = page["vv_status"] + page["vc_status"] + page["vb_status"]
        n_blocked = sum(s == LINK_BLOCKED for s in every)
        drawn = drv.execute_script(
            "return window.phiremanTerrainLayers.blocked.getLatLngs().length"
        )
        assert drawn == n_blocked
        # A real click on a link opens its profile, with the frame's verdict.
        hit = _wait(lambda: drv.execute_script(_FIND_LINK_JS), 30, "a link to click")
        m = drv.find_element("id", "map")
        ActionChains(drv).move_to_element_with_offset(
            m, int(hit["x"] - hit["w"] / 2), int(hit["y"] - hit["h"] / 2)
        ).click().perform()
        names = ["ok", "blocked by terrain", "out of range"]
        prof = _wait(
            lambda: drv.execute_script(
                "const b = document.getElementById('terrain-profile');"
                "return b && !b.hidden && window.phiremanProfile ? window.phiremanProfile : null"
            ),
            30,
            "the link profile panel",
        )
        assert prof["status_name"] == names[hit["st"]]
        np.testing.assert_allclose(
            sorted([prof["a"], prof["b"]]), sorted([hit["a"], hit["b"]]), atol=0.11
        )
        verdict = drv.find_element("id", "terrain-verdict").text
        assert verdict.startswith(names[hit["st"]].upper())
        assert drv.find_element("css selector", "#terrain-svg path")  # the drawing
        # Shift-click two vehicles: the profile between them.
        two = drv.execute_script(_FIND_VEHICLES_JS)
        assert two is not None, "no two vehicles apart on screen"
        from selenium.webdriver.common.keys import Keys

        chain = ActionChains(drv).key_down(Keys.SHIFT)
        for v in two["v"]:
            chain = chain.move_to_element_with_offset(
                m, int(v["x"] - two["w"] / 2), int(v["y"] - two["h"] / 2)
            ).click()
        chain.key_up(Keys.SHIFT).perform()
        want = sorted(v["p"] for v in two["v"])
        prof = _wait(
            lambda: (lambda p: p if sorted([p["a"], p["b"]]) == want else None)(
                drv.execute_script("return window.phiremanProfile")
            ),
            30,
            "the profile between the two vehicles",
        )
        head = drv.find_element("css selector", "#terrain-profile .head").text
        assert all(f"vehicle {v['label']}" in head for v in two["v"]), head


def test_export_of_an_in_process_run_is_refused_in_one_line(canyon_run):
    from user_cli import PHIREMAN, run

    res = run([PHIREMAN, "replay", str(canyon_run), "--export", "geojson"], canyon_run, 120)
    assert res.returncode == 2
    assert "--export reads a 'phireman fly' run" in res.stderr
    assert "Traceback" not in res.stderr

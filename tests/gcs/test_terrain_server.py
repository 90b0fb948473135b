"""The station's side of ArduPilot's terrain protocol (gcs/terrain.py) and terrain-following
setpoints (gcs/control.py terrain_targets): in memory, explicit time."""

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.control import TerrainAltitude, terrain_targets
from gcs.link import StationConfig, StationLink
from gcs.terrain import TerrainServer, mission_heights
from mavedge import terrain_grid as tg
from planner.geometry import geodetic_to_ned_m
from planner.terrain import Canyon, Hill, path_clearance_m, synthetic_terrain

from gcs_fakes import FakeAutopilot

ORIGIN = (36.0544, -112.1401, 2100.0)
DEM = synthetic_terrain(
    [Hill((300.0, -200.0), 150.0, 120.0), Canyon([(-1500, 350), (1500, 380)], 250.0, 40.0, 150.0)],
    1500.0,
    10.0,
    ORIGIN[2],
)
VEH = ("veh", 1)


def _request(lat_e7, lon_e7, spacing, mask):
    return mav.MAVLink_terrain_request_message(lat_e7, lon_e7, spacing, mask)


def test_answer_has_one_data_per_bit_with_the_dems_heights_at_the_posts():
    server = TerrainServer(mission_heights(DEM, *ORIGIN))
    info = tg.grid_info(round(ORIGIN[0] * 1e7), round(ORIGIN[1] * 1e7), 30)
    mask = (1 << 0) | (1 << 9) | (1 << 55)
    out = server.answer(_request(info.grid_lat_e7, info.grid_lon_e7, 30, mask))
    assert [m.gridbit for m in out] == [0, 9, 55]
    for m in out:
        assert (m.lat, m.lon, m.grid_spacing) == (info.grid_lat_e7, info.grid_lon_e7, 30)
        lat, lon = tg.post_locations_e7(m.lat, m.lon, 30.0, [m.gridbit])
        ned = geodetic_to_ned_m(lat[0], lon[0], ORIGIN[2], *ORIGIN)
        want = DEM.height_m(ned[:, :2])
        assert np.abs(np.asarray(m.data) - want).max() <= 0.5  # rounded to whole metres
    assert server.answer(_request(info.grid_lat_e7, info.grid_lon_e7, 30, 0)) == []
    assert server.answer(_request(info.grid_lat_e7, info.grid_lon_e7, 0, 1)) == []


def test_station_link_answers_requests_and_keeps_reports():
    link = StationLink(StationConfig(), now_s=0.0)
    ap = FakeAutopilot(sysid=3)
    link.receive_datagram(ap.heartbeat(), VEH, 0.0)
    link.datagrams_to_send(0.0)
    lat, lon = round(ORIGIN[0] * 1e7), round(ORIGIN[1] * 1e7)
    # No map: the request goes unanswered.
    link.receive_datagram(ap.pack(_request(lat, lon, 30, 0b111)), VEH, 0.1)
    assert not [d for d, a in link.datagrams_to_send(0.1) if b"" != d and a == VEH and _is_data(d)]
    link.terrain_server = TerrainServer(mission_heights(DEM, *ORIGIN))
    link.receive_datagram(ap.pack(_request(lat, lon, 30, 0b111)), VEH, 0.2)
    sent = [d for d, a in link.datagrams_to_send(0.2) if a == VEH and _is_data(d)]
    assert len(sent) == 3
    rep = mav.MAVLink_terrain_report_message(lat, lon, 30, 2101.5, 99.0, 5, 51)
    link.receive_datagram(ap.pack(rep), VEH, 0.3)
    r = link.terrain_reports[3]
    assert (r.spacing_m, r.pending, r.loaded, r.t_s) == (30, 5, 51, 0.3)
    assert r.terrain_height_m == pytest.approx(2101.5)


def _is_data(frame: bytes) -> bool:
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    msgs = parser.parse_buffer(frame) or []
    return any(m.get_type() == "TERRAIN_DATA" for m in msgs)


def test_terrain_targets_hold_the_height_above_the_ground_under_the_target():
    ta = TerrainAltitude(DEM, ORIGIN[2], clearance_m=15.0, ceiling_agl_m=120.0)
    pos = np.array([[-400.0, -400.0, -100.0]])  # over the plane, 100 m above it
    tgt = np.array([[-395.0, -400.0]])
    out = terrain_targets(pos, tgt, np.array([100.0]), ta)
    assert out[0, :2].tolist() == tgt[0].tolist()
    assert ORIGIN[2] - out[0, 2] == pytest.approx(DEM.height_m(tgt)[0] + 100.0)


def test_terrain_targets_climb_first_when_the_straight_path_is_not_clear():
    ta = TerrainAltitude(DEM, ORIGIN[2], clearance_m=15.0)
    # 20 m above the plane, heading into the hill: the straight path would hit it
    pos = np.array([[300.0, -420.0, -20.0]])
    tgt = np.array([[300.0, -300.0]])
    out = terrain_targets(pos, tgt, np.array([20.0]), ta)
    assert out[0, :2].tolist() == pos[0, :2].tolist()  # a climb over where it is
    assert ORIGIN[2] - out[0, 2] >= DEM.height_m(tgt)[0] + 15.0


def test_every_terrain_target_path_clears_the_ground():
    ta = TerrainAltitude(DEM, ORIGIN[2], clearance_m=15.0, ceiling_agl_m=120.0)
    rng = np.random.default_rng(4)
    ne = rng.uniform(-1000, 1000, size=(400, 2))
    agl = rng.uniform(15.0, 120.0, size=400)
    pos = np.column_stack([ne, ORIGIN[2] - (DEM.height_m(ne) + agl)])
    tgt = ne + rng.uniform(-25, 25, size=(400, 2))
    out = terrain_targets(pos, tgt, np.full(400, 100.0), ta)
    alt0, alt1 = ORIGIN[2] - pos[:, 2], ORIGIN[2] - out[:, 2]
    clear = path_clearance_m(DEM, ne, out[:, :2], alt0, alt1, 64)
    assert clear.min() >= 15.0 - 1.0  # a path sampled 4x finer than the check: within 1 m
    moved = np.linalg.norm(out[:, :2] - ne, axis=1) > 0
    assert moved.mean() > 0.5  # most move; the rest climb first


def test_a_vehicle_below_the_ground_on_its_way_home_climbs_before_rtl():
    from types import SimpleNamespace

    from gcs.control import ControlConfig
    from gcs.operations.end import EndStep

    ta = TerrainAltitude(DEM, ORIGIN[2], clearance_m=15.0)
    sent = []
    op = SimpleNamespace(
        control=ControlConfig(terrain=ta),
        _send_targets=lambda snap, rows, target, now_s: sent.append((rows.tolist(), target)),
    )
    # vehicle 0 east of the hill (150 m high at 300 N -200 E), 30 m over the plane: the hill
    # stands between it and the base; vehicle 1 high above everything
    pos = np.array([[300.0, -400.0, -30.0], [0.0, 900.0, -500.0]])
    snap = SimpleNamespace(pos_ned_m=pos, has_position=np.array([True, True]))
    assert EndStep._climb_before_rtl(op, snap, 0, 1.0)
    ((rows, target),) = sent
    assert rows == [0] and target[0, :2].tolist() == pos[0, :2].tolist()
    f = np.linspace(0.0, 1.0, 1001)[:, None]
    highest = float(DEM.height_m(pos[0, :2] * (1.0 - f)).max())  # the hill's flank on the way
    assert highest > ORIGIN[2] + 30.0
    assert ORIGIN[2] - target[0, 2] == pytest.approx(highest + 15.0, abs=1.0)
    assert not EndStep._climb_before_rtl(op, snap, 1, 1.0)  # high enough: RTL at once
    op.control = ControlConfig()  # a flat earth: never
    assert not EndStep._climb_before_rtl(op, snap, 0, 1.0)

"""The emulator over terrain (vehicle_emu/terrain.py, core_terrain.py): links that must clear
the ground, ground contact, ArduPilot's terrain database and its terrain frames. In memory,
explicit time."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavedge import terrain_grid as tg
from planner.geometry import ned_to_geodetic
from planner.terrain import Hill, LinkBudget, Ridge, TerrainRadio, synthetic_terrain
from vehicle_emu.link import VehicleCore
from vehicle_emu.radio import RadioConfig
from vehicle_emu.swarm import Swarm
from vehicle_emu.terrain import VEHICLE_ANTENNA_AGL_M, Ground, TerrainDatabase

from emu_helpers import GCS_ADDR, FakeGcs, of_type

HOME = (47.5, 8.5, 400.0)
#: A ridge 150 m high 300 m north of the base; a hill to the east.
DEM = synthetic_terrain(
    [Ridge([(300.0, -900.0), (300.0, 900.0)], 150.0, 80.0), Hill((0.0, 400.0), 60.0, 80.0)],
    900.0,
    10.0,
    HOME[2],
)
GROUND = Ground(TerrainRadio(DEM, LinkBudget()), HOME[2])


def _heights(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    from planner.geometry import geodetic_to_ned_m

    ned = geodetic_to_ned_m(lat, lon, HOME[2], *HOME)
    return DEM.height_m(ned[..., :2])


def _serve(db: TerrainDatabase, lat_e7: int, lon_e7: int, t: float) -> int:
    """Answer the database's requests as a station would (one request per call)."""
    req = db.request(lat_e7, lon_e7, t)
    if req is None:
        return 0
    glat, glon, spacing, mask = req
    n = 0
    for bit in range(56):
        if mask >> bit & 1:
            la, lo = tg.post_locations_e7(glat, glon, float(spacing), [bit])
            data = np.rint(_heights(la[0], lo[0])).astype(int)
            assert db.on_data(glat, glon, spacing, bit, data.tolist())
            n += 1
    return n


def test_database_requests_until_loaded_then_knows_the_ground():
    db = TerrainDatabase(30)
    lat, lon = round(HOME[0] * 1e7), round(HOME[1] * 1e7)
    t = 0.0
    assert _serve(db, lat, lon, t) == 56  # the block under the vehicle, all of it
    assert db.request(lat, lon, t + 1.0) is None  # at most every 2 s (TerrainGCS.cpp)
    for _ in range(12):  # then its neighbours, one block per request
        t += 2.0
        _serve(db, lat, lon, t)
    pending, loaded = db.statistics()
    assert pending == 0 and loaded % 56 == 0 and loaded >= 56 * 4
    rng = np.random.default_rng(2)
    for n, e in rng.uniform(-300, 300, size=(40, 2)):
        la, lo, _ = ned_to_geodetic(np.array([n, e, 0.0]), *HOME)
        h = db.height_amsl_m(round(float(la) * 1e7), round(float(lo) * 1e7))
        assert h is not None
        want = float(DEM.height_m(np.array([n, e])))
        # posts rounded to whole metres; off the ridge the ground is smooth at 30 m posts, on
        # its crest (150 m over 80 m) the 30 m posts cut the top by up to ~12 m
        assert h == pytest.approx(want, abs=1.0 if n < 150 else 15.0)
    # a sub-grid of a block it does not hold is ignored
    assert not db.on_data(1, 2, 30, 0, [0] * 16)


def test_database_without_data_knows_nothing():
    db = TerrainDatabase(100)
    assert db.height_amsl_m(round(HOME[0] * 1e7), round(HOME[1] * 1e7)) is None
    assert db.statistics() == (0, 0)


def _core_with_terrain() -> tuple[VehicleCore, FakeGcs]:
    core = VehicleCore(1, "ardupilot", origin_lla=HOME)
    core.enable_terrain(30, 0.0)
    return core, FakeGcs()


def test_ardupilot_core_asks_reports_and_stores():
    core, gcs = _core_with_terrain()
    t, requests, reports = 0.0, [], []
    from gcs.terrain import TerrainServer  # the station's side, for a cross-check

    server = TerrainServer(_heights)
    for _ in range(300):  # 30 s
        t = round(t + 0.1, 6)
        core.receive_datagram(gcs.heartbeat(), GCS_ADDR, t)
        core.handle_timer(t)
        out = gcs.decode(core.datagrams_to_send(t))
        reports += of_type(out, "TERRAIN_REPORT")
        for req in of_type(out, "TERRAIN_REQUEST"):
            requests.append(req)
            for data in server.answer(req):
                core.receive_datagram(gcs.frame(data), GCS_ADDR, t)
    assert requests and requests[0].grid_spacing == 30 and requests[0].mask == tg.FULL_MASK
    assert 25 <= len(reports) <= 31  # once a second
    first, last = reports[0], reports[-1]
    assert first.spacing == 0 and first.loaded == 0  # nothing yet
    assert last.pending == 0 and last.loaded >= 56 and last.spacing == 30
    assert last.terrain_height == pytest.approx(HOME[2], abs=1.0)


def test_terrain_frame_flies_above_the_databases_ground_and_is_refused_without_it():
    core, gcs = _core_with_terrain()
    la, lo, _ = ned_to_geodetic(np.array([0.0, 400.0, 0.0]), *HOME)  # the hill top, 460 m
    lat_e7, lon_e7 = round(float(la) * 1e7), round(float(lo) * 1e7)
    pers = core.pers
    frame = mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT
    assert pers.global_to_world(lat_e7, lon_e7, 50.0, frame) is None  # no terrain yet
    db = core.terrain_db
    assert db is not None
    t = 0.0
    for _ in range(12):
        t += 2.0
        _serve(db, lat_e7, lon_e7, t)
    ned = pers.global_to_world(lat_e7, lon_e7, 50.0, frame)
    assert ned is not None
    assert HOME[2] - ned[2] == pytest.approx(460.0 + 50.0, abs=3.0)
    # home-relative stays home-relative
    rel = pers.global_to_world(lat_e7, lon_e7, 50.0, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
    assert -rel[2] == pytest.approx(50.0, abs=0.05)  # 400 m away: the earth's curvature


def _swarm(n: int, spawn_ne: np.ndarray) -> Swarm:
    down = GROUND.ground_down_m(spawn_ne)
    return Swarm(
        n,
        home_lla=HOME,
        spawn_ned_m=np.column_stack([spawn_ne, down]),
        radio=RadioConfig(),
        rng=np.random.default_rng(0),
        ground=GROUND,
        terrain_spacing_m=30,
    )


def test_radio_needs_line_of_sight_over_the_ridge():
    sw = _swarm(2, np.array([[100.0, 0.0], [600.0, 0.0]]))
    ph = sw.physics
    # both 20 m up: the ridge (150 m) between the first and the second cuts the second off
    ph.pos_ned_m[:, 2] = GROUND.ground_down_m(ph.pos_ned_m[:, :2]) - 20.0
    sw.radio.update(ph.pos_ned_m, ph.alive)
    assert sw.radio.active.tolist() == [True, False]
    ph.pos_ned_m[1, 2] = GROUND.ground_down_m(ph.pos_ned_m[1:, :2])[0] - 400.0  # high above it
    ph.pos_ned_m[0, 2] = -300.0
    sw.radio.update(ph.pos_ned_m, ph.alive)
    assert sw.radio.active.tolist() == [True, True]
    # and the disc range is not used over terrain (RadioConfig() is infinite anyway)


def test_a_fleet_on_its_pads_is_heard_from_the_base_mast():
    """A vehicle on the ground has its antenna on top of the airframe, not in the dirt: 60 m from
    a 3 m mast over flat ground its link clears the Fresnel zone (at 0 m it did not, and a fleet
    on its pads was never heard)."""
    ground = Ground(TerrainRadio(DEM, LinkBudget()), HOME[2], base_antenna_agl_m=3.0)
    ang = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    pos = np.zeros((8, 3))
    pos[:, 0], pos[:, 1] = 60.0 * np.cos(ang) - 100.0, 60.0 * np.sin(ang)  # south of the ridge
    pos[:, 2] = ground.ground_down_m(pos[:, :2])  # on the ground
    base = np.array([-100.0, 0.0, 0.0])
    assert ground.links_to_base(pos, base).all()
    assert ground.active_mask(pos, np.ones(8, bool), base).all()
    np.testing.assert_allclose(
        ground.antenna_amsl_m(pos), ground.height_amsl_m(pos[:, :2]) + VEHICLE_ANTENNA_AGL_M
    )
    pos[:, 2] -= 20.0  # in flight the antenna is where the vehicle is
    np.testing.assert_allclose(ground.antenna_amsl_m(pos), HOME[2] - pos[:, 2])


def test_flown_into_the_hill_is_lost_and_landing_on_it_is_not():
    sw = _swarm(2, np.array([[0.0, 200.0], [0.0, 400.0]]))
    ph = sw.physics
    # vehicle 0 flies east at 10 m above the plane into the hill's flank
    ph.armed[:] = True
    ph.landed[:] = False
    ph.pos_ned_m[0, 2] = -10.0
    ph.command_position(0, np.array([0.0, 400.0, -10.0]))
    # vehicle 1 hovers 5 m above the hill top (60 m up) and lands there
    ph.pos_ned_m[1, 2] = ph.ground_down_m[1] - 5.0
    ph.command_land(1)
    t = 0.0
    for _ in range(400):  # 20 s of the swarm's physics and ground contact
        t = round(t + 0.05, 6)
        was_landed = ph.landed.copy()
        ph.step(0.05)
        sw._ground_contact(was_landed, t)
    assert not ph.alive[0] and sw.stats["terrain_crashes"] == 1
    assert 100.0 < ph.pos_ned_m[0, 1] < 400.0  # lost on the flank, short of the top
    assert ph.alive[1] and ph.landed[1]
    assert ph.pos_ned_m[1, 2] == pytest.approx(GROUND.ground_down_m(ph.pos_ned_m[1:, :2])[0])


def test_the_station_sets_the_terrain_interval_by_terrain_requests_id():
    # GCS_Common.cpp map_message_id_to_ap_message: TERRAIN_REQUEST -> MSG_TERRAIN, which sends the
    # report (and any request) at that interval
    core, gcs = _core_with_terrain()
    t = 0.0
    cmd = gcs.command(
        mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_TERRAIN_REQUEST, 250_000
    )
    core.receive_datagram(cmd, GCS_ADDR, t)
    acks = [m for m in gcs.decode(core.datagrams_to_send(t)) if m.get_type() == "COMMAND_ACK"]
    assert acks and acks[0].result == mavlink.MAV_RESULT_ACCEPTED
    reports = 0
    for _ in range(100):  # 10 s
        t = round(t + 0.1, 6)
        core.receive_datagram(gcs.heartbeat(), GCS_ADDR, t)
        core.handle_timer(t)
        reports += len(of_type(gcs.decode(core.datagrams_to_send(t)), "TERRAIN_REPORT"))
    assert 30 <= reports <= 41  # 4 Hz, not the default 1 Hz (0.1 s ticks: every 0.3 s at worst)
    # a vehicle without a terrain database refuses it, as before
    plain = VehicleCore(2, "ardupilot", origin_lla=HOME)
    plain.receive_datagram(
        gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 133, 250_000, target=2), GCS_ADDR, 0.0
    )
    acks = [m for m in gcs.decode(plain.datagrams_to_send(0.0)) if m.get_type() == "COMMAND_ACK"]
    assert acks and acks[0].result != mavlink.MAV_RESULT_ACCEPTED


def test_px4_drops_a_terrain_frame_setpoint_without_a_terrain_estimate():
    # mavlink_receiver.cpp handle_message_set_position_target_global_int: frame 11 needs
    # vehicle_global_position.terrain_alt_valid (a distance sensor), else return
    core = VehicleCore(1, "px4", origin_lla=HOME)
    gcs = FakeGcs()
    la, lo, _ = ned_to_geodetic(np.array([50.0, 0.0, 0.0]), *HOME)

    def target(frame):
        return gcs.frame(
            mavlink.MAVLink_set_position_target_global_int_message(
                0,
                1,
                1,
                frame,
                0b110111111000,
                round(float(la) * 1e7),
                round(float(lo) * 1e7),
                30.0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        )

    before = core.stats.setpoints_ignored
    core.receive_datagram(target(mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT), GCS_ADDR, 0.1)
    assert core.stats.setpoints_ignored == before + 1
    core.receive_datagram(target(mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT), GCS_ADDR, 0.2)
    assert core.stats.setpoints_ignored == before + 1


def test_hops_over_terrain_follow_the_links_that_clear_it():
    from vehicle_emu.radio import Radio

    # a chain north from the base over flat ground, 250 m apart at 30 m up, with the 1.6 km
    # budget: every vehicle hears the base directly (1 hop) ...
    ne = np.array([[-250.0, 0.0], [-500.0, 0.0], [-750.0, 0.0]])
    pos = np.column_stack([ne, GROUND.ground_down_m(ne) - 30.0])
    radio = Radio(RadioConfig(latency_per_hop_s=0.1), np.zeros(3), np.random.default_rng(0), GROUND)
    radio.update(pos, np.ones(3, bool))
    assert radio.active.all() and radio.hops.tolist() == [1, 1, 1]
    # ... then a budget of ~400 m: a chain of three hops
    short = Ground(TerrainRadio(DEM, LinkBudget(fade_margin_db=22.0)), HOME[2])
    assert 250.0 < short.radio.budget.max_range_m < 500.0
    radio = Radio(RadioConfig(latency_per_hop_s=0.1), np.zeros(3), np.random.default_rng(0), short)
    radio.update(pos, np.ones(3, bool))
    assert radio.active.all() and radio.hops.tolist() == [1, 2, 3]
    assert radio.transit(2) == pytest.approx(0.3)

"""Real ArduCopter asks the station for terrain and flies over it (docs/terrain.md §6).

One ArduCopter SITL started by :mod:`mission.flight.sitl` at the canyon_deep mission's base, with
TERRAIN_ENABLE=1 and TERRAIN_SPACING=30 (skipped without ``PHIREMAN_ARDUCOPTER``). Its working
directory has no terrain files, so the firmware asks its ground station with TERRAIN_REQUEST
(libraries/AP_Terrain/TerrainGCS.cpp ``send_request``); :class:`gcs.terrain.TerrainServer`
answers from the mission's DEM. The vehicle's TERRAIN_REPORT must show the blocks loaded
(pending 0) and the DEM's height under it. Then a short flight: take off, and a
SET_POSITION_TARGET_GLOBAL_INT in MAV_FRAME_GLOBAL_TERRAIN_ALT_INT (40 m above the ground)
over the canyon's floor, 250 m below the rim: the vehicle descends into the canyon and holds
40 m above its floor. SITL's own physics takes its ground from the same terrain database
(libraries/SITL/SIM_Aircraft.cpp ``Aircraft::ground_height_difference`` with SIM_TERRAIN on),
so the ground it flies over is the one the station served.
"""

from __future__ import annotations

import time

import pytest

import sitl_gcs
from sitl_gcs import note_vehicle
from gcs.terrain import TerrainServer, mission_heights
from gcs.wire import deg_to_e7, mavlink
from mission.flight.sitl import SitlError, SitlSpec, SitlSwarm, find_binary
from mission.format.examples import example_path
from mission.format.load import load_mission
from mission.format.terrain import build_terrain
from planner.geometry import ned_to_geodetic

pytestmark = [pytest.mark.sitl, pytest.mark.udp]

SPACING_M = 30


def test_arducopter_loads_terrain_from_the_station_and_flies_terrain_frames(tmp_path):
    from pymavlink import mavutil

    try:
        binary = find_binary("ardupilot")
    except SitlError as exc:
        pytest.skip(f"real-firmware test skipped: {exc}")
    mission = load_mission(example_path("canyon_deep"))  # a floor 80 m wide: wider than 30 m posts
    dem = build_terrain(mission)
    assert dem is not None
    o = mission.origin
    home = (o.lat_deg, o.lon_deg, o.alt_amsl_m)
    server = TerrainServer(mission_heights(dem, *home))
    spec = SitlSpec(
        "ardupilot",
        1,
        binary,
        home,
        workdir=tmp_path / "sitl",
        params={"TERRAIN_ENABLE": 1, "TERRAIN_SPACING": SPACING_M},
        first_instance=9,
        speedup=4.0,
    )
    with SitlSwarm(spec) as sitl:
        conn = mavutil.mavlink_connection(
            sitl.connection(0), source_system=255, source_component=190, dialect="ardupilotmega"
        )
        st: dict = {"requests": 0, "data": 0}

        def on_message(m) -> None:
            kind = m.get_type()
            if kind == "TERRAIN_REQUEST":
                st["requests"] += 1
                for data in server.answer(m):
                    conn.mav.send(data)
                    st["data"] += 1
            elif kind == "TERRAIN_REPORT":
                st["report"] = m
            note_vehicle(st, m)

        def pump(seconds: float, until=None) -> bool:
            return sitl_gcs.pump(conn, seconds, on_message, until)

        try:
            assert pump(120, lambda: "sysid" in st), "no heartbeat"
            sysid = int(st["sysid"])
            # TERRAIN_REPORT / TERRAIN_REQUEST go out with the EXTRA3 stream (MSG_TERRAIN).
            for stream, hz in (
                (mavlink.MAV_DATA_STREAM_EXTRA3, 2),
                (mavlink.MAV_DATA_STREAM_POSITION, 4),
            ):
                conn.mav.request_data_stream_send(sysid, 1, stream, hz, 1)

            def loaded() -> bool:
                # Before its position is known the firmware reports (and asks for) 0 N 0 E.
                r = st.get("report")
                here = r is not None and abs(r.lat * 1e-7 - o.lat_deg) < 0.01
                return here and r.pending == 0 and r.loaded > 0 and r.spacing > 0

            assert pump(180, loaded), f"terrain never loaded: {st.get('report')}, {st}"
            r = st["report"]
            print(f"\nloaded: {r} after {st['requests']} requests, {st['data']} TERRAIN_DATA")
            assert r.spacing == SPACING_M and r.loaded % 56 == 0
            assert r.terrain_height == pytest.approx(o.alt_amsl_m, abs=1.5)

            # A short flight: GUIDED, arm (retried until the estimator is ready), take off.
            end = time.monotonic() + 240
            while not st.get("armed") and time.monotonic() < end:
                conn.mav.command_long_send(
                    sysid, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0
                )
                conn.mav.command_long_send(
                    sysid, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
                )
                pump(2.0)
            assert st.get("armed"), "never armed"
            conn.mav.command_long_send(
                sysid, 1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, float("nan"), 0, 0, 30.0
            )
            assert pump(120, lambda: st.get("rel", 0) > 25.0), "no take-off"
            # Over the canyon floor (350 m east of the base, 250 m below the rim), 40 m above it.
            la, lo, _ = ned_to_geodetic([0.0, 350.0, 0.0], *home)
            floor_m = float(dem.height_m([[0.0, 350.0]])[0])
            target = (deg_to_e7(float(la)), deg_to_e7(float(lo)))

            def over_floor() -> bool:
                conn.mav.set_position_target_global_int_send(
                    0,
                    sysid,
                    1,
                    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
                    0b110111111000,
                    *target,
                    40.0,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                )
                amsl = home[2] + st.get("rel", 0.0)
                return abs(amsl - (floor_m + 40.0)) < 5.0

            assert pump(240, over_floor), f"never reached 40 m over the floor: {st}"
            pump(5.0)
            r = st["report"]
            print(f"over the floor: {r}")
            assert r.terrain_height == pytest.approx(floor_m, abs=3.0)
            assert r.current_height == pytest.approx(40.0, abs=5.0)
        finally:
            conn.close()

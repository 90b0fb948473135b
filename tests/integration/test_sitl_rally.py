"""Real firmware accepts the station's rally upload (gcs/rally.py RallyUpload) and stores it.

One SITL vehicle per firmware, started by :mod:`mission.flight.sitl` as ``phireman sitl`` starts it
(skipped without ``PHIREMAN_ARDUCOPTER`` / ``PHIREMAN_PX4``). The upload state machine is driven
over a pymavlink connection on the wall clock; the points are then read back with the mission
protocol's download (MISSION_REQUEST_LIST / MISSION_REQUEST_INT, mission_type RALLY).
"""

from __future__ import annotations

import time

import pytest

from gcs.rally import (
    MISSION_PROTOCOL_MESSAGES,
    RallyPoint,
    RallyUpload,
    UploadState,
    is_refusal_text,
    mission_event,
)
import sitl_gcs
from sitl_gcs import note_vehicle
from gcs.wire import deg_to_e7, mavlink
from mission.flight.sitl import DEFAULT_HOMES, SitlError, SitlSpec, SitlSwarm, find_binary

pytestmark = [pytest.mark.sitl, pytest.mark.udp]

T_RALLY = mavlink.MAV_MISSION_TYPE_RALLY


def _points(firmware: str) -> tuple[RallyPoint, ...]:
    lat, lon, _ = DEFAULT_HOMES[firmware]
    return (
        RallyPoint(deg_to_e7(lat + 0.0008), deg_to_e7(lon), 40.0),
        RallyPoint(deg_to_e7(lat), deg_to_e7(lon - 0.0011), 35.0),
    )


def _recv(conn, kinds, timeout_s: float):
    m = conn.recv_match(type=list(kinds), blocking=True, timeout=timeout_s)
    return m


@pytest.mark.parametrize("firmware", ["ardupilot", "px4"])
def test_rally_upload_is_accepted_by_real_firmware(tmp_path, firmware):
    from pymavlink import mavutil

    try:
        binary = find_binary(firmware)
    except SitlError as exc:
        pytest.skip(f"real-firmware test skipped: {exc}")
    spec = SitlSpec(
        firmware,
        1,
        binary,
        DEFAULT_HOMES[firmware],
        workdir=tmp_path / "sitl",
        first_instance=7 if firmware == "ardupilot" else 0,
    )
    with SitlSwarm(spec) as sitl:
        conn = mavutil.mavlink_connection(
            sitl.connection(0), source_system=255, source_component=190, dialect="ardupilotmega"
        )
        try:
            hb = None
            end = time.monotonic() + 120
            while time.monotonic() < end and hb is None:
                conn.mav.heartbeat_send(
                    mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4
                )
                m = _recv(conn, ["HEARTBEAT"], 1.0)
                if m is not None and m.get_srcComponent() == 1 and m.type != mavlink.MAV_TYPE_GCS:
                    hb = m
            assert hb is not None, "no heartbeat from the vehicle"
            sysid = hb.get_srcSystem()
            time.sleep(5.0)  # let the firmware finish booting its mission storage
            points = _points(firmware)
            up = RallyUpload(sysid, points, time.monotonic())
            seen = []
            end = time.monotonic() + 60
            while not up.finished and time.monotonic() < end:
                for msg in up.take_messages():
                    conn.mav.send(msg)
                m = _recv(conn, MISSION_PROTOCOL_MESSAGES, 0.2)
                now = time.monotonic()
                if m is not None and m.get_srcSystem() == sysid:
                    seen.append((m.get_type(), getattr(m, "seq", getattr(m, "type", None))))
                    up.on_event(mission_event(0, sysid, m, now), now)
                up.handle_timer(now)
            print(f"\n[{firmware}] upload: {up.state} result {up.result} seen {seen}")
            assert up.state == UploadState.DONE, (up.reason, seen)
            assert up.result == mavlink.MAV_MISSION_ACCEPTED
            # Read them back (the download half of the mission protocol).
            conn.mav.mission_request_list_send(sysid, 1, T_RALLY)
            count = _recv(conn, ["MISSION_COUNT"], 5.0)
            assert count is not None and count.count == len(points), count
            for seq, p in enumerate(points):
                conn.mav.mission_request_int_send(sysid, 1, seq, T_RALLY)
                item = _recv(conn, ["MISSION_ITEM_INT"], 5.0)
                assert item is not None and item.seq == seq
                assert item.command == mavlink.MAV_CMD_NAV_RALLY_POINT
                assert (item.x, item.y) == (p.lat_e7, p.lon_e7)
                assert item.z == pytest.approx(p.alt_above_home_m, abs=0.5)
                # Sent in frame 3 (gcs/rally.py RALLY_ITEM_FRAME); reported by altitude reference:
                # PX4 6 in int mode (mavlink_mission.cpp format_mavlink_mission_item), ArduPilot 3
                # (MissionItemProtocol_Rally::get_item_as_mission_item). So a read-back alone
                # cannot prove the navigator can use the point (the RTL test below does).
                assert item.frame == (
                    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
                    if firmware == "px4"
                    else mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
                ), item
            conn.mav.mission_ack_send(sysid, 1, mavlink.MAV_MISSION_ACCEPTED, T_RALLY)
        finally:
            conn.close()


def _upload(conn, sysid: int, points, timeout_s: float = 60.0) -> RallyUpload:
    up = RallyUpload(sysid, points, time.monotonic())
    end = time.monotonic() + timeout_s
    while not up.finished and time.monotonic() < end:
        for msg in up.take_messages():
            conn.mav.send(msg)
        m = _recv(conn, MISSION_PROTOCOL_MESSAGES, 0.2)
        now = time.monotonic()
        if m is not None and m.get_srcSystem() == sysid:
            up.on_event(mission_event(0, sysid, m, now), now)
        up.handle_timer(now)
    return up


def _ne_m(lat_deg: float, lon_deg: float, home) -> tuple[float, float]:
    from planner.geometry import geodetic_to_ned_m

    ned = geodetic_to_ned_m(lat_deg, lon_deg, home[2], *home)
    return float(ned[0]), float(ned[1])


@pytest.mark.parametrize("firmware", ["ardupilot", "px4"])
def test_real_firmware_rtl_flies_to_the_uploaded_rally_point(tmp_path, firmware):
    """Take off, fly 150 m north, upload a rally point 70 m north, RTL: the vehicle returns to
    the rally point (ArduCopter with RALLY_LIMIT_KM 0 as the station sets it, RALLY_INCL_HOME 1;
    PX4 with its default RTL_TYPE 0), not home."""
    from pymavlink import mavutil

    try:
        binary = find_binary(firmware)
    except SitlError as exc:
        pytest.skip(f"real-firmware test skipped: {exc}")
    home = DEFAULT_HOMES[firmware]
    params = {"RALLY_LIMIT_KM": 0.0} if firmware == "ardupilot" else {"NAV_DLL_ACT": 0}
    speedup = 4.0 if firmware == "ardupilot" else 1.0
    spec = SitlSpec(
        firmware,
        1,
        binary,
        home,
        workdir=tmp_path / "sitl",
        params=params,
        first_instance=8 if firmware == "ardupilot" else 0,
        speedup=speedup,
    )
    with SitlSwarm(spec) as sitl:
        conn = mavutil.mavlink_connection(
            sitl.connection(0), source_system=255, source_component=190, dialect="ardupilotmega"
        )
        pos: dict[str, float] = {}
        texts: list[tuple[int, str]] = []

        def on_message(m) -> None:
            if m.get_type() == "STATUSTEXT":
                texts.append((m.severity, m.text))
            note_vehicle(pos, m)

        def pump(seconds: float, until=None) -> bool:
            return sitl_gcs.pump(conn, seconds, on_message, until)

        try:
            assert pump(120, lambda: "sysid" in pos), "no heartbeat"
            sysid = int(pos["sysid"])
            conn.mav.command_long_send(
                sysid,
                1,
                mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                0,
                mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                200_000,
                0,
                0,
                0,
                0,
                0,
            )
            assert pump(60, lambda: "lat" in pos), "no position"
            rally_lat = home[0] + 70.0 / 111_320.0
            up = _upload(conn, sysid, (RallyPoint(deg_to_e7(rally_lat), deg_to_e7(home[1]), 20.0),))
            assert up.state == UploadState.DONE, up.reason
            # Arm and take off (retried until the estimator is ready).
            guided = (1, 4, 0) if firmware == "ardupilot" else None
            end = time.monotonic() + 240
            while not pos.get("armed") and time.monotonic() < end:
                if guided is not None:
                    conn.mav.command_long_send(
                        sysid, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, *guided, 0, 0, 0, 0
                    )
                conn.mav.command_long_send(
                    sysid, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
                )
                pump(2.0)
            assert pos.get("armed"), "never armed"
            # NAV_TAKEOFF: ArduCopter takes param7 above home and only uses the altitude. PX4 takes
            # param7 as AMSL and params 5/6 as the take-off latitude/longitude, and only
            # non-finite values mean "here" (PX4 src/modules/navigator/navigator_main.cpp,
            # Navigator::run, VEHICLE_CMD_NAV_TAKEOFF: PX4_ISFINITE(cmd.param5) &&
            # PX4_ISFINITE(cmd.param6)); takeoff.cpp Takeoff::set_takeoff_position passes them on.
            # With 0, 0 the target is 0 N 0 E: PX4 main 2025-07 accepts the command and enters
            # AUTO.TAKEOFF but never lifts off (the trajectory towards a point thousands of km
            # away climbs too slowly for the want-takeoff test in
            # src/modules/flight_mode_manager/tasks/Auto/FlightTaskAuto.cpp, FlightTaskAuto::update,
            # unsmoothed vz < -0.3 m/s) and auto-disarms. So NaN, NaN, as QGroundControl sends.
            if firmware == "ardupilot":
                takeoff = (float("nan"), 0.0, 0.0, 20.0)
            else:
                takeoff = (float("nan"), float("nan"), float("nan"), home[2] + 20.0)
            conn.mav.command_long_send(sysid, 1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, *takeoff)
            assert pump(120, lambda: pos.get("rel", 0) > 15.0), "no take-off"
            # Out 150 m north (PX4's navigator takes DO_REPOSITION's altitude as AMSL).
            frame, alt = (
                (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 20.0)
                if firmware == "ardupilot"
                else (mavlink.MAV_FRAME_GLOBAL_INT, home[2] + 20.0)
            )
            out_lat = home[0] + 150.0 / 111_320.0
            end = time.monotonic() + 240
            while time.monotonic() < end and _ne_m(pos["lat"], pos["lon"], home)[0] < 145.0:
                conn.mav.command_int_send(
                    sysid,
                    1,
                    frame,
                    mavlink.MAV_CMD_DO_REPOSITION,
                    0,
                    0,
                    -1,
                    1,
                    0,
                    float("nan"),
                    deg_to_e7(out_lat),
                    deg_to_e7(home[1]),
                    alt,
                )
                pump(3.0)
            assert _ne_m(pos["lat"], pos["lon"], home)[0] >= 145.0, pos
            # RTL: to the rally point, 80 m back, not to home, 150 m back.
            conn.mav.command_long_send(
                sysid, 1, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0
            )
            track: list[tuple[float, float, float]] = []  # (wall s, north m, east m)

            def settled() -> bool:
                now = time.monotonic()
                track.append((now, *_ne_m(pos["lat"], pos["lon"], home)))
                recent = [n for t, n, _ in track if t >= now - 8.0]
                return (
                    now - track[0][0] > 10.0
                    and track[-1][1] < 120.0
                    and max(recent) - min(recent) < 0.5
                )  # 8 s without moving north

            pump(400, settled)
            _, north, east = track[-1]
            print(
                f"\n[{firmware}] after RTL: {north:.1f} m north, {east:.1f} m east of home; "
                f"closest to home {min(n for _, n, _ in track):.1f} m north"
            )
            assert north == pytest.approx(70.0, abs=6.0) and abs(east) < 6.0, track[-1]
            assert min(n for _, n, _ in track) > 60.0  # it never came home
            # PX4 rtl.cpp RTL::setSafepointAsDestination complains every 2 s about a point in a
            # frame it cannot fly to (gcs/rally.py REFUSAL_TEXTS): never about the station's.
            assert not [t for t in texts if is_refusal_text(t[1])], texts
        finally:
            conn.close()

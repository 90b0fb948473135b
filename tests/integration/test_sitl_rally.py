"""Real firmware accepts the station's rally upload (gcs/rally.py RallyUpload) and stores it.

One SITL vehicle per firmware, started by :mod:`mission.sitl` as ``phireman sitl`` starts it
(skipped without ``PHIREMAN_ARDUCOPTER`` / ``PHIREMAN_PX4``). The upload state machine is driven
over a pymavlink connection on the wall clock; the points are then read back with the mission
protocol's download (MISSION_REQUEST_LIST / MISSION_REQUEST_INT, mission_type RALLY).
"""

from __future__ import annotations

import time

import pytest

from gcs.rally import MISSION_PROTOCOL_MESSAGES, RallyPoint, RallyUpload, UploadState, mission_event
from gcs.wire import deg_to_e7, mavlink
from mission.sitl import DEFAULT_HOMES, SitlError, SitlSpec, SitlSwarm, find_binary

pytestmark = [pytest.mark.sitl, pytest.mark.udp]

T_RALLY = mavlink.MAV_MISSION_TYPE_RALLY


def _points(firmware: str) -> tuple[RallyPoint, ...]:
    lat, lon, _ = DEFAULT_HOMES[firmware]
    return (RallyPoint(deg_to_e7(lat + 0.0008), deg_to_e7(lon), 40.0),
            RallyPoint(deg_to_e7(lat), deg_to_e7(lon - 0.0011), 35.0))


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
    spec = SitlSpec(firmware, 1, binary, DEFAULT_HOMES[firmware], workdir=tmp_path / "sitl",
                    first_instance=7 if firmware == "ardupilot" else 0)
    with SitlSwarm(spec) as sitl:
        conn = mavutil.mavlink_connection(sitl.connection(0), source_system=255,
                                          source_component=190, dialect="ardupilotmega")
        try:
            hb = None
            end = time.monotonic() + 120
            while time.monotonic() < end and hb is None:
                conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4)
                m = _recv(conn, ["HEARTBEAT"], 1.0)
                if m is not None and m.get_srcComponent() == 1 and m.type != mavlink.MAV_TYPE_GCS:
                    hb = m
            assert hb is not None, "no heartbeat from the vehicle"
            sysid = hb.get_srcSystem()
            time.sleep(5.0)          # let the firmware finish booting its mission storage
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
            conn.mav.mission_ack_send(sysid, 1, mavlink.MAV_MISSION_ACCEPTED, T_RALLY)
        finally:
            conn.close()

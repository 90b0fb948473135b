"""Live task trackers in the station core and :class:`gcs.tasks.LiveTasks`, in memory, explicit time."""

from __future__ import annotations

import numpy as np
import pytest
from gcs_fakes import FakeAutopilot, drain, sent
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.events import TaskPositionReceived, VehicleDiscovered
from gcs.fleet import MissionOrigin
from gcs.link import StationConfig
from gcs.tasks import LiveTasks
from planner.geometry import geodetic_to_ned_m

ADDR = ("10.0.0.7", 14600)
ORIGIN = MissionOrigin(39.7596, -121.6219, 540.0)


def _tracker(compid=1):
    return FakeAutopilot(
        sysid=200,
        compid=compid,
        autopilot=mav.MAV_AUTOPILOT_INVALID,
        vehicle_type=mav.MAV_TYPE_GROUND_ROVER,
    )


def test_a_tracker_is_never_a_vehicle_and_is_asked_for_its_position(station):
    link = station(task_sysids=(200,), stream_rates_hz=())
    tr = _tracker()
    link.receive_datagram(tr.heartbeat(), ADDR, 0.0)
    assert not any(isinstance(e, VehicleDiscovered) for e in drain(link))
    assert link.vehicles() == [] and link.stats.task_heartbeats == 1
    out = [m for m, a in sent(link, 0.0) if a == ADDR]  # (sent() drains the queue)
    cmds = [m for m in out if m.get_type() == "COMMAND_LONG"]
    assert [(c.command, c.target_system, int(c.param1)) for c in cmds] == [
        (mav.MAV_CMD_SET_MESSAGE_INTERVAL, 200, mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
    ]
    assert cmds[0].param2 == pytest.approx(1e6)  # 1 Hz
    streams = [m for m in out if m.get_type() == "REQUEST_DATA_STREAM"]
    assert len(streams) == 1 and streams[0].req_stream_id == mav.MAV_DATA_STREAM_POSITION
    # A second heartbeat soon after: no second request (no flood while the stream starts).
    link.receive_datagram(tr.heartbeat(), ADDR, 1.0)
    assert sent(link, 1.0, "COMMAND_LONG") == []
    # Still no position after telemetry_stale_s: asked again.
    link.receive_datagram(tr.heartbeat(), ADDR, 3.5)
    assert len(sent(link, 3.5, "COMMAND_LONG")) == 1


def test_tracker_position_becomes_a_task_event_from_any_component(station):
    link = station(task_sysids=(200,), stream_rates_hz=())
    tr = _tracker(compid=191)  # a companion-computer component, not the autopilot
    link.receive_datagram(tr.global_position(0.0, 0.0, 0.0, 0.0), ADDR, 0.5)  # no fix: ignored
    assert drain(link) == []
    link.receive_datagram(tr.global_position(39.7610, -121.6200, 545.0, 5.0), ADDR, 1.0)
    [ev] = drain(link)
    assert isinstance(ev, TaskPositionReceived)
    assert (ev.sysid, ev.t_s) == (200, 1.0)
    assert (ev.lat_deg, ev.lon_deg, ev.alt_amsl_m) == pytest.approx(
        (39.7610, -121.6200, 545.0), abs=1e-6
    )
    # Nothing is ever commanded to it, and it never appears as a vehicle.
    link.handle_timer(10.0)
    assert link.vehicles() == []
    assert [
        m
        for m, a in sent(link, 10.0, "COMMAND_LONG")
        if a == ADDR and m.command != mav.MAV_CMD_SET_MESSAGE_INTERVAL
    ] == []


def test_a_vehicle_beside_a_tracker_is_still_discovered(station):
    link = station(task_sysids=(200,), stream_rates_hz=())
    link.receive_datagram(FakeAutopilot(sysid=3).heartbeat(custom_mode=4), ADDR, 0.0)
    link.receive_datagram(_tracker().heartbeat(), ADDR, 0.0)
    kinds = [(type(e).__name__, e.sysid) for e in drain(link)]
    assert kinds == [("VehicleDiscovered", 3)]


def test_task_sysids_are_validated():
    with pytest.raises(ValueError, match="own sysid"):
        StationConfig(task_sysids=(255,))
    with pytest.raises(ValueError, match="1..255"):
        StationConfig(task_sysids=(0,))


def test_live_tasks_fill_their_columns_in_the_mission_frame():
    live = LiveTasks(ORIGIN, {1: 200, 3: 201})
    static = np.array([[10.0, 20.0], [np.nan, np.nan], [-5.0, 7.0], [np.nan, np.nan]])
    out = live.fill(static)
    assert np.array_equal(out[[0, 2]], static[[0, 2]]) and np.isnan(out[[1, 3]]).all()
    assert live.waiting_for() == (200, 201)
    assert live.apply(
        TaskPositionReceived(0, 201, 2.0, lat_deg=39.7610, lon_deg=-121.6200, alt_amsl_m=545.0)
    )
    assert not live.apply(
        TaskPositionReceived(0, 202, 2.0, lat_deg=39.0, lon_deg=-121.0, alt_amsl_m=0.0)
    )  # not ours
    want = geodetic_to_ned_m(
        39.7610, -121.6200, 545.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_amsl_m
    )[:2]
    out = live.fill(static)
    assert out[3] == pytest.approx(want, abs=1e-6) and np.isnan(out[1]).all()
    assert 100 < want[0] < 200 and 100 < want[1] < 200  # about 156 m N, 163 m E
    assert live.waiting_for() == (200,)
    assert live.silent(3.0, 5.0) == (200,) and live.silent(8.0, 5.0) == (200, 201)
    assert static[3, 0] != static[3, 0]  # fill never writes into its input


def test_two_tasks_cannot_share_a_tracker():
    with pytest.raises(ValueError, match="share"):
        LiveTasks(ORIGIN, {0: 200, 1: 200})

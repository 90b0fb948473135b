"""Who is a vehicle: allowed sysids, a vehicle budget, and consistency over time (issue 12 B)."""

import random

import pytest
from gcs_fakes import FakeAutopilot, drain, sent
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.events import (
    ModeChanged,
    TelemetryReceived,
    VehicleDiscovered,
    VehicleRecovered,
)
from gcs.link import StationConfig

A1, A2, A3 = ("10.0.0.1", 14550), ("10.0.0.2", 14550), ("10.0.0.3", 14550)
GUIDED = 4
PX4 = mav.MAV_AUTOPILOT_PX4


def test_config_validates_and_normalises():
    assert StationConfig(allowed_sysids=[3, 1]).allowed_sysids == frozenset({1, 3})
    with pytest.raises(ValueError):
        StationConfig(allowed_sysids={0})
    with pytest.raises(ValueError):
        StationConfig(max_vehicles=0)


def test_only_allowed_sysids_become_vehicles(station):
    link = station(allowed_sysids=frozenset({1, 2}))
    for sysid, addr in ((1, A1), (7, A2), (7, A2), (2, A3)):
        link.receive_datagram(FakeAutopilot(sysid=sysid).heartbeat(GUIDED), addr, 0.0)
    link.receive_datagram(FakeAutopilot(sysid=9).global_position(47, 8, 500, 10), A2, 0.1)
    assert sorted(v.sysid for v in link.vehicles()) == [1, 2]
    assert [e.sysid for e in drain(link) if isinstance(e, VehicleDiscovered)] == [1, 2]
    assert link.stats.refused_sysids == 3
    assert link.stats.refused_by_sysid == {7: 2, 9: 1}
    assert link.stats.from_unknown_sysid == 0
    assert all(a != A2 for _, a in sent(link, 0.1))  # nothing ever sent to the refused system


def test_non_vehicle_heartbeats_are_not_refusals(station):
    link = station(allowed_sysids=frozenset({1}))
    gcs = FakeAutopilot(
        sysid=250, compid=190, vehicle_type=mav.MAV_TYPE_GCS, autopilot=mav.MAV_AUTOPILOT_INVALID
    )
    link.receive_datagram(gcs.heartbeat(), A2, 0.0)
    assert link.stats.non_vehicle_heartbeats == 1 and link.stats.refused_sysids == 0


def test_max_vehicles_keeps_the_first_heard(station):
    link = station(max_vehicles=2)
    for t, sysid in enumerate((5, 3, 8, 5, 9)):
        link.receive_datagram(FakeAutopilot(sysid=sysid).heartbeat(GUIDED), ("h", sysid), float(t))
    assert sorted(v.sysid for v in link.vehicles()) == [3, 5]
    assert link.stats.refused_by_sysid == {8: 1, 9: 1}
    # Lost vehicles keep their places: the budget is of vehicles, not of live ones.
    link.handle_timer(100.0)
    link.receive_datagram(FakeAutopilot(sysid=8).heartbeat(GUIDED), ("h", 8), 100.0)
    assert sorted(v.sysid for v in link.vehicles()) == [3, 5]


def test_changed_autopilot_or_type_while_live_is_dropped(station):
    link = station()
    real = FakeAutopilot(sysid=1)
    link.receive_datagram(real.heartbeat(GUIDED), A1, 0.0)
    drain(link)
    for fake in (
        FakeAutopilot(sysid=1, autopilot=PX4),
        FakeAutopilot(sysid=1, vehicle_type=mav.MAV_TYPE_FIXED_WING),
    ):
        link.receive_datagram(fake.heartbeat(6, armed=True), A1, 0.5)  # same address, even
    v = link.vehicle(1)
    assert (v.autopilot, v.vehicle_type, v.adapter, v.mode, v.armed) == (
        mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
        mav.MAV_TYPE_QUADROTOR,
        "ardupilot",
        "GUIDED",
        False,
    )
    assert drain(link) == [] and link.stats.inconsistent_frames == 2
    # Silent for the whole timeout, then back as PX4: re-flashed, accepted.
    link.handle_timer(10.0)
    drain(link)
    link.receive_datagram(FakeAutopilot(sysid=1, autopilot=PX4).heartbeat(0), A1, 11.0)
    assert link.vehicle(1).autopilot == PX4
    assert any(isinstance(e, VehicleRecovered) for e in drain(link))


def test_second_address_while_the_first_is_live_is_dropped(station):
    link = station(address_hold_s=2.0)
    real = FakeAutopilot(sysid=1)
    twin = FakeAutopilot(sysid=1)
    link.receive_datagram(real.heartbeat(GUIDED), A1, 0.0)
    link.receive_datagram(real.global_position(47.0, 8.0, 500, 10), A1, 1.0)
    drain(link)
    link.receive_datagram(twin.heartbeat(6), A2, 1.5)
    link.receive_datagram(twin.global_position(10.0, 10.0, 500, 10), A2, 1.6)
    assert drain(link) == []
    assert link.address_of(1) == A1 and link.vehicle(1).mode == "GUIDED"
    assert link.stats.inconsistent_frames == 2
    # Its gimbal on another port is no inconsistency (ignored as before).
    gimbal = FakeAutopilot(sysid=1, compid=mav.MAV_COMP_ID_GIMBAL)
    link.receive_datagram(gimbal.statustext("hello"), A3, 1.7)
    assert link.stats.inconsistent_frames == 2
    # The old address silent past the hold: telemetry alone does not move it, a heartbeat does.
    link.receive_datagram(twin.global_position(10.0, 10.0, 500, 10), A2, 3.5)
    assert link.address_of(1) == A1 and link.stats.inconsistent_frames == 3
    link.receive_datagram(twin.heartbeat(GUIDED), A2, 3.6)
    assert link.address_of(1) == A2
    sent(link, 3.6)
    link.arm(1, 3.7)
    assert {a for _, a in sent(link, 3.7)} == {A2}


def _random_frame(rng: random.Random, aps: dict) -> tuple[bytes, int, int, bool]:
    """One valid frame from a random system: (bytes, sysid, compid, is a vehicle heartbeat)."""
    sysid = rng.randrange(1, 256)
    compid = 1 if rng.random() < 0.7 else rng.randrange(0, 256)
    ap = aps.setdefault(
        (sysid, compid),
        FakeAutopilot(
            sysid=sysid,
            compid=compid,
            autopilot=rng.choice((3, 12, 0, 8)),
            vehicle_type=rng.choice((2, 1, 6, 18, 26)),
        ),
    )
    kind = rng.randrange(5)
    if kind == 0:
        vehicle = compid == 1 and ap.vehicle_type not in (6, 18, 26)
        return (
            ap.heartbeat(rng.randrange(0, 1 << 20), armed=rng.random() < 0.5),
            sysid,
            compid,
            vehicle,
        )
    if kind == 1:
        data = ap.global_position(
            rng.uniform(-80, 80),
            rng.uniform(-170, 170),
            rng.uniform(0, 3000),
            rng.uniform(-100, 100),
        )
    elif kind == 2:
        data = ap.ack(rng.choice((400, 176, 511)), rng.randrange(0, 6))
    elif kind == 3:
        data = ap.statustext("x" * rng.randrange(1, 50))
    else:
        data = ap.param_value("SYSID_MYGCS", rng.uniform(0, 255))
    return data, sysid, compid, False


def test_fuzz_random_bytes_and_frames_create_no_vehicle_and_are_counted(station):
    """Random bytes and random valid frames (random sysids, components, autopilots) from a few
    strange addresses, while two real vehicles fly: no new vehicle, no address or autopilot
    switch, no foreign telemetry, no mode change; every foreign frame is counted."""
    rng = random.Random(12)
    link = station(allowed_sysids=frozenset({1, 2}), address_hold_s=2.0)
    real = {1: (FakeAutopilot(sysid=1), A1), 2: (FakeAutopilot(sysid=2), A2)}
    strangers = [(f"192.0.2.{i}", 40000 + i) for i in range(5)]
    aps: dict = {}
    expect_refused = expect_inconsistent = 0
    t = 0.0
    for step in range(20000):
        t = step * 0.005  # 100 s at 200 datagrams/s
        if step % 50 == 0:  # each real vehicle: heartbeat and position at 4 Hz
            for ap, addr in real.values():
                link.receive_datagram(ap.heartbeat(GUIDED), addr, t)
                link.receive_datagram(ap.global_position(47.0, 8.0, 500.0, 20.0), addr, t)
        addr = rng.choice(strangers)
        r = rng.random()
        if r < 0.4:
            link.receive_datagram(rng.randbytes(rng.randrange(1, 300)), addr, t)
        elif r < 0.5:  # garbage around a frame, or a cut frame
            data, *_ = _random_frame(rng, aps)
            link.receive_datagram(rng.randbytes(5) + data[: rng.randrange(1, len(data))], addr, t)
        else:
            data, sysid, compid, vehicle_hb = _random_frame(rng, aps)
            if sysid == 255:
                pass  # our own sysid: counted apart
            elif sysid in real:
                if compid == 1:
                    expect_inconsistent += 1
            elif data[7] == 0 and not vehicle_hb:  # msgid 0: a non-vehicle heartbeat
                pass
            else:
                expect_refused += 1
            link.receive_datagram(data, addr, t)
        link.handle_timer(t)
        link.datagrams_to_send(t)
    events = drain(link)
    assert sorted(v.sysid for v in link.vehicles()) == [1, 2]
    assert [e.sysid for e in events if isinstance(e, VehicleDiscovered)] == [1, 2]
    for sysid, (_, addr) in real.items():
        v = link.vehicle(sysid)
        assert link.address_of(sysid) == addr and v.autopilot == 3 and v.mode == "GUIDED"
        assert not v.lost and not v.armed
    assert not [e for e in events if isinstance(e, (ModeChanged, VehicleRecovered))]
    assert {(e.lat_deg, e.lon_deg) for e in events if isinstance(e, TelemetryReceived)} == {
        (47.0, 8.0)
    }
    st = link.stats
    assert st.refused_sysids == expect_refused > 1000
    assert sum(st.refused_by_sysid.values()) == st.refused_sysids
    assert not {1, 2, 255} & set(st.refused_by_sysid)
    assert st.inconsistent_frames == expect_inconsistent > 20
    assert st.handler_errors == 0 and st.decode.bad_data > 1000

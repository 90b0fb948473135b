"""Several links as one station: same sysid on two networks stays two vehicles."""

import pytest
from gcs_fakes import FakeAutopilot
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.events import VehicleDiscovered
from gcs.link import StationConfig, StationLink, UnknownVehicle
from gcs.station import Station


def test_two_links_same_sysid_are_distinct_vehicles():
    cfg = StationConfig(stream_rates_hz=())
    st = Station([StationLink(cfg, link_id=0), StationLink(cfg, link_id=1)])
    a, b = FakeAutopilot(sysid=1), FakeAutopilot(sysid=1, autopilot=mav.MAV_AUTOPILOT_PX4)
    st.link(0).receive_datagram(a.heartbeat(4), "net0", 0.0)
    st.link(1).receive_datagram(b.heartbeat(393216), "net1", 0.0)
    evs = st.events()
    assert [(e.link_id, e.sysid) for e in evs if isinstance(e, VehicleDiscovered)] == [
        (0, 1),
        (1, 1),
    ]
    assert sorted(st.networked()) == [(0, 1), (1, 1)]
    st.datagrams_to_send(0.0)
    st.arm((0, 1), 0.1)
    out = st.datagrams_to_send(0.1)
    assert [(lid, addr) for lid, _, addr in out] == [(0, "net0")]
    assert st.next_timer_s() == pytest.approx(0.0)
    st.handle_timer(1.0)
    assert {lid for lid, _, _ in st.datagrams_to_send(1.0)} == {0, 1}
    with pytest.raises(UnknownVehicle):
        st.rtl((2, 1), 1.0)
    with pytest.raises(ValueError):
        Station([StationLink(cfg, link_id=0), StationLink(cfg, link_id=0)])

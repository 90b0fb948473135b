"""Swarm: radio reachability, attrition, identities/networks, multiplexing, ground truth."""

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavedge import codec
from vehicle_emu import events as ev
from vehicle_emu.attrition import Attrition
from vehicle_emu.radio import RadioConfig
from vehicle_emu.swarm import Swarm, identity_of_index

from emu_helpers import GCS_ADDR, FakeGcs, acks, of_type


def _run(swarm, gcs, t0, t1, hb=True):
    """Tick from t0 to t1 (20 Hz); GCS heartbeats at 1 Hz to every endpoint; decode per sysid."""
    got = {}
    t = t0
    next_hb = t0
    while t < t1 - 1e-9:
        t = round(t + 0.05, 6)
        if hb and t >= next_hb:
            for e in range(swarm.n_endpoints):
                swarm.receive_datagram(e, gcs.heartbeat(), GCS_ADDR, t)
            next_hb = t + 1.0
        swarm.handle_timer(t)
        for endpoint, data, addr in swarm.datagrams_to_send(t):
            for m in gcs.decode([(data, addr)]):
                got.setdefault(m.get_srcSystem() + 1000 * endpoint * swarm.mux, []).append(m)
    return got, t


def chain_swarm(**kw):
    spawn = np.array([[80.0, 0, 0], [160.0, 0, 0], [240.0, 0, 0]])
    return Swarm(
        3,
        spawn_ned_m=spawn,
        radio=RadioConfig(radio_range_m=100.0),
        rng=np.random.default_rng(3),
        **kw,
    )


def test_chain_relay_loss_cuts_both_directions():
    swarm = chain_swarm()
    gcs = FakeGcs()
    got, t = _run(swarm, gcs, 0.0, 3.0)
    assert swarm.active.tolist() == [True, True, True]
    assert all(len(of_type(got.get(s, []), "HEARTBEAT")) >= 2 for s in (1, 2, 3))
    # commands reach v3 through v1 and v2
    swarm.receive_datagram(2, gcs.command(176, 1, 4, target=3), GCS_ADDR, t)
    acked = gcs.decode([(d, a) for e, d, a in swarm.datagrams_to_send(t) if e == 2])
    assert acks(acked, 176) == [mavlink.MAV_RESULT_ACCEPTED]

    swarm.kill(0, t)  # the first relay dies
    got, t = _run(swarm, gcs, t, t + 5.0)
    assert swarm.active.tolist() == [False, False, False]
    assert got == {}  # no telemetry from anyone
    before = [c.stats.datagrams_in for c in swarm.cores]
    for e, sysid in ((1, 2), (2, 3)):
        swarm.receive_datagram(e, gcs.command(400, 1, target=sysid), GCS_ADDR, t)
    assert [c.stats.datagrams_in for c in swarm.cores] == before  # never delivered
    assert swarm.datagrams_to_send(t) == []
    assert not swarm.cores[1].armed and not swarm.cores[2].armed
    assert swarm.stats["dropped_radio_in"] >= 2 and swarm.stats["dropped_radio_out"] > 0
    assert any(
        isinstance(e, ev.VehicleKilled) and e.index == 0 for e in iter(swarm.next_event, None)
    )


def test_killed_vehicle_heartbeat_stops_and_stays_stopped():
    swarm = Swarm(2, rng=np.random.default_rng(4), kills=[(2.0, 1)])
    gcs = FakeGcs()
    got, t = _run(swarm, gcs, 0.0, 2.0)
    assert len(of_type(got[2], "HEARTBEAT")) == 2
    got, t = _run(swarm, gcs, t, 10.0)
    assert 2 not in got and len(of_type(got[1], "HEARTBEAT")) == 8
    assert not swarm.alive[1] and swarm.cores[1].stats.dropped_dead == 0
    dropped = swarm.stats["dropped_dead"]
    swarm.receive_datagram(1, gcs.command(400, 1, target=2), GCS_ADDR, t)
    assert swarm.stats["dropped_dead"] == dropped + 1
    assert swarm.datagrams_to_send(t) == [] and not swarm.cores[1].armed


def test_vehicle_dead_in_flight_freezes():
    swarm = Swarm(1, rng=np.random.default_rng(5))
    gcs = FakeGcs()
    for data in (
        gcs.command(176, 1, 4),
        gcs.command(400, 1),
        gcs.command(22, 0, 0, 0, 0, 0, 0, 10),
    ):
        swarm.receive_datagram(0, data, GCS_ADDR, 0.0)
    _, t = _run(swarm, gcs, 0.0, 3.0)
    swarm.kill(0, t)
    pos = swarm.physics.pos_ned_m[0].copy()
    _run(swarm, gcs, t, t + 3.0)
    assert np.array_equal(swarm.physics.pos_ned_m[0], pos)


def test_more_than_254_vehicles_use_several_networks():
    swarm = Swarm(600, rng=np.random.default_rng(6), mux=True)
    assert swarm.n_networks == 3 and swarm.n_endpoints == 3
    assert identity_of_index(253) == (0, 254) and identity_of_index(254) == (1, 1)
    assert swarm.identity(599) == (2, 600 - 508)
    ids = {swarm.identity(i) for i in range(600)}
    assert len(ids) == 600 and all(1 <= s <= 254 for _, s in ids)
    assert swarm.index_of(1, 1) == 254
    # a command to (network 1, sysid 1) reaches exactly vehicle 254
    gcs = FakeGcs()
    swarm.receive_datagram(1, gcs.command(400, 1, target=1), GCS_ADDR, 0.0)
    assert [i for i, c in enumerate(swarm.cores) if c.armed] == [254]
    out = [(d, e) for e, d, _ in swarm.datagrams_to_send(0.0)]
    assert {e for _, e in out} == {1}
    assert acks(gcs.decode(out), 400) == [mavlink.MAV_RESULT_ACCEPTED]


def test_mux_broadcast_heartbeat_reaches_all_members():
    swarm = Swarm(5, rng=np.random.default_rng(7), mux=True)
    swarm.receive_datagram(0, FakeGcs().heartbeat(), GCS_ADDR, 0.0)
    assert [c.stats.gcs_heartbeats for c in swarm.cores] == [1] * 5


def test_truth_log_and_task_uptime():
    # one vehicle flies out of range of a task and back; TU from the truth log
    spawn = np.array([[80.0, 0, 0], [160.0, 0, 0]])  # base - v0 - v1 chain
    tasks = np.array([[200.0, 0.0], [500.0, 0.0]])
    swarm = Swarm(
        2,
        spawn_ned_m=spawn,
        radio=RadioConfig(radio_range_m=100.0),
        task_pos_fn=lambda t: tasks,
        rng=np.random.default_rng(8),
        kills=[(5.0, 0)],
    )
    gcs = FakeGcs()
    _run(swarm, gcs, 0.0, 10.0)
    arr = swarm.truth.arrays()
    assert arr["t_s"].tolist() == pytest.approx(list(range(11)))  # 1 Hz, t = 0 .. 10 s
    assert arr["task_connected"].shape == (11, 2)
    # task 0 connected until vehicle 0 (the only link to the base) dies at t=5
    assert arr["task_connected"][:, 0].tolist() == [True] * 5 + [False] * 6
    assert not arr["task_connected"][:, 1].any()
    assert arr["active"][-1].tolist() == [False, False]
    tu1, tu2 = swarm.task_uptime()
    assert tu1 == pytest.approx(5 / 11 / 2) and tu2 == pytest.approx(5 / 11)


def test_attrition_hazard_rate_statistics():
    rng = np.random.default_rng(9)
    att = Attrition(20_000, hazard_per_s=0.01, rng=rng)
    alive = np.ones(20_000, dtype=bool)
    for k in range(100):  # 10 s in 0.1 s steps
        for i, _ in att.step(k * 0.1, (k + 1) * 0.1, alive):
            alive[i] = False
    expected = 1 - np.exp(-0.1)
    assert abs((~alive).mean() - expected) < 4 * np.sqrt(expected / 20_000)


def test_radio_latency_and_loss_are_seeded():
    def run(seed):
        swarm = Swarm(
            3,
            spawn_ned_m=[[50.0, 0, 0], [100.0, 0, 0], [150.0, 0, 0]],
            radio=RadioConfig(radio_range_m=60.0, latency_per_hop_s=0.1, loss_per_hop=0.2),
            rng=np.random.default_rng(seed),
            stream_rates_hz={33: 10},
        )
        got, _ = _run(swarm, FakeGcs(), 0.0, 5.0)
        return {k: len(v) for k, v in got.items()}, swarm.radio.hops.tolist()

    a, hops = run(1)
    assert hops == [1, 2, 3]
    assert a == run(1)[0] and a != run(2)[0]
    assert a[1] > a[2] > a[3]  # more hops, more loss


def test_out_of_range_vehicle_failsafes_home_and_is_heard_again():
    """The paper's default: a disconnected drone flies home, and the GCS can take it back."""
    swarm = Swarm(1, radio=RadioConfig(radio_range_m=100.0), rng=np.random.default_rng(10))
    gcs = FakeGcs()
    for data in (
        gcs.command(176, 1, 4),
        gcs.command(400, 1),
        gcs.command(22, 0, 0, 0, 0, 0, 0, 10),
        gcs.local_target(150, 0, -10),
    ):
        swarm.receive_datagram(0, data, GCS_ADDR, 0.0)
    got, t = _run(swarm, gcs, 0.0, 12.0)
    assert not swarm.active[0]  # beyond 100 m: the GCS cannot hear it
    t_lost = next(tt for tt, a in zip(swarm.truth.t_s, swarm.truth.active) if not a[0])
    got, t = _run(swarm, gcs, t, t + 30.0)
    core = swarm.cores[0]
    assert core.mode_name == "RTL"
    fs = [e for e in iter(swarm.next_event, None) if isinstance(e, ev.FailsafeTriggered)]
    assert fs and t_lost <= fs[0].t_s <= t_lost + 5.0 + 1.5
    assert swarm.active[0] and of_type(got[1], "HEARTBEAT")  # home again and heard
    swarm.receive_datagram(0, gcs.command(176, 1, 4), GCS_ADDR, t)
    assert core.mode_name == "GUIDED"  # the ground station takes it back


def test_mux_router_parses_each_frame_once(monkeypatch):
    """The router reads target_system from the header bytes; only the addressed core decodes
    (CRC, signature, unpack): one decode per frame, not two (issue 13.1)."""
    swarm = Swarm(5, rng=np.random.default_rng(7), mux=True)
    gcs = FakeGcs()
    data = gcs.command(400, 1, target=3) + gcs.heartbeat()
    calls = []
    orig = codec._MAVLink.decode  # every frame's decode, its fast path or pymavlink's

    def counting(self, msgbuf):
        calls.append(1)
        return orig(self, msgbuf)

    monkeypatch.setattr(codec._MAVLink, "decode", counting)
    swarm.receive_datagram(0, data, GCS_ADDR, 0.0)
    # one decode for the addressed COMMAND_LONG, one for the broadcast HEARTBEAT (shared by
    # every member without a signing key: "decode once, deliver many")
    assert len(calls) == 1 + 1
    assert [c.stats.commands for c in swarm.cores] == [0, 0, 1, 0, 0]
    assert [c.stats.gcs_heartbeats for c in swarm.cores] == [1] * 5
    assert [c.stats.datagrams_in for c in swarm.cores] == [1, 1, 2, 1, 1]
    # a frame for a sysid nobody has is unroutable, and so is a datagram without a frame
    swarm.receive_datagram(0, gcs.command(400, 1, target=99), GCS_ADDR, 0.0)
    swarm.receive_datagram(0, b"\x01\x02\x03", GCS_ADDR, 0.0)
    assert swarm.stats["unroutable"] == 2


def test_broadcast_decoded_once_but_signed_cores_check_their_own(monkeypatch):
    """A broadcast frame is decoded once for the cores without a key; a core with a signing
    key decodes it itself and refuses it unsigned; a dead core counts it as dropped."""
    key = bytes(range(32))
    swarm = Swarm(4, rng=np.random.default_rng(7), mux=True, per_vehicle_params={})
    swarm.cores[1]._codec.set_signing_key(key)
    swarm.kill(3, 0.0)
    calls = []
    orig = codec._MAVLink.decode  # every frame's decode, its fast path or pymavlink's

    def counting(self, msgbuf):
        calls.append(1)
        return orig(self, msgbuf)

    monkeypatch.setattr(codec._MAVLink, "decode", counting)
    swarm.receive_datagram(0, FakeGcs().heartbeat(), GCS_ADDR, 0.0)
    assert len(calls) == 2  # the shared decode and the signed core's own
    assert [c.stats.gcs_heartbeats for c in swarm.cores] == [1, 0, 1, 0]
    assert swarm.cores[1].stats.signing_rejected == 1
    assert swarm.stats["dropped_dead"] == 1
    # a signed heartbeat reaches every live core (pymavlink accepts it without a key)
    swarm.receive_datagram(0, FakeGcs(signing_key=key).heartbeat(), GCS_ADDR, 0.1)
    assert [c.stats.gcs_heartbeats for c in swarm.cores] == [2, 1, 2, 0]


def test_cores_with_output_are_always_marked():
    """datagrams_to_send visits the cores in ``_out_dirty``: every core with queued frames must
    be there (the scan of every core it replaces would have found them), through ticks with
    batched and per-vehicle telemetry, commands, broadcasts, a kill and a datagram loss."""
    swarm = Swarm(
        6,
        rng=np.random.default_rng(5),
        mux=True,
        radio=RadioConfig(loss_per_hop=0.2, latency_per_hop_s=0.02),
    )
    gcs = FakeGcs()
    swarm.cores[2]._codec.set_signing_key(bytes(range(32)))  # per-vehicle telemetry path
    marked = 0
    t = 0.0
    for step in range(200):
        t = round(t + 0.05, 6)
        if step % 20 == 0:
            swarm.receive_datagram(0, gcs.heartbeat(), GCS_ADDR, t)
        if step % 7 == 0:
            swarm.receive_datagram(0, gcs.command(400, 1, target=1 + step % 6), GCS_ADDR, t)
        if step == 100:
            swarm.kill(4, t)
        with_out = {i for i, c in enumerate(swarm.cores) if c._out}
        assert with_out <= swarm._out_dirty
        marked += len(with_out)
        swarm.handle_timer(t)
        with_out = {i for i, c in enumerate(swarm.cores) if c._out}
        assert with_out <= swarm._out_dirty
        marked += len(with_out)
        swarm.datagrams_to_send(t)
        assert not any(c._out for c in swarm.cores if c.alive)
    assert marked > 50


@pytest.mark.parametrize(
    "cfg",
    [
        RadioConfig(radio_range_m=60.0),
        RadioConfig(radio_range_m=60.0, latency_per_hop_s=0.01),
        RadioConfig(radio_range_m=60.0, loss_per_hop=0.3),
        RadioConfig(),
    ],
)
def test_radio_transit_many_is_transit_per_index(cfg):
    """Radio.transit_many (one array lookup without hop counts) against transit in a loop: the
    same fates, counters and random draws, indices out of range included."""
    from vehicle_emu.radio import Radio

    rng = np.random.default_rng(5)
    pos = rng.uniform(-150, 150, (40, 3))
    alive = rng.random(40) > 0.2
    fast = Radio(cfg, np.zeros(3), np.random.default_rng(9))
    slow = Radio(cfg, np.zeros(3), np.random.default_rng(9))
    fast.update(pos, alive)
    slow.update(pos, alive)
    for _ in range(3):
        idx = rng.integers(0, 45, 30).tolist()
        assert fast.transit_many(idx) == [slow.transit(i) for i in idx]
        assert (fast.n_dropped_inactive, fast.n_dropped_loss) == (
            slow.n_dropped_inactive,
            slow.n_dropped_loss,
        )
    assert fast.transit_many([]) == []
    assert 0 < slow.n_dropped_inactive

"""Learned UDP peers expire and are capped; warnings from remote input are rate-limited.

In memory with explicit time (no sockets). The reference behaviour: PX4's mavlink UDP instance
latches one partner (src/modules/mavlink/mavlink_receiver.cpp, "partner IP"), MAVProxy's
``udpin`` answers only its last sender; the emulator keeps a few peers (several GCS may share an
endpoint) but forgets them after ``peer_timeout_s`` of silence and keeps at most ``max_peers``.
"""

import logging

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from vehicle_emu.link import RateLimitedLog, VehicleCore
from vehicle_emu.swarm import MAX_PEERS, PEER_TIMEOUT_S, Swarm

from emu_helpers import GCS_ADDR


def _swarm(**kw):
    return Swarm(1, personality="px4", rng=np.random.default_rng(0), **kw)


def _tick(swarm, t0, t1, dt=0.05):
    """Tick from t0 to t1; returns the set of destinations and the number of datagrams."""
    dests, n = set(), 0
    t = t0
    while t < t1 - 1e-9:
        t = round(t + dt, 6)
        swarm.handle_timer(t)
        for _, _, addr in swarm.datagrams_to_send(t):
            dests.add(addr)
            n += 1
    return dests, n


def test_one_off_senders_are_forgotten_and_capped(gcs):
    """2,000 one-off senders (the issue's measurement: 353,250 datagrams in 24 s) leave at most
    ``max_peers`` destinations, and none once they have been silent for peer_timeout_s."""
    swarm = _swarm(peer_timeout_s=10.0, max_peers=4)
    hb = gcs.heartbeat()
    for k in range(2000):
        swarm.receive_datagram(0, hb, (f"10.9.{k // 250}.{k % 250}", 40000 + k), 0.01)
    assert len(swarm.peers[0]) == 4  # the cap
    assert swarm.stats["peers_evicted"] == 2000 - 4
    dests, n = _tick(swarm, 0.0, 5.0)
    assert len(dests) == 4
    per_peer_5s = n / 4
    dests, n = _tick(swarm, 5.0, 10.0)
    assert len(dests) == 4  # 10 s not yet exceeded
    dests, n = _tick(swarm, 10.0, 24.0)
    assert swarm.peers[0] == [] and swarm.stats["peers_expired"] == 4
    # only the ~1 s before the sweep noticed the silence still went out
    assert n <= 4 * per_peer_5s / 5 * 1.5


def test_a_live_gcs_is_kept_and_a_configured_one_never_expires(gcs):
    live, quiet, fixed = ("10.0.0.2", 14550), ("10.0.0.3", 14550), ("10.0.0.9", 14550)
    swarm = _swarm(peer_timeout_s=10.0, gcs_addrs=[fixed])
    swarm.receive_datagram(0, gcs.heartbeat(), quiet, 0.0)
    t = 0.0
    while t < 30.0:  # `live` sends a heartbeat every 1 s
        swarm.receive_datagram(0, gcs.heartbeat(), live, t)
        _tick(swarm, t, t + 1.0)
        t += 1.0
    assert swarm.peers[0] == [fixed, live]  # quiet expired after 10 s
    assert swarm.stats["peers_expired"] == 1
    # a returning peer is learned again
    swarm.receive_datagram(0, gcs.heartbeat(), quiet, t)
    assert set(swarm.peers[0]) == {fixed, live, quiet}


def test_eviction_drops_the_least_recently_heard(gcs):
    swarm = _swarm(max_peers=2)
    a, b, c = ("10.0.0.1", 1), ("10.0.0.2", 2), ("10.0.0.3", 3)
    swarm.receive_datagram(0, gcs.heartbeat(), a, 0.0)
    swarm.receive_datagram(0, gcs.heartbeat(), b, 1.0)
    swarm.receive_datagram(0, gcs.heartbeat(), a, 2.0)  # a heard again: b is now the oldest
    swarm.receive_datagram(0, gcs.heartbeat(), c, 3.0)
    assert swarm.peers[0] == [a, c]


def test_peer_defaults_are_sane():
    # longer than the vehicles' own GCS-loss timeouts (ArduPilot FS_GCS_TIMEOUT 5 s, PX4
    # COM_DL_LOSS_T 10 s), so a GCS is never forgotten while the vehicles still consider it live
    assert PEER_TIMEOUT_S > 10.0 and MAX_PEERS >= 2
    with pytest.raises(ValueError):
        _swarm(peer_timeout_s=0.0)


# ---------------------------------------------------------------------------------------------
# Rate-limited warnings
# ---------------------------------------------------------------------------------------------


def test_rate_limited_log_counts_what_it_suppressed(caplog):
    logger = logging.getLogger("test.ratelimit")
    rl = RateLimitedLog(logger, interval_s=10.0)
    with caplog.at_level(logging.WARNING, logger="test.ratelimit"):
        results = [rl.log(t * 0.1, "bad", logging.WARNING, "bad frame %d", t) for t in range(250)]
    # t = 0 .. 24.9 s: logged at 0, 10, 20 s
    assert [r.getMessage() for r in caplog.records] == [
        "bad frame 0",
        "bad frame 100 (99 more suppressed in the last 10 s)",
        "bad frame 200 (99 more suppressed in the last 10 s)",
    ]
    assert sum(results) == 3 and rl.n_suppressed == 247
    # keys are independent and bounded
    rl2 = RateLimitedLog(logger, interval_s=10.0, max_keys=3)
    for k in range(10):
        assert rl2.log(0.0, k, logging.DEBUG, "k")
    assert len(rl2._state) == 3


def test_garbage_and_unknown_messages_log_once_per_interval(gcs, caplog):
    core = VehicleCore(1, "ardupilot")
    junk = bytes([0xFD, 9, 0, 0, 0, 255, 190, 0x39, 0x30, 0]) + b"\x00" * 11  # id 12345
    with caplog.at_level(logging.INFO, logger="vehicle_emu.link"):
        for k in range(500):  # 50 s of 10 Hz garbage
            t = k * 0.1
            core.receive_datagram(b"\xfe\x05garbage-garbage" + junk, GCS_ADDR, t)
    st = core.stats
    assert st.bad_data + st.unknown_msg_ids >= 500  # every one counted ...
    lines = [r for r in caplog.records if "bad frame" in r.getMessage()]
    assert 4 <= len(lines) <= 6  # ... but logged once per 10 s
    assert "suppressed" in lines[-1].getMessage()


def test_swarm_cores_share_one_limiter(gcs, caplog):
    """SETUP_SIGNING from an untrusted link, to every vehicle of a 5-vehicle network."""
    swarm = Swarm(5, personality="ardupilot", mux=True, rng=np.random.default_rng(0))
    with caplog.at_level(logging.WARNING, logger="vehicle_emu.link"):
        for k in range(100):
            for sysid in range(1, 6):
                f = gcs.frame(mavlink.MAVLink_setup_signing_message(sysid, 1, [1] * 32, 0))
                swarm.receive_datagram(0, f, GCS_ADDR, k * 0.05)
    refused = [r for r in caplog.records if "SETUP_SIGNING" in r.getMessage()]
    assert sum(c.stats.signing_rejected for c in swarm.cores) == 500
    assert len(refused) == 1  # 5 s < interval: one line for the fleet

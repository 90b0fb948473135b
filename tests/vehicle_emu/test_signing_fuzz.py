"""MAVLink 2 signing accept/reject, and fuzzing the vehicle core with 10^5 datagrams."""

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from vehicle_emu.link import VehicleCore

from emu_helpers import GCS_ADDR, FakeGcs, acks

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))


def test_signed_vehicle_accepts_only_correctly_signed_commands():
    core = VehicleCore(1, "ardupilot", signing_key=KEY)
    good, bad, unsigned = FakeGcs(signing_key=KEY), FakeGcs(signing_key=OTHER_KEY), FakeGcs()
    for g in (unsigned, bad):
        core.receive_datagram(g.command(176, 1, 4), GCS_ADDR, 0.0)
        core.receive_datagram(g.local_target(1, 2, -3), GCS_ADDR, 0.0)
    assert core.stats.signing_rejected == 4
    assert core.mode_name == "STABILIZE" and core.datagrams_to_send(0.0) == []
    assert core.stats.commands == 0 and core.stats.setpoints == 0
    core.receive_datagram(good.command(176, 1, 4), GCS_ADDR, 0.1)
    assert core.mode_name == "GUIDED"
    out = core.datagrams_to_send(0.1)
    # our replies are signed and verify with the shared key
    assert all(d[2] & mavlink.MAVLINK_IFLAG_SIGNED for d, _ in out)
    rx = mavlink.MAVLink(None, 255, 190)
    rx.signing.secret_key = KEY
    msgs = rx.parse_buffer(out[0][0])
    assert acks(msgs, 176) == [mavlink.MAV_RESULT_ACCEPTED]
    # a replayed frame (same timestamp) is rejected
    frame = good.command(400, 1)
    core.receive_datagram(frame, GCS_ADDR, 0.2)
    core.receive_datagram(frame, GCS_ADDR, 0.2)
    assert core.stats.commands == 2 and core.stats.signing_rejected == 5


def test_setup_signing_only_over_trusted_link():
    trusted = ("127.0.0.1", 5000)
    core = VehicleCore(1, "ardupilot", trusted_addrs={trusted})
    gcs = FakeGcs()
    msg = mavlink.MAVLink_setup_signing_message(1, 1, list(KEY), 1_000)
    core.receive_datagram(gcs.frame(msg), GCS_ADDR, 0.0)  # untrusted radio link
    assert not core.signing_enabled and core.stats.signing_rejected == 1
    core.receive_datagram(gcs.frame(msg), trusted, 0.0)
    assert core.signing_enabled
    core.receive_datagram(gcs.command(176, 1, 4), GCS_ADDR, 0.1)  # now unsigned is refused
    assert core.mode_name == "STABILIZE" and core.stats.signing_rejected == 2
    core.receive_datagram(FakeGcs(signing_key=KEY).command(176, 1, 4), GCS_ADDR, 0.2)
    assert core.mode_name == "GUIDED"


def _valid_frames():
    gcs = FakeGcs()
    return [
        gcs.heartbeat(),
        gcs.command(176, 1, 4),
        gcs.command(400, 1),
        gcs.command(22, 0, 0, 0, 0, 0, 0, 10),
        gcs.local_target(5, 5, -5),
        gcs.local_target(0, 0, 0, mask=3527, vx=1.0),
        gcs.command(511, 33, 100000),
        gcs.frame(mavlink.MAVLink_param_set_message(1, 1, b"GUID_TIMEOUT", 2.0, 9)),
        gcs.frame(
            mavlink.MAVLink_set_position_target_global_int_message(
                0, 1, 1, 6, 3576, 10, 20, 5.0, 0, 0, 0, 0, 0, 0, 0, 0
            )
        ),
        gcs.frame(mavlink.MAVLink_timesync_message(0, 5)),
        gcs.frame(mavlink.MAVLink_request_data_stream_message(1, 1, 0, 4, 1)),
        gcs.frame(mavlink.MAVLink_param_request_list_message(1, 1)),
    ]


def test_fuzz_random_and_mutated_datagrams_never_raise_and_are_counted():
    rng = np.random.default_rng(2024)
    frames = _valid_frames()
    for personality in ("ardupilot", "px4"):
        core = VehicleCore(1, personality)
        n = 50_000
        t = 0.0
        untraced = 0
        for k in range(n):
            r = rng.random()
            if r < 0.3:  # pure random bytes
                data = rng.bytes(int(rng.integers(0, 300)))
            else:  # mutated valid frames: bit flips, truncation, concatenation
                f = bytearray(frames[int(rng.integers(len(frames)))])
                if r < 0.6:
                    for _ in range(int(rng.integers(1, 4))):
                        f[int(rng.integers(len(f)))] ^= 1 << int(rng.integers(8))
                elif r < 0.75:
                    f = f[: int(rng.integers(0, len(f)))]
                elif r < 0.9:
                    f = f + frames[int(rng.integers(len(frames)))] + rng.bytes(3)
                else:  # payload bytes randomised, CRC left wrong
                    f[10:-2] = rng.bytes(len(f) - 12)
                data = bytes(f)
            st = core.stats
            before = (
                st.messages_in
                + st.bad_data
                + st.unknown_msg_ids
                + st.signing_rejected
                + st.truncated_bytes
            )
            core.receive_datagram(data, GCS_ADDR, t)
            after = (
                st.messages_in
                + st.bad_data
                + st.unknown_msg_ids
                + st.signing_rejected
                + st.truncated_bytes
            )
            untraced += bool(data) and after == before
            if k % 50 == 0:
                t += 0.05
                core.handle_timer(t)
                core.datagrams_to_send(t)
        st = core.stats
        assert st.datagrams_in == n and st.handler_errors == 0
        counted = st.bad_data + st.unknown_msg_ids + st.messages_in + st.signing_rejected
        assert counted > 0 and st.bad_data > n * 0.3
        # every non-empty datagram left a trace: decoded, or counted bad/unknown/truncated
        assert untraced == 0

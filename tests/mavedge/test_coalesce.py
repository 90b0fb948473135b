"""mavedge.codec.coalesce_datagrams: per destination, the same frames in the same order, in
datagrams no larger than the limit (unless one alone is)."""

import random

from mavedge import codec
from mavedge import mavlink as mav


class _F:
    def write(self, _d):
        pass


def _frames(rng, n):
    s = mav.MAVLink(_F(), 3, 1)
    out = []
    for _ in range(n):
        kind = rng.random()
        if kind < 0.5:
            m = mav.MAVLink_global_position_int_message(*(rng.randint(0, 1000) for _ in range(9)))
        elif kind < 0.9:
            m = mav.MAVLink_heartbeat_message(2, 3, 81, 4, 4, 3)
        else:
            m = mav.MAVLink_statustext_message(4, bytes(rng.randint(40, 50)) + b"x" * 50)
        out.append(bytes(m.pack(s)))
        s.seq = (s.seq + 1) % 256
    return out


def test_coalesced_datagrams_carry_the_same_frames_per_destination():
    rng = random.Random(2)
    for limit in (60, 300, codec.MAX_DATAGRAM_BYTES):
        frames = _frames(rng, 400)
        dests = [("127.0.0.1", 14550 + rng.randint(0, 3)) for _ in frames]
        # inputs: one frame per datagram, or a vehicle's few frames already joined
        datagrams, i = [], 0
        while i < len(frames):
            k = rng.choice([1, 1, 2, 3])
            datagrams.append((dests[i], b"".join(frames[i : i + k])))
            i += k
        out = codec.coalesce_datagrams(datagrams, limit)
        for dest in set(dests):
            want = [f for d, data in datagrams if d == dest for f in codec.split_frames(data)]
            got_dgrams = [data for d, data in out if d == dest]
            assert [f for data in got_dgrams for f in codec.split_frames(data)] == want
            for data in got_dgrams:
                assert (
                    len(data) <= limit
                    or len(codec.split_frames(data)) == 1
                    or any(len(d) > limit and data == d for _, d in datagrams)
                )
        assert len(out) < len(datagrams)
        # destinations in the order of their first datagram
        first = list(dict.fromkeys(d for d, _ in datagrams))
        assert list(dict.fromkeys(d for d, _ in out)) == first


def test_single_datagrams_pass_unchanged():
    assert codec.coalesce_datagrams([("a", b"\xfd1"), ("b", b"\xfd2")]) == [
        ("a", b"\xfd1"),
        ("b", b"\xfd2"),
    ]

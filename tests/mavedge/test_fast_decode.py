"""The codec's fast datagram path (mavedge/codec.py ``_parse_datagram``, ``_decode_fast``)
against pymavlink's parser and decoder, the reference: same messages attribute for attribute,
same refusals and counters, on generated frames of every message type it covers, MAVLink 2
(truncated trailing zeros included) and 1, signed and unsigned, bad CRC, garbage, truncated
tails, unknown incompat flags, payloads longer than the dialect knows."""

import random

import pytest

from mavedge import codec
from mavedge import mavlink as mav

KEY = bytes(range(32))


class _F:
    def write(self, _d):
        pass


_INT_RANGES = {
    "uint8_t": (0, 255),
    "int8_t": (-128, 127),
    "uint16_t": (0, 65535),
    "int16_t": (-32768, 32767),
    "uint32_t": (0, 2**32 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
}


def _random_message(cls, rng: random.Random):
    """One message of ``cls`` with random field values; about a third of the fields zero, the
    trailing ones more often (so MAVLink 2 trims the payload)."""
    args = []
    n = len(cls.fieldnames)
    for k, ftype in enumerate(cls.fieldtypes):
        if rng.random() < (0.3 if k < n - 2 else 0.6):
            args.append(0.0 if ftype in ("float", "double") else 0)
        elif ftype in ("float", "double"):
            args.append(rng.choice([rng.uniform(-1e6, 1e6), float("nan"), float("inf"), -0.0]))
        else:
            lo, hi = _INT_RANGES[ftype]
            args.append(rng.randint(lo, hi))
    return cls(*args)


def _sender(sysid, key=None, ts=10**9):
    m = mav.MAVLink(_F(), sysid, 1)
    if key is not None:
        m.signing.secret_key = key
        m.signing.sign_outgoing = True
        m.signing.timestamp = ts
    return m


def _state(m):
    """Everything a decoded message carries (the header as its fields)."""
    if isinstance(m, codec.RawFrame):
        d = {k: getattr(m, k) for k in codec.RawFrame.__slots__}
    else:
        d = dict(vars(m))
    if "_header" in d:
        d["_header"] = vars(d["_header"])
    # NaN != NaN: compare floats by their repr
    return type(m).__name__, {k: repr(v) for k, v in sorted(d.items())}


@pytest.fixture
def reference(monkeypatch):
    """Run a callable with the fast path switched off: pymavlink's parser and decoder."""

    def run(fn):
        with monkeypatch.context() as mp:
            mp.setattr(codec, "_FAST", {})
            mp.setattr(codec, "_parse_datagram", lambda _mav, _data: None)
            return fn()

    return run


def _covered_classes():
    return [codec._FAST[i].cls for i in sorted(codec._FAST)]


def test_fast_path_covers_the_streamed_telemetry():
    for name in ("HEARTBEAT", "GLOBAL_POSITION_INT", "SYS_STATUS", "ATTITUDE", "COMMAND_ACK"):
        assert getattr(mav, f"MAVLINK_MSG_ID_{name}") in codec._FAST
    for name in ("STATUSTEXT", "PARAM_VALUE", "SETUP_SIGNING"):  # strings, arrays: pymavlink
        assert getattr(mav, f"MAVLINK_MSG_ID_{name}") not in codec._FAST


def _datagrams(rng: random.Random, signed: bool = False):
    """(label, datagram) pairs: one frame of every covered type, then mixed datagrams."""
    out = []
    classes = _covered_classes()
    s = _sender(rng.randint(1, 254), KEY if signed else None)
    for cls in classes:
        for _ in range(2):
            out.append((cls.msgname, bytes(_random_message(cls, rng).pack(s))))
            s.seq = (s.seq + 1) % 256
    v1 = _sender(9)
    for cls in rng.sample(classes, 20):
        if cls.id < 256:
            out.append(("v1 " + cls.msgname, bytes(_random_message(cls, rng).pack(v1, True))))
    for _ in range(200):
        k = rng.randint(2, 6)
        frames = [bytes(_random_message(rng.choice(classes), rng).pack(s)) for _ in range(k)]
        data = bytearray(b"".join(frames))
        kind = rng.choice(["clean", "badcrc", "garbage", "tail", "incompat", "between"])
        if kind == "badcrc":
            data[rng.randrange(1, len(data))] ^= 1 << rng.randrange(8)
        elif kind == "garbage":
            data[:0] = bytes([0x55, 0x00, 0x13])
        elif kind == "tail":
            data = data[: len(data) - rng.randint(1, 5)]
        elif kind == "incompat":
            data[2] |= 0x04
        elif kind == "between":
            cut = len(frames[0])
            data[cut:cut] = b"\x00\x01"
        out.append((kind, bytes(data)))
    return out


def _longer_than_known(rng: random.Random) -> bytes:
    """A GLOBAL_POSITION_INT frame with 3 extra payload bytes (a newer dialect's extension)."""
    s = _sender(4)
    cls = mav.MAVLink_global_position_int_message
    msg = _random_message(cls, rng)
    msg.hdg = 123  # the last field non-zero: no truncation
    f = bytearray(msg.pack(s))
    payload = f[10:-2] + b"\x01\x02\x03"
    hdr = bytearray(f[:10])
    hdr[1] = len(payload)
    body = hdr + payload
    crc = mav.x25crc(body[1:] + bytes((cls.crc_extra,))).crc
    return bytes(body + bytes((crc & 0xFF, crc >> 8)))


@pytest.mark.parametrize("signed_frames", [False, True])
@pytest.mark.parametrize("key", [None, KEY])
def test_station_decoder_matches_pymavlink(reference, signed_frames, key):
    rng = random.Random(7)
    cases = _datagrams(rng, signed_frames) + [("longer", _longer_than_known(rng))]
    full = frozenset({mav.MAVLINK_MSG_ID_HEARTBEAT, mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT})
    for full_ids in (None, full):

        def run(full_ids=full_ids):
            c = codec.Codec(255, 190, signing_key=key, full_msgids=full_ids)
            dec = c.new_decoder()
            got = [[_state(m) for m in dec.feed(d)] for _label, d in cases]
            return got, vars(c.stats)

        fast, ref = run(), reference(run)
        assert fast[1] == ref[1]
        for (label, _d), a, b in zip(cases, fast[0], ref[0]):
            assert a == b, label
        assert fast[1]["frames"] > 300


@pytest.mark.parametrize("signed_frames", [False, True])
@pytest.mark.parametrize("key", [None, KEY])
def test_vehicle_decoder_matches_pymavlink(reference, signed_frames, key):
    rng = random.Random(11)
    cases = _datagrams(rng, signed_frames) + [("longer", _longer_than_known(rng))]

    def run():
        c = codec.VehicleCodec(3, signing_key=key, allow_unsigned_ids=frozenset({0}))
        out = []
        for _label, d in cases:
            r = c.decode_datagram(d)
            out.append(
                (
                    [_state(m) for m in r.messages],
                    r.n_bad,
                    r.n_unknown,
                    r.n_signature_rejected,
                    r.n_truncated_bytes,
                )
            )
        return out

    fast, ref = run(), reference(run)
    for (label, _d), a, b in zip(cases, fast, ref):
        assert a == b, label
    assert sum(len(x[0]) for x in fast) > (300 if key is None or signed_frames else 0)


def test_fast_path_is_taken(monkeypatch):
    """The comparison above is not vacuous: a clean datagram never reaches parse_buffer, and
    well-formed telemetry never reaches pymavlink's decode."""
    rng = random.Random(3)
    s = _sender(5)
    cls = mav.MAVLink_global_position_int_message
    data = b"".join(bytes(_random_message(cls, rng).pack(s)) for _ in range(3))
    calls = []
    monkeypatch.setattr(mav.MAVLink, "parse_buffer", lambda *a: calls.append("parse"))
    monkeypatch.setattr(mav.MAVLink, "decode", lambda *a: calls.append("decode"))
    dec = codec.Codec(255, 190).new_decoder()
    assert [m.get_type() for m in dec.feed(data)] == ["GLOBAL_POSITION_INT"] * 3
    assert calls == []


@pytest.mark.parametrize("key", [None, KEY])
def test_encoders_match_pymavlink_pack(key):
    """Codec.encode / VehicleCodec.encode (their fast path for unsigned frames) give pymavlink's
    bytes, sequence for sequence, for random messages of every covered type and a few others."""
    rng = random.Random(13)
    station = codec.Codec(255, 190, signing_key=key)
    vehicle = codec.VehicleCodec(42, 1, signing_key=key)
    if key is not None:
        vehicle.advance_signing_timestamp(10**9)
    ref_station = _sender(255, key, 0)
    ref_station.srcComponent = 190
    ref_vehicle = _sender(42, key, 10**9)
    others = [
        mav.MAVLink_statustext_message(4, b"hello"),
        mav.MAVLink_param_value_message(b"X", 1.5, 9, 3, 2),
    ]
    msgs = [_random_message(cls, rng) for cls in _covered_classes() for _ in range(3)] + others
    if key is not None:
        station.set_signing_time(0)  # the twin's timestamp starts at 0 as well
    for msg in msgs:
        assert station.encode(msg) == bytes(msg.pack(ref_station)), msg.get_type()
        ref_station.seq = (ref_station.seq + 1) % 256
        assert vehicle.encode(msg) == bytes(msg.pack(ref_vehicle)), msg.get_type()
        ref_vehicle.seq = (ref_vehicle.seq + 1) % 256


def test_fast_encode_is_taken(monkeypatch):
    monkeypatch.setattr(mav.MAVLink_message, "_pack", lambda *a, **k: 1 / 0)
    frame = codec.Codec(255, 190).encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
    assert codec.Codec(1, 1).new_decoder().feed(frame)[0].get_type() == "HEARTBEAT"

"""The batched telemetry path is byte-for-byte the reference (per-vehicle pymavlink) path."""

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from vehicle_emu import telemetry as tm
from vehicle_emu.physics import CTRL_VEL
from vehicle_emu.swarm import Swarm
from vehicle_emu.telemetry_batch import BATCHED_TYPES, pack_frames

KEY = bytes(range(32))


def _swarm(kind, n=40):
    pers = ["px4" if i % 3 else "ardupilot" for i in range(n)]
    sw = Swarm(
        n,
        personality=pers,
        mux=True,
        spawn_spacing_m=25.0,
        gcs_addrs=[("gcs", 1)],
        rng=np.random.default_rng(5),
        telemetry=kind,
    )
    rng = np.random.default_rng(11)
    ph = sw.physics
    ph.armed[:] = True
    for c in sw.cores:
        c.armed = True
    ph.target_pos_ned_m[:] = np.column_stack(
        [rng.uniform(-300, 300, (n, 2)), rng.uniform(-60, -5, n)]
    )
    ph.max_speed_h_m_s[:] = rng.uniform(2, 12, n)
    # velocity control on some (POSITION_TARGET mask and zero position), far targets on others
    for i in range(0, n, 7):
        ph.ctrl[i] = CTRL_VEL
        ph.target_vel_ned_m_s[i] = (3.0, -2.0, -0.5)
    ph.target_pos_ned_m[5] = (4e7, -3e7, -50.0)
    # every stream on some vehicles, in different orders and rates; one stream switched off
    ids = list(tm.BUILDERS)
    for i in (1, 2, 4, 9):
        order = ids if i % 2 else ids[::-1]
        for k, msg_id in enumerate(order):
            sw.cores[i].set_stream_rate(msg_id, 2.0 + k % 5, 0.0)
    sw.cores[8].set_stream_rate(tm.M_GLOBAL_POSITION_INT, 0.0, 0.0)
    sw.cores[8].set_stream_rate(tm.M_GLOBAL_POSITION_INT, 7.0, 0.0)
    # one signing vehicle and one with a broken (non-finite) state: the reference path
    sw.cores[3]._codec.set_signing_key(KEY, initial_timestamp=5)
    ph.target_pos_ned_m[6] = (np.nan, 0.0, -10.0)
    return sw


def test_batch_frames_equal_reference_frames():
    ref, bat = _swarm("reference"), _swarm("batch")
    t = 0.0
    n_frames = 0
    for k in range(160):
        t = round(t + 0.05, 6)
        if k == 60:  # a mode change and a disarm mid-run
            for sw in (ref, bat):
                sw.cores[2]._set_mode(sw.cores[2].pers.rtl_mode, t, "test")
                sw.cores[10]._disarm(t, "test")
        if k == 90:  # a vehicle lost: silent from now on, on both paths
            for sw in (ref, bat):
                sw.kill(12, t)
        if k == 100:  # a GCS asks for a stream mid-run (SET_MESSAGE_INTERVAL path)
            for sw in (ref, bat):
                sw.cores[13].set_stream_rate(tm.M_ATTITUDE, 4.0, t)
        ref.handle_timer(t)
        bat.handle_timer(t)
        a, b = ref.datagrams_to_send(t), bat.datagrams_to_send(t)
        assert a == b, f"tick {k}"
        n_frames += len(a)
    assert n_frames > 500
    assert ref.core_stats() == bat.core_stats()
    assert bat._batch.n_batched > 2000 and bat._batch.n_reference > 0


@pytest.mark.parametrize("msg_id", sorted(BATCHED_TYPES))
def test_pack_frames_match_pymavlink(msg_id):
    """Random field values (mixed truncation lengths) packed both ways."""
    cls, _ = BATCHED_TYPES[msg_id]
    rng = np.random.default_rng(msg_id)
    mav = mavlink.MAVLink(None, 1, 1)
    fields = {}
    k = 12
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes):
        if name == "q":
            fields[name] = rng.uniform(-1, 1, (k, 4)).astype(np.float32).astype(float)
        elif ftype == "float":
            v = rng.uniform(-1e4, 1e4, k).astype(np.float32).astype(float)
            v[rng.random(k) < 0.3] = 0.0
            fields[name] = v
        elif ftype in (
            "uint8_t",
            "int8_t",
            "uint16_t",
            "int16_t",
            "uint32_t",
            "int32_t",
            "uint64_t",
        ):
            hi = {
                "uint8_t": 255,
                "int8_t": 127,
                "uint16_t": 65535,
                "int16_t": 32767,
                "uint32_t": 2**32 - 1,
                "int32_t": 2**31 - 1,
                "uint64_t": 2**40,
            }[ftype]
            lo = -hi - 1 if ftype.startswith("int") else 0
            v = rng.integers(lo, hi, k, endpoint=True)
            v[rng.random(k) < 0.3] = 0
            fields[name] = v
    seq = rng.integers(0, 256, k)
    frames = pack_frames(cls, fields, seq, 7, 1)
    for r in range(k):
        mav.seq = int(seq[r])
        mav.srcSystem, mav.srcComponent = 7, 1
        kwargs = {}
        for name in cls.fieldnames:
            val = fields.get(name)
            kwargs[name] = (
                (list(val[r]) if np.ndim(val) == 2 else val[r].item()) if val is not None else 0
            )
        msg = cls(**kwargs)
        assert frames[r] == bytes(msg.pack(mav)), (cls.msgname, r)


def test_a_failing_batch_falls_back_to_the_reference_frames(monkeypatch):
    """A bug in a vectorised field function costs speed, never frames or sequence numbers."""
    import vehicle_emu.telemetry_batch as tb

    ref, bat = _swarm("reference", n=12), _swarm("batch", n=12)
    cls, _ = tb.BATCHED_TYPES[tm.M_GLOBAL_POSITION_INT]

    def broken(*_a):
        raise RuntimeError("boom")

    monkeypatch.setitem(tb.BATCHED_TYPES, tm.M_GLOBAL_POSITION_INT, (cls, broken))
    t = 0.0
    for k in range(30):
        t = round(t + 0.05, 6)
        ref.handle_timer(t)
        bat.handle_timer(t)
        assert ref.datagrams_to_send(t) == bat.datagrams_to_send(t), f"tick {k}"

import csv
import json
import math

import pytest
from gcs_fakes import FakeAutopilot, drain

from gcs.events import VehicleLost
from gcs.link import StationConfig, StationLink
from gcs.records import EventLog, MetricsWriter, TlogWriter, write_summary

A1 = ("127.0.0.1", 14550)


def test_tlog_round_trip_through_mavutil(tmp_path):
    from pymavlink import mavutil

    link = StationLink(StationConfig(record_frames=True, unix_time_at_zero_s=1.7e9))
    ap = FakeAutopilot(sysid=1)
    link.receive_datagram(ap.heartbeat(4), A1, 0.0)
    link.receive_datagram(ap.global_position(47.5, 8.25, 500.0, 12.34), A1, 0.25)
    link.arm(1, 0.5)
    link.handle_timer(1.0)
    link.receive_datagram(ap.ack(400) + ap.statustext("Arming motors"), A1, 1.1)
    link.datagrams_to_send(1.1)
    drain(link)
    frames = link.take_frames()
    assert any(out for _, out, _ in frames) and any(not out for _, out, _ in frames)

    path = tmp_path / "run.tlog"
    with TlogWriter(path) as tlog:
        tlog.write_frames(frames)
    raw = path.read_bytes()
    assert int.from_bytes(raw[:8], "big") == int(1.7e9 * 1e6)  # big-endian microseconds

    mlog = mavutil.mavlink_connection(str(path))
    read = []
    while (m := mlog.recv_match()) is not None:
        read.append(m)
    assert len(read) == len(frames)
    for (t, _, frame), m in zip(frames, read):
        assert bytes(m.get_msgbuf()) == frame
        assert m._timestamp == pytest.approx(t, abs=1e-6)
    types = [m.get_type() for m in read]
    assert types[0] == "HEARTBEAT" and "COMMAND_ACK" in types and "STATUSTEXT" in types


def test_event_log_metrics_and_summary(tmp_path):
    with EventLog(tmp_path / "events.jsonl") as log:
        log.write(VehicleLost(0, 3, 12.5, 7.5), run="a")
    (line,) = (tmp_path / "events.jsonl").read_text().splitlines()
    assert json.loads(line) == {
        "type": "VehicleLost",
        "link_id": 0,
        "sysid": 3,
        "t_s": 12.5,
        "last_heartbeat_s": 7.5,
        "run": "a",
    }

    with MetricsWriter(tmp_path / "m.csv") as m:
        m.write({"t_s": 0.0, "networked": 3, "tasks_covered": 2})
        m.write({"t_s": 0.5, "networked": 2, "tasks_covered": 2})
        with pytest.raises(ValueError):
            m.write({"t_s": 1.0, "surprise": 1})
    rows = list(csv.DictReader(open(tmp_path / "m.csv")))
    assert [r["networked"] for r in rows] == ["3", "2"]

    with MetricsWriter(tmp_path / "m.jsonl") as m:
        m.write({"t_s": 0.0, "tu": math.nan})
    assert json.loads((tmp_path / "m.jsonl").read_text()) == {"t_s": 0.0, "tu": None}

    write_summary(tmp_path / "summary.json", {"tu1": 0.99, "seeds": (1, 2)})
    assert json.loads((tmp_path / "summary.json").read_text()) == {"seeds": [1, 2], "tu1": 0.99}
    assert not (tmp_path / "summary.json.tmp").exists()


def _wait_for(predicate, timeout_s: float = 10.0) -> bool:
    """Wait on a condition (bounded), never assert on elapsed time."""
    import threading

    done = threading.Event()
    for _ in range(int(timeout_s / 0.01)):
        if predicate():
            return True
        done.wait(0.01)
    return predicate()


def test_writes_are_buffered_and_close_writes_everything(tmp_path):
    path = tmp_path / "b.tlog"
    tlog = TlogWriter(path, flush_period_s=3600.0)  # the thread will not flush in this test
    frames = [(1.7e9 + i, bool(i % 2), bytes([0xFD, i % 256, 0, 0])) for i in range(1000)]
    tlog.write_frames(frames[:500])
    for t, _, f in frames[500:]:
        tlog.write(t, f)
    assert path.stat().st_size == 0  # nothing written on the caller's thread
    tlog.close()
    raw = path.read_bytes()
    assert len(raw) == 1000 * 12 and tlog.frames == 1000
    assert raw[:12] == int(1.7e9 * 1e6).to_bytes(8, "big") + bytes([0xFD, 0, 0, 0])
    assert raw[-4:] == bytes([0xFD, 999 % 256, 0, 0])
    tlog.close()  # idempotent
    with pytest.raises(ValueError):
        tlog.write(0.0, b"x")


def test_background_thread_flushes_without_close(tmp_path):
    ev_path, m_path = tmp_path / "e.jsonl", tmp_path / "m.csv"
    events = EventLog(ev_path, flush_period_s=0.02)
    metrics = MetricsWriter(m_path, flush_period_s=0.02)
    try:
        events.write(VehicleLost(0, 3, 12.5, 7.5))
        metrics.write({"t_s": 0.0, "networked": 3})
        # Crash safety: the records reach the file while the writers are still open.
        assert _wait_for(lambda: ev_path.stat().st_size > 0 and m_path.stat().st_size > 0)
        assert json.loads(ev_path.read_text())["sysid"] == 3
        assert m_path.read_text().splitlines() == ["t_s,networked", "0.0,3"]
    finally:
        events.close()
        metrics.close()


def test_order_is_kept_across_flushes(tmp_path):
    path = tmp_path / "o.tlog"
    tlog = TlogWriter(path, flush_period_s=0.001)
    for i in range(20000):
        tlog.write(float(i), b"")
        if i % 5000 == 0:
            tlog.flush()  # flushes from this thread interleave with the background ones
    tlog.close()
    raw = path.read_bytes()
    stamps = [int.from_bytes(raw[k : k + 8], "big") for k in range(0, len(raw), 8)]
    assert stamps == [i * 1_000_000 for i in range(20000)]


def test_jsonable_matches_its_reference_on_events_and_nested_values():
    import dataclasses
    import enum

    import numpy as np

    from gcs.events import BatteryReceived, ModeChanged
    from gcs.records import _jsonable, _jsonable_reference

    class Kind(enum.IntEnum):
        A = 3

    @dataclasses.dataclass
    class Nested:
        xs: tuple
        d: dict
        arr: np.ndarray

    values = [
        BatteryReceived(0, 7, 12.5, "SYS_STATUS", 0.42, 11.1, None),
        BatteryReceived(1, 2, 3.0, "BATTERY_STATUS", None, None, 2.0, 100.0, 60.0, 2),
        ModeChanged(0, 3, 1.0, 4, "GUIDED", "STABILIZE"),
        Nested(
            (1, float("-inf"), "x", None, True), {1: np.float64(2.5), "k": [np.int64(4)]}, np.eye(2)
        ),
        [np.float64("nan"), Kind.A, {"a": (1.5, 2)}],
        np.float32(1.25),
    ]
    for v in values:
        assert _jsonable(v) == _jsonable_reference(v)
        assert json.dumps(_jsonable(v)) == json.dumps(_jsonable_reference(v))

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

    link = StationLink(StationConfig(record_frames=True, unix_time_offset_s=1.7e9))
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
    assert json.loads(line) == {"type": "VehicleLost", "link_id": 0, "sysid": 3, "t_s": 12.5,
                                "last_heartbeat_s": 7.5, "run": "a"}

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

"""CoT parsing and building (XML, TAK protocol v1) and the TAK crew table, in memory with
explicit time: stale is unknown, patterns join, bad input is refused with a reason."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs.cot import CotError, CotStream, cot_xml, parse_cot
from gcs.fleet import MissionOrigin
from gcs.tak import CrewMatch, TakContactReported, TakCrews

ORIGIN = MissionOrigin(-35.36326, 149.16523, 584.0)
T0 = 1_790_000_000.0


def _xml(**kw) -> bytes:
    args = dict(
        uid="ANDROID-a",
        type="a-f-G-U-C",
        lat_deg=-35.36,
        lon_deg=149.17,
        now_unix_s=T0,
        stale_after_s=30.0,
        callsign="ALPHA",
        hae_m=610.5,
        course_deg=90.0,
        speed_m_s=1.5,
    )
    args.update(kw)
    return cot_xml(**args)


def test_xml_round_trip():
    ev = parse_cot(_xml())
    assert ev.uid == "ANDROID-a" and ev.callsign == "ALPHA" and ev.type == "a-f-G-U-C"
    assert ev.lat_deg == pytest.approx(-35.36) and ev.lon_deg == pytest.approx(149.17)
    assert ev.hae_m == pytest.approx(610.5) and ev.course_deg == pytest.approx(90.0)
    assert ev.time_unix_s == pytest.approx(T0) and ev.lifetime_s == pytest.approx(30.0)


def test_unknown_hae_is_none():
    assert parse_cot(_xml(hae_m=None)).hae_m is None


def test_protobuf_mesh_and_stream():
    import takproto

    xml = _xml().decode()
    mesh = bytes(takproto.xml2proto(xml, takproto.TAKProtoVer.MESH))
    stream = bytes(takproto.xml2proto(xml, takproto.TAKProtoVer.STREAM))
    for data in (mesh, stream):
        ev = parse_cot(data)
        assert ev.uid == "ANDROID-a" and ev.callsign == "ALPHA"
        assert ev.lat_deg == pytest.approx(-35.36) and ev.lifetime_s == pytest.approx(30.0)


@pytest.mark.parametrize(
    "data, why",
    [
        (b"", "empty"),
        (b"<event uid='x'", "not well-formed"),
        (b"<foo/>", "not <event>"),
        (b"<event type='a' time='2026-01-01T00:00:00Z' stale='2026-01-01T00:01:00Z'/>", "no uid"),
        (
            b"<event uid='x' time='2026-01-01T00:00:00Z' stale='2026-01-01T00:01:00Z'/>",
            "no <point>",
        ),
        (
            b"<event uid='x' time='yesterday' stale='2026-01-01T00:01:00Z'><point lat='1' "
            b"lon='2'/></event>",
            "not an ISO 8601 time",
        ),
        (
            b"<event uid='x' time='2026-01-01T00:00:00Z' stale='2026-01-01T00:01:00Z'><point "
            b"lat='91' lon='2'/></event>",
            "lat must be in",
        ),
        (
            b"<event uid='x' time='2026-01-01T00:00:00Z' stale='2026-01-01T00:01:00Z'><point "
            b"lat='north' lon='2'/></event>",
            "not a number",
        ),
        (b"<!DOCTYPE x [<!ENTITY a 'b'>]><event/>", "DOCTYPE"),
        (b"\xbf\x01\xbf\xff\xff\xff", "not a TAK protocol v1 message"),
        (b"\xbf\x05ab", "says 5 bytes"),
    ],
)
def test_bad_input_says_why(data, why):
    with pytest.raises(CotError, match=why):
        parse_cot(data)


def test_stream_framing_splits_and_reassembles():
    import takproto

    a, b = _xml(uid="A"), _xml(uid="B")
    c = bytes(takproto.xml2proto(_xml(uid="C").decode(), takproto.TAKProtoVer.STREAM))
    data = b"junk" + a + b + c
    s = CotStream()
    got = []
    for i in range(0, len(data), 7):  # 7-byte pieces: every event is split somewhere
        got += s.feed(data[i : i + 7])
    assert [parse_cot(m).uid for m in got] == ["A", "B", "C"]
    assert s.dropped == 4


def _rep(uid, callsign, north_m, t_s, stale_s, east_m=0.0):
    from planner.geometry import ned_to_geodetic

    lat, lon, _ = ned_to_geodetic(
        np.array([north_m, east_m, 0.0]), ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_amsl_m
    )
    return TakContactReported(
        t_s=t_s,
        uid=uid,
        callsign=callsign,
        lat_deg=float(lat),
        lon_deg=float(lon),
        hae_m=None,
        stale_s=stale_s,
    )


def test_crews_follow_reports_and_stale_is_unknown():
    crews = TakCrews(
        ORIGIN, {0: CrewMatch("Alpha", callsign="alpha"), 2: CrewMatch("Bravo", uid="ANDROID-b")}
    )
    base = np.array([[1.0, 1.0], [5.0, 5.0], [2.0, 2.0]])
    assert np.isnan(crews.fill(base)[[0, 2]]).all() and crews.fill(base)[1, 0] == 5.0
    assert crews.waiting_for() == ("Alpha", "Bravo")
    assert crews.apply(_rep("ANDROID-a", "ALPHA", 80.0, 10.0, 40.0))  # callsign: any case
    assert crews.apply(_rep("ANDROID-b", "B", -50.0, 10.0, 15.0))
    assert not crews.apply(_rep("ANDROID-x", "X", 0.0, 10.0, 40.0))
    pos = crews.fill(base)
    assert pos[0] == pytest.approx([80.0, 0.0], abs=0.01)
    assert pos[2] == pytest.approx([-50.0, 0.0], abs=0.01)
    assert crews.expire(14.9) == []
    assert crews.expire(15.0) == [2]  # Bravo's report held until 15 s
    assert math.isnan(crews.fill(base)[2, 0]) and crews.fill(base)[0, 0] == pytest.approx(80.0)
    crews.apply(_rep("ANDROID-b", "B", -60.0, 20.0, 30.0))  # reports again: known again
    assert crews.fill(base)[2] == pytest.approx([-60.0, 0.0], abs=0.01)
    # An older report than the last one is not applied.
    crews.apply(_rep("ANDROID-b", "B", 0.0, 19.0, 30.0))
    assert crews.fill(base)[2, 0] == pytest.approx(-60.0, abs=0.01)
    assert crews.counters["out_of_order"] == 1 and crews.counters["expired"] == 1


def test_pattern_slots_are_taken_by_new_contacts():
    crews = TakCrews(
        ORIGIN,
        {
            0: CrewMatch("Engine 0", callsign_pattern="ENGINE-*"),
            1: CrewMatch("Engine 1", callsign_pattern="ENGINE-*"),
            2: CrewMatch("Hand", callsign_regex=r"HAND-\d+"),
        },
    )
    assert crews.waiting_for() == ()  # slots never hold up the launch
    assert crews.apply(_rep("u7", "engine-7", 10.0, 1.0, 60.0))
    assert crews.apply(_rep("u9", "ENGINE-9", 20.0, 1.0, 60.0))
    assert not crews.apply(_rep("u3", "ENGINE-3", 30.0, 1.0, 60.0))  # both slots taken
    assert not crews.apply(_rep("h1", "HAND-1x", 30.0, 1.0, 60.0))  # regex: whole callsign
    assert crews.apply(_rep("h2", "HAND-12", 40.0, 1.0, 60.0))
    pos = crews.fill(np.zeros((3, 2)))
    assert pos[:, 0] == pytest.approx([10.0, 20.0, 40.0], abs=0.01)
    assert crews.counters["joined"] == 3
    assert [s.uid for s in crews.states()] == ["u7", "u9", "h2"]


def test_report_stale_on_arrival_is_ignored():
    crews = TakCrews(ORIGIN, {0: CrewMatch("A", uid="a")})
    crews.apply(_rep("a", None, 10.0, 5.0, 5.0))
    assert np.isnan(crews.fill(np.zeros((1, 2)))).all()

"""MAVLink forwarding (gcs.forward): frame splitting and routing in memory, then a real pymavlink
client on a forwarding port during an emulated flight (loopback UDP, port 0)."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest

from gcs.forward import Forwarder, Override, override_of, split_frames
from gcs.wire import mavlink


def _frame(msg, sysid: int, compid: int = 1) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    return bytes(msg.pack(mav))


def _hb():
    return mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)


def _cmd(target: int):
    return mavlink.MAVLink_command_long_message(
        target, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0
    )


class _FakeLink:
    def __init__(self, link_id: int) -> None:
        self.link_id = link_id
        self.taps = []
        self.sent: list[bytes] = []

    def add_tap(self, tap) -> None:
        self.taps.append(tap)

    def send_raw(self, frame: bytes) -> None:
        self.sent.append(frame)


class _FakeOut:
    def __init__(self) -> None:
        self.got: list[bytes] = []
        self.replies: list[tuple[bytes, object]] = []

    def send(self, payload: bytes) -> None:
        self.got.append(payload)

    def reply(self, payload: bytes, source: object) -> None:
        self.replies.append((payload, source))


def test_split_frames_whole_and_cut():
    a, b = _frame(_hb(), 1), _frame(_cmd(2), 254)
    frames, used = split_frames(b"\x00junk" + a + b + b[:5])
    assert frames == [a, b] and used == 5 + len(a) + len(b)


def _forwarder(readonly=False, on_override=None):
    fwd = Forwarder(["udpout:127.0.0.1:9"], readonly=readonly, on_override=on_override)
    links = [_FakeLink(0), _FakeLink(1)]
    for link in links:
        fwd.attach(link)
    out = _FakeOut()
    fwd._outputs.append(out)
    return fwd, links, out


def test_routing_by_target_system_and_broadcast():
    fwd, (l0, l1), out = _forwarder()
    l0.taps[0](_frame(_hb(), 7), ("emu", 0))
    l1.taps[0](_frame(_hb(), 9), ("emu", 1))
    l1.taps[0](_frame(_hb(), 255, 190), ("gcs", 1))  # another 255 GCS on a link: not forwarded
    assert len(out.got) == 2 and fwd.stats["frames_out"] == 2
    fwd.from_output(_frame(_cmd(9), 254), "qgc")
    assert l1.sent and not l0.sent
    fwd.from_output(_frame(_cmd(0), 254), "qgc")  # broadcast: every link
    assert len(l0.sent) == 1 and len(l1.sent) == 2
    fwd.from_output(_frame(_cmd(9), 255), "qgc")  # the station's own sysid: dropped
    assert len(l1.sent) == 2 and fwd.stats["dropped_own_sysid"] == 1


def test_readonly_drops_everything_from_outputs():
    fwd, (l0, l1), out = _forwarder(readonly=True)
    l0.taps[0](_frame(_hb(), 7), ("emu", 0))
    fwd.from_output(_frame(_cmd(7), 254), "qgc")
    fwd.from_output(_frame(_cmd(0), 254), "qgc")
    assert not l0.sent and not l1.sent and fwd.stats["dropped_readonly"] == 2
    assert out.got  # vehicle traffic still goes out


# ------------------------------------------------------------------------------------------------
# Overrides from a forwarded client (issue 26)

C = mavlink


def _long(target: int, command: int, *params: float, compid: int = 1):
    p = list(params) + [0.0] * (7 - len(params))
    return C.MAVLink_command_long_message(target, compid, command, 0, *p)


def _int(target: int, command: int, *params: float):
    p = list(params) + [0.0] * (4 - len(params))
    return C.MAVLink_command_int_message(target, 1, 6, command, 0, 0, *p, 453000000, 70000000, 30.0)


def _item_int(target: int, current: int):
    return C.MAVLink_mission_item_int_message(
        target, 1, 0, 6, C.MAV_CMD_NAV_WAYPOINT, current, 1, 0, 0, 0, 0, 453000000, 70000000, 30.0
    )


#: What QGroundControl and other clients send to take a vehicle, and what they only read.
TAKING = [
    (C.MAVLink_set_mode_message(7, 1, 6), ("SET_MODE", None, 6, None)),  # PX4 / QGC: message
    (_long(7, C.MAV_CMD_DO_SET_MODE, 1, 6), ("COMMAND_LONG", C.MAV_CMD_DO_SET_MODE, 6, None)),
    (_long(7, C.MAV_CMD_NAV_RETURN_TO_LAUNCH), ("COMMAND_LONG", 20, None, None)),
    (_long(7, C.MAV_CMD_NAV_LAND), ("COMMAND_LONG", C.MAV_CMD_NAV_LAND, None, None)),
    (_long(7, C.MAV_CMD_COMPONENT_ARM_DISARM, 0), ("COMMAND_LONG", 400, None, False)),
    (_long(7, C.MAV_CMD_COMPONENT_ARM_DISARM, 1), ("COMMAND_LONG", 400, None, True)),
    (_int(7, C.MAV_CMD_DO_REPOSITION, -1, 1), ("COMMAND_INT", C.MAV_CMD_DO_REPOSITION, None, None)),
    (_item_int(7, 2), ("MISSION_ITEM_INT", None, None, None)),  # ArduPilot guided "go to"
]
READING = [
    C.MAVLink_heartbeat_message(C.MAV_TYPE_GCS, C.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3),
    C.MAVLink_param_request_read_message(7, 1, b"FS_GCS_ENABLE", -1),
    C.MAVLink_param_request_list_message(7, 1),
    C.MAVLink_mission_request_list_message(7, 1, 0),
    C.MAVLink_mission_request_int_message(7, 1, 0, 0),
    _long(7, C.MAV_CMD_REQUEST_MESSAGE, 148),
    _long(7, C.MAV_CMD_SET_MESSAGE_INTERVAL, 33, 200000),
    _item_int(7, 0),  # a mission upload's item
]


def test_override_of_takes_mode_return_land_arm_and_goto_but_not_reads():
    for msg, want in TAKING:
        assert override_of(msg) == want, msg.get_type()
    for msg in READING:
        assert override_of(msg) is None, msg.get_type()


def test_override_names_the_mode_by_the_vehicles_autopilot():
    ov = Override("c", 7, 1, ((0, 7),), "SET_MODE", custom_mode=6)
    assert ov.what(C.MAV_AUTOPILOT_ARDUPILOTMEGA) == "SET_MODE RTL"
    assert ov.what() == "SET_MODE custom_mode 6"
    arm = Override("c", 7, 1, ((0, 7),), "COMMAND_LONG", command=400, arm=False)
    assert arm.what() == "COMPONENT_ARM_DISARM disarm"


def _decode(payload: bytes) -> list:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return [m for m in parser.parse_buffer(payload) or [] if m.get_type() != "BAD_DATA"]


def test_a_refused_override_is_not_routed_and_the_client_is_told_why():
    asked: list[Override] = []
    reason = "phireman: vehicle 7 is flown by the relay plan; hold it on the station first"

    def policy(ov: Override) -> str | None:
        asked.append(ov)
        return reason

    fwd, (l0, l1), out = _forwarder(on_override=policy)
    l0.taps[0](_frame(_hb(), 7), ("emu", 0))
    l1.taps[0](_frame(_hb(), 9), ("emu", 1))
    source = ("udpout:127.0.0.1:9", ("127.0.0.1", 14550))
    fwd.from_output(_frame(_long(7, C.MAV_CMD_DO_SET_MODE, 1, 6), 254, 190), source)
    assert not l0.sent and not l1.sent
    (ov,) = asked
    assert ov.vids == ((0, 7),) and ov.client == "127.0.0.1:14550 sysid 254"
    assert (ov.client_sysid, ov.client_compid) == (254, 190)
    ((payload, to),) = out.replies
    assert to == source and len(out.got) == 2  # to that client only (out.got: 2 heartbeats)
    ack, *texts = _decode(payload)
    assert ack.get_type() == "COMMAND_ACK" and ack.command == C.MAV_CMD_DO_SET_MODE
    assert ack.result == C.MAV_RESULT_DENIED
    assert (ack.target_system, ack.target_component) == (254, 190)
    # As from the vehicle (QGC drops messages of other sysids; matches the ACK by component).
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in (ack, *texts)} == {(7, 1)}
    assert all(t.get_type() == "STATUSTEXT" for t in texts) and len(texts) == 2
    assert all(t.severity == C.MAV_SEVERITY_WARNING for t in texts)
    assert [t.chunk_seq for t in texts] == [0, 1] and texts[0].id == texts[1].id != 0
    assert "".join(t.text for t in texts) == reason
    # A mode change by message (PX4 in QGC) is refused too, without an ACK (it has none).
    fwd.from_output(_frame(C.MAVLink_set_mode_message(9, 1, 6), 254, 190), source)
    assert not l1.sent and [m.get_type() for m in _decode(out.replies[-1][0])] == [
        "STATUSTEXT",
        "STATUSTEXT",
    ]
    # Read-only traffic is never asked about and still reaches the vehicle.
    for msg in READING:
        fwd.from_output(_frame(msg, 254, 190), source)
    assert len(asked) == 2 and len(l0.sent) == len(READING)
    assert fwd.stats["overrides_refused"] == 2 and fwd.stats["overrides_passed"] == 0


def test_a_passed_override_is_routed_to_the_addressed_vehicle():
    asked: list[Override] = []
    fwd, (l0, l1), out = _forwarder(on_override=lambda ov: asked.append(ov))
    l0.taps[0](_frame(_hb(), 7), ("emu", 0))
    l1.taps[0](_frame(_hb(), 9), ("emu", 1))
    fwd.from_output(_frame(_long(9, C.MAV_CMD_NAV_RETURN_TO_LAUNCH), 254), ("x", ("h", 1)))
    assert len(l1.sent) == 1 and not l0.sent and not out.replies
    assert asked[0].vids == ((1, 9),)
    fwd.from_output(_frame(C.MAVLink_set_mode_message(0, 1, 6), 254), ("x", ("h", 1)))
    assert asked[1].vids == ((0, 7), (1, 9))  # a broadcast addresses every vehicle heard
    assert fwd.stats["overrides_passed"] == 2


def test_bad_output_kind_is_refused():
    with pytest.raises(ValueError, match="udpout"):
        Forwarder(["tcp:127.0.0.1:5760"])


# ------------------------------------------------------------------------------------------------
# A real client during an emulated flight


def _small_mission(count=4):
    from mission.format.schema import RunSpec
    from small_mission import crew, small_mission

    return small_mission(
        "fwd",
        RunSpec(duration_s=600.0, seed=2, speedup=4.0),
        count=count,
        tasks=(crew(60.0, 40.0, "Crew"),),
        latency_s=0.01,
    )


class _Flight:
    """An emulated flight (in-process emulator) on its own thread and loop, stopped on demand."""

    def __init__(self, tmp_path, **opts) -> None:
        from mission.flight.runners import FlyOptions
        from mission.view.live import attach

        self.info: dict = {}
        self.stop = threading.Event()
        self.error: BaseException | None = None
        self.result = None
        self.op = None
        """The flight's operator (set at its first poll)."""

        def hook(op, world):
            self.op = op
            if self.stop.is_set():
                op.phase = "done"

        self.opts = FlyOptions(
            emulator_in_process=True,
            out_dir=str(tmp_path / "runs"),
            on_live=self.info.update,
            on_operator=hook,
            attach_view=attach,
            **opts,
        )
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        from mission.flight.runners import fly_emulated_async

        try:
            self.result = asyncio.run(fly_emulated_async(_small_mission(), self.opts))
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            self.error = exc

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(120)


def _client():
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=254, source_component=190)
    return conn, conn.port.getsockname()[1]


def _recv_until(conn, cond, timeout_s: float, what: str):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        m = conn.recv_match(blocking=True, timeout=0.5)
        if m is not None and cond(m):
            return m
    raise AssertionError(f"timed out waiting for {what}")


@pytest.mark.udp
@pytest.mark.parametrize("readonly", [False, True])
def test_client_sees_every_vehicle_and_commands_reach_the_addressed_one(tmp_path, readonly):
    conn, port = _client()
    try:
        with _Flight(
            tmp_path, forward=(f"udpout:127.0.0.1:{port}",), forward_readonly=readonly
        ) as flight:
            seen = {"HEARTBEAT": set(), "GLOBAL_POSITION_INT": set()}

            def every_vehicle(m):
                if m.get_type() in seen and m.get_srcSystem() != 255:
                    seen[m.get_type()].add(m.get_srcSystem())
                return all(s >= {1, 2, 3, 4} for s in seen.values())

            _recv_until(conn, every_vehicle, 90, "HEARTBEAT and GLOBAL_POSITION_INT of 4 vehicles")
            assert seen["HEARTBEAT"] == {1, 2, 3, 4}  # never the station's sysid 255
            conn.mav.command_long_send(
                3, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0
            )

            def acked(m):
                return (
                    m.get_type() == "COMMAND_ACK"
                    and m.command == mavlink.MAV_CMD_REQUEST_MESSAGE
                    and m.target_system == 254
                )

            if not readonly:
                ack = _recv_until(conn, acked, 30, "the addressed vehicle's COMMAND_ACK")
                assert ack.get_srcSystem() == 3
            else:
                # Dropped: no answer while every vehicle's heartbeat comes round several times.
                beats, got_ack = 0, False
                end = time.monotonic() + 60
                while beats < 40 and time.monotonic() < end:
                    m = conn.recv_match(blocking=True, timeout=0.5)
                    if m is None:
                        continue
                    got_ack |= acked(m)
                    beats += m.get_type() == "HEARTBEAT"
                assert beats >= 40 and not got_ack
                fwd = flight.info["forwarder"]
                assert fwd.stats["dropped_readonly"] >= 1 and fwd.stats["routed"] == 0
        assert flight.error is None, flight.error
    finally:
        conn.close()


@pytest.mark.udp
@pytest.mark.parametrize(
    "policy,personality", [("honour", "ardupilot"), ("refuse", "ardupilot"), ("honour", "px4")]
)
def test_a_clients_rtl_during_a_flight_is_honoured_or_refused_never_undone(
    tmp_path, policy, personality
):
    """QGroundControl's RTL through the forward port (a SET_MODE, as QGC sends it for PX4 and a
    MAVProxy ``rtl`` does), during a short emulated ``phireman fly``: honoured, the vehicle stays
    in RTL and the station records who took it; refused, it flies on in the guided mode and the
    client gets the station's STATUSTEXT (and a COMMAND_ACK DENIED for DO_SET_MODE)."""
    from gcs.autopilot import adapter_for

    conn, port = _client()
    try:
        with _Flight(
            tmp_path,
            forward=(f"udpout:127.0.0.1:{port}",),
            forward_overrides=policy,
            serve="127.0.0.1:0",
            personality=personality,
        ) as flight:
            want = 3

            def guided_in_run(m):
                if m.get_type() != "HEARTBEAT" or m.get_srcSystem() != want:
                    return False
                ad = adapter_for(m.autopilot)
                armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                in_run = flight.op is not None and flight.op.phase == "run"
                return in_run and armed and ad.is_guided(m.custom_mode)

            hb = _recv_until(conn, guided_in_run, 120, f"vehicle {want} flying the plan")
            ad = adapter_for(hb.autopilot)
            rtl = ad.mode_number(ad.rtl_mode)
            op = flight.op
            conn.mav.set_mode_send(want, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, rtl)
            if policy == "refuse":
                conn.mav.command_long_send(
                    want, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, rtl, 0, 0, 0, 0, 0
                )
            modes, texts, acks = [], {}, []
            end = time.monotonic() + 60
            while len(modes) < 25 and time.monotonic() < end:
                m = conn.recv_match(blocking=True, timeout=0.5)
                if m is None or m.get_srcSystem() != want:
                    continue
                if m.get_type() == "HEARTBEAT":
                    modes.append(ad.mode_name(m.custom_mode))
                elif m.get_type() == "STATUSTEXT" and m.text.startswith("phireman"):
                    texts[m.id] = m.text
                elif m.get_type() == "STATUSTEXT" and m.id in texts:
                    texts[m.id] += m.text
                elif m.get_type() == "COMMAND_ACK" and m.target_system == 254:
                    acks.append((m.command, m.result))
            assert len(modes) >= 25, "too few heartbeats of the vehicle"
            vid = (0, want)
            if policy == "honour":
                # Once in RTL it stays there (the station never switches it back) ...
                first = modes.index(ad.rtl_mode)
                assert set(modes[first:]) <= {ad.rtl_mode, ad.land_mode}, modes
                assert vid not in [(l, s) for _, l, s in op.reclaimed]
                # ... and the station says who took it, with what.
                assert op.released.get(vid) == "override"
                rec = op.overrides[vid]
                assert rec.source.endswith("sysid 254") and rec.result.startswith(
                    f"SET_MODE {ad.rtl_mode} ("
                )
                label = f"taken by {rec.source}: {rec.result}"
                # The live page says so, on the vehicle and in the event feed.
                frame = _get_json(flight.info["url"] + "api/frame")
                row = frame["v"]["id"].index(f"0:{want}")
                assert frame["v"]["released"][row] == label
                assert any(
                    e["vehicle"] == f"0:{want}"
                    and "OVERRIDE" in e["text"]
                    and rec.source in e["text"]
                    for e in frame["events"]
                )
            else:
                assert ad.rtl_mode not in modes and set(modes) == {ad.guided_mode}, modes
                assert vid not in op.released
                assert list(texts.values())[0] == (
                    f"phireman: vehicle {want} is flown by the relay plan; hold it on the "
                    "station first"
                )
                assert (mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_RESULT_DENIED) in acks
                assert any(a.action == "override-refused" for a in op.actions)
        assert flight.error is None, flight.error
        if policy == "honour":  # the replay of the run says the same (events.jsonl)
            from mission.view.live.replay import ReplaySource

            last = ReplaySource(flight.result.run_dir).frame()
            assert last["v"]["released"][last["v"]["id"].index(f"0:{want}")] == label
    finally:
        conn.close()


def _get_json(url: str) -> dict:
    import json
    import urllib.request

    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


@pytest.mark.udp
@pytest.mark.parametrize("kind", ["udpin", "tcpin"])
def test_a_refusal_goes_to_the_one_client_that_sent_it(kind):
    """udpin / tcpin outputs serve several clients: the refusal reaches only the sender."""
    set_mode = _frame(C.MAVLink_set_mode_message(7, 1, 6), 254)

    async def main():
        fwd = Forwarder([f"{kind}:127.0.0.1:0"], on_override=lambda ov: "phireman: no")
        link = _FakeLink(0)
        fwd.attach(link)
        await fwd.start()
        addr = fwd.addresses[0]
        try:
            if kind == "udpin":
                loop = asyncio.get_running_loop()
                queues = [asyncio.Queue(), asyncio.Queue()]
                socks = []
                for q in queues:

                    class _P(asyncio.DatagramProtocol):
                        def datagram_received(self, data, _addr, q=q):
                            q.put_nowait(data)

                    tr, _ = await loop.create_datagram_endpoint(_P, remote_addr=addr)
                    tr.sendto(_frame(_hb(), 254, 190))  # the forwarder learns its peers
                    socks.append(tr)
                await asyncio.sleep(0.2)
                link.taps[0](_frame(_hb(), 7), ("emu", 0))  # the vehicle is heard by both
                socks[0].sendto(set_mode)
                await asyncio.sleep(0.3)
                got = [b"".join(q.get_nowait() for _ in range(q.qsize())) for q in queues]
                for tr in socks:
                    tr.close()
            else:
                conns = [await asyncio.open_connection(*addr) for _ in range(2)]
                await asyncio.sleep(0.2)
                link.taps[0](_frame(_hb(), 7), ("emu", 0))
                conns[0][1].write(set_mode)
                await conns[0][1].drain()
                await asyncio.sleep(0.3)
                got = []
                for r, w in conns:
                    data = b""
                    while True:
                        try:
                            data += await asyncio.wait_for(r.read(65536), 0.3)
                        except TimeoutError:
                            break
                    got.append(data)
                    w.close()
            return got, link.sent
        finally:
            fwd.close()

    (got_a, got_b), to_vehicle = asyncio.run(main())

    def texts(data):
        return [(m.get_srcSystem(), m.text) for m in _decode(data) if m.get_type() == "STATUSTEXT"]

    assert texts(got_a) == [(7, "phireman: no")]
    assert texts(got_b) == [] and _decode(got_b)  # b hears the vehicle, not a's refusal
    assert set_mode not in to_vehicle

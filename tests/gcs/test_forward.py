"""MAVLink forwarding (gcs.forward): frame splitting and routing in memory, then a real pymavlink
client on a forwarding port during an emulated flight (loopback UDP, port 0)."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest

from gcs.forward import Forwarder, split_frames
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

    def send(self, payload: bytes) -> None:
        self.got.append(payload)


def test_split_frames_whole_and_cut():
    a, b = _frame(_hb(), 1), _frame(_cmd(2), 254)
    frames, used = split_frames(b"\x00junk" + a + b + b[:5])
    assert frames == [a, b] and used == 5 + len(a) + len(b)


def _forwarder(readonly=False):
    fwd = Forwarder(["udpout:127.0.0.1:9"], readonly=readonly)
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

        def hook(op, world):
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

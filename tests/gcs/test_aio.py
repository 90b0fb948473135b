"""The asyncio adapter over real loopback sockets (port 0 only, deadlines, no sleeps)."""

import asyncio

import pytest
from gcs_fakes import FakeAutopilot

from gcs.aio import LinkOpenError, StationAdapter
from gcs.events import CommandAcked
from gcs.link import StationConfig
from gcs.records import TlogWriter
from mavedge.clock import VirtualClock

#: No stream or HOME_POSITION requests: these tests check exact command sequences.
_CFG = StationConfig(stream_rates_hz=(), request_home_position=False)

pytestmark = pytest.mark.udp


class _Vehicle(asyncio.DatagramProtocol):
    def __init__(self):
        self.ap = FakeAutopilot(sysid=1)
        self.inbox: asyncio.Queue = asyncio.Queue()

    def connection_made(self, transport):
        self.transport = transport

    def datagram_received(self, data, addr):
        for m in self.ap.decode(data):
            self.inbox.put_nowait((m, addr))


async def _next(queue, kind, timeout_s=5.0):
    async def get():
        while True:
            item = await queue.get()
            m = item[0] if isinstance(item, tuple) else item
            name = m.get_type() if hasattr(m, "get_type") else type(m).__name__
            if name == kind:
                return item

    return await asyncio.wait_for(get(), timeout_s)


def test_udpout_station_discovers_commands_and_records(tmp_path):
    async def main():
        loop = asyncio.get_running_loop()
        transport, vehicle = await loop.create_datagram_endpoint(
            _Vehicle, local_addr=("127.0.0.1", 0)
        )
        host, port = transport.get_extra_info("sockname")
        tlog = TlogWriter(tmp_path / "aio.tlog")
        station = await StationAdapter(f"udpout:{host}:{port}", _CFG, tlog=tlog).start()
        try:
            hb, gcs_addr = await _next(vehicle.inbox, "HEARTBEAT")  # udpout heartbeats first
            assert hb.type == 6 and hb.get_srcSystem() == 255
            transport.sendto(vehicle.ap.heartbeat(4), gcs_addr)
            assert (await _next(station.events, "VehicleDiscovered")).sysid == 1
            transport.sendto(vehicle.ap.global_position(47.5, 8.0, 500, 12.34), gcs_addr)
            tel = await _next(station.events, "TelemetryReceived")
            assert tel.rel_alt_m == 12.34
            station.core.arm(1, station.now())
            station.transmit()
            cmd, _ = await _next(vehicle.inbox, "COMMAND_LONG")
            assert cmd.command == 400
            transport.sendto(vehicle.ap.ack(400), gcs_addr)
            assert isinstance(await _next(station.events, "CommandAcked"), CommandAcked)
        finally:
            station.close()
            transport.close()
            tlog.close()
        assert tlog.frames >= 6

    asyncio.run(main())


def test_tcp_client_stream_reassembles_split_frames():
    async def main():
        ap = FakeAutopilot(sysid=2, autopilot=12)
        got: asyncio.Queue = asyncio.Queue()
        writers = []

        async def vehicle(reader, writer):
            writers.append(writer)
            data = ap.heartbeat(393216) + ap.global_position(47.0, 8.0, 400.0, 5.0)
            writer.write(data[:7])  # a frame split across TCP segments
            await writer.drain()
            writer.write(data[7:])
            while chunk := await reader.read(4096):
                for m in ap.decode(chunk):
                    got.put_nowait(m)

        server = await asyncio.start_server(vehicle, "127.0.0.1", 0)
        host, port = server.sockets[0].getsockname()[:2]
        station = await StationAdapter(f"tcp:{host}:{port}", _CFG).start()
        try:
            ev = await _next(station.events, "VehicleDiscovered")
            assert (ev.sysid, ev.mode) == (2, "OFFBOARD")
            await _next(station.events, "TelemetryReceived")
            assert (await _next(got, "HEARTBEAT")).type == 6
        finally:
            station.close()
            server.close()
            for w in writers:
                w.close()
                await asyncio.wait_for(w.wait_closed(), 5.0)

    asyncio.run(main())


def test_tcp_client_reconnects_when_the_server_restarts():
    """SITL restarted on its TCP port: the station reconnects, drops the old stream's partial
    frame and hears the vehicle again (events, no fixed sleeps: every wait has a deadline)."""

    async def main():
        ap = FakeAutopilot(sysid=3)
        sessions: asyncio.Queue = asyncio.Queue()

        async def vehicle(reader, writer):
            n = sessions.qsize()
            if n == 0:  # first life: a heartbeat, then half a frame, then the process dies
                writer.write(ap.heartbeat(4) + ap.global_position(47.0, 8.0, 400.0, 5.0)[:9])
            else:  # after the restart: a whole new stream
                writer.write(ap.heartbeat(6) + ap.global_position(47.0, 8.0, 400.0, 5.0))
            await writer.drain()
            sessions.put_nowait(writer)
            if n == 0:
                writer.close()
                return
            while await reader.read(4096):
                pass

        server = await asyncio.start_server(vehicle, "127.0.0.1", 0)
        host, port = server.sockets[0].getsockname()[:2]
        station = await StationAdapter(f"tcp:{host}:{port}", _CFG, reconnect_s=(0.05, 0.2)).start()
        try:
            ev = await _next(station.events, "VehicleDiscovered")
            assert (ev.sysid, ev.mode) == (3, "GUIDED")
            tel = await _next(station.events, "TelemetryReceived")  # only after the reconnect
            assert station.reconnects == 1 and sessions.qsize() == 2
            assert tel.rel_alt_m == pytest.approx(5.0)
            assert station.core.vehicle(3).mode == "RTL"  # the new stream's heartbeat
            assert station.core.stats.decode.bad_data == 0  # the cut frame was never glued on
        finally:
            station.close()
            server.close()
            while not sessions.empty():
                w = sessions.get_nowait()
                w.close()

    asyncio.run(main())


async def _free_tcp_port() -> int:
    """A port nothing listens on (bound on port 0 by the kernel, then released)."""
    server = await asyncio.start_server(lambda r, w: None, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    server.close()
    await server.wait_closed()
    return port


def test_tcp_server_not_up_at_start_is_retried_in_the_background():
    """SITL not started yet: start() succeeds with the link down (LinkDown, once), connects when
    the server comes up (LinkUp) and hears the vehicle; never fatal."""

    async def main():
        port = await _free_tcp_port()
        link_events: list = []
        station_events: list = []
        station = await StationAdapter(
            f"tcp:127.0.0.1:{port}",
            _CFG,
            reconnect_s=(0.02, 0.05),
            on_event=station_events.append,
            on_link_event=link_events.append,
        ).start()
        ap = FakeAutopilot(sysid=6)
        up = asyncio.Event()
        server = None
        try:
            assert not station.connected and "Connection refused" in station.down_reason
            assert [type(e).__name__ for e in link_events] == ["LinkDown"]
            assert "\n" not in link_events[0].reason and str(port) in link_events[0].reason
            station.transmit()  # sending while down: dropped, no error

            async def vehicle(reader, writer):
                writer.write(ap.heartbeat(4))
                await writer.drain()
                up.set()
                while await reader.read(4096):
                    pass
                writer.close()

            server = await asyncio.start_server(vehicle, "127.0.0.1", port)
            await asyncio.wait_for(up.wait(), 5.0)
            while not any(type(e).__name__ == "VehicleDiscovered" for e in station_events):
                await asyncio.sleep(0.01)
            assert station.connected and station.reconnects == 1
            assert [type(e).__name__ for e in link_events] == ["LinkDown", "LinkUp"]
            # Link events never reach on_event (its consumers expect vehicles, with a sysid).
            assert all(hasattr(e, "sysid") for e in station_events)
        finally:
            station.close()
            if server is not None:
                server.close()

    asyncio.run(asyncio.wait_for(main(), 20.0))


def test_udpin_address_in_use_is_a_one_line_error():
    async def main():
        loop = asyncio.get_running_loop()
        taken, _ = await loop.create_datagram_endpoint(
            asyncio.DatagramProtocol, local_addr=("127.0.0.1", 0)
        )
        port = taken.get_extra_info("sockname")[1]
        try:
            with pytest.raises(LinkOpenError) as info:
                await StationAdapter(f"udpin:127.0.0.1:{port}", _CFG).start()
        finally:
            taken.close()
        return info.value

    exc = asyncio.run(main())
    msg = str(exc)
    assert isinstance(exc, OSError) and "\n" not in msg
    assert "cannot listen on 127.0.0.1" in msg and "in use" in msg


def test_udpin_is_up_at_once():
    async def main():
        station = await StationAdapter("udpin:127.0.0.1:0", _CFG).start()
        try:
            assert station.connected
            ev = await asyncio.wait_for(station.events.get(), 5.0)
            assert type(ev).__name__ == "LinkUp" and ev.connection == "udpin:127.0.0.1:0"
        finally:
            station.close()

    asyncio.run(main())


def test_steady_incoming_traffic_does_not_starve_the_station_timers():
    # A vehicle that streams (PX4: ~300 frames/s) calls transmit() on every datagram. Re-arming
    # the timer on each call cancelled it before it could run (asyncio runs an iteration's I/O
    # callbacks before the timers that fell due): heartbeats and setpoints stopped while frames
    # kept arriving. The core clock here is explicit: 0.01 s per datagram, 4 s in all.
    async def main():
        loop = asyncio.get_running_loop()
        transport, vehicle = await loop.create_datagram_endpoint(
            _Vehicle, local_addr=("127.0.0.1", 0)
        )
        host, port = transport.get_extra_info("sockname")
        now = [0.0]
        station = await StationAdapter(f"udpout:{host}:{port}", _CFG, clock=lambda: now[0]).start()
        try:
            _, gcs_addr = await _next(vehicle.inbox, "HEARTBEAT")
            beats = 0
            for _ in range(400):
                now[0] += 0.01
                transport.sendto(vehicle.ap.heartbeat(4), gcs_addr)  # one every loop iteration
                await asyncio.sleep(0)
                while not vehicle.inbox.empty():
                    m, _ = vehicle.inbox.get_nowait()
                    beats += m.get_type() == "HEARTBEAT"
        finally:
            station.close()
            transport.close()
        assert beats >= 3, beats  # 1 Hz over 4 s of core time (the first one was taken above)

    asyncio.run(main())


def test_station_on_a_clock_follows_its_time_and_unix_anchor():
    # A mavedge Clock carries the core's time, the wall delay of its timers and the Unix anchor
    # of signatures and .tlog stamps. A VirtualClock: nothing is due until the test moves time.
    async def main():
        loop = asyncio.get_running_loop()
        transport, vehicle = await loop.create_datagram_endpoint(
            _Vehicle, local_addr=("127.0.0.1", 0)
        )
        host, port = transport.get_extra_info("sockname")
        clock = VirtualClock(10.0, unix_time_at_zero_s=1.75e9)
        station = await StationAdapter(f"udpout:{host}:{port}", _CFG, clock=clock).start()
        try:
            assert station.now() == 10.0
            assert station.core.config.unix_time_at_zero_s == 1.75e9
            await _next(vehicle.inbox, "HEARTBEAT")  # the first one, at start
            beats = 0
            for _ in range(3):  # 1 Hz in clock time: one heartbeat per second moved
                clock.advance(1.0)
                station.transmit()
                await _next(vehicle.inbox, "HEARTBEAT")
                beats += 1
            assert station.now() == 13.0
        finally:
            station.close()
            transport.close()
        assert beats == 3

    asyncio.run(main())


def test_a_clock_brings_its_own_speedup():
    with pytest.raises(ValueError, match="time_scale"):
        StationAdapter("udpout:127.0.0.1:14550", _CFG, clock=VirtualClock(), time_scale=10.0)


def test_a_timer_wakeup_before_the_cores_deadline_skips_the_scan():
    # A paced clock can lag the wall-time estimate the timer was armed with: a wake-up before
    # the core's next_timer_s() re-arms without handle_timer (nothing is due by its contract);
    # one at or after it runs handle_timer.
    async def main():
        clock = VirtualClock(5.0)
        station = await StationAdapter("udpout:127.0.0.1:9", _CFG, clock=clock).start()
        calls = []
        orig = station.core.handle_timer
        station.core.handle_timer = lambda now_s: (calls.append(now_s), orig(now_s))
        try:
            station._on_timer()  # the first heartbeat is due at start
            assert calls == [5.0] and station.early_wakeups == 0
            due = station.core.next_timer_s()
            assert due is not None and due > clock.now()
            station._on_timer()  # early: the clock did not reach the deadline
            assert calls == [5.0] and station.early_wakeups == 1
            clock.advance(due - clock.now())
            station._on_timer()
            assert calls == [5.0, due] and station.early_wakeups == 1
        finally:
            station.close()

    asyncio.run(main())


def test_drain_reads_every_queued_datagram_before_the_loop_runs():
    # Under lock-step the station's loop drains its sockets before it acknowledges a time
    # (mission/flight/station_loop.py): 50 vehicles' heartbeats sent while the loop does not run
    # are all read by one drain, not one a loop iteration.
    import socket

    async def main():
        station = await StationAdapter("udpin:127.0.0.1:0", _CFG).start()
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            aps = [FakeAutopilot(sysid=s) for s in range(1, 51)]
            for ap in aps:
                sender.sendto(ap.heartbeat(4), station.local_address[:2])
            assert station.drain() == 50
            assert (station.drained, station.drained_max) == (50, 50)
            assert station.drain() == 0
            found = set()
            while not station.events.empty():
                e = station.events.get_nowait()
                if type(e).__name__ == "VehicleDiscovered":
                    found.add(e.sysid)
            assert found == set(range(1, 51))
        finally:
            sender.close()
            station.close()

    asyncio.run(main())

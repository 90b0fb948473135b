"""Serial links on a pseudo-terminal pair: the station opens the pty's slave as ``DEVICE,BAUD``
(the path the CLI's --connect takes), a fake autopilot speaks MAVLink on the master fd.

Real I/O but no network, no fixed ports and no sleeps: every wait is on an event, bounded by
``asyncio.wait_for``.
"""

from __future__ import annotations

import asyncio
import os

import pytest
from gcs_fakes import FakeAutopilot
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.aio import SerialLinkError, StationAdapter, _SerialPort, open_links
from gcs.connection import parse_connection
from gcs.link import StationConfig

#: No stream or HOME_POSITION requests: these tests check exact command sequences.
_CFG = StationConfig(stream_rates_hz=(), request_home_position=False)

pytestmark = [
    pytest.mark.skipif(
        not hasattr(os, "openpty") or os.name != "posix",
        reason="needs os.openpty (POSIX pseudo-terminals)",
    ),
    pytest.mark.timeout(30),  # a regression to blocking I/O must fail, not hang the suite
]

WAIT_S = 5.0


class _Master:
    """The vehicle's end of the pty: bytes out with os.write, frames in through add_reader."""

    def __init__(self, fd: int, ap: FakeAutopilot) -> None:
        self.fd, self.ap = fd, ap
        self.inbox: asyncio.Queue = asyncio.Queue()
        os.set_blocking(fd, False)

    def start(self) -> None:
        asyncio.get_running_loop().add_reader(self.fd, self._readable)

    def stop(self) -> None:
        asyncio.get_running_loop().remove_reader(self.fd)

    def _readable(self) -> None:
        try:
            data = os.read(self.fd, 65536)
        except (BlockingIOError, OSError):
            return
        for m in self.ap.decode(data):
            self.inbox.put_nowait(m)

    def send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:  # small writes: the pty takes them whole
            view = view[os.write(self.fd, view) :]


async def _next(queue: asyncio.Queue, kind: str, timeout_s: float = WAIT_S):
    async def get():
        while True:
            item = await queue.get()
            name = item.get_type() if hasattr(item, "get_type") else type(item).__name__
            if name == kind:
                return item

    return await asyncio.wait_for(get(), timeout_s)


@pytest.fixture
def pty():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    yield master, path
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


def test_station_flies_a_serial_link_on_a_pty(pty):
    master_fd, path = pty

    async def main():
        ap = FakeAutopilot(
            sysid=1,
            compid=1,
            autopilot=mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
            vehicle_type=mav.MAV_TYPE_QUADROTOR,
        )
        master = _Master(master_fd, ap)
        # The CLI's path: connection string -> StationAdapter(...).start() (open_links here).
        [station] = await open_links([f"{path},57600"], _CFG)
        chunks: asyncio.Queue = asyncio.Queue()
        receive = station.receive

        def spy(data, addr):  # observe each read the adapter makes
            chunks.put_nowait(len(data))
            receive(data, addr)

        station.receive = spy
        master.start()
        try:
            assert station.spec.kind == "serial" and station.spec.baud == 57600
            # The station heartbeats the serial peer before hearing anything.
            hb = await _next(master.inbox, "HEARTBEAT")
            assert (hb.get_srcSystem(), hb.type) == (255, mav.MAV_TYPE_GCS)
            assert hb.autopilot == mav.MAV_AUTOPILOT_INVALID

            # One heartbeat split across two reads: the first part must be consumed on its own
            # before the rest is written, so the stream decoder has to carry the partial frame.
            frame = ap.heartbeat(custom_mode=4)  # GUIDED
            master.send(frame[:7])
            got = 0
            while got < 7:
                got += await asyncio.wait_for(chunks.get(), WAIT_S)
            assert got == 7
            master.send(frame[7:] + ap.global_position(47.5, 8.25, 512.5, 12.34))

            ev = await _next(station.events, "VehicleDiscovered")
            assert (ev.sysid, ev.autopilot, ev.vehicle_type) == (
                1,
                mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                mav.MAV_TYPE_QUADROTOR,
            )
            assert ev.mode == "GUIDED"
            tel = await _next(station.events, "TelemetryReceived")
            assert tel.sysid == 1
            assert tel.lat_deg == pytest.approx(47.5, abs=1e-7)
            assert tel.rel_alt_m == pytest.approx(12.34, abs=1e-3)
            assert station.core.stats.decode.truncated == 0

            # Commands go back down the same wire.
            station.core.arm(1, station.now())
            station.transmit()
            cmd = await _next(master.inbox, "COMMAND_LONG")
            assert (cmd.command, cmd.target_system) == (mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        finally:
            master.stop()
            station.close()
        station.close()  # idempotent

    asyncio.run(main())


def test_hangup_closes_the_port_once_without_spinning(pty):
    master_fd, path = pty

    async def main():
        loop = asyncio.get_running_loop()
        errors = []
        loop.set_exception_handler(lambda _loop, ctx: errors.append(ctx))
        lost = loop.create_future()
        port = _SerialPort.open(
            parse_connection(f"{path},115200"),
            loop,
            lambda data: None,
            on_lost=lambda why: lost.set_result(why),
        )
        os.close(master_fd)  # the radio is unplugged
        why = await asyncio.wait_for(lost, WAIT_S)
        assert why
        assert port.closed
        port.write(b"\xfd" * 20)  # after a hang-up: dropped, no exception
        assert port.frames_dropped == 1
        port.close()  # no PortNotOpenError from a second close
        assert errors == []  # no callback raising in a loop

    asyncio.run(main())


def test_writes_never_block_and_drop_whole_frames(pty):
    """The vehicle stops reading: the station's writes return at once, the backlog stays near a
    second at the baud rate, and what does arrive later is whole frames in order."""
    master_fd, path = pty

    async def main():
        loop = asyncio.get_running_loop()
        port = _SerialPort.open(parse_connection(f"{path},57600"), loop, lambda data: None)
        ap = FakeAutopilot(sysid=9)
        frames = [ap.statustext(f"frame {i:05d}".ljust(50, ".")) for i in range(4000)]
        # Nobody reads the pty while these ~320 kB (far more than it holds) are written: a write
        # that blocked would never return (the timeout mark then fails the test), so no clock is
        # needed. The port's descriptor must be non-blocking, and the writes return with the
        # excess dropped as whole frames, the rest queued within the limit.
        assert port._fd is not None and not os.get_blocking(port._fd)
        for f in frames:
            port.write(f)
        assert port.frames_dropped > 0
        assert 0 < port.tx_pending_bytes <= port.tx_limit_bytes
        sent = len(frames) - port.frames_dropped

        master = _Master(master_fd, FakeAutopilot())
        master.start()
        try:
            texts = []
            while len(texts) < sent:
                m = await _next(master.inbox, "STATUSTEXT")
                texts.append(m.text)
            assert port.tx_pending_bytes == 0
            # Drops are whole frames at the tail (no loop turn while writing): the first `sent`.
            assert [int(t.split()[1].rstrip(".")) for t in texts] == list(range(sent))
            assert master.ap.parser.total_receive_errors == 0  # no frame was cut
        finally:
            master.stop()
            port.close()

    asyncio.run(main())


def test_missing_device_is_waited_for_with_a_one_line_reason(tmp_path):
    """A USB radio not plugged in yet: start() succeeds, the link is down with a one-line
    reason, and it is retried (see test_device_plugged_in_later_and_replugged)."""
    path = tmp_path / "ttyNOPE"

    async def main():
        station = await StationAdapter(f"{path},57600", _CFG, reconnect_s=(0.05, 0.1)).start()
        try:
            ev = await _next(station.events, "LinkDown")
            assert not station.connected and station.core is not None
            return ev
        finally:
            station.close()

    ev = asyncio.run(main())
    assert ev.link_id == 0 and ev.connection == f"{path},57600"
    assert "\n" not in ev.reason and str(path) in ev.reason
    assert "No such file or directory" in ev.reason and ev.reason.count("Errno") == 0


def test_device_plugged_in_later_and_replugged(tmp_path):
    """The device path appears after start (a symlink, as udev's /dev/serial/by-id names are),
    the vehicle is heard; the radio is unplugged (hang-up) and plugged in again (a new pty):
    the station reopens it and hears the vehicle again."""
    link = tmp_path / "ttyRADIO"

    async def main():
        station = await StationAdapter(f"{link},57600", _CFG, reconnect_s=(0.02, 0.05)).start()
        ptys = []
        try:
            await _next(station.events, "LinkDown")
            for life in range(2):
                master_fd, slave_fd = os.openpty()
                ptys += [master_fd, slave_fd]
                tmp = tmp_path / f"ttyRADIO.{life}"
                os.symlink(os.ttyname(slave_fd), tmp)
                os.replace(tmp, link)  # plugged in
                await _next(station.events, "LinkUp")
                assert station.connected and station.reconnects == life + 1
                master = _Master(master_fd, FakeAutopilot(sysid=4 + life))
                master.start()
                # The station heartbeats the new port by itself (a static peer) ...
                assert (await _next(master.inbox, "HEARTBEAT")).get_srcSystem() == 255
                master.send(master.ap.heartbeat(4))  # ... and hears what comes up it.
                assert (await _next(station.events, "VehicleDiscovered")).sysid == 4 + life
                master.stop()
                if life == 0:  # unplugged: the hang-up takes the link down, once
                    os.close(master_fd)
                    os.close(slave_fd)
                    ptys.clear()
                    down = await _next(station.events, "LinkDown")
                    assert "lost" in down.reason and not station.connected
        finally:
            station.close()
            for fd in ptys:
                os.close(fd)

    asyncio.run(main())


def test_a_regular_file_is_not_a_serial_port(tmp_path):
    path = tmp_path / "notatty"
    path.write_bytes(b"")

    async def main():
        with pytest.raises(SerialLinkError, match="notatty"):
            await StationAdapter(f"{path},57600").start()

    asyncio.run(main())


def test_without_pyserial_the_error_is_clear_and_an_oserror(monkeypatch, tmp_path):
    import sys

    monkeypatch.setitem(sys.modules, "serial", None)  # import serial -> ImportError

    async def main():
        with pytest.raises(SerialLinkError, match="pyserial") as info:
            await StationAdapter(f"{tmp_path / 'tty'},57600").start()
        assert isinstance(info.value, OSError) and isinstance(info.value, RuntimeError)

    asyncio.run(main())


@pytest.mark.parametrize(
    "text, device, baud",
    [
        (
            "/dev/serial/by-path/pci-0000:00:14.0-usb-0:2:1.0-port0",
            "/dev/serial/by-path/pci-0000:00:14.0-usb-0:2:1.0-port0",
            115200,
        ),
        (
            "/dev/serial/by-path/pci-0000:00:14.0-usb-0:2:1.0-port0,57600",
            "/dev/serial/by-path/pci-0000:00:14.0-usb-0:2:1.0-port0",
            57600,
        ),
        (
            "/dev/serial/by-path/pci-0000:00:14.0-usb-0:2:1.0:921600",
            "/dev/serial/by-path/pci-0000:00:14.0-usb-0:2:1.0",
            921600,
        ),
        ("/dev/ttyUSB0:57600", "/dev/ttyUSB0", 57600),
    ],
)
def test_device_paths_with_colons(text, device, baud):
    spec = parse_connection(text)
    assert (spec.kind, spec.device, spec.baud) == ("serial", device, baud)

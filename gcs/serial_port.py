"""A serial port on the station's event loop (:class:`_SerialPort`, used by
:class:`gcs.aio.StationAdapter` for ``/dev/tty...,BAUD`` links) and the one-line error a port
that cannot be opened raises (:class:`SerialLinkError`).
"""

from __future__ import annotations

import asyncio
import errno
import logging
import os
from collections.abc import Callable
from typing import Any

from gcs.connection import ConnectionSpec

__all__ = ["SerialLinkError"]

#: Serial-port lines keep the logger they always had (the adapter's).
log = logging.getLogger("gcs.aio")


class SerialLinkError(OSError, RuntimeError):
    """A serial link that cannot be opened (also a RuntimeError, as before pyserial was a
    dependency); the message names the device and the reason in one line. ``retryable``: the
    device may appear later (absent, busy, I/O error), so the station waits for it rather than
    fail."""

    retryable: bool = False


#: Errors opening a serial device that go away by themselves: not plugged in yet (ENOENT,
#: ENODEV, ENXIO), another program or ModemManager probing it (EBUSY), a device mid-reset.
_SERIAL_RETRY_ERRNOS = frozenset(
    {errno.ENOENT, errno.ENODEV, errno.ENXIO, errno.EBUSY, errno.EIO, errno.EAGAIN, errno.EINTR}
)


class _SerialPort:
    """A serial port on the event loop (POSIX): pyserial opens and configures it (baud, raw mode),
    then the file descriptor is read with ``loop.add_reader`` and written without blocking.

    Writes come one whole MAVLink frame at a time. What the kernel does not take at once is kept
    in order and flushed by ``loop.add_writer``; when about a second of backlog at the port's baud
    rate is already waiting, further frames are dropped whole (never cut), as a radio link drops
    them -- the station retries commands, and a stale setpoint queued for seconds helps no-one.
    A hang-up (USB unplugged, the other end of a pty closed) is logged once and closes the port;
    the station then sees its vehicles time out.
    """

    READ_CHUNK_BYTES = 65536

    def __init__(
        self,
        port: Any,
        loop: asyncio.AbstractEventLoop,
        on_data: Callable[[bytes], None],
        *,
        name: str,
        baud: int,
        link_id: int = 0,
        on_lost: Callable[[str], None] | None = None,
    ) -> None:
        self._port = port
        self._fd: int | None = port.fileno()
        self._loop = loop
        self._on_data = on_data
        self._on_lost = on_lost
        self.name = name
        self.link_id = link_id
        self.tx_limit_bytes = max(4096, baud // 10)  # ~1 s at 8N1 (10 bits a byte)
        self._tx = bytearray()
        self.frames_dropped = 0
        os.set_blocking(self._fd, False)
        loop.add_reader(self._fd, self._readable)

    @classmethod
    def open(
        cls,
        spec: ConnectionSpec,
        loop: asyncio.AbstractEventLoop,
        on_data: Callable[[bytes], None],
        *,
        link_id: int = 0,
        on_lost: Callable[[str], None] | None = None,
    ) -> _SerialPort:
        if os.name != "posix":
            raise SerialLinkError(
                f"{spec.text!r}: serial links are supported on Linux and macOS "
                "only (they need the event loop's add_reader)"
            )
        try:
            import serial
        except ImportError:
            raise SerialLinkError(
                f"{spec.text!r}: serial links need pyserial (pip install 'pyserial>=3.5')"
            ) from None
        try:
            port = serial.Serial(spec.device, spec.baud, timeout=0)
        except (OSError, ValueError) as exc:  # SerialException is an OSError
            err = SerialLinkError(_serial_open_reason(spec, exc))
            err.retryable = getattr(exc, "errno", None) in _SERIAL_RETRY_ERRNOS
            raise err from exc
        assert spec.device is not None and spec.baud is not None  # a serial spec has both
        try:
            return cls(
                port,
                loop,
                on_data,
                name=spec.device,
                baud=spec.baud,
                link_id=link_id,
                on_lost=on_lost,
            )
        except BaseException:
            port.close()
            raise

    @property
    def closed(self) -> bool:
        return self._fd is None

    @property
    def tx_pending_bytes(self) -> int:
        return len(self._tx)

    def _readable(self) -> None:
        if self._fd is None:
            return
        try:
            data = os.read(self._fd, self.READ_CHUNK_BYTES)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # EIO: hang-up
            self._lost(exc.strerror or str(exc))
            return
        if not data:
            self._lost("end of file")
            return
        self._on_data(data)

    def write(self, data: bytes) -> None:
        if self._fd is None:
            self.frames_dropped += 1
            return
        if self._tx:  # keep order behind what is already waiting
            if len(self._tx) + len(data) > self.tx_limit_bytes:
                self.frames_dropped += 1
                log.debug(
                    "link %d: %s backlog full (%d bytes): frame dropped",
                    self.link_id,
                    self.name,
                    len(self._tx),
                )
            else:
                self._tx += data
            return
        n = self._write_now(data)
        if n is not None and n < len(data):
            self._tx += data[n:]
            self._loop.add_writer(self._fd, self._writable)

    def _write_now(self, data: bytes | bytearray) -> int | None:
        """Bytes the kernel took at once (0 if it would block); None if the port was lost."""
        assert self._fd is not None  # both callers return early on a closed port
        try:
            return os.write(self._fd, data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError as exc:
            self._lost(exc.strerror or str(exc))
            return None

    def _writable(self) -> None:
        if self._fd is None:
            return
        n = self._write_now(self._tx)
        if n is None:
            return
        del self._tx[:n]
        if not self._tx:
            self._loop.remove_writer(self._fd)

    def _lost(self, why: str) -> None:
        log.warning("link %d: serial port %s lost (%s); closing it", self.link_id, self.name, why)
        self.close()
        if self._on_lost is not None:
            self._on_lost(why)

    def close(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        self._loop.remove_reader(fd)
        self._loop.remove_writer(fd)
        self._tx.clear()
        try:
            self._port.close()
        except OSError as exc:
            log.debug("link %d: closing %s: %s", self.link_id, self.name, exc)


def _serial_open_reason(spec: ConnectionSpec, exc: BaseException) -> str:
    """One line: which device, why (without pyserial's doubled ``[Errno N] ... [Errno N]``)."""
    code = getattr(exc, "errno", None)
    if isinstance(code, int) and code > 0:
        reason = os.strerror(code)
        if code in (errno.EACCES, errno.EPERM):
            reason += " (on Linux: is the user in the 'dialout' group?)"
        elif code == errno.EBUSY:
            reason += " (another program has the port open?)"
    else:
        reason = str(exc) or type(exc).__name__
    return f"serial device {spec.device!r} at {spec.baud} baud: {reason}"

"""Connection strings as MAVProxy / pymavlink (and MAVSDK) users write them.

Accepted forms (docs/design/mavlink.md §1.8; pymavlink ``mavutil.mavlink_connection``):

==========================  ===========================================================
``udpin:HOST:PORT``         listen on HOST:PORT (``0.0.0.0:14550`` is the usual GCS port)
``udp:HOST:PORT``           same as ``udpin`` (pymavlink's default for ``udp:``)
``udpout:HOST:PORT``        send to HOST:PORT from an ephemeral port
``tcp:HOST:PORT``           connect to a TCP server (SITL ``tcp:127.0.0.1:5760``)
``tcpin:HOST:PORT``         listen for one TCP client
``DEVICE,BAUD``             serial, e.g. ``/dev/ttyUSB0,57600`` or ``COM3,57600``
``DEVICE:BAUD``             serial, the same with a colon (BAUD digits; else all is DEVICE)
``DEVICE``                  serial at the default baud (115200, as mavutil)
``HOST:PORT``               no scheme: ``udpin`` (as mavutil)
``udpin://H:P`` etc.        MAVSDK style; ``serial://DEV:BAUD``
==========================  ===========================================================
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["ConnectionSpec", "parse_connection", "DEFAULT_BAUD"]

DEFAULT_BAUD = 115200
_KINDS = ("udpin", "udpout", "tcp", "tcpin", "serial")
_SCHEMES = {
    "udp": "udpin",
    "udpin": "udpin",
    "udpout": "udpout",
    "tcp": "tcp",
    "tcpin": "tcpin",
    "serial": "serial",
}
_UNSUPPORTED = {"udpbcast", "udpcast", "mcast", "ws", "wss", "wsserver"}
_WINDOWS_COM = re.compile(r"^COM\d+$", re.IGNORECASE)


@dataclass(frozen=True)
class ConnectionSpec:
    """A parsed connection string."""

    kind: str
    """One of ``udpin``, ``udpout``, ``tcp``, ``tcpin``, ``serial``."""
    host: str | None = None
    port: int | None = None
    device: str | None = None
    baud: int | None = None
    text: str = ""
    """The string as given (for messages and logs)."""

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ValueError(f"connection kind must be one of {_KINDS}, got {self.kind!r}")

    @property
    def address(self) -> tuple[str, int]:
        if self.host is None or self.port is None:
            raise ValueError(f"{self.text!r} is a serial connection and has no network address")
        return (self.host, self.port)


def _port(text: str, value: str) -> int:
    if not value.isdigit():
        raise ValueError(f"bad connection string {text!r}: port {value!r} is not a number")
    port = int(value)
    if not 0 <= port <= 65535:
        raise ValueError(f"bad connection string {text!r}: port {port} is outside 0..65535")
    return port


def _baud(text: str, value: str) -> int:
    if not value.isdigit() or int(value) <= 0:
        raise ValueError(
            f"bad connection string {text!r}: baud rate {value!r} is not a positive integer"
        )
    return int(value)


def _host_port(text: str, rest: str, kind: str) -> ConnectionSpec:
    if rest.startswith("["):  # [IPv6]:port
        host, sep, tail = rest[1:].partition("]")
        if not sep or not tail.startswith(":"):
            raise ValueError(f"bad connection string {text!r}: expected [IPV6]:PORT")
        port_s = tail[1:]
    else:
        host, sep, port_s = rest.rpartition(":")
        if not sep:
            raise ValueError(f"bad connection string {text!r}: expected {kind}:HOST:PORT")
    if not host:
        if kind in ("udpin", "tcpin"):
            host = "0.0.0.0"
        else:
            raise ValueError(f"bad connection string {text!r}: {kind} needs a host to send to")
    port = _port(text, port_s)
    if port == 0 and kind in ("udpout", "tcp"):
        raise ValueError(f"bad connection string {text!r}: cannot send to port 0")
    return ConnectionSpec(kind=kind, host=host, port=port, text=text)


def _serial(text: str, rest: str) -> ConnectionSpec:
    device, sep, baud = rest.rpartition(",")
    if not sep:
        # DEVICE:BAUD only when the tail is a number: udev's /dev/serial/by-path names contain
        # colons (pci-0000:00:14.0-usb-0:2:1.0-port0) and are whole device paths.
        device, sep, baud = rest.rpartition(":")
        if not (sep and baud.isdigit()):
            device, baud = rest, ""
    if not device:
        raise ValueError(f"bad connection string {text!r}: missing serial device")
    return ConnectionSpec(
        kind="serial", device=device, baud=_baud(text, baud) if baud else DEFAULT_BAUD, text=text
    )


def parse_connection(text: str) -> ConnectionSpec:
    """Parse a MAVProxy/pymavlink-style connection string.

    Raises
    ------
    ValueError
        With the offending string and what was expected.

    Examples
    --------
    >>> parse_connection("udpin:0.0.0.0:14550")
    ConnectionSpec(kind='udpin', host='0.0.0.0', port=14550, device=None, baud=None, text='udpin:0.0.0.0:14550')
    >>> parse_connection("/dev/ttyUSB0,57600").baud
    57600
    """
    if not isinstance(text, str):
        raise ValueError(f"connection string must be a str, got {type(text).__name__}")
    s = text.strip()
    if not s:
        raise ValueError(
            "empty connection string; expected e.g. udpin:0.0.0.0:14550, "
            "udpout:127.0.0.1:14550, tcp:127.0.0.1:5760 or /dev/ttyUSB0,57600"
        )
    scheme, sep, rest = s.partition(":")
    if sep and rest.startswith("//"):  # MAVSDK style udpin://host:port
        rest = rest[2:]
    low = scheme.lower()
    if sep and low in _SCHEMES:
        kind = _SCHEMES[low]
        if not rest:
            raise ValueError(f"bad connection string {text!r}: nothing after {scheme}:")
        if kind == "serial":
            return _serial(text, rest)
        return _host_port(text, rest, kind)
    if sep and low in _UNSUPPORTED:
        raise ValueError(
            f"connection type {scheme!r} in {text!r} is not supported; use one of "
            "udpin:, udpout:, udp:, tcp:, tcpin: or a serial DEVICE,BAUD"
        )
    # No known scheme: a serial device path, or HOST:PORT (udpin, as mavutil does).
    if s.startswith("/") or _WINDOWS_COM.match(s.split(",")[0].split(":")[0]):
        return _serial(text, s)
    if "," in s:
        return _serial(text, s)
    if sep:
        host, _, port = s.rpartition(":")
        if port.isdigit() and host and ":" not in host:
            return _host_port(text, s, "udpin")
        raise ValueError(
            f"bad connection string {text!r}: unknown scheme {scheme!r}; expected "
            "udpin:, udpout:, udp:, tcp:, tcpin: or a serial DEVICE,BAUD"
        )
    raise ValueError(
        f"bad connection string {text!r}: expected udpin:HOST:PORT, udpout:HOST:PORT, "
        "tcp:HOST:PORT, tcpin:HOST:PORT or a serial DEVICE,BAUD"
    )

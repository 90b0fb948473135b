import pytest

from gcs.connection import ConnectionSpec, parse_connection


@pytest.mark.parametrize(
    "text, expected",
    [
        ("udpin:0.0.0.0:14550", ("udpin", "0.0.0.0", 14550, None, None)),
        ("udp:127.0.0.1:14550", ("udpin", "127.0.0.1", 14550, None, None)),
        ("udpin::14550", ("udpin", "0.0.0.0", 14550, None, None)),
        ("udpout:192.168.1.5:14550", ("udpout", "192.168.1.5", 14550, None, None)),
        ("tcp:127.0.0.1:5760", ("tcp", "127.0.0.1", 5760, None, None)),
        ("tcpin:0.0.0.0:5760", ("tcpin", "0.0.0.0", 5760, None, None)),
        ("udpin://0.0.0.0:14540", ("udpin", "0.0.0.0", 14540, None, None)),
        ("udpin:[::1]:14550", ("udpin", "::1", 14550, None, None)),
        ("127.0.0.1:14550", ("udpin", "127.0.0.1", 14550, None, None)),
        ("/dev/ttyUSB0,57600", ("serial", None, None, "/dev/ttyUSB0", 57600)),
        ("/dev/ttyACM0:115200", ("serial", None, None, "/dev/ttyACM0", 115200)),
        (
            "/dev/serial/by-id/usb-ArduPilot_fmuv3-if00,921600",
            ("serial", None, None, "/dev/serial/by-id/usb-ArduPilot_fmuv3-if00", 921600),
        ),
        ("COM3,57600", ("serial", None, None, "COM3", 57600)),
        ("/dev/ttyUSB0", ("serial", None, None, "/dev/ttyUSB0", 115200)),
        ("serial:///dev/ttyUSB0:57600", ("serial", None, None, "/dev/ttyUSB0", 57600)),
        ("  UDPOUT:localhost:14550 ", ("udpout", "localhost", 14550, None, None)),
    ],
)
def test_good_connection_strings(text, expected):
    spec = parse_connection(text)
    assert (spec.kind, spec.host, spec.port, spec.device, spec.baud) == expected
    assert spec.text == text


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("", "empty"),
        ("udpin:0.0.0.0", "HOST:PORT"),
        ("udpout::14550", "needs a host"),
        ("tcp:127.0.0.1:notaport", "not a number"),
        ("udpin:0.0.0.0:70000", "outside"),
        ("udpout:127.0.0.1:0", "port 0"),
        ("/dev/ttyUSB0,fast", "baud"),
        ("/dev/ttyUSB0,0", "baud"),
        ("udpcast:1.2.3.4:14550", "not supported"),
        ("ftp:host:21:x", "unknown scheme"),
        ("justaword", "expected"),
        ("tcp:", "nothing after"),
    ],
)
def test_bad_connection_strings_say_why(text, fragment):
    with pytest.raises(ValueError, match=fragment):
        parse_connection(text)


def test_address_of_serial_is_an_error():
    with pytest.raises(ValueError):
        _ = parse_connection("/dev/ttyUSB0").address
    with pytest.raises(ValueError):
        ConnectionSpec(kind="bogus")

"""Connection URLs in MAVSDK's style -> pymavlink connection strings, and clear errors."""

import pytest

from companion.link import LinkError, LinkUrl, LinkUrlError, parse_link_url


@pytest.mark.parametrize(
    ("url", "device", "baud"),
    [
        ("udpin://0.0.0.0:14540", "udpin:0.0.0.0:14540", 0),
        ("udpout://192.168.1.10:14550", "udpout:192.168.1.10:14550", 0),
        ("tcpout://127.0.0.1:5760", "tcp:127.0.0.1:5760", 0),
        ("serial:///dev/ttyAMA0:921600", "/dev/ttyAMA0", 921600),
        ("serial://COM3:57600", "COM3", 57600),
        ("  udpin://localhost:14540 ", "udpin:localhost:14540", 0),
    ],
)
def test_valid_urls_become_pymavlink_strings(url, device, baud):
    parsed = parse_link_url(url)
    assert parsed.pymavlink_device == device
    assert parsed.baud == baud
    assert parse_link_url(str(parsed)) == parsed


def test_parts_are_typed():
    assert parse_link_url("udpin://0.0.0.0:14540") == LinkUrl("udpin", host="0.0.0.0", port=14540)
    serial = parse_link_url("serial:///dev/ttyUSB0:57600")
    assert (serial.device, serial.baud, serial.is_stream) == ("/dev/ttyUSB0", 57600, True)
    assert not parse_link_url("udpout://h:1").is_stream


@pytest.mark.parametrize(
    ("url", "reason"),
    [
        ("0.0.0.0:14540", "SCHEME://"),
        ("udp://:14540", "unknown scheme 'udp'"),
        ("http://example.com:80", "unknown scheme"),
        ("udpin://0.0.0.0", "HOST:PORT"),
        ("udpin://:14540", "HOST:PORT"),
        ("udpin://0.0.0.0:port", "not a positive integer"),
        ("udpin://0.0.0.0:70000", "outside 1..65535"),
        ("udpin://0.0.0.0:0", "outside 1..65535"),
        ("udpout://[::1]:14540", "IPv6"),
        ("tcpout://a b:5760", "not a host name"),
        ("serial:///dev/ttyAMA0", "DEVICE:BAUD"),
        ("serial:///dev/ttyAMA0:fast", "baud rate 'fast'"),
        ("serial:///dev/ttyAMA0:-9600", "not a positive integer"),
    ],
)
def test_bad_urls_raise_a_clear_typed_error(url, reason):
    with pytest.raises(LinkUrlError) as info:
        parse_link_url(url)
    assert reason in str(info.value)
    assert repr(url) in str(info.value)
    assert isinstance(info.value, LinkError)
    assert isinstance(info.value, ValueError)


def test_non_string_is_rejected():
    with pytest.raises(LinkUrlError):
        parse_link_url(14540)  # type: ignore[arg-type]

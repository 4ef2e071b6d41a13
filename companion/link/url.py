"""Connection URLs in MAVSDK's style, turned into pymavlink connection strings.

======================================  =============================================
URL                                     meaning
======================================  =============================================
``udpin://0.0.0.0:14540``               listen on a UDP port; answer whoever sends (the
                                        usual companion setup: PX4's onboard link sends
                                        to port 14540)
``udpout://192.168.1.10:14550``         send to a UDP host and port, receive the replies
``tcpout://127.0.0.1:5760``             connect to a TCP server
``serial:///dev/ttyAMA0:921600``        a serial port and its baud rate (PX4 TELEM2)
``memory://onboard``                    the in-memory link of a simulated vehicle in the
                                        same process (a flight on simulated time:
                                        ``sitl demo --clock virtual``)
======================================  =============================================

Anything else (a missing port, an unknown scheme, IPv6, a baud rate that is not a
positive integer) raises :class:`~companion.link.errors.LinkUrlError` naming the URL.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from companion.link.errors import LinkUrlError

__all__ = ["LinkUrl", "parse_link_url"]

Scheme = Literal["udpin", "udpout", "tcpout", "serial", "memory"]
_SCHEMES: tuple[Scheme, ...] = ("udpin", "udpout", "tcpout", "serial", "memory")
_PYMAVLINK_PREFIX = {"udpin": "udpin", "udpout": "udpout", "tcpout": "tcp"}


@dataclass(frozen=True)
class LinkUrl:
    """A parsed connection URL.

    ``host``/``port`` are set for the network schemes, ``device``/``baud`` for serial,
    ``device`` (the channel's name) for memory.
    """

    scheme: Scheme
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    @property
    def pymavlink_device(self) -> str:
        """The connection string for ``pymavlink.mavutil.mavlink_connection`` (the serial
        baud rate goes in its ``baud`` argument: :attr:`baud`)."""
        if self.scheme == "serial":
            return self.device
        return f"{_PYMAVLINK_PREFIX[self.scheme]}:{self.host}:{self.port}"

    @property
    def is_stream(self) -> bool:
        """True for byte streams (TCP, serial), False for datagrams (UDP)."""
        return self.scheme in ("tcpout", "serial")

    def __str__(self) -> str:
        if self.scheme == "serial":
            return f"serial://{self.device}:{self.baud}"
        if self.scheme == "memory":
            return f"memory://{self.device}"
        return f"{self.scheme}://{self.host}:{self.port}"


def _fail(url: str, reason: str) -> LinkUrlError:
    return LinkUrlError(f"bad connection URL {url!r}: {reason}")


def _positive_int(url: str, text: str, what: str, maximum: int) -> int:
    if not text.isdigit():
        raise _fail(url, f"{what} {text!r} is not a positive integer")
    value = int(text)
    if not 1 <= value <= maximum:
        raise _fail(url, f"{what} {value} is outside 1..{maximum}")
    return value


def parse_link_url(url: str) -> LinkUrl:
    """Parse ``udpin://HOST:PORT``, ``udpout://HOST:PORT``, ``tcpout://HOST:PORT``,
    ``serial://DEVICE:BAUD`` or ``memory://NAME`` (see the module docstring); raises
    ``LinkUrlError``."""
    if not isinstance(url, str):
        raise LinkUrlError(f"bad connection URL {url!r}: not a string")
    scheme, sep, rest = url.strip().partition("://")
    if not sep:
        raise _fail(url, "expected SCHEME://..., e.g. udpin://0.0.0.0:14540")
    if scheme not in _SCHEMES:
        raise _fail(url, f"unknown scheme {scheme!r}; use one of {', '.join(_SCHEMES)}")
    if scheme == "memory":
        if not rest or any(c.isspace() or c in "/:" for c in rest):
            raise _fail(url, "expected memory://NAME")
        return LinkUrl("memory", device=rest)
    where, colon, number = rest.rpartition(":")
    if not colon or not where:
        what = "DEVICE:BAUD" if scheme == "serial" else "HOST:PORT"
        raise _fail(url, f"expected {scheme}://{what}")
    if scheme == "serial":
        return LinkUrl("serial", device=where, baud=_positive_int(url, number, "baud rate", 10**8))
    if "[" in where or ":" in where:
        raise _fail(url, "IPv6 addresses are not supported by pymavlink's sockets")
    if any(c.isspace() or c == "/" for c in where):
        raise _fail(url, f"{where!r} is not a host name or IPv4 address")
    return LinkUrl(scheme, host=where, port=_positive_int(url, number, "port", 65535))

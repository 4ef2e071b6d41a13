"""Non-blocking byte I/O over pymavlink's connection objects (UDP, TCP, serial).

pymavlink opens the port (``mavutil.mavlink_connection`` with the string from
:class:`~companion.link.url.LinkUrl`); this module only reads and writes bytes on its
non-blocking file descriptor (the socket, or the serial port opened with timeout 0), so
that the link's reader can wait with the event loop's ``add_reader`` and parse with its
own MAVLink 2 codec. Reads and writes go to the socket / port directly: a closed peer
becomes :class:`LinkClosedError` instead of pymavlink's reconnect attempts and prints.
``udpin`` answers the sender of the latest datagram (PX4's onboard link); before the
first datagram there is nobody to send to and frames are dropped (counted).

On Linux, UDP datagrams carry the kernel's arrival time (``SO_TIMESTAMPNS_NEW``), so the
transport can say how long datagrams waited in the socket before the process read them
(:meth:`Transport.take_longest_socket_wait_s`): the part of a delay that happened in this
process, not on the way.
"""

from __future__ import annotations

import socket
import struct
import time
from typing import Any

from pymavlink import mavutil

from bytelink.memory import MemoryEnd, attach, require_memory_loop
from companion.link.errors import LinkClosedError
from companion.link.url import LinkUrl

__all__ = ["MemoryTransport", "Transport", "open_transport"]

_READ_SIZE = 65536

_SO_TIMESTAMPNS_NEW = 64
"""Linux >= 5.1 (asm-generic/socket.h, also x86): arrival time as a ``__kernel_timespec``
(two int64 on every architecture). Python's socket module does not name it."""
_TIMESPEC = struct.Struct("qq")
_ANCILLARY_SIZE = socket.CMSG_SPACE(_TIMESPEC.size)


class Transport:
    """A pymavlink connection seen as non-blocking ``read()`` / ``write()`` of bytes."""

    def __init__(self, url: LinkUrl, conn: Any) -> None:
        self.url = url
        self._conn = conn
        self.fd: int = conn.fd if url.scheme == "serial" else conn.port.fileno()
        self.peer: tuple[str, int] | None = None
        """UDP: where frames go; for ``udpin`` the sender of the latest datagram."""
        if url.scheme == "udpout":
            self.peer = (socket.gethostbyname(url.host), url.port)
        self.unsent_frames = 0
        """Frames dropped: full socket buffer, or no peer yet (``udpin`` before the first
        datagram arrived)."""
        self._stamped = not url.is_stream and _enable_arrival_times(conn.port)
        self._longest_wait_s = 0.0

    def take_longest_socket_wait_s(self) -> float | None:
        """The longest a datagram waited in the socket, from the kernel's arrival time to
        this process's read, since the previous call [s]; None where the transport cannot
        tell (serial, TCP, no kernel arrival times)."""
        if not self._stamped:
            return None
        longest, self._longest_wait_s = self._longest_wait_s, 0.0
        return longest

    def read(self) -> bytes:
        """Bytes available now (one datagram for UDP), or ``b""`` if none."""
        try:
            if self.url.scheme == "tcpout":
                try:
                    data = self._conn.port.recv(_READ_SIZE)
                except BlockingIOError:
                    return b""
                if not data:
                    raise LinkClosedError(f"{self.url}: the peer closed the connection")
                return data
            if self.url.scheme == "serial":
                return bytes(self._conn.port.read(_READ_SIZE))
            try:
                if self._stamped:
                    data, ancillary, _, sender = self._conn.port.recvmsg(
                        _READ_SIZE, _ANCILLARY_SIZE
                    )
                    self._note_arrival(ancillary)
                else:
                    data, sender = self._conn.port.recvfrom(_READ_SIZE)
            except (BlockingIOError, ConnectionRefusedError):
                return b""
            if self.url.scheme == "udpin":
                self.peer = sender
            return data
        except LinkClosedError:
            raise
        except Exception as exc:  # pyserial raises SerialException, sockets OSError
            raise LinkClosedError(f"{self.url}: read failed: {exc}") from exc

    def _note_arrival(self, ancillary: list[tuple[int, int, bytes]]) -> None:
        for level, kind, value in ancillary:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS_NEW:
                seconds, nanoseconds = _TIMESPEC.unpack_from(value)
                waited_s = time.time() - (seconds + nanoseconds * 1e-9)
                self._longest_wait_s = max(self._longest_wait_s, waited_s)

    def write(self, buf: bytes) -> None:
        """Send one frame, without waiting (see :attr:`unsent_frames`)."""
        try:
            if self.url.scheme == "tcpout":
                self._conn.port.send(buf)
            elif self.url.scheme == "serial":
                self._conn.port.write(buf)
            elif self.peer is None:
                self.unsent_frames += 1
            else:
                self._conn.port.sendto(buf, self.peer)
        except BlockingIOError:
            self.unsent_frames += 1
        except Exception as exc:
            raise LinkClosedError(f"{self.url}: write failed: {exc}") from exc

    def close(self) -> None:
        self._conn.close()


def _enable_arrival_times(sock: socket.socket) -> bool:
    """Ask the kernel to stamp each datagram with its arrival time (CLOCK_REALTIME);
    False where it cannot (not Linux, a kernel before 5.1)."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS_NEW, 1)
    except OSError:
        return False
    return True


class MemoryTransport:
    """The in-memory link ``memory://NAME`` of a simulated vehicle in this process
    (:mod:`bytelink.memory`): one MAVLink datagram per chunk, the same interface as
    :class:`Transport`; opened on the lockstep loop only."""

    def __init__(self, url: LinkUrl, end: MemoryEnd) -> None:
        self.url = url
        self._end = end
        self.fd: int = end.fileno()
        self.peer: tuple[str, int] | None = None
        self.unsent_frames = 0

    def take_longest_socket_wait_s(self) -> float | None:
        """None: nothing waits in a socket."""
        return None

    def read(self) -> bytes:
        """One datagram, or ``b""`` if none."""
        if self._end.closed:
            raise LinkClosedError(f"{self.url}: the link is closed")
        return self._end.receive()

    def write(self, buf: bytes) -> None:
        """Send one frame."""
        try:
            self._end.send(buf)
        except ConnectionError as exc:
            raise LinkClosedError(f"{self.url}: write failed: {exc}") from exc

    def close(self) -> None:
        self._end.close()


def open_transport(url: LinkUrl, system_id: int, component_id: int) -> Transport | MemoryTransport:
    """Open the port (blocking: a TCP connect waits for the peer; call it in a thread,
    except ``memory://``, which must be opened on the lockstep loop's thread)."""
    if url.scheme == "memory":
        try:
            require_memory_loop(str(url))
            return MemoryTransport(url, attach(url.device))
        except (ConnectionError, LookupError) as exc:
            raise LinkClosedError(f"{url}: cannot open: {exc}") from exc
    try:
        conn = mavutil.mavlink_connection(
            url.pymavlink_device,
            baud=url.baud or 115200,
            source_system=system_id,
            source_component=component_id,
            retries=0,
        )
        return Transport(url, conn)
    except Exception as exc:  # OSError, ValueError, pyserial's SerialException
        raise LinkClosedError(f"{url}: cannot open: {exc}") from exc

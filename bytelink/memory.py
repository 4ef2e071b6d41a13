"""In-memory byte channels: a serial line or a datagram link between two parts of one
process, for flights on simulated time.

As python-can's ``virtual`` interface keeps its channels in a process-wide table by name,
a :class:`MemoryChannel` is created under a name by the side that serves it (the
simulated vehicle, the simulated servo bus) and attached by name by the client (the
MAVLink link ``memory://NAME``, the Dynamixel bus ``dynamixel://memory:NAME``). The bytes
that cross it are the real wire bytes (MAVLink 2 frames, Dynamixel Protocol 2.0 packets):
only the medium is memory.

Each end has a *virtual* file descriptor (:meth:`MemoryEnd.fileno`), a number no open file
of the process can have. An event loop that serves memory ends
(:class:`sitl.vehicle.lockstep.LockstepLoop`, which sets ``serves_memory_ports``) resolves it with
:func:`end_for_fd`; the operating system's selectors cannot, so a client refuses to open a
memory end on any other loop (:func:`require_memory_loop`).

Writes never block and never drop: what one end sends waits in the other end's inbox, one
chunk per send (a datagram, or a burst of serial bytes), until that end receives it.
"""

from __future__ import annotations

import asyncio
import itertools
from collections import deque

__all__ = [
    "MemoryChannel",
    "MemoryEnd",
    "attach",
    "create_channel",
    "end_for_fd",
    "require_memory_loop",
]

_FIRST_VIRTUAL_FD = 1 << 28
"""Virtual descriptors start here, far above any descriptor the kernel hands out."""
_next_fd = itertools.count(_FIRST_VIRTUAL_FD)
_ends: dict[int, MemoryEnd] = {}
_channels: dict[str, MemoryChannel] = {}


class MemoryEnd:
    """One end of a :class:`MemoryChannel`: send to the peer, receive what it sent."""

    def __init__(self, channel: str, side: str) -> None:
        self.channel = channel
        self.side = side
        self.peer: MemoryEnd | None = None
        self._inbox: deque[bytes] = deque()
        self._fd = next(_next_fd)
        self.closed = False
        self.attached = side == "server"
        """Someone reads this end: the server always, the client once :func:`attach`
        took it. What is sent to an end nobody reads is dropped, as a datagram to a port
        nobody listens on."""
        _ends[self._fd] = self

    def fileno(self) -> int:
        """The end's virtual descriptor (see the module docstring)."""
        return self._fd

    @property
    def readable(self) -> bool:
        """Something waits in the inbox."""
        return bool(self._inbox)

    def send(self, data: bytes) -> None:
        """Put ``data`` in the peer's inbox (one chunk); raises ``ConnectionError`` when
        either end is closed."""
        peer = self.peer
        if self.closed or peer is None or peer.closed:
            raise ConnectionError(f"memory channel {self.channel!r} is closed")
        if data and peer.attached:
            peer._inbox.append(bytes(data))

    def receive(self) -> bytes:
        """The oldest chunk waiting, or ``b""`` if none."""
        return self._inbox.popleft() if self._inbox else b""

    def receive_all(self) -> bytes:
        """Every byte waiting, joined (a serial line has no chunk boundaries)."""
        data = b"".join(self._inbox)
        self._inbox.clear()
        return data

    def close(self) -> None:
        """Close this end (idempotent); the peer's sends then fail."""
        self.closed = True
        self._inbox.clear()
        _ends.pop(self._fd, None)


class MemoryChannel:
    """A named pair of ends: :attr:`server` for the simulated device, :attr:`client` for
    the companion's driver. Use as a context manager or call :meth:`close`."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.server = MemoryEnd(name, "server")
        self.client = MemoryEnd(name, "client")
        self.server.peer, self.client.peer = self.client, self.server

    def close(self) -> None:
        """Close both ends and forget the name (idempotent)."""
        self.server.close()
        self.client.close()
        if _channels.get(self.name) is self:
            del _channels[self.name]

    def __enter__(self) -> MemoryChannel:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def create_channel(name: str) -> MemoryChannel:
    """Create the channel ``name``; raises ``ValueError`` if it exists."""
    if not name:
        raise ValueError("a memory channel needs a name")
    if name in _channels:
        raise ValueError(f"memory channel {name!r} exists already")
    channel = _channels[name] = MemoryChannel(name)
    return channel


def attach(name: str) -> MemoryEnd:
    """The client end of the channel ``name`` (once); raises ``LookupError`` naming the
    channels there are when it does not exist or is taken."""
    channel = _channels.get(name)
    if channel is None:
        there = ", ".join(sorted(_channels)) or "none"
        raise LookupError(f"no memory channel {name!r} in this process (there are: {there})")
    if channel.client.attached:
        raise LookupError(f"memory channel {name!r} is attached already")
    channel.client.attached = True
    return channel.client


def end_for_fd(fd: int) -> MemoryEnd | None:
    """The open end whose virtual descriptor is ``fd``, or None."""
    return _ends.get(fd)


def require_memory_loop(what: str) -> asyncio.AbstractEventLoop:
    """The running loop, if it serves memory ends; else a ``ConnectionError`` saying
    that ``what`` flies only on simulated time."""
    loop = asyncio.get_running_loop()
    if not getattr(loop, "serves_memory_ports", False):
        raise ConnectionError(
            f"{what} is an in-memory channel: it exists only inside a flight on simulated "
            "time (sitl demo --clock virtual)"
        )
    return loop

"""The simulator's end of PX4's ``simulator_mavlink`` link: a TCP server PX4 connects to.

PX4 (an airframe without SIH or Gazebo) connects as a TCP client to 127.0.0.1:4560 + its
instance number as soon as its start-up script reaches ``simulator_mavlink start``, and
waits there until the first HIL_SENSOR sets its clock. MAVLink 2 frames flow both ways on
the one stream. Thin I/O: :meth:`SimulatorLink.open` binds and listens, :meth:`accept`
waits for PX4, :meth:`send` packs and writes messages, :meth:`receive` parses what has
arrived; :meth:`close` is idempotent. Loopback only.
"""

from __future__ import annotations

import select
import socket
import time

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["SimulatorLink", "SimulatorLinkError"]

_HOST = "127.0.0.1"
_SYSTEM_ID = 1
_COMPONENT_ID = 51
"""The simulator's MAVLink component id (PX4's simulator_mavlink ignores it)."""
_CHUNK = 65536


class SimulatorLinkError(RuntimeError):
    """PX4 did not connect in time, or closed the simulator link."""


class SimulatorLink:
    """A TCP server on 127.0.0.1:``port`` for one PX4 (module docstring)."""

    def __init__(self, port: int) -> None:
        self.port = int(port)
        self._server: socket.socket | None = None
        self._peer: socket.socket | None = None
        self._mav = mavlink.MAVLink(None, srcSystem=_SYSTEM_ID, srcComponent=_COMPONENT_ID)
        self.bytes_sent = 0
        self.bytes_received = 0

    def open(self) -> None:
        """Listen on 127.0.0.1:port (OSError when it is taken)."""
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            server.bind((_HOST, self.port))
            server.listen(1)
        except OSError:
            server.close()
            raise
        self._server = server

    @property
    def connected(self) -> bool:
        return self._peer is not None

    def accept(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` [s] for PX4 to connect; SimulatorLinkError otherwise."""
        if self._server is None:
            raise RuntimeError("open the simulator link before accepting PX4")
        ready, _, _ = select.select([self._server], [], [], timeout_s)
        if not ready:
            raise SimulatorLinkError(
                f"PX4 did not connect to the simulator port {self.port} within {timeout_s:g} s"
            )
        peer, _ = self._server.accept()
        peer.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._peer = peer

    def send(self, *messages: mavlink.MAVLink_message) -> None:
        """Write the messages, in order, as one burst."""
        if self._peer is None:
            raise RuntimeError("PX4 is not connected")
        data = b"".join(m.pack(self._mav) for m in messages)
        try:
            self._peer.sendall(data)
        except OSError as exc:
            raise SimulatorLinkError(f"PX4 closed the simulator link: {exc}") from None
        self.bytes_sent += len(data)

    def receive(self, timeout_s: float = 0.0) -> list[mavlink.MAVLink_message]:
        """The messages PX4 sent, waiting up to ``timeout_s`` [s] for the first bytes
        (0: only what has arrived). SimulatorLinkError when PX4 closed the link."""
        if self._peer is None:
            raise RuntimeError("PX4 is not connected")
        deadline = time.monotonic() + timeout_s
        messages: list[mavlink.MAVLink_message] = []
        wait = timeout_s
        while True:
            ready, _, _ = select.select([self._peer], [], [], max(wait, 0.0))
            if not ready:
                return messages
            try:
                data = self._peer.recv(_CHUNK)
            except OSError as exc:
                raise SimulatorLinkError(f"PX4 closed the simulator link: {exc}") from None
            if not data:
                raise SimulatorLinkError("PX4 closed the simulator link")
            self.bytes_received += len(data)
            messages.extend(self._mav.parse_buffer(data) or [])
            if messages:
                return messages
            wait = deadline - time.monotonic()

    def close(self) -> None:
        """Close the connection and the server socket; safe twice."""
        for sock in (self._peer, self._server):
            if sock is not None:
                sock.close()
        self._peer = self._server = None

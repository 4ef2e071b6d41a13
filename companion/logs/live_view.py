"""Live view: the flight log's channels served to Foxglove while the mission flies.

``companion mission pickup --live PORT`` and ``sitl demo --live PORT`` start a Foxglove
WebSocket server (foxglove-sdk) on ``127.0.0.1:PORT`` on the context of the flight's MCAP
writer (:class:`companion.logs.mcap_log.McapLogWriter`): the same channels, schemas and
Protobuf messages as ``flight.mcap``, stamped with the vehicle time, go to the file and to
whoever connects, from one writer. In Foxglove, *Open connection* ->
``ws://127.0.0.1:PORT``.

What it costs the control loop: nothing more than the log: the messages a block of cycles
is encoded into once (:func:`~companion.logs.mcap_log.encode_block`) are handed to the SDK,
which sends them from its own threads, a block at a time (every
:data:`~companion.logs.flightlog.BLOCK_ROWS` cycles, 80 ms at 125 Hz), every cycle's.
A client too slow for the stream loses the oldest messages (the SDK's per-client backlog),
never the control loop's time.
"""

from __future__ import annotations

from typing import Any

import foxglove

__all__ = ["LiveView", "LiveViewError", "check_port"]

BACKLOG_MESSAGES = 4096
"""Messages queued per client before the oldest are dropped (about 4 s of the stream)."""


class LiveViewError(RuntimeError):
    """The live view cannot start (the port taken)."""


def check_port(port: int) -> None:
    """:class:`LiveViewError` unless ``port`` is a TCP port (0: any free one)."""
    if not 0 <= port <= 65535:
        raise LiveViewError(f"must be a TCP port, 0-65535 (0: any free port), got {port}")


class LiveView:
    """A Foxglove WebSocket server publishing the channels of a flight log's MCAP writer
    (its ``context``); a context manager around :meth:`open` / :meth:`close`.

    ``port`` 0 takes a free port (:attr:`port` tells which once open).
    """

    def __init__(self, port: int, context: foxglove.Context, *, host: str = "127.0.0.1") -> None:
        check_port(port)
        self.host = host
        self.port = port
        self._context = context
        self._server: Any = None

    def __enter__(self) -> LiveView:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def open(self) -> None:
        """Start the server (it advertises the context's channels); :class:`LiveViewError`
        when the port cannot be bound."""
        try:
            self._server = foxglove.start_server(
                name="aerial-manipulator companion",
                host=self.host,
                port=self.port,
                context=self._context,
                message_backlog_size=BACKLOG_MESSAGES,
            )
        except RuntimeError as exc:
            raise LiveViewError(f"live view on {self.host}:{self.port}: {exc}") from None
        self.port = self._server.port

    def close(self) -> None:
        """Stop the server (idempotent)."""
        server, self._server = self._server, None
        if server is not None:
            server.stop()

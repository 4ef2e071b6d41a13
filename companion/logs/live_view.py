"""Live view: the flight log's channels served to Foxglove while the mission flies.

``companion mission pickup --live PORT`` and ``sitl demo --live PORT`` start a Foxglove
WebSocket server (foxglove-sdk, the ``live`` extra) on ``127.0.0.1:PORT`` and publish the
channels of ``flight.mcap`` (:mod:`companion.logs.mcap_log`: the same topics, schemas and JSON
messages, stamped with the vehicle time) to whoever connects: in Foxglove, *Open
connection* -> ``ws://127.0.0.1:PORT``.

What it costs the control loop: a cycle's messages are encoded and handed to the SDK, which
sends them from its own threads; cycles are published at most :data:`RATE_HZ` times per
second of wall time (the others are skipped, the log keeps them all), events every time.
With no client connected nothing is encoded. A client too slow for the stream loses the
oldest messages (the SDK's per-client backlog), never the control loop's time.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from companion.logs.mcap_log import (
    CHANNELS,
    SCHEMAS,
    ArmGeometry,
    cycle_messages,
    encode,
    log_message,
    schema_data,
    time_ns,
)

if TYPE_CHECKING:
    from companion.logs.flightlog import CycleRecord

__all__ = ["RATE_HZ", "LiveView", "LiveViewError", "check_port"]

RATE_HZ = 30.0
"""Most cycles published per second of wall time."""
BACKLOG_MESSAGES = 1024
"""Messages queued per client before the oldest are dropped (about 4 s of the stream)."""


class LiveViewError(RuntimeError):
    """The live view cannot start (foxglove-sdk missing, the port taken)."""


def check_port(port: int) -> None:
    """:class:`LiveViewError` unless ``port`` is a TCP port (0: any free one)."""
    if not 0 <= port <= 65535:
        raise LiveViewError(f"must be a TCP port, 0-65535 (0: any free port), got {port}")


class LiveView:
    """A Foxglove WebSocket server publishing the flight log's channels; a context manager.

    ``port`` 0 takes a free port (:attr:`port` tells which once open). ``clock`` gives the
    wall time [s] that paces the publishing (``time.monotonic``).
    """

    def __init__(
        self,
        port: int,
        geometry: ArmGeometry,
        *,
        host: str = "127.0.0.1",
        rate_hz: float = RATE_HZ,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        check_port(port)
        self.host = host
        self.port = port
        self.geometry = geometry
        self.period_s = 1.0 / rate_hz
        self.published = 0
        """Cycles published so far."""
        self._clock = clock
        self._next_s = -float("inf")
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[str, Any] = {}
        self._last_t_s = 0.0

    def __enter__(self) -> LiveView:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def open(self) -> None:
        """Start the server and advertise the channels; :class:`LiveViewError` when
        foxglove-sdk is not installed or the port cannot be bound."""
        try:
            import foxglove
        except ImportError:
            raise LiveViewError(
                "the live view needs foxglove-sdk: pip install 'aerial-manipulator-companion[live]'"
            ) from None
        context = self._context = foxglove.Context()  # the server and channels live in it
        try:
            self._server = foxglove.start_server(
                name="aerial-manipulator companion",
                host=self.host,
                port=self.port,
                context=context,
                message_backlog_size=BACKLOG_MESSAGES,
            )
        except RuntimeError as exc:
            raise LiveViewError(f"live view on {self.host}:{self.port}: {exc}") from None
        self.port = self._server.port
        for topic, name in CHANNELS.items():
            schema = foxglove.Schema(
                name=name, encoding="jsonschema", data=schema_data(SCHEMAS[name])
            )
            self._channels[topic] = foxglove.Channel(
                topic, schema=schema, message_encoding="json", context=context
            )

    def write(self, record: CycleRecord) -> None:
        """Publish one cycle's messages, unless one was published less than a period ago
        or no client listens."""
        self._last_t_s = record.t_vehicle_s
        now_s = self._clock()
        if now_s < self._next_s or not self._channels:
            return
        if not self._channels["/tf"].has_sinks():
            return
        self._next_s = now_s + self.period_s
        ns = time_ns(record.t_vehicle_s)
        for topic, message in cycle_messages(record, self.geometry):
            self._channels[topic].log(encode(message), log_time=ns)
        self.published += 1

    def event(self, kind: str, detail: str, t_vehicle_s: float) -> None:
        """Publish an event on ``/events`` (a time not finite, as before the first pose: the
        last cycle's)."""
        channel = self._channels.get("/events")
        if channel is None:
            return
        ns = time_ns(t_vehicle_s if math.isfinite(t_vehicle_s) else self._last_t_s)
        channel.log(encode(log_message(kind, detail, ns)), log_time=ns)

    def close(self) -> None:
        """Stop the server (idempotent)."""
        server, self._server = self._server, None
        self._channels = {}
        if server is not None:
            server.stop()
        self._context = None

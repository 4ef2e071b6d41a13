"""Serial transport for the Dynamixel bus: bytes in and out, awaited on the event loop.

:class:`SerialTransport` configures the port with pyserial and then reads it without a
thread: the event loop watches the file descriptor (:meth:`asyncio.loop.add_reader`)
and a callback drains it into a buffer as soon as bytes arrive. :meth:`~SerialTransport.read`
waits for that buffer up to an absolute deadline.

Why not a thread executor running blocking reads: a blocking ``read`` in a worker thread
cannot be cancelled, so a cancelled or timed-out transaction would leave a read pending
that steals the next transaction's bytes, and each hop to the executor costs tens to
hundreds of microseconds of scheduling. Watching the descriptor wakes the loop the
moment the kernel has bytes, deadlines are exact (``asyncio.timeout_at``), and
cancellation is free. The cost: POSIX only (the selector event loop), which is what the
companion computer runs.

Latency: USB-serial adapters (FTDI in the ROBOTIS U2D2) hold received bytes for their
latency timer, 16 ms by default, which alone would break a 1 kHz loop. :meth:`open`
asks the kernel for low-latency mode (``ASYNC_LOW_LATENCY``, pyserial
``set_low_latency_mode``), which the ftdi_sio driver maps to a 1 ms timer. Devices
without that ioctl (pseudo-terminals, some CDC-ACM adapters) keep their behaviour; this
is logged at debug level, not raised.

Writes go straight to the kernel: packets are tens of bytes, far below the tty buffer.
Nothing is opened in ``__init__``; :meth:`close` is idempotent.
"""

from __future__ import annotations

import asyncio
import logging
import os

import serial

from arm_driver.errors import CommunicationError
from bytelink.memory import MemoryEnd, attach, require_memory_loop

__all__ = [
    "BITS_PER_BYTE",
    "MEMORY_PREFIX",
    "MemorySerialTransport",
    "SerialTransport",
    "open_transport",
]

_LOG = logging.getLogger(__name__)

BITS_PER_BYTE = 10
"""Bits on the line per byte: start, 8 data, stop (8N1) [bit]."""


class SerialTransport:
    """A serial port whose received bytes are awaited with a deadline.

    Parameters
    ----------
    device
        Path of the serial device, e.g. ``/dev/ttyUSB0`` or a pty's slave.
    baudrate
        Line rate [bit/s].
    low_latency
        Ask the kernel for low-latency mode on open (see the module docstring).
    """

    def __init__(self, device: str, baudrate: int, *, low_latency: bool = True) -> None:
        if baudrate <= 0:
            raise ValueError(f"baud rate {baudrate} must be positive")
        self.device = device
        self.baudrate = baudrate
        self.low_latency = low_latency
        self._serial: serial.Serial | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._buffer = bytearray()
        self._ready = asyncio.Event()
        self._lost: OSError | None = None

    @property
    def is_open(self) -> bool:
        """The port is open."""
        return self._serial is not None

    @property
    def byte_time_s(self) -> float:
        """Time one byte takes on the line [s]."""
        return BITS_PER_BYTE / self.baudrate

    async def open(self) -> None:
        """Open and configure the port (8N1, non-blocking) and start watching it.

        Raises
        ------
        CommunicationError
            The device cannot be opened or configured.
        """
        if self._serial is not None:
            return
        try:
            port = serial.Serial(self.device, self.baudrate, timeout=0, write_timeout=0.1)
        except (serial.SerialException, OSError, ValueError) as error:
            raise CommunicationError(f"cannot open {self.device}: {error}") from error
        if self.low_latency:
            try:
                port.set_low_latency_mode(True)
            except (OSError, ValueError, AttributeError) as error:
                _LOG.debug("%s: no low-latency mode (%s)", self.device, error)
        port.reset_input_buffer()
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(port.fileno(), self._on_readable)
        self._serial = port
        self._lost = None

    def close(self) -> None:
        """Stop watching and close the port; safe to call twice."""
        port, self._serial = self._serial, None
        if port is None:
            return
        if self._loop is not None and not self._loop.is_closed():
            self._loop.remove_reader(port.fileno())
        port.close()
        self._buffer.clear()
        self._ready.set()  # wake a pending read, which then raises

    async def __aenter__(self) -> SerialTransport:
        await self.open()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        self.close()

    def _check_open(self) -> None:
        """Raise ``CommunicationError`` unless the port is open and not lost."""
        if self._lost is not None:
            raise CommunicationError(f"{self.device}: connection lost: {self._lost}")
        if self._serial is None:
            raise CommunicationError(f"{self.device}: the port is not open")

    def _port(self) -> serial.Serial:
        self._check_open()
        assert self._serial is not None
        return self._serial

    def _on_readable(self) -> None:
        if self._serial is None:
            return
        try:
            data = os.read(self._serial.fileno(), 4096)
        except BlockingIOError:
            return
        except InterruptedError:
            return
        except OSError as error:  # the device went away (USB unplugged, pty closed)
            self._lost = error
            self._loop.remove_reader(self._serial.fileno())  # type: ignore[union-attr]
            self._ready.set()
            return
        self._buffer += data
        self._ready.set()

    def discard_input(self) -> int:
        """Drop bytes received and not yet read (stale replies); return how many.

        Also drains what the kernel holds and the event loop has not handed to us yet: a
        reply that arrived while the loop was busy after its request timed out must not be
        taken for the answer to the next request.
        """
        self._check_open()
        self._drain_kernel()
        dropped = len(self._buffer)
        self._buffer.clear()
        self._ready.clear()
        return dropped

    def _drain_kernel(self) -> None:
        """Move every byte the kernel holds into the buffer now (non-blocking)."""
        for _ in range(64):
            before = len(self._buffer)
            self._on_readable()
            if len(self._buffer) == before or self._serial is None:
                return

    def write(self, data: bytes) -> None:
        """Send bytes; returns once the kernel has them (not once they are on the line).

        Raises
        ------
        CommunicationError
            The port is closed, lost, or the write failed.
        """
        port = self._port()
        try:
            port.write(data)
        except serial.SerialException as error:  # pyserial's own says "write failed: ..."
            raise CommunicationError(f"{self.device}: {error}") from error
        except OSError as error:
            raise CommunicationError(f"{self.device}: write failed: {error}") from error

    async def read(self, deadline: float) -> bytes:
        """Bytes received so far, waiting for at least one until ``deadline``.

        Parameters
        ----------
        deadline
            Absolute time on the event loop's clock (``loop.time()``) [s].

        Returns
        -------
        bytes
            The received bytes, or ``b""`` if none came before the deadline.

        Raises
        ------
        CommunicationError
            The port is closed or was lost.
        """
        self._check_open()
        if not self._buffer:
            try:
                async with asyncio.timeout_at(deadline):
                    await self._ready.wait()
            except TimeoutError:
                # The loop may have been busy past the deadline with the reply already in
                # the kernel: look once more before calling it a timeout.
                self._drain_kernel()
                if not self._buffer:
                    return b""
            self._check_open()
        data = bytes(self._buffer)
        self._buffer.clear()
        self._ready.clear()
        return data


MEMORY_PREFIX = "memory:"
"""A device named ``memory:NAME`` is the in-memory line ``NAME`` (:mod:`bytelink.memory`)."""


class MemorySerialTransport(SerialTransport):
    """The serial line of a simulated servo bus in the same process (``memory:NAME``):
    the same bytes, deadlines and buffer as :class:`SerialTransport`, on the lockstep
    loop's clock; only the medium is memory (no kernel, no latency timer)."""

    def __init__(self, device: str, baudrate: int, *, low_latency: bool = True) -> None:
        super().__init__(device, baudrate, low_latency=low_latency)
        self._end: MemoryEnd | None = None

    @property
    def is_open(self) -> bool:
        return self._end is not None

    async def open(self) -> None:
        if self._end is not None:
            return
        name = self.device.removeprefix(MEMORY_PREFIX)
        try:
            loop = require_memory_loop(self.device)
            end = attach(name)
        except (ConnectionError, LookupError) as error:
            raise CommunicationError(f"cannot open {self.device}: {error}") from error
        self._loop = loop
        loop.add_reader(end.fileno(), self._on_readable)
        self._end = end
        self._lost = None

    def close(self) -> None:
        end, self._end = self._end, None
        if end is None:
            return
        if self._loop is not None and not self._loop.is_closed():
            self._loop.remove_reader(end.fileno())
        end.close()
        self._buffer.clear()
        self._ready.set()

    def _check_open(self) -> None:
        if self._end is None:
            raise CommunicationError(f"{self.device}: the port is not open")

    def _on_readable(self) -> None:
        if self._end is None:
            return
        data = self._end.receive_all()
        if data:
            self._buffer += data
            self._ready.set()

    def _drain_kernel(self) -> None:
        self._on_readable()

    def write(self, data: bytes) -> None:
        self._check_open()
        assert self._end is not None
        try:
            self._end.send(data)
        except ConnectionError as error:
            raise CommunicationError(f"{self.device}: write failed: {error}") from error


def open_transport(device: str, baudrate: int, *, low_latency: bool = True) -> SerialTransport:
    """The transport of ``device``: a serial port, or ``memory:NAME`` (unopened)."""
    kind = MemorySerialTransport if device.startswith(MEMORY_PREFIX) else SerialTransport
    return kind(device, baudrate, low_latency=low_latency)

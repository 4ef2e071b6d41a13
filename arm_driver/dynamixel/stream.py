"""Frame Protocol 2.0 packets out of a serial byte stream. Pure: no I/O, no clock.

A serial line delivers fragments: garbage before a header (line noise, a servo
powering up, the tail of a reply that timed out), half a packet, several packets at
once. :class:`StatusParser` (host side) and :class:`InstructionParser` (servo or
emulator side) take any chunks and give back complete, checked packets::

    parser = StatusParser()
    parser.feed(chunk)              # whatever the transport read
    for packet in parser:           # complete packets so far, oldest first
        ...

Resynchronisation follows the e-Manual's "Processing Order of Reception": search for
``FF FF FD 00`` (a stuffed ``FF FF FD FD`` is not a header), read the id and length,
wait for that many bytes, check the CRC on the stuffed bytes, then unstuff. A header
whose id or length is impossible is skipped at once. So is a header followed, inside
the frame it claims, by ``FF FF FD`` without its stuffing byte: no real frame contains
that, so a false header in garbage with a large length cannot hold back the real
packets behind it. A frame that fails its CRC raises
:class:`~arm_driver.errors.CrcError` once, after its first byte has been dropped, and
parsing resumes at the next header: no packet after it is lost.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Generic, TypeVar

from arm_driver.dynamixel.protocol import (
    HEADER,
    LENGTH_MAX,
    PREAMBLE,
    STUFF_PATTERN,
    InstructionPacket,
    StatusPacket,
    decode_packet,
)
from arm_driver.errors import CommunicationError

__all__ = ["DEFAULT_MAX_LENGTH", "InstructionParser", "StatusParser"]

DEFAULT_MAX_LENGTH = 1024
"""Largest length field accepted by default [bytes] (DynamixelSDK's ``RXPACKET_MAX_LEN``);
a read of the whole XM430 control table (662 bytes) fits."""

P = TypeVar("P", StatusPacket, InstructionPacket)


class _PacketParser(Generic[P]):
    """Frames packets of type ``_wanted`` out of a byte stream; see the module docstring."""

    _wanted: type[P]

    def __init__(self, *, max_length: int = DEFAULT_MAX_LENGTH) -> None:
        if not 4 <= max_length <= LENGTH_MAX:
            raise ValueError(f"max_length {max_length} out of range (4-{LENGTH_MAX})")
        self._buffer = bytearray()
        self._max_length = max_length
        self.discarded_bytes = 0
        """Bytes dropped while looking for a header (garbage, false or damaged frames)."""
        self.skipped_packets = 0
        """Valid packets of the other kind skipped (e.g. the echo of our own instructions)."""

    @property
    def buffered(self) -> int:
        """Bytes received but not yet returned in a packet or discarded."""
        return len(self._buffer)

    def feed(self, data: bytes) -> None:
        """Append bytes received from the line (any chunk: a fragment or many packets)."""
        self._buffer += data

    def clear(self) -> None:
        """Drop everything buffered (e.g. after a timeout, before the next request)."""
        self.discarded_bytes += len(self._buffer)
        self._buffer.clear()

    def __iter__(self) -> Iterator[P]:
        """Yield the complete packets buffered so far (see :meth:`next_packet`)."""
        while (packet := self.next_packet()) is not None:
            yield packet

    def next_packet(self) -> P | None:
        """Return the next complete packet, or None until more bytes are fed.

        Raises
        ------
        CommunicationError
            A frame with a plausible header failed its checks (CRC, stuffing, contents).
            Its first byte is dropped before raising, so the next call resynchronises on
            the following header.
        """
        buffer = self._buffer
        while True:
            start = buffer.find(HEADER)
            if start < 0:
                self._drop(len(buffer) - self._header_prefix())
                return None
            self._drop(start)
            if len(buffer) < PREAMBLE:
                return None
            length = buffer[5] | buffer[6] << 8
            if buffer[4] in (0xFD, 0xFF) or not 3 <= length <= self._max_length:
                self._drop(1)  # not a header: impossible id or length
                continue
            total = PREAMBLE + length
            if self._impossible_stuffing(total):
                self._drop(1)  # a header inside the frame it claims: a false header
                continue
            if len(buffer) < total:
                return None
            try:
                packet = decode_packet(bytes(buffer[:total]))
            except CommunicationError:
                self._drop(1)
                raise
            del buffer[:total]
            if isinstance(packet, self._wanted):
                return packet
            self.skipped_packets += 1

    def _drop(self, count: int) -> None:
        if count > 0:
            del self._buffer[:count]
            self.discarded_bytes += count

    def _header_prefix(self) -> int:
        """Length of the longest proper prefix of HEADER that ends the buffer."""
        for size in (3, 2, 1):
            if self._buffer.endswith(HEADER[:size]):
                return size
        return 0

    def _impossible_stuffing(self, total: int) -> bool:
        """True if the stuffed area received so far has FF FF FD not followed by FD."""
        buffer = self._buffer
        end = min(len(buffer), total - 2)
        position = buffer.find(STUFF_PATTERN, PREAMBLE, end)
        while position >= 0:
            after = position + 3
            if after == total - 2 or (after < end and buffer[after] != 0xFD):
                return True
            position = buffer.find(STUFF_PATTERN, after, end)
        return False


class StatusParser(_PacketParser[StatusPacket]):
    """Frame :class:`~arm_driver.dynamixel.protocol.StatusPacket` objects (host side).

    Instruction packets (the echo of our own on a bus that echoes, another master's)
    are skipped and counted in :attr:`skipped_packets`. The error byte is decoded,
    not acted on: pass packets to the reply parsers or to ``check_status``.

    Parameters
    ----------
    max_length
        Largest length field accepted [bytes after the length field].
    """

    _wanted = StatusPacket


class InstructionParser(_PacketParser[InstructionPacket]):
    """Frame :class:`~arm_driver.dynamixel.protocol.InstructionPacket` objects.

    The servo (emulator) side counterpart of :class:`StatusParser`: status packets
    from other servos on the bus are skipped and counted in :attr:`skipped_packets`.

    Parameters
    ----------
    max_length
        Largest length field accepted [bytes after the length field].
    """

    _wanted = InstructionPacket

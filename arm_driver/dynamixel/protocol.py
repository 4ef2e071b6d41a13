"""DYNAMIXEL Protocol 2.0 framing: CRC-16, byte stuffing, packets, a stream parser.

Pure functions over bytes (no I/O, no clock, no global state); the transport moves the
bytes and the bus decides what to send and when to give up waiting.

Packet layout (ROBOTIS e-Manual, "DYNAMIXEL Protocol 2.0", Instruction / Status Packet)::

    FF FF FD 00 | ID | LEN_L LEN_H | INST | [ERR] | PARAM ... | CRC_L CRC_H

- header ``FF FF FD`` and reserved ``00``;
- ID 0-252 (0x00-0xFC), 254 (0xFE) is the broadcast id; 253 and 255 are never used;
- length (little-endian) counts the bytes after it: instruction, [error], parameters
  *after stuffing*, and the two CRC bytes;
- a status packet has instruction 0x55 and one error byte: bit 7 is the Alert flag,
  bits 0-6 the error number (:class:`~arm_driver.errors.StatusError`);
- CRC-16 over everything from the header to the last parameter byte (stuffing
  included), polynomial 0x8005, initial value 0, no reflection (the e-Manual's
  ``update_crc``; DynamixelSDK ``protocol2_packet_handler.updateCRC`` uses the same
  256-entry table; computed by fastcrc, as pymavlink computes MAVLink's);
- byte stuffing (e-Manual, "Packet Process"): in the instruction-to-parameters area
  every ``FF FF FD`` becomes ``FF FF FD FD``, so a header never appears inside a
  packet; the receiver checks the CRC on the stuffed bytes, then removes the stuffing.

Errors: malformed bytes raise :class:`~arm_driver.errors.CommunicationError` (or its
:class:`~arm_driver.errors.CrcError`); a well-formed status packet whose error byte is
nonzero is turned into :class:`~arm_driver.errors.InstructionError` or
:class:`~arm_driver.errors.HardwareError` by :func:`check_status`. Bad arguments
(an id out of range, too many parameters) raise ``ValueError``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from fastcrc.crc16 import umts as crc16_umts

from arm_driver.errors import CommunicationError, CrcError, HardwareError, InstructionError

__all__ = [
    "ALERT_BIT",
    "BROADCAST_ID",
    "HEADER",
    "LENGTH_MAX",
    "MAX_ID",
    "PREAMBLE",
    "STUFF_PATTERN",
    "Instruction",
    "InstructionPacket",
    "StatusPacket",
    "check_status",
    "crc16",
    "decode_instruction",
    "decode_packet",
    "decode_status",
    "encode_instruction",
    "encode_status",
    "stuff",
    "unstuff",
]

HEADER = b"\xff\xff\xfd\x00"
"""Header (``FF FF FD``) and reserved byte (``00``) that start every packet."""
BROADCAST_ID = 0xFE
"""Packet id addressing every servo on the bus."""
MAX_ID = 0xFC
"""Largest id a single servo can have (252)."""
ALERT_BIT = 0x80
"""Alert flag in a status packet's error byte."""

STUFF_PATTERN = b"\xff\xff\xfd"
"""The byte sequence that byte stuffing escapes (a header without its reserved byte)."""
_STUFFED = b"\xff\xff\xfd\xfd"
PREAMBLE = 7
"""Bytes before the instruction: header (3), reserved, id, length (2)."""
LENGTH_MAX = 0xFFFF
"""Largest value of the 16-bit length field."""


class Instruction(enum.IntEnum):
    """Instruction codes (e-Manual, Protocol 2.0, "Instruction")."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    BULK_READ = 0x92
    BULK_WRITE = 0x93


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16 of DYNAMIXEL Protocol 2.0 (polynomial 0x8005, MSB first, initial 0): the
    CRC-16/UMTS of fastcrc's catalogue, whose table is the e-Manual's and the SDK's.

    Parameters
    ----------
    data
        Bytes to checksum: a whole packet from the header to the last parameter.
    crc
        Running value to continue from (0 for a new packet).

    Returns
    -------
    int
        The 16-bit CRC; the packet carries it little-endian (CRC_L, CRC_H).
    """
    return crc16_umts(data, crc)


def stuff(data: bytes) -> bytes:
    """Byte-stuff the instruction-to-parameters area: ``FF FF FD`` -> ``FF FF FD FD``.

    ``FF FF FD`` cannot overlap itself, so replacing every occurrence is exactly the
    e-Manual's rule (a stuffing ``FD`` after each ``FF FF FD`` found in the data).
    """
    return bytes(data).replace(STUFF_PATTERN, _STUFFED)


def unstuff(data: bytes) -> bytes:
    """Undo :func:`stuff`.

    Raises
    ------
    CommunicationError
        If some ``FF FF FD`` is not followed by the stuffing ``FD``: such bytes were not
        made by :func:`stuff` (a header inside a packet, or a damaged packet).
    """
    data = bytes(data)
    if data.count(STUFF_PATTERN) != data.count(_STUFFED):
        raise CommunicationError("malformed packet: FF FF FD without its stuffing byte FD")
    return data.replace(_STUFFED, STUFF_PATTERN)


def _check_id(servo_id: int, *, broadcast: bool) -> None:
    if not (0 <= servo_id <= MAX_ID or (broadcast and servo_id == BROADCAST_ID)):
        allowed = "0-252 or 254 (broadcast)" if broadcast else "0-252"
        raise ValueError(f"servo id {servo_id} out of range ({allowed})")


def _frame(servo_id: int, body: bytes) -> bytes:
    stuffed = stuff(body)
    length = len(stuffed) + 2
    if length > LENGTH_MAX:
        raise ValueError(f"packet too long: length {length} > {LENGTH_MAX}")
    packet = bytearray(HEADER)
    packet += bytes((servo_id, length & 0xFF, length >> 8))
    packet += stuffed
    crc = crc16(packet)
    packet += bytes((crc & 0xFF, crc >> 8))
    return bytes(packet)


def _unframe(data: bytes) -> tuple[int, bytes]:
    """Check one complete frame and return its id and unstuffed instruction + rest."""
    if len(data) < PREAMBLE + 3:
        raise CommunicationError(f"malformed packet: {len(data)} bytes is too short")
    if data[:4] != HEADER:
        raise CommunicationError(f"malformed packet: bad header {data[:4].hex(' ')}")
    servo_id = data[4]
    length = data[5] | data[6] << 8
    if len(data) != PREAMBLE + length:
        raise CommunicationError(
            f"malformed packet from id {servo_id}: length field {length} needs "
            f"{PREAMBLE + length} bytes, got {len(data)}",
            servo_id=servo_id,
        )
    received = data[-2] | data[-1] << 8
    computed = crc16(memoryview(data)[:-2])
    if computed != received:
        raise CrcError(computed, received, servo_id=servo_id)
    if servo_id > BROADCAST_ID or servo_id == 0xFD:
        raise CommunicationError(f"malformed packet: invalid id {servo_id}")
    body = data[PREAMBLE:-2]
    if STUFF_PATTERN not in body:
        return servo_id, body
    try:
        return servo_id, unstuff(body)
    except CommunicationError as error:
        raise CommunicationError(f"id {servo_id}: {error}", servo_id=servo_id) from None


@dataclass(frozen=True)
class InstructionPacket:
    """An instruction packet, as sent by the host (and decoded by a servo emulator).

    Attributes
    ----------
    servo_id
        Target id: 0-252, or 254 (:data:`BROADCAST_ID`).
    instruction
        Instruction code (:class:`Instruction`, or any other byte but 0x55).
    params
        Parameters, unstuffed.
    """

    servo_id: int
    instruction: int
    params: bytes = b""

    def __post_init__(self) -> None:
        _check_id(self.servo_id, broadcast=True)
        if not 0 <= self.instruction <= 0xFF or self.instruction == Instruction.STATUS:
            raise ValueError(f"instruction 0x{self.instruction:X} is not an instruction")
        object.__setattr__(self, "params", bytes(self.params))


@dataclass(frozen=True)
class StatusPacket:
    """A status packet, as returned by a servo.

    Attributes
    ----------
    servo_id
        Id of the servo that answered (0-252).
    error
        Error number, bits 0-6 of the error byte (0: none; see
        :class:`~arm_driver.errors.StatusError`).
    alert
        Alert flag, bit 7 of the error byte: the servo has a hardware fault.
    params
        Parameters, unstuffed (e.g. the data of a Read).
    """

    servo_id: int
    error: int = 0
    alert: bool = False
    params: bytes = b""

    def __post_init__(self) -> None:
        _check_id(self.servo_id, broadcast=False)
        if not 0 <= self.error < ALERT_BIT:
            raise ValueError(f"status error number {self.error} out of range (0-127)")
        object.__setattr__(self, "alert", bool(self.alert))
        object.__setattr__(self, "params", bytes(self.params))


def encode_instruction(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """Encode an instruction packet (stuffing, length and CRC applied).

    Parameters
    ----------
    servo_id
        Target id, 0-252 or 254 (broadcast).
    instruction
        Instruction code (not 0x55, which marks status packets).
    params
        Parameters before stuffing.

    Returns
    -------
    bytes
        The packet as it goes on the wire.
    """
    packet = InstructionPacket(servo_id, instruction, params)
    return _frame(packet.servo_id, bytes((packet.instruction,)) + packet.params)


def decode_instruction(data: bytes) -> InstructionPacket:
    """Decode one complete instruction packet (what a servo, or its emulator, receives).

    Raises
    ------
    CommunicationError
        Bad header, length, id, stuffing, or a status packet (instruction 0x55).
    CrcError
        CRC mismatch.
    """
    return _instruction_from_body(*_unframe(bytes(data)))


def _instruction_from_body(servo_id: int, body: bytes) -> InstructionPacket:
    if body[0] == Instruction.STATUS:
        raise CommunicationError(
            f"id {servo_id}: expected an instruction packet, got a status packet",
            servo_id=servo_id,
        )
    try:
        instruction: int = Instruction(body[0])
    except ValueError:
        instruction = body[0]
    return InstructionPacket(servo_id, instruction, body[1:])


def encode_status(
    servo_id: int, error: int = 0, params: bytes = b"", *, alert: bool = False
) -> bytes:
    """Encode a status packet (what a servo, or its emulator, sends back).

    Parameters
    ----------
    servo_id
        Id of the answering servo, 0-252.
    error
        Error number (0-127).
    params
        Parameters before stuffing.
    alert
        Set the Alert bit (0x80): the servo has a hardware fault.
    """
    packet = StatusPacket(servo_id, error, alert, params)
    error_byte = packet.error | (ALERT_BIT if packet.alert else 0)
    return _frame(packet.servo_id, bytes((Instruction.STATUS, error_byte)) + packet.params)


def decode_status(data: bytes) -> StatusPacket:
    """Decode one complete status packet.

    The error byte is decoded, not acted on: :func:`check_status` raises for it.

    Raises
    ------
    CommunicationError
        Bad header, length, id, stuffing, or not a status packet.
    CrcError
        CRC mismatch.
    """
    return _status_from_body(*_unframe(bytes(data)))


def _status_from_body(servo_id: int, body: bytes) -> StatusPacket:
    if body[0] != Instruction.STATUS or len(body) < 2:
        raise CommunicationError(
            f"id {servo_id}: expected a status packet (instruction 0x55 and an error "
            f"byte), got instruction 0x{body[0]:02X} with {len(body) - 1} more byte(s)",
            servo_id=servo_id,
        )
    if servo_id > MAX_ID:
        raise CommunicationError(f"status packet with invalid id {servo_id}")
    return StatusPacket(servo_id, body[1] & ~ALERT_BIT, bool(body[1] & ALERT_BIT), body[2:])


def decode_packet(data: bytes) -> StatusPacket | InstructionPacket:
    """Decode one complete packet of either kind (instruction 0x55: a status packet).

    Raises
    ------
    CommunicationError
        Bad header, length, id or stuffing.
    CrcError
        CRC mismatch.
    """
    servo_id, body = _unframe(bytes(data))
    if body[0] == Instruction.STATUS:
        return _status_from_body(servo_id, body)
    return _instruction_from_body(servo_id, body)


def check_status(packet: StatusPacket, *, ignore_alert: bool = False) -> StatusPacket:
    """Raise for a status packet that reports an error; return it unchanged otherwise.

    Parameters
    ----------
    packet
        Decoded status packet.
    ignore_alert
        Accept a packet whose Alert bit is set (used to read Hardware Error Status,
        address 70, from a faulted servo: every reply of that servo has Alert set).

    Raises
    ------
    HardwareError
        Alert bit set (and not ignored); ``status`` is None: the codec cannot know the
        bits of address 70, the bus reads them.
    InstructionError
        Nonzero error number.
    """
    if packet.alert and not ignore_alert:
        raise HardwareError(packet.servo_id, None, error_number=packet.error)
    if packet.error:
        raise InstructionError(packet.servo_id, packet.error)
    return packet

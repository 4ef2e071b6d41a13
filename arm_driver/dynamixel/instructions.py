"""Protocol 2.0 instructions the driver uses, their replies, and control-table fields.

Builders return the packet bytes to send; reply parsers take decoded
:class:`~arm_driver.dynamixel.protocol.StatusPacket` objects, check them
(:func:`~arm_driver.dynamixel.protocol.check_status`) and return the data. Pure: no I/O.

Parameter layouts (ROBOTIS e-Manual, "DYNAMIXEL Protocol 2.0", Instruction Details):

=============  ======  =============================================================
instruction    code    parameters (all multi-byte values little-endian)
=============  ======  =============================================================
Ping           0x01    none; reply: model number (2), firmware version (1)
Read           0x02    address (2), length (2); reply: the data
Write          0x03    address (2), data; reply: none
Reboot         0x08    none; reply: none
Sync Read      0x82    address (2), length (2), ids; one reply per id, in id order
Sync Write     0x83    address (2), length (2), then per servo: id, data (length)
=============  ======  =============================================================

Which instructions are answered: a Ping always (a broadcast Ping by every servo); Read
and Write sent to the broadcast id never; otherwise per Status Return Level(68) (0:
Ping only, 1: Ping and Read, 2: all; factory value 2). Sync Read and Sync Write go to
the broadcast id; Sync Write is never answered.

Fault handling: every reply parser raises :class:`~arm_driver.errors.InstructionError`
for a nonzero error number and :class:`~arm_driver.errors.HardwareError` for the Alert
bit, unless ``ignore_alert=True`` (how the bus reads Hardware Error Status, address 70,
from a faulted servo, before raising ``HardwareError`` with the decoded bits). A reply
from the wrong servo or of the wrong size raises
:class:`~arm_driver.errors.CommunicationError`.

Field helpers encode and decode control-table values: little-endian, 1, 2 or 4 bytes,
unsigned or two's-complement signed (the XM430 stores negative Goal Current, Goal
Velocity, Goal Position, Homing Offset and Present values in two's complement).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from arm_driver.dynamixel.protocol import (
    BROADCAST_ID,
    PREAMBLE,
    STUFF_PATTERN,
    Instruction,
    StatusPacket,
    _check_id,
    check_status,
    crc16,
    encode_instruction,
)
from arm_driver.errors import CommunicationError

__all__ = [
    "FIELD_SIZES",
    "PingReply",
    "SyncWriteFrame",
    "decode_int",
    "decode_uint",
    "encode_int",
    "encode_ping",
    "encode_read",
    "encode_reboot",
    "encode_sync_read",
    "encode_sync_write",
    "encode_uint",
    "encode_write",
    "parse_ping_reply",
    "parse_read_reply",
    "parse_sync_read_replies",
    "parse_write_reply",
]

FIELD_SIZES = (1, 2, 4)
"""Sizes of control-table fields [bytes]."""

_ADDRESS_MAX = 0xFFFF


def _check_size(size: int) -> None:
    if size not in FIELD_SIZES:
        raise ValueError(f"field size {size} bytes is not one of {FIELD_SIZES}")


def encode_uint(value: int, size: int) -> bytes:
    """Encode an unsigned field, little-endian.

    Parameters
    ----------
    value
        Raw value, 0 to 2**(8 size) - 1.
    size
        Field size [bytes]: 1, 2 or 4.

    Raises
    ------
    ValueError
        Size not 1, 2 or 4, or value out of range for it.
    """
    _check_size(size)
    if not 0 <= value < 1 << (8 * size):
        raise ValueError(f"{value} does not fit an unsigned {size}-byte field")
    return int(value).to_bytes(size, "little", signed=False)


def encode_int(value: int, size: int) -> bytes:
    """Encode a signed (two's complement) field, little-endian.

    Parameters
    ----------
    value
        Raw value, -2**(8 size - 1) to 2**(8 size - 1) - 1.
    size
        Field size [bytes]: 1, 2 or 4.

    Raises
    ------
    ValueError
        Size not 1, 2 or 4, or value out of range for it.
    """
    _check_size(size)
    half = 1 << (8 * size - 1)
    if not -half <= value < half:
        raise ValueError(f"{value} does not fit a signed {size}-byte field")
    return int(value).to_bytes(size, "little", signed=True)


def decode_uint(data: bytes) -> int:
    """Decode an unsigned little-endian field of 1, 2 or 4 bytes."""
    _check_size(len(data))
    return int.from_bytes(data, "little", signed=False)


def decode_int(data: bytes) -> int:
    """Decode a signed (two's complement) little-endian field of 1, 2 or 4 bytes."""
    _check_size(len(data))
    return int.from_bytes(data, "little", signed=True)


def _address_length(address: int, length: int) -> bytes:
    if not 0 <= address <= _ADDRESS_MAX:
        raise ValueError(f"address {address} out of range (0-{_ADDRESS_MAX})")
    if not 1 <= length <= _ADDRESS_MAX:
        raise ValueError(f"data length {length} out of range (1-{_ADDRESS_MAX})")
    return address.to_bytes(2, "little") + length.to_bytes(2, "little")


def encode_ping(servo_id: int) -> bytes:
    """Ping packet, to one servo or to every servo (``BROADCAST_ID``)."""
    return encode_instruction(servo_id, Instruction.PING)


def encode_read(servo_id: int, address: int, length: int) -> bytes:
    """Read packet: ``length`` bytes from control-table ``address`` of one servo.

    The broadcast id is refused: a broadcast Read is never answered.
    """
    _check_id(servo_id, broadcast=False)
    return encode_instruction(servo_id, Instruction.READ, _address_length(address, length))


def encode_write(servo_id: int, address: int, data: bytes) -> bytes:
    """Write packet: ``data`` to control-table ``address`` of one servo, or of all.

    EEPROM addresses (below 64 on the XM430) can only be written with torque off.
    """
    header = _address_length(address, len(data))[:2]
    return encode_instruction(servo_id, Instruction.WRITE, header + bytes(data))


def encode_reboot(servo_id: int) -> bytes:
    """Reboot packet: the only way to turn torque on again after a hardware shutdown."""
    return encode_instruction(servo_id, Instruction.REBOOT)


def _check_ids(ids: Sequence[int]) -> None:
    if not ids:
        raise ValueError("no servo ids given")
    for servo_id in ids:
        _check_id(servo_id, broadcast=False)
    if len(set(ids)) != len(ids):
        raise ValueError(f"duplicate servo ids in {list(ids)}")


def encode_sync_read(address: int, length: int, ids: Sequence[int]) -> bytes:
    """Sync Read packet (broadcast): the same ``length`` bytes at ``address`` of each id.

    Each servo answers with its own status packet; see :func:`parse_sync_read_replies`.
    """
    ids = list(ids)
    _check_ids(ids)
    params = _address_length(address, length) + bytes(ids)
    return encode_instruction(BROADCAST_ID, Instruction.SYNC_READ, params)


def encode_sync_write(address: int, length: int, data: Mapping[int, bytes]) -> bytes:
    """Sync Write packet (broadcast): per servo id, ``length`` bytes at ``address``.

    Parameters
    ----------
    address
        Control-table address, the same for every servo.
    length
        Bytes written to each servo.
    data
        Servo id -> its data (exactly ``length`` bytes), sent in the mapping's order.

    Raises
    ------
    ValueError
        No servo, an id out of range, or data of the wrong length.
    """
    ids = list(data)
    _check_ids(ids)
    params = bytearray(_address_length(address, length))
    for servo_id, value in data.items():
        if len(value) != length:
            raise ValueError(f"servo {servo_id}: {len(value)} bytes of data, expected {length}")
        params.append(servo_id)
        params += value
    return encode_instruction(BROADCAST_ID, Instruction.SYNC_WRITE, bytes(params))


class SyncWriteFrame:
    """Sync Write packets of one field to the same servos in the same order: the bytes of
    :func:`encode_sync_write`, with the fixed start (header, broadcast id, length,
    instruction, address, data length) and its CRC-16 made once; each packet adds the ids
    and data and continues the CRC over them.

    Byte stuffing can only come from inside one servo's data (ids are at most 0xFC, so
    ``FF FF FD`` cannot span an id); a packet whose data needs it is made by
    :func:`encode_sync_write`.

    Parameters
    ----------
    address, length
        As for :func:`encode_sync_write`: the control-table address and the bytes
        written to each servo.
    ids
        Servo ids, in the order their data is given and sent.

    Raises
    ------
    ValueError
        No servo, an id out of range or twice, or an address or length out of range.
    """

    def __init__(self, address: int, length: int, ids: Sequence[int]) -> None:
        self.ids = tuple(ids)
        _check_ids(self.ids)
        self._address = address
        self._length = length
        blank = encode_sync_write(address, length, dict.fromkeys(self.ids, bytes(length)))
        self._start = blank[: PREAMBLE + 5]
        self._start_crc = crc16(self._start)
        self._id_bytes = tuple(bytes((servo_id,)) for servo_id in self.ids)

    def packet(self, data: Sequence[bytes]) -> bytes:
        """The Sync Write packet of ``data``, one value of ``length`` bytes per id, in the
        order of :attr:`ids`.

        Raises
        ------
        ValueError
            Not one value per id, or a value of the wrong length.
        """
        if len(data) != len(self.ids):
            raise ValueError(f"{len(data)} values for servo ids {list(self.ids)}")
        parts = []
        for id_byte, value in zip(self._id_bytes, data, strict=True):
            if len(value) != self._length:
                raise ValueError(
                    f"servo {id_byte[0]}: {len(value)} bytes of data, expected {self._length}"
                )
            parts.append(id_byte)
            parts.append(value)
        tail = b"".join(parts)
        if STUFF_PATTERN in tail:
            by_id = dict(zip(self.ids, data, strict=True))
            return encode_sync_write(self._address, self._length, by_id)
        return self._start + tail + crc16(tail, self._start_crc).to_bytes(2, "little")


@dataclass(frozen=True)
class PingReply:
    """What a servo says about itself in reply to a Ping.

    Attributes
    ----------
    servo_id
        Id of the servo that answered.
    model_number
        Model number (1020 for the XM430-W350).
    firmware_version
        Firmware version.
    """

    servo_id: int
    model_number: int
    firmware_version: int


def _checked(
    packet: StatusPacket, servo_id: int | None, size: int, what: str, ignore_alert: bool
) -> StatusPacket:
    if servo_id is not None and packet.servo_id != servo_id:
        raise CommunicationError(
            f"servo {servo_id}: {what} reply came from servo {packet.servo_id}",
            servo_id=servo_id,
        )
    check_status(packet, ignore_alert=ignore_alert)
    if len(packet.params) != size:
        raise CommunicationError(
            f"servo {packet.servo_id}: {what} reply carries {len(packet.params)} "
            f"parameter byte(s), expected {size}",
            servo_id=packet.servo_id,
        )
    return packet


def parse_ping_reply(
    packet: StatusPacket, servo_id: int | None = None, *, ignore_alert: bool = False
) -> PingReply:
    """Model number and firmware version from a Ping reply.

    Parameters
    ----------
    packet
        Decoded status packet.
    servo_id
        Id pinged, or None after a broadcast Ping (any id is accepted).
    ignore_alert
        Accept a reply whose Alert bit is set.
    """
    params = _checked(packet, servo_id, 3, "Ping", ignore_alert).params
    return PingReply(packet.servo_id, params[0] | params[1] << 8, params[2])


def parse_read_reply(
    packet: StatusPacket, servo_id: int, length: int, *, ignore_alert: bool = False
) -> bytes:
    """The data of a Read (or of one servo's Sync Read) reply.

    Parameters
    ----------
    packet
        Decoded status packet.
    servo_id
        Id that was read.
    length
        Bytes that were asked for.
    ignore_alert
        Accept a reply whose Alert bit is set.
    """
    return _checked(packet, servo_id, length, "Read", ignore_alert).params


def parse_write_reply(packet: StatusPacket, servo_id: int, *, ignore_alert: bool = False) -> None:
    """Check a Write (or Reboot) reply: no error and no parameter."""
    _checked(packet, servo_id, 0, "Write", ignore_alert)


def parse_sync_read_replies(
    packets: Iterable[StatusPacket],
    ids: Sequence[int],
    length: int,
    *,
    ignore_alert: bool = False,
) -> dict[int, bytes]:
    """The data of a Sync Read: exactly one status packet per id asked, in any order.

    Parameters
    ----------
    packets
        Decoded status packets received after the Sync Read.
    ids
        Ids that were asked, as given to :func:`encode_sync_read`.
    length
        Bytes asked from each servo.
    ignore_alert
        Accept replies whose Alert bit is set.

    Returns
    -------
    dict
        Servo id -> its data, in the order of ``ids``.

    Raises
    ------
    CommunicationError
        A reply from a servo not asked, two replies from one servo, a missing reply, or
        a reply of the wrong size. (The bus reports missing replies at its deadline as
        :class:`~arm_driver.errors.BusTimeoutError` before calling this.)
    """
    wanted = set(ids)
    replies: dict[int, bytes] = {}
    for packet in packets:
        if packet.servo_id not in wanted:
            raise CommunicationError(
                f"Sync Read reply from servo {packet.servo_id}, which was not asked "
                f"(asked: {list(ids)})",
                servo_id=packet.servo_id,
            )
        if packet.servo_id in replies:
            raise CommunicationError(
                f"servo {packet.servo_id}: two replies to one Sync Read",
                servo_id=packet.servo_id,
            )
        replies[packet.servo_id] = _checked(
            packet, packet.servo_id, length, "Sync Read", ignore_alert
        ).params
    missing = [servo_id for servo_id in ids if servo_id not in replies]
    if missing:
        raise CommunicationError(
            f"no Sync Read reply from servo(s) {missing}",
            servo_id=missing[0] if len(missing) == 1 else None,
        )
    return {servo_id: replies[servo_id] for servo_id in ids}

"""DYNAMIXEL Protocol 2.0 codec for the XM430-W350: pure functions over bytes.

- :mod:`~arm_driver.dynamixel.protocol`: CRC-16, byte stuffing, instruction and
  status packets, status error byte -> typed exceptions;
- :mod:`~arm_driver.dynamixel.stream`: packets out of a byte stream (fragments,
  garbage, several packets per chunk);
- :mod:`~arm_driver.dynamixel.instructions`: Ping, Read, Write, Reboot, Sync Read,
  Sync Write packets and their replies; little-endian field helpers;
- :mod:`~arm_driver.dynamixel.control_table`: the XM430-W350 entries the driver uses;
- :mod:`~arm_driver.dynamixel.units`: raw units <-> SI.

Nothing here does I/O: the transport moves bytes, the bus decides what to send.
"""

from arm_driver.dynamixel import control_table, units
from arm_driver.dynamixel.instructions import (
    FIELD_SIZES,
    PingReply,
    SyncWriteFrame,
    decode_int,
    decode_uint,
    encode_int,
    encode_ping,
    encode_read,
    encode_reboot,
    encode_sync_read,
    encode_sync_write,
    encode_uint,
    encode_write,
    parse_ping_reply,
    parse_read_reply,
    parse_sync_read_replies,
    parse_write_reply,
)
from arm_driver.dynamixel.protocol import (
    ALERT_BIT,
    BROADCAST_ID,
    HEADER,
    MAX_ID,
    Instruction,
    InstructionPacket,
    StatusPacket,
    check_status,
    crc16,
    decode_instruction,
    decode_packet,
    decode_status,
    encode_instruction,
    encode_status,
    stuff,
    unstuff,
)
from arm_driver.dynamixel.stream import DEFAULT_MAX_LENGTH, InstructionParser, StatusParser

__all__ = [
    "ALERT_BIT",
    "BROADCAST_ID",
    "DEFAULT_MAX_LENGTH",
    "FIELD_SIZES",
    "HEADER",
    "MAX_ID",
    "Instruction",
    "InstructionPacket",
    "InstructionParser",
    "PingReply",
    "StatusPacket",
    "StatusParser",
    "SyncWriteFrame",
    "check_status",
    "control_table",
    "crc16",
    "decode_instruction",
    "decode_int",
    "decode_packet",
    "decode_status",
    "decode_uint",
    "encode_instruction",
    "encode_int",
    "encode_ping",
    "encode_read",
    "encode_reboot",
    "encode_status",
    "encode_sync_read",
    "encode_sync_write",
    "encode_uint",
    "encode_write",
    "parse_ping_reply",
    "parse_read_reply",
    "parse_sync_read_replies",
    "parse_write_reply",
    "stuff",
    "units",
    "unstuff",
]

"""The two messages of every control cycle, read and framed without pymavlink's message
objects: ODOMETRY in, SET_ATTITUDE_TARGET out.

The control cycle runs on every ODOMETRY (125 Hz) and answers with a SET_ATTITUDE_TARGET,
and pymavlink's generic codec costs more than the rest of their handling: it copies a
frame through its stream buffer and lays the 233-byte ODOMETRY payload's 18 fields (two
covariance arrays of 21) out into a message object, and it builds a message object for
each setpoint before packing it.

- :func:`odometry_frame` checks one whole frame as pymavlink does (MAVLink 2 marker,
  length, no signature, the CRC with ODOMETRY's ``CRC_EXTRA``) and unpacks its payload
  (zero-padded where MAVLink 2 trimmed trailing zeros) with the same layout. Any other
  frame (another message, a signed or MAVLink 1 frame, a bad CRC, bytes around it) is
  None: the link's reader hands those to pymavlink as before.
- :func:`attitude_target_frame` packs an unsigned MAVLink 2 SET_ATTITUDE_TARGET frame,
  byte for byte what pymavlink packs (payload layout, trailing zeros trimmed, CRC).

Pure: bytes in, fields out; values in, bytes out.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from pymavlink.dialects.v20 import common as mavlink2
from pymavlink.generator.mavcrc import x25crc

__all__ = ["ODOMETRY_ID", "OdometryFields", "attitude_target_frame", "odometry_frame"]

_MESSAGE = mavlink2.MAVLink_odometry_message
ODOMETRY_ID = _MESSAGE.id
"""ODOMETRY's message id (331)."""
_PAYLOAD = struct.Struct(_MESSAGE.unpacker.format)
"""The payload's wire layout (pymavlink's: fields sorted by size, extensions last)."""
_HEADER = struct.Struct("<BBBBBBBHB")
_HEADER_LEN = _HEADER.size
_CRC = struct.Struct("<H")
_CRC_EXTRA = bytes((_MESSAGE.crc_extra,))
_MAGIC_V2 = mavlink2.PROTOCOL_MARKER_V2
_PAD = bytes(_PAYLOAD.size)
_TARGET = mavlink2.MAVLink_set_attitude_target_message
_TARGET_PAYLOAD = struct.Struct(_TARGET.unpacker.format)
_TARGET_CRC_EXTRA = bytes((_TARGET.crc_extra,))
_TARGET_ID_LOW, _TARGET_ID_HIGH = _TARGET.id & 0xFFFF, _TARGET.id >> 16


class OdometryFields(NamedTuple):
    """One ODOMETRY's header and fields, under pymavlink's field names (NED / FRD, SI
    units as MAVLink sends them; see :meth:`TelemetryDecoder.odometry
    <companion.link.telemetry.TelemetryDecoder.odometry>`)."""

    seq: int
    src_system: int
    src_component: int
    time_usec: int
    frame_id: int
    child_frame_id: int
    x: float
    y: float
    z: float
    q: tuple[float, ...]
    vx: float
    vy: float
    vz: float
    rollspeed: float
    pitchspeed: float
    yawspeed: float
    pose_covariance: tuple[float, ...]
    velocity_covariance: tuple[float, ...]
    reset_counter: int


def odometry_frame(data: bytes) -> OdometryFields | None:
    """The fields of ``data`` when it is exactly one unsigned MAVLink 2 ODOMETRY frame with
    a good CRC; otherwise None (nothing raised: pymavlink then parses it)."""
    n = len(data)
    if n < _HEADER_LEN + 2 or data[0] != _MAGIC_V2 or data[2] != 0:
        return None
    _, length, _, _, seq, system, component, id_low, id_high = _HEADER.unpack_from(data)
    if (
        (id_low | (id_high << 16)) != ODOMETRY_ID
        or n != _HEADER_LEN + length + 2
        or length > _PAYLOAD.size
    ):
        return None
    end = _HEADER_LEN + length
    if x25crc(data[1:end] + _CRC_EXTRA).crc != _CRC.unpack_from(data, end)[0]:
        return None
    payload = data[_HEADER_LEN:end]
    if length < _PAYLOAD.size:
        payload += _PAD[length:]
    f = _PAYLOAD.unpack(payload)
    return OdometryFields(
        seq, system, component, f[0], f[56], f[57], f[1], f[2], f[3], f[4:8], f[8], f[9],
        f[10], f[11], f[12], f[13], f[14:35], f[35:56], f[58],
    )  # fmt: skip


def attitude_target_frame(
    seq: int,
    src_system: int,
    src_component: int,
    time_boot_ms: int,
    target_system: int,
    target_component: int,
    type_mask: int,
    q: tuple[float, float, float, float] | list[float],
    thrust: float,
) -> bytes:
    """SET_ATTITUDE_TARGET as an unsigned MAVLink 2 frame with sequence number ``seq``,
    from ``src_system`` / ``src_component``: ``time_boot_ms`` [ms] (modulo 2^32 already),
    the target, ``type_mask``, the quaternion ``q`` body FRD -> world NED ``[w, x, y, z]``
    and the relative thrust; the body rates zero (ignored with the type mask)."""
    w, x, y, z = q
    payload = _TARGET_PAYLOAD.pack(
        time_boot_ms, w, x, y, z, 0.0, 0.0, 0.0, thrust, target_system, target_component,
        type_mask,
    )  # fmt: skip
    payload = payload.rstrip(b"\0") or payload[:1]
    head = _HEADER.pack(
        _MAGIC_V2, len(payload), 0, 0, seq, src_system, src_component, _TARGET_ID_LOW,
        _TARGET_ID_HIGH,
    )  # fmt: skip
    frame = head + payload
    return frame + _CRC.pack(x25crc(frame[1:] + _TARGET_CRC_EXTRA).crc)

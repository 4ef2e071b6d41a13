"""Flight log as MCAP: ``LOG.mcap`` beside ``LOG.csv``, for Foxglove and PlotJuggler.

The same control cycles as ``LOG.csv`` (:mod:`companion.logs.flightlog`), as Protobuf
messages (message encoding ``protobuf``, schema encoding ``protobuf``: each schema record
holds its ``FileDescriptorSet``). The vehicle, the arm and the events use Foxglove's
published schemas (``foxglove.FrameTransforms``, ``foxglove.PoseInFrame``,
``foxglove.Log``, as foxglove-sdk ships them), so that the 3D panel shows the scene as is;
the rest are flat messages of doubles (package ``companion``) whose field names carry their
unit, as the CSV's columns do. A value that was not available that cycle is NaN; a flag is
0 / 1.

Every message's log time and publish time is the vehicle time of its cycle (time since
boot) [ns]; a ``timestamp`` field in Foxglove's messages holds the same time.

=================  ===========================  ==============================================
channel            schema                       content (one message per cycle unless said)
=================  ===========================  ==============================================
``/tf``            ``foxglove.FrameTransforms`` ``world`` -> ``base_link`` (q's position and
                                                ZYX attitude, ENU / FLU), ``base_link`` ->
                                                ``link1`` (at the mount point r_a, turned by
                                                eta1 about body y), ``link1`` -> ``link2`` (at
                                                l1 along link 1, turned by eta2), ``link2`` ->
                                                ``gripper`` (at l2 along link 2); each frame's
                                                x axis points along its link (DESIGN.md
                                                section 3). Cycles with a finite q only.
``/vehicle/pose``  ``foxglove.PoseInFrame``     the vehicle's pose in ``world``; as ``/tf``.
``/state``         ``companion.State``          q and q_dot by name (``x_m``..., ``x_m_s``...)
``/desired``       ``companion.Desired``        q_d by the names of q
``/setpoint``      ``companion.Setpoint``       roll, pitch, yaw [rad] (ENU / FLU), thrust [N],
                                                PX4's relative thrust, saturation flags;
                                                cycles that sent a setpoint only
``/estimate``      ``companion.Estimate``       theta_hat (m2, m3, m4, lc = m3/m2), the
                                                confidence (excitation, spread, confident,
                                                frozen), the thrust scale
``/timing``        ``companion.Timing``         loop period [ms] (vehicle time)
``/events``        ``foxglove.Log``             one per event of ``LOG.events.csv``: name =
                                                kind, message = detail; level ERROR for a
                                                ``fault``, FATAL for a ``failure``, INFO else
=================  ===========================  ==============================================

Nothing of the wall clock enters the file: the cycle's latencies and CPU time go to
``LOG.timing.csv``, so two identical flights on simulated time give the same ``LOG.mcap``,
byte for byte. Simulator flights add ``/truth`` after the flight (:mod:`sitl.truth_mcap`)
through :func:`merge_messages`.

Writing: foxglove-sdk's MCAP writer (LZ4 chunks: a third of Zstandard's CPU time per
chunk, files 15 % larger). The cycles reach it a block at a
time (:mod:`companion.logs.columns`): :func:`encode_block` turns a block of rows into its
messages with a few numpy operations over the whole block (the message layouts are fixed:
every number is a double), and each block ends its chunk, handed to the operating system.
The control cycle only hands the block over: :class:`McapLogWriter`'s writer thread
encodes, logs and ends the chunk (about 0.3 ms a block, after the cycle), blocks and
events in the order they were handed over, so the file is the same byte for byte.
A crash loses the blocks not yet written (the one being filled, and one being written:
the writer takes a block as it is handed over) and the summary; :func:`describe_mcap`
still reads the chunks written before it. The live view (:mod:`companion.logs.live_view`) serves the
same channels from the same writer.
"""

from __future__ import annotations

import heapq
import json
import math
import os
import queue
import struct
import threading
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, cast

import foxglove
import numpy as np
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Header, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from numpy.typing import NDArray

from companion.config import CompanionConfig
from companion.logs import columns
from companion.logs.flightlog import BLOCK_ROWS, Q_NAMES, FlightLogError, FlightLogWriter
from companion.user_files import UserFileError, open_regular_file

__all__ = [
    "CHANNELS",
    "CHUNK_SIZE",
    "SCHEMAS",
    "ArmGeometry",
    "ChannelInfo",
    "ChannelSpec",
    "FlightLogWithMcap",
    "McapInfo",
    "McapLogWriter",
    "describe_mcap",
    "encode_block",
    "json_channel",
    "log_message",
    "mcap_path",
    "merge_messages",
    "pose_in_frame",
    "time_ns",
]

CHUNK_SIZE = 256 * 1024
"""Most bytes of messages per chunk; a block of rows ends its chunk before that."""

Q_KEYS = tuple(
    f"{n}_{u}"
    for n, u in zip(Q_NAMES, ("m", "m", "m", "rad", "rad", "rad", "rad", "rad"), strict=True)
)
"""Field names of q in ``/state``, ``/desired`` and ``/truth`` (q's order, with unit)."""
Q_DOT_KEYS = tuple(f"{k}_s" for k in Q_KEYS)
"""Field names of q_dot in ``/state``."""
THETA_KEYS = ("m2_kg", "m3_kg_m", "m4_kg_m2", "lc_m")
"""Field names of theta (and lc = m3/m2) in ``/estimate`` and ``/truth``."""

LOG_LEVELS = {"fault": 4, "failure": 5}
"""foxglove.Log level of an event kind (4 ERROR, 5 FATAL); every other kind is 2 (INFO)."""
LOG_INFO = 2


# -- Protobuf, written by hand (fixed layouts) ---------------------------------------------


def _varint(value: int) -> bytes:
    out = bytearray()
    while value > 0x7F:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def _key(number: int, wire_type: int) -> bytes:
    return _varint(number << 3 | wire_type)


def _bytes_field(number: int, payload: bytes) -> bytes:
    """A length-delimited field (string, bytes, message)."""
    return _key(number, 2) + _varint(len(payload)) + payload


def _int_field(number: int, value: int) -> bytes:
    """A varint field (omitted at 0, as Protobuf 3 writes it)."""
    return _key(number, 0) + _varint(value) if value else b""


def _double_fields(names: Sequence[str]) -> list[bytes | int]:
    """A message of doubles numbered 1, 2, ... in ``names``' order: its layout."""
    parts: list[bytes | int] = []
    for i in range(len(names)):
        parts += [_key(i + 1, 1), i]
    return parts


def _descriptor_set(name: str, fields: Sequence[str]) -> bytes:
    """The ``FileDescriptorSet`` of the Protobuf 3 message ``name`` (``package.Message``)
    with one double per field, numbered 1, 2, ... (``optional`` label, type double)."""
    package, message = name.rsplit(".", 1)
    described = b"".join(
        _bytes_field(
            2,
            _bytes_field(1, field.encode())
            + _int_field(3, number)
            + _int_field(4, 1)
            + _int_field(5, 1)
            + _bytes_field(10, field.encode()),
        )
        for number, field in enumerate(fields, start=1)
    )
    file = (
        _bytes_field(1, f"{package}/{message}.proto".encode())
        + _bytes_field(2, package.encode())
        + _bytes_field(4, _bytes_field(1, message.encode()) + described)
        + _bytes_field(12, b"proto3")
    )
    return _bytes_field(1, file)


class _Layout:
    """A message whose bytes are fixed but for its doubles: constant parts and slots
    (``int``: a column of the values)."""

    def __init__(self, parts: Sequence[bytes | int]) -> None:
        template = bytearray()
        slots: list[int] = []
        order: list[int] = []
        for part in parts:
            if isinstance(part, int):
                slots.extend(range(len(template), len(template) + 8))
                order.append(part)
                template += bytes(8)
            else:
                template += part
        self.template = np.frombuffer(bytes(template), dtype=np.uint8)
        self.width = len(template)
        self.slots = np.array(slots, dtype=np.intp)
        self.order = np.array(order, dtype=np.intp)

    def pack(self, values: NDArray[np.float64]) -> bytes:
        """The messages of the rows of ``values`` [n, columns], one after the other
        (:attr:`width` bytes each)."""
        n = len(values)
        out = np.empty((n, self.width), dtype=np.uint8)
        out[:] = self.template
        doubles = np.ascontiguousarray(values[:, self.order], dtype="<f8")
        out[:, self.slots] = doubles.view(np.uint8).reshape(n, -1)
        return out.tobytes()


_F64 = struct.Struct("<d")


def _vector3(x: bytes | int, y: bytes | int, z: bytes | int) -> list[bytes | int]:
    """``foxglove.Vector3`` (x, y, z: doubles 1-3), each a slot or 8 constant bytes."""
    return [b"\x09", x, b"\x11", y, b"\x19", z]


def _quaternion(start: int) -> list[bytes | int]:
    """``foxglove.Quaternion`` (x, y, z, w: doubles 1-4) from slots ``start`` .. +3."""
    return [b"\x09", start, b"\x11", start + 1, b"\x19", start + 2, b"\x21", start + 3]


def _constant(value: float) -> bytes:
    return _F64.pack(value)


_IDENTITY: list[bytes | int] = [b"\x09", _constant(0.0), b"\x11", _constant(0.0)]
_IDENTITY += [b"\x19", _constant(0.0), b"\x21", _constant(1.0)]
"""The unit ``foxglove.Quaternion`` (no slot)."""


def _width(parts: Sequence[bytes | int]) -> int:
    """Bytes of a layout's parts (a slot is 8)."""
    return sum(8 if isinstance(p, int) else len(p) for p in parts)


def _nested(number: int, parts: list[bytes | int]) -> list[bytes | int]:
    """A message field of fixed size (a slot is 8 bytes)."""
    return [_key(number, 2) + _varint(_width(parts)), *parts]


def timestamp_field(ns: int) -> bytes:
    """Field 1 holding a ``google.protobuf.Timestamp`` of ``ns`` [ns] (Foxglove's
    ``timestamp``): seconds (field 1) and nanoseconds (field 2), each omitted at 0; the
    Timestamp is at most 12 bytes, so its length is one byte."""
    sec, nsec = divmod(ns, 1_000_000_000)
    body = (b"\x08" + _varint(sec) if sec else b"") + (b"\x10" + _varint(nsec) if nsec else b"")
    return b"\x0a" + _LENGTH[len(body)] + body


_LENGTH = [bytes((n,)) for n in range(128)]
"""The varint of a length below 128: one byte."""


# -- schemas -------------------------------------------------------------------------------

_FIELDS: dict[str, tuple[str, ...]] = {
    "companion.State": (*Q_KEYS, *Q_DOT_KEYS),
    "companion.Desired": Q_KEYS,
    "companion.Setpoint": (
        "roll_rad",
        "pitch_rad",
        "yaw_rad",
        "thrust_n",
        "thrust_rel",
        "tilt_saturated",
        "thrust_saturated",
    ),
    "companion.Estimate": (
        *THETA_KEYS,
        "excitation",
        "spread",
        "confident",
        "frozen",
        "thrust_scale",
    ),
    "companion.Timing": ("loop_period_ms",),
}
"""The companion's messages: their double fields, in field-number order."""

SCHEMAS: dict[str, bytes] = {
    "foxglove.FrameTransforms": foxglove.messages.FrameTransforms.get_schema().data,
    "foxglove.PoseInFrame": foxglove.messages.PoseInFrame.get_schema().data,
    "foxglove.Log": foxglove.messages.Log.get_schema().data,
    **{name: _descriptor_set(name, fields) for name, fields in _FIELDS.items()},
}
"""Every schema the companion writes, by name: its ``FileDescriptorSet`` (Foxglove's as
foxglove-sdk publishes them)."""

CHANNELS: dict[str, str] = {
    "/tf": "foxglove.FrameTransforms",
    "/vehicle/pose": "foxglove.PoseInFrame",
    "/state": "companion.State",
    "/desired": "companion.Desired",
    "/setpoint": "companion.Setpoint",
    "/estimate": "companion.Estimate",
    "/timing": "companion.Timing",
    "/events": "foxglove.Log",
}
"""Topic -> schema name of every channel the companion writes, in registration order."""

_STATE_COLUMNS = np.r_[columns.Q, columns.Q_DOT]
_ESTIMATE_COLUMNS = np.r_[
    columns.THETA,
    columns.LC,
    columns.EXCITATION,
    columns.SPREAD,
    columns.CONFIDENT,
    columns.FROZEN,
    columns.THRUST_SCALE,
]
_SENT = columns.SETPOINT.start + 5
"""A setpoint's flag column: NaN on cycles that sent none."""


# -- conversions (pure) ------------------------------------------------------------------


@dataclass(frozen=True)
class ArmGeometry:
    """Where the arm's frames sit (DESIGN.md section 3)."""

    mount_point_m: tuple[float, float, float]
    """Joint 1 r_a in the body frame (FLU, from the vehicle CoM) [m]."""
    link1_length_m: float
    link2_length_m: float

    @classmethod
    def from_config(cls, config: CompanionConfig) -> ArmGeometry:
        arm = config.arm
        x, y, z = (float(v) for v in arm.mount_point_m)
        return cls((x, y, z), arm.link1.length_m, arm.link2.length_m)


def mcap_path(log_path: str | Path) -> Path:
    """``flight.csv`` -> ``flight.mcap``."""
    path = Path(log_path)
    return path.with_name(f"{path.stem}.mcap")


def time_ns(t_s: float) -> int:
    """Vehicle time [s] as MCAP's log time [ns] (rounded to the nearest nanosecond)."""
    if not (math.isfinite(t_s) and t_s >= 0.0):
        raise FlightLogError(f"vehicle time {t_s!r} s is not a time since boot")
    return round(t_s * 1e9)


def _quaternion_parts(angles: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """(x, y, z, w) of the quaternions of R = Rz(psi) Ry(theta) Rx(phi) with ``angles``
    [3, n] = (phi, theta, psi) [rad], as :func:`companion.link.setpoint.quaternion_from_euler_zyx`
    over arrays (one cosine and one sine of all half angles)."""
    half = 0.5 * angles
    (cr, cp, cy), (sr, sp, sy) = np.cos(half), np.sin(half)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def _frame(
    parent: str, child: str, translation: list[bytes | int], rotation: list[bytes | int]
) -> list[bytes | int]:
    """A ``foxglove.FrameTransform`` after its timestamp: frames, translation, rotation."""
    return [
        _bytes_field(2, parent.encode()),
        _bytes_field(3, child.encode()),
        *_nested(4, translation),
        *_nested(5, rotation),
    ]


_POSE_PARTS: list[bytes | int] = [
    _bytes_field(2, b"world"),
    *_nested(3, [*_nested(1, _vector3(0, 1, 2)), *_nested(2, _quaternion(3))]),
]
"""``foxglove.PoseInFrame`` after its timestamp, from the slots of :class:`_Transforms`."""
_POSE = _Layout(_POSE_PARTS)


def _shift(parts: Sequence[bytes | int], offset: int) -> list[bytes | int]:
    """``parts`` with their slots ``offset`` columns further."""
    return [p + offset if isinstance(p, int) else p for p in parts]


_CYCLE_COLUMNS = np.r_[
    _STATE_COLUMNS, columns.Q_D, columns.SETPOINT, _ESTIMATE_COLUMNS, columns.PERIOD
]
"""The row's columns in the companion's messages, after the transforms' 15 slots."""
_CYCLE_DOUBLES = [
    (_double_fields(_FIELDS[name]), 15 + start)
    for name, start in (
        ("companion.State", 0),
        ("companion.Desired", 16),
        ("companion.Setpoint", 24),
        ("companion.Estimate", 31),
        ("companion.Timing", 40),
    )
]
"""The companion's messages' layouts and where their slots start in a cycle's values."""


class _Transforms:
    """``/tf`` and ``/vehicle/pose`` of a block (see the module table). A joint angle eta
    about body y turns its link's x axis to (cos eta, 0, sin eta): a rotation by -eta about
    y. Slots: base position (0-2), base attitude (3-6), link 1's (7-10), link 2's (11-14)."""

    def __init__(self, geometry: ArmGeometry) -> None:
        mx, my, mz = (_constant(v) for v in geometry.mount_point_m)
        zero = _constant(0.0)
        frames = [
            _frame("world", "base_link", _vector3(0, 1, 2), _quaternion(3)),
            _frame("base_link", "link1", _vector3(mx, my, mz), _quaternion(7)),
            _frame("link1", "link2", _vector3(_constant(geometry.link1_length_m), zero, zero),
                   _quaternion(11)),
            _frame("link2", "gripper", _vector3(_constant(geometry.link2_length_m), zero, zero),
                   _IDENTITY),
        ]  # fmt: skip
        self._tails = [_width(parts) for parts in frames]
        messages = [
            *frames,
            _POSE_PARTS,
            *(_shift(layout, offset) for layout, offset in _CYCLE_DOUBLES),
        ]
        self.cycle = _Layout([part for parts in messages for part in parts])
        """A cycle's messages but the timestamps, one after the other: the four
        transforms' tails, the pose's, then ``/state`` ... ``/timing``."""
        widths = [_width(parts) for parts in messages]
        self.offsets = [sum(widths[:i]) for i in range(len(widths) + 1)]
        """Where each of :attr:`cycle`'s messages starts (and the last ends) [bytes]."""
        self._heads: dict[int, list[bytes]] = {}

    def heads(self, stamp: int) -> list[bytes]:
        """The field header of each transform whose timestamp field is ``stamp`` bytes."""
        heads = self._heads.get(stamp)
        if heads is None:
            heads = self._heads[stamp] = [
                _key(1, 2) + _varint(stamp + tail) for tail in self._tails
            ]
        return heads

    @staticmethod
    def values(rows: NDArray[np.float64]) -> NDArray[np.float64]:
        """The slots of the transforms [n, 15] of ``rows``: base position, the base's,
        link 1's and link 2's quaternions (:func:`_quaternion_parts` of the three at once)."""
        n = len(rows)
        q = rows[:, columns.Q]
        angles = np.zeros((3, 3 * n))  # phi, theta, psi of the base, link 1, link 2
        angles[0, :n] = q[:, 3]
        angles[1, :n] = q[:, 4]
        angles[1, n : 2 * n] = -q[:, 6]
        angles[1, 2 * n :] = -q[:, 7]
        angles[2, :n] = q[:, 5]
        x, y, z, w = _quaternion_parts(angles)
        out = np.empty((n, 15))
        out[:, :3] = q[:, :3]
        for j, part in enumerate((x, y, z, w)):
            out[:, 3 + j : 15 : 4] = part.reshape(3, n).T
        return out


def encode_block(
    rows: NDArray[np.float64], transforms: _Transforms
) -> list[tuple[str, int, bytes]]:
    """(topic, log time [ns], message) of the cycles in ``rows`` (rows of
    :data:`companion.logs.columns.ROW`), in time order and :data:`CHANNELS` order within a
    cycle (pure). The fixed parts of a cycle's messages are packed in one go over the
    block; a row adds its timestamps."""
    n = len(rows)
    if n == 0:
        return []
    times = [time_ns(t) for t in rows[:, columns.T].tolist()]
    flown = cast(list[bool], np.isfinite(rows[:, columns.Q]).all(axis=1).tolist())
    sent = cast(list[bool], np.isfinite(rows[:, _SENT]).tolist())
    values = np.column_stack((transforms.values(rows), rows[:, _CYCLE_COLUMNS]))
    blob = transforms.cycle.pack(values)
    width = transforms.cycle.width
    out: list[tuple[str, int, bytes]] = []
    add = out.append
    o0, o1, o2, o3, o4, o5, o6, o7, o8, o9, o10 = transforms.offsets
    heads = transforms.heads
    start = 0
    for ns, is_flown, is_sent in zip(times, flown, sent, strict=True):
        cycle = blob[start : start + width]
        start += width
        if is_flown:
            stamp = timestamp_field(ns)
            h0, h1, h2, h3 = heads(len(stamp))
            tf = b"".join(
                (
                    h0, stamp, cycle[o0:o1], h1, stamp, cycle[o1:o2],
                    h2, stamp, cycle[o2:o3], h3, stamp, cycle[o3:o4],
                )
            )  # fmt: skip
            add(("/tf", ns, tf))
            add(("/vehicle/pose", ns, stamp + cycle[o4:o5]))
        add(("/state", ns, cycle[o5:o6]))
        add(("/desired", ns, cycle[o6:o7]))
        if is_sent:
            add(("/setpoint", ns, cycle[o7:o8]))
        add(("/estimate", ns, cycle[o8:o9]))
        add(("/timing", ns, cycle[o9:o10]))
    return out


def pose_in_frame(q: Sequence[float], ns: int) -> bytes:
    """``foxglove.PoseInFrame`` in ``world`` of the vehicle at q (8 entries: position, ZYX
    attitude; ENU / FLU) at ``ns`` [ns], Protobuf-encoded."""
    rows = np.full((1, columns.WIDTH), math.nan)
    rows[0, columns.Q] = q
    return timestamp_field(ns) + _POSE.pack(_Transforms.values(rows))


def log_message(kind: str, detail: str, ns: int) -> bytes:
    """``foxglove.Log`` of one event at ``ns`` [ns] (see :data:`LOG_LEVELS`),
    Protobuf-encoded."""
    return (
        timestamp_field(ns)
        + _int_field(2, LOG_LEVELS.get(kind, LOG_INFO))
        + (_bytes_field(3, detail.encode()) if detail else b"")
        + (_bytes_field(4, kind.encode()) if kind else b"")
    )


# -- writing -----------------------------------------------------------------------------

ChannelSpec = tuple[str, str, bytes, str]
"""A channel's (schema name, schema encoding, schema data, message encoding)."""


def json_channel(name: str, schema: dict[str, Any]) -> ChannelSpec:
    """A channel of JSON messages under the JSON schema ``schema`` named ``name``."""
    return name, "jsonschema", json.dumps(schema, indent=1).encode("utf-8"), "json"


def protobuf_channel(name: str) -> ChannelSpec:
    """A channel of Protobuf messages under :data:`SCHEMAS`' ``name``."""
    return name, "protobuf", SCHEMAS[name], "protobuf"


_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False, ensure_ascii=False)


def encode(message: dict[str, Any]) -> bytes:
    """A message as compact UTF-8 JSON (no NaN: missing values are null)."""
    return _ENCODER.encode(message).encode("utf-8")


def merge_messages(
    mcap_path: str | Path,
    channels: dict[str, ChannelSpec],
    messages: Iterable[tuple[int, str, bytes]],
) -> int:
    """Rewrite the closed log ``mcap_path`` with new ``channels`` (topic -> its spec) and
    their ``messages`` ((log time [ns], topic, encoded message), in time order) merged in
    time order with what it holds; the number of messages added. The file is replaced in
    one step (a crash leaves the old one).

    Raises ``ValueError`` if the log has no summary or already has one of the channels.
    """
    mcap_path = Path(mcap_path)
    tmp = mcap_path.with_name(mcap_path.name + ".tmp")
    added = 0
    try:
        src_file = open_regular_file(mcap_path)
    except UserFileError as exc:
        raise ValueError(str(exc)) from None
    with src_file as src:
        try:
            reader = make_reader(src)
            summary = reader.get_summary()
            library = reader.get_header().library
        except McapError as exc:
            raise ValueError(f"{mcap_path}: not a readable MCAP log ({exc})") from None
        if summary is None:
            raise ValueError(f"{mcap_path}: no summary (the flight's log was not closed)")
        present = sorted(c.topic for c in summary.channels.values() if c.topic in channels)
        if present:
            raise ValueError(f"{mcap_path}: holds {', '.join(present)} already")
        with open(tmp, "xb") as dst:
            try:
                writer = Writer(dst, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
                writer.start(profile=reader.get_header().profile, library=library)
                schema_ids: dict[tuple[str, str, bytes], int] = {}

                def register(topic: str, spec: ChannelSpec) -> int:
                    name, encoding, data, message_encoding = spec
                    key = (name, encoding, data)
                    if key not in schema_ids:
                        schema_ids[key] = writer.register_schema(name, encoding, data)
                    return writer.register_channel(topic, message_encoding, schema_ids[key])

                ids: dict[int, int] = {}
                for cid, channel in sorted(summary.channels.items()):
                    schema = summary.schemas[channel.schema_id]
                    spec = (schema.name, schema.encoding, schema.data, channel.message_encoding)
                    ids[cid] = register(channel.topic, spec)
                new_ids = {topic: register(topic, spec) for topic, spec in channels.items()}
                old = (
                    (m.log_time, 0, ids[m.channel_id], m.data, m.publish_time, m.sequence)
                    for _, _, m in reader.iter_messages(log_time_order=False)
                )
                sequence = dict.fromkeys(new_ids, 0)

                def new() -> Iterable[tuple[int, int, int, bytes, int, int]]:
                    for ns, topic, data in messages:
                        yield ns, 1, new_ids[topic], data, ns, sequence[topic]
                        sequence[topic] += 1

                for log_time, source, cid, data, publish_time, seq in heapq.merge(
                    old, new(), key=lambda m: (m[0], m[1])
                ):
                    writer.add_message(cid, log_time, data, publish_time, seq)
                    added += source
                writer.finish()
                dst.flush()
                os.fsync(dst.fileno())
            except BaseException:
                tmp.unlink(missing_ok=True)
                raise
    os.replace(tmp, mcap_path)
    return added


class McapLogWriter:
    """Writes ``LOG.mcap`` (see the module docstring) with foxglove-sdk's writer:
    :meth:`write_block` the cycles of a block, :meth:`event` one event.

    Both hand their work to the writer's own thread (started by :meth:`open`, ended by
    :meth:`close`), which carries it out in order: a cycle waits for no encoding, no
    compression and no write. A failure there is raised as :class:`FlightLogError` by
    the next call.

    Nothing is opened in the constructor; use ``with McapLogWriter(path, geometry)`` or
    :meth:`open` / :meth:`close` (idempotent). The file is never overwritten. Once open,
    :attr:`context` holds the channels: a live view started on it serves them too.
    """

    def __init__(self, path: str | Path, geometry: ArmGeometry) -> None:
        self.path = Path(path)
        self.geometry = geometry
        self.messages = 0
        """Messages written (by the writer thread: all of them once :meth:`close` returns)."""
        self.context: foxglove.Context | None = None
        self._writer: Any = None
        self._channels: dict[str, foxglove.Channel] = {}
        self._log: dict[str, Any] = {}
        """Per topic, its channel's ``base.log(data, log_time, sink_id)``: what
        ``Channel.log`` calls for bytes, without its checks of the message's type."""
        self._transforms = _Transforms(geometry)
        self._last_ns = 0
        self._closed = False
        self._work: queue.SimpleQueue[tuple[Callable[..., None], tuple[Any, ...]] | None] = (
            queue.SimpleQueue()
        )
        self._thread: threading.Thread | None = None
        self._failure: BaseException | None = None
        """What stopped the writer thread, if it failed."""

    def __enter__(self) -> McapLogWriter:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        if self.context is not None or self._closed:
            raise FlightLogError(f"{self.path}: an McapLogWriter opens once")
        try:
            open(self.path, "xb").close()  # claims the name: never overwrite a log
        except FileExistsError:
            self._closed = True
            raise FlightLogError(
                f"{self.path}: exists; a flight log is never overwritten"
            ) from None
        except OSError as exc:
            self._closed = True
            raise FlightLogError(f"{self.path}: cannot write: {exc.strerror}") from None
        context = self.context = foxglove.Context()
        options = MCAPWriteOptions(compression=MCAPCompression.Lz4, chunk_size=CHUNK_SIZE)
        self._writer = foxglove.open_mcap(
            self.path, allow_overwrite=True, context=context, writer_options=options
        )
        for topic, name in CHANNELS.items():
            schema = foxglove.Schema(name=name, encoding="protobuf", data=SCHEMAS[name])
            channel = self._channels[topic] = foxglove.Channel(
                topic, schema=schema, message_encoding="protobuf", context=context
            )
            self._log[topic] = channel.base.log
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._thread.start()

    def write_block(self, rows: NDArray[np.float64]) -> None:
        """Have the cycles of ``rows`` (rows of :data:`companion.logs.columns.ROW`, not
        changed afterwards) written and their chunk ended (handed to the operating
        system)."""
        self._hand_over(self._write_block, rows)

    def event(self, kind: str, detail: str, t_vehicle_s: float) -> None:
        """Have an event appended as a ``foxglove.Log`` message on ``/events``. An event
        before the vehicle's clock is known (NaN, as the app's time before its first pose)
        is logged at the last time logged (0 before any)."""
        self._hand_over(self._event, kind, detail, t_vehicle_s)

    def _hand_over(self, work: Callable[..., None], *args: Any) -> None:
        if self._thread is None:
            raise FlightLogError(f"{self.path}: the log is not open")
        if self._failure is not None:
            raise FlightLogError(f"{self.path}: cannot write: {self._failure}")
        self._work.put((work, args))

    def _run(self) -> None:
        """The writer thread: the work handed over, in order, until :meth:`close`."""
        while (item := self._work.get()) is not None:
            if self._failure is None:
                work, args = item
                try:
                    work(*args)
                except Exception as exc:  # the disk's, or foxglove-sdk's
                    self._failure = exc

    def _write_block(self, rows: NDArray[np.float64]) -> None:
        log = self._log
        messages = encode_block(rows, self._transforms)
        for topic, ns, data in messages:
            log[topic](data, ns, None)
        if messages:
            self._last_ns = messages[-1][1]
            self.messages += len(messages)
        self._writer.flush()

    def _event(self, kind: str, detail: str, t_vehicle_s: float) -> None:
        ns = time_ns(t_vehicle_s) if math.isfinite(t_vehicle_s) else self._last_ns
        self._last_ns = ns
        self._channels["/events"].log(log_message(kind, detail, ns), log_time=ns)
        self.messages += 1
        self._writer.flush()

    def close(self) -> None:
        """Let the writer thread finish its work, write the summary, fsync and close
        (idempotent); raises :class:`FlightLogError` if the thread failed."""
        self._closed = True
        thread, self._thread = self._thread, None
        if thread is not None:
            self._work.put(None)
            thread.join()
        writer, self._writer = self._writer, None
        self._channels = {}
        self._log = {}
        self.context = None
        if writer is None:
            return
        writer.close()
        fd = os.open(self.path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        if self._failure is not None:
            raise FlightLogError(f"{self.path}: cannot write: {self._failure}")


class FlightLogWithMcap(FlightLogWriter):
    """:class:`~companion.logs.flightlog.FlightLogWriter` that also writes ``LOG.mcap``: every
    block of cycles and every event (the ones it derives from the cycles too) go to both.

    Opens the MCAP after the CSV files (and closes it after them); a file of either that
    exists stops the open, as for the CSV alone.
    """

    def __init__(
        self, path: str | Path, geometry: ArmGeometry, block_rows: int = BLOCK_ROWS
    ) -> None:
        super().__init__(path, block_rows)
        self.mcap = McapLogWriter(mcap_path(self.path), geometry)

    def open(self) -> None:
        if self.mcap.path.exists():  # before the CSV files are created
            raise FlightLogError(f"{self.mcap.path}: exists; a flight log is never overwritten")
        super().open()
        try:
            self.mcap.open()
        except FlightLogError:
            super().close()
            raise

    def commit(self) -> None:
        """As :meth:`FlightLogWriter.commit`; a row whose vehicle time is no time since boot
        (negative, not finite) is refused and left out."""
        log = self.columns
        t = float(log.block[log.n - 1, columns.T])
        if not (math.isfinite(t) and t >= 0.0):
            log.n -= 1
            log.block[log.n] = math.nan
            time_ns(t)
        super().commit()

    def write_block(self, rows: NDArray[np.float64]) -> None:
        super().write_block(rows)
        self.mcap.write_block(rows)

    def event(self, kind: str, detail: str, t_vehicle_s: float) -> None:
        super().event(kind, detail, t_vehicle_s)
        self.mcap.event(kind, detail, t_vehicle_s)

    def close(self) -> None:
        try:
            super().close()
        finally:
            self.mcap.close()


# -- reading -----------------------------------------------------------------------------


@dataclass(frozen=True)
class ChannelInfo:
    """One channel of an MCAP file."""

    topic: str
    schema: str
    """Schema name (``""``: none)."""
    schema_encoding: str
    message_encoding: str
    messages: int


@dataclass(frozen=True)
class McapInfo:
    """What :func:`describe_mcap` found."""

    path: Path
    library: str
    channels: tuple[ChannelInfo, ...]
    start_ns: int | None
    """Earliest log time [ns] (None: no message)."""
    end_ns: int | None
    warnings: tuple[str, ...] = ()
    """What could not be read: a file cut by a crash (counted up to the cut)."""

    @property
    def messages(self) -> int:
        return sum(c.messages for c in self.channels)

    def lines(self) -> list[str]:
        """A readable description, one line each."""
        out = [f"{self.path}: {self.messages} messages, {len(self.channels)} channels"]
        if self.start_ns is not None and self.end_ns is not None:
            start, end = self.start_ns * 1e-9, self.end_ns * 1e-9
            out.append(
                f"time: {start:.3f} s to {end:.3f} s ({end - start:.3f} s, log time: vehicle time)"
            )
        width = max((len(c.topic) for c in self.channels), default=0)
        swidth = max((len(c.schema) for c in self.channels), default=0)
        for c in self.channels:
            out.append(
                f"  {c.topic:<{width}}  {c.schema:<{swidth}}  "
                f"{c.schema_encoding}/{c.message_encoding}  {c.messages:>8} messages"
            )
        out.extend(f"warning: {w}" for w in self.warnings)
        return out


def _from_summary(path: Path, stream: IO[bytes]) -> McapInfo | None:
    """The description from the file's summary; None when it has none (cut by a crash)."""
    reader = make_reader(stream)
    library = reader.get_header().library
    summary = reader.get_summary()
    if summary is None or summary.statistics is None:
        return None
    stats = summary.statistics
    channels = []
    for cid, channel in sorted(summary.channels.items()):
        schema = summary.schemas.get(channel.schema_id)
        channels.append(
            ChannelInfo(
                topic=channel.topic,
                schema="" if schema is None else schema.name,
                schema_encoding="" if schema is None else schema.encoding,
                message_encoding=channel.message_encoding,
                messages=stats.channel_message_counts.get(cid, 0),
            )
        )
    empty = stats.message_count == 0
    start = None if empty else stats.message_start_time
    end = None if empty else stats.message_end_time
    return McapInfo(path, library, tuple(channels), start, end)


def _scan(path: Path, stream: IO[bytes]) -> McapInfo:
    """The description from every record up to where the file ends or is cut."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    counts: dict[int, int] = {}
    times: list[int] = []
    library = ""
    warnings: list[str] = []
    try:
        for record in StreamReader(stream).records:
            if isinstance(record, Message):
                counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
                times.append(record.log_time)
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels.setdefault(record.id, record)
            elif isinstance(record, Header):
                library = record.library
    except (McapError, EOFError, ValueError, struct.error):
        if not channels:
            raise FlightLogError(f"{path}: not an MCAP file") from None
        warnings.append(f"{path}: cut short: counted the messages before the cut")
    infos = []
    for cid, channel in sorted(channels.items()):
        schema = schemas.get(channel.schema_id)
        infos.append(
            ChannelInfo(
                topic=channel.topic,
                schema="" if schema is None else schema.name,
                schema_encoding="" if schema is None else schema.encoding,
                message_encoding=channel.message_encoding,
                messages=counts.get(cid, 0),
            )
        )
    start = min(times) if times else None
    end = max(times) if times else None
    return McapInfo(path, library, tuple(infos), start, end, tuple(warnings))


def describe_mcap(path: str | Path) -> McapInfo:
    """Channels, schemas, message counts and time range of an MCAP file.

    From the file's summary when it has one; a file cut by a crash (no summary) is read
    record by record up to the cut, which :attr:`McapInfo.warnings` names. Raises
    ``FlightLogError`` for a file that cannot be read or is not MCAP.
    """
    path = Path(path)
    try:
        f = open_regular_file(path)
    except UserFileError as exc:
        raise FlightLogError(str(exc)) from None
    try:
        with f:
            try:
                info = _from_summary(path, f)
            except (McapError, EOFError, ValueError, struct.error):
                info = None
            if info is not None:
                return info
            f.seek(0)
            return _scan(path, f)
    except OSError as exc:
        raise FlightLogError(f"{path}: cannot read: {exc.strerror}") from None

"""Flight log as MCAP: ``LOG.mcap`` beside ``LOG.csv``, for Foxglove and PlotJuggler.

The same control cycles as ``LOG.csv`` (:mod:`companion.logs.flightlog`), as JSON messages
(message encoding ``json``) under JSON schemas (schema encoding ``jsonschema``). The vehicle
and the arm use Foxglove's well-known schemas, so that the 3D panel shows the scene as is;
the rest are plain schemas whose field names carry their unit, as the CSV's columns do.

Every message's log time and publish time is the vehicle time of its cycle (time since
boot) [ns]; a Foxglove ``timestamp`` field in it holds the same time.

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
``/state``         ``companion.State``          q and q_dot by name (``x_m``, ``eta1_rad``...)
``/desired``       ``companion.Desired``        q_d by the same names
``/setpoint``      ``companion.Setpoint``       roll, pitch, yaw [rad] (ENU / FLU), thrust [N],
                                                PX4's relative thrust, saturation flags;
                                                cycles that sent a setpoint only
``/estimate``      ``companion.Estimate``       theta_hat (m2, m3, m4, lc = m3/m2), the
                                                confidence (excitation, spread, confident,
                                                frozen), the thrust scale
``/timing``        ``companion.Timing``         loop period [ms] (vehicle time); the live
                                                view adds the wall-clock latencies [us] when
                                                measured, the file keeps them out
``/events``        ``foxglove.Log``             one per event of ``LOG.events.csv``: name =
                                                kind, message = detail; level ERROR for a
                                                ``fault``, FATAL for a ``failure``, INFO else
=================  ===========================  ==============================================

A value that was not available that cycle (None, NaN) is ``null``. Nothing of the wall
clock enters the file: the cycle's latencies and CPU time go to ``LOG.timing.csv``, so two
identical flights on simulated time give the same ``LOG.mcap``, byte for byte. Simulator flights add
``/truth`` after the flight (:mod:`sitl.truth_mcap`), through :func:`start_writer`,
:func:`register_channel` and :func:`pose_in_frame` here.

Timing: a cycle's messages are encoded (a few tens of microseconds) into the writer's
in-memory chunk; a full chunk (:data:`CHUNK_SIZE`) is compressed with Zstandard and handed
to the operating system (``benchmarks/bench_mcap_log.py`` measures both). Closing writes the
summary (channels, counts, time range) and fsyncs. A crash loses the open chunk and the
summary; :func:`describe_mcap` still reads the chunks written before it.
"""

from __future__ import annotations

import heapq
import json
import math
import os
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Header, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from numpy.typing import ArrayLike

from companion.config import CompanionConfig
from companion.link.setpoint import quaternion_from_euler_zyx
from companion.logs.flightlog import Q_NAMES, CycleRecord, FlightLogError, FlightLogWriter
from companion.user_files import UserFileError, open_regular_file

__all__ = [
    "CHANNELS",
    "CHUNK_SIZE",
    "SCHEMAS",
    "ArmGeometry",
    "ChannelInfo",
    "FlightLogWithMcap",
    "McapInfo",
    "McapLogWriter",
    "cycle_messages",
    "describe_mcap",
    "encode",
    "frame_transforms",
    "log_message",
    "mcap_path",
    "pose_in_frame",
    "register_channel",
    "start_writer",
    "time_ns",
]

CHUNK_SIZE = 64 * 1024
"""Bytes of messages per chunk (about 40 cycles). A full chunk is indexed and compressed in
one go, in the cycle that fills it: a small one keeps that cycle's write short (about
0.3 ms more, measured) and loses less in a crash."""
PROFILE = ""
"""MCAP profile: none (JSON messages, no ROS)."""
LIBRARY = "aerial-manipulator-companion"

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


# -- schemas -----------------------------------------------------------------------------

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
}
_VECTOR3 = {
    "type": "object",
    "title": "foxglove.Vector3",
    "properties": {axis: {"type": "number"} for axis in "xyz"},
}
_QUATERNION = {
    "type": "object",
    "title": "foxglove.Quaternion",
    "properties": {
        "x": {"type": "number", "default": 0},
        "y": {"type": "number", "default": 0},
        "z": {"type": "number", "default": 0},
        "w": {"type": "number", "default": 1},
    },
}
_FRAME_TRANSFORM = {
    "type": "object",
    "title": "foxglove.FrameTransform",
    "description": "A transform between two reference frames in 3D space",
    "properties": {
        "timestamp": {**_TIME, "description": "Timestamp of transform"},
        "parent_frame_id": {"type": "string", "description": "Name of the parent frame"},
        "child_frame_id": {"type": "string", "description": "Name of the child frame"},
        "translation": {**_VECTOR3, "description": "Translation component of the transform"},
        "rotation": {**_QUATERNION, "description": "Rotation component of the transform"},
    },
}


def _foxglove(title: str, description: str, properties: dict[str, Any]) -> dict[str, Any]:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
    }


def _plain(title: str, description: str, fields: dict[str, Any]) -> dict[str, Any]:
    """A plain schema: a Foxglove ``timestamp`` and the given fields."""
    return _foxglove(title, description, {"timestamp": _TIME, **fields})


_NUMBER = {"type": ["number", "null"]}
_FLAG = {"type": ["boolean", "null"]}


def _numbers(keys: Iterable[str], description: str) -> dict[str, Any]:
    return {
        "type": "object",
        "description": description,
        "properties": {k: _NUMBER for k in keys},
    }


SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.FrameTransforms": _foxglove(
        "foxglove.FrameTransforms",
        "An array of FrameTransform messages",
        {"transforms": {"type": "array", "items": _FRAME_TRANSFORM}},
    ),
    "foxglove.PoseInFrame": _foxglove(
        "foxglove.PoseInFrame",
        "A timestamped pose for an object or reference frame in 3D space",
        {
            "timestamp": {**_TIME, "description": "Timestamp of pose"},
            "frame_id": {"type": "string", "description": "Frame of reference for pose"},
            "pose": {
                "type": "object",
                "title": "foxglove.Pose",
                "properties": {"position": _VECTOR3, "orientation": _QUATERNION},
            },
        },
    ),
    "foxglove.Log": _foxglove(
        "foxglove.Log",
        "A log message",
        {
            "timestamp": {**_TIME, "description": "Timestamp of log message"},
            "level": {
                "title": "foxglove.LogLevel",
                "description": "Log level",
                "oneOf": [
                    {"title": name, "const": value}
                    for value, name in enumerate(
                        ("UNKNOWN", "DEBUG", "INFO", "WARNING", "ERROR", "FATAL")
                    )
                ],
            },
            "message": {"type": "string", "description": "Log message"},
            "name": {"type": "string", "description": "Process or node name"},
            "file": {"type": "string", "description": "Filename"},
            "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
        },
    ),
    "companion.State": _plain(
        "companion.State",
        "Filtered q [m, rad] and q_dot [m/s, rad/s] (world ENU, body FLU, ZYX Euler)",
        {
            "q": _numbers(Q_KEYS, "q = [x, y, z, phi, theta, psi, eta1, eta2]"),
            "q_dot": _numbers(Q_DOT_KEYS, "q_dot"),
        },
    ),
    "companion.Desired": _plain(
        "companion.Desired",
        "Desired q_d [m, rad] (world ENU, body FLU, ZYX Euler)",
        {k: _NUMBER for k in Q_KEYS},
    ),
    "companion.Setpoint": _plain(
        "companion.Setpoint",
        "Attitude setpoint sent to PX4 (ENU / FLU, ZYX Euler) and collective thrust",
        {
            "roll_rad": _NUMBER,
            "pitch_rad": _NUMBER,
            "yaw_rad": _NUMBER,
            "thrust_n": _NUMBER,
            "thrust_rel": {**_NUMBER, "description": "PX4's relative thrust in [0, 1]"},
            "tilt_saturated": _FLAG,
            "thrust_saturated": _FLAG,
        },
    ),
    "companion.Estimate": _plain(
        "companion.Estimate",
        "Payload estimate theta_hat = (m2, m3, m4), lc = m3/m2, its confidence and the "
        "thrust scale (true over modelled thrust)",
        {
            **{k: _NUMBER for k in THETA_KEYS},
            "excitation": _NUMBER,
            "spread": _NUMBER,
            "confident": _FLAG,
            "frozen": _FLAG,
            "thrust_scale": _NUMBER,
        },
    ),
    "companion.Timing": _plain(
        "companion.Timing",
        "Vehicle time since the previous cycle [ms]; in the live view also the wall-clock "
        "latencies [us] when measured (a flight log keeps them in LOG.timing.csv)",
        {
            "loop_period_ms": _NUMBER,
            "setpoint_latency_us": _NUMBER,
            "cycle_latency_us": _NUMBER,
            "setpoint_cpu_us": _NUMBER,
        },
    ),
}
"""Every schema the companion writes, by name (Foxglove's as published, JSON flavour)."""

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


def _stamp(ns: int) -> dict[str, int]:
    sec, nsec = divmod(ns, 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _xyzw(q_wxyz: Sequence[float]) -> dict[str, float]:
    w, x, y, z = q_wxyz
    return {"x": x, "y": y, "z": z, "w": w}


def _transform(
    stamp: dict[str, int],
    parent: str,
    child: str,
    translation: Sequence[float],
    rotation: dict[str, float],
) -> dict[str, Any]:
    x, y, z = translation
    return {
        "timestamp": stamp,
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": x, "y": y, "z": z},
        "rotation": rotation,
    }


_IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


def frame_transforms(q: Sequence[float], geometry: ArmGeometry, ns: int) -> dict[str, Any]:
    """``foxglove.FrameTransforms`` of the vehicle and the arm at q (see the module table).

    A joint angle eta about body y turns its link's x axis to (cos eta, 0, sin eta): a
    rotation by -eta about y (R_y(a) turns x to (cos a, 0, -sin a)).
    """
    x, y, z, phi, theta, psi, eta1, eta2 = q
    stamp = _stamp(ns)
    return {
        "transforms": [
            _transform(
                stamp,
                "world",
                "base_link",
                (x, y, z),
                _xyzw(quaternion_from_euler_zyx(phi, theta, psi)),
            ),
            _transform(
                stamp,
                "base_link",
                "link1",
                geometry.mount_point_m,
                _xyzw(quaternion_from_euler_zyx(0.0, -eta1, 0.0)),
            ),
            _transform(
                stamp,
                "link1",
                "link2",
                (geometry.link1_length_m, 0.0, 0.0),
                _xyzw(quaternion_from_euler_zyx(0.0, -eta2, 0.0)),
            ),
            _transform(stamp, "link2", "gripper", (geometry.link2_length_m, 0.0, 0.0), _IDENTITY),
        ]
    }


def pose_in_frame(q: Sequence[float], ns: int, frame_id: str = "world") -> dict[str, Any]:
    """``foxglove.PoseInFrame`` of the vehicle at q (position, ZYX attitude; ENU / FLU)."""
    x, y, z, phi, theta, psi = q[:6]
    return {
        "timestamp": _stamp(ns),
        "frame_id": frame_id,
        "pose": {
            "position": {"x": x, "y": y, "z": z},
            "orientation": _xyzw(quaternion_from_euler_zyx(phi, theta, psi)),
        },
    }


def _value(v: float | None) -> float | None:
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _flag(v: bool | None) -> bool | None:
    return None if v is None else bool(v)


def _floats(values: ArrayLike | None, n: int) -> list[float] | None:
    if values is None:
        return None
    out = np.asarray(values, dtype=np.float64).reshape(-1).tolist()
    if len(out) != n:
        raise FlightLogError(f"expected {n} values, got {len(out)}")
    return out


def _named(keys: Sequence[str], values: list[float] | None) -> dict[str, float | None]:
    if values is None:
        return dict.fromkeys(keys)
    return {k: (v if math.isfinite(v) else None) for k, v in zip(keys, values, strict=True)}


def cycle_messages(
    record: CycleRecord, geometry: ArmGeometry, *, wall_clock: bool = True
) -> list[tuple[str, dict]]:
    """(topic, message) of one control cycle, in :data:`CHANNELS` order (pure); without
    ``wall_clock`` ``/timing`` holds the loop period only (the file's)."""
    r = record
    ns = time_ns(r.t_vehicle_s)
    stamp = _stamp(ns)
    out: list[tuple[str, dict]] = []
    q = _floats(r.q, len(Q_KEYS))
    if q is not None and all(math.isfinite(v) for v in q):
        out.append(("/tf", frame_transforms(q, geometry, ns)))
        out.append(("/vehicle/pose", pose_in_frame(q, ns)))
    out.append(
        (
            "/state",
            {
                "timestamp": stamp,
                "q": _named(Q_KEYS, q),
                "q_dot": _named(Q_DOT_KEYS, _floats(r.q_dot, len(Q_KEYS))),
            },
        )
    )
    out.append(("/desired", {"timestamp": stamp, **_named(Q_KEYS, _floats(r.q_d, len(Q_KEYS)))}))
    sp = r.setpoint
    if sp is not None:
        out.append(
            (
                "/setpoint",
                {
                    "timestamp": stamp,
                    "roll_rad": _value(sp.roll_rad),
                    "pitch_rad": _value(sp.pitch_rad),
                    "yaw_rad": _value(sp.yaw_rad),
                    "thrust_n": _value(sp.thrust_n),
                    "thrust_rel": _value(sp.thrust_relative),
                    "tilt_saturated": bool(sp.tilt_saturated),
                    "thrust_saturated": bool(sp.thrust_saturated),
                },
            )
        )
    if r.theta_hat is None:
        theta = dict.fromkeys(THETA_KEYS)
    else:
        m2, m3, m4 = np.asarray(r.theta_hat, dtype=np.float64).reshape(3).tolist()
        theta = {
            "m2_kg": _value(m2),
            "m3_kg_m": _value(m3),
            "m4_kg_m2": _value(m4),
            "lc_m": _value(m3 / m2) if m2 != 0.0 else None,
        }
    out.append(
        (
            "/estimate",
            {
                "timestamp": stamp,
                **theta,
                "excitation": _value(r.theta_excitation),
                "spread": _value(r.theta_spread),
                "confident": _flag(r.theta_confident),
                "frozen": _flag(r.theta_frozen),
                "thrust_scale": _value(r.thrust_scale_hat),
            },
        )
    )
    timing: dict[str, Any] = {"timestamp": stamp, "loop_period_ms": _value(r.loop_period_ms)}
    if wall_clock:
        for key in ("setpoint_latency_us", "cycle_latency_us", "setpoint_cpu_us"):
            value = _value(getattr(r, key))
            if value is not None:
                timing[key] = value
    out.append(("/timing", timing))
    return out


def log_message(kind: str, detail: str, ns: int) -> dict[str, Any]:
    """``foxglove.Log`` of one event (see :data:`LOG_LEVELS`)."""
    return {
        "timestamp": _stamp(ns),
        "level": LOG_LEVELS.get(kind, LOG_INFO),
        "message": detail,
        "name": kind,
        "file": "",
        "line": 0,
    }


_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False, ensure_ascii=False)


def encode(message: dict[str, Any]) -> bytes:
    """A message as compact UTF-8 JSON (no NaN: missing values are null)."""
    return _ENCODER.encode(message).encode("utf-8")


# -- writing -----------------------------------------------------------------------------


def start_writer(stream: IO[bytes]) -> Writer:
    """An MCAP writer on ``stream``, started (Zstandard chunks of :data:`CHUNK_SIZE`)."""
    writer = Writer(stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
    writer.start(profile=PROFILE, library=LIBRARY)
    return writer


def schema_data(schema: dict[str, Any]) -> bytes:
    """A JSON schema as the bytes a channel's schema record carries."""
    return json.dumps(schema, indent=1).encode("utf-8")


def register_channel(
    writer: Writer,
    topic: str,
    schema_name: str,
    schema: dict[str, Any],
    schema_ids: dict[str, int],
) -> int:
    """Register ``topic`` under ``schema_name`` (the schema once per writer, remembered in
    ``schema_ids``); the channel id."""
    schema_id = schema_ids.get(schema_name)
    if schema_id is None:
        data = schema_data(schema)
        schema_id = writer.register_schema(name=schema_name, encoding="jsonschema", data=data)
        schema_ids[schema_name] = schema_id
    return writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)


def merge_messages(
    mcap_path: str | Path,
    channels: dict[str, tuple[str, dict[str, Any]]],
    messages: Iterable[tuple[int, str, bytes]],
) -> int:
    """Rewrite the closed log ``mcap_path`` with new ``channels`` (topic -> (schema name,
    JSON schema)) and their ``messages`` ((log time [ns], topic, JSON bytes), in time
    order) merged in time order with what it holds; the number of messages added. The
    file is replaced in one step (a crash leaves the old one).

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
        except McapError as exc:
            raise ValueError(f"{mcap_path}: not a readable MCAP log ({exc})") from None
        if summary is None:
            raise ValueError(f"{mcap_path}: no summary (the flight's log was not closed)")
        present = sorted(c.topic for c in summary.channels.values() if c.topic in channels)
        if present:
            raise ValueError(f"{mcap_path}: holds {', '.join(present)} already")
        with open(tmp, "xb") as dst:
            try:
                writer = start_writer(dst)
                schema_ids: dict[str, int] = {}
                ids: dict[int, int] = {}
                for cid, channel in sorted(summary.channels.items()):
                    schema = summary.schemas[channel.schema_id]
                    ids[cid] = register_channel(
                        writer, channel.topic, schema.name, json.loads(schema.data), schema_ids
                    )
                new_ids = {
                    topic: register_channel(writer, topic, name, schema, schema_ids)
                    for topic, (name, schema) in channels.items()
                }
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
    """Writes ``LOG.mcap`` (see the module docstring): :meth:`write` one cycle,
    :meth:`event` one event.

    Nothing is opened in the constructor; use ``with McapLogWriter(path, geometry)`` or
    :meth:`open` / :meth:`close` (idempotent). The file is never overwritten.
    """

    def __init__(self, path: str | Path, geometry: ArmGeometry) -> None:
        self.path = Path(path)
        self.geometry = geometry
        self.messages = 0
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._last_ns = 0
        self._closed = False

    def __enter__(self) -> McapLogWriter:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        if self._file is not None or self._closed:
            raise FlightLogError(f"{self.path}: an McapLogWriter opens once")
        try:
            self._file = open(self.path, "xb")
        except FileExistsError:
            self._closed = True
            raise FlightLogError(
                f"{self.path}: exists; a flight log is never overwritten"
            ) from None
        except OSError as exc:
            self._closed = True
            raise FlightLogError(f"{self.path}: cannot write: {exc.strerror}") from None
        self._writer = start_writer(self._file)
        schema_ids: dict[str, int] = {}
        for topic, name in CHANNELS.items():
            self._channels[topic] = register_channel(
                self._writer, topic, name, SCHEMAS[name], schema_ids
            )
            self._sequence[topic] = 0

    def _add(self, topic: str, ns: int, message: dict[str, Any]) -> None:
        assert self._writer is not None
        sequence = self._sequence[topic]
        self._sequence[topic] = sequence + 1
        self._writer.add_message(self._channels[topic], ns, encode(message), ns, sequence)
        self.messages += 1

    def write(self, record: CycleRecord) -> None:
        """Append one cycle's messages."""
        if self._writer is None:
            raise FlightLogError(f"{self.path}: the log is not open")
        ns = time_ns(record.t_vehicle_s)
        for topic, message in cycle_messages(record, self.geometry, wall_clock=False):
            self._add(topic, ns, message)
        self._last_ns = ns

    def event(self, kind: str, detail: str, t_vehicle_s: float) -> None:
        """Append an event as a ``foxglove.Log`` message on ``/events``. An event before
        the vehicle's clock is known (NaN, as the app's time before its first pose) is
        logged at the last time logged (0 before any)."""
        if self._writer is None:
            raise FlightLogError(f"{self.path}: the log is not open")
        ns = time_ns(t_vehicle_s) if math.isfinite(t_vehicle_s) else self._last_ns
        self._last_ns = ns
        self._add("/events", ns, log_message(kind, detail, ns))

    def close(self) -> None:
        """Write the summary, fsync and close (idempotent)."""
        self._closed = True
        writer, self._writer = self._writer, None
        f, self._file = self._file, None
        if f is None:
            return
        try:
            if writer is not None:
                writer.finish()
            f.flush()
            os.fsync(f.fileno())
        finally:
            f.close()


class FlightLogWithMcap(FlightLogWriter):
    """:class:`~companion.logs.flightlog.FlightLogWriter` that also writes ``LOG.mcap``: every
    cycle and every event (the ones it derives from the cycles too) go to both files.

    Opens the MCAP after the CSV files (and closes it after them); a file of either that
    exists stops the open, as for the CSV alone.
    """

    def __init__(
        self, path: str | Path, geometry: ArmGeometry, flush_every_rows: int = 250
    ) -> None:
        super().__init__(path, flush_every_rows)
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

    def write(self, record: CycleRecord) -> None:
        super().write(record)
        self.mcap.write(record)

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

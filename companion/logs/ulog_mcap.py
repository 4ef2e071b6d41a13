"""PX4's own log (ULog) on the flight log's timeline: chosen PX4 topics merged into a
flight's ``flight.mcap`` (:func:`companion.logs.mcap_log.merge_messages`).

PX4 stamps each ULog message with its ``timestamp`` in microseconds since PX4 booted; the
companion logs by the vehicle's clock it reads from ODOMETRY, also time since PX4 booted
(:mod:`companion.logs.mcap_log`). The two therefore share one time axis with no offset, and one
view in Foxglove or PlotJuggler shows PX4's attitude setpoint beside the companion's. This
holds for a flight with the real PX4 (its SD card's ``.ulg``) and for PX4 SITL (its
``log/`` directory; ``sitl demo --autopilot px4`` merges it itself).

=====================================  =================================================
channel (schema ``px4.TOPIC``)          fields (ULog names, ``[i]`` as ``_i``)
=====================================  =================================================
``/px4/vehicle_attitude_setpoint``      ``q_d_0..3`` (FRD -> NED), ``thrust_body_0..2``
``/px4/vehicle_attitude``               ``q_0..3``
``/px4/vehicle_local_position``         ``x y z vx vy vz`` [m, m/s, NED]
``/px4/actuator_motors``                ``control_0..5`` (normalized motor commands)
``/px4/vehicle_status``                 ``nav_state arming_state``
``/px4/battery_status``                 ``voltage_v current_a remaining``
=====================================  =================================================

A topic PX4 did not log is left out. Reading a ULog needs pyulog (the ``sim`` extra, or
``pip install pyulog``), imported only here.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from companion.logs.mcap_log import ChannelSpec, encode, json_channel, merge_messages
from companion.user_files import UserFileError, check_regular_file, open_regular_file

__all__ = ["PX4_TOPICS", "UlogError", "add_ulog", "ulog_channels"]

PX4_TOPICS: dict[str, tuple[str, ...]] = {
    "vehicle_attitude_setpoint": (
        "q_d[0]", "q_d[1]", "q_d[2]", "q_d[3]",
        "thrust_body[0]", "thrust_body[1]", "thrust_body[2]",
    ),
    "vehicle_attitude": ("q[0]", "q[1]", "q[2]", "q[3]"),
    "vehicle_local_position": ("x", "y", "z", "vx", "vy", "vz"),
    "actuator_motors": tuple(f"control[{i}]" for i in range(6)),
    "vehicle_status": ("nav_state", "arming_state"),
    "battery_status": ("voltage_v", "current_a", "remaining"),
}  # fmt: skip
"""PX4 topic -> the ULog fields written for it (instance 0 of each)."""


class UlogError(RuntimeError):
    """The ULog cannot be read (missing, corrupt, or pyulog not installed); one line."""


def _key(field: str) -> str:
    """A ULog field name as a JSON key: ``q_d[0]`` -> ``q_d_0``."""
    return field.replace("[", "_").replace("]", "")


def _schema(topic: str, fields: tuple[str, ...]) -> dict[str, Any]:
    return {
        "title": f"px4.{topic}",
        "description": f"PX4's {topic} (uORB), from its ULog",
        "type": "object",
        "properties": {
            "timestamp": {
                "type": "object",
                "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
            },
            **{_key(f): {"type": ["number", "null"]} for f in fields},
        },
    }


def _topic_messages(topic: str, data: dict[str, Any]) -> Iterator[tuple[int, str, bytes]]:
    """(log time [ns], channel, JSON) of one logged topic, in time order."""
    fields = [f for f in PX4_TOPICS[topic] if f in data]
    channel = f"/px4/{topic}"
    columns = [data[f].tolist() for f in fields]
    keys = [_key(f) for f in fields]
    for i, t_us in enumerate(data["timestamp"].tolist()):
        ns = int(t_us) * 1000
        message: dict[str, Any] = {"timestamp": {"sec": ns // 10**9, "nsec": ns % 10**9}}
        for key, column in zip(keys, columns, strict=True):
            value = float(column[i])
            message[key] = value if math.isfinite(value) else None
        yield ns, channel, encode(message)


def _read(ulog_path: Path) -> dict[str, dict[str, Any]]:
    """Topic -> its columns (instance 0), for the topics of :data:`PX4_TOPICS` logged."""
    try:
        from pyulog import ULog
    except ImportError:
        raise UlogError("reading a ULog needs pyulog: pip install pyulog") from None
    try:
        f = open_regular_file(ulog_path)
    except UserFileError as exc:
        raise UlogError(str(exc)) from None
    try:
        with f:
            ulog = ULog(f, list(PX4_TOPICS))
    except Exception as exc:  # pyulog raises what its parser meets in a corrupt file
        raise UlogError(f"{ulog_path}: not a readable ULog ({exc})") from None
    logged = {
        d.name: d.data for d in ulog.data_list if d.multi_id == 0 and len(d.data["timestamp"])
    }
    if not logged:
        raise UlogError(
            f"{ulog_path}: not a readable ULog of a flight (none of {', '.join(PX4_TOPICS)} in it)"
        )
    return logged


def ulog_channels(logged: dict[str, dict[str, Any]]) -> dict[str, ChannelSpec]:
    """Channel -> its JSON channel (schema name ``px4.TOPIC``) of the logged topics."""
    return {
        f"/px4/{topic}": json_channel(f"px4.{topic}", _schema(topic, PX4_TOPICS[topic]))
        for topic in PX4_TOPICS
        if topic in logged
    }


def add_ulog(mcap_path: str | Path, ulog_path: str | Path) -> int:
    """Merge the PX4 topics of :data:`PX4_TOPICS` logged in ``ulog_path`` into the closed
    flight log ``mcap_path``, in time order; the number of messages added.

    Raises :class:`UlogError` for a ULog that cannot be read and ``ValueError`` for a
    flight log that is not closed or holds PX4's channels already.
    """
    try:  # both files are what they should be before either is read
        check_regular_file(mcap_path)
    except UserFileError as exc:
        raise UlogError(str(exc)) from None
    logged = _read(Path(ulog_path))
    streams = [_topic_messages(topic, logged[topic]) for topic in PX4_TOPICS if topic in logged]
    merged = heapq.merge(*streams, key=lambda m: m[0])
    return merge_messages(mcap_path, ulog_channels(logged), merged)

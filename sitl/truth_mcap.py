"""The simulator's truth in a flight's MCAP, beside the companion's estimate.

After a simulator flight, :func:`add_truth` writes the truth log (``truth.jsonl``, one
line per truth step, :func:`sitl.vehicle.runner.truth_record`) into the flight's ``flight.mcap``
(:mod:`companion.logs.mcap_log`), merged with the companion's messages in time order:

=================  ===========================  ==============================================
channel            schema                       content (one message per truth line)
=================  ===========================  ==============================================
``/truth``         ``sitl.Truth``               link 2's true theta by the names of
                                                ``/estimate`` (``m2_kg``, ``m3_kg_m``,
                                                ``m4_kg_m2``, ``lc_m``: the payload's mass and
                                                centre of mass with the link), the true q by
                                                the names of ``/state``, payload attached,
                                                on the ground, armed, object position
``/truth/pose``    ``foxglove.PoseInFrame``     the true vehicle pose in ``world``
=================  ===========================  ==============================================

The truth's time is the simulator's, which is the vehicle's clock the companion logs by
(time since boot), so ``/estimate`` and ``/truth`` plot on one time axis. The companion
never sees any of it: the truth goes in after the flight, from the file.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from companion.logs.mcap_log import (
    Q_KEYS,
    THETA_KEYS,
    encode,
    json_channel,
    merge_messages,
    pose_in_frame,
    protobuf_channel,
    time_ns,
)

__all__ = ["TRUTH_CHANNELS", "TRUTH_SCHEMA", "add_flight_truth", "add_truth", "truth_messages"]

_NUMBER = {"type": ["number", "null"]}
_FLAG = {"type": ["boolean", "null"]}

TRUTH_SCHEMA: dict[str, Any] = {
    "title": "sitl.Truth",
    "description": "The simulator's truth: link 2's theta (payload included), q, contact",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "title": "time",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
            },
        },
        **{k: _NUMBER for k in THETA_KEYS},
        "q": {"type": "object", "properties": {k: _NUMBER for k in Q_KEYS}},
        "payload_attached": _FLAG,
        "on_ground": _FLAG,
        "armed": _FLAG,
        "object_position_m": {
            "type": ["object", "null"],
            "properties": {axis: {"type": "number"} for axis in "xyz"},
        },
    },
}

TRUTH_CHANNELS = {"/truth": "sitl.Truth", "/truth/pose": "foxglove.PoseInFrame"}
"""Topic -> schema name of the truth's channels."""


def _finite(v: Any) -> float | None:
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def truth_messages(record: dict[str, Any]) -> tuple[int, list[tuple[str, bytes]]]:
    """(log time [ns], [(topic, encoded message)]) of one truth-log line (pure): ``/truth``
    in JSON, ``/truth/pose`` in Protobuf as the flight's ``/vehicle/pose``."""
    ns = time_ns(float(record["t_s"]))
    q = [float(v) for v in record["q"]]
    m2, m3, m4 = (float(v) for v in record["true_theta"])
    obj = record.get("object_position_m")
    truth = {
        "timestamp": dict(zip(("sec", "nsec"), divmod(ns, 1_000_000_000), strict=True)),
        "m2_kg": _finite(m2),
        "m3_kg_m": _finite(m3),
        "m4_kg_m2": _finite(m4),
        "lc_m": _finite(m3 / m2) if m2 != 0.0 else None,
        "q": {k: _finite(v) for k, v in zip(Q_KEYS, q, strict=True)},
        "payload_attached": record.get("payload_attached"),
        "on_ground": record.get("on_ground"),
        "armed": record.get("armed"),
        "object_position_m": None if obj is None else dict(zip("xyz", obj, strict=True)),
    }
    messages: list[tuple[str, bytes]] = [("/truth", encode(truth))]
    if all(math.isfinite(v) for v in q):
        messages.append(("/truth/pose", pose_in_frame(q, ns)))
    return ns, messages


def _truth_lines(truth_path: Path) -> Iterator[tuple[int, str, bytes]]:
    with open(truth_path, encoding="utf-8") as f:
        for line in f:
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError:  # a last line cut by a crash
                return
            ns, messages = truth_messages(record)
            for topic, message in messages:
                yield ns, topic, message


def add_truth(mcap_path: str | Path, truth_path: str | Path) -> int:
    """Rewrite ``mcap_path`` with the truth of ``truth_path`` merged in; the number of
    truth messages added (:func:`companion.logs.mcap_log.merge_messages`: the file is replaced
    in one step).

    Raises ``ValueError`` if the MCAP already has a truth channel.
    """
    channels = {
        "/truth": json_channel("sitl.Truth", TRUTH_SCHEMA),
        "/truth/pose": protobuf_channel("foxglove.PoseInFrame"),
    }
    return merge_messages(mcap_path, channels, _truth_lines(Path(truth_path)))


def add_flight_truth(out_dir: Path, truth_log: Path | None) -> int:
    """:func:`add_truth` of ``truth_log`` into ``out_dir``'s ``flight.mcap``, when both
    exist (a flight refused before it flew has no log); the number of messages added."""
    flight = Path(out_dir) / "flight.mcap"
    if truth_log is None or not truth_log.exists() or not flight.exists():
        return 0
    return add_truth(flight, truth_log)

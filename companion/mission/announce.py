"""The mission's progress told on the MAVLink link: one STATUSTEXT per phase and fault.

PX4 records a STATUSTEXT from a component of its own system in its log (ULog
``logging`` messages, as ``[mavlink: component 191] pickup: phase grasp``) and shows it on
the ground station (``MavlinkReceiver::handle_message_statustext``), so the mission's phases
appear beside PX4's own events; the simulator reads them to start a fault at a phase.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

__all__ = ["FAULT_PREFIX", "PHASE_PREFIX", "STATUSTEXT_CHARS", "announcement", "phase_of"]

PHASE_PREFIX = "pickup: phase "
"""A phase's text: this prefix and the phase's name (``companion.mission.pickup.Phase``)."""
FAULT_PREFIX = "pickup: fault "
"""A fault's text: this prefix, the fault's name and its detail."""
STATUSTEXT_CHARS = 50
"""STATUSTEXT's text field [bytes]: a longer text is cut there."""

_SEVERITY = {
    "phase": mavlink2.MAV_SEVERITY_INFO,
    "fault": mavlink2.MAV_SEVERITY_WARNING,
}
_PREFIX = {"phase": PHASE_PREFIX, "fault": FAULT_PREFIX}


def announcement(kind: str, detail: str) -> tuple[int, bytes] | None:
    """(MAV_SEVERITY, text) of the STATUSTEXT telling a mission event of ``kind`` (``phase``
    or ``fault``, as the flight log's events), or None for kinds not told."""
    if kind not in _SEVERITY:
        return None
    text = (_PREFIX[kind] + detail).encode("ascii", "replace")[:STATUSTEXT_CHARS]
    return _SEVERITY[kind], text


def phase_of(text: str) -> str | None:
    """The phase a STATUSTEXT's text announces, or None when it announces none."""
    if not text.startswith(PHASE_PREFIX):
        return None
    return text[len(PHASE_PREFIX) :].strip() or None

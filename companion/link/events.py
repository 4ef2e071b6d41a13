"""Events the link publishes to its subscribers (keys: the classes themselves)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LinkLost", "LinkRegained", "VehicleDetected", "VehicleId"]


@dataclass(frozen=True)
class VehicleId:
    """MAVLink address of the autopilot: system and component id."""

    system_id: int
    component_id: int


@dataclass(frozen=True)
class VehicleDetected:
    """The first PX4 HEARTBEAT: from now on commands and setpoints go to ``vehicle``."""

    vehicle: VehicleId


@dataclass(frozen=True)
class LinkLost:
    """No vehicle ``reason`` (``"heartbeat"`` or ``"telemetry"``) for ``silent_s`` [s],
    longer than the configured timeout."""

    reason: str
    silent_s: float


@dataclass(frozen=True)
class LinkRegained:
    """Heartbeat and telemetry are fresh again after a :class:`LinkLost` of ``lost_for_s``
    [s]."""

    reason: str
    lost_for_s: float

"""When the mission's phases began, as seen from the vehicle: the start of a fault placed
at a phase.

The companion tells each phase on the onboard link (a STATUSTEXT ``pickup: phase NAME``,
:mod:`companion.mission.announce`); PX4's take-off and landing are the autopilot's own modes
(AUTO_TAKEOFF: ``takeoff``, AUTO_LAND: ``landing``). :class:`MissionPhases` records the
simulated time [s] each phase was first seen; :class:`PhaseStart` names a moment as a phase
and an offset into it. Only what crossed the link is read: never the companion's state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from companion.mission.announce import phase_of
from companion.mission.pickup import Phase

__all__ = [
    "FAULT_PHASES",
    "PX4_PHASES",
    "FaultStart",
    "MissionPhases",
    "PhaseStart",
    "Stretch",
    "valid_start",
]

_MODE_PHASES = {"AUTO_TAKEOFF": "takeoff", "AUTO_LAND": "landing"}
PX4_PHASES: tuple[str, ...] = tuple(_MODE_PHASES.values())
"""The moments that are the autopilot's own modes, not told by the companion."""
FAULT_PHASES: tuple[str, ...] = (
    "takeoff",
    *(p.value for p in Phase if p not in (Phase.DONE, Phase.RETURN)),
    "landing",
)
"""The moments a fault can be placed at, in flight order."""


@dataclass(frozen=True)
class PhaseStart:
    """A moment in a flight: ``offset_s`` [s, simulated time] after ``phase`` began."""

    phase: str
    offset_s: float = 0.0

    def __post_init__(self) -> None:
        if self.phase not in FAULT_PHASES:
            raise ValueError(f"phase must be one of {', '.join(FAULT_PHASES)}, got {self.phase!r}")
        if not (math.isfinite(self.offset_s) and self.offset_s >= 0.0):
            raise ValueError(f"a phase's offset must be at least 0 s, got {self.offset_s!r}")


FaultStart = float | PhaseStart
"""When a fault starts: a simulated time [s] or a :class:`PhaseStart`."""


def valid_start(start: FaultStart) -> bool:
    """A phase (checked when made) or a finite simulated time >= 0 [s]."""
    return isinstance(start, PhaseStart) or (math.isfinite(start) and start >= 0.0)


@dataclass(frozen=True)
class Stretch:
    """A fault acting on its traffic for ``duration_s`` [s] from ``start``, at a strength:
    the subclass's own field named :attr:`STRENGTH` (a fraction of the traffic, or a delay
    [s]) in (0, :attr:`MOST`]. Checked when made (ValueError)."""

    start: FaultStart
    duration_s: float
    WHAT: ClassVar[str]
    """The fault, as the error says it."""
    STRENGTH: ClassVar[str]
    """The subclass's field of the strength."""
    MOST: ClassVar[float] = 1.0

    def __post_init__(self) -> None:
        what, value = self.WHAT, getattr(self, self.STRENGTH)
        if not valid_start(self.start):
            raise ValueError(f"a {what} starts at a time >= 0 or a phase, got {self.start!r}")
        if not (math.isfinite(self.duration_s) and self.duration_s > 0.0):
            raise ValueError(f"a {what} lasts a positive time, got {self.duration_s!r}")
        if not (math.isfinite(value) and 0.0 < value <= self.MOST):
            raise ValueError(f"{self.STRENGTH} must be in (0, {self.MOST:g}], got {value!r}")


class MissionPhases:
    """The simulated time each phase of the flight was first seen [s]."""

    def __init__(self) -> None:
        self.began_s: dict[str, float] = {}

    def observe_text(self, text: str, now_s: float) -> str | None:
        """A STATUSTEXT's text received from the companion at ``now_s`` [s]; returns the
        phase it begins, None when it begins none (not a phase, or told before)."""
        phase = phase_of(text)
        if phase is None or phase in self.began_s:
            return None
        self.began_s[phase] = now_s
        return phase

    def observe_mode(self, mode_name: str, now_s: float) -> None:
        """The autopilot's mode (its display name) at ``now_s`` [s]."""
        phase = _MODE_PHASES.get(mode_name)
        if phase is not None:
            self.began_s.setdefault(phase, now_s)

    def start_s(self, start: FaultStart) -> float | None:
        """The simulated time ``start`` names [s], None while its phase has not begun."""
        if not isinstance(start, PhaseStart):
            return start
        began = self.began_s.get(start.phase)
        return None if began is None else began + start.offset_s

    def reached(self, start: FaultStart, now_s: float) -> bool:
        """``start`` has come by ``now_s`` [s]."""
        start_s = self.start_s(start)
        return start_s is not None and now_s >= start_s

    def within(self, start: FaultStart, duration_s: float, now_s: float) -> bool:
        """``now_s`` [s] lies in the stretch of ``duration_s`` [s] from ``start``."""
        start_s = self.start_s(start)
        return start_s is not None and start_s <= now_s < start_s + duration_s

"""Whether the vehicle carries the object: the gripper and the estimate (pure, no clock).

Two witnesses, each able to say "not carried" on its own:

- **the gripper servo**: closed on an object its jaws stop on the object, short of the
  closed position, and the servo pushes against it (its present current); closed on
  nothing it reaches the closed position and draws (almost) none
  (:func:`gripper_holds`). Read a few times a second while the object should be in the
  jaws, it tells within a fraction of a second that an object slipped out;
- **the estimate**: once the estimator is confident, link 2's mass m2 (paper eq. theta:
  link 2 plus payload) must lie above the empty link 2's by ``mass_margin_kg``
  (:meth:`CarryWatch.update`). It needs the excitation to become confident, so it is the
  slow witness, and the only one on a bus that cannot read the gripper.

:class:`CarryWatch` turns them into a verdict: at the end of the grasp (the gripper closed
on nothing: ``grasp_failed``) and through the carry (``payload_lost`` once the object was
seen in the jaws, ``grasp_failed`` if it never was).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.mission.pickup import Outcome

__all__ = ["CarryThresholds", "CarryVerdict", "CarryWatch", "gripper_holds"]

EMPTY_READINGS = 2
"""Consecutive gripper readings at the closed position that make an object lost (one
reading could be a servo's glitch; at the app's 10 Hz that is 0.1-0.2 s)."""


@dataclass(frozen=True)
class CarryThresholds:
    """Where "holding" ends (``[flight]`` keys of the same names).

    Attributes
    ----------
    gripper_margin_rad
        The jaws hold an object when the gripper servo stopped more than this short of its
        closed position, toward open [rad] (servo shaft angle).
    gripper_current_a
        ... and it draws at least this current magnitude [A] (only where the bus reports a
        current).
    mass_margin_kg
        A confident estimate of m2 below the empty link 2's plus this carries nothing [kg].
    """

    gripper_margin_rad: float = 0.1
    gripper_current_a: float = 0.2
    mass_margin_kg: float = 0.05

    def __post_init__(self) -> None:
        if not (self.gripper_margin_rad > 0.0 and self.mass_margin_kg > 0.0):
            raise ValueError("gripper_margin_rad and mass_margin_kg must be positive")
        if not self.gripper_current_a >= 0.0:
            raise ValueError("gripper_current_a must be >= 0")


def gripper_holds(
    position_rad: float,
    current_a: float,
    open_rad: float,
    closed_rad: float,
    thresholds: CarryThresholds,
) -> bool:
    """Whether the gripper servo, at shaft angle ``position_rad`` [rad] drawing
    ``current_a`` [A] (NaN: not reported), holds an object between its jaws, which travel
    from ``open_rad`` to ``closed_rad`` [rad]: stopped short of closed by more than the
    margin, toward open, and pushing (when the current is known)."""
    toward_open = (position_rad - closed_rad) * math.copysign(1.0, open_rad - closed_rad)
    short = toward_open > thresholds.gripper_margin_rad
    pushing = math.isnan(current_a) or abs(current_a) >= thresholds.gripper_current_a
    return short and pushing


@dataclass(frozen=True)
class CarryVerdict:
    """The object is not carried."""

    outcome: Outcome
    """``grasp_failed``, ``payload_lost`` (or ``beyond_authority``, from
    :mod:`companion.mission.authority`)."""
    detail: str
    """What showed it, one line."""


@dataclass
class CarryWatch:
    """The carry's two witnesses over one pickup; see the module docstring.

    Parameters
    ----------
    thresholds
        Margins of the gripper and the estimate.
    empty_m2_kg
        Mass of the empty link 2 (the nominal theta's m2) [kg].
    """

    thresholds: CarryThresholds
    empty_m2_kg: float
    seen: bool = False
    """The gripper (or a confident estimate) showed the object in the jaws."""
    _empty_readings: int = 0

    def grasp(self, holds: bool | None) -> CarryVerdict | None:
        """At the end of the grasp, the gripper's last reading (``None``: not readable):
        a gripper closed on nothing is ``grasp_failed``."""
        if holds is None:
            return None
        if not holds:
            return CarryVerdict(
                Outcome.GRASP_FAILED,
                "the gripper closed on nothing (servo at its closed position, no current)",
            )
        self.seen = True
        return None

    def gripper(self, holds: bool) -> CarryVerdict | None:
        """A new gripper reading in the carry: :data:`EMPTY_READINGS` in a row at the
        closed position lose the object."""
        if holds:
            self.seen = True
            self._empty_readings = 0
            return None
        self._empty_readings += 1
        if self._empty_readings < EMPTY_READINGS:
            return None
        if self.seen:
            return CarryVerdict(
                Outcome.PAYLOAD_LOST,
                "the object slipped out of the gripper (held before; the servo is now at its "
                f"closed position with no current, {EMPTY_READINGS} readings in a row)",
            )
        return CarryVerdict(
            Outcome.GRASP_FAILED,
            "the grasp did not take: the gripper never held the object (servo at its closed "
            "position, no current)",
        )

    def estimate(self, m2_kg: float, confident: bool) -> CarryVerdict | None:
        """The estimate in the carry: a confident m2 [kg] within ``mass_margin_kg`` of the
        empty link 2 carries nothing."""
        if not confident:
            return None
        floor = self.empty_m2_kg + self.thresholds.mass_margin_kg
        if m2_kg >= floor:
            self.seen = True
            return None
        what = "the object was lost" if self.seen else "the grasp did not take"
        return CarryVerdict(
            Outcome.PAYLOAD_LOST if self.seen else Outcome.GRASP_FAILED,
            f"{what}: the confident estimate m2 = {m2_kg:.3f} kg is below the empty link 2 "
            f"({self.empty_m2_kg:.3f} kg) + {self.thresholds.mass_margin_kg:g} kg",
        )

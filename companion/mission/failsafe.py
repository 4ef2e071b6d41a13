"""Faults the flight application watches for, and the reaction to each (pure, no clock).

``link_lost``
    No vehicle heartbeat or telemetry for the link's timeout. Freeze the estimate and
    abort: when the link returns, ask PX4 to land (PX4 itself has already failsafed on the
    lost OFFBOARD stream).
``servo_bus``
    The arm bus failed (timeouts past its retries). Freeze the estimate; the bus is in its
    safe state (joints limp, gripper holding); abort: PX4 lands.
``estimate_bound``
    The estimate sits on a bound of its projection for ``bound_hold_s``. Freeze the
    estimate and fly on with it.
``saturation``
    Tilt or thrust saturated for ``saturation_hold_s`` without a break. Abort: PX4 holds
    position (AUTO.LOITER), then lands.
``loop_overrun``
    Three control periods within 1 s of vehicle time each longer than the longest period
    the velocity gains tolerate (:mod:`companion.mission.loop_period`): the onboard computer (or
    the pose stream) cannot keep the rate. Abort: PX4 holds position, then lands. (Single
    late cycles only pause the estimator.)
``link_latency``
    The link's round trip (a pose down, a TIMESYNC request up; :mod:`companion.mission.round_trip`)
    over ``flight.max_round_trip_s`` in three replies in a row: the position loop flies on
    old poses and PX4 flies old setpoints. Freeze the estimate and abort: PX4 holds position
    on its own estimate (AUTO.LOITER), then lands; the commands arrive late, but arrive.
``offboard_lost``
    PX4 left OFFBOARD while the mission flew in it (pilot, PX4 failsafe). Abort: leave the
    vehicle to PX4 and the pilot; never re-enter OFFBOARD.
``navigation``
    PX4's estimate stays invalid for ``flight.nav_invalid_hold_s`` (its variances past
    the limits, or no valid velocity; :mod:`companion.mission.navigation`): the position loop
    flies blind. Freeze the estimate and abort: PX4 lands (AUTO.LAND descends without a
    position estimate).
``ground_contact``
    In OFFBOARD, PX4's land detector says landed or the estimated height fell to the
    take-off height (a navigation drift near the ground): no tilt and no control on the
    ground. Freeze the estimate and abort: level attitude at the thrust floor until PX4
    acknowledges the landing, and PX4 disarms.

An abort ends the mission; the app reports it in the summary and the log and exits 1
(the reactions are carried out by :mod:`companion.mission.sequence`).

The object not carried (:mod:`companion.mission.carry_check`) ends the pickup, not the flight
(:data:`CARRY_REACTIONS`, carried out by :meth:`~companion.mission.pickup.PickupMission.abandon`):

``grasp_failed``
    The gripper closed on nothing at the end of the grasp (or the object was never seen
    in the jaws through the carry). Open the gripper (whatever it touches is let go), the
    estimate back at the empty arm and held, climb to cruise altitude, fly home, land.
``payload_lost``
    The object left the gripper between the lift and the place point. The same, with the
    gripper left as it is.
``beyond_authority``
    From the end of the grasp through the lift's first centimetres, the payload needs more
    hover thrust or servo torque than ``[flight]`` allows (:mod:`companion.mission.authority`).
    As for ``grasp_failed``: the gripper opens where the object was grasped, so it stays
    there (or falls back from at most those centimetres).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

from companion.mission.pickup import LETS_GO, Outcome

__all__ = ["CARRY_REACTIONS", "REACTIONS", "FailsafeMonitor", "Fault", "FaultEvent", "Reaction"]


class Fault(StrEnum):
    """What went wrong."""

    LINK_LOST = "link_lost"
    SERVO_BUS = "servo_bus"
    ESTIMATE_BOUND = "estimate_bound"
    SATURATION = "saturation"
    LOOP_OVERRUN = "loop_overrun"
    LINK_LATENCY = "link_latency"
    OFFBOARD_LOST = "offboard_lost"
    NAVIGATION = "navigation"
    GROUND_CONTACT = "ground_contact"


class Reaction(StrEnum):
    """What the application does about it."""

    FREEZE_ESTIMATE = "freeze_estimate"
    LAND = "land"
    HOLD_THEN_LAND = "hold_then_land"
    RELEASE_TO_PX4 = "release_to_px4"
    LEVEL_ON_GROUND = "level_on_ground"
    """The way out is level at the thrust floor, not hover thrust (the vehicle is down)."""
    OPEN_GRIPPER = "open_gripper"
    RESET_ESTIMATE = "reset_estimate"
    """Back to the empty arm's values, held."""
    RETURN_HOME = "return_home"
    """Climb to cruise altitude where the vehicle is, fly home (the pickup ends)."""


REACTIONS: dict[Fault, tuple[Reaction, ...]] = {
    Fault.LINK_LOST: (Reaction.FREEZE_ESTIMATE, Reaction.LAND),
    Fault.SERVO_BUS: (Reaction.FREEZE_ESTIMATE, Reaction.LAND),
    Fault.ESTIMATE_BOUND: (Reaction.FREEZE_ESTIMATE,),
    Fault.SATURATION: (Reaction.FREEZE_ESTIMATE, Reaction.HOLD_THEN_LAND),
    Fault.LOOP_OVERRUN: (Reaction.FREEZE_ESTIMATE, Reaction.HOLD_THEN_LAND),
    Fault.LINK_LATENCY: (Reaction.FREEZE_ESTIMATE, Reaction.HOLD_THEN_LAND),
    Fault.OFFBOARD_LOST: (Reaction.FREEZE_ESTIMATE, Reaction.RELEASE_TO_PX4),
    Fault.NAVIGATION: (Reaction.FREEZE_ESTIMATE, Reaction.LAND),
    Fault.GROUND_CONTACT: (Reaction.FREEZE_ESTIMATE, Reaction.LEVEL_ON_GROUND, Reaction.LAND),
}
"""The reactions of each fault, in the order they are carried out."""
CARRY_REACTIONS: dict[Outcome, tuple[Reaction, ...]] = {
    outcome: ((Reaction.OPEN_GRIPPER,) if outcome in LETS_GO else ())
    + (Reaction.RESET_ESTIMATE, Reaction.RETURN_HOME, Reaction.LAND)
    for outcome in (Outcome.GRASP_FAILED, Outcome.PAYLOAD_LOST, Outcome.BEYOND_AUTHORITY)
}
"""What the object not carried does (the module docstring), by the mission's outcome: the
gripper opened for the outcomes the mission lets go on
(:data:`~companion.mission.pickup.LETS_GO`)."""


@dataclass(frozen=True)
class FaultEvent:
    """A fault raised at vehicle time ``t_s`` [s]."""

    t_s: float
    fault: Fault
    detail: str
    reactions: tuple[Reaction, ...]

    @property
    def aborts(self) -> bool:
        """Whether the mission ends."""
        return any(r != Reaction.FREEZE_ESTIMATE for r in self.reactions)


@dataclass
class FailsafeMonitor:
    """Raises each fault once, when its condition has held long enough.

    Parameters
    ----------
    bound_hold_s
        Time the estimate may sit on a bound before ``estimate_bound`` [s].
    saturation_hold_s
        Time tilt or thrust may stay saturated before ``saturation`` [s].
    """

    bound_hold_s: float = 1.0
    saturation_hold_s: float = 2.0
    raised: list[FaultEvent] = field(default_factory=list)
    _bound_since: float = math.nan
    _saturated_since: float = math.nan

    def __post_init__(self) -> None:
        if not (self.bound_hold_s > 0.0 and self.saturation_hold_s > 0.0):
            raise ValueError("hold times must be positive")

    def has(self, fault: Fault) -> bool:
        """Whether ``fault`` was raised."""
        return any(event.fault == fault for event in self.raised)

    @property
    def aborted(self) -> bool:
        """Whether a raised fault ends the mission."""
        return any(event.aborts for event in self.raised)

    def raise_fault(self, t_s: float, fault: Fault, detail: str) -> FaultEvent | None:
        """Raise ``fault`` now (once; later calls return None)."""
        if self.has(fault):
            return None
        event = FaultEvent(t_s, fault, detail, REACTIONS[fault])
        self.raised.append(event)
        return event

    def update(
        self,
        t_s: float,
        *,
        on_bound: bool,
        tilt_saturated: bool,
        thrust_saturated: bool,
    ) -> list[FaultEvent]:
        """Check the conditions that must last at vehicle time ``t_s`` [s]; new events."""
        events = []
        self._bound_since = _since(self._bound_since, on_bound, t_s)
        if t_s - self._bound_since >= self.bound_hold_s:
            event = self.raise_fault(
                t_s, Fault.ESTIMATE_BOUND, f"estimate on its bound for {self.bound_hold_s:g} s"
            )
            events += [event] if event else []
        saturated = tilt_saturated or thrust_saturated
        self._saturated_since = _since(self._saturated_since, saturated, t_s)
        if t_s - self._saturated_since >= self.saturation_hold_s:
            what = "tilt" if tilt_saturated else "thrust"
            event = self.raise_fault(
                t_s, Fault.SATURATION, f"{what} saturated for {self.saturation_hold_s:g} s"
            )
            events += [event] if event else []
        return events


def _since(since: float, active: bool, t_s: float) -> float:
    if not active:
        return math.nan
    return t_s if math.isnan(since) else since

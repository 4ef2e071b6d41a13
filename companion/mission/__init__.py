"""The pickup mission: what the companion does from the ground back to the ground.

Pure parts (no I/O, no clock; vehicle time):

- :mod:`~companion.mission.pickup`: the pickup's phases and desired states (:class:`PickupMission`);
- :mod:`~companion.mission.sequence`: the flight around it: arming, take-off, the OFFBOARD
  handover, landing, each aborting fault's reactions (:class:`FlightSequence`);
- :mod:`~companion.mission.failsafe`: the faults and their reactions, in one table;
- :mod:`~companion.mission.carry_check`: whether the object is carried;
- :mod:`~companion.mission.offboard`: what is streamed to PX4;
- :mod:`~companion.mission.vehicle_params`: PX4's parameters against the config;
- :mod:`~companion.mission.navigation`, :mod:`~companion.mission.loop_period`: watches of
  PX4's estimate and of the loop's period;
- :mod:`~companion.mission.report`: the report and the flight figures.

The shell over the links (asyncio): :mod:`~companion.mission.app` (:class:`PickupApp`),
:mod:`~companion.mission.cycle` (one control cycle), :mod:`~companion.mission.preflight`
(what is asked of PX4 before arming), :mod:`~companion.mission.arm_supervisor` (the servo
bus task), :mod:`~companion.mission.scheduling` (real-time scheduling of the loop).
"""

from typing import TYPE_CHECKING

from companion.lazy import lazy_attributes

__all__ = [
    "Fault",
    "FlightSequence",
    "MissionAborted",
    "MissionError",
    "MissionReport",
    "Outcome",
    "Phase",
    "PickupApp",
    "PickupMission",
    "PickupPlan",
    "Reaction",
]

_HOME = {
    "MissionAborted": "companion.mission.app",
    "MissionError": "companion.mission.app",
    "PickupApp": "companion.mission.app",
    "Fault": "companion.mission.failsafe",
    "Reaction": "companion.mission.failsafe",
    "Outcome": "companion.mission.pickup",
    "Phase": "companion.mission.pickup",
    "PickupMission": "companion.mission.pickup",
    "PickupPlan": "companion.mission.pickup",
    "MissionReport": "companion.mission.report",
    "FlightSequence": "companion.mission.sequence",
}
"""Where each public name lives (:mod:`companion.lazy`)."""

if TYPE_CHECKING:
    from companion.mission.app import MissionAborted, MissionError, PickupApp
    from companion.mission.failsafe import Fault, Reaction
    from companion.mission.pickup import Outcome, Phase, PickupMission, PickupPlan
    from companion.mission.report import MissionReport
    from companion.mission.sequence import FlightSequence

__getattr__ = lazy_attributes(__name__, _HOME)

"""Truth physics of the SITL vehicle: hexacopter + 2-DOF arm + payload.

Independent of :mod:`companion.model` by design (DESIGN.md section 6): model errors there
must show up against this plant, not be copied into it. Entry point::

    from sitl.physics import TruthPlant, AttitudeSetpoint
    plant = TruthPlant.from_scenario(scenario, mode="ideal", payload_attached=True)
    state = plant.step_ideal(tau)                      # tau conjugate to q (8,)

    plant = TruthPlant.from_scenario(scenario, mode="underactuated")
    state = plant.step(AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, 0.45), [0.0, 0.0])

Both backends are a :class:`Plant` (underactuated); the Pinocchio one is also an
:class:`IdealPlant` (:mod:`~sitl.physics.protocols`).

Modules: :mod:`~sitl.physics.plant` (integration, modes, payload),
:mod:`~sitl.physics.articulation` (the Pinocchio model), :mod:`~sitl.physics.rotors`
(thrust curve, motor lag, mixer), :mod:`~sitl.physics.attitude_control` (PX4-like loops),
:mod:`~sitl.physics.frames` (quaternion / Euler conversions).
"""

from sitl.physics.attitude_control import AttitudeSetpoint
from sitl.physics.backends import PHYSICS_BACKENDS, BackendError, PhysicsBackend, make_plant
from sitl.physics.errors import (
    EulerSingularityError,
    PlantDivergedError,
    PlantError,
    PlantModeError,
)
from sitl.physics.plant import PlantMode, TruthPlant
from sitl.physics.protocols import IdealPlant, Plant, PlantCore
from sitl.physics.state import ActuatorState, PlantState

__all__ = [
    "PHYSICS_BACKENDS",
    "ActuatorState",
    "AttitudeSetpoint",
    "BackendError",
    "EulerSingularityError",
    "IdealPlant",
    "PhysicsBackend",
    "Plant",
    "PlantCore",
    "PlantDivergedError",
    "PlantError",
    "PlantMode",
    "PlantModeError",
    "PlantState",
    "TruthPlant",
    "make_plant",
]

"""Choose the physics backend of the truth plant: Pinocchio (ours) or JSBSim.

Both plants are a :class:`~sitl.physics.protocols.Plant` in underactuated mode
(``reset``, ``step``, ``state``, ``time_s``, ``actuators``, payload handling,
``true_theta``, ``total_mass_kg``, ``rate_hz``, ``dt_s``), so the offline simulator and
the SITL vehicle take either::

    plant = make_plant(scenario, "jsbsim", "underactuated", payload_attached=True,
                       wind=Wind((3.0, 0.0, 0.0), "milspec", 7.7))

``ideal`` mode (a generalized force on all 8 coordinates) exists only on Pinocchio, and
wind only on JSBSim (the Pinocchio plant has no atmosphere); asking for either elsewhere
raises :class:`BackendError`. The JSBSim backend is imported only when asked for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal, overload

from sitl.physics.errors import PlantModeError
from sitl.physics.plant import PlantMode, TruthPlant
from sitl.physics.protocols import IdealPlant, Plant
from sitl.scenario import Scenario

if TYPE_CHECKING:
    from sitl.physics.jsbsim import Wind

__all__ = ["PHYSICS_BACKENDS", "BackendError", "PhysicsBackend", "make_plant"]

PhysicsBackend = Literal["pinocchio", "jsbsim"]
PHYSICS_BACKENDS: tuple[PhysicsBackend, ...] = ("pinocchio", "jsbsim")


class BackendError(PlantModeError, ValueError):
    """The backend cannot build this plant (unknown backend, mode or option it lacks)."""


@overload
def make_plant(
    scenario: Scenario,
    physics: PhysicsBackend,
    mode: Literal["ideal"],
    *,
    payload_attached: bool = False,
    wind: Wind | None = None,
) -> IdealPlant: ...
@overload
def make_plant(
    scenario: Scenario,
    physics: PhysicsBackend = "pinocchio",
    mode: Literal["underactuated"] = "underactuated",
    *,
    payload_attached: bool = False,
    wind: Wind | None = None,
) -> Plant: ...
@overload
def make_plant(
    scenario: Scenario,
    physics: PhysicsBackend = "pinocchio",
    mode: PlantMode = "underactuated",
    *,
    payload_attached: bool = False,
    wind: Wind | None = None,
) -> Plant | IdealPlant: ...
def make_plant(
    scenario: Scenario,
    physics: PhysicsBackend = "pinocchio",
    mode: PlantMode = "underactuated",
    *,
    payload_attached: bool = False,
    wind: Wind | None = None,
) -> Plant | IdealPlant:
    """The truth plant of ``scenario`` on the chosen backend, at rest at ``initial_q``:
    an :class:`IdealPlant` in ideal mode (Pinocchio only), a :class:`Plant` otherwise.

    Parameters
    ----------
    scenario : Scenario
        Validated scenario.
    physics : {"pinocchio", "jsbsim"}
        Backend.
    mode : {"ideal", "underactuated"}
        Plant input; ``ideal`` needs ``physics="pinocchio"``.
    payload_attached : bool
        Start with the payload grasped.
    wind : sitl.physics.jsbsim.Wind, optional
        Steady wind and turbulence, in place of the scenario's steady ``plant.wind_m_s``;
        turbulence needs ``physics="jsbsim"``.

    Raises
    ------
    BackendError
        Unknown backend or mode, ideal mode on JSBSim, or turbulence on Pinocchio.
    """
    if physics not in PHYSICS_BACKENDS:
        raise BackendError(f"physics must be one of {PHYSICS_BACKENDS}, got {physics!r}")
    if mode not in ("ideal", "underactuated"):
        raise BackendError(f"mode must be 'ideal' or 'underactuated', got {mode!r}")
    steady = scenario.plant.wind_m_s if wind is None else wind.velocity_enu_m_s
    if mode == "ideal" and any(steady):
        raise BackendError(
            "wind needs mode='underactuated': the ideal plant (tau on all 8 rows) has no drag "
            "for the wind to act through"
        )
    if physics == "pinocchio":
        if wind is not None and wind.turbulence != "none":
            raise BackendError(
                "turbulence needs physics='jsbsim': the Pinocchio plant's drag acts on the "
                "steady wind only"
            )
        return TruthPlant.from_scenario(
            scenario,
            mode,
            payload_attached=payload_attached,
            wind_m_s=None if wind is None else wind.velocity_enu_m_s,
        )
    if mode == "ideal":
        raise BackendError(
            "ideal mode (tau on all 8 rows) exists only with physics='pinocchio': JSBSim "
            "flies the vehicle through its rotors and attitude loop (mode='underactuated')"
        )
    from sitl.physics.jsbsim import JsbsimPlant

    return JsbsimPlant.from_scenario(scenario, payload_attached=payload_attached, wind=wind)

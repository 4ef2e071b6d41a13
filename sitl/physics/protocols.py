"""What the simulators require of a truth plant: typed protocols both backends satisfy.

Two inputs, two protocols over one common part (:class:`PlantCore`: state, time, reset,
payload, truth):

:class:`Plant`
    The vehicle as flown: an attitude/thrust setpoint to the PX4-like loop and servo
    torques (:meth:`Plant.step`). :class:`~sitl.physics.TruthPlant` in ``underactuated``
    mode and :class:`~sitl.physics.jsbsim.JsbsimPlant`. The SITL vehicle and the offline
    simulator's underactuated runs use this.
:class:`IdealPlant`
    The paper's simulation: a generalized force on all 8 coordinates
    (:meth:`IdealPlant.step_ideal`). Only :class:`~sitl.physics.TruthPlant` (``ideal``
    mode); JSBSim has no such input.

:func:`~sitl.physics.make_plant` returns an :class:`IdealPlant` for ``mode="ideal"`` and a
:class:`Plant` otherwise. ``TruthPlant`` is one class for both modes, so it satisfies
both protocols; which input it takes is its ``mode``, checked when it steps
(:class:`~sitl.physics.PlantModeError`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy as np
    from numpy.typing import ArrayLike, NDArray

    from companion.config import Theta
    from sitl.physics.attitude_control import AttitudeLoopParams, AttitudeSetpoint
    from sitl.physics.battery import BatteryReading
    from sitl.physics.state import ActuatorState, PlantState
    from sitl.scenario import Scenario

__all__ = ["IdealPlant", "Plant", "PlantCore"]


class PlantCore(Protocol):
    """What every truth plant has, whatever its input: one fixed step of ``dt_s``, the
    truth state, and the payload on link 2."""

    @property
    def scenario(self) -> Scenario:
        """The validated scenario the plant was built from."""
        ...

    @property
    def rate_hz(self) -> float:
        """Integration rate ``plant.rate_hz`` [Hz]."""
        ...

    @property
    def dt_s(self) -> float:
        """One step, 1 / ``rate_hz`` [s]."""
        ...

    @property
    def time_s(self) -> float:
        """Simulation time [s]."""
        ...

    @property
    def state(self) -> PlantState:
        """The truth state now (q, q_dot, q_ddot, attitude, body rates)."""
        ...

    def reset(
        self,
        q: ArrayLike,
        q_dot: ArrayLike | None = None,
        *,
        time_s: float = 0.0,
        rotor_thrusts_n: ArrayLike | None = None,
    ) -> PlantState:
        """Put the plant in state (q, q_dot), shape (8,) each, at ``time_s`` [s]."""
        ...

    @property
    def payload_attached(self) -> bool:
        """Whether link 2 carries the payload."""
        ...

    def attach_payload(self, share: float = 1.0) -> None:
        """Grasp the payload, link 2 carrying ``share`` of it and the ground the rest
        (raises :class:`~sitl.physics.PlantError` if attached)."""
        ...

    def set_payload_share(self, share: float) -> None:
        """The share (0-1) of the grasped payload link 2 carries, the ground the rest."""
        ...

    def detach_payload(self) -> None:
        """Release the payload (raises :class:`~sitl.physics.PlantError` if none)."""
        ...

    @property
    def true_theta(self) -> Theta:
        """(m2, m3, m4) of link 2 as it is now: truth, never shown to the companion."""
        ...

    @property
    def total_mass_kg(self) -> float:
        """Vehicle + arm (+ payload) [kg]."""
        ...


class Plant(PlantCore, Protocol):
    """The vehicle as flown: PX4-like attitude loop, lagged rotors, servo torques."""

    @property
    def has_ground(self) -> bool:
        """True if the plant has its own ground contact (JSBSim's gear); False if it flies
        in free space and a SITL adds the ground."""
        ...

    def step(self, setpoint: AttitudeSetpoint, joint_torques_n_m: ArrayLike) -> PlantState:
        """Advance one step under an attitude/thrust setpoint and two servo torques [N m]."""
        ...

    def advance(self, setpoint: AttitudeSetpoint, joint_torques_n_m: ArrayLike) -> None:
        """:meth:`step` without building the new state (read :attr:`state` when needed)."""
        ...

    @property
    def coordinates(self) -> tuple[Sequence[float], Sequence[float]]:
        """q and q_dot now (8 each), read without building the state."""
        ...

    @property
    def actuators(self) -> ActuatorState:
        """Motor commands, rotor thrusts and joint torques of the last step."""
        ...

    @property
    def rotor_thrusts_n(self) -> NDArray[np.float64]:
        """Thrust of each rotor now [N], shape (6,)."""
        ...

    @property
    def battery(self) -> BatteryReading | None:
        """The battery's voltage, current and charge now; None for an ideal supply."""
        ...

    @property
    def thrust_per_command(self) -> float:
        """The true thrust scale now: thrust per command over the believed rotors' [-]."""
        ...

    def configure_autopilot(self, params: AttitudeLoopParams) -> None:
        """New parameters for the PX4-like attitude loop, as a PARAM_SET on PX4."""
        ...


class IdealPlant(PlantCore, Protocol):
    """The paper's simulation: a generalized force tau acts on all 8 coordinates."""

    def step_ideal(self, tau: ArrayLike) -> PlantState:
        """Advance one step under tau, shape (8,), conjugate to q [N, N m]."""
        ...

    def acceleration(self, tau: ArrayLike) -> NDArray[np.float64]:
        """q_ddot at the current state under tau (rigid-body dynamics only); no step."""
        ...

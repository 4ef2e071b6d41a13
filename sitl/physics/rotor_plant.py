"""What the two truth plants share: the clock, the truth state, six lagging rotors driven by
the PX4-like attitude loop or by an outside autopilot's motor commands, and the arm's joint
torques clipped to the servos.

:class:`~sitl.physics.plant.TruthPlant` (our rigid-body integrator, Pinocchio) and
:class:`~sitl.physics.jsbsim.plant.JsbsimPlant` (JSBSim) differ in how one step moves the
bodies (:meth:`RotorPlant._step_rotors`) and in where they keep the state
(:meth:`RotorPlant._truth`); the rest is here, once. Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sitl.physics.attitude_control import AttitudeLoopParams, AttitudeSetpoint, Px4AttitudeLoop
from sitl.physics.battery import BatteryReading, LipoPack
from sitl.physics.errors import PlantModeError
from sitl.physics.rotors import N_ROTORS, RotorBank
from sitl.physics.state import ActuatorState, PlantState

__all__ = ["RotorPlant"]

FloatArray = NDArray[np.float64]
_UNKNOWN3 = (math.nan, math.nan, math.nan)
"""Signals of an autopilot outside the plant (rate setpoint, normalized torques)."""


class RotorPlant:
    """Base of the rotor-driven truth plants (module docstring). A subclass sets ``dt_s``,
    ``_t0``, ``_steps``, ``_rotors``, ``_autopilot``, ``_servo_limit`` and the caches, and
    implements :meth:`_truth`, :meth:`_attitude` and :meth:`_step_rotors`."""

    dt_s: float
    _t0: float
    _steps: int
    _rotors: RotorBank
    _max_thrust_n: float
    _thrust_mismatch: float
    """A rotor's full thrust at the battery's reference voltage [N]."""
    _battery: LipoPack | None
    """The battery feeding the rotors, or None (an ideal supply)."""
    _autopilot: Px4AttitudeLoop
    _servo_limit: float
    _state_cache: PlantState | None
    _actuators: ActuatorState | None
    _actuator_signals: tuple | None
    """The actuator signals of the last step (None: kept where :meth:`_signals` reads them)."""

    @property
    def flies_rotors(self) -> bool:
        """Whether the rotors move the vehicle (not the paper's ideal generalized force)."""
        return True

    def _need_rotors(self, message: str) -> None:
        if not self.flies_rotors:
            raise PlantModeError(message)

    def _truth(self) -> tuple:
        """(q, q_dot, q_ddot, quaternion, R row-major 9, omega body, payload attached) now."""
        raise NotImplementedError

    def _signals(self) -> tuple:
        """(motor commands, rotor thrusts [N], joint torques [N m], rate setpoint [rad/s],
        normalized torques) of the last step."""
        assert self._actuator_signals is not None
        return self._actuator_signals

    def _attitude(
        self,
    ) -> tuple[tuple[float, float, float, float], tuple[float, float, float]]:
        """(attitude quaternion [w, x, y, z] (ENU/FLU), body rate (FLU) [rad/s]) now."""
        raise NotImplementedError

    def _step_rotors(
        self,
        motor_commands: list[float],
        joint: list[float],
        rate_setpoint_rad_s: tuple,
        torque_normalized: tuple,
    ) -> None:
        """One step pushed by the rotors' thrusts, which then move toward ``motor_commands``
        through their lag; records the actuator signals."""
        raise NotImplementedError

    def _feed_rotors(self) -> None:
        """Draw the battery for the thrusts acting over this step, and set the thrust the
        next commands make at its voltage (truth only)."""
        battery = self._battery
        if battery is not None:
            battery.draw(self._rotors.thrust_list_n, self.dt_s)
            self._rotors.max_thrust_n = self._max_thrust_n * battery.thrust_factor

    @property
    def battery(self) -> BatteryReading | None:
        """The battery's voltage, current and charge now, or None for an ideal supply."""
        return None if self._battery is None else self._battery.reading()

    @property
    def thrust_per_command(self) -> float:
        """The thrust a motor command makes now over what the believed rotors make (the
        true thrust scale: ``plant.thrust_mismatch`` times the battery's factor) [-]."""
        battery = self._battery
        return self._thrust_mismatch * (1.0 if battery is None else battery.thrust_factor)

    # ------------------------------------------------------------------ state

    @property
    def time_s(self) -> float:
        """Simulation time [s] (``reset`` time + steps * dt, no accumulated rounding)."""
        return self._t0 + self._steps * self.dt_s

    @property
    def state(self) -> PlantState:
        """The current truth state (frozen; built once per step, on first access)."""
        if self._state_cache is None:
            self._state_cache = PlantState.from_lists(self.time_s, *self._truth())
        return self._state_cache

    @property
    def coordinates(self) -> tuple[Sequence[float], Sequence[float]]:
        """q and q_dot now (8 each, the order of :attr:`PlantState.q`): the floats the
        state is made of, read without building it (for a host that needs a few of them
        every step)."""
        truth = self._truth()
        return truth[0], truth[1]

    @property
    def actuators(self) -> ActuatorState:
        """Actuator signals of the last step.

        Raises
        ------
        PlantModeError
            In the ideal mode, which has no actuators.
        """
        self._need_rotors("actuator signals exist only in underactuated mode")
        if self._actuators is None:
            self._actuators = ActuatorState.from_signals(self._signals())
        return self._actuators

    def configure_autopilot(self, params: AttitudeLoopParams) -> None:
        """Give the PX4-like attitude loop new parameters (gains, THR_MDL_FAC) at once, as a
        PARAM_SET does on PX4; its integrators carry on. The motors keep their own curve.

        Raises
        ------
        PlantModeError
            In the ideal mode, which has no autopilot.
        """
        self._need_rotors("the autopilot exists only in underactuated mode")
        self._autopilot.configure(params)

    @property
    def rotor_thrusts_n(self) -> FloatArray:
        """Thrust each rotor produces now [N], shape (6,) (zeros in the ideal mode)."""
        return self._rotors.thrusts_n if self.flies_rotors else np.zeros(N_ROTORS)

    @property
    def total_thrust_n(self) -> float:
        """Sum of :attr:`rotor_thrusts_n` [N] (0 in the ideal mode)."""
        return self._rotors.total_thrust_n if self.flies_rotors else 0.0

    # ------------------------------------------------------------------- step

    def step(self, setpoint: AttitudeSetpoint, joint_torques_n_m: ArrayLike) -> PlantState:
        """Advance one step under an attitude/thrust setpoint and joint torques.

        Parameters
        ----------
        setpoint : AttitudeSetpoint
            Attitude (ENU/FLU quaternion) and relative collective thrust for the PX4-like
            loop.
        joint_torques_n_m : array_like, shape (2,)
            Servo torque commands [N m], clipped to +-``plant.servo_torque_limit_n_m``.

        The autopilot runs once per step on the true attitude and body rate; the rotors
        push with the thrust their lag state has at the start of the step, which then
        moves toward the new commands.

        Raises
        ------
        PlantModeError
            In the ideal mode.
        ValueError
            On joint torques that are not 2 finite values.
        EulerSingularityError
            If the vehicle reaches theta = +-90 deg (q cannot be reported).
        PlantDivergedError
            If the state became non-finite.
        """
        self.advance(setpoint, joint_torques_n_m)
        return self.state

    def advance(self, setpoint: AttitudeSetpoint, joint_torques_n_m: ArrayLike) -> None:
        """:meth:`step` without building the new state (read :attr:`state` when needed);
        the same errors."""
        self._need_rotors("step() needs mode='underactuated'; use step_ideal() instead")
        joint = self._joint_torques(joint_torques_n_m)
        quaternion, omega = self._attitude()
        commands, rate_sp, torque = self._autopilot.commands(quaternion, omega, setpoint)
        self._step_rotors(commands, joint, rate_sp, torque)

    def step_motors(self, motor_commands: ArrayLike, joint_torques_n_m: ArrayLike) -> PlantState:
        """Advance one step under six motor commands and joint torques, for an autopilot
        outside the plant (the real PX4 through ``simulator_mavlink``).

        Parameters
        ----------
        motor_commands : array_like, shape (6,)
            Normalized command of each rotor (order of :mod:`sitl.physics.rotors`), clipped
            to [0, 1]; the motors answer with their own thrust curve and lag.
        joint_torques_n_m : array_like, shape (2,)
            As for :meth:`step`.

        The plant's own attitude loop does not run: the actuator signals' rate setpoint and
        normalized torques are NaN (the outside autopilot's).

        Raises
        ------
        PlantModeError
            In the ideal mode.
        ValueError
            On commands that are not 6 finite values or joint torques not 2.
        EulerSingularityError, PlantDivergedError
            As for :meth:`step`.
        """
        self.advance_motors(motor_commands, joint_torques_n_m)
        return self.state

    def advance_motors(self, motor_commands: ArrayLike, joint_torques_n_m: ArrayLike) -> None:
        """:meth:`step_motors` without building the new state (read :attr:`state` when
        needed); the same errors."""
        self._need_rotors("step_motors() needs mode='underactuated'")
        arr = np.asarray(motor_commands, dtype=np.float64)
        if arr.shape != (N_ROTORS,) or not np.all(np.isfinite(arr)):
            raise ValueError(
                f"motor_commands must be {N_ROTORS} finite values, got {motor_commands!r}"
            )
        joint = self._joint_torques(joint_torques_n_m)
        self._step_rotors(np.clip(arr, 0.0, 1.0).tolist(), joint, _UNKNOWN3, _UNKNOWN3)

    def _joint_torques(self, joint_torques_n_m: ArrayLike) -> list[float]:
        """Two finite joint torques [N m] clipped to the servo limit (ValueError otherwise);
        a list or tuple of two is read without numpy (the per-step path)."""
        if isinstance(joint_torques_n_m, (list, tuple)) and len(joint_torques_n_m) == 2:
            j1, j2 = float(joint_torques_n_m[0]), float(joint_torques_n_m[1])
        else:
            joint_arr = np.asarray(joint_torques_n_m, dtype=np.float64)
            if joint_arr.shape != (2,):
                raise ValueError(
                    f"joint_torques_n_m must be 2 finite values, got {joint_torques_n_m!r}"
                )
            j1, j2 = joint_arr.tolist()
        if not math.isfinite(j1 + j2):
            raise ValueError(
                f"joint_torques_n_m must be 2 finite values, got {joint_torques_n_m!r}"
            )
        lim = self._servo_limit
        return [min(max(j1, -lim), lim), min(max(j2, -lim), lim)]

"""A pure model of a DroneCAN servo actuator: force and position commands, arming, faults.

No I/O and no clock: :class:`CanActuator` takes decoded commands
(:meth:`~CanActuator.command`), advances its loops by a time step the caller gives
(:meth:`~CanActuator.step`) and reports what an ``actuator.Status`` carries
(:meth:`~CanActuator.status`). :mod:`sitl.servo.dronecan_node` puts actuators on a CAN
bus; the SITL couples each to a physics joint through
:class:`~sitl.servo.xm430.ServoJoint` (shaft angle and rate in, torque out).

What is modelled (semantics of ``uavcan.equipment.actuator.Command`` and
``safety.ArmingStatus``; the numbers are an XM430-W350-class servo's, as
:mod:`sitl.servo.xm430`):

- COMMAND_TYPE_FORCE [N m]: the goal torque, clamped to +-``max_torque_n_m``;
- COMMAND_TYPE_POSITION [rad]: a PD law ``tau = kp (goal - angle) - kd rate``, clamped;
- other command types (unitless, speed, PWM) are not supported: ignored and counted;
- the output follows the goal torque through a first-order lag
  (``torque_time_constant_s``); disarmed, the output is zero (limp) and commands are
  remembered but not applied;
- command timeout: in force mode, no command for ``command_timeout_s`` sets the goal
  torque to 0 (a companion that died must not leave a torque applied); position goals
  are held;
- overload: a goal at or above ``overload_fraction`` x ``max_torque_n_m`` for
  ``overload_time_s`` sets the Overload bit; any hardware error bit turns the output off
  until :meth:`~CanActuator.restart` (``uavcan.protocol.RestartNode``).

Hardware errors use the bits of :class:`arm_driver.errors.HardwareErrorStatus`, which the
emulator reports in ``NodeStatus.vendor_specific_status_code`` (DroneCAN leaves that
code's meaning to the vendor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from arm_driver.errors import HardwareErrorStatus

__all__ = ["CanActuator", "CanActuatorParameters", "CommandType"]


class CommandType:
    """``uavcan.equipment.actuator.Command.command_type`` values (DSDL)."""

    UNITLESS = 0
    POSITION = 1
    FORCE = 2
    SPEED = 3
    PWM = 4


@dataclass(frozen=True)
class CanActuatorParameters:
    """Loop and physical parameters of the model.

    Attributes
    ----------
    max_torque_n_m
        Largest output torque magnitude [N m] (XM430-W350 stall torque at 12 V).
    torque_time_constant_s
        Time constant of the output torque's lag behind the goal [s].
    position_kp_n_m_per_rad
        Position loop proportional gain [N m/rad].
    position_kd_n_m_s_per_rad
        Position loop derivative gain [N m s/rad].
    command_timeout_s
        Time without a command after which a force goal falls to 0 [s].
    overload_fraction
        Fraction of ``max_torque_n_m`` at or above which the goal counts as overload [-].
    overload_time_s
        Sustained overload time before the Overload bit is set [s].
    """

    max_torque_n_m: float = 4.1
    torque_time_constant_s: float = 0.5e-3
    position_kp_n_m_per_rad: float = 17.8
    position_kd_n_m_s_per_rad: float = 0.53
    command_timeout_s: float = 0.5
    overload_fraction: float = 0.95
    overload_time_s: float = 1.0

    def __post_init__(self) -> None:
        for name in (
            "max_torque_n_m",
            "torque_time_constant_s",
            "command_timeout_s",
            "overload_time_s",
        ):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not 0.0 < self.overload_fraction <= 1.0:
            raise ValueError("overload_fraction must be in (0, 1]")


class CanActuator:
    """One simulated DroneCAN servo actuator; implements :class:`~sitl.servo.xm430.ServoJoint`.

    Parameters
    ----------
    actuator_id
        Actuator id, 0-255 (``actuator.Command.actuator_id``).
    parameters
        Loop and physical parameters.
    angle_rad
        Initial shaft angle [rad]; the position goal starts there.
    """

    def __init__(
        self,
        actuator_id: int,
        parameters: CanActuatorParameters | None = None,
        *,
        angle_rad: float = 0.0,
    ) -> None:
        if not 0 <= actuator_id <= 255:
            raise ValueError(f"actuator id {actuator_id} out of range (0-255)")
        self.actuator_id = actuator_id
        self.parameters = parameters if parameters is not None else CanActuatorParameters()
        self.armed = False
        """Outputs enabled by ``safety.ArmingStatus`` STATUS_FULLY_ARMED."""
        self.mode = CommandType.POSITION
        """Type of the last applied command (FORCE or POSITION)."""
        self.goal_torque_n_m = 0.0
        """Last force goal [N m], after clamping and the command timeout."""
        self.goal_position_rad = float(angle_rad)
        """Last position goal [rad]."""
        self.hardware_error = HardwareErrorStatus(0)
        self.unsupported_commands = 0
        """Commands of a type this actuator does not support (ignored)."""
        self._torque_n_m = 0.0
        self._since_command_s = 0.0
        self._overload_s = 0.0
        self.set_state(angle_rad, 0.0)

    # -- commands ---------------------------------------------------------------------

    def command(self, command_type: int, value: float) -> bool:
        """Take one ``actuator.Command``; False if its type is not supported."""
        if command_type == CommandType.FORCE and math.isfinite(value):
            limit = self.parameters.max_torque_n_m
            self.goal_torque_n_m = max(-limit, min(limit, float(value)))
        elif command_type == CommandType.POSITION and math.isfinite(value):
            self.goal_position_rad = float(value)
        else:
            self.unsupported_commands += 1
            return False
        self.mode = command_type
        self._since_command_s = 0.0
        return True

    def inject_hardware_error(self, bits: HardwareErrorStatus) -> None:
        """Set hardware error bits, as a fault would; the output turns off."""
        self.hardware_error |= bits

    def restart(self) -> None:
        """What ``uavcan.protocol.RestartNode`` does: errors cleared, disarmed, goal held."""
        self.hardware_error = HardwareErrorStatus(0)
        self.armed = False
        self.goal_torque_n_m = 0.0
        self.goal_position_rad = self._angle_rad
        self._overload_s = 0.0

    @property
    def output_enabled(self) -> bool:
        """Armed and free of hardware errors: the output drives the joint."""
        return self.armed and not self.hardware_error

    # -- physics (ServoJoint) -----------------------------------------------------------

    def set_state(self, angle_rad: float, rate_rad_s: float) -> None:
        """The shaft's angle [rad] and rate [rad/s], from the physics joint."""
        self._angle_rad = float(angle_rad)
        self._rate_rad_s = float(rate_rad_s)

    def torque_n_m(self) -> float:
        """Torque applied to the joint now [N m], counter-clockwise positive."""
        return self._torque_n_m if self.output_enabled else 0.0

    def couple(self, angle_rad: float, rate_rad_s: float) -> float:
        """:meth:`set_state`, then :meth:`torque_n_m` [N m]."""
        self.set_state(angle_rad, rate_rad_s)
        return self.torque_n_m()

    def commanded_torque_n_m(self) -> float:
        """Torque the active command asks for now [N m], clamped (0 when not enabled)."""
        if not self.output_enabled:
            return 0.0
        p = self.parameters
        if self.mode == CommandType.FORCE:
            goal = self.goal_torque_n_m
        else:
            goal = p.position_kp_n_m_per_rad * (self.goal_position_rad - self._angle_rad)
            goal -= p.position_kd_n_m_s_per_rad * self._rate_rad_s
        return max(-p.max_torque_n_m, min(p.max_torque_n_m, goal))

    def step(self, dt_s: float) -> None:
        """Advance the torque lag, command timeout and overload detector by ``dt_s`` [s]."""
        if not dt_s >= 0.0:
            raise ValueError(f"time step {dt_s} s must be >= 0")
        p = self.parameters
        self._since_command_s += dt_s
        if self.mode == CommandType.FORCE and self._since_command_s >= p.command_timeout_s:
            self.goal_torque_n_m = 0.0
        goal = self.commanded_torque_n_m()
        self._torque_n_m += (goal - self._torque_n_m) * -math.expm1(
            -dt_s / p.torque_time_constant_s
        )
        overloaded = abs(goal) >= p.overload_fraction * p.max_torque_n_m
        self._overload_s = self._overload_s + dt_s if overloaded else 0.0
        if self._overload_s >= p.overload_time_s:
            self.inject_hardware_error(HardwareErrorStatus.OVERLOAD)
        if not self.output_enabled:
            self._torque_n_m = 0.0

    def status(self) -> tuple[float, float, float, int]:
        """(position [rad], force [N m], speed [rad/s], power rating [%]) for a Status."""
        torque = self.torque_n_m()
        load = round(100.0 * abs(torque) / self.parameters.max_torque_n_m)
        return self._angle_rad, torque, self._rate_rad_s, min(100, load)

"""Joint-space configuration and state of the arm, shared by every bus backend.

Frames and units: angles [rad], rates [rad/s], torques [N m], in the *joint* frame,
counter-clockwise positive about the joint axis as the arm's model defines it. A joint's
``direction`` and ``zero_offset_rad`` map it to the servo shaft, whose angle is 0 at the
servo's centre position (:data:`arm_driver.dynamixel.units.POSITION_CENTER_TICKS` for a
Dynamixel).

Joint torque: a measured torque (:attr:`JointState.torque_n_m`) is the torque reaching
the link, the motor's torque less the gearbox friction at the measured rate
(:meth:`JointConfig.link_torque_n_m`): it is what the arm's equations of motion, and the
payload estimator's joint rows, see. A commanded torque is the motor's
(:meth:`JointConfig.servo_current_a`), without friction feed-forward: the friction is
dissipative, so leaving it uncompensated only adds damping to the passivity-based
controller, while compensating it from the measured rate feeds the rate's noise and
quantization (0.024 rad/s per Dynamixel velocity unit; Coulomb friction flips sign with
it) back into the command as negative damping. The XM430's 0.02 N m s/rad is small
beside the controller's own joint damping (k = 0.3-1.4 N m s/rad in the configs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["GripperConfig", "GripperState", "JointConfig", "JointState"]


@dataclass(frozen=True)
class JointConfig:
    """One arm joint and the servo that drives it.

    Attributes
    ----------
    name
        Joint name, the key of every joint-space command and state.
    servo_id
        The servo's id on its bus.
    torque_constant_n_m_per_a
        Calibrated output torque per motor current [N m/A]. For the XM430-W350, the
        datasheet's stall torque over stall current (4.1 N m / 2.3 A = 1.78 N m/A at
        12 V) is an example value, not a calibration.
    torque_max_n_m
        Largest torque magnitude a command may ask for [N m].
    direction
        +1 if a positive joint angle turns the servo counter-clockwise seen from its
        front, -1 if clockwise.
    zero_offset_rad
        Servo shaft angle [rad] (0 at the servo's centre position) where the joint angle
        is 0: ``servo = zero_offset_rad + direction * joint``.
    position_min_rad, position_max_rad
        Joint angle limits [rad].
    viscous_friction_n_m_s_per_rad
        Calibrated viscous friction of the servo's gearbox at the joint [N m s/rad], >= 0.
    coulomb_friction_n_m
        Calibrated Coulomb (dry) friction of the gearbox at the joint [N m], >= 0.

    Torque and current (:meth:`link_torque_n_m`, :meth:`servo_current_a`): the motor
    drives ``direction * torque_constant_n_m_per_a * i`` [N m, joint frame] into the
    gearbox, whose friction ``b * rate + Fc * sign(rate)`` takes its share before the link
    (both friction keys 0 by default: all of the motor's torque reaches the link). The
    Dynamixel backend converts through these two methods; the DroneCAN backend's
    actuators close their own torque loop and report their output torque, so it uses
    neither the torque constant nor the friction.
    """

    name: str
    servo_id: int
    torque_constant_n_m_per_a: float
    torque_max_n_m: float
    direction: int = 1
    zero_offset_rad: float = 0.0
    position_min_rad: float = -math.pi
    position_max_rad: float = math.pi
    viscous_friction_n_m_s_per_rad: float = 0.0
    coulomb_friction_n_m: float = 0.0

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a joint needs a name")
        if self.direction not in (1, -1):
            raise ValueError(f"joint {self.name!r}: direction must be +1 or -1")
        if not (
            math.isfinite(self.torque_constant_n_m_per_a) and self.torque_constant_n_m_per_a > 0
        ):
            raise ValueError(f"joint {self.name!r}: torque constant must be positive and finite")
        if not (math.isfinite(self.torque_max_n_m) and self.torque_max_n_m >= 0):
            raise ValueError(f"joint {self.name!r}: torque_max_n_m must be >= 0 and finite")
        if not math.isfinite(self.zero_offset_rad):
            raise ValueError(f"joint {self.name!r}: zero_offset_rad must be finite")
        if not self.position_min_rad < self.position_max_rad:
            raise ValueError(f"joint {self.name!r}: position_min_rad must be < position_max_rad")
        for key in ("viscous_friction_n_m_s_per_rad", "coulomb_friction_n_m"):
            if not (math.isfinite(getattr(self, key)) and getattr(self, key) >= 0):
                raise ValueError(f"joint {self.name!r}: {key} must be >= 0 and finite")

    def servo_angle_rad(self, joint_angle_rad: float) -> float:
        """Servo shaft angle [rad] for a joint angle [rad]."""
        return self.zero_offset_rad + self.direction * joint_angle_rad

    def joint_angle_rad(self, servo_angle_rad: float) -> float:
        """Joint angle [rad] for a servo shaft angle [rad]."""
        return self.direction * (servo_angle_rad - self.zero_offset_rad)

    def friction_torque_n_m(self, rate_rad_s: float) -> float:
        """Gearbox friction [N m, joint frame] at joint rate ``rate_rad_s`` [rad/s]:
        ``b * rate + Fc * sign(rate)``, opposing the motion (0 at rest)."""
        dry = math.copysign(self.coulomb_friction_n_m, rate_rad_s) if rate_rad_s else 0.0
        return self.viscous_friction_n_m_s_per_rad * rate_rad_s + dry

    def link_torque_n_m(self, servo_current_a: float, rate_rad_s: float) -> float:
        """Torque reaching the link [N m, joint frame] from the servo's motor current [A,
        signed as the shaft angle] at joint rate ``rate_rad_s`` [rad/s]:
        ``direction * Kt * i - friction(rate)``."""
        motor_n_m = self.direction * self.torque_constant_n_m_per_a * servo_current_a
        return motor_n_m - self.friction_torque_n_m(rate_rad_s)

    def servo_current_a(self, torque_n_m: float) -> float:
        """Servo motor current [A, signed as the shaft angle] for a motor torque [N m, joint
        frame]: ``direction * torque / Kt``. No friction feed-forward: commands are what
        the motor drives (see the module docstring: why)."""
        return self.direction * torque_n_m / self.torque_constant_n_m_per_a


@dataclass(frozen=True)
class GripperConfig:
    """The gripper's servo, driven in a position mode between two shaft angles.

    Attributes
    ----------
    servo_id
        The servo's id on the arm's bus.
    open_position_rad, closed_position_rad
        Servo shaft angles [rad] (0 at the servo's centre position) of open and closed.
    """

    servo_id: int
    open_position_rad: float
    closed_position_rad: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.open_position_rad) and math.isfinite(self.closed_position_rad)):
            raise ValueError("gripper positions must be finite")


@dataclass(frozen=True)
class JointState:
    """One joint's measured state.

    Attributes
    ----------
    name
        Joint name.
    position_rad
        Joint angle [rad].
    velocity_rad_s
        Joint rate [rad/s].
    torque_n_m
        Joint torque reaching the link [N m]: the motor's (measured current times the
        torque constant) less the gearbox friction at ``velocity_rad_s``
        (:meth:`JointConfig.link_torque_n_m`), or the actuator's own output torque.
    timestamp_s
        ``time.monotonic()`` when the reply was received [s].
    """

    name: str
    position_rad: float
    velocity_rad_s: float
    torque_n_m: float
    timestamp_s: float


@dataclass(frozen=True)
class GripperState:
    """The gripper servo's measured state: closed on an object it stops short of its closed
    position and pushes against it (current); closed on nothing it reaches it.

    Attributes
    ----------
    position_rad
        Servo shaft angle [rad] (0 at the servo's centre, as ``GripperConfig``).
    current_a
        Present motor current [A], signed as the shaft angle; NaN where the backend does
        not report a current.
    timestamp_s
        ``time.monotonic()`` when the reply was received [s].
    """

    position_rad: float
    current_a: float
    timestamp_s: float

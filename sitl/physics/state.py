"""Frozen outputs of the truth plant: the rigid-body state and the actuator signals."""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["ActuatorState", "PlantState", "frozen_array"]

FloatArray = NDArray[np.float64]

_PACK_STATE = struct.Struct("40d").pack
"""The 40 floats of a state as the bytes of float64 values (native order)."""


def frozen_array(values: ArrayLike) -> FloatArray:
    """A read-only float64 copy of ``values``."""
    arr = np.array(values, dtype=np.float64)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class PlantState:
    """Truth state of the plant at one instant (arrays are read-only).

    Attributes
    ----------
    time_s : float
        Simulation time [s].
    q : ndarray, shape (8,)
        [x, y, z] vehicle CoM in the world (ENU) [m], [phi, theta, psi] ZYX Euler angles
        [rad] (phi and psi unwrapped: continuous, not wrapped to +-pi), [eta1, eta2] [rad].
    q_dot : ndarray, shape (8,)
        Time derivative of q: world velocity [m/s], Euler rates and joint rates [rad/s].
    q_ddot : ndarray, shape (8,)
        Acceleration of the step that led here: evaluated at the previous state (time_s -
        dt) under the input held over that step [m/s^2, rad/s^2]. Zero after a reset.
        Truth for tests only - never hand it to an estimator.
    quaternion_wxyz : ndarray, shape (4,)
        Attitude, body (FLU) to world (ENU), ``[w, x, y, z]``.
    rotation_world_body : ndarray, shape (3, 3)
        R = Rz(psi) Ry(theta) Rx(phi), body to world.
    omega_body_rad_s : ndarray, shape (3,)
        Angular velocity of the body in body (FLU) axes [rad/s].
    payload_attached : bool
        Whether the payload is part of link 2.
    """

    time_s: float
    q: FloatArray
    q_dot: FloatArray
    q_ddot: FloatArray
    quaternion_wxyz: FloatArray
    rotation_world_body: FloatArray
    omega_body_rad_s: FloatArray
    payload_attached: bool

    @classmethod
    def from_lists(
        cls,
        time_s: float,
        q: list[float],
        q_dot: list[float],
        q_ddot: list[float],
        quaternion_wxyz: tuple[float, ...],
        rotation9: tuple[float, ...],
        omega_body_rad_s: tuple[float, ...],
        payload_attached: bool,
    ) -> PlantState:
        """A state from a plant's per-step float lists (one read-only array behind all
        fields, over an immutable bytes object; ``rotation9`` is R row-major)."""
        flat = np.frombuffer(
            _PACK_STATE(*q, *q_dot, *q_ddot, *quaternion_wxyz, *rotation9, *omega_body_rad_s)
        )
        return cls(
            time_s=time_s,
            q=flat[0:8],
            q_dot=flat[8:16],
            q_ddot=flat[16:24],
            quaternion_wxyz=flat[24:28],
            rotation_world_body=flat[28:37].reshape(3, 3),
            omega_body_rad_s=flat[37:40],
            payload_attached=payload_attached,
        )


@dataclass(frozen=True)
class ActuatorState:
    """Actuator signals of the last underactuated step (for logging; arrays read-only).

    Attributes
    ----------
    motor_commands : ndarray, shape (6,)
        Normalized motor commands in [0, 1] from the mixer.
    rotor_thrusts_n : ndarray, shape (6,)
        Thrust of each rotor applied over the step [N] (rotor order: see
        :mod:`sitl.physics.rotors`).
    joint_torques_n_m : ndarray, shape (2,)
        Joint torques applied after the servo limit [N m].
    rate_setpoint_rad_s : ndarray, shape (3,)
        Body-rate setpoint of the attitude loop (FLU) [rad/s].
    torque_normalized : ndarray, shape (3,)
        Rate-controller output (roll, pitch, yaw) [-].
    """

    motor_commands: FloatArray
    rotor_thrusts_n: FloatArray
    joint_torques_n_m: FloatArray
    rate_setpoint_rad_s: FloatArray
    torque_normalized: FloatArray

    @classmethod
    def from_signals(cls, signals: tuple) -> ActuatorState:
        """From a plant's per-step tuple (motor commands, rotor thrusts [N], joint torques
        [N m], rate setpoint [rad/s], normalized torques), as read-only arrays."""
        commands, thrusts, joint, rate_sp, torque = signals
        return cls(
            motor_commands=frozen_array(commands),
            rotor_thrusts_n=frozen_array(thrusts),
            joint_torques_n_m=frozen_array(joint),
            rate_setpoint_rad_s=frozen_array(rate_sp),
            torque_normalized=frozen_array(torque),
        )

"""SET_ATTITUDE_TARGET and SET_POSITION_TARGET_LOCAL_NED content from our setpoints (pure;
the link sends it).

Our setpoints are ENU/FLU (:class:`companion.control.setpoints.AttitudeThrustSetpoint`: ZYX Euler
angles and PX4's relative thrust). PX4 wants the quaternion body FRD -> world NED, the
collective thrust relative to the maximum, in [0, 1] (a multicopter takes it as
``thrust_body[2] = -thrust`` and linearizes it per motor with THR_MDL_FAC), and
``type_mask`` bits set for what to ignore: 7 = ignore the three body rates, i.e.
attitude + thrust only (PX4 ``mavlink_receiver.cpp``, ``handle_message_set_attitude_target``).

A :class:`~companion.control.setpoints.PositionSetpoint` goes as SET_POSITION_TARGET_LOCAL_NED
in MAV_FRAME_LOCAL_NED: position, velocity and acceleration in PX4's local NED frame (the
frame its ODOMETRY gives the pose in), yaw from north; only the yaw rate ignored. PX4 takes
each unignored field into its trajectory setpoint (NaN for an ignored one) and flies it with
``mc_pos_control`` (``handle_message_set_position_target_local_ned``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from numpy.typing import ArrayLike

from companion.frames import (
    euler_ned_frd_from_enu_flu,
    ned_from_enu,
    quaternion_ned_frd_from_enu_flu_floats,
)
from companion.link.errors import SetpointError

if TYPE_CHECKING:
    from companion.control.setpoints import PositionSetpoint

__all__ = [
    "ATTITUDE_ONLY_TYPE_MASK",
    "POSITION_VELOCITY_ACCELERATION_YAW_TYPE_MASK",
    "PositionTargetNed",
    "attitude_target_ned_frd",
    "checked_thrust",
    "position_target_local_ned",
    "quaternion_from_euler_zyx",
]

ATTITUDE_ONLY_TYPE_MASK = 7
"""ATTITUDE_TARGET_TYPEMASK_BODY_{ROLL,PITCH,YAW}_RATE_IGNORE: attitude and thrust only."""

POSITION_VELOCITY_ACCELERATION_YAW_TYPE_MASK = 2048
"""POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE: position, velocity, acceleration and yaw."""


def quaternion_from_euler_zyx(phi: float, theta: float, psi: float) -> tuple[float, ...]:
    """Quaternion ``[w, x, y, z]`` of R = Rz(psi) Ry(theta) Rx(phi) [rad] (frame-agnostic:
    ENU/FLU angles give the ENU/FLU attitude)."""
    cr, sr = math.cos(0.5 * phi), math.sin(0.5 * phi)
    cp, sp = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cy, sy = math.cos(0.5 * psi), math.sin(0.5 * psi)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def checked_thrust(thrust_relative: float) -> float:
    """The relative thrust for SET_ATTITUDE_TARGET, as a float; ``SetpointError`` if it is
    not a finite number in [0, 1] (clamping is the setpoint mapping's job, not the
    link's)."""
    thrust = float(thrust_relative)
    if not (math.isfinite(thrust) and 0.0 <= thrust <= 1.0):
        raise SetpointError(f"normalized thrust {thrust!r} is not in [0, 1]")
    return thrust


def attitude_target_ned_frd(
    q_enu_flu: ArrayLike, thrust_relative: float
) -> tuple[list[float], float]:
    """(``q`` body FRD -> world NED, ``thrust``) for SET_ATTITUDE_TARGET.

    Raises ``SetpointError`` for a non-finite or zero quaternion, or a thrust that is not
    a finite number in [0, 1] (clamping is the setpoint mapping's job, not the link's).
    """
    thrust = checked_thrust(thrust_relative)
    q: Any = q_enu_flu
    try:
        q_ned = quaternion_ned_frd_from_enu_flu_floats(q)
    except ValueError as exc:
        raise SetpointError(f"attitude setpoint: {exc}") from None
    return list(q_ned), thrust


@dataclass(frozen=True)
class PositionTargetNed:
    """SET_POSITION_TARGET_LOCAL_NED's values: local NED position [m], velocity [m/s],
    acceleration [m/s^2] and yaw from north [rad]."""

    position_m: tuple[float, float, float]
    velocity_m_s: tuple[float, float, float]
    acceleration_m_s2: tuple[float, float, float]
    yaw_rad: float


def position_target_local_ned(setpoint: PositionSetpoint) -> PositionTargetNed:
    """The NED values of a position setpoint (ENU).

    Raises ``SetpointError`` for a value that is not finite (PX4 would take a NaN as
    "ignore this field" and fly something else than asked).
    """
    values = (
        *setpoint.position_m,
        *setpoint.velocity_m_s,
        *setpoint.acceleration_m_s2,
        setpoint.yaw_rad,
    )
    if not all(math.isfinite(v) for v in values):
        raise SetpointError(f"position setpoint {values!r} is not finite")

    def ned(v: tuple[float, float, float]) -> tuple[float, float, float]:
        x, y, z = (float(c) for c in ned_from_enu(v))
        return x, y, z

    _, _, yaw = euler_ned_frd_from_enu_flu(0.0, 0.0, setpoint.yaw_rad)
    return PositionTargetNed(
        ned(setpoint.position_m),
        ned(setpoint.velocity_m_s),
        ned(setpoint.acceleration_m_s2),
        yaw,
    )

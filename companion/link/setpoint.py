"""SET_ATTITUDE_TARGET content from our attitude setpoints (pure; the link sends it).

Our setpoints are ENU/FLU (:class:`companion.control.setpoints.AttitudeThrustSetpoint`: ZYX Euler
angles and PX4's relative thrust). PX4 wants the quaternion body FRD -> world NED, the
collective thrust relative to the maximum, in [0, 1] (a multicopter takes it as
``thrust_body[2] = -thrust`` and linearizes it per motor with THR_MDL_FAC), and
``type_mask`` bits set for what to ignore: 7 = ignore the three body rates, i.e.
attitude + thrust only (PX4 ``mavlink_receiver.cpp``, ``handle_message_set_attitude_target``).
"""

from __future__ import annotations

import math
from typing import Any

from numpy.typing import ArrayLike

from companion.frames import quaternion_ned_frd_from_enu_flu
from companion.link.errors import SetpointError

__all__ = ["ATTITUDE_ONLY_TYPE_MASK", "attitude_target_ned_frd", "quaternion_from_euler_zyx"]

ATTITUDE_ONLY_TYPE_MASK = 7
"""ATTITUDE_TARGET_TYPEMASK_BODY_{ROLL,PITCH,YAW}_RATE_IGNORE: attitude and thrust only."""


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


def attitude_target_ned_frd(
    q_enu_flu: ArrayLike, thrust_relative: float
) -> tuple[list[float], float]:
    """(``q`` body FRD -> world NED, ``thrust``) for SET_ATTITUDE_TARGET.

    Raises ``SetpointError`` for a non-finite or zero quaternion, or a thrust that is not
    a finite number in [0, 1] (clamping is the setpoint mapping's job, not the link's).
    """
    thrust = float(thrust_relative)
    if not (math.isfinite(thrust) and 0.0 <= thrust <= 1.0):
        raise SetpointError(f"normalized thrust {thrust!r} is not in [0, 1]")
    q: Any = q_enu_flu
    try:
        q_ned = quaternion_ned_frd_from_enu_flu(q)
    except ValueError as exc:
        raise SetpointError(f"attitude setpoint: {exc}") from None
    return [float(c) for c in q_ned], thrust

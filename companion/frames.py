"""The one place where PX4's frames meet ours: NED / FRD <-> ENU / FLU (DESIGN.md section 2).

Ours: world ENU (x east, y north, z up), body FLU (x forward, y left, z up). PX4 and MAVLink:
world NED (x north, y east, z down), body FRD (x forward, y right, z down). Quaternions are
Hamilton, scalar first ``[w, x, y, z]``, and rotate body vectors into the world, in both
conventions (MAVLink's ``q`` fields use the same order and meaning).

Both changes of axes are proper rotations, so attitudes convert by conjugation:
``R_ned_frd = A R_enu_flu B`` with ``A`` = ENU->NED and ``B`` = FRD->FLU. Every function
has an inverse here, and the pairs are round-trip tested. The MAVLink link of the companion
and the MAVLink endpoint of the SITL both convert through this module and nowhere else.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "enu_from_ned",
    "enu_from_ned_floats",
    "euler_enu_flu_from_ned_frd",
    "euler_ned_frd_from_enu_flu",
    "euler_zyx_from_quaternion",
    "flu_from_frd",
    "flu_from_frd_floats",
    "frd_from_flu",
    "ned_from_enu",
    "quaternion_enu_flu_from_ned_frd",
    "quaternion_enu_flu_from_ned_frd_floats",
    "quaternion_ned_frd_from_enu_flu",
    "quaternion_ned_frd_from_enu_flu_floats",
    "rotation_from_quaternion",
]

FloatArray = NDArray[np.float64]

_S = math.sqrt(0.5)
_Q_NED_ENU = (0.0, _S, _S, 0.0)
"""Rotation ENU -> NED as a quaternion: 180 deg about the axis (1, 1, 0)/sqrt(2)."""
_Q_FLU_FRD = (0.0, 1.0, 0.0, 0.0)
"""Rotation FRD -> FLU (and back): 180 deg about the body x axis."""


def ned_from_enu(v_enu: ArrayLike) -> FloatArray:
    """A world vector (position [m], velocity [m/s], ...) from ENU into NED."""
    e, n, u = np.asarray(v_enu, dtype=np.float64)
    return np.array([n, e, -u])


def enu_from_ned(v_ned: ArrayLike) -> FloatArray:
    """A world vector from NED into ENU (inverse of :func:`ned_from_enu`)."""
    return np.array(enu_from_ned_floats(*np.asarray(v_ned, dtype=np.float64)))


def enu_from_ned_floats(n: float, e: float, d: float) -> tuple[float, float, float]:
    """:func:`enu_from_ned` of a vector's three components, as a tuple (the link's
    decoders, once per message: no array)."""
    return (e, n, -d)


def frd_from_flu(v_flu: ArrayLike) -> FloatArray:
    """A body vector (angular rate [rad/s], specific force [m/s^2], ...) from FLU into FRD."""
    return np.array(flu_from_frd_floats(*np.asarray(v_flu, dtype=np.float64)))


def flu_from_frd(v_frd: ArrayLike) -> FloatArray:
    """A body vector from FRD into FLU (the same flip; inverse of :func:`frd_from_flu`)."""
    return frd_from_flu(v_frd)


def flu_from_frd_floats(x: float, y: float, z: float) -> tuple[float, float, float]:
    """:func:`flu_from_frd` of a vector's three components, as a tuple."""
    return (x, -y, -z)


def _multiply(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def _unit(q_wxyz: ArrayLike) -> tuple[float, float, float, float]:
    if type(q_wxyz) is tuple and len(q_wxyz) == 4:  # the codec's and the setpoint's
        w, x, y, z = map(float, q_wxyz)
    else:
        w, x, y, z = np.asarray(q_wxyz, dtype=np.float64).reshape(4).tolist()
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if not math.isfinite(norm) or norm < 1e-9:
        raise ValueError(f"not a rotation quaternion: {[w, x, y, z]}")
    if w < 0.0:
        norm = -norm
    return (w / norm, x / norm, y / norm, z / norm)


def quaternion_ned_frd_from_enu_flu(q_enu_flu: ArrayLike) -> FloatArray:
    """Attitude body FLU -> world ENU ``[w, x, y, z]`` as body FRD -> world NED (w >= 0)."""
    return np.array(quaternion_ned_frd_from_enu_flu_floats(q_enu_flu))


def quaternion_ned_frd_from_enu_flu_floats(
    q_enu_flu: ArrayLike,
) -> tuple[float, float, float, float]:
    """:func:`quaternion_ned_frd_from_enu_flu` as a tuple of floats (the link's setpoints)."""
    return _unit(_multiply(_multiply(_Q_NED_ENU, _unit(q_enu_flu)), _Q_FLU_FRD))


def quaternion_enu_flu_from_ned_frd(q_ned_frd: ArrayLike) -> FloatArray:
    """Attitude body FRD -> world NED ``[w, x, y, z]`` as body FLU -> world ENU (w >= 0).

    Raises ``ValueError`` for a zero, NaN or infinite quaternion (a corrupt message).
    """
    return np.array(quaternion_enu_flu_from_ned_frd_floats(q_ned_frd))


def quaternion_enu_flu_from_ned_frd_floats(
    q_ned_frd: ArrayLike,
) -> tuple[float, float, float, float]:
    """:func:`quaternion_enu_flu_from_ned_frd` as a tuple of floats (the link's decoders)."""
    return _unit(_multiply(_multiply(_Q_NED_ENU, _unit(q_ned_frd)), _Q_FLU_FRD))


def rotation_from_quaternion(q_wxyz: ArrayLike) -> FloatArray:
    """Rotation matrix (body to world) of a quaternion ``[w, x, y, z]`` (normalized first)."""
    w, x, y, z = _unit(q_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def euler_zyx_from_quaternion(q_wxyz: ArrayLike) -> tuple[float, float, float]:
    """ZYX Euler angles (phi, theta, psi) [rad] of a quaternion ``[w, x, y, z]`` (normalized
    first), with R = Rz(psi) Ry(theta) Rx(phi): the entries of
    :func:`rotation_from_quaternion` it needs, without the matrix (once per pose)."""
    w, x, y, z = _unit(q_wxyz)
    sin_theta = 2 * (x * z - w * y)
    return (
        math.atan2(2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
        -math.asin(max(-1.0, min(1.0, sin_theta))),
        math.atan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z)),
    )


def euler_ned_frd_from_enu_flu(phi: float, theta: float, psi: float) -> tuple[float, float, float]:
    """ZYX Euler angles [rad] of our frames (roll, pitch, yaw about z up) as PX4's.

    Roll is the same, pitch changes sign (nose up is +theta about FLU's y = left, and +pitch
    about FRD's y = right), and yaw is measured from north clockwise: ``pi/2 - psi``,
    wrapped to (-pi, pi].
    """
    return phi, -theta, _wrap(0.5 * math.pi - psi)


def euler_enu_flu_from_ned_frd(roll: float, pitch: float, yaw: float) -> tuple[float, float, float]:
    """PX4's ZYX Euler angles (roll, pitch, yaw from north) as ours, yaw wrapped to (-pi, pi]."""
    return roll, -pitch, _wrap(0.5 * math.pi - yaw)


def _wrap(angle_rad: float) -> float:
    wrapped = math.remainder(angle_rad, 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped

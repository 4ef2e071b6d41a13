"""Attitude conversions of the truth plant: quaternions, ZYX Euler angles, Euler-rate maps.

Conventions (DESIGN.md section 2): world ENU (z up), body FLU, R = Rz(psi) Ry(theta) Rx(phi)
maps body vectors to the world. Quaternions are Hamilton, scalar first, ``[w, x, y, z]``,
and describe the same body-to-world rotation (Pinocchio stores ``[x, y, z, w]``; that order
never leaves :mod:`sitl.physics.plant`). The body angular velocity is
``omega_B = W(Phi) Phi_dot`` with

    W = [[1, 0, -sin(theta)],
         [0, cos(phi), sin(phi) cos(theta)],
         [0, -sin(phi), cos(phi) cos(theta)]],

which is singular at theta = +-pi/2; the functions that invert it raise
:class:`~sitl.physics.errors.EulerSingularityError` there.

Everything here is written with scalar ``math`` calls: these run every plant step, and on
3-vectors they are several times faster than numpy.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sitl.physics.errors import EulerSingularityError

__all__ = [
    "COS_THETA_MIN",
    "Rot9",
    "euler_accelerations",
    "euler_from_rotation",
    "euler_from_rotation9",
    "euler_rate_matrix",
    "euler_rate_matrix_dot_times",
    "euler_rate_matrix_inverse",
    "euler_rate_matrix_inverse9",
    "quaternion_from_euler",
    "quaternion_multiply",
    "rotation9_from_quaternion",
    "rotation_from_euler",
    "rotation_from_quaternion",
]

FloatArray = NDArray[np.float64]

COS_THETA_MIN = 1e-6
"""Smallest |cos(theta)| at which W(Phi) is inverted; closer to +-90 deg pitch raises."""

_TWO_PI = 2.0 * math.pi


Rot9 = tuple[float, float, float, float, float, float, float, float, float]
"""A 3x3 matrix as 9 floats, row-major (the allocation-free form used every step)."""


def rotation9_from_quaternion(w: float, x: float, y: float, z: float) -> Rot9:
    """Row-major entries of the rotation (body to world) of unit quaternion w + xi + yj + zk."""
    return (
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )


def rotation_from_quaternion(q_wxyz: Iterable[float]) -> FloatArray:
    """Rotation matrix (body to world) of a unit quaternion ``[w, x, y, z]``, shape (3, 3)."""
    w, x, y, z = (float(c) for c in q_wxyz)
    return np.array(rotation9_from_quaternion(w, x, y, z)).reshape(3, 3)


def rotation_from_euler(phi: float, theta: float, psi: float) -> FloatArray:
    """R = Rz(psi) Ry(theta) Rx(phi) (body to world), shape (3, 3); angles in rad."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return np.array(
        [
            [cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf],
            [sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf],
            [-st, ct * sf, ct * cf],
        ]
    )


def quaternion_from_euler(phi: float, theta: float, psi: float) -> FloatArray:
    """Unit quaternion ``[w, x, y, z]`` of R = Rz(psi) Ry(theta) Rx(phi), with w >= 0."""
    cf, sf = math.cos(0.5 * phi), math.sin(0.5 * phi)
    ct, st = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cp, sp = math.cos(0.5 * psi), math.sin(0.5 * psi)
    q = np.array(
        [
            cp * ct * cf + sp * st * sf,
            cp * ct * sf - sp * st * cf,
            cp * st * cf + sp * ct * sf,
            sp * ct * cf - cp * st * sf,
        ]
    )
    return q if q[0] >= 0.0 else -q


def quaternion_multiply(a: Iterable[float], b: Iterable[float]) -> FloatArray:
    """Hamilton product a * b of quaternions ``[w, x, y, z]`` (apply b, then a)."""
    aw, ax, ay, az = (float(c) for c in a)
    bw, bx, by, bz = (float(c) for c in b)
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def euler_from_rotation9(
    r: Rot9, previous: tuple[float, float, float] | None = None
) -> tuple[float, float, float]:
    """:func:`euler_from_rotation` on a row-major 9-tuple."""
    phi = math.atan2(r[7], r[8])
    theta = math.asin(max(-1.0, min(1.0, -r[6])))
    psi = math.atan2(r[3], r[0])
    if previous is not None:
        phi += _TWO_PI * round((previous[0] - phi) / _TWO_PI)
        psi += _TWO_PI * round((previous[2] - psi) / _TWO_PI)
    return phi, theta, psi


def euler_from_rotation(
    rotation: ArrayLike, previous: tuple[float, float, float] | None = None
) -> tuple[float, float, float]:
    """ZYX Euler angles (phi, theta, psi) [rad] of a body-to-world rotation matrix.

    Parameters
    ----------
    rotation : array_like, shape (3, 3)
        R = Rz(psi) Ry(theta) Rx(phi).
    previous : tuple of 3 float, optional
        Angles of the previous sample. When given, phi and psi are unwrapped to the
        2 pi branch nearest to it, so that they stay continuous through +-pi; otherwise
        they lie in (-pi, pi]. theta always lies in [-pi/2, pi/2].
    """
    r = np.asarray(rotation, dtype=np.float64).reshape(9).tolist()
    return euler_from_rotation9(tuple(r), previous)  # type: ignore[arg-type]


def euler_rate_matrix(phi: float, theta: float) -> FloatArray:
    """W(Phi) with omega_body = W Phi_dot, shape (3, 3) (depends on phi and theta only)."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    return np.array([[1.0, 0.0, -st], [0.0, cf, sf * ct], [0.0, -sf, cf * ct]])


def euler_rate_matrix_inverse9(phi: float, theta: float) -> Rot9:
    """Row-major entries of W(Phi)^-1; raises like :func:`euler_rate_matrix_inverse`."""
    ct = math.cos(theta)
    if abs(ct) < COS_THETA_MIN:
        raise EulerSingularityError(theta)
    cf, sf = math.cos(phi), math.sin(phi)
    tt = math.sin(theta) / ct
    return (1.0, sf * tt, cf * tt, 0.0, cf, -sf, 0.0, sf / ct, cf / ct)


def euler_rate_matrix_inverse(phi: float, theta: float) -> FloatArray:
    """W(Phi)^-1 with Phi_dot = W^-1 omega_body, shape (3, 3).

    Raises
    ------
    EulerSingularityError
        If |cos(theta)| < ``COS_THETA_MIN`` (pitch at +-90 deg, gimbal lock).
    """
    return np.array(euler_rate_matrix_inverse9(phi, theta)).reshape(3, 3)


def euler_rate_matrix_dot_times(
    phi: float, theta: float, phi_dot: float, theta_dot: float, psi_dot: float
) -> tuple[float, float, float]:
    """W_dot Phi_dot, the velocity term of omega_dot = W Phi_ddot + W_dot Phi_dot (3 floats)."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    return (
        -ct * theta_dot * psi_dot,
        -sf * phi_dot * theta_dot + (cf * ct * phi_dot - sf * st * theta_dot) * psi_dot,
        -cf * phi_dot * theta_dot - (sf * ct * phi_dot + cf * st * theta_dot) * psi_dot,
    )


def euler_accelerations(
    phi: float,
    theta: float,
    euler_dot: list[float],
    omega_dot: list[float],
    w_inv9: Rot9,
) -> tuple[float, float, float]:
    """Phi_ddot = W^-1 (omega_dot - W_dot Phi_dot), from body angular acceleration [rad/s^2].

    ``w_inv9`` is :func:`euler_rate_matrix_inverse9` (phi, theta), passed in because the
    caller already has it.
    """
    c0, c1, c2 = euler_rate_matrix_dot_times(phi, theta, *euler_dot)
    d0, d1, d2 = omega_dot[0] - c0, omega_dot[1] - c1, omega_dot[2] - c2
    wi = w_inv9
    return (d0 + wi[1] * d1 + wi[2] * d2, wi[4] * d1 + wi[5] * d2, wi[7] * d1 + wi[8] * d2)

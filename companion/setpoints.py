"""Attitude and thrust setpoints from the controller's translational force (paper eq. phid).

Everything here is in the project frames (world ENU, body FLU, Euler ZYX); the conversion
to PX4's NED/FRD quaternion happens only at the MAVLink boundary. Thrust is converted
between newtons and PX4's normalized thrust by :class:`ThrustCurve`, the one place for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["AttitudeThrustSetpoint", "ThrustCurve", "attitude_thrust_setpoint", "tilt_from_force"]


def tilt_from_force(
    force_w: NDArray[np.float64], yaw_rad: float, tilt_max_rad: float
) -> tuple[float, float, bool]:
    """Small-angle tilt mapping, paper eq. phid, with a tilt limit.

    ``theta_d = (cos psi f_x + sin psi f_y) / f_z``,
    ``phi_d = (sin psi f_x - cos psi f_y) / f_z``; if ``sqrt(phi_d^2 + theta_d^2)`` exceeds
    ``tilt_max_rad`` both are scaled down together (the direction of the tilt is kept).

    Parameters
    ----------
    force_w : ndarray, shape (3,)
        Desired force on the vehicle, world ENU [N] (the controller's tau[0:3]).
    yaw_rad : float
        Current yaw psi [rad].
    tilt_max_rad : float
        Tilt limit [rad].

    Returns
    -------
    phi_d, theta_d : float
        Desired roll and pitch [rad] (ZYX Euler, FLU body).
    saturated : bool
        True if the limit was applied, or the force does not point up (then level).
    """
    fx, fy, fz = float(force_w[0]), float(force_w[1]), float(force_w[2])
    if fz <= 0.0:
        return 0.0, 0.0, True
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    theta_d = (c * fx + s * fy) / fz
    phi_d = (s * fx - c * fy) / fz
    tilt = math.hypot(phi_d, theta_d)
    if tilt > tilt_max_rad:
        scale = tilt_max_rad / tilt
        return phi_d * scale, theta_d * scale, True
    return phi_d, theta_d, False


@dataclass(frozen=True)
class ThrustCurve:
    """PX4's thrust model: ``rel_thrust = f u^2 + (1 - f) u`` with f = THR_MDL_FAC.

    Parameters
    ----------
    max_thrust_n : float
        Total thrust of all rotors at normalized command u = 1 [N].
    thr_mdl_fac : float
        PX4 parameter THR_MDL_FAC in [0, 1].
    """

    max_thrust_n: float
    thr_mdl_fac: float

    def __post_init__(self) -> None:
        if self.max_thrust_n <= 0.0:
            raise ValueError("max_thrust_n must be positive")
        if not 0.0 <= self.thr_mdl_fac <= 1.0:
            raise ValueError("thr_mdl_fac must lie in [0, 1]")

    def thrust_n(self, normalized: float) -> float:
        """Total thrust [N] for a normalized command u in [0, 1]."""
        u = min(max(normalized, 0.0), 1.0)
        f = self.thr_mdl_fac
        return self.max_thrust_n * (f * u * u + (1.0 - f) * u)

    def normalized(self, thrust_n: float) -> tuple[float, bool]:
        """Normalized command u in [0, 1] for a total thrust [N], and whether it saturated."""
        rel = thrust_n / self.max_thrust_n
        saturated = not 0.0 <= rel <= 1.0
        rel = min(max(rel, 0.0), 1.0)
        f = self.thr_mdl_fac
        if f < 1e-9:
            return rel, saturated
        b = 1.0 - f
        u = (-b + math.sqrt(b * b + 4.0 * f * rel)) / (2.0 * f)
        return min(u, 1.0), saturated


@dataclass(frozen=True)
class AttitudeThrustSetpoint:
    """What goes to the autopilot: attitude (ENU/FLU, ZYX Euler) and collective thrust."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    thrust_n: float
    """Collective thrust along body z [N]."""
    thrust_normalized: float
    """PX4 normalized thrust in [0, 1] from :class:`ThrustCurve`."""
    tilt_saturated: bool
    thrust_saturated: bool


def attitude_thrust_setpoint(
    force_w: NDArray[np.float64],
    yaw_rad: float,
    yaw_d_rad: float,
    tilt_max_rad: float,
    curve: ThrustCurve,
) -> AttitudeThrustSetpoint:
    """Setpoint for a desired world force: tilt by eq. phid, thrust so that the vertical
    component of the tilted thrust equals ``force_w[2]`` (``T = f_z / (cos phi cos theta)``).

    ``yaw_rad`` is the measured yaw (used by eq. phid), ``yaw_d_rad`` the yaw to command.
    """
    phi, theta, tilt_sat = tilt_from_force(force_w, yaw_rad, tilt_max_rad)
    thrust = max(float(force_w[2]), 0.0) / (math.cos(phi) * math.cos(theta))
    u, thrust_sat = curve.normalized(thrust)
    return AttitudeThrustSetpoint(
        roll_rad=phi,
        pitch_rad=theta,
        yaw_rad=yaw_d_rad,
        thrust_n=curve.thrust_n(u),
        thrust_normalized=u,
        tilt_saturated=tilt_sat,
        thrust_saturated=thrust_sat,
    )

"""Attitude and thrust setpoints from the controller's translational force (paper eq. phid).

Everything here is in the project frames (world ENU, body FLU, Euler ZYX); the conversion
to PX4's NED/FRD quaternion happens only at the MAVLink boundary. Thrust is converted
between newtons and PX4's relative thrust by :class:`ThrustModel`, the one place for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "AttitudeThrustSetpoint",
    "PositionSetpoint",
    "ThrustModel",
    "attitude_thrust_setpoint",
    "fixed_setpoint",
    "tilt_from_force",
]


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
class ThrustModel:
    """The force PX4 makes for the thrust of SET_ATTITUDE_TARGET, and back.

    PX4 takes that thrust as *relative* collective thrust r in [0, 1] (a fraction of the
    vehicle's maximum thrust) and linearizes it per motor with its parameter THR_MDL_FAC
    (mixer, ``FunctionMotors``: motor command ``u`` with ``r = f u^2 + (1 - f) u``). On
    motors whose thrust curve is that ``f`` -- the vehicle's THR_MDL_FAC equal to the
    configured ``vehicle.rotors.thr_mdl_fac``, which the flight app checks before it flies
    -- the force is linear: ``T = r * max_thrust_n``.

    Parameters
    ----------
    max_thrust_n : float
        Collective thrust of all rotors at r = 1 [N].
    min_relative : float
        Smallest relative thrust commanded in flight (the thrust floor, PX4's
        MPC_THR_MIN): below it the mixer has no room left for the roll and pitch
        torques (airmode off).
    """

    max_thrust_n: float
    min_relative: float = 0.0

    def __post_init__(self) -> None:
        if not self.max_thrust_n > 0.0:
            raise ValueError("max_thrust_n must be positive")
        if not 0.0 <= self.min_relative < 1.0:
            raise ValueError("min_relative must lie in [0, 1)")

    @property
    def min_thrust_n(self) -> float:
        """The thrust floor [N]."""
        return self.min_relative * self.max_thrust_n

    def thrust_n(self, relative: float) -> float:
        """Collective thrust [N] of a relative thrust (clipped to [0, 1])."""
        return self.max_thrust_n * min(max(relative, 0.0), 1.0)

    def relative(self, thrust_n: float) -> tuple[float, bool]:
        """Relative thrust for a collective thrust [N], clipped to [min_relative, 1], and
        whether it was clipped."""
        rel = thrust_n / self.max_thrust_n
        clipped = min(max(rel, self.min_relative), 1.0)
        return clipped, clipped != rel


@dataclass(frozen=True)
class AttitudeThrustSetpoint:
    """What goes to the autopilot: attitude (ENU/FLU, ZYX Euler) and collective thrust."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    thrust_n: float
    """Collective thrust along body z [N]."""
    thrust_relative: float
    """PX4's relative thrust in [0, 1] (:class:`ThrustModel`)."""
    tilt_saturated: bool
    thrust_saturated: bool
    q_ned_frd: tuple[float, float, float, float] | None = field(default=None, compare=False)
    """The attitude as SET_ATTITUDE_TARGET carries it, body FRD -> world NED ``[w, x, y,
    z]``, where the compiled step computed it with the link's own operations (the same
    bits); None: the link converts the Euler angles."""


@dataclass(frozen=True)
class PositionSetpoint:
    """What goes to the autopilot when PX4's own position controller flies the vehicle:
    position, velocity and acceleration feed-forward (world ENU) and yaw (ZYX, about z up
    from east). PX4's velocity loop adds the acceleration to its own output and its hover
    thrust estimator supplies the weight (``mc_pos_control``)."""

    position_m: tuple[float, float, float]
    velocity_m_s: tuple[float, float, float]
    acceleration_m_s2: tuple[float, float, float]
    yaw_rad: float


def attitude_thrust_setpoint(
    force_w: NDArray[np.float64],
    yaw_rad: float,
    yaw_d_rad: float,
    tilt_max_rad: float,
    model: ThrustModel,
) -> AttitudeThrustSetpoint:
    """Setpoint for a desired world force: tilt by eq. phid, thrust so that the vertical
    component of the tilted thrust equals ``force_w[2]`` (``T = f_z / (cos phi cos theta)``).

    ``yaw_rad`` is the measured yaw (used by eq. phid), ``yaw_d_rad`` the yaw to command.
    The thrust never falls below the model's floor: a force that does not point up (or
    less than the floor) is flown at the floor, tilted toward its horizontal part as if
    its vertical part were the floor (so the vehicle keeps its roll and pitch authority
    and the horizontal direction asked for), and reported saturated.
    """
    floor_n = model.min_thrust_n
    fz = float(force_w[2])
    lifted = force_w if fz >= floor_n and fz > 0.0 else np.array((force_w[0], force_w[1], floor_n))
    phi, theta, tilt_sat = tilt_from_force(lifted, yaw_rad, tilt_max_rad)
    thrust = max(fz, 0.0) / (math.cos(phi) * math.cos(theta))
    rel, thrust_sat = model.relative(thrust)
    return AttitudeThrustSetpoint(
        roll_rad=phi,
        pitch_rad=theta,
        yaw_rad=yaw_d_rad,
        thrust_n=model.thrust_n(rel),
        thrust_relative=rel,
        tilt_saturated=tilt_sat or lifted is not force_w,
        thrust_saturated=thrust_sat,
    )


def fixed_setpoint(
    roll_rad: float, pitch_rad: float, yaw_rad: float, thrust_n: float, model: ThrustModel
) -> AttitudeThrustSetpoint:
    """An attitude (ZYX Euler, ENU/FLU) [rad] with a collective thrust [N] clipped to the
    model's range: the safe setpoints of the OFFBOARD handover (the attitude the vehicle
    has, hover thrust) and of the ground (level)."""
    rel, sat = model.relative(thrust_n)
    thrust = model.thrust_n(rel)
    return AttitudeThrustSetpoint(roll_rad, pitch_rad, yaw_rad, thrust, rel, False, sat)

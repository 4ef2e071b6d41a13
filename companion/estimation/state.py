"""State assembly: measurements in, q, q_dot, q_ddot out (DESIGN.md section 1, step 2).

Measurements arrive in the project frames (ENU world, FLU body, ZYX Euler); conversions
from PX4's NED/FRD happen before, at the MAVLink boundary. Body rates become Euler rates
here, with the filter's current attitude. Also here: the generalized force the estimator
can trust in flight (thrust along body z, servo torques), computed from commands and
measurements, never from truth.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.coordinates import ATTITUDE, N_Q, PHI, THETA
from companion.estimation.filters import FilteredState, StateFilter

if TYPE_CHECKING:
    from companion.config import Sensors

__all__ = ["StateAssembler", "euler_rates_from_body_rates", "thrust_force_world"]

FloatArray = NDArray[np.float64]
# Tuples: the filter caches its row selections by them without a conversion.
_POSE_ROWS = (0, 1, 2, 3, 4, 5)
_POSITION_ROWS = (0, 1, 2)
_EULER_ROWS = tuple(range(N_Q)[ATTITUDE])
_JOINT_ROWS = (6, 7)


def euler_rates_from_body_rates(
    phi: float, theta: float, omega_body: Iterable[float]
) -> FloatArray:
    """(phi_dot, theta_dot, psi_dot) = W(phi, theta)^-1 omega_B for R = Rz Ry Rx [rad/s].

    Singular at theta = +-pi/2 (raises ZeroDivisionError there, as the Euler angles do).
    """
    wx, wy, wz = (float(w) for w in omega_body)
    sp, cp = math.sin(phi), math.cos(phi)
    ct = math.cos(theta)
    tt = math.tan(theta)
    return np.array((wx + sp * tt * wy + cp * tt * wz, cp * wy - sp * wz, (sp * wy + cp * wz) / ct))


def thrust_force_world(phi: float, theta: float, psi: float, thrust_n: float) -> FloatArray:
    """World-frame (ENU) force R(phi, theta, psi) e3 T of a collective thrust T [N]."""
    sp, cp = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    ss, cs = math.sin(psi), math.cos(psi)
    return thrust_n * np.array((cp * st * cs + sp * ss, cp * st * ss - sp * cs, cp * ct))


class StateAssembler:
    """Feeds pose, body-rate and joint measurements to a :class:`StateFilter`.

    Measurement noise is fixed per row at construction (the filter's fast path).

    Parameters
    ----------
    jerk_psd : array_like, shape (8,)
        Filter process noise per row (m^2/s^5, rad^2/s^5).
    position_std : array_like, shape (8,)
        Noise of measured q per row: position [m], Euler angles [rad], joint angles [rad].
    velocity_std : array_like, shape (8,)
        Noise of measured q_dot per row (for the Euler rows: of the body rates, taken
        equal near level) [m/s, rad/s].
    """

    def __init__(self, jerk_psd: ArrayLike, position_std: ArrayLike, velocity_std: ArrayLike):
        self.filter = StateFilter(
            jerk_psd=jerk_psd,
            position_std=np.maximum(position_std, 1e-9),
            velocity_std=np.maximum(velocity_std, 1e-9),
        )

    @classmethod
    def from_sensors(cls, sensors: Sensors) -> StateAssembler:
        """For the measurement noise of a scenario's ``[sensors]`` section.

        Encoder quantisation (4096 ticks/rev) acts as uniform noise of step/sqrt(12), and
        the servos' Present Velocity unit likewise; the vehicle's velocity, when the
        autopilot reports it (:meth:`velocity`), has ``velocity_std_m_s``.
        """
        s = sensors
        joint_std = max(s.joint_std_rad, 2.0 * math.pi / 4096 / math.sqrt(12.0))
        return cls(
            s.jerk_psd,
            position_std=[s.position_std_m] * 3 + [s.attitude_std_rad] * 3 + [joint_std] * 2,
            velocity_std=[s.velocity_std_m_s] * 3
            + [s.gyro_std_rad_s] * 3
            + [s.joint_velocity_unit_rad_s / math.sqrt(12.0)] * 2,
        )

    @classmethod
    def noise_free(cls, jerk_psd: ArrayLike) -> StateAssembler:
        """For exact measurements of q and q_dot (idealised runs): fused with std 1e-6
        (m, rad) and 1e-5 (m/s, rad/s). Smaller values make the update ill-conditioned
        without improving q_ddot (about 1e-3 m/s^2 RMS on the paper run)."""
        return cls(jerk_psd, np.full(N_Q, 1e-6), np.full(N_Q, 1e-5))

    @property
    def ready(self) -> bool:
        """True once every row has had a position measurement."""
        return self.filter.ready

    @property
    def estimate(self) -> FilteredState:
        """q, q_dot, q_ddot (raises FilterNotReadyError before :attr:`ready`)."""
        return self.filter.estimate

    def predict(self, dt_s: float) -> None:
        """Bring the filter to the current time (once per control step)."""
        self.filter.predict(dt_s)

    def pose(
        self, position_m: Iterable[float], euler_rad: Iterable[float], age_s: float = 0.0
    ) -> None:
        """Motion-capture pose: ENU position [m] and ZYX Euler angles [rad]."""
        values = (*position_m, *euler_rad)
        self.filter.update_position(values, latency_s=age_s, rows=_POSE_ROWS)

    def velocity(self, velocity_enu_m_s: ArrayLike, age_s: float = 0.0) -> None:
        """The autopilot's velocity estimate, world ENU [m/s]."""
        self.filter.update_velocity(velocity_enu_m_s, latency_s=age_s, rows=_POSITION_ROWS)

    def reset_position(self, position_m: ArrayLike) -> None:
        """Start the x, y, z rows again from a position [m] (the autopilot's estimate
        jumped: an EKF reset), keeping nothing of the old motion."""
        self.filter.reset_rows(position_m, rows=_POSITION_ROWS)

    def body_rates(self, omega_body_rad_s: Iterable[float], age_s: float = 0.0) -> None:
        """Gyro body rates (FLU) [rad/s], converted with the filter's attitude (in one
        compiled call where the filter can: :meth:`StateFilter.update_body_rates`)."""
        f = self.filter
        if not f.ready or f.update_body_rates(omega_body_rad_s, latency_s=age_s):
            return
        phi, theta = f.value(PHI), f.value(THETA)
        rates = euler_rates_from_body_rates(phi, theta, omega_body_rad_s)
        f.update_velocity(rates, latency_s=age_s, rows=_EULER_ROWS)

    def cycle(
        self,
        dt_s: float,
        position_m: Iterable[float],
        euler_rad: Iterable[float],
        velocity_enu_m_s: ArrayLike | None,
        omega_body_rad_s: Iterable[float] | None,
        eta_rad: Sequence[float] | None,
        eta_dot_rad_s: Sequence[float] | None,
        joint_age_s: float = 0.0,
    ) -> None:
        """One control cycle's measurements on a started filter, in this order:
        :meth:`predict` by ``dt_s`` [s], :meth:`pose`, :meth:`velocity`,
        :meth:`body_rates`, :meth:`joints` and :meth:`joint_rates` (``joint_age_s`` [s]
        old); None: not measured this cycle (the joint rates come with the angles). In one
        compiled call where the filter can (:meth:`StateFilter.fuse_cycle`)."""
        pose = (*position_m, *euler_rad)
        if self.filter.fuse_cycle(
            dt_s, pose, velocity_enu_m_s, omega_body_rad_s, eta_rad, eta_dot_rad_s, joint_age_s
        ):
            return
        self.predict(dt_s)
        self.filter.update_position(pose, rows=_POSE_ROWS)
        if velocity_enu_m_s is not None:
            self.velocity(velocity_enu_m_s)
        if omega_body_rad_s is not None:
            self.body_rates(omega_body_rad_s)
        if eta_rad is not None and eta_dot_rad_s is not None:
            self.joints(eta_rad, joint_age_s)
            self.joint_rates(eta_dot_rad_s, joint_age_s)

    def joints(self, eta_rad: ArrayLike, age_s: float = 0.0) -> None:
        """Servo joint angles [rad]."""
        self.filter.update_position(eta_rad, latency_s=age_s, rows=_JOINT_ROWS)

    def joint_rates(self, eta_dot_rad_s: ArrayLike, age_s: float = 0.0) -> None:
        """Servo joint velocities (Present Velocity) [rad/s]."""
        self.filter.update_velocity(eta_dot_rad_s, latency_s=age_s, rows=_JOINT_ROWS)

    def exact(self, q: ArrayLike, q_dot: ArrayLike) -> None:
        """Measurements of all of q and q_dot at once."""
        self.filter.update_position(q)
        self.filter.update_velocity(q_dot)

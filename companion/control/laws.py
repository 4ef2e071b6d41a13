"""Controllers of the aerial manipulator (paper sections III-B and IV-A).

All return the generalized force tau (conjugate to q, DESIGN.md section 2) from the state,
the desired trajectory and the model terms at this step; none keeps a clock.

- :class:`PassivityController`: the augmented passivity-based law (eq. tau2) with the
  estimator's theta; :meth:`PassivityController.nonadaptive` is the paper's baseline (the
  same law with theta frozen at the empty-arm values).
- :class:`SlidingModeController`: the adaptive sliding-mode controller (eq. asc1) with the
  total-mass read-out of eq. asc2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.coordinates import N_Q
from companion.estimation.estimator import Skip
from companion.estimation.filters import FilteredState
from companion.model import ModelTerms

if TYPE_CHECKING:
    from companion.config import CompanionConfig

__all__ = [
    "ControlLaw",
    "ControlRateError",
    "DesiredState",
    "HorizontalTrim",
    "PassivityController",
    "SlidingModeController",
    "check_control_rate",
    "damping_step_ratio",
    "wrap_angle_error",
]

FloatArray = NDArray[np.float64]
YAW = 5
_ONE = np.ones(1)
"""The last entry of xi = [m2, m3, m4, 1]."""


class ControlRateError(ValueError):
    """The control period is too long for the controller's velocity gains."""


def damping_step_ratio(
    mass_matrix: FloatArray, k: ArrayLike, dt_s: float, rows: tuple[int, ...]
) -> float:
    """``dt * lambda_max(M_rr^-1 k_rr)`` on the rows the controller actuates.

    The velocity feedback ``-k q_dot`` of eqs. tau2 and asc1, held constant for one control
    period, is a discrete damping loop that is unstable when this ratio exceeds 2 (each
    step overshoots the velocity it damps). Computed with the Cholesky factor of M_rr, so
    the eigenvalues are those of a symmetric matrix.
    """
    idx = np.asarray(rows)
    chol = np.linalg.cholesky(mass_matrix[np.ix_(idx, idx)])
    inv = np.linalg.inv(chol)
    k_rr = np.diag(np.asarray(k, dtype=float)[idx])
    return float(dt_s * np.linalg.eigvalsh(inv @ k_rr @ inv.T)[-1])


def check_control_rate(
    mass_matrix: FloatArray,
    k: ArrayLike,
    dt_s: float,
    rows: tuple[int, ...],
    limit: float = 1.0,
) -> float:
    """Raise :class:`ControlRateError` if :func:`damping_step_ratio` reaches ``limit``
    (default 1: half the stability bound, for margin); return the ratio otherwise."""
    ratio = damping_step_ratio(mass_matrix, k, dt_s, rows)
    if ratio >= limit:
        raise ControlRateError(
            f"control period {dt_s * 1e3:.3g} ms is too long for the velocity gains: "
            f"dt * max eig(M^-1 k) = {ratio:.2f} (the discrete loop is unstable above 2; "
            f"keep it below {limit:g}); raise the control rate to at least "
            f"{ratio / (limit * dt_s):.0f} Hz or lower k"
        )
    return ratio


@dataclass(frozen=True)
class DesiredState:
    """q_d and its first two derivatives, each shape (8,) (m, rad and their rates)."""

    q: FloatArray
    q_dot: FloatArray
    q_ddot: FloatArray


def wrap_angle_error(e: FloatArray) -> FloatArray:
    """e with the yaw entry wrapped to [-pi, pi) (a copy)."""
    out = e.copy()
    out[YAW] = (float(out[YAW]) + np.pi) % (2.0 * np.pi) - np.pi
    return out


class ControlLaw(Protocol):
    """A control law as :class:`~companion.control.flight.FlightControl` runs it, one step
    of ``dt_s`` [s]: the generalized force tau (shape (8,), conjugate to q) and the theta
    the law used (shape (3,)), from the model terms at the filtered state, the desired
    state (roll and pitch rows from the tilt reference), the estimator's theta_hat and the
    force applied over the last step (NaN on rows without a known force), or why it is not
    known (:class:`~companion.estimation.estimator.Skip`)."""

    @property
    def velocity_gain(self) -> FloatArray:
        """Diagonal of the law's velocity feedback gain (k, K1), shape (8,): what the
        control rate must be fast enough for (:func:`check_control_rate`)."""
        ...

    def control(
        self,
        dt_s: float,
        terms: ModelTerms,
        state: FilteredState,
        desired: DesiredState,
        theta_hat: FloatArray,
        applied_tau: FloatArray | Skip,
    ) -> tuple[FloatArray, FloatArray]: ...


class PassivityController:
    """Augmented passivity-based control, eq. tau2:

    ``tau = Mhat qd_ddot + Chat qd_dot + Ghat - k (e_c_dot + Lambda e_c)``, ``e_c = q - q_d``,
    with ``Mhat qd_ddot + Chat qd_dot + Ghat = Y(q, q_dot, qd_dot, qd_ddot) [thetahat, 1]``.

    Parameters
    ----------
    k, lam : array_like, shape (8,)
        Diagonals of k (N s/m, N m s/rad) and Lambda (1/s).
    fixed_theta : array_like, shape (3,), optional
        If given, theta is frozen at this value and the estimate passed to :meth:`torque`
        is ignored (the non-adaptive baseline).
    """

    def __init__(self, k: ArrayLike, lam: ArrayLike, fixed_theta: ArrayLike | None = None):
        self.k = np.asarray(k, dtype=float)
        self.k_lam = self.k * np.asarray(lam, dtype=float)
        self.fixed_theta: FloatArray | None = (
            None if fixed_theta is None else np.asarray(fixed_theta, dtype=float)
        )
        self._fixed_xi: FloatArray | None = (
            None if self.fixed_theta is None else np.concatenate((self.fixed_theta, _ONE))
        )

    @classmethod
    def nonadaptive(cls, k: ArrayLike, lam: ArrayLike, nominal_theta: ArrayLike):
        """The paper's conventional controller: eq. tau2 with the empty-arm theta."""
        return cls(k, lam, fixed_theta=nominal_theta)

    @property
    def velocity_gain(self) -> FloatArray:
        return self.k

    def control(self, dt_s, terms, state, desired, theta_hat, applied_tau):
        """:class:`ControlLaw`: eq. tau2 with ``theta_hat`` (or the fixed theta)."""
        used = self.fixed_theta if self.fixed_theta is not None else np.asarray(theta_hat)
        return self.torque(terms, state.q, state.q_dot, desired, used), used

    def torque(
        self,
        terms: ModelTerms,
        q: FloatArray,
        q_dot: FloatArray,
        desired: DesiredState,
        theta_hat: ArrayLike,
    ) -> FloatArray:
        """tau, shape (8,), for ``terms = model.terms(q, q_dot)``."""
        xi = self._fixed_xi if self._fixed_xi is not None else np.concatenate((theta_hat, _ONE))
        feedforward = terms.regressor(desired.q_dot, desired.q_ddot) @ xi
        e = wrap_angle_error(q - desired.q)
        return feedforward - self.k * (q_dot - desired.q_dot) - self.k_lam * e


class HorizontalTrim:
    """Slow integral action on the horizontal rows x, y of eq. tau2's force.

    A real vehicle holds its *estimated* attitude: a bias of that estimate (an IMU
    misalignment, EKF2's accelerometer-bias state wandering; 2 deg is 0.4 N at 1.2 kg) is
    a horizontal force the model does not have, and the passivity law, without integral
    action, answers it with a position error of bias / (k Lambda) (10 cm on PX4 SIH with
    the paper's gains). The trim integrates the sliding variable
    ``s = (q_dot - q_d_dot) + Lambda (q - q_d)`` on x, y: ``d_dot = -gain s``, ``|d_i| <=
    limit``; tau[0:2] += d. It is the ``Deltahat`` of the sliding-mode law (eq. asc1)
    restricted to x, y, with a gain small against k Lambda so the loop keeps its phase
    margin (integral time k / gain).

    Parameters
    ----------
    gain_n_per_m : float
        Integral gain [N per (m/s) s, i.e. N/m]; 0 disables the trim.
    limit_n : float
        Largest trim force per axis [N].
    """

    def __init__(self, gain_n_per_m: float, limit_n: float) -> None:
        if not (gain_n_per_m >= 0.0 and limit_n >= 0.0):
            raise ValueError("gain and limit must be >= 0")
        self.gain = gain_n_per_m
        self.limit = limit_n
        self.force_n = np.zeros(2)
        """The trim force, world x, y [N]."""

    def start(self, force_n: FloatArray) -> None:
        """Start from a force, world x, y [N] (clipped to the limit)."""
        self.force_n = np.clip(np.asarray(force_n, dtype=float), -self.limit, self.limit)

    def update(self, dt_s: float, sliding_xy: FloatArray) -> FloatArray:
        """Integrate over ``dt_s`` [s] with the sliding variable of x, y [m/s]; the force."""
        f = self.force_n - dt_s * self.gain * np.asarray(sliding_xy, dtype=float)
        self.force_n = np.clip(f, -self.limit, self.limit)
        return self.force_n


class SlidingModeController:
    """Adaptive sliding-mode control (eq. asc1) with the mass read-out of eq. asc2.

    ``s = q_dot - qr_dot``, ``qr_dot = qd_dot - Lambda (q - q_d)``,
    ``tau = Mhat qr_ddot + Chat qr_dot + Ghat + Deltahat - K1 s - K2 sat(s / phi)``,
    ``Deltahat_dot = -gamma_delta s``. The model terms use m2hat with the centre of mass
    held at the empty-arm lc (the law estimates the mass only). ``sat`` is sgn with a
    boundary layer of width phi (a pure sgn chatters at the control rate).

    Mass read-out (eq. asc2), read as Newton's law for the vertical row: the third rows of
    Mhat and Chat give ``m z_ddot_com`` for the previous estimate, so
    ``mhat = tau_3 / (g + (Mhat_3 q_ddot + Chat_3 q_dot) / mhat_prev)`` and
    ``m2hat = mhat - (m_b + m1)``, low-passed with time constant ``mass_filter_s`` and kept
    within [m2_min, m2_max].
    """

    def __init__(
        self,
        k1: ArrayLike,
        k2: ArrayLike,
        lam: ArrayLike,
        boundary_layer: ArrayLike,
        gamma_delta: ArrayLike,
        known_mass_kg: float,
        gravity_m_s2: float,
        nominal_lc_m: float,
        m2_0: float,
        m2_bounds_kg: tuple[float, float],
        mass_filter_s: float,
    ) -> None:
        self.k1 = np.asarray(k1, dtype=float)
        self.k2 = np.asarray(k2, dtype=float)
        self.lam = np.asarray(lam, dtype=float)
        self.phi = np.asarray(boundary_layer, dtype=float)
        self.gamma_delta = np.asarray(gamma_delta, dtype=float)
        self.known_mass_kg = known_mass_kg
        self.g = gravity_m_s2
        self.lc = nominal_lc_m
        self.m2_bounds = m2_bounds_kg
        self.mass_filter_s = mass_filter_s
        self.m2 = m2_0
        self.delta = np.zeros(N_Q)

    @classmethod
    def from_config(cls, config: CompanionConfig) -> SlidingModeController:
        """The law with the gains of ``[controller.sliding_mode]`` and the estimator's
        initial m2 and bounds."""
        sm = config.controller.sliding_mode
        return cls(
            k1=sm.k1,
            k2=sm.k2,
            lam=sm.lambda_,
            boundary_layer=sm.boundary_layer,
            gamma_delta=sm.gamma_delta,
            known_mass_kg=config.vehicle.mass_kg + config.arm.link1.mass_kg,
            gravity_m_s2=config.environment.gravity_m_s2,
            nominal_lc_m=config.nominal_theta.lc_m,
            m2_0=config.estimator.initial_theta.m2_kg,
            m2_bounds_kg=(config.estimator.m2_bounds_kg[0], config.estimator.m2_bounds_kg[1]),
            mass_filter_s=sm.mass_filter_s,
        )

    @property
    def theta(self) -> FloatArray:
        """(m2, m3, m4) the law uses: m2hat at the empty-arm lc (point mass)."""
        return self._xi()[:3]

    @property
    def velocity_gain(self) -> FloatArray:
        return self.k1

    def control(self, dt_s, terms, state, desired, theta_hat, applied_tau):
        """:class:`ControlLaw`: eq. asc1 with its own mass read-out (``theta_hat``, the
        estimator's, is not used); the read-out takes the applied vertical force."""
        force_z_n = None if isinstance(applied_tau, Skip) else float(applied_tau[2])
        tau = self.torque(dt_s, terms, state.q, state.q_dot, state.q_ddot, desired, force_z_n)
        return tau, self.theta

    def _xi(self) -> FloatArray:
        """xi = [theta, 1] (eq. reg)."""
        m2, lc = self.m2, self.lc
        return np.array((m2, m2 * lc, m2 * lc**2, 1.0))

    def torque(
        self,
        dt: float,
        terms: ModelTerms,
        q: FloatArray,
        q_dot: FloatArray,
        q_ddot: FloatArray,
        desired: DesiredState,
        applied_force_z_n: float | None,
    ) -> FloatArray:
        """tau, shape (8,); advances Deltahat and the mass read-out by dt [s].

        ``applied_force_z_n`` is the vertical world force actually applied during the last
        control period [N] (in flight: the thrust model's force along the measured body z),
        the force that produced ``q_ddot``; None (not known) or not finite skips the
        read-out. Using
        this step's commanded tau_3 instead lets the read-out run away once thrust
        saturates: the command then exceeds the force that produced the acceleration.
        """
        e = wrap_angle_error(q - desired.q)
        qr_dot = desired.q_dot - self.lam * e
        qr_ddot = desired.q_ddot - self.lam * (q_dot - desired.q_dot)
        s = q_dot - qr_dot
        xi = self._xi()
        sat = np.minimum(np.maximum(s / self.phi, -1.0), 1.0)
        tau = terms.regressor(qr_dot, qr_ddot) @ xi + self.delta - self.k1 * s - self.k2 * sat
        self.delta = self.delta - dt * self.gamma_delta * s
        if applied_force_z_n is not None and math.isfinite(applied_force_z_n):
            self._read_mass(dt, terms, q_dot, q_ddot, applied_force_z_n, xi)
        return tau

    def _read_mass(self, dt, terms, q_dot, q_ddot, force_z, xi) -> None:
        """Eq. asc2 with the previous estimate; first-order low-pass, then bounds."""
        total_prev = self.known_mass_kg + self.m2
        # Row 3 of M q_ddot + C q_dot + G is m (g + z_ddot_com) for the previous estimate.
        specific_force = float(terms.regressor(q_dot, q_ddot)[2] @ xi) / total_prev
        if specific_force <= 0.1 * self.g:
            return  # near free fall the read-out is meaningless: keep the estimate
        m2_read = force_z / specific_force - self.known_mass_kg
        a = min(dt / self.mass_filter_s, 1.0)
        m2 = self.m2 + a * (m2_read - self.m2)
        self.m2 = min(max(m2, self.m2_bounds[0]), self.m2_bounds[1])

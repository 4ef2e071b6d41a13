"""Servo torque constant and gearbox friction from the arm held still and swept (pure).

``companion arm calibrate`` (:mod:`companion.cli.arm`) moves the arm and reads the servos;
this module plans where it goes and fits what it read. No I/O, no clock.

Model of joint j (joint frame, SI units), with the vehicle level and still:

    Kt_j i_j = tau_j(q, q_dot) + b_j eta_dot_j + Fc_j sign(eta_dot_j)

- ``i_j`` the servo's present current [A], signed as the joint (``direction`` applied);
- ``tau_j = (G(q) + C(q, q_dot) q_dot)_j`` [N m], the torque the arm's model
  (:class:`companion.model.ManipulatorModel`, the empty link 2 of the config) needs at
  rest or at constant joint speed (eq. mcg_model without ``M q_ddot``: every sample is
  taken at rest or in the constant-speed middle of a sweep);
- ``Kt_j`` the torque constant [N m/A], ``b_j`` the viscous [N m s/rad] and ``Fc_j`` the
  Coulomb friction [N m] of the gearbox.

1. Static poses (:func:`static_poses`, ``q_dot = 0``, no friction): ``i = tau / Kt``,
   least squares through the origin for ``1/Kt`` (the current is the measured, noisy
   side; the angles are read to 0.09 deg), :func:`fit_torque_constant`.
2. Sweeps (:func:`sweep_corners`) at two speeds or more, both directions: with ``Kt``
   from step 1, ``r = Kt i - tau = b eta_dot + Fc sign(eta_dot)``, least squares
   (:func:`fit_friction`). One speed cannot tell ``b`` from ``Fc``. Coulomb friction is
   kept only where the data support it: its estimate exceeds :data:`COULOMB_SIGNIFICANCE`
   standard errors and half a current step; otherwise ``Fc = 0`` and ``b`` is fitted
   alone. A dry-friction term fitted into noise would flip the measured torque by ``2 Fc``
   at every sign change of a quantized rate; viscous friction is continuous in the rate.

Each fit states why it cannot be trusted (``problem``), or None.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.coordinates import JOINTS, N_Q, TILT
from companion.model import ManipulatorModel

__all__ = [
    "COULOMB_SIGNIFICANCE",
    "MAX_KT_RELATIVE_ERROR",
    "MIN_GRAVITY_CURRENT_STEPS",
    "MIN_SWEEP_SAMPLES",
    "FrictionFit",
    "TorqueConstantFit",
    "fit_friction",
    "fit_torque_constant",
    "model_torque_n_m",
    "static_poses",
    "sweep_corners",
]

FloatArray = NDArray[np.float64]

MIN_GRAVITY_CURRENT_STEPS = 10.0
"""Smallest largest-current at the static poses, in steps of the servo's current
resolution, for a torque constant to be fitted: below it the reading's rounding alone
makes the fit a few percent off (too little gravity torque at the poses)."""
MAX_KT_RELATIVE_ERROR = 0.02
"""Largest standard error of a fitted torque constant, relative to it [-]."""
MIN_SWEEP_SAMPLES = 20
"""Fewest constant-speed samples per direction for a friction fit."""
MIN_SWEEP_RATE_RAD_S = 0.1
"""Slowest joint rate [rad/s] a sweep sample counts as moving at."""
COULOMB_SIGNIFICANCE = 3.0
"""Standard errors by which a Coulomb friction estimate must exceed 0 to be kept."""
MAX_FRICTION_RELATIVE_ERROR = 0.25
"""Largest uncertainty of the fitted friction at the fastest sweep, relative to the
friction there (or to one current step, when larger) [-]."""


def static_poses(
    limits_rad: Sequence[tuple[float, float]], levels: int = 4, margin: float = 0.1
) -> list[tuple[float, float]]:
    """Joint angles (eta1, eta2) [rad] of the static poses: a ``levels`` x ``levels`` grid
    within each joint's limits less ``margin`` of its range at both ends, visited as a
    serpentine (eta2 up, then down at the next eta1), so each eta2 level is approached
    from both sides."""
    if len(limits_rad) != 2:
        raise ValueError(f"the arm has 2 joints, got limits for {len(limits_rad)}")
    if levels < 2 or not 0.0 <= margin < 0.5:
        raise ValueError(f"need levels >= 2 and margin in [0, 0.5), got {levels}, {margin}")
    grids = [np.linspace(*_inside(low, high, margin), levels) for low, high in limits_rad]
    poses: list[tuple[float, float]] = []
    for k, eta1 in enumerate(grids[0]):
        column = grids[1] if k % 2 == 0 else grids[1][::-1]
        poses.extend((float(eta1), float(eta2)) for eta2 in column)
    return poses


def sweep_corners(
    limits_rad: Sequence[tuple[float, float]], margin: float = 0.1
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Ends (low, high) [rad] of the sweeps: every joint from its lower limit to its upper
    one, less ``margin`` of its range at both ends."""
    inside = [_inside(low, high, margin) for low, high in limits_rad]
    return tuple(low for low, _ in inside), tuple(high for _, high in inside)


def _inside(low: float, high: float, margin: float) -> tuple[float, float]:
    span = high - low
    return low + margin * span, high - margin * span


def model_torque_n_m(
    model: ManipulatorModel,
    theta: ArrayLike,
    eta_rad: ArrayLike,
    eta_dot_rad_s: ArrayLike,
    tilt_rad: ArrayLike | None = None,
) -> FloatArray:
    """Joint torques [N m] the model needs to hold or move the arm at constant joint speed,
    ``(G(q) + C(q, q_dot) q_dot)`` on the joint rows, the vehicle still at the origin, level
    or at roll and pitch ``tilt_rad`` [rad]; ``eta_rad``, ``eta_dot_rad_s`` (and
    ``tilt_rad``) of shape (n, 2) give shape (n, 2)."""
    eta = np.atleast_2d(np.asarray(eta_rad, dtype=np.float64))
    eta_dot = np.atleast_2d(np.asarray(eta_dot_rad_s, dtype=np.float64))
    tilt = np.zeros_like(eta) if tilt_rad is None else np.atleast_2d(np.asarray(tilt_rad, float))
    out = np.empty_like(eta)
    q, q_dot = np.zeros(N_Q), np.zeros(N_Q)
    for k in range(eta.shape[0]):
        q[TILT], q[JOINTS], q_dot[JOINTS] = tilt[k], eta[k], eta_dot[k]
        terms = model.terms(q, q_dot)
        out[k] = (terms.gravity(theta) + terms.coriolis_matrix(theta) @ q_dot)[JOINTS]
    return out


@dataclass(frozen=True)
class TorqueConstantFit:
    """One joint's torque constant from the static poses.

    Attributes
    ----------
    torque_constant_n_m_per_a
        Fitted Kt [N m/A] (NaN when there is nothing to fit).
    relative_standard_error
        Standard error of Kt over Kt [-], the residuals' spread floored at the current
        rounding's (one step / sqrt(12)).
    residual_rms_n_m
        RMS of ``Kt i - tau`` over the poses [N m].
    max_gravity_torque_n_m
        Largest ``|tau|`` at the poses [N m].
    poses
        Number of poses.
    problem
        Why the fit cannot be trusted, or None.
    """

    torque_constant_n_m_per_a: float
    relative_standard_error: float
    residual_rms_n_m: float
    max_gravity_torque_n_m: float
    poses: int
    problem: str | None


def fit_torque_constant(
    torque_n_m: ArrayLike, current_a: ArrayLike, current_resolution_a: float
) -> TorqueConstantFit:
    """Least squares ``i = tau / Kt`` over static poses (module docstring, step 1).

    Parameters
    ----------
    torque_n_m : array_like, shape (n,)
        Model torque ``tau`` of the joint at each pose [N m].
    current_a : array_like, shape (n,)
        Present current at each pose [A], signed as the joint.
    current_resolution_a
        One step of the servo's current reading [A] (2.69 mA for an XM430).
    """
    tau = np.asarray(torque_n_m, dtype=np.float64)
    i = np.asarray(current_a, dtype=np.float64)
    n = tau.size
    max_tau = float(np.max(np.abs(tau))) if n else 0.0
    steps = float(np.max(np.abs(i))) / current_resolution_a if n else 0.0
    if n < 4:
        return TorqueConstantFit(math.nan, math.inf, math.nan, max_tau, n, f"{n} poses (< 4)")
    tau_sq = float(tau @ tau)
    if steps < MIN_GRAVITY_CURRENT_STEPS or tau_sq == 0.0:
        return TorqueConstantFit(
            math.nan,
            math.inf,
            math.nan,
            max_tau,
            n,
            f"too little gravity torque at the poses: the largest current is {steps:.1f} "
            f"steps of the reading (< {MIN_GRAVITY_CURRENT_STEPS:g}), largest model torque "
            f"{max_tau:.3f} N m",
        )
    slope = float(tau @ i) / tau_sq  # 1/Kt [A/(N m)]
    spread = math.sqrt(float(np.sum((i - slope * tau) ** 2)) / (n - 1))
    spread = max(spread, current_resolution_a / math.sqrt(12.0))
    relative = spread / math.sqrt(tau_sq) / abs(slope) if slope else math.inf
    kt = 1.0 / slope if slope else math.nan
    residual = float(np.sqrt(np.mean((kt * i - tau) ** 2))) if slope else math.nan
    problem = None
    if not slope > 0.0:
        problem = (
            "the current does not follow the gravity torque with a positive constant "
            "(a wrong direction, or the model's link masses)"
        )
    elif relative > MAX_KT_RELATIVE_ERROR:
        problem = (
            f"poor fit: Kt uncertain by {100 * relative:.1f} % "
            f"(> {100 * MAX_KT_RELATIVE_ERROR:g} %), residual {residual:.4f} N m"
        )
    return TorqueConstantFit(kt, relative, residual, max_tau, n, problem)


@dataclass(frozen=True)
class FrictionFit:
    """One joint's gearbox friction from the sweeps.

    Attributes
    ----------
    viscous_friction_n_m_s_per_rad
        Fitted b [N m s/rad] (>= 0; NaN when there is nothing to fit).
    coulomb_friction_n_m
        Fitted Fc [N m]: 0 unless the data support it (module docstring).
    viscous_standard_error
        Standard error of b [N m s/rad].
    coulomb_estimate_n_m, coulomb_standard_error
        Fc and its standard error in the fit with both terms [N m], shown when it was
        dropped.
    residual_rms_n_m
        RMS of ``r - b eta_dot - Fc sign(eta_dot)`` [N m].
    samples
        Samples used (moving, both directions).
    problem
        Why the fit cannot be trusted, or None.
    """

    viscous_friction_n_m_s_per_rad: float
    coulomb_friction_n_m: float
    viscous_standard_error: float
    coulomb_estimate_n_m: float
    coulomb_standard_error: float
    residual_rms_n_m: float
    samples: int
    problem: str | None

    @classmethod
    def unfitted(cls, samples: int, problem: str) -> FrictionFit:
        """No fit (NaN values) of ``samples`` samples, for ``problem``."""
        nan = math.nan
        return cls(nan, nan, nan, nan, nan, nan, samples, problem)


def _least_squares(a: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Solution, standard errors and residual RMS of ``a x = y``."""
    x, *_ = np.linalg.lstsq(a, y, rcond=None)
    residual = y - a @ x
    dof = max(1, y.size - a.shape[1])
    variance = float(residual @ residual) / dof
    errors = np.sqrt(variance * np.diag(np.linalg.inv(a.T @ a)))
    return np.asarray(x, dtype=np.float64), errors, float(np.sqrt(np.mean(residual**2)))


def fit_friction(
    rate_rad_s: ArrayLike, friction_torque_n_m: ArrayLike, torque_resolution_n_m: float
) -> FrictionFit:
    """Least squares ``r = b eta_dot + Fc sign(eta_dot)`` over sweep samples (module
    docstring, step 2).

    Parameters
    ----------
    rate_rad_s : array_like, shape (n,)
        Joint rate at each sample [rad/s].
    friction_torque_n_m : array_like, shape (n,)
        ``Kt i - tau`` at each sample [N m].
    torque_resolution_n_m
        One current step times Kt [N m].
    """
    rate = np.asarray(rate_rad_s, dtype=np.float64)
    r = np.asarray(friction_torque_n_m, dtype=np.float64)
    moving = np.abs(rate) >= MIN_SWEEP_RATE_RAD_S
    rate, r = rate[moving], r[moving]
    up, down = int(np.sum(rate > 0)), int(np.sum(rate < 0))
    if min(up, down) < MIN_SWEEP_SAMPLES:
        return FrictionFit.unfitted(
            rate.size,
            f"the joint did not sweep: {up} samples moving up, {down} down "
            f"(< {MIN_SWEEP_SAMPLES} each at >= {MIN_SWEEP_RATE_RAD_S:g} rad/s)",
        )
    speeds = np.abs(rate)
    if speeds.max() < 1.5 * speeds.min():
        return FrictionFit.unfitted(
            rate.size, "sweeps at one speed cannot tell viscous from Coulomb friction"
        )
    both, both_errors, residual = _least_squares(np.column_stack([rate, np.sign(rate)]), r)
    coulomb, coulomb_error = float(both[1]), float(both_errors[1])
    keep = coulomb > COULOMB_SIGNIFICANCE * coulomb_error and coulomb > torque_resolution_n_m / 2
    if keep:
        viscous, viscous_error, kept = float(both[0]), float(both_errors[0]), coulomb
    else:
        alone, alone_errors, residual = _least_squares(rate[:, None], r)
        viscous, viscous_error, kept = float(alone[0]), float(alone_errors[0]), 0.0
    problem = None
    fastest = float(speeds.max())
    if viscous < -2.0 * viscous_error:
        problem = (
            f"negative viscous friction {viscous:.4f} N m s/rad: the current leads the "
            "motion (a wrong direction, or the model's link masses)"
        )
    else:
        uncertainty = viscous_error * fastest + (coulomb_error if keep else 0.0)
        scale = max(abs(viscous) * fastest + kept, torque_resolution_n_m)
        if uncertainty > MAX_FRICTION_RELATIVE_ERROR * scale:
            problem = (
                f"poor fit: friction uncertain by {uncertainty:.4f} N m at {fastest:.2f} "
                f"rad/s (> {100 * MAX_FRICTION_RELATIVE_ERROR:g} % of {scale:.4f} N m)"
            )
    return FrictionFit(
        max(viscous, 0.0),
        kept,
        viscous_error,
        coulomb,
        coulomb_error,
        residual,
        rate.size,
        problem,
    )

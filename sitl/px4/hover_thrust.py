"""PX4's hover thrust estimator (``src/modules/mc_hover_thrust_estimator``), in Python.

:class:`ZeroOrderHoverThrustEkf` is PX4's ``ZeroOrderHoverThrustEkf``: a one-state Kalman
filter on the hover thrust Th (relative thrust that holds altitude) with the measurement
model of the vertical acceleration a_z (up, m/s^2) under the vertical relative thrust T::

    a_z = g T / Th - g,        H = da_z/dTh = -g T / Th^2

The state is constant (process noise HTE_HT_NOISE), a measurement is fused when its
normalized innovation squared passes the gate HTE_ACC_GATE, a low-passed signed test ratio
above 0.2 (measurements rejected one way for a while: a payload was grasped) bumps the state
variance, and the measurement noise is learned from the residuals. Pure: predict / fuse.

:class:`HoverThrustEstimator` is the module around it (``MulticopterHoverThrustEstimator``):
it runs only armed and in the air, reset to MPC_THR_HOVER +- HTE_HT_ERR_INIT while
disarmed, clamps the estimate to MPC_THR_HOVER +- HTE_THR_RANGE, lowers its trust in fast
flight (HTE_VZ_THR, HTE_VXY_THR), and declares the estimate valid once its variance is
below 0.001 (and, the first time, the test ratio passes) for 2 s. The position controller
then flies with it (:class:`~sitl.px4.position_control.PositionController`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["HoverThrustEstimate", "HoverThrustEstimator", "ZeroOrderHoverThrustEkf"]

_ONE_G = 9.80665
"""PX4 CONSTANTS_ONE_G [m/s^2]."""
_NOISE_LEARNING_TIME_CONSTANT_S = 2.0
_LPF_TIME_CONSTANT_S = 1.0
_VALID_VARIANCE = 0.001
_VALID_HYSTERESIS_S = 2.0


class ZeroOrderHoverThrustEkf:
    """PX4's single-state hover thrust filter; see the module docstring.

    Parameters
    ----------
    hover_thrust : float
        Initial estimate [relative thrust].
    hover_thrust_std : float
        Initial 1-sigma uncertainty (HTE_HT_ERR_INIT).
    process_noise_std : float
        Process noise (HTE_HT_NOISE) [relative thrust / s].
    gate : float
        Innovation gate (HTE_ACC_GATE) [standard deviations].
    bounds : tuple of 2 float
        (min, max) of the estimate.
    """

    def __init__(
        self,
        hover_thrust: float,
        hover_thrust_std: float,
        process_noise_std: float,
        gate: float,
        bounds: tuple[float, float] = (0.1, 0.9),
    ) -> None:
        self.bounds = bounds
        self.hover_thrust = min(max(hover_thrust, 0.1), 0.9)
        self.variance = hover_thrust_std * hover_thrust_std
        self.process_variance = process_noise_std * process_noise_std
        self.gate = gate
        self.accel_variance = 5.0
        """Learned measurement noise variance [(m/s^2)^2]."""
        self.accel_variance_scale = 1.0
        self.innovation = 0.0
        self.innovation_variance = 0.0
        self.test_ratio = 0.0
        self._dt = 0.02
        self._residual_lpf = 0.0
        self._signed_ratio_lpf = 0.0

    def predict(self, dt_s: float) -> None:
        """Propagate the variance over ``dt_s`` [s] (the state is constant)."""
        self.variance += self.process_variance * dt_s * dt_s
        self._dt = dt_s

    def fuse(self, accel_up_m_s2: float, thrust_up: float) -> None:
        """Fuse one vertical acceleration [m/s^2, up] measured under vertical relative
        thrust ``thrust_up``."""
        h = -_ONE_G * thrust_up / (self.hover_thrust * self.hover_thrust)
        r = self.accel_variance * self.accel_variance_scale
        innov_var = max(h * self.variance * h + r, r)
        innov = accel_up_m_s2 - self._predicted(thrust_up)
        gain = self.variance * h / innov_var
        ratio = innov * innov / (self.gate * self.gate * innov_var)
        residual = innov
        if ratio < 1.0:
            lo, hi = self.bounds
            self.hover_thrust = min(max(self.hover_thrust + gain * innov, lo), hi)
            self.variance = min(max((1.0 - gain * h) * self.variance, 1e-10), 1.0)
            residual = accel_up_m_s2 - self._predicted(thrust_up)
        elif abs(self._signed_ratio_lpf) > 0.2:
            self.variance += 1e3 * self.process_variance * self._dt
        alpha = self._dt / (_LPF_TIME_CONSTANT_S + self._dt)
        signed = math.copysign(min(ratio, 1.0), innov)
        self._residual_lpf = (1.0 - alpha) * self._residual_lpf + alpha * residual
        self._signed_ratio_lpf = (1.0 - alpha) * self._signed_ratio_lpf + alpha * signed
        beta = self._dt / (_NOISE_LEARNING_TIME_CONSTANT_S + self._dt)
        unbiased = residual - self._residual_lpf
        learned = (1.0 - beta) * self.accel_variance + beta * (
            unbiased * unbiased + h * self.variance * h
        )
        self.accel_variance = min(max(learned, 1.0), 400.0)
        self.innovation, self.innovation_variance, self.test_ratio = innov, innov_var, ratio

    def _predicted(self, thrust_up: float) -> float:
        return _ONE_G * thrust_up / self.hover_thrust - _ONE_G


@dataclass(frozen=True)
class HoverThrustEstimate:
    """What the estimator publishes (PX4 ``hover_thrust_estimate``)."""

    hover_thrust: float
    """Relative thrust that hovers [-]."""
    variance: float
    """Its variance [-^2]."""
    valid: bool
    """The position controller may use it."""


class HoverThrustEstimator:
    """PX4's ``mc_hover_thrust_estimator`` module around :class:`ZeroOrderHoverThrustEkf`.

    Parameters
    ----------
    params : Px4Params-like mapping
        Read at every update: MPC_THR_HOVER and the HTE_* parameters.
    """

    def __init__(self, params) -> None:
        self._params = params
        self._valid = False
        self._valid_candidate_since: float | None = None
        self._ekf = self._fresh()

    def _fresh(self) -> ZeroOrderHoverThrustEkf:
        p = self._params
        return ZeroOrderHoverThrustEkf(
            p["MPC_THR_HOVER"], p["HTE_HT_ERR_INIT"], p["HTE_HT_NOISE"], p["HTE_ACC_GATE"]
        )

    @property
    def estimate(self) -> HoverThrustEstimate:
        """The current estimate."""
        return HoverThrustEstimate(self._ekf.hover_thrust, self._ekf.variance, self._valid)

    def reset(self) -> None:
        """Back to MPC_THR_HOVER (PX4 does this while disarmed)."""
        self._ekf = self._fresh()
        self._valid = False
        self._valid_candidate_since = None

    def update(
        self,
        now_s: float,
        dt_s: float,
        accel_up_m_s2: float,
        thrust_up: float,
        velocity_enu_m_s: tuple[float, float, float],
    ) -> HoverThrustEstimate:
        """One estimator step in the air (armed, not landed, above 1 m): the estimate
        position step ``dt_s`` [s] apart, the vertical acceleration [m/s^2, up] and the
        vertical relative thrust of the position controller's setpoint."""
        p = self._params
        ekf = self._ekf
        hover = p["MPC_THR_HOVER"]
        spread = p["HTE_THR_RANGE"]
        ekf.bounds = (min(max(hover - spread, 0.0), 0.8), min(max(hover + spread, 0.2), 0.9))
        ekf.process_variance = p["HTE_HT_NOISE"] ** 2
        ekf.gate = p["HTE_ACC_GATE"]
        if not 0.001 < dt_s < 1.0:
            return self.estimate
        vx, vy, vz = velocity_enu_m_s
        scale_z = max(abs(vz) - p["HTE_VZ_THR"] + 1.0, 1.0)
        scale_xy = max(math.hypot(vx, vy) - p["HTE_VXY_THR"] + 1.0, 1.0)
        scale = max(scale_xy, scale_z)
        ekf.accel_variance_scale = scale * scale
        ekf.predict(dt_s)
        ekf.fuse(accel_up_m_s2, thrust_up)
        candidate = ekf.variance < _VALID_VARIANCE and (self._valid or ekf.test_ratio < 1.0)
        if not candidate:
            self._valid_candidate_since = None
            self._valid = False
        else:
            if self._valid_candidate_since is None:
                self._valid_candidate_since = now_s
            self._valid = self._valid or now_s - self._valid_candidate_since >= _VALID_HYSTERESIS_S
        return self.estimate

    def invalidate(self) -> None:
        """Not in the air: the estimate stays but is no longer valid (PX4)."""
        self._valid = False
        self._valid_candidate_since = None

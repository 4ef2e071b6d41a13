"""What the simulated autopilot knows of its own state: an EKF2-like estimate of the truth.

Stands in for PX4's EKF2, as measured on the real PX4 SITL build (v1.17.0-alpha1):

- **output grid**: one estimate per two IMU samples, i.e. every 8 ms with IMU_INTEG_RATE
  250 Hz (125 Hz), each stamped with the IMU sample time it was computed at (whole
  multiples of 4000 us: ODOMETRY.time_usec); between outputs the last one is held;
- **errors**: position and velocity errors are one smooth process per axis: a first-order
  Gauss-Markov offset (standard deviation ``sigma``, correlation time ``tau``) seen
  through a first-order lag ``smoothing_s``, whose derivative is the velocity error (the
  EKF's velocity is smooth and consistent with its position). Attitude errors are
  Gauss-Markov angles about the body axes. The body rate is the gyro
  (:class:`~sitl.vehicle.sensors.GyroSensor`, scenario ``[sensors]``); the accelerometer reads the
  truth specific force;
- **two aiding modes** (:data:`ERROR_MODELS`): ``"mocap"``, EKF2 fusing external vision
  alone (motion capture indoors, the paper's lab; :func:`sitl.px4_sitl.mocap.mocap_parameters`):
  millimetre errors, positions in the motion
  capture's frame, which is the world's; ``"gps"``, EKF2 fusing GPS and baro (SIH
  outdoors): positions from where the estimator started (the vehicle at boot, at rest on
  the ground: local origin), 0.2-0.3 m off at rest after boot, the height wandering by
  up to a metre during a flight;
- **reported quality** (:class:`~sitl.px4.measurement.EstimatorReport`): the variances
  of ODOMETRY and the ESTIMATOR_STATUS test ratios EKF2 reported in each mode, and its
  reset counter after boot.

Nothing here reaches the companion except through MAVLink. Random numbers come only from
the seeded generator passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from companion.coordinates import ATTITUDE, POSITION
from sitl.physics.frames import quaternion_from_euler
from sitl.px4.measurement import EstimatorReport, VehicleMeasurement
from sitl.scenario import Scenario
from sitl.vehicle.sensors import GyroSensor
from sitl.vehicle.world import World

__all__ = ["ERROR_MODELS", "EstimateErrorModel", "Navigation", "NavigationMode"]

NavigationMode = Literal["mocap", "gps"]


@dataclass(frozen=True)
class EstimateErrorModel:
    """Size of the estimator's errors in one aiding mode, and what it reports.

    Attributes
    ----------
    horizontal_std_m, vertical_std_m : float
        Standard deviation of the Gauss-Markov position offset per horizontal axis and
        of the height [m].
    boot_std_m : float
        Standard deviation of the offset at boot, per axis [m] (the offset then wanders
        towards its stationary size).
    horizontal_tau_s, vertical_tau_s : float
        Its correlation times [s].
    smoothing_s : float
        Lag through which the offset becomes the position error [s]; the velocity error
        is the offset's rate.
    tilt_std_rad, yaw_std_rad : float
        Standard deviation of the roll / pitch and of the yaw error [rad].
    attitude_tau_s : float
        Their correlation time [s].
    report : EstimatorReport
        Variances, test ratios and boot reset counter EKF2 reported in this mode.
    """

    horizontal_std_m: float
    vertical_std_m: float
    boot_std_m: float
    horizontal_tau_s: float
    vertical_tau_s: float
    smoothing_s: float
    tilt_std_rad: float
    yaw_std_rad: float
    attitude_tau_s: float
    report: EstimatorReport


ERROR_MODELS: dict[str, EstimateErrorModel] = {
    "mocap": EstimateErrorModel(
        horizontal_std_m=0.004,
        vertical_std_m=0.003,
        boot_std_m=0.003,
        horizontal_tau_s=1.0,
        vertical_tau_s=1.0,
        smoothing_s=0.2,
        tilt_std_rad=0.003,
        yaw_std_rad=0.003,
        attitude_tau_s=2.0,
        # measured: EKF2 on vision alone (sitl.px4_sitl.mocap's parameters, 100 Hz poses),
        # SIH at rest
        report=EstimatorReport(
            aiding="vision",
            position_variance_m2=(1.2e-5, 1.1e-5),
            velocity_variance_m2_s2=(3.6e-4, 2.9e-4),
            attitude_variance_rad2=(4.1e-4, 4.1e-4, 2.1e-4),
            reset_counter=9,
            test_ratios=(math.nan, 0.0165, 0.0152, 0.0026, math.nan),
        ),
    ),
    "gps": EstimateErrorModel(
        horizontal_std_m=0.2,
        vertical_std_m=0.6,
        boot_std_m=0.2,
        horizontal_tau_s=60.0,
        vertical_tau_s=30.0,
        smoothing_s=2.0,
        tilt_std_rad=0.005,
        yaw_std_rad=0.02,
        attitude_tau_s=10.0,
        # measured: EKF2 fusing SIH GPS and baro, at rest after boot
        report=EstimatorReport(
            aiding="gps",
            position_variance_m2=(0.041, 0.0024),
            velocity_variance_m2_s2=(0.0087, 0.001),
            attitude_variance_rad2=(3.9e-4, 3.9e-4, 0.035),
            reset_counter=11,
            test_ratios=(0.039, 0.043, 0.0083, 0.050, 0.0048),
        ),
    ),
}
"""The estimator's error model per aiding mode (see the module docstring)."""

_EXACT = EstimateErrorModel(0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 1.0, EstimatorReport())


class _SmoothOffset:
    """Gauss-Markov offsets seen through first-order lags: position and attitude errors.

    One process per component: ``rough`` is the exactly discretized Gauss-Markov process
    (stationary standard deviation ``std``, correlation time ``tau``), ``smooth`` follows
    it through its group's lag (``smoothing_s`` [s]: the position's, then the attitude's); the
    error is ``smooth`` and its rate ``(rough - smooth) / smoothing_s``. Both start at a
    draw of standard deviation ``boot_std`` (the offset after boot), which then wanders
    towards the stationary ``std``. The components are the position's three [m, ENU]
    then the attitude's three Euler angles [rad]; each step draws all six noises in one
    block, the position's first (the order of one draw per group).
    """

    def __init__(
        self,
        rng: np.random.Generator,
        std: np.ndarray,
        tau_s: np.ndarray,
        smoothing_s: tuple[float, float],
        boot_std: np.ndarray,
    ) -> None:
        self._rng = rng
        self._std = std
        self._tau = tau_s
        self._smoothing_s = smoothing_s
        self._factors: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None = None
        self.rough = rng.standard_normal(std.size) * boot_std
        self.smooth = self.rough.copy()

    def step(self, dt_s: float) -> None:
        factors = self._factors
        if factors is None or factors[0] != dt_s:  # computed once for the output period
            a = np.exp(-dt_s / self._tau)
            gain = np.repeat([1.0 - math.exp(-dt_s / s) for s in self._smoothing_s], 3)
            factors = self._factors = (dt_s, a, self._std * np.sqrt(1.0 - a * a), gain)
        _, a, noise, gain = factors
        self.rough = a * self.rough + noise * self._rng.standard_normal(self._std.size)
        self.smooth += gain * (self.rough - self.smooth)

    @property
    def position_rate(self) -> np.ndarray:
        """Rate of the position error [m/s, ENU]."""
        return (self.rough[:3] - self.smooth[:3]) / self._smoothing_s[0]


class Navigation:
    """The autopilot's estimate of the vehicle state; see the module docstring.

    Parameters
    ----------
    scenario
        Gyro rate and noise (``[sensors]``).
    rng
        Seeded generator, the only source of randomness.
    mode
        Aiding: ``"mocap"`` (external vision) or ``"gps"`` (GPS and baro).
    noise
        ``False`` for an exact estimate (still on the estimator's output grid).
    imu_rate_hz
        IMU_INTEG_RATE: the IMU sample grid [Hz]; the estimator outputs every second
        sample.
    """

    def __init__(
        self,
        scenario: Scenario,
        rng: np.random.Generator,
        *,
        mode: NavigationMode = "mocap",
        noise: bool = True,
        imu_rate_hz: float = 250.0,
    ) -> None:
        if mode not in ERROR_MODELS:
            raise ValueError(f"navigation mode must be one of {sorted(ERROR_MODELS)}, got {mode!r}")
        if not (math.isfinite(imu_rate_hz) and imu_rate_hz > 0.0):
            raise ValueError(f"imu_rate_hz must be positive, got {imu_rate_hz!r}")
        self.mode: NavigationMode = mode
        self.report = ERROR_MODELS[mode].report
        model = ERROR_MODELS[mode] if noise else _EXACT
        self._noise = noise
        self._imu_period_us = round(1e6 / imu_rate_hz)
        self._output_period_us = 2 * self._imu_period_us
        self.output_period_s = self._output_period_us * 1e-6
        """Time between two estimates [s] (8 ms at 250 Hz)."""
        h, v = model.horizontal_std_m, model.vertical_std_m
        tilt, yaw = model.tilt_std_rad, model.yaw_std_rad
        htau, vtau, atau = model.horizontal_tau_s, model.vertical_tau_s, model.attitude_tau_s
        boot = model.boot_std_m
        self._offset = _SmoothOffset(
            rng,
            np.array([h, h, v, tilt, tilt, yaw]),
            np.array([htau, htau, vtau, atau, atau, atau]),
            (model.smoothing_s, 1e-3),
            np.array([boot, boot, boot, tilt, tilt, yaw]),
        )
        s = scenario.sensors
        self._gyro = GyroSensor(rng, rate_std_rad_s=s.gyro_std_rad_s, rate_hz=s.gyro_rate_hz)
        self._last: VehicleMeasurement | None = None
        self._last_output_us: int | None = None
        self._omega: np.ndarray | None = None
        self.local_origin_enu_m: np.ndarray | None = None if mode == "gps" else np.zeros(3)
        """Where the local frame's origin is in the world [m, ENU]: the world origin with
        motion capture, the vehicle's position at the first estimate with GPS."""

    @property
    def next_output_us(self) -> int | None:
        """Simulation time [us] of the next estimator output: before it, :meth:`measure`
        returns the last estimate (None before the first)."""
        last = self._last_output_us
        return None if last is None else last + self._output_period_us

    def measure(self, world: World) -> VehicleMeasurement:
        """The estimate at the world's current time: a new one when an estimator output
        time has passed since the last, else the last one (the same object)."""
        now_us = round(world.time_s * 1e6)
        output_us = now_us - now_us % self._output_period_us
        if self._last is not None and output_us == self._last_output_us:
            return self._last
        state = world.state
        if self._noise:
            gyro = self._gyro.sample(state.time_s, state.omega_body_rad_s)
            if gyro is not None:
                self._omega = gyro.omega_body_rad_s
        dt_s = (
            self.output_period_s
            if self._last_output_us is None
            else (output_us - self._last_output_us) * 1e-6
        )
        self._last_output_us = output_us
        offset = self._offset
        offset.step(dt_s)
        q = state.q
        if self.local_origin_enu_m is None:
            self.local_origin_enu_m = np.array(q[POSITION])
        smooth = offset.smooth
        position = q[POSITION] - self.local_origin_enu_m + smooth[:3]
        velocity = state.q_dot[POSITION] + offset.position_rate
        if self._noise:
            angles = q[ATTITUDE] + smooth[3:]
            quaternion = quaternion_from_euler(*angles.tolist())
        else:
            quaternion = state.quaternion_wxyz
        omega = self._omega if self._noise and self._omega is not None else state.omega_body_rad_s
        battery = world.battery
        self._last = VehicleMeasurement(
            time_s=state.time_s,
            position_enu_m=position,
            velocity_enu_m_s=velocity,
            quaternion_enu_flu_wxyz=quaternion,
            omega_flu_rad_s=omega,
            specific_force_flu_m_s2=world.specific_force_flu_m_s2(),
            on_ground=world.on_ground,
            battery_voltage_v=battery.voltage_v,
            battery_current_a=battery.current_a,
            battery_remaining=battery.remaining,
            estimate_time_us=output_us,
            estimator=self.report,
        )
        return self._last

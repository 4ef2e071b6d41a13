"""Sensor models: truth in, noisy, rate-limited and delayed measurements out.

Used by the offline simulator and the SITL vehicle. Each sensor has

- an update rate ``rate_hz``: samples are published at ``start_s + k / rate_hz``
  (k = 0, 1, ...), at the first call of :meth:`sample` at or after that time;
- a latency ``latency_s``: the measurement published at time t reflects the truth at
  t - latency_s. The sensor keeps a small delay buffer of the truths passed to
  :meth:`sample`, keyed on the simulation time given by the caller (there is no clock);
  the truth used is the latest one at or before t - latency_s (zero-order hold, exact
  when the caller's step divides the latency);
- additive zero-mean Gaussian noise with a standard deviation per channel (unit in the
  parameter name), drawn from the seeded :class:`numpy.random.Generator` passed in.

Call ``sensor.sample(t_s, truth)`` once per simulation step with non-decreasing
``t_s``; it returns a frozen measurement when one is published at ``t_s`` and ``None``
otherwise (also while the delay buffer does not yet reach back ``latency_s``). If the
caller steps more coarsely than the sensor period, at most one sample is published per
call and the missed ones are dropped.

Conventions (DESIGN.md section 2): q = [x, y, z, phi, theta, psi, eta1, eta2], ENU world,
FLU body, Euler ZYX R = Rz(psi) Ry(theta) Rx(phi), SI units. Euler-angle noise is added
to the angles and the result is wrapped to [-pi, pi), so a yaw near +-pi stays in range.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.coordinates import ATTITUDE, N_Q

__all__ = [
    "GyroMeasurement",
    "GyroSensor",
    "JointEncoderMeasurement",
    "JointEncoders",
    "PoseMeasurement",
    "PoseSensor",
    "StateMeasurement",
    "StateSensor",
    "wrap_angle",
]

FloatArray = NDArray[np.float64]


EULER_ROWS = tuple(range(N_Q)[ATTITUDE])
"""Rows of q holding the Euler angles phi, theta, psi."""

_TIME_TOL_S = 1e-9
"""Tolerance on simulation times (s): absorbs rounding in ``t = k * dt`` step loops."""


def wrap_angle(angle_rad: ArrayLike) -> FloatArray:
    """Wrap angles to [-pi, pi).

    Parameters
    ----------
    angle_rad : array_like
        Angles [rad], any shape.

    Returns
    -------
    ndarray
        The same angles [rad] in [-pi, pi), same shape; values already in range are
        returned unchanged (bit for bit).
    """
    a = np.asarray(angle_rad, dtype=np.float64)
    inside = (a >= -math.pi) & (a < math.pi)
    wrapped = np.mod(a + math.pi, 2.0 * math.pi) - math.pi
    wrapped = np.where(wrapped >= math.pi, wrapped - 2.0 * math.pi, wrapped)  # rounding
    return np.where(inside, a, wrapped)


def _readonly(a: FloatArray) -> FloatArray:
    a.flags.writeable = False
    return a


def _std_vector(std: ArrayLike, size: int, name: str) -> FloatArray:
    try:
        s = np.broadcast_to(np.asarray(std, dtype=np.float64), (size,)).copy()
    except ValueError:
        raise ValueError(f"{name} must be a scalar or have shape ({size},), got {std!r}") from None
    if not np.all(np.isfinite(s)) or np.any(s < 0.0):
        raise ValueError(f"{name} must be finite and >= 0, got {std!r}")
    return s


class _Sensor:
    """Shared policy: sample schedule, delay buffer, Gaussian noise, angle wrapping.

    Subclasses give the truth size, the rows to wrap, and build their measurement type
    from :meth:`_sample_array`.
    """

    def __init__(
        self,
        size: int,
        std: FloatArray,
        rate_hz: float,
        latency_s: float,
        start_s: float,
        rng: np.random.Generator,
        wrap_rows: tuple[int, ...] = (),
    ) -> None:
        if not isinstance(rng, np.random.Generator):
            raise TypeError("rng must be a numpy.random.Generator (seeded by the caller)")
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate_hz must be finite and > 0, got {rate_hz!r}")
        if not (math.isfinite(latency_s) and latency_s >= 0.0):
            raise ValueError(f"latency_s must be finite and >= 0, got {latency_s!r}")
        if not math.isfinite(start_s):
            raise ValueError(f"start_s must be finite, got {start_s!r}")
        self._size = size
        self._std = std
        self._rate_hz = float(rate_hz)
        self._latency_s = float(latency_s)
        self._start_s = float(start_s)
        self._rng = rng
        self._wrap_rows = np.asarray(wrap_rows, dtype=np.intp)
        self._next_index = 0
        self._last_t_s = -math.inf
        self._buffer: deque[tuple[float, FloatArray]] = deque()

    @property
    def rate_hz(self) -> float:
        """Publication rate [Hz]."""
        return self._rate_hz

    @property
    def latency_s(self) -> float:
        """Delay between the truth a measurement reflects and its publication [s]."""
        return self._latency_s

    def _sample_array(self, t_s: float, truth: ArrayLike) -> tuple[float, FloatArray] | None:
        """Record ``truth`` at ``t_s``; return ``(stamp_s, noisy)`` when a sample is due."""
        t_s = float(t_s)
        if not math.isfinite(t_s):
            raise ValueError(f"t_s must be finite, got {t_s!r}")
        if t_s < self._last_t_s:
            raise ValueError(f"time went backwards: t_s={t_s!r} after {self._last_t_s!r}")
        value = np.array(truth, dtype=np.float64)
        if value.shape != (self._size,):
            raise ValueError(f"truth must have shape ({self._size},), got {value.shape}")
        self._last_t_s = t_s
        buf = self._buffer
        buf.append((t_s, value))
        capture_s = t_s - self._latency_s + _TIME_TOL_S
        # Keep only the newest truth at or before the capture time, and everything after.
        while len(buf) > 1 and buf[1][0] <= capture_s:
            buf.popleft()

        index = math.floor((t_s - self._start_s + _TIME_TOL_S) * self._rate_hz)
        if index < self._next_index:
            return None
        self._next_index = index + 1
        stamp_s, delayed = buf[0]
        if stamp_s > capture_s:
            return None  # the buffer does not reach back latency_s yet
        noisy = delayed + self._std * self._rng.standard_normal(self._size)
        if self._wrap_rows.size:
            noisy[self._wrap_rows] = wrap_angle(noisy[self._wrap_rows])
        return stamp_s, noisy


@dataclass(frozen=True, slots=True)
class PoseMeasurement:
    """A motion-capture pose sample (arrays are read-only)."""

    t_s: float
    """Publication time [s] (simulation time)."""
    stamp_s: float
    """Time of the truth this sample reflects [s] (``t_s - latency``)."""
    position_m: FloatArray
    """Vehicle position, shape (3,) [m], world frame ENU."""
    euler_rad: FloatArray
    """Euler angles (phi, theta, psi), shape (3,) [rad], ZYX, each in [-pi, pi)."""


class PoseSensor(_Sensor):
    """Motion capture: vehicle position and attitude (e.g. Vicon, 100 Hz, 1 mm).

    Parameters
    ----------
    rng : numpy.random.Generator
        Seeded generator; the only source of randomness.
    position_std_m : float or array_like, shape (3,)
        Noise standard deviation of x, y, z [m].
    attitude_std_rad : float or array_like, shape (3,)
        Noise standard deviation of phi, theta, psi [rad].
    rate_hz : float
        Publication rate [Hz].
    latency_s : float
        Delay of the published sample behind the truth [s], >= 0.
    start_s : float
        Time of the first scheduled sample [s] (phase of the schedule).
    """

    def __init__(
        self,
        rng: np.random.Generator,
        *,
        position_std_m: ArrayLike = 1e-3,
        attitude_std_rad: ArrayLike = 1e-3,
        rate_hz: float = 100.0,
        latency_s: float = 0.0,
        start_s: float = 0.0,
    ) -> None:
        std = np.concatenate(
            [
                _std_vector(position_std_m, 3, "position_std_m"),
                _std_vector(attitude_std_rad, 3, "attitude_std_rad"),
            ]
        )
        super().__init__(6, std, rate_hz, latency_s, start_s, rng, wrap_rows=(3, 4, 5))

    def sample(self, t_s: float, q: ArrayLike) -> PoseMeasurement | None:
        """Record the truth and return the pose sample published at ``t_s``, if any.

        Parameters
        ----------
        t_s : float
            Simulation time [s], non-decreasing between calls.
        q : array_like, shape (8,)
            True generalized coordinates (m, rad); rows 0-5 are used.

        Returns
        -------
        PoseMeasurement or None
            ``None`` when no sample is published at ``t_s``.
        """
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (N_Q,):
            raise ValueError(f"q must have shape ({N_Q},), got {q.shape}")
        out = self._sample_array(t_s, q[:6])
        if out is None:
            return None
        stamp_s, z = out
        return PoseMeasurement(
            t_s=float(t_s),
            stamp_s=stamp_s,
            position_m=_readonly(z[:3]),
            euler_rad=_readonly(z[3:]),
        )


@dataclass(frozen=True, slots=True)
class GyroMeasurement:
    """A gyroscope sample (array is read-only)."""

    t_s: float
    """Publication time [s] (simulation time)."""
    stamp_s: float
    """Time of the truth this sample reflects [s] (``t_s - latency``)."""
    omega_body_rad_s: FloatArray
    """Body angular velocity, shape (3,) [rad/s], body frame FLU."""


class GyroSensor(_Sensor):
    """Gyroscope: body angular rates with white noise and a constant bias (e.g. 250 Hz).

    Parameters
    ----------
    rng : numpy.random.Generator
        Seeded generator; the only source of randomness.
    rate_std_rad_s : float or array_like, shape (3,)
        Noise standard deviation per body axis [rad/s].
    bias_rad_s : array_like, shape (3,)
        Constant bias added to every sample [rad/s], body frame FLU.
    rate_hz, latency_s, start_s : float
        As for :class:`PoseSensor` [Hz, s, s].
    """

    def __init__(
        self,
        rng: np.random.Generator,
        *,
        rate_std_rad_s: ArrayLike = 3e-3,
        bias_rad_s: ArrayLike = (0.0, 0.0, 0.0),
        rate_hz: float = 250.0,
        latency_s: float = 0.0,
        start_s: float = 0.0,
    ) -> None:
        std = _std_vector(rate_std_rad_s, 3, "rate_std_rad_s")
        bias = np.asarray(bias_rad_s, dtype=np.float64)
        if bias.shape != (3,) or not np.all(np.isfinite(bias)):
            raise ValueError(f"bias_rad_s must be 3 finite values, got {bias_rad_s!r}")
        self._bias = bias.copy()
        super().__init__(3, std, rate_hz, latency_s, start_s, rng)

    def sample(self, t_s: float, omega_body_rad_s: ArrayLike) -> GyroMeasurement | None:
        """Record the truth and return the gyro sample published at ``t_s``, if any.

        Parameters
        ----------
        t_s : float
            Simulation time [s], non-decreasing between calls.
        omega_body_rad_s : array_like, shape (3,)
            True body angular velocity [rad/s], body frame FLU.

        Returns
        -------
        GyroMeasurement or None
            ``None`` when no sample is published at ``t_s``.
        """
        out = self._sample_array(t_s, omega_body_rad_s)
        if out is None:
            return None
        stamp_s, z = out
        return GyroMeasurement(
            t_s=float(t_s), stamp_s=stamp_s, omega_body_rad_s=_readonly(z + self._bias)
        )


@dataclass(frozen=True, slots=True)
class JointEncoderMeasurement:
    """A joint-encoder sample (array is read-only)."""

    t_s: float
    """Publication time [s] (simulation time)."""
    stamp_s: float
    """Time of the truth this sample reflects [s] (``t_s - latency``)."""
    eta_rad: FloatArray
    """Joint angles (eta1, eta2, ...), shape (n_joints,) [rad]."""


class JointEncoders(_Sensor):
    """Servo position encoders, optionally quantized (e.g. 100 Hz, 4096 ticks/rev).

    Parameters
    ----------
    rng : numpy.random.Generator
        Seeded generator; the only source of randomness.
    n_joints : int
        Number of joints.
    angle_std_rad : float or array_like, shape (n_joints,)
        Noise standard deviation per joint [rad], added before quantization.
    ticks_per_rev : int or None
        Encoder resolution [ticks/rev]; the reading is rounded to the nearest multiple
        of ``2 pi / ticks_per_rev`` rad. ``None``: no quantization.
    rate_hz, latency_s, start_s : float
        As for :class:`PoseSensor` [Hz, s, s].
    """

    def __init__(
        self,
        rng: np.random.Generator,
        *,
        n_joints: int = 2,
        angle_std_rad: ArrayLike = 0.0,
        ticks_per_rev: int | None = 4096,
        rate_hz: float = 100.0,
        latency_s: float = 0.0,
        start_s: float = 0.0,
    ) -> None:
        if n_joints < 1:
            raise ValueError(f"n_joints must be >= 1, got {n_joints!r}")
        if ticks_per_rev is not None and ticks_per_rev < 1:
            raise ValueError(f"ticks_per_rev must be >= 1 or None, got {ticks_per_rev!r}")
        self._resolution_rad = None if ticks_per_rev is None else 2.0 * math.pi / ticks_per_rev
        std = _std_vector(angle_std_rad, n_joints, "angle_std_rad")
        super().__init__(n_joints, std, rate_hz, latency_s, start_s, rng)

    @property
    def resolution_rad(self) -> float | None:
        """Quantization step [rad], or ``None`` without quantization."""
        return self._resolution_rad

    def sample(self, t_s: float, eta_rad: ArrayLike) -> JointEncoderMeasurement | None:
        """Record the truth and return the encoder sample published at ``t_s``, if any.

        Parameters
        ----------
        t_s : float
            Simulation time [s], non-decreasing between calls.
        eta_rad : array_like, shape (n_joints,)
            True joint angles [rad].

        Returns
        -------
        JointEncoderMeasurement or None
            ``None`` when no sample is published at ``t_s``.
        """
        out = self._sample_array(t_s, eta_rad)
        if out is None:
            return None
        stamp_s, z = out
        if self._resolution_rad is not None:
            z = np.round(z / self._resolution_rad) * self._resolution_rad
        return JointEncoderMeasurement(t_s=float(t_s), stamp_s=stamp_s, eta_rad=_readonly(z))


@dataclass(frozen=True, slots=True)
class StateMeasurement:
    """A sample of all generalized coordinates (array is read-only)."""

    t_s: float
    """Publication time [s] (simulation time)."""
    stamp_s: float
    """Time of the truth this sample reflects [s] (``t_s - latency``)."""
    q: FloatArray
    """Generalized coordinates [x, y, z, phi, theta, psi, eta1, eta2], shape (8,):
    position [m] world ENU, Euler angles ZYX [rad] in [-pi, pi), joint angles [rad]."""


class StateSensor(_Sensor):
    """The whole of q at one rate with per-row noise (e.g. the paper's 40 Hz state link).

    A convenience for the offline simulator: it stands for motion capture plus encoders
    relayed over one link (paper section V: states sent to the vehicle at 40 Hz).

    Parameters
    ----------
    rng : numpy.random.Generator
        Seeded generator; the only source of randomness.
    q_std : float or array_like, shape (8,)
        Noise standard deviation per row of q: [m] for rows 0-2, [rad] for rows 3-7.
    rate_hz, latency_s, start_s : float
        As for :class:`PoseSensor` [Hz, s, s].
    """

    def __init__(
        self,
        rng: np.random.Generator,
        *,
        q_std: ArrayLike = 1e-3,
        rate_hz: float = 40.0,
        latency_s: float = 0.0,
        start_s: float = 0.0,
    ) -> None:
        std = _std_vector(q_std, N_Q, "q_std")
        super().__init__(N_Q, std, rate_hz, latency_s, start_s, rng, wrap_rows=EULER_ROWS)

    def sample(self, t_s: float, q: ArrayLike) -> StateMeasurement | None:
        """Record the truth and return the sample of q published at ``t_s``, if any.

        Parameters
        ----------
        t_s : float
            Simulation time [s], non-decreasing between calls.
        q : array_like, shape (8,)
            True generalized coordinates (m, rad).

        Returns
        -------
        StateMeasurement or None
            ``None`` when no sample is published at ``t_s``.
        """
        out = self._sample_array(t_s, q)
        if out is None:
            return None
        stamp_s, z = out
        return StateMeasurement(t_s=float(t_s), stamp_s=stamp_s, q=_readonly(z))

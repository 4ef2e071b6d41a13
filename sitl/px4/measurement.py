"""What the simulated autopilot knows of its vehicle at one estimator output (from the world).

Frames and units are ours (DESIGN.md section 2): world ENU, body FLU, SI. The conversion
to PX4's NED / FRD happens only when telemetry is encoded, through :mod:`companion.frames`.
The measurement carries what PX4's estimator would know (state estimate and its reported
quality, IMU, battery, ground contact) and nothing of the world's truth that PX4 could not
observe (payload attached, arm parameters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["EstimatorReport", "VehicleMeasurement"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class EstimatorReport:
    """What EKF2 reports about its own estimate (ODOMETRY covariances, ESTIMATOR_STATUS).

    Attributes
    ----------
    aiding : {"vision", "gps"}
        What the estimator fuses for position: external vision (motion capture) or GPS
        and baro.
    position_variance_m2 : tuple of 2 float
        Variance of each horizontal position axis and of the height [m^2].
    velocity_variance_m2_s2 : tuple of 2 float
        The same for the velocity [m^2/s^2].
    attitude_variance_rad2 : tuple of 3 float
        Variances of roll, pitch and yaw [rad^2].
    reset_counter : int
        Count of the estimate's discontinuities (ODOMETRY.reset_counter).
    test_ratios : tuple of 5 float
        ESTIMATOR_STATUS innovation test ratios: velocity, horizontal position, vertical
        position, magnetometer, height above ground (NaN: not fused).
    """

    aiding: str = "vision"
    position_variance_m2: tuple[float, float] = (1.2e-5, 1.1e-5)
    velocity_variance_m2_s2: tuple[float, float] = (3.6e-4, 2.9e-4)
    attitude_variance_rad2: tuple[float, float, float] = (4.1e-4, 4.1e-4, 2.1e-4)
    reset_counter: int = 0
    test_ratios: tuple[float, float, float, float, float] = (
        math.nan, 0.0165, 0.0152, 0.0026, math.nan,
    )  # fmt: skip


@dataclass(frozen=True)
class VehicleMeasurement:
    """The vehicle state as PX4 would estimate it, at one instant.

    Attributes
    ----------
    time_s : float
        Simulation time since boot [s].
    position_enu_m : ndarray, shape (3,)
        Vehicle position in the world (ENU) [m]; the world origin is the geodetic
        reference of :class:`~sitl.px4.geo.GeoReference` and the local NED origin.
    velocity_enu_m_s : ndarray, shape (3,)
        Vehicle velocity in the world (ENU) [m/s].
    quaternion_enu_flu_wxyz : ndarray, shape (4,)
        Attitude, body FLU to world ENU, ``[w, x, y, z]``.
    omega_flu_rad_s : ndarray, shape (3,)
        Body angular velocity in FLU axes [rad/s].
    specific_force_flu_m_s2 : ndarray, shape (3,)
        Accelerometer reading (specific force, ``+g`` up at rest) in FLU axes [m/s^2].
    on_ground : bool
        The world's ground contact is holding the vehicle (PX4's land detector input).
    battery_voltage_v : float
        Battery voltage [V].
    battery_current_a : float
        Battery current [A]; negative when not measured.
    battery_remaining : float
        Remaining charge as a fraction in [0, 1].
    estimate_time_us : int, optional
        The estimator's time of this estimate: the IMU sample time it was computed at
        [us since boot] (ODOMETRY.time_usec); default ``time_s`` in whole microseconds.
    estimator : EstimatorReport
        The estimator's reported quality.

    Raises
    ------
    ValueError
        On arrays of the wrong shape or non-finite values.
    """

    time_s: float
    position_enu_m: FloatArray
    velocity_enu_m_s: FloatArray
    quaternion_enu_flu_wxyz: FloatArray
    omega_flu_rad_s: FloatArray
    specific_force_flu_m_s2: FloatArray
    on_ground: bool
    battery_voltage_v: float = 16.0
    battery_current_a: float = -1.0
    battery_remaining: float = 1.0
    estimate_time_us: int | None = None
    estimator: EstimatorReport = EstimatorReport()

    def __post_init__(self) -> None:
        if not self._set_arrays_fast():
            self._set_arrays()
        for name in ("time_s", "battery_voltage_v", "battery_current_a", "battery_remaining"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value!r}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "on_ground", bool(self.on_ground))
        if self.estimate_time_us is None:
            object.__setattr__(self, "estimate_time_us", round(self.time_s * 1e6))

    def _set_arrays_fast(self) -> bool:
        """One read-only copy of all five vectors, each field a view of its part, when
        they are 1-D float arrays of the right sizes with finite values (the simulator's
        case, every plant step); False (nothing set) otherwise."""
        values = [getattr(self, name) for name, _ in _ARRAYS]
        for value, (_, size) in zip(values, _ARRAYS, strict=True):
            if type(value) is not np.ndarray or value.shape != (size,):
                return False
            if value.dtype != np.float64:
                return False
        flat = np.concatenate(values)
        # the sum of the entries is finite iff every entry is (cheaper than np.isfinite)
        if not math.isfinite(sum(flat.tolist())):
            return False  # the per-field check says which one (or accepts a sum overflow)
        flat.flags.writeable = False
        for (name, _), start, stop in _SLICES:
            object.__setattr__(self, name, flat[start:stop])
        return True

    def _set_arrays(self) -> None:
        for name, size in _ARRAYS:
            arr = np.array(getattr(self, name), dtype=np.float64)
            if arr.ndim != 1:
                arr = arr.reshape(-1)
            # the sum of the entries is finite iff every entry is (cheaper than np.isfinite)
            if arr.shape != (size,) or not math.isfinite(sum(arr.tolist())):
                raise ValueError(f"{name} must be {size} finite values, got {arr!r}")
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)


_ARRAYS = (
    ("position_enu_m", 3),
    ("velocity_enu_m_s", 3),
    ("quaternion_enu_flu_wxyz", 4),
    ("omega_flu_rad_s", 3),
    ("specific_force_flu_m_s2", 3),
)
"""The vector fields and their sizes."""
_SLICES = tuple(
    (field, sum(n for _, n in _ARRAYS[:i]), sum(n for _, n in _ARRAYS[: i + 1]))
    for i, field in enumerate(_ARRAYS)
)

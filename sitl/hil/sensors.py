"""What PX4's sensors read on our simulated vehicle: IMU, magnetometer, barometer, GPS.

Pure: truth in (our frames: world ENU, body FLU, SI units), noisy measurements out, the
noise drawn from the seeded :class:`numpy.random.Generator` passed in; conversion to PX4's
NED / FRD and MAVLink units happens in :mod:`sitl.hil.messages` only. Motion capture is
:class:`sitl.vehicle.sensors.PoseSensor` with the scenario's ``[sensors]`` (rate, latency, noise),
as in the offline simulation.

- **IMU** (:class:`Imu`): the specific force and body rate averaged over one IMU period
  (an IMU's delta velocity and delta angle over its sample interval divided by it), white
  noise: the gyro's from the scenario (``[sensors] gyro_std_rad_s``), the accelerometer's
  :data:`ACCEL_STD_M_S2`.
- **Magnetometer** (:class:`Magnetometer`): the Earth's field at PX4 SITL's home
  (:data:`EARTH_FIELD_NED_GAUSS`: the declination, inclination and strength PX4 main's
  own world magnetic model tables give there, measured on the build) in the body frame,
  white noise :data:`MAG_STD_GAUSS`. The arm's servos disturb nothing.
- **Barometer** (:class:`Barometer`): ISA pressure and temperature at the altitude AMSL,
  white noise :data:`BARO_STD_PA`.
- **GPS** (:class:`GpsReceiver`, grades :data:`GPS_GRADES`): the antenna at the vehicle
  CoM, a first-order Gauss-Markov position error per axis (what wanders over a flight)
  plus white noise, white velocity noise, a latency, at 10 Hz.

Every sensor is exact with ``noise=False`` (the same schedules and latencies).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.frames import enu_from_ned, ned_from_enu
from sitl.px4.geo import GeoReference

__all__ = [
    "ACCEL_STD_M_S2",
    "BARO_STD_PA",
    "EARTH_FIELD_NED_GAUSS",
    "GPS_GRADES",
    "MAG_STD_GAUSS",
    "BaroReading",
    "Barometer",
    "GpsFix",
    "GpsGrade",
    "GpsReceiver",
    "Imu",
    "ImuReading",
    "Magnetometer",
    "isa_pressure_pa",
]

FloatArray = NDArray[np.float64]

ACCEL_STD_M_S2 = 0.02
"""Accelerometer white noise per axis [m/s^2] (assumed: a MEMS IMU's ~70 ug/sqrt(Hz)
density over its bandwidth, 0.008 m/s^2, plus vibration)."""
MAG_STD_GAUSS = 0.005
"""Magnetometer white noise per axis [gauss] (assumed: a few milligauss, ~1 % of the field)."""
BARO_STD_PA = 1.2
"""Barometer white noise [Pa] (datasheet: MS5611 at its finest oversampling, 0.012 mbar
RMS, about 0.1 m of height)."""

_DECLINATION_DEG = 3.4056
_INCLINATION_DEG = 63.1572
_STRENGTH_GAUSS = 0.48239
EARTH_FIELD_NED_GAUSS = (
    _STRENGTH_GAUSS
    * math.cos(math.radians(_INCLINATION_DEG))
    * math.cos(math.radians(_DECLINATION_DEG)),
    _STRENGTH_GAUSS
    * math.cos(math.radians(_INCLINATION_DEG))
    * math.sin(math.radians(_DECLINATION_DEG)),
    _STRENGTH_GAUSS * math.sin(math.radians(_INCLINATION_DEG)),
)
"""The Earth's magnetic field at PX4 SITL's home (47.397742 N, 8.545594 E), world NED
[gauss]: declination 3.4056 deg, inclination 63.1572 deg, strength 0.48239 G (measured: PX4
main's EKF2_MAG_DECL and its estimator_status reference inclination and strength there)."""

_SEA_LEVEL_PA = 101325.0
_SEA_LEVEL_K = 288.15
_LAPSE_K_M = 0.0065
_ISA_EXPONENT = 5.25588


def isa_pressure_pa(altitude_amsl_m: float) -> float:
    """Static pressure of the ISA troposphere at an altitude above mean sea level [Pa]."""
    return _SEA_LEVEL_PA * (1.0 - _LAPSE_K_M * altitude_amsl_m / _SEA_LEVEL_K) ** _ISA_EXPONENT


@dataclass(frozen=True)
class ImuReading:
    """One IMU sample, body FLU."""

    specific_force_flu_m_s2: tuple[float, float, float]
    """What the accelerometer reads: R^T (a - g) [m/s^2]."""
    omega_flu_rad_s: tuple[float, float, float]
    """Body rate [rad/s]."""


class Imu:
    """Accelerometer and gyro with white noise (module docstring).

    Parameters
    ----------
    rng
        Seeded generator.
    gyro_std_rad_s, accel_std_m_s2
        Noise per axis [rad/s], [m/s^2] (0: exact).
    """

    def __init__(
        self, rng: np.random.Generator, *, gyro_std_rad_s: float, accel_std_m_s2: float
    ) -> None:
        self._rng = rng
        self._std = np.array([accel_std_m_s2] * 3 + [gyro_std_rad_s] * 3)

    def measure(self, specific_force_flu_m_s2: ArrayLike, omega_flu_rad_s: ArrayLike) -> ImuReading:
        """The sample of a true specific force and body rate (each averaged over the IMU
        period, body FLU)."""
        truth = np.concatenate((np.asarray(specific_force_flu_m_s2), np.asarray(omega_flu_rad_s)))
        noisy = (truth + self._std * self._rng.standard_normal(6)).tolist()
        return ImuReading(tuple(noisy[0:3]), tuple(noisy[3:6]))


class Magnetometer:
    """The Earth's field in the body frame with white noise (module docstring)."""

    def __init__(self, rng: np.random.Generator, *, std_gauss: float) -> None:
        self._rng = rng
        self._std = float(std_gauss)
        self._field_enu = enu_from_ned(EARTH_FIELD_NED_GAUSS)

    def measure(self, rotation_world_body: ArrayLike) -> tuple[float, float, float]:
        """Field [gauss] along body FLU for the attitude R (body FLU -> world ENU)."""
        field = np.asarray(rotation_world_body).T @ self._field_enu
        return tuple((field + self._std * self._rng.standard_normal(3)).tolist())


@dataclass(frozen=True)
class BaroReading:
    """One barometer sample."""

    pressure_pa: float
    """Static pressure [Pa]."""
    temperature_c: float
    """Air temperature [deg C] (ISA, exact)."""
    altitude_amsl_m: float
    """The pressure altitude of the noisy pressure [m AMSL]."""


class Barometer:
    """ISA pressure at the vehicle's altitude with white noise (module docstring).

    Parameters
    ----------
    rng
        Seeded generator.
    origin
        The world origin's altitude AMSL (``origin.altitude_amsl_m``, world z = 0).
    std_pa
        Pressure noise [Pa].
    """

    def __init__(self, rng: np.random.Generator, origin: GeoReference, *, std_pa: float) -> None:
        self._rng = rng
        self._origin_m = origin.altitude_amsl_m
        self._std = float(std_pa)

    def measure(self, height_m: float) -> BaroReading:
        """The sample at world height ``height_m`` (ENU z) [m]."""
        altitude = self._origin_m + height_m
        pressure = isa_pressure_pa(altitude) + self._std * float(self._rng.standard_normal())
        ratio = (pressure / _SEA_LEVEL_PA) ** (1.0 / _ISA_EXPONENT)
        return BaroReading(
            pressure_pa=pressure,
            temperature_c=_SEA_LEVEL_K - _LAPSE_K_M * altitude - 273.15,
            altitude_amsl_m=(1.0 - ratio) * _SEA_LEVEL_K / _LAPSE_K_M,
        )


@dataclass(frozen=True)
class GpsGrade:
    """How good a GPS receiver is.

    Attributes
    ----------
    name
        ``standard`` or ``rtk``.
    fix_type
        GPS_FIX_TYPE it reports (3: 3D fix, 6: RTK fixed).
    horizontal_std_m, vertical_std_m
        Stationary standard deviation of the slowly wandering position error per horizontal
        axis and of the height [m].
    correlation_s
        Its correlation time [s].
    white_std_m
        White position noise per axis on top [m].
    velocity_std_m_s
        White velocity noise per axis [m/s].
    latency_s
        Age of a fix when PX4 receives it [s].
    rate_hz
        Fixes per second.
    """

    name: str
    fix_type: int
    horizontal_std_m: float
    vertical_std_m: float
    correlation_s: float
    white_std_m: float
    velocity_std_m_s: float
    latency_s: float
    rate_hz: float = 10.0


GPS_GRADES: dict[str, GpsGrade] = {
    # assumed: a single-frequency receiver with SBAS (u-blox M8/M9 class: 1.5-2.5 m CEP
    # absolute, 0.05 m/s velocity); the error that matters after EKF2 set its origin is its
    # wander over a flight, 0.3-1 m over minutes; ~0.1 s from measurement to PX4
    "standard": GpsGrade("standard", 3, 0.7, 1.4, 300.0, 0.05, 0.05, 0.1),
    # assumed: RTK fixed (u-blox ZED-F9P class: 0.01 m + 1 ppm CEP horizontal)
    "rtk": GpsGrade("rtk", 6, 0.01, 0.02, 60.0, 0.003, 0.02, 0.05),
}
"""The GPS receivers ``sitl run --autopilot px4 --navigation gps --gps GRADE`` simulates."""


@dataclass(frozen=True)
class GpsFix:
    """One GPS fix."""

    latitude_deg: float
    longitude_deg: float
    altitude_amsl_m: float
    velocity_enu_m_s: tuple[float, float, float]
    """Ground velocity, world ENU [m/s]."""
    eph_m: float
    """Reported horizontal position accuracy (1 sigma) [m]."""
    epv_m: float
    """Reported vertical position accuracy [m]."""
    fix_type: int
    satellites: int


class GpsReceiver:
    """A GPS receiver of a given grade at the world's geodetic origin (module docstring).

    Call :meth:`sample` once per simulation frame with non-decreasing times; it returns a
    fix when one is due (every ``1 / rate_hz`` s), reflecting the truth ``latency_s``
    earlier (the newest truth passed at or before then).

    Parameters
    ----------
    rng
        Seeded generator.
    grade
        The receiver (:data:`GPS_GRADES`).
    origin
        Geodetic position of the world origin.
    noise
        False: exact fixes (same rate and latency).
    """

    _SATELLITES = 12

    def __init__(
        self,
        rng: np.random.Generator,
        grade: GpsGrade,
        origin: GeoReference,
        *,
        noise: bool = True,
    ) -> None:
        self.grade = grade
        self._rng = rng
        self._origin = origin
        self._noise = noise
        h, v = grade.horizontal_std_m, grade.vertical_std_m
        self._wander_std = np.array([h, h, v])
        self._wander = self._wander_std * rng.standard_normal(3) if noise else np.zeros(3)
        self._period_s = 1.0 / grade.rate_hz
        self._next_s: float | None = None
        self._last_s: float | None = None
        self._truths: deque[tuple[float, FloatArray, FloatArray]] = deque()

    def sample(
        self, t_s: float, position_enu_m: ArrayLike, velocity_enu_m_s: ArrayLike
    ) -> GpsFix | None:
        """Record the truth at ``t_s`` [s] (vehicle CoM position and velocity, world ENU)
        and return the fix due now, if any."""
        grade = self.grade
        self._truths.append(
            (t_s, np.array(position_enu_m, float), np.array(velocity_enu_m_s, float))
        )
        capture_s = t_s - grade.latency_s + 1e-9
        while len(self._truths) > 1 and self._truths[1][0] <= capture_s:
            self._truths.popleft()
        if self._noise and self._last_s is not None:
            a = math.exp(-(t_s - self._last_s) / grade.correlation_s)
            drive = self._wander_std * math.sqrt(1.0 - a * a)
            self._wander = a * self._wander + drive * self._rng.standard_normal(3)
        self._last_s = t_s
        if self._next_s is None:
            self._next_s = t_s + grade.latency_s
        stamp_s, position, velocity = self._truths[0]
        if t_s + 1e-9 < self._next_s or stamp_s > capture_s:
            return None
        while self._next_s <= t_s + 1e-9:  # a fix per period; a missed one is dropped
            self._next_s += self._period_s
        if self._noise:
            position = position + self._wander + grade.white_std_m * self._rng.standard_normal(3)
            velocity = velocity + grade.velocity_std_m_s * self._rng.standard_normal(3)
        lat, lon, alt = self._origin.global_from_ned(*ned_from_enu(position).tolist())
        return GpsFix(
            latitude_deg=lat,
            longitude_deg=lon,
            altitude_amsl_m=alt,
            velocity_enu_m_s=tuple(velocity.tolist()),
            eph_m=math.hypot(grade.horizontal_std_m, grade.white_std_m),
            epv_m=math.hypot(grade.vertical_std_m, grade.white_std_m),
            fix_type=grade.fix_type,
            satellites=self._SATELLITES,
        )

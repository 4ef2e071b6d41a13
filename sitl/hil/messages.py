"""The simulator link's MAVLink messages: our sensor readings in, PX4's units and frames out.

The boundary of :mod:`sitl.hil`: readings arrive in our frames (world ENU, body FLU, SI)
and leave as PX4's ``simulator_mavlink`` reads them (``SimulatorMavlink.cpp``): world NED,
body FRD (through :mod:`companion.frames`), hPa, 1e-7 degrees, millimetres, cm/s. Pure
functions; the socket is :mod:`sitl.hil.link`.

- HIL_SENSOR (:func:`hil_sensor`): sensor id 0, PX4's lockstep clock (``time_usec``);
  ``fields_updated`` says which of accelerometer, gyro, magnetometer and barometer the
  message carries (PX4 reads only those).
- HIL_GPS (:func:`hil_gps`), ODOMETRY of a motion-capture pose (:func:`vision_odometry`,
  MAV_ESTIMATOR_TYPE_VISION: EKF2's external vision) and the ground truth
  HIL_STATE_QUATERNION (:func:`hil_state_quaternion`) are stamped by PX4 on arrival with
  its lockstep time.
- HIL_ACTUATOR_CONTROLS (:func:`motor_commands`): PX4's output i in ``controls[i]``,
  motors in [0, 1] (``pwm_out_sim``), all zero while disarmed, the armed flag in ``mode``.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.frames import frd_from_flu, ned_from_enu, quaternion_ned_frd_from_enu_flu
from sitl.hil.sensors import BaroReading, GpsFix, ImuReading
from sitl.physics import PlantState
from sitl.physics.frames import quaternion_from_euler
from sitl.physics.rotors import N_ROTORS
from sitl.px4.geo import GeoReference
from sitl.px4_sitl.mocap import MocapPose, odometry_message
from sitl.vehicle.sensors import PoseMeasurement

__all__ = [
    "FIELDS_ACCEL",
    "FIELDS_BARO",
    "FIELDS_GYRO",
    "FIELDS_MAG",
    "MODE_FLAG_ARMED",
    "hil_gps",
    "hil_sensor",
    "hil_state_quaternion",
    "motor_commands",
    "vision_odometry",
]

FIELDS_ACCEL = 0b111
"""HIL_SENSOR.fields_updated: xacc, yacc, zacc."""
FIELDS_GYRO = 0b111 << 3
"""HIL_SENSOR.fields_updated: xgyro, ygyro, zgyro."""
FIELDS_MAG = 0b111 << 6
"""HIL_SENSOR.fields_updated: xmag, ymag, zmag."""
FIELDS_BARO = (1 << 9) | (1 << 11) | (1 << 12)
"""HIL_SENSOR.fields_updated: abs_pressure, pressure_alt, temperature (PX4's BARO set)."""
MODE_FLAG_ARMED = 128
"""HIL_ACTUATOR_CONTROLS.mode: PX4 is armed (MAV_MODE_FLAG_SAFETY_ARMED)."""
_STANDARD_GRAVITY = 9.80665


def hil_sensor(
    time_us: int,
    imu: ImuReading,
    mag_flu_gauss: tuple[float, float, float] | None = None,
    baro: BaroReading | None = None,
) -> mavlink.MAVLink_hil_sensor_message:
    """HIL_SENSOR of an IMU sample at PX4 time ``time_us`` [us], with a magnetometer
    (body FLU [gauss]) and a barometer sample when given."""
    ax, ay, az = frd_from_flu(imu.specific_force_flu_m_s2).tolist()
    gx, gy, gz = frd_from_flu(imu.omega_flu_rad_s).tolist()
    fields = FIELDS_ACCEL | FIELDS_GYRO
    mx = my = mz = 0.0
    if mag_flu_gauss is not None:
        mx, my, mz = frd_from_flu(mag_flu_gauss).tolist()
        fields |= FIELDS_MAG
    pressure_hpa = altitude_m = temperature_c = 0.0
    if baro is not None:
        pressure_hpa = baro.pressure_pa / 100.0
        altitude_m, temperature_c = baro.altitude_amsl_m, baro.temperature_c
        fields |= FIELDS_BARO
    return mavlink.MAVLink_hil_sensor_message(
        time_us, ax, ay, az, gx, gy, gz, mx, my, mz,
        pressure_hpa, 0.0, altitude_m, temperature_c, fields, 0,
    )  # fmt: skip


def _int16(value: float) -> int:
    return int(max(-32768, min(32767, round(value))))


def hil_gps(utc_us: int, fix: GpsFix) -> mavlink.MAVLink_hil_gps_message:
    """HIL_GPS of a fix; ``utc_us`` is the receiver's UTC time [us since 1970]."""
    vn, ve, vd = ned_from_enu(fix.velocity_enu_m_s).tolist()
    ground_speed = math.hypot(vn, ve)
    course_cdeg = round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0) % 36000
    return mavlink.MAVLink_hil_gps_message(
        utc_us,
        fix.fix_type,
        round(fix.latitude_deg * 1e7),
        round(fix.longitude_deg * 1e7),
        round(fix.altitude_amsl_m * 1e3),
        min(65534, round(fix.eph_m * 100.0)),
        min(65534, round(fix.epv_m * 100.0)),
        min(65534, round(ground_speed * 100.0)),
        _int16(vn * 100.0),
        _int16(ve * 100.0),
        _int16(vd * 100.0),
        course_cdeg if ground_speed > 0.1 else 65535,
        fix.satellites,
        0,
        0,
    )


def vision_odometry(
    time_us: int, pose: PoseMeasurement, position_std_m: float, attitude_std_rad: float
) -> mavlink.MAVLink_odometry_message:
    """ODOMETRY of a motion-capture pose (world ENU position, ZYX Euler angles of body FLU)
    as external vision in local NED / body FRD with its noise as variances
    (:func:`sitl.px4_sitl.mocap.odometry_message`); ``time_us`` is the mocap system's clock."""
    q_ned_frd = quaternion_ned_frd_from_enu_flu(quaternion_from_euler(*pose.euler_rad.tolist()))
    ned = MocapPose(
        tuple(ned_from_enu(pose.position_m).tolist()),
        tuple(q_ned_frd.tolist()),
    )
    return odometry_message(ned, time_us, position_std_m, attitude_std_rad)


def hil_state_quaternion(
    time_us: int, state: PlantState, acceleration_enu_m_s2: np.ndarray, origin: GeoReference
) -> mavlink.MAVLink_hil_state_quaternion_message:
    """HIL_STATE_QUATERNION: the truth of the vehicle CoM (attitude FRD -> NED, body
    rates FRD, position in 1e-7 deg and mm AMSL, NED velocity [cm/s], NED acceleration
    [mG]) for PX4's ground-truth topics."""
    north, east, down = ned_from_enu(state.q[0:3]).tolist()
    lat, lon, alt = origin.global_from_ned(north, east, down)
    vn, ve, vd = ned_from_enu(state.q_dot[0:3]).tolist()
    accel = ned_from_enu(acceleration_enu_m_s2) * (1000.0 / _STANDARD_GRAVITY)
    speed_cm_s = min(65535, round(100.0 * math.sqrt(vn * vn + ve * ve + vd * vd)))
    return mavlink.MAVLink_hil_state_quaternion_message(
        time_us,
        quaternion_ned_frd_from_enu_flu(state.quaternion_wxyz).tolist(),
        *frd_from_flu(state.omega_body_rad_s).tolist(),
        round(lat * 1e7),
        round(lon * 1e7),
        round(alt * 1e3),
        _int16(vn * 100.0),
        _int16(ve * 100.0),
        _int16(vd * 100.0),
        speed_cm_s,
        speed_cm_s,
        *(_int16(a) for a in accel.tolist()),
    )


def motor_commands(
    message: mavlink.MAVLink_hil_actuator_controls_message,
) -> tuple[list[float], bool]:
    """PX4's six motor commands (output i -> rotor i, each clipped to [0, 1]) and whether
    PX4 is armed."""
    commands = [min(max(float(u), 0.0), 1.0) for u in message.controls[:N_ROTORS]]
    return commands, bool(message.mode & MODE_FLAG_ARMED)

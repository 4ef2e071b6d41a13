"""Telemetry of the simulated PX4: the NED / FRD messages of its streams.

Which message is due when, per link, is :mod:`sitl.px4.streams`'s. The streams of the
estimate (:data:`~sitl.px4.streams.ESTIMATOR_STREAMS`) carry the estimate's IMU sample
time as their timestamps.

Message contents: positions relative to the local origin (the world origin), in NED
through :mod:`companion.frames` (the only place that converts frames); Euler angles of
ATTITUDE are the ZYX angles of the NED / FRD quaternion; the IMU reading is the body FRD
specific force. Global positions use the estimator's global origin (none: no
GLOBAL_POSITION_INT, as PX4 without GPS or SET_GPS_GLOBAL_ORIGIN). ODOMETRY is PX4's:
frame and child frame MAV_FRAME_LOCAL_NED (velocity in NED), the estimator's variances on
the covariance diagonals (zeros elsewhere), its reset counter, estimator type AUTOPILOT,
quality 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import common as mavlink
from pymavlink.dialects.v20 import development

from companion.frames import frd_from_flu, ned_from_enu, quaternion_ned_frd_from_enu_flu
from companion.frames import rotation_from_quaternion as rotation_from_quaternion_wxyz
from sitl.physics import AttitudeSetpoint
from sitl.physics.frames import euler_from_rotation
from sitl.px4.geo import GeoReference
from sitl.px4.measurement import VehicleMeasurement
from sitl.px4.modes import Px4Mode, base_mode_flags
from sitl.px4.streams import CURRENT_MODE, GCS_RATES_HZ, ONBOARD_RATES_HZ

"""A NED/FRD quaternion [w, x, y, z] and its ZYX Euler angles [rad]."""

__all__ = ["Home", "TelemetryEncoder", "VehicleStatus"]

M = mavlink
_PRESENT = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | M.MAV_SYS_STATUS_LOGGING
    | M.MAV_SYS_STATUS_SENSOR_BATTERY
)
"""SYS_STATUS sensors present (PX4 SIH; GPS added with GPS aiding)."""
_HEALTHY = (
    _PRESENT
    | M.MAV_SYS_STATUS_SENSOR_DIFFERENTIAL_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | M.MAV_SYS_STATUS_AHRS
)
"""SYS_STATUS health bits as PX4 SIH sets them (besides the pre-arm check bit)."""

_ESTIMATOR_FLAGS = (
    M.ESTIMATOR_ATTITUDE
    | M.ESTIMATOR_VELOCITY_HORIZ
    | M.ESTIMATOR_VELOCITY_VERT
    | M.ESTIMATOR_POS_HORIZ_REL
    | M.ESTIMATOR_POS_VERT_ABS
    | M.ESTIMATOR_CONST_POS_MODE
    | M.ESTIMATOR_PRED_POS_HORIZ_REL
)
"""ESTIMATOR_STATUS flags PX4's EKF2 sets with any position aiding (measured on vision
alone: 431); a global origin adds POS_HORIZ_ABS (447), GPS and baro add POS_VERT_AGL and
PRED_POS_HORIZ_ABS (1023)."""

_IMU_FIELDS = 0b0001_1100_0011_1111
"""HIGHRES_IMU.fields_updated: acc, gyro, abs pressure, pressure alt, temperature (no mag)."""

_SEA_LEVEL_PA = 101_325.0


def _centiamps(m: VehicleMeasurement) -> int:
    """The battery current as SYS_STATUS and BATTERY_STATUS carry it [cA], -1 when not
    measured."""
    current = m.battery_current_a
    return -1 if current < 0.0 else min(round(current * 100.0), 32767)


@dataclass(frozen=True)
class Home:
    """Home: where the vehicle was last armed (world ENU [m])."""

    east_m: float
    north_m: float
    up_m: float


@dataclass(frozen=True)
class VehicleStatus:
    """The autopilot state the telemetry reports (from the commander and the estimator).

    Attributes
    ----------
    mode : Px4Mode
        The mode flown (HEARTBEAT, CURRENT_MODE.custom_mode).
    intended_mode : Px4Mode
        The mode the user asked for (CURRENT_MODE.intended_custom_mode; differs from
        ``mode`` during a failsafe).
    armed, failsafe, prearm_ok : bool
        Arming state, failsafe active, arming checks pass.
    landed_state : int
        MAV_LANDED_STATE_*.
    home : Home or None
        Home position (None: no home, e.g. no global position yet).
    origin : GeoReference or None
        The estimator's global origin (None: no global position).
    mav_type : int
        MAV_TYPE parameter (HEARTBEAT.type).
    setpoint : AttitudeSetpoint or None
        The attitude setpoint flown (ATTITUDE_TARGET; None while disarmed).
    estimator_resets : int
        Resets of the estimate made by the autopilot (a new global origin), added to the
        estimator's own reset counter.
    """

    mode: Px4Mode
    intended_mode: Px4Mode
    armed: bool
    landed_state: int
    failsafe: bool
    prearm_ok: bool
    home: Home | None
    origin: GeoReference | None
    mav_type: int
    setpoint: AttitudeSetpoint | None
    estimator_resets: int = 0


class TelemetryEncoder:
    """Builds the MAVLink messages of the streams from a measurement and the status.

    Parameters
    ----------
    geo : GeoReference
        Geodetic position of the world origin (AMSL altitudes of the baro).
    flight_sw_version : int
        AUTOPILOT_VERSION.flight_sw_version (PX4 layout: major, minor, patch, type bytes).
    unix_time_at_boot_us : int
        Wall-clock time of boot [us since 1970] (SYSTEM_TIME).
    """

    def __init__(
        self, geo: GeoReference, flight_sw_version: int, unix_time_at_boot_us: int = 0
    ) -> None:
        self.geo = geo
        self.flight_sw_version = flight_sw_version
        self.unix_time_at_boot_us = int(unix_time_at_boot_us)
        self._ping_seq = 0
        self._quaternion_of: VehicleMeasurement | None = None
        self._quaternion_ned: NDArray[np.float64] | None = None
        self._euler_of: VehicleMeasurement | None = None
        self._euler_ned: tuple[float, float, float] | None = None

    def build(
        self, msg_id: int, now_s: float, m: VehicleMeasurement, status: VehicleStatus
    ) -> mavlink.MAVLink_message | None:
        """The message ``msg_id`` at ``now_s``; None when it has no data now (a global
        position without a global origin, a home that is not set)."""
        return self._builders[msg_id](self, now_s, m, status)

    def can_build(self, msg_id: int) -> bool:
        """Whether ``msg_id`` is a message this encoder makes."""
        return msg_id in self._builders

    @classmethod
    def streamable(cls) -> frozenset[int]:
        """Every message id the encoder can stream."""
        return frozenset(cls._builders)

    def heartbeat(self, status: VehicleStatus) -> mavlink.MAVLink_heartbeat_message:
        """HEARTBEAT: MAV_TYPE, PX4, PX4's base/custom mode and system status (armed:
        ACTIVE, CRITICAL in a failsafe; disarmed: STANDBY when it may arm, else UNINIT)."""
        if status.armed:
            state = M.MAV_STATE_CRITICAL if status.failsafe else M.MAV_STATE_ACTIVE
        else:
            state = M.MAV_STATE_STANDBY if status.prearm_ok else M.MAV_STATE_UNINIT
        return M.MAVLink_heartbeat_message(
            status.mav_type,
            M.MAV_AUTOPILOT_PX4,
            base_mode_flags(status.mode, status.armed),
            status.mode.custom_mode,
            state,
            3,
        )

    def autopilot_version(self, system_id: int) -> mavlink.MAVLink_autopilot_version_message:
        """AUTOPILOT_VERSION with the capabilities this vehicle really has."""
        caps = (
            M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
            | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
            | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        )
        return M.MAVLink_autopilot_version_message(
            caps,
            self.flight_sw_version,
            0,
            0,
            0,
            [0] * 8,
            [0] * 8,
            [0] * 8,
            0,
            0,
            system_id,
            [0] * 18,
        )

    def gps_global_origin(self, origin: GeoReference, now_s: float) -> mavlink.MAVLink_message:
        """GPS_GLOBAL_ORIGIN of the estimator's origin (degE7, mm AMSL)."""
        return M.MAVLink_gps_global_origin_message(
            round(origin.latitude_deg * 1e7),
            round(origin.longitude_deg * 1e7),
            round(origin.altitude_amsl_m * 1e3),
            round(now_s * 1e6),
        )

    # ------------------------------------------------------------- builders

    @staticmethod
    def _time_ms(now_s: float) -> int:
        return int(now_s * 1e3) & 0xFFFFFFFF

    @staticmethod
    def _estimate_ms(m: VehicleMeasurement) -> int:
        return (m.estimate_time_us // 1000) & 0xFFFFFFFF  # type: ignore[operator]

    def _heartbeat(self, now_s, m, status):
        return self.heartbeat(status)

    def _sys_status(self, now_s, m, status):
        gps = M.MAV_SYS_STATUS_SENSOR_GPS if m.estimator.aiding == "gps" else 0
        present = _PRESENT | gps
        health = _HEALTHY | (M.MAV_SYS_STATUS_PREARM_CHECK if status.prearm_ok else 0)
        return M.MAVLink_sys_status_message(
            present, present | M.MAV_SYS_STATUS_SENSOR_RC_RECEIVER, health, 0,
            round(m.battery_voltage_v * 1e3), _centiamps(m), round(m.battery_remaining * 100),
            0, 0, 0, 0, 0, 0, 0, 0, 1,
        )  # fmt: skip

    def _system_time(self, now_s, m, status):
        return M.MAVLink_system_time_message(
            self.unix_time_at_boot_us + round(now_s * 1e6), self._time_ms(now_s)
        )

    def _ping(self, now_s, m, status):
        self._ping_seq = (self._ping_seq + 1) & 0xFFFFFFFF
        return M.MAVLink_ping_message(round(now_s * 1e6), self._ping_seq, 0, 0)

    def _timesync(self, now_s, m, status):
        return M.MAVLink_timesync_message(0, round(now_s * 1e9))

    def _ned_quaternion(self, m: VehicleMeasurement) -> NDArray[np.float64]:
        """The measured attitude as a NED/FRD quaternion ``[w, x, y, z]``; converted once
        per estimate, which every attitude stream due at its step shares."""
        if m is not self._quaternion_of or self._quaternion_ned is None:
            self._quaternion_ned = quaternion_ned_frd_from_enu_flu(m.quaternion_enu_flu_wxyz)
            self._quaternion_of = m
        return self._quaternion_ned

    def _ned_euler(self, m: VehicleMeasurement) -> tuple[float, float, float]:
        """The ZYX Euler angles of :meth:`_ned_quaternion` (roll, pitch, yaw from north)
        [rad]; computed once per estimate, and only when a stream due needs them (not for
        ODOMETRY alone)."""
        if m is not self._euler_of or self._euler_ned is None:
            rotation = rotation_from_quaternion_wxyz(self._ned_quaternion(m))
            self._euler_ned = euler_from_rotation(rotation)
            self._euler_of = m
        return self._euler_ned

    def _heading(self, m: VehicleMeasurement) -> float:
        """NED yaw of the measured attitude [rad] (heading from north, clockwise)."""
        return self._ned_euler(m)[2]

    def _attitude(self, now_s, m, status):
        roll, pitch, yaw = self._ned_euler(m)
        p, q_rate, r = frd_from_flu(m.omega_flu_rad_s)
        return M.MAVLink_attitude_message(self._estimate_ms(m), roll, pitch, yaw, p, q_rate, r)

    def _attitude_quaternion(self, now_s, m, status):
        w, x, y, z = self._ned_quaternion(m)
        p, q_rate, r = frd_from_flu(m.omega_flu_rad_s)
        return M.MAVLink_attitude_quaternion_message(
            self._estimate_ms(m), w, x, y, z, p, q_rate, r, [0.0] * 4
        )

    def _attitude_target(self, now_s, m, status):
        sp = status.setpoint
        if sp is None:
            q, thrust = [1.0, 0.0, 0.0, 0.0], 0.0
        else:
            q, thrust = list(quaternion_ned_frd_from_enu_flu(sp.quaternion_wxyz)), sp.thrust
        return M.MAVLink_attitude_target_message(self._time_ms(now_s), 0, q, 0.0, 0.0, 0.0, thrust)

    def _highres_imu(self, now_s, m, status):
        ax, ay, az = frd_from_flu(m.specific_force_flu_m_s2)
        gx, gy, gz = frd_from_flu(m.omega_flu_rad_s)
        alt = self.geo.altitude_amsl_m + float(m.position_enu_m[2])
        pressure_hpa = _SEA_LEVEL_PA * (1.0 - 2.25577e-5 * alt) ** 5.25588 / 100.0
        return M.MAVLink_highres_imu_message(
            int(now_s * 1e6), ax, ay, az, gx, gy, gz, 0.0, 0.0, 0.0,
            pressure_hpa, 0.0, alt, 25.0, _IMU_FIELDS, 0,
        )  # fmt: skip

    def _local_position_ned(self, now_s, m, status):
        x, y, z = ned_from_enu(m.position_enu_m)
        vx, vy, vz = ned_from_enu(m.velocity_enu_m_s)
        return M.MAVLink_local_position_ned_message(self._estimate_ms(m), x, y, z, vx, vy, vz)

    def _odometry(self, now_s, m, status):
        x, y, z = ned_from_enu(m.position_enu_m)
        q = self._ned_quaternion(m)
        vx, vy, vz = ned_from_enu(m.velocity_enu_m_s)
        p, q_rate, r = frd_from_flu(m.omega_flu_rad_s)
        report = m.estimator
        pose = [0.0] * 21
        pose[0] = pose[6] = report.position_variance_m2[0]
        pose[11] = report.position_variance_m2[1]
        pose[15], pose[18], pose[20] = report.attitude_variance_rad2
        velocity = [0.0] * 21
        velocity[0] = velocity[6] = report.velocity_variance_m2_s2[0]
        velocity[11] = report.velocity_variance_m2_s2[1]
        return M.MAVLink_odometry_message(
            m.estimate_time_us, M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_LOCAL_NED, x, y, z, list(q),
            vx, vy, vz, p, q_rate, r, pose, velocity,
            report.reset_counter + status.estimator_resets,
            M.MAV_ESTIMATOR_TYPE_AUTOPILOT, 0,
        )  # fmt: skip

    def _global_position_int(self, now_s, m, status):
        origin = status.origin
        if origin is None:
            return None
        n, e, d = ned_from_enu(m.position_enu_m)
        lat, lon, alt = origin.global_from_ned(n, e, d)
        home_amsl = 0.0
        if status.home is not None:
            home_amsl = origin.altitude_amsl_m + status.home.up_m
        vn, ve, vd = ned_from_enu(m.velocity_enu_m_s)
        return M.MAVLink_global_position_int_message(
            self._estimate_ms(m), round(lat * 1e7), round(lon * 1e7), round(alt * 1e3),
            round((alt - home_amsl) * 1e3), round(vn * 100), round(ve * 100), round(vd * 100),
            round(math.degrees(self._heading(m)) * 100) % 36000,
        )  # fmt: skip

    def _vfr_hud(self, now_s, m, status):
        ve, vn, vu = m.velocity_enu_m_s.tolist()
        thrust = status.setpoint.thrust if status.armed and status.setpoint is not None else 0.0
        return M.MAVLink_vfr_hud_message(
            math.nan,
            math.hypot(ve, vn),
            round(math.degrees(self._heading(m))) % 360,
            round(100.0 * thrust),
            self.geo.altitude_amsl_m + float(m.position_enu_m[2]),
            vu,
        )

    def _extended_sys_state(self, now_s, m, status):
        return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED, status.landed_state)

    def _altitude(self, now_s, m, status):
        up = float(m.position_enu_m[2])
        home_up = status.home.up_m if status.home is not None else 0.0
        amsl = self.geo.altitude_amsl_m + up
        return M.MAVLink_altitude_message(
            m.estimate_time_us, amsl, amsl, up, up - home_up, math.nan, math.nan
        )

    def _battery_status(self, now_s, m, status):
        millivolts = min(round(m.battery_voltage_v * 1e3), 65534)
        return M.MAVLink_battery_status_message(
            0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 32767,
            [millivolts] + [65535] * 9, _centiamps(m), -1, -1, round(m.battery_remaining * 100), 0,
            M.MAV_BATTERY_CHARGE_STATE_OK, [0] * 4, 0, 0,
        )  # fmt: skip

    def _estimator_status(self, now_s, m, status):
        report = m.estimator
        flags = _ESTIMATOR_FLAGS
        if status.origin is not None:
            flags |= M.ESTIMATOR_POS_HORIZ_ABS
        if report.aiding == "gps":
            flags |= M.ESTIMATOR_PRED_POS_HORIZ_ABS | M.ESTIMATOR_POS_VERT_AGL
        var_h, var_v = report.position_variance_m2
        vel, pos_h, pos_v, mag, hagl = report.test_ratios
        return M.MAVLink_estimator_status_message(
            m.estimate_time_us, flags, vel, pos_h, pos_v, mag, hagl, math.nan,
            math.sqrt(2.0 * var_h), math.sqrt(var_v),
        )  # fmt: skip

    def _home_position(self, now_s, m, status):
        home, origin = status.home, status.origin
        if home is None or origin is None:
            return None
        n, e, d = ned_from_enu((home.east_m, home.north_m, home.up_m))
        lat, lon, alt = origin.global_from_ned(n, e, d)
        return M.MAVLink_home_position_message(
            round(lat * 1e7), round(lon * 1e7), round(alt * 1e3), float(n), float(e), float(d),
            [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(now_s * 1e6),
        )  # fmt: skip

    def _current_mode(self, now_s, m, status):
        return development.MAVLink_current_mode_message(
            0, status.mode.custom_mode, status.intended_mode.custom_mode
        )

    _builders: ClassVar[dict] = {
        M.MAVLINK_MSG_ID_HEARTBEAT: _heartbeat,
        M.MAVLINK_MSG_ID_SYS_STATUS: _sys_status,
        M.MAVLINK_MSG_ID_SYSTEM_TIME: _system_time,
        M.MAVLINK_MSG_ID_PING: _ping,
        M.MAVLINK_MSG_ID_TIMESYNC: _timesync,
        M.MAVLINK_MSG_ID_ATTITUDE: _attitude,
        M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: _attitude_quaternion,
        M.MAVLINK_MSG_ID_ATTITUDE_TARGET: _attitude_target,
        M.MAVLINK_MSG_ID_HIGHRES_IMU: _highres_imu,
        M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: _local_position_ned,
        M.MAVLINK_MSG_ID_ODOMETRY: _odometry,
        M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: _global_position_int,
        M.MAVLINK_MSG_ID_VFR_HUD: _vfr_hud,
        M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: _extended_sys_state,
        M.MAVLINK_MSG_ID_ALTITUDE: _altitude,
        M.MAVLINK_MSG_ID_BATTERY_STATUS: _battery_status,
        M.MAVLINK_MSG_ID_ESTIMATOR_STATUS: _estimator_status,
        M.MAVLINK_MSG_ID_HOME_POSITION: _home_position,
        CURRENT_MODE: _current_mode,
    }


assert set(ONBOARD_RATES_HZ) <= set(TelemetryEncoder._builders)
assert set(GCS_RATES_HZ) <= set(TelemetryEncoder._builders)

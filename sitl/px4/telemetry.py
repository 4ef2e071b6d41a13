"""Telemetry of the simulated PX4: stream rates per link and the NED / FRD messages.

Rates follow PX4's stream tables (``mavlink_main.cpp``): the onboard link uses the
"onboard" rates of issue 5, the GCS link PX4's "normal" mode rates. Every rate is
changeable per link with MAV_CMD_SET_MESSAGE_INTERVAL (-1 disables, 0 restores the
default). Scheduling is in simulation time with integer microseconds: a stream with
interval T is due at k T; a stream that fell behind (a coarse caller) is sent once and
rescheduled from now, never in a burst.

Message contents: positions relative to the local origin (the world origin), in NED
through :mod:`companion.frames` (the only place that converts frames); Euler angles of
ATTITUDE are the ZYX angles of the NED / FRD quaternion; the IMU reading is the body FRD
specific force. Global positions use :class:`~sitl.px4.geo.GeoReference`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from pymavlink.dialects.v20 import common as mavlink

from companion.frames import frd_from_flu, ned_from_enu, quaternion_ned_frd_from_enu_flu
from companion.frames import rotation_from_quaternion as rotation_from_quaternion_wxyz
from sitl.physics.frames import euler_from_rotation
from sitl.px4.commander import Home
from sitl.px4.geo import GeoReference
from sitl.px4.measurement import VehicleMeasurement
from sitl.px4.modes import Px4Mode, base_mode_flags

__all__ = [
    "GCS_RATES_HZ",
    "ONBOARD_RATES_HZ",
    "StreamScheduler",
    "TelemetryEncoder",
    "VehicleStatus",
]

M = mavlink
ONBOARD_RATES_HZ: dict[int, float] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    M.MAVLINK_MSG_ID_ATTITUDE: 100.0,
    M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    M.MAVLINK_MSG_ID_HIGHRES_IMU: 50.0,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    M.MAVLINK_MSG_ID_ODOMETRY: 30.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 30.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    M.MAVLINK_MSG_ID_ALTITUDE: 10.0,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
}
"""Default rates [Hz] of the onboard (API) link."""

GCS_RATES_HZ: dict[int, float] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    M.MAVLINK_MSG_ID_ATTITUDE: 20.0,
    M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    M.MAVLINK_MSG_ID_ALTITUDE: 1.0,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
}
"""Default rates [Hz] of the GCS link (PX4 "normal" mode)."""

_SENSORS = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_AHRS
    | M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | M.MAV_SYS_STATUS_SENSOR_BATTERY
)
"""SYS_STATUS sensors present, enabled and healthy (besides the pre-arm check bit)."""

_IMU_FIELDS = 0b0001_1100_0011_1111
"""HIGHRES_IMU.fields_updated: acc, gyro, abs pressure, pressure alt, temperature (no mag)."""

_SEA_LEVEL_PA = 101_325.0


@dataclass(frozen=True)
class VehicleStatus:
    """The autopilot state the telemetry reports (from :class:`~sitl.px4.commander.Commander`)."""

    mode: Px4Mode
    armed: bool
    landed_state: int
    failsafe: bool
    prearm_ok: bool
    home: Home | None


class StreamScheduler:
    """When each message of one link is due, in simulation time.

    Parameters
    ----------
    default_rates_hz : mapping of message id to rate [Hz]
        The streams of the link and their default rates.
    """

    def __init__(self, default_rates_hz: Mapping[int, float]) -> None:
        self._default_us = {
            msg_id: round(1e6 / rate) for msg_id, rate in default_rates_hz.items() if rate > 0
        }
        self._interval_us: dict[int, int | None] = dict(self._default_us)
        self._next_us: dict[int, int] = dict.fromkeys(self._default_us, 0)
        self._earliest_us = 0
        """No stream is due before this time [us] (``due`` returns at once before it)."""

    @property
    def streams(self) -> list[int]:
        """Message ids this link can stream."""
        return list(self._default_us)

    def interval_us(self, msg_id: int) -> int | None:
        """Current interval [us] of a stream, None when disabled (KeyError if unknown)."""
        return self._interval_us[msg_id]

    def set_interval(self, msg_id: int, interval_us: float, now_us: int) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL: -1 disables, 0 restores the default, > 0 sets [us].

        Raises
        ------
        KeyError
            The message is not a stream of this vehicle.
        ValueError
            A non-finite interval or one below -1.
        """
        if msg_id not in self._default_us:
            raise KeyError(msg_id)
        if not math.isfinite(interval_us) or interval_us < -1.0:
            raise ValueError(f"interval {interval_us!r} us")
        if interval_us < 0.0:
            self._interval_us[msg_id] = None
            return
        self._interval_us[msg_id] = (
            self._default_us[msg_id] if interval_us == 0.0 else max(round(interval_us), 1)
        )
        self._next_us[msg_id] = now_us
        self._earliest_us = min(self._earliest_us, now_us)

    def trigger(self, msg_id: int, now_us: int) -> None:
        """Make an enabled stream due now (a HEARTBEAT right after a mode change)."""
        if self._interval_us.get(msg_id) is not None:
            self._next_us[msg_id] = now_us
            self._earliest_us = min(self._earliest_us, now_us)

    def due(self, now_us: int) -> list[int]:
        """Message ids due at ``now_us``; each is rescheduled one interval later."""
        if now_us < self._earliest_us:
            return []
        out = []
        next_us = self._next_us
        earliest = None
        for msg_id, interval in self._interval_us.items():
            if interval is None:
                continue
            nxt = next_us[msg_id]
            if now_us >= nxt:
                out.append(msg_id)
                nxt += interval
                if nxt <= now_us:
                    nxt = now_us + interval
                next_us[msg_id] = nxt
            if earliest is None or nxt < earliest:
                earliest = nxt
        # Disabled streams are not waited for; with none enabled, check again every time.
        self._earliest_us = now_us if earliest is None else earliest
        return out


class TelemetryEncoder:
    """Builds the MAVLink messages of the streams from a measurement and the status.

    Parameters
    ----------
    geo : GeoReference
        Geodetic position of the world origin.
    flight_sw_version : int
        AUTOPILOT_VERSION.flight_sw_version (PX4 layout: major, minor, patch, type bytes).
    """

    def __init__(self, geo: GeoReference, flight_sw_version: int) -> None:
        self.geo = geo
        self.flight_sw_version = flight_sw_version

    def build(
        self, msg_id: int, now_s: float, m: VehicleMeasurement, status: VehicleStatus
    ) -> mavlink.MAVLink_message:
        """The message ``msg_id`` (one of the stream ids) at ``now_s``."""
        return self._builders[msg_id](self, now_s, m, status)

    def can_build(self, msg_id: int) -> bool:
        """Whether ``msg_id`` is a message this encoder makes (REQUEST_MESSAGE)."""
        return msg_id in self._builders

    def heartbeat(self, status: VehicleStatus) -> mavlink.MAVLink_heartbeat_message:
        """HEARTBEAT: hexarotor, PX4, PX4's base/custom mode, standby/active/critical."""
        if status.failsafe:
            state = M.MAV_STATE_CRITICAL
        else:
            state = M.MAV_STATE_ACTIVE if status.armed else M.MAV_STATE_STANDBY
        return M.MAVLink_heartbeat_message(
            M.MAV_TYPE_HEXAROTOR,
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

    # ------------------------------------------------------------- builders

    @staticmethod
    def _time_ms(now_s: float) -> int:
        return int(now_s * 1e3) & 0xFFFFFFFF

    def _heartbeat(self, now_s, m, status):
        return self.heartbeat(status)

    def _attitude(self, now_s, m, status):
        q = quaternion_ned_frd_from_enu_flu(m.quaternion_enu_flu_wxyz)
        roll, pitch, yaw = euler_from_rotation(rotation_from_quaternion_wxyz(q))
        p, q_rate, r = frd_from_flu(m.omega_flu_rad_s)
        return M.MAVLink_attitude_message(self._time_ms(now_s), roll, pitch, yaw, p, q_rate, r)

    def _attitude_quaternion(self, now_s, m, status):
        w, x, y, z = quaternion_ned_frd_from_enu_flu(m.quaternion_enu_flu_wxyz)
        p, q_rate, r = frd_from_flu(m.omega_flu_rad_s)
        return M.MAVLink_attitude_quaternion_message(
            self._time_ms(now_s), w, x, y, z, p, q_rate, r, [0.0] * 4
        )

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
        return M.MAVLink_local_position_ned_message(self._time_ms(now_s), x, y, z, vx, vy, vz)

    def _odometry(self, now_s, m, status):
        x, y, z = ned_from_enu(m.position_enu_m)
        q = quaternion_ned_frd_from_enu_flu(m.quaternion_enu_flu_wxyz)
        v_body = rotation_from_quaternion_wxyz(q).T @ ned_from_enu(m.velocity_enu_m_s)
        p, q_rate, r = frd_from_flu(m.omega_flu_rad_s)
        nan21 = [math.nan] * 21
        return M.MAVLink_odometry_message(
            int(now_s * 1e6), M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_BODY_FRD, x, y, z, list(q),
            v_body[0], v_body[1], v_body[2], p, q_rate, r, nan21, nan21, 0,
            M.MAV_ESTIMATOR_TYPE_NAIVE, 100,
        )  # fmt: skip

    def _global_position_int(self, now_s, m, status):
        n, e, d = ned_from_enu(m.position_enu_m)
        lat, lon, alt = self.geo.global_from_ned(n, e, d)
        home_up = status.home.up_m if status.home is not None else 0.0
        vn, ve, vd = ned_from_enu(m.velocity_enu_m_s)
        _, _, yaw = euler_from_rotation(
            rotation_from_quaternion_wxyz(
                quaternion_ned_frd_from_enu_flu(m.quaternion_enu_flu_wxyz)
            )
        )
        return M.MAVLink_global_position_int_message(
            self._time_ms(now_s), round(lat * 1e7), round(lon * 1e7), round(alt * 1e3),
            round((-d - home_up) * 1e3), round(vn * 100), round(ve * 100), round(vd * 100),
            round(math.degrees(yaw) * 100) % 36000,
        )  # fmt: skip

    def _sys_status(self, now_s, m, status):
        health = _SENSORS | (M.MAV_SYS_STATUS_PREARM_CHECK if status.prearm_ok else 0)
        present = _SENSORS | M.MAV_SYS_STATUS_PREARM_CHECK
        return M.MAVLink_sys_status_message(
            present, present, health, 0, round(m.battery_voltage_v * 1e3), -1,
            round(m.battery_remaining * 100), 0, 0, 0, 0, 0, 0, 0, 0, 0,
        )  # fmt: skip

    def _extended_sys_state(self, now_s, m, status):
        return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED, status.landed_state)

    def _altitude(self, now_s, m, status):
        up = float(m.position_enu_m[2])
        home_up = status.home.up_m if status.home is not None else 0.0
        amsl = self.geo.altitude_amsl_m + up
        return M.MAVLink_altitude_message(
            int(now_s * 1e6), amsl, amsl, up, up - home_up, math.nan, math.nan
        )

    def _battery_status(self, now_s, m, status):
        millivolts = min(round(m.battery_voltage_v * 1e3), 65534)
        return M.MAVLink_battery_status_message(
            0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 32767,
            [millivolts] + [65535] * 9, -1, -1, -1, round(m.battery_remaining * 100), 0,
            M.MAV_BATTERY_CHARGE_STATE_OK, [0] * 4, 0, 0,
        )  # fmt: skip

    def _home_position(self, now_s, m, status):
        home = status.home
        if home is None:
            pos = m.position_enu_m
            home = Home(float(pos[0]), float(pos[1]), float(pos[2]))
        n, e, d = ned_from_enu((home.east_m, home.north_m, home.up_m))
        lat, lon, alt = self.geo.global_from_ned(n, e, d)
        return M.MAVLink_home_position_message(
            round(lat * 1e7), round(lon * 1e7), round(alt * 1e3), float(n), float(e), float(d),
            [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(now_s * 1e6),
        )  # fmt: skip

    _builders: ClassVar[dict] = {
        M.MAVLINK_MSG_ID_HEARTBEAT: _heartbeat,
        M.MAVLINK_MSG_ID_ATTITUDE: _attitude,
        M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: _attitude_quaternion,
        M.MAVLINK_MSG_ID_HIGHRES_IMU: _highres_imu,
        M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: _local_position_ned,
        M.MAVLINK_MSG_ID_ODOMETRY: _odometry,
        M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: _global_position_int,
        M.MAVLINK_MSG_ID_SYS_STATUS: _sys_status,
        M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: _extended_sys_state,
        M.MAVLINK_MSG_ID_ALTITUDE: _altitude,
        M.MAVLINK_MSG_ID_BATTERY_STATUS: _battery_status,
        M.MAVLINK_MSG_ID_HOME_POSITION: _home_position,
    }


assert set(ONBOARD_RATES_HZ) <= set(TelemetryEncoder._builders)
assert set(GCS_RATES_HZ) <= set(TelemetryEncoder._builders)

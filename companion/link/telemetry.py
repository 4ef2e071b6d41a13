"""What the application uses from the vehicle's telemetry, in our frames (DESIGN.md section 2).

PX4 sends NED/FRD; every sample here is converted through :mod:`companion.frames`:
positions and velocities world ENU, attitudes body FLU -> world ENU (quaternions
``[w, x, y, z]``), rates and specific force body FLU. Each sample carries the vehicle's
clock, so that the application also runs against a simulator faster than real time:
:class:`VehiclePose` in microseconds since the autopilot booted (ODOMETRY's ``time_usec``,
the estimator's IMU sample time; LOCAL_POSITION_NED's ``time_boot_ms`` x 1000), the others
in milliseconds (``time_usec`` truncated).

The decoders are pure: a bad message (NaN, a zero quaternion, an unsupported frame)
raises :class:`~companion.link.errors.TelemetryError` with a short ``reason``, which the
link's reader counts and drops.

=====================  =========================================================
sample                 from
=====================  =========================================================
:class:`VehiclePose`   ODOMETRY (``pose_from="odometry"``), or LOCAL_POSITION_NED
                       with the latest ATTITUDE_QUATERNION (``"local_position"``)
:class:`BodyRates`     the same message as the attitude (ODOMETRY or
                       ATTITUDE_QUATERNION)
:class:`ImuSample`     HIGHRES_IMU
:class:`VehicleStatus` HEARTBEAT of the vehicle (armed, PX4 mode)
:class:`LandedState`   EXTENDED_SYS_STATE
:class:`BatteryState`  SYS_STATUS (the battery's voltage and current)
:class:`TimesyncReply` TIMESYNC answering a request (``tc1`` > 0; PX4's own
                       requests give none)
=====================  =========================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from math import isfinite
from typing import Any, Literal

from pymavlink.dialects.v20 import common as mavlink2

from companion.frames import (
    enu_from_ned_floats,
    euler_zyx_from_quaternion,
    flu_from_frd,
    flu_from_frd_floats,
    quaternion_enu_flu_from_ned_frd_floats,
    rotation_from_quaternion,
)
from companion.link.errors import TelemetryError
from companion.link.px4_modes import Px4Mode, decode_custom_mode

__all__ = [
    "BatteryState",
    "BodyRates",
    "ImuSample",
    "LandedState",
    "PoseSource",
    "TelemetryDecoder",
    "TimesyncReply",
    "VehiclePose",
    "VehicleStatus",
]

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
PoseSource = Literal["odometry", "local_position"]

_LANDED_NAMES = {
    mavlink2.MAV_LANDED_STATE_UNDEFINED: "UNDEFINED",
    mavlink2.MAV_LANDED_STATE_ON_GROUND: "ON_GROUND",
    mavlink2.MAV_LANDED_STATE_IN_AIR: "IN_AIR",
    mavlink2.MAV_LANDED_STATE_TAKEOFF: "TAKEOFF",
    mavlink2.MAV_LANDED_STATE_LANDING: "LANDING",
}


@dataclass(frozen=True)
class VehiclePose:
    """Vehicle pose in ENU / FLU, and what the autopilot's estimator says of its quality."""

    time_usec: int
    """Vehicle time of the estimate [us since boot]."""
    position_enu_m: Vec3
    velocity_enu_m_s: Vec3 | None
    """None when the autopilot reports no valid velocity (NaN)."""
    q_enu_flu: Quat
    """Attitude, body FLU -> world ENU, ``[w, x, y, z]`` with w >= 0."""
    position_var_m2: Vec3 | None = None
    """Variances of the position, world ENU axes [m^2] (ODOMETRY pose_covariance); None
    when not reported (NaN, or LOCAL_POSITION_NED)."""
    velocity_var_m2_s2: Vec3 | None = None
    """Variances of the velocity, world ENU axes [m^2/s^2]; None when not reported."""
    reset_counter: int | None = None
    """The estimator's reset counter (ODOMETRY): it changes when the estimate jumps."""

    @property
    def time_boot_ms(self) -> int:
        """Vehicle time [ms since boot] (truncated)."""
        return self.time_usec // 1000

    @property
    def time_s(self) -> float:
        """Vehicle time [s since boot]."""
        return self.time_usec * 1e-6

    def euler_zyx_rad(self) -> Vec3:
        """(phi, theta, psi) [rad] with R = Rz(psi) Ry(theta) Rx(phi) (DESIGN.md section 2)."""
        return euler_zyx_from_quaternion(self.q_enu_flu)


@dataclass(frozen=True)
class BodyRates:
    """Angular velocity of the body, body FLU [rad/s]."""

    time_boot_ms: int
    omega_flu_rad_s: Vec3


@dataclass(frozen=True)
class ImuSample:
    """One HIGHRES_IMU sample: accelerometer specific force [m/s^2] (about +9.81 on z at
    rest) and gyro rates [rad/s], both body FLU."""

    time_boot_ms: int
    specific_force_flu_m_s2: Vec3
    omega_flu_rad_s: Vec3


@dataclass(frozen=True)
class VehicleStatus:
    """The vehicle's HEARTBEAT: armed flag and PX4 mode.

    ``time_boot_ms`` is the latest vehicle time seen before it (HEARTBEAT has no clock),
    or None before any timed message.
    """

    time_boot_ms: int | None
    armed: bool
    mode: Px4Mode
    system_status: int
    """MAV_STATE (3 standby, 4 active, 5 critical, 6 emergency, ...)."""

    @property
    def mode_name(self) -> str:
        return self.mode.name


@dataclass(frozen=True)
class LandedState:
    """EXTENDED_SYS_STATE's landed state (MAV_LANDED_STATE) and its name."""

    time_boot_ms: int | None
    landed_state: int
    name: str

    @property
    def on_ground(self) -> bool:
        return self.landed_state == mavlink2.MAV_LANDED_STATE_ON_GROUND


@dataclass(frozen=True)
class BatteryState:
    """The battery as SYS_STATUS reports it (PX4: its battery_status topic)."""

    time_boot_ms: int | None
    """Latest vehicle time seen before it [ms] (SYS_STATUS has no clock)."""
    voltage_v: float | None
    """Battery voltage [V]; None when not measured (UINT16_MAX)."""
    current_a: float | None
    """Current drawn [A]; None when not measured (-1)."""


@dataclass(frozen=True)
class TimesyncReply:
    """The vehicle's answer to a TIMESYNC request (:mod:`companion.mission.round_trip`)."""

    tc1_ns: int
    """The vehicle's clock when the request came in [ns]."""
    ts1_ns: int
    """The request's own timestamp, echoed [ns]."""


def _finite(reason: str, values: Any) -> tuple[float, ...]:
    out = tuple(map(float, values))
    if not all(map(isfinite, out)):
        raise TelemetryError(reason, f"non-finite value in {out}")
    return out


def _vec3_enu(values: Any, reason: str) -> Vec3:
    return enu_from_ned_floats(*_finite(reason, values))


def _vec3_flu(values: Any, reason: str) -> Vec3:
    return flu_from_frd_floats(*_finite(reason, values))


def _variances(covariance: Any) -> Vec3 | None:
    """The x, y, z diagonal of a MAVLink upper-triangle 6x6 covariance (entries 0, 6, 11),
    NED axes reordered to ENU; None when not reported (NaN or negative)."""
    try:
        n, e, d = float(covariance[0]), float(covariance[6]), float(covariance[11])
    except (TypeError, IndexError):
        return None
    if isfinite(n) and isfinite(e) and isfinite(d) and n >= 0.0 and e >= 0.0 and d >= 0.0:
        return (e, n, d)
    return None


def _q_enu_flu(q_ned_frd: Any) -> Quat:
    q = _finite("bad_quaternion", q_ned_frd)
    w, x, y, z = q
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if abs(norm - 1.0) > 1e-2:
        raise TelemetryError("bad_quaternion", f"norm {norm:.4g} is not 1")
    return quaternion_enu_flu_from_ned_frd_floats(q)


class TelemetryDecoder:
    """Turns the vehicle's MAVLink messages into the samples above (pure, no I/O).

    Parameters
    ----------
    pose_from : {"odometry", "local_position"}
        Which stream makes :class:`VehiclePose` and :class:`BodyRates` (one source only, so
        that two estimator outputs are never interleaved).
    """

    def __init__(self, pose_from: PoseSource = "odometry") -> None:
        if pose_from not in ("odometry", "local_position"):
            raise ValueError(f"pose_from must be 'odometry' or 'local_position', not {pose_from!r}")
        self.pose_from = pose_from
        self.time_boot_ms: int | None = None
        """Latest vehicle time seen [ms]."""
        self._attitude: Quat | None = None

    def _clock(self, time_boot_ms: int) -> int:
        self.time_boot_ms = int(time_boot_ms)
        return self.time_boot_ms

    def decode(self, msg: Any) -> tuple[object, ...]:
        """Samples made by one message (none for a message type not listed above)."""
        kind = msg.get_type()
        if kind == "ODOMETRY":
            return self.odometry(msg)
        if kind == "ATTITUDE_QUATERNION":
            return self._attitude_quaternion(msg) if self.pose_from == "local_position" else ()
        if kind == "LOCAL_POSITION_NED":
            return self._local_position(msg) if self.pose_from == "local_position" else ()
        if kind == "HIGHRES_IMU":
            t = self._clock(msg.time_usec // 1000)
            force = _vec3_flu((msg.xacc, msg.yacc, msg.zacc), "bad_imu")
            gyro = _vec3_flu((msg.xgyro, msg.ygyro, msg.zgyro), "bad_imu")
            return (ImuSample(t, force, gyro),)
        if kind == "HEARTBEAT":
            armed = bool(msg.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
            mode = decode_custom_mode(msg.custom_mode)
            return (VehicleStatus(self.time_boot_ms, armed, mode, int(msg.system_status)),)
        if kind == "SYS_STATUS":
            millivolts, centiamps = int(msg.voltage_battery), int(msg.current_battery)
            return (
                BatteryState(
                    self.time_boot_ms,
                    None if millivolts == 0xFFFF else millivolts * 1e-3,
                    None if centiamps < 0 else centiamps * 1e-2,
                ),
            )
        if kind == "EXTENDED_SYS_STATE":
            state = int(msg.landed_state)
            if state not in _LANDED_NAMES:
                raise TelemetryError("bad_landed_state", str(state))
            return (LandedState(self.time_boot_ms, state, _LANDED_NAMES[state]),)
        if kind == "TIMESYNC":
            tc1 = int(msg.tc1)
            return (TimesyncReply(tc1, int(msg.ts1)),) if tc1 > 0 else ()
        return ()

    def odometry(self, msg: Any) -> tuple[object, ...]:
        """:class:`VehiclePose` and :class:`BodyRates` of one ODOMETRY (pymavlink's message,
        or the link's :class:`~companion.link.cycle_codec.OdometryFields`: the same field
        names); none unless ``pose_from`` is ``"odometry"``."""
        if self.pose_from != "odometry":
            return ()
        if msg.frame_id != mavlink2.MAV_FRAME_LOCAL_NED:
            raise TelemetryError("unsupported_frame", f"ODOMETRY frame_id {msg.frame_id}")
        q = _q_enu_flu(msg.q)
        position = _vec3_enu((msg.x, msg.y, msg.z), "bad_position")
        velocity: Vec3 | None = None
        vx, vy, vz = v = (float(msg.vx), float(msg.vy), float(msg.vz))
        if isfinite(vx) and isfinite(vy) and isfinite(vz):
            if msg.child_frame_id == mavlink2.MAV_FRAME_LOCAL_NED:
                velocity = enu_from_ned_floats(vx, vy, vz)
            elif msg.child_frame_id == mavlink2.MAV_FRAME_BODY_FRD:
                world = rotation_from_quaternion(q) @ flu_from_frd(v)
                velocity = (float(world[0]), float(world[1]), float(world[2]))
            else:
                raise TelemetryError(
                    "unsupported_frame", f"ODOMETRY child_frame_id {msg.child_frame_id}"
                )
        rates = _vec3_flu((msg.rollspeed, msg.pitchspeed, msg.yawspeed), "bad_rates")
        time_usec = int(msg.time_usec)
        t = self.time_boot_ms = time_usec // 1000
        pose = VehiclePose(
            time_usec,
            position,
            velocity,
            q,
            _variances(msg.pose_covariance),
            _variances(msg.velocity_covariance),
            int(msg.reset_counter),
        )
        return (pose, BodyRates(t, rates))

    def _attitude_quaternion(self, msg: Any) -> tuple[object, ...]:
        q = _q_enu_flu((msg.q1, msg.q2, msg.q3, msg.q4))
        rates = _vec3_flu((msg.rollspeed, msg.pitchspeed, msg.yawspeed), "bad_rates")
        self._attitude = q
        return (BodyRates(self._clock(msg.time_boot_ms), rates),)

    def _local_position(self, msg: Any) -> tuple[object, ...]:
        if self._attitude is None:
            raise TelemetryError("no_attitude_yet", "LOCAL_POSITION_NED before any attitude")
        position = _vec3_enu((msg.x, msg.y, msg.z), "bad_position")
        v = (float(msg.vx), float(msg.vy), float(msg.vz))
        velocity = _vec3_enu(v, "bad_velocity") if all(map(math.isfinite, v)) else None
        t = self._clock(msg.time_boot_ms)
        return (VehiclePose(t * 1000, position, velocity, self._attitude),)

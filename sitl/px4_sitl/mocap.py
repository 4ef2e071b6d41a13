"""Motion capture for PX4 SIH: SIH's ground truth in, a motion-capture pose out.

The paper's lab flies with motion capture (100 Hz Vicon) and no GPS. ``sitl sih
--navigation mocap`` makes PX4 navigate that way: SIH's GPS simulation off and EKF2 on
external vision (:func:`mocap_parameters`), and a :class:`MocapFeeder` thread that reads
SIH's ground truth (HIL_STATE_QUATERNION on the SIH display link, asked for at the mocap
rate with SET_MESSAGE_INTERVAL) and sends PX4 the pose a motion-capture system would
(ODOMETRY, position and attitude with seeded noise, no velocity) over a MAVLink link of
its own, which the host starts in PX4 (``mavlink start``) so that no ground station's or
companion's link is taken over.

Frames and units: the mocap frame is local NED at SIH's origin (``SIH_LOC_LAT0``,
``SIH_LOC_LON0``, ``SIH_LOC_H0`` as PX4 stores them, in float32): x north, y east, z down
[m]; the body frame is FRD; quaternions are (w, x, y, z) rotating FRD vectors into NED,
with w >= 0. SIH's global position is its NED position through the flat-earth map of
:class:`sitl.px4.geo.GeoReference` (PX4 ``simulator_sih``: radius 6371 km), so the
inverse map recovers SIH's NED position.

Measured with the PX4 build of ``PX4_SITL_DIR`` (v1.17.0-alpha1), which set the choices:

- ODOMETRY with ``frame_id`` MAV_FRAME_LOCAL_FRD: EKF2 fuses position and yaw but never
  declares its yaw aligned (``cs_yaw_align`` stays False): "Preflight Fail: heading
  estimate not stable" for ever, and no arming. With MAV_FRAME_LOCAL_NED (a mocap frame
  whose x axis points north) it is ready for takeoff about 2 s after the first pose.
- ``estimator_type`` MAV_ESTIMATOR_TYPE_MOCAP goes to PX4's ``mocap_odometry`` topic,
  which EKF2 does not read: the pose is sent as MAV_ESTIMATOR_TYPE_VISION.
- With EKF2's barometer and range-finder height on beside vision, the height estimate
  wandered 3-6 cm at rest; with vision alone it stays within 3 mm of the truth.
- HIL_STATE_QUATERNION carries ``time_usec`` 0 and latitude / longitude in int32 1e-7
  degrees: the truth the feeder sees is quantised to 11 mm north and 7.5 mm east (1 mm
  in altitude), under EKF2's own floor ``EKF2_EVP_NOISE`` >= 10 mm.
- SET_MESSAGE_INTERVAL for HIL_STATE_QUATERNION on the SIH link is ACCEPTED; 100 Hz
  asked arrives at about 97 Hz.
- PX4 stamps the pose on arrival (its timesync with the feeder never converges), so
  ``EKF2_EV_DELAY`` is the truth's age on arrival: up to one SIH step (4 ms) plus the
  loopback trip, 5 ms, scaled by the simulation speed factor.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sitl.px4.endpoint import MavlinkEndpoint
from sitl.px4.geo import GeoReference
from sitl.px4_sitl.launcher import Px4Ports

__all__ = [
    "DEFAULT_ORIGIN",
    "MocapFeeder",
    "MocapPose",
    "mocap_parameters",
    "noisy_pose",
    "odometry_message",
    "sih_origin",
    "truth_pose",
]

DEFAULT_ORIGIN = GeoReference(47.397742, 8.545594, 489.4)
"""SIH's default origin (PX4's SITL home, Zurich): latitude, longitude [deg], AMSL [m]."""
EV_DELAY_S = 5e-3
"""Age of a truth sample when PX4 receives the pose at 1x speed [s] (module docstring)."""
_EV_CTRL_HPOS_VPOS_YAW = 1 | 2 | 8
_HGT_REF_VISION = 3
_MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY = 197
_INTERVAL_RETRY_S = 1.0


def sih_origin(origin: GeoReference) -> GeoReference:
    """``origin`` as SIH holds it: its parameters are float32."""
    return GeoReference(
        float(np.float32(origin.latitude_deg)),
        float(np.float32(origin.longitude_deg)),
        float(np.float32(origin.altitude_amsl_m)),
    )


def mocap_parameters(origin: GeoReference = DEFAULT_ORIGIN, speed: float = 1.0) -> dict:
    """PX4 parameters for flying on motion capture without GPS, SIH at ``origin``.

    SIH's GPS simulation off; EKF2 without GNSS, barometer and range finder, fusing
    external vision position (horizontal and vertical) and yaw, vision as the height
    reference, the pose's own variances bounded below by EKF2's minimum noises (10 mm,
    0.05 rad), and the pose's age on arrival as its delay (``speed``: PX4's simulation
    speed factor, PX4's clock runs that much faster than the wall clock).
    """
    return {
        "SENS_EN_GPSSIM": 0,
        "EKF2_GPS_CTRL": 0,
        "EKF2_BARO_CTRL": 0,
        "EKF2_RNG_CTRL": 0,
        "EKF2_EV_CTRL": _EV_CTRL_HPOS_VPOS_YAW,
        "EKF2_HGT_REF": _HGT_REF_VISION,
        "EKF2_EV_NOISE_MD": 0,
        "EKF2_EVP_NOISE": 0.01,
        "EKF2_EVA_NOISE": 0.05,
        "EKF2_EV_DELAY": round(EV_DELAY_S * 1e3 * speed, 1),
        "SIH_LOC_LAT0": origin.latitude_deg,
        "SIH_LOC_LON0": origin.longitude_deg,
        "SIH_LOC_H0": origin.altitude_amsl_m,
    }


@dataclass(frozen=True)
class MocapPose:
    """A rigid-body pose in the mocap frame (module docstring)."""

    position_ned_m: tuple[float, float, float]
    """Body origin, local NED [m]."""
    q_ned_frd: tuple[float, float, float, float]
    """Attitude (w, x, y, z), FRD body -> NED, unit, w >= 0."""


def _canonical(q: np.ndarray) -> tuple[float, float, float, float]:
    q = q / np.linalg.norm(q)
    w, x, y, z = (-q if q[0] < 0.0 else q).tolist()
    return (w, x, y, z)


def truth_pose(truth: mavlink.MAVLink_hil_state_quaternion_message, origin: GeoReference):
    """SIH's ground truth (HIL_STATE_QUATERNION) as a :class:`MocapPose` about ``origin``
    (SIH's origin, :func:`sih_origin`)."""
    north, east, down = origin.ned_from_global(truth.lat * 1e-7, truth.lon * 1e-7, truth.alt * 1e-3)
    q = _canonical(np.asarray(truth.attitude_quaternion, dtype=float))
    return MocapPose((north, east, down), q)


def noisy_pose(
    pose: MocapPose, rng: np.random.Generator, position_std_m: float, attitude_std_rad: float
) -> MocapPose:
    """``pose`` as a motion-capture system measures it: white Gaussian noise of
    ``position_std_m`` [m] on each NED axis and a small body-frame rotation of
    ``attitude_std_rad`` [rad] per FRD axis."""
    position = np.asarray(pose.position_ned_m) + rng.normal(0.0, position_std_m, 3)
    rotation = rng.normal(0.0, attitude_std_rad, 3)
    angle = float(np.linalg.norm(rotation))
    axis = rotation / angle if angle > 0.0 else np.zeros(3)
    w, x, y, z = pose.q_ned_frd
    dw, (dx, dy, dz) = math.cos(0.5 * angle), math.sin(0.5 * angle) * axis
    q = np.array(
        [
            w * dw - x * dx - y * dy - z * dz,
            w * dx + x * dw + y * dz - z * dy,
            w * dy - x * dz + y * dw + z * dx,
            w * dz + x * dy - y * dx + z * dw,
        ]
    )
    north, east, down = position.tolist()
    return MocapPose((north, east, down), _canonical(q))


def odometry_message(
    pose: MocapPose, time_usec: int, position_std_m: float, attitude_std_rad: float
) -> mavlink.MAVLink_odometry_message:
    """ODOMETRY of a vision pose: frame MAV_FRAME_LOCAL_NED, child MAV_FRAME_BODY_FRD,
    pose variances on the diagonal, velocity and rates unknown (NaN), quality 100."""
    pose_covariance = [0.0] * 21  # upper triangle of the 6x6 (x, y, z, roll, pitch, yaw)
    for index in (0, 6, 11):
        pose_covariance[index] = position_std_m**2
    for index in (15, 18, 20):
        pose_covariance[index] = attitude_std_rad**2
    nan = math.nan
    return mavlink.MAVLink_odometry_message(
        time_usec,
        mavlink.MAV_FRAME_LOCAL_NED,
        mavlink.MAV_FRAME_BODY_FRD,
        *pose.position_ned_m,
        list(pose.q_ned_frd),
        nan,
        nan,
        nan,
        nan,
        nan,
        nan,
        pose_covariance,
        [nan] * 21,
        0,
        mavlink.MAV_ESTIMATOR_TYPE_VISION,
        100,
    )


class MocapFeeder:
    """A thread that turns SIH's ground truth into motion-capture poses for PX4.

    Parameters
    ----------
    ports
        The PX4 instance's ports (the SIH display link's two ports).
    origin
        SIH's origin as PX4 holds it (:func:`sih_origin`).
    rng
        Seeded generator of the measurement noise.
    rate_hz
        Poses per second of PX4 time (HIL_STATE_QUATERNION is asked for at this rate).
    speed
        PX4's simulation speed factor (PX4 seconds per wall-clock second).
    position_std_m, attitude_std_rad
        Noise of the poses [m], [rad] (defaults: the paper's lab, 1 mm and 2 mrad).

    :meth:`open` binds both UDP endpoints on 127.0.0.1 (the truth link's port is
    ``ports.sih_display_remote``; the mocap link's is free, :attr:`local_port`), so that
    PX4's mocap link can be pointed at it; :meth:`start` (after :meth:`connect`) starts the
    thread; :meth:`close` (idempotent) stops it and releases the ports. A context manager.
    """

    def __init__(
        self,
        ports: Px4Ports,
        origin: GeoReference,
        rng: np.random.Generator,
        *,
        rate_hz: float = 100.0,
        speed: float = 1.0,
        position_std_m: float = 1e-3,
        attitude_std_rad: float = 2e-3,
    ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate_hz must be positive, got {rate_hz!r}")
        if not (math.isfinite(speed) and speed > 0.0):
            raise ValueError(f"speed must be a positive factor, got {speed!r}")
        if not (position_std_m >= 0.0 and attitude_std_rad >= 0.0):
            raise ValueError("noise standard deviations must be >= 0")
        self.origin = origin
        self.rate_hz = float(rate_hz)
        self.speed = float(speed)
        self.position_std_m = float(position_std_m)
        self.attitude_std_rad = float(attitude_std_rad)
        self._rng = rng
        self._system_id = ports.instance + 1
        self._truth_link = MavlinkEndpoint(
            ports.sih_display_remote,
            ports.sih_display_local,
            system_id=self._system_id,
            component_id=_MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY,
        )
        self._mocap_link = MavlinkEndpoint(
            0, 0, system_id=self._system_id, component_id=_MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY
        )
        self._lock = threading.Lock()
        self._truth: tuple[float, MocapPose] | None = None
        self.truth_samples = 0
        """HIL_STATE_QUATERNION messages received."""
        self.poses_sent = 0
        """ODOMETRY messages sent."""
        self.interval_accepted = False
        """PX4 acknowledged the SET_MESSAGE_INTERVAL for the truth stream."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ---------------------------------------------------------------- lifecycle

    def open(self) -> None:
        """Bind the truth and mocap endpoints (127.0.0.1)."""
        try:
            self._truth_link.open()
            self._mocap_link.open()
        except OSError:
            self.close()
            raise

    @property
    def local_port(self) -> int:
        """The UDP port the mocap link sends from: PX4's mocap link sends here."""
        return self._mocap_link.local_address[1]

    def connect(self, px4_port: int) -> None:
        """Send the poses to PX4's mocap link, bound on ``px4_port``."""
        self._mocap_link.remote_address = ("127.0.0.1", int(px4_port))

    def start(self) -> None:
        """Start forwarding (after :meth:`open` and :meth:`connect`)."""
        if self._thread is not None:
            raise RuntimeError("the mocap feeder is already running")
        if not self._truth_link.is_open:
            raise RuntimeError("open the mocap feeder before starting it")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="mocap-feeder", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread and release the ports; safe to call twice."""
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=5.0)
            self._thread = None
        self._truth_link.close()
        self._mocap_link.close()

    def __enter__(self) -> MocapFeeder:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def truth(self) -> tuple[float, MocapPose] | None:
        """The latest ground truth (``time.monotonic()`` of its arrival [s], pose), or
        None before the first."""
        with self._lock:
            return self._truth

    # ------------------------------------------------------------------- thread

    def _request_interval(self) -> None:
        params = [mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION, 1e6 / self.rate_hz, 0, 0, 0, 0, 0]
        self._truth_link.send(
            mavlink.MAVLink_command_long_message(
                self._system_id, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, *params
            )
        )

    def _run(self) -> None:
        # PX4 time runs ``speed`` times faster than the wall clock; a burst of truth
        # samples read at once becomes one pose, the latest.
        min_gap_s = 0.8 / (self.rate_hz * self.speed)
        last_sent = asked = -math.inf
        while not self._stop.wait(1e-3):
            now = time.monotonic()
            if not self.interval_accepted and now - asked >= _INTERVAL_RETRY_S:
                self._request_interval()
                asked = now
            latest = None
            for message in self._truth_link.receive():
                kind = message.get_type()
                if kind == "HIL_STATE_QUATERNION":
                    latest = message
                    self.truth_samples += 1
                elif (
                    kind == "COMMAND_ACK"
                    and message.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
                ):
                    self.interval_accepted = message.result == mavlink.MAV_RESULT_ACCEPTED
            self._mocap_link.receive()  # PX4's heartbeats on the mocap link: not needed
            if latest is None:
                continue
            pose = truth_pose(latest, self.origin)
            with self._lock:
                self._truth = (now, pose)
            if now - last_sent >= min_gap_s:
                measured = noisy_pose(pose, self._rng, self.position_std_m, self.attitude_std_rad)
                stamp_us = int(now * 1e6)  # the mocap system's own clock
                self._mocap_link.send(
                    odometry_message(measured, stamp_us, self.position_std_m, self.attitude_std_rad)
                )
                self.poses_sent += 1
                last_sent = now

"""The servos' torque constants measured before every take-off, against the empty arm's
gravity (pure: no I/O, no clock; times are vehicle time [s]).

A Dynamixel servo reports its motor current; the app reads it as joint torque through the
configured torque constant ``Kt`` [N m/A] (:class:`arm_driver.joint.JointConfig`). A
servo whose ``Kt`` is 12 % off its datasheet value moves the estimated payload centre of
mass by about a fifth, and nothing in flight tells. So, with the vehicle still on the
ground and disarmed, the control loop holds the empty arm at a few poses
(:func:`check_poses`) instead of stowed, reaches each by a minimum-jerk move, waits until
the joints are still and averages what the servos read there (:class:`ServoCheck`); then
each joint's ``Kt`` is fitted as ``companion arm calibrate`` fits it
(:func:`~companion.calibration.servo.fit_torque_constant`: ``i = tau / Kt`` through the
origin, ``tau`` the model's gravity torque of the empty arm at the read angles and the
vehicle's attitude, ``i`` the read torque over the configured ``Kt``).

The poses are chosen so that the arm never goes lower than it hangs stowed (the vehicle
stood on its gear with the arm stowed, so the ground lies below that) nor higher than a
straight arm at joint 1's upper limit (the config's clearance of the propellers), and
within the joint limits; they put the links level and tilted, where the gravity torque
on each joint is large, and approach the angles from both sides.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.calibration.servo import TorqueConstantFit, fit_torque_constant, model_torque_n_m
from companion.config import CompanionConfig
from companion.mission.pickup import min_jerk
from companion.model import ManipulatorModel

__all__ = [
    "CANDIDATE_POSES_RAD",
    "MIN_POSES",
    "ServoCheck",
    "ServoCheckTimes",
    "TorqueConstantSources",
    "check_poses",
    "fit_servo_check",
    "torque_constant_sources",
]

FloatArray = NDArray[np.float64]

CANDIDATE_POSES_RAD = (
    (0.0, -0.8),
    (0.0, 0.0),
    (0.35, -0.35),
    (-0.35, 0.35),
    (0.0, -0.5 * math.pi),
)
"""(eta1, eta2) [rad] the check may visit, in order: link 2 down 46 deg, the arm straight
forward, link 1 up 20 deg with link 2 level, link 1 down 20 deg with link 2 level, and the
stowed pose last (where the mission starts from)."""
MIN_POSES = 4
"""Fewest poses a torque constant is fitted from."""


@dataclass(frozen=True)
class ServoCheckTimes:
    """Durations of the check (vehicle time [s]) and when a joint counts as still."""

    move_s: float = 1.0
    settle_s: float = 0.3
    average_s: float = 0.4
    pose_timeout_s: float = 3.0
    still_rad_s: float = 0.05


def check_poses(
    limits_rad: Sequence[tuple[float, float]],
    link_lengths_m: tuple[float, float],
    stow_rad: tuple[float, float],
) -> list[tuple[float, float]]:
    """The poses of :data:`CANDIDATE_POSES_RAD` that lie within the joint limits
    ``limits_rad`` [rad] and between the stowed arm's lowest point and a straight arm's
    height at joint 1's upper limit (module docstring); links ``(l1, l2)`` [m]."""
    top = sum(link_lengths_m) * math.sin(limits_rad[0][1])
    bottom = min(_heights(stow_rad, link_lengths_m))
    poses = []
    for pose in CANDIDATE_POSES_RAD:
        within = all(low <= eta <= high for eta, (low, high) in zip(pose, limits_rad, strict=True))
        heights = _heights(pose, link_lengths_m)
        if within and min(heights) >= bottom - 1e-9 and max(heights) <= top + 1e-9:
            poses.append(pose)
    return poses


def _heights(pose: Sequence[float], lengths: tuple[float, float]) -> tuple[float, float]:
    """Heights [m] of the elbow and the tip above joint 1 (joint frame: eta up from forward,
    link 2 at eta1 + eta2)."""
    elbow = lengths[0] * math.sin(pose[0])
    return elbow, elbow + lengths[1] * math.sin(pose[0] + pose[1])


@dataclass
class _Reading:
    eta_rad: list[FloatArray] = field(default_factory=list)
    tilt_rad: list[FloatArray] = field(default_factory=list)
    torque_n_m: list[FloatArray] = field(default_factory=list)


class ServoCheck:
    """The poses in turn (module docstring): :meth:`target` is the joints' desired state for
    the control loop at a time, :meth:`update` takes what was read on each cycle.

    Parameters
    ----------
    poses
        (eta1, eta2) [rad] to visit, from :func:`check_poses`.
    start_rad
        The joints' angles when the check starts [rad].
    t_s
        Vehicle time the check starts [s].
    times
        Durations and stillness (:class:`ServoCheckTimes`).
    """

    def __init__(
        self,
        poses: Sequence[tuple[float, float]],
        start_rad: ArrayLike,
        t_s: float,
        times: ServoCheckTimes | None = None,
    ) -> None:
        if not poses:
            raise ValueError("the servo check needs at least one pose")
        self.times = times or ServoCheckTimes()
        self._poses = [np.array(p, dtype=np.float64) for p in poses]
        self._from = np.array(start_rad, dtype=np.float64)
        self._index = 0
        self._moved_at_s = t_s
        self._still_since_s = math.nan
        self._reading = _Reading()
        self.readings: list[tuple[FloatArray, FloatArray, FloatArray]] = []
        """Per pose reached: mean (eta [rad], vehicle roll and pitch [rad], read joint
        torque [N m])."""
        self.missed: list[tuple[float, float]] = []
        """Poses the joints did not come to rest at within the timeout."""

    @property
    def finished(self) -> bool:
        return self._index >= len(self._poses)

    def target(self, t_s: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The joints' desired (angle [rad], rate [rad/s], acceleration [rad/s^2]) at
        ``t_s``: the minimum-jerk move to the current pose, then the pose."""
        goal = self._poses[min(self._index, len(self._poses) - 1)]
        if self.finished:
            return goal, np.zeros(2), np.zeros(2)
        return min_jerk(t_s - self._moved_at_s, self.times.move_s, self._from, goal)

    def update(
        self,
        t_s: float,
        eta_rad: ArrayLike,
        eta_dot_rad_s: ArrayLike,
        tilt_rad: ArrayLike,
        torque_n_m: ArrayLike,
    ) -> None:
        """One cycle's joint angles and rates, vehicle roll and pitch and the joint torques
        the servos read (through the configured torque constants)."""
        if self.finished:
            return
        times = self.times
        since_move = t_s - self._moved_at_s
        if since_move < times.move_s:
            return
        if since_move > times.move_s + times.pose_timeout_s:
            goal = self._poses[self._index]
            self.missed.append((float(goal[0]), float(goal[1])))
            self._next(t_s)
            return
        still = float(np.max(np.abs(eta_dot_rad_s))) < times.still_rad_s
        if not still:
            self._still_since_s = math.nan
            self._reading = _Reading()
            return
        if math.isnan(self._still_since_s):
            self._still_since_s = t_s
        if t_s - self._still_since_s < times.settle_s:
            return
        reading = self._reading
        reading.eta_rad.append(np.array(eta_rad, dtype=np.float64))
        reading.tilt_rad.append(np.array(tilt_rad, dtype=np.float64))
        reading.torque_n_m.append(np.array(torque_n_m, dtype=np.float64))
        if t_s - self._still_since_s >= times.settle_s + times.average_s:
            self.readings.append(
                (
                    np.mean(reading.eta_rad, axis=0),
                    np.mean(reading.tilt_rad, axis=0),
                    np.mean(reading.torque_n_m, axis=0),
                )
            )
            self._next(t_s)

    def _next(self, t_s: float) -> None:
        self._from = self._poses[self._index]
        self._index += 1
        self._moved_at_s = t_s
        self._still_since_s = math.nan
        self._reading = _Reading()


def fit_servo_check(
    readings: Sequence[tuple[FloatArray, FloatArray, FloatArray]],
    model: ManipulatorModel,
    theta: Sequence[float],
    believed_kt_n_m_per_a: Sequence[float],
    current_resolution_a: float,
) -> list[TorqueConstantFit]:
    """Each joint's torque constant from the check's ``readings`` (:attr:`ServoCheck.readings`)
    of the empty arm (``theta`` its nominal parameters): the read torque over the
    ``believed_kt_n_m_per_a`` it was read through is the current [A]; fewer than
    :data:`MIN_POSES` readings give fits that say so."""
    if readings:
        eta = np.array([r[0] for r in readings])
        tilt = np.array([r[1] for r in readings])
        read = np.array([r[2] for r in readings])
        tau = model_torque_n_m(model, theta, eta, np.zeros_like(eta), tilt)
    else:
        tau = read = np.zeros((0, len(believed_kt_n_m_per_a)))
    return [
        fit_torque_constant(tau[:, j], read[:, j] / kt, current_resolution_a)
        for j, kt in enumerate(believed_kt_n_m_per_a)
    ]


@dataclass(frozen=True)
class TorqueConstantSources:
    """Where each joint's torque constant comes from before the flight."""

    per_joint: dict[str, dict[str, str | float]]
    """Joint name -> {"source": "calibrated" | "datasheet", "n_m_per_a": Kt [N m/A]}."""
    check: bool
    """The servo check is to measure them (``flight.servo_check``)."""
    note: str | None
    """Which joints fly on datasheet values, when they are not checked."""


def torque_constant_sources(config: CompanionConfig) -> TorqueConstantSources:
    """Each joint's torque constant and its source (a Dynamixel's current reads as torque
    through it; a DroneCAN actuator reports its own torque: nothing to check), and whether
    the servo check is to measure them: ``flight.servo_check`` "always", or "auto" with a
    joint not ``torque_calibrated``."""
    bus = config.arm_bus
    if bus is None or not bus.url.startswith("dynamixel"):
        return TorqueConstantSources({}, False, None)
    per_joint: dict[str, dict[str, str | float]] = {
        j.name: {
            "source": "calibrated" if j.torque_calibrated else "datasheet",
            "n_m_per_a": j.torque_constant_n_m_per_a,
        }
        for j in bus.joints
    }
    datasheet = [j.name for j in bus.joints if not j.torque_calibrated]
    check = config.flight.servo_check
    if check == "always" or (check == "auto" and datasheet):
        return TorqueConstantSources(per_joint, True, None)
    note = None
    if datasheet:
        note = (
            f"joints {', '.join(datasheet)} fly on the datasheet's torque constants, not "
            "their servos' own: the payload's centre of mass is estimated from them "
            "(12 % off moves it by a fifth); run `companion arm calibrate --write`"
        )
    return TorqueConstantSources(per_joint, False, note)

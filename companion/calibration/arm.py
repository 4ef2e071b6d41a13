"""The bus work of ``companion arm calibrate``: the arm through its poses and sweeps.

The plan and the fits are pure (:mod:`companion.calibration.servo`); this module moves the
arm and reads the servos (:func:`measure`), then hands the readings to the fits
(:func:`fit_joints`). Dynamixel only: a DroneCAN actuator reports its own output torque
(:mod:`arm_driver.dronecan.bus`).

Procedure, with the vehicle on the ground or a stand and the arm free to move within its
joint limits:

1. read where the arm is (every joint must be within its limits, else nothing moves);
   torque off, current-based position mode, goal = the present angles, torque on: the
   joints hold where they are (limp for a moment if they were holding already);
2. static poses (:func:`~companion.calibration.servo.static_poses`): each reached by a
   move at :data:`TRANSIT_SPEED_RAD_S`, held until every joint reads zero rate for
   :data:`SETTLE_S`, then :data:`STATIC_READS` reads averaged;
3. sweeps: from the low corner to the high one
   (:func:`~companion.calibration.servo.sweep_corners`) and back, at each of
   :data:`SWEEP_SPEEDS_RAD_S` (the joint with the longest travel at that speed, the other
   slower); every move is the servos' own constant-speed ramp (their Profile Velocity,
   :func:`_ramp`), read at random times; the reads of the middle :data:`SWEEP_MIDDLE` of
   each sweep are kept;
4. back to the start angles, Profile Velocity 0 again (the factory value: goals taken at
   once), then the servos' mode and torque as they were: torque off (limp) if it was off,
   holding the start angles in their position mode if they held, off if they were in
   current mode (no controller is left to command them).

Safety: every joint's torque is limited to ``torque_limit_n_m`` (the servos' own current
limit in current-based position mode, at the config's torque constant); every goal lies
within the joint limits (:class:`~arm_driver.bus.ArmBus` refuses others before sending);
a joint that does not reach a goal within :data:`ARRIVAL_TIMEOUT_S` stops the procedure.
On any error or cancellation (Ctrl-C) torque goes off at once, as far as the servos still
answer, and the error is raised.

Current: the bus is opened with the config's torque constants and no friction, so a
joint's read torque divided by its torque constant is the servo's present current [A],
signed as the joint.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from arm_driver.bus import JointConfig, JointState, OperatingMode, open_bus
from arm_driver.dynamixel.bus import DynamixelBus
from arm_driver.dynamixel.units import CURRENT_A_PER_UNIT
from arm_driver.errors import ArmDriverError
from companion.calibration.servo import (
    FrictionFit,
    TorqueConstantFit,
    fit_friction,
    fit_torque_constant,
    model_torque_n_m,
    static_poses,
    sweep_corners,
)
from companion.model import ManipulatorModel

__all__ = [
    "ARRIVAL_TIMEOUT_S",
    "CYCLE_S",
    "READ_PERIOD_S",
    "SETTLE_S",
    "STATIC_READS",
    "SWEEP_MIDDLE",
    "SWEEP_SPEEDS_RAD_S",
    "TRANSIT_SPEED_RAD_S",
    "JointCalibration",
    "Readings",
    "calibration_joints",
    "fit_joints",
    "measure",
]

FloatArray = NDArray[np.float64]

SWEEP_SPEEDS_RAD_S = (0.5, 1.5)
"""Sweep speeds of the joint with the longest travel [rad/s]: two, so that viscous and
Coulomb friction can be told apart; a tenth and a third of the XM430-W350's 4.8 rad/s
no-load speed."""
TRANSIT_SPEED_RAD_S = 0.8
"""Speed of the moves between static poses [rad/s]."""
READ_PERIOD_S = 0.005
"""Mean time between two reads during a move [s], each drawn in [0.5, 1.5] x this."""
CYCLE_S = 0.01
"""Pause between two reads while the arm settles [s]."""
_SLOWEST_RAD_S = 0.05
"""Profile Velocity of a joint that barely travels in a move [rad/s] (0 would be none:
the servo would jump to its goal)."""
ARRIVAL_TOLERANCE_RAD = math.radians(2.0)
"""How close to its goal a joint must come [rad] (a position loop sags under gravity)."""
ARRIVAL_TIMEOUT_S = 3.0
"""Longest wait for the joints to reach a move's end beyond its planned duration, or to
settle there [s]."""
SETTLE_S = 0.3
"""Time every joint must read zero rate before a static pose is read [s]."""
STATIC_READS = 5
"""Reads averaged at each static pose."""
SWEEP_MIDDLE = (0.15, 0.85)
"""Part of each sweep (fraction of the longest joint travel done) whose reads are kept."""
_POSITION_MODES = (OperatingMode.POSITION, OperatingMode.CURRENT_BASED_POSITION)


@dataclass(frozen=True)
class Readings:
    """What :func:`measure` read, joint order as the config (joint frame, SI units).

    Attributes
    ----------
    static_eta_rad, static_current_a
        Shape (poses, 2): angles [rad] and present currents [A] at rest.
    sweep_eta_rad, sweep_rate_rad_s, sweep_current_a
        Shape (samples, 2): angles [rad], rates [rad/s] and currents [A] at constant speed.
    """

    static_eta_rad: FloatArray
    static_current_a: FloatArray
    sweep_eta_rad: FloatArray
    sweep_rate_rad_s: FloatArray
    sweep_current_a: FloatArray


@dataclass(frozen=True)
class JointCalibration:
    """One joint's fits (:mod:`companion.calibration.servo`)."""

    joint: JointConfig
    torque_constant: TorqueConstantFit
    friction: FrictionFit

    @property
    def problem(self) -> str | None:
        """Why the calibration cannot be trusted, or None."""
        return self.torque_constant.problem or self.friction.problem


def calibration_joints(
    joints: Sequence[JointConfig], torque_limit_n_m: float
) -> tuple[JointConfig, ...]:
    """The joints as the calibration drives them: torque limit at most
    ``torque_limit_n_m`` [N m], no friction (so a read torque over Kt is the current)."""
    return tuple(
        dataclasses.replace(
            joint,
            torque_max_n_m=min(joint.torque_max_n_m, torque_limit_n_m),
            viscous_friction_n_m_s_per_rad=0.0,
            coulomb_friction_n_m=0.0,
        )
        for joint in joints
    )


async def measure(url: str, joints: Sequence[JointConfig], rng: np.random.Generator) -> Readings:
    """Open the bus at ``url`` with ``joints`` (from :func:`calibration_joints`) and run the
    procedure of the module docstring, reading at random times drawn from ``rng`` (see
    :func:`_ramp`); the bus is closed on return.

    Raises
    ------
    ArmDriverError
        A servo error, a lost link, a joint that did not reach a goal; torque was turned
        off (or a note says it could not be).
    ValueError
        The arm is outside its limits at the start (nothing moved).
    """
    async with open_bus(url, joints) as arm:
        if not isinstance(arm, DynamixelBus):
            raise ValueError(f"{url}: the calibration drives Dynamixel servos only")
        states = await arm.read_joint_states()
        start = [states[joint.name].position_rad for joint in joints]
        for joint, angle in zip(joints, start, strict=True):
            low, high = joint.position_min_rad, joint.position_max_rad
            if not low <= angle <= high:
                raise ValueError(
                    f"joint {joint.name!r} is at {math.degrees(angle):.1f} deg, outside its "
                    f"limits [{math.degrees(low):.1f}, {math.degrees(high):.1f}] deg: move it "
                    "inside by hand (nothing was moved)"
                )
        mode, torque = arm.operating_mode, arm.torque_enabled
        try:
            await arm.hold_in_place()
            readings = await _run(arm, joints, rng)
            await _ramp(arm, joints, start, TRANSIT_SPEED_RAD_S, rng)
        except BaseException as error:
            await _torque_off(arm, joints, error)
            raise
        await _restore(arm, joints, start, mode, torque)
        return readings


async def _run(
    arm: DynamixelBus, joints: Sequence[JointConfig], rng: np.random.Generator
) -> Readings:
    limits = [(j.position_min_rad, j.position_max_rad) for j in joints]
    static_eta, static_current = [], []
    for pose in static_poses(limits):
        await _ramp(arm, joints, pose, TRANSIT_SPEED_RAD_S, rng)
        reads = await _settled(arm, joints)
        static_eta.append(np.mean([_angles(r, joints) for r in reads], axis=0))
        static_current.append(np.mean([_currents(r, joints) for r in reads], axis=0))
    low, high = sweep_corners(limits)
    sweep: list[Mapping[str, JointState]] = []
    for speed in SWEEP_SPEEDS_RAD_S:
        await _ramp(arm, joints, low, TRANSIT_SPEED_RAD_S, rng)
        await _settled(arm, joints)
        await _ramp(arm, joints, high, speed, rng, sweep)
        await _ramp(arm, joints, low, speed, rng, sweep)
    return Readings(
        static_eta_rad=_rows(static_eta),
        static_current_a=_rows(static_current),
        sweep_eta_rad=_rows([_angles(r, joints) for r in sweep]),
        sweep_rate_rad_s=_rows([[r[j.name].velocity_rad_s for j in joints] for r in sweep]),
        sweep_current_a=_rows([_currents(r, joints) for r in sweep]),
    )


def _rows(values: Sequence[ArrayLike]) -> FloatArray:
    """Shape (len(values), 2), also when empty."""
    return np.asarray(values, dtype=np.float64).reshape(-1, 2)


def _angles(states: Mapping[str, JointState], joints: Sequence[JointConfig]) -> list[float]:
    return [states[j.name].position_rad for j in joints]


def _currents(states: Mapping[str, JointState], joints: Sequence[JointConfig]) -> list[float]:
    return [states[j.name].torque_n_m / j.torque_constant_n_m_per_a for j in joints]


async def _ramp(
    arm: DynamixelBus,
    joints: Sequence[JointConfig],
    goal: Sequence[float],
    speed_rad_s: float,
    rng: np.random.Generator,
    record: list[Mapping[str, JointState]] | None = None,
) -> None:
    """Move in a straight line from where the joints are to ``goal`` [rad], the joint with
    the longest travel at ``speed_rad_s`` [rad/s] (each joint's Profile Velocity in
    proportion to its travel, one Goal Position each); read at random intervals of
    :data:`READ_PERIOD_S` on average until every joint is within
    :data:`ARRIVAL_TOLERANCE_RAD` of its goal; the reads of the move's middle
    (:data:`SWEEP_MIDDLE` of the longest travel) go to ``record``.

    Why the servo's profile and not a stream of goals from here: a servo rounds each goal
    to its position step (0.088 deg) and its position loop jerks the arm at every new one
    (19.6 N m/rad on the XM430 model: 0.03 N m per step); goals streamed over a shared
    bus come at uneven times, and reads taken between them see that ripple at a phase set
    by the bus's own timing, a bias as large as the friction (measured on the stand: the
    viscous friction 10-30 % high). The profile is the servo's own smooth ramp."""
    states = await arm.read_joint_states()
    begin = np.array(_angles(states, joints))
    end = np.array(goal, dtype=np.float64)
    travel = np.abs(end - begin)
    longest = int(np.argmax(travel))
    if travel[longest] > 0.0:
        await arm.set_profile_velocity(
            {
                j.name: max(speed_rad_s * float(t) / float(travel[longest]), _SLOWEST_RAD_S)
                for j, t in zip(joints, travel, strict=True)
            }
        )
    await arm.write_joint_positions({j.name: float(a) for j, a in zip(joints, end, strict=True)})
    deadline = time.monotonic() + float(travel[longest]) / speed_rad_s + ARRIVAL_TIMEOUT_S
    while True:
        await asyncio.sleep(float(rng.uniform(0.5, 1.5)) * READ_PERIOD_S)
        states = await arm.read_joint_states()
        angles = np.array(_angles(states, joints))
        if record is not None and travel[longest] > 0.0:
            progress = (angles[longest] - begin[longest]) / (end[longest] - begin[longest])
            if SWEEP_MIDDLE[0] <= progress <= SWEEP_MIDDLE[1]:
                record.append(states)
        errors = np.abs(angles - end)
        if np.all(errors <= ARRIVAL_TOLERANCE_RAD):
            return
        if time.monotonic() > deadline:
            k = int(np.argmax(errors))
            raise ArmDriverError(
                f"joint {joints[k].name!r} is at {math.degrees(angles[k]):.1f} deg, not "
                f"{math.degrees(end[k]):.1f} deg, {ARRIVAL_TIMEOUT_S:g} s after it should "
                "have arrived: blocked, or the torque limit (--torque-limit) cannot move it"
            )


async def _settled(
    arm: DynamixelBus, joints: Sequence[JointConfig]
) -> list[Mapping[str, JointState]]:
    """:data:`STATIC_READS` reads once every joint read zero rate for :data:`SETTLE_S`."""
    deadline = time.monotonic() + ARRIVAL_TIMEOUT_S
    still_since = math.inf
    while True:
        states = await arm.read_joint_states()
        now = time.monotonic()
        if any(states[j.name].velocity_rad_s != 0.0 for j in joints):
            still_since = math.inf
        else:
            still_since = min(still_since, now)
        if now - still_since >= SETTLE_S:
            break
        if now > deadline:
            raise ArmDriverError(
                f"the arm did not come to rest within {ARRIVAL_TIMEOUT_S:g} s at a pose"
            )
        await asyncio.sleep(CYCLE_S)
    reads: list[Mapping[str, JointState]] = [states]
    for _ in range(STATIC_READS - 1):
        await asyncio.sleep(CYCLE_S)
        reads.append(await arm.read_joint_states())
    return reads


async def _torque_off(
    arm: DynamixelBus, joints: Sequence[JointConfig], error: BaseException
) -> None:
    """Torque off at once, then Profile Velocity 0, best effort; a failure to turn torque
    off is noted on ``error``'s first line."""
    try:
        await arm.disable_torque()
    except ArmDriverError as failed:
        note = f"torque off not confirmed: {str(failed).splitlines()[0]}"
        if error.args and isinstance(error.args[0], str):
            error.args = (f"{error.args[0]}; {note}", *error.args[1:])
        else:
            error.add_note(note)
        return
    with contextlib.suppress(ArmDriverError):
        await arm.set_profile_velocity(dict.fromkeys((j.name for j in joints), 0.0))


async def _restore(
    arm: DynamixelBus,
    joints: Sequence[JointConfig],
    start: Sequence[float],
    mode: OperatingMode | None,
    torque: bool | None,
) -> None:
    """Profile Velocity 0, the servos' mode and torque as they were (module docstring,
    step 4)."""
    await arm.set_profile_velocity(dict.fromkeys((j.name for j in joints), 0.0))
    await arm.disable_torque()
    if mode is not None and mode is not arm.operating_mode:
        await arm.set_operating_mode(mode)
    if torque and mode in _POSITION_MODES:
        await arm.write_joint_positions(
            {j.name: angle for j, angle in zip(joints, start, strict=True)}
        )
        await arm.enable_torque()


def fit_joints(
    readings: Readings,
    model: ManipulatorModel,
    theta: ArrayLike,
    joints: Sequence[JointConfig],
    current_resolution_a: float = CURRENT_A_PER_UNIT,
) -> list[JointCalibration]:
    """Each joint's torque constant from the static poses, then its friction from the
    sweeps (:mod:`companion.calibration.servo`), the model ``model`` with link 2's
    ``theta`` = (m2, m3, m4) (the empty arm)."""
    static_tau = model_torque_n_m(
        model, theta, readings.static_eta_rad, np.zeros_like(readings.static_eta_rad)
    )
    sweep_tau = model_torque_n_m(model, theta, readings.sweep_eta_rad, readings.sweep_rate_rad_s)
    results = []
    for k, joint in enumerate(joints):
        kt = fit_torque_constant(
            static_tau[:, k], readings.static_current_a[:, k], current_resolution_a
        )
        # A failed fit is refused anyway; its friction is shown at the config's constant.
        scale = joint.torque_constant_n_m_per_a if kt.problem else kt.torque_constant_n_m_per_a
        friction = fit_friction(
            readings.sweep_rate_rad_s[:, k],
            scale * readings.sweep_current_a[:, k] - sweep_tau[:, k],
            scale * current_resolution_a,
        )
        results.append(JointCalibration(joint, kt, friction))
    return results

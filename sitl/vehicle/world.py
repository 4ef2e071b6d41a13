"""The simulated world: truth plant, arm servos, gripper, payload object, ground and battery.

Pure: no I/O, no clock, no threads. The SITL runner calls :meth:`World.advance` once per
plant step (``1 / plant.rate_hz`` of simulation time) while holding the servo bus lock,
because the servo models are also read and written by the bus thread.

Coupling of the servos (:class:`~sitl.servo.ServoJoint`): before each step every joint
servo gets its shaft angle ``zero_offset + direction * eta`` and rate, and its output
torque (present current x torque constant) times ``direction`` becomes the joint torque
the plant applies - the same mapping :class:`arm_driver.joint.JointConfig` uses on the
companion side, so a wrong direction in a config moves the arm the wrong way in the SITL
as it would on the vehicle.

Simplifications, all stated here:

- Ground (plants without their own, ``plant.has_ground`` False; JSBSim's gear is its
  own): flat, at world z = 0. The base stands when its CoM is ``landing_gear_height_m``
  above it. When a step ends with the CoM below that height, the base is pinned level and
  at rest where it touched down (x, y and yaw of the touch-down; roll, pitch and all base
  velocities zero): a perfectly inelastic contact with static friction. The arm then
  moves as on a fixed stand under gravity and its torques (the step is taken again with
  the base held, :meth:`~sitl.physics.TruthPlant.hold_base`). The arm and the payload do
  not collide with the ground.
- Gripper: one jaw shaft (inertia, viscous friction, hard stops at the open and closed
  positions) driven by the gripper servo. It counts as closed past the middle of its
  travel toward the closed position. When it closes with its jaws (``jaw_point_m`` along
  link 2) within ``grasp_tolerance_m`` of the object, the plant attaches the payload (an
  inelastic capture, see :meth:`~sitl.physics.TruthPlant.attach_payload`) with its centre
  of mass at the payload's own point along link 2 (``payload.position_m``: where the
  object's mass lies beyond or short of the jaws) and the ground still holding its
  weight: link 2 takes it over as the jaws rise
  :data:`LIFT_SPAN_M` above where the jaws closed, and gives it back to the ground if it
  sinks there again before it has cleared :data:`CLEAR_M`
  (:meth:`~sitl.physics.TruthPlant.set_payload_share`): a payload too heavy to lift stays
  on the ground. The jaws stop on the
  object, ``jaw_closure_on_object`` of the way from open to closed: the servo then reads
  short of its closed position and draws its stall current (closed on nothing it reaches
  the closed stop and draws none). When it opens, the object is released where it is and
  falls straight down to its resting height.
- What goes wrong in a pickup (truth only): ``grasp_fails`` makes the jaws close on
  nothing whatever the distance (the object slides away); ``payload_slip_after_s`` makes a
  grasped object slip out that long after the grasp: it falls straight down to its resting
  height and the jaws close on nothing.
- Battery: the plant's (``plant.battery``, :mod:`sitl.physics.battery`), whose voltage the
  rotors' thrust follows; without one an ideal supply at the reference voltage of a 4S
  pack (:data:`IDEAL_SUPPLY`), its current unknown.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from arm_driver.joint import GripperConfig, JointConfig
from companion.compiled import twin
from companion.coordinates import ETA1, ETA2, POSITION, PSI, X, Y, Z
from sitl import vehicle_step
from sitl.physics import AttitudeSetpoint, PlantState
from sitl.physics.battery import REFERENCE_CELL_V, BatteryReading
from sitl.physics.frames import quaternion_from_euler
from sitl.servo import ServoJoint, XM430Servo

__all__ = [
    "CLEAR_M",
    "IDEAL_SUPPLY",
    "LIFT_SPAN_M",
    "GripperJaw",
    "World",
    "WorldSettings",
    "WorldTruth",
]

IDEAL_SUPPLY = BatteryReading(4 * REFERENCE_CELL_V, -1.0, 1.0)
"""The battery reading of a plant without ``plant.battery``: a 4S pack at the reference
voltage [V], current unknown (-1 A, as MAVLink says), full."""

JAWS_INSIDE_TIP_M = 0.02
"""Where the jaws hold an object when ``jaw_point_m`` is not given: this far inside link
2's tip [m]."""

_CONTACT_SLACK_M = 0.03
"""A plant with its own gear stands when its CoM is within this of the gear height [m]
(the gear's spring compresses and extends by millimetres) and hardly moves vertically."""
LIFT_SPAN_M = 0.01
"""How far the grasped object's point rises above where the jaws closed while its weight
passes from the ground to link 2 [m] (assumed: the give of the jaws, the arm and the
object's seat)."""
CLEAR_M = 0.05
"""Height above where the jaws closed at which the object has left the ground for good
[m]: below it, a vehicle that sinks back sets the object down again."""

FloatArray = NDArray[np.float64]
_STEP = twin(vehicle_step)
"""The jaw's arithmetic: :mod:`sitl.vehicle_step`, compiled where built."""
_JAW_ANGLE, _JAW_RATE = vehicle_step.JAW_ANGLE, vehicle_step.JAW_RATE
_JAW_LOW, _JAW_HIGH = vehicle_step.JAW_LOW, vehicle_step.JAW_HIGH


@dataclass(frozen=True)
class WorldSettings:
    """What the world holds besides the vehicle (SI units, world ENU).

    Attributes
    ----------
    landing_gear_height_m
        Height of the base's centre of mass above the ground when it stands [m].
    payload_position_m
        Where the payload object's centre of mass rests at the start, world ENU [m];
        ``None`` for no object.
    grasp_tolerance_m
        Largest distance between the object and the jaws (:attr:`jaw_point_m` along link 2)
        at which closing the gripper grasps [m].
    jaw_point_m
        Where along link 2 the jaws hold an object, from joint 2 [m]; ``None``: 2 cm inside
        the tip. The grasped object's centre of mass sits at the payload's own point along
        link 2 (``payload.position_m``), which need not be the jaws'.
    start_position_m
        Base CoM position at the start, world ENU [m]; its z is replaced by the landing
        gear height (the vehicle starts standing on the ground).
    start_yaw_rad
        Heading at the start (ENU: 0 = east, counter-clockwise positive) [rad].
    start_joints_rad
        (eta1, eta2) at the start [rad].
    jaw_closure_on_object
        Fraction of the jaw's travel from open to closed at which the jaws meet a grasped
        object, in (0.5, 1) (past the middle: the gripper counts as closed) [-]. The
        gripper servo's position loop pushes against the object with ``kp`` x the rest of
        the travel; past its overload current for a second it shuts down, as a real
        XM430 in Position mode would.
    grasp_fails
        Closing the gripper never grasps (truth: the object slides out of the jaws).
    payload_slip_after_s
        Time after a grasp at which the object slips out of the closed gripper and falls
        [s]; ``None``: it stays until the gripper opens.
    """

    landing_gear_height_m: float = 0.25
    payload_position_m: tuple[float, float, float] | None = None
    grasp_tolerance_m: float = 0.05
    jaw_point_m: float | None = None
    start_position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_yaw_rad: float = 0.0
    start_joints_rad: tuple[float, float] = (0.0, 0.0)
    jaw_closure_on_object: float = 0.8
    grasp_fails: bool = False
    payload_slip_after_s: float | None = None

    def __post_init__(self) -> None:
        if not self.landing_gear_height_m > 0.0:
            raise ValueError("landing_gear_height_m must be > 0")
        if not self.grasp_tolerance_m > 0.0:
            raise ValueError("grasp_tolerance_m must be > 0")
        jaw = self.jaw_point_m
        if jaw is not None and not (math.isfinite(jaw) and jaw > 0.0):
            raise ValueError("jaw_point_m must be > 0 and finite")
        if not 0.5 < self.jaw_closure_on_object < 1.0:
            raise ValueError("jaw_closure_on_object must lie between 0.5 and 1 (exclusive)")
        slip = self.payload_slip_after_s
        if slip is not None and not (math.isfinite(slip) and slip >= 0.0):
            raise ValueError("payload_slip_after_s must be >= 0 and finite")
        values = [*self.start_position_m, self.start_yaw_rad, *self.start_joints_rad]
        if self.payload_position_m is not None:
            values += list(self.payload_position_m)
        if not all(math.isfinite(v) for v in values):
            raise ValueError("world positions and angles must be finite")


class GripperJaw:
    """The gripper's jaw: a shaft between hard stops, turned by the gripper servo.

    Parameters
    ----------
    config
        Open and closed servo shaft angles [rad].
    inertia_kg_m2
        Reflected inertia of jaw and gear train [kg m^2].
    friction_n_m_s
        Viscous friction [N m s/rad].
    closure_on_object
        Fraction of the travel from open to closed at which the jaws meet a held object [-].
    """

    def __init__(
        self,
        config: GripperConfig,
        *,
        inertia_kg_m2: float = 2e-3,
        friction_n_m_s: float = 0.02,
        closure_on_object: float = 0.8,
    ) -> None:
        self.config = config
        opened, closed = config.open_position_rad, config.closed_position_rad
        self._empty_stops = (min(opened, closed), max(opened, closed))
        on_object = opened + closure_on_object * (closed - opened)
        self._object_stops = (min(opened, on_object), max(opened, on_object))
        self._middle = 0.5 * (opened + closed)
        """The middle of the travel [rad]."""
        self._closing = closed - opened
        """The travel toward the closed position [rad] (its sign: the closing direction)."""
        self.buffer = vehicle_step.jaw_buffer(
            opened, *self._empty_stops, inertia_kg_m2, friction_n_m_s
        )
        """The shaft's angle and rate, its stops and constants
        (:func:`sitl.vehicle_step.jaw_buffer`): the vehicle's step may advance it itself."""
        self.holding = False
        """An object is between the jaws: they stop on it, short of the closed stop."""

    @property
    def angle_rad(self) -> float:
        """The jaw shaft's angle [rad]."""
        return self.buffer[_JAW_ANGLE]

    @property
    def rate_rad_s(self) -> float:
        """The jaw shaft's rate [rad/s]."""
        return self.buffer[_JAW_RATE]

    def hold(self, holding: bool) -> None:
        """An object between the jaws (they stop on it) or none (they close fully)."""
        self.holding = holding
        low, high = self._object_stops if holding else self._empty_stops
        jaw = self.buffer
        jaw[_JAW_LOW], jaw[_JAW_HIGH] = low, high
        if not low <= jaw[_JAW_ANGLE] <= high:
            jaw[_JAW_ANGLE] = min(max(jaw[_JAW_ANGLE], low), high)
            jaw[_JAW_RATE] = 0.0

    @property
    def closed(self) -> bool:
        """Past the middle of the travel toward the closed position."""
        return (self.angle_rad - self._middle) * self._closing > 0.0

    def advance(self, torque_n_m: float, dt_s: float) -> None:
        """Semi-implicit Euler step under the servo's torque [N m] for ``dt_s`` [s]."""
        _STEP.jaw_advance(self.buffer, torque_n_m, dt_s)


@dataclass(frozen=True)
class WorldTruth:
    """Ground truth of one instant, for the truth log and tests (never sent on MAVLink)."""

    time_s: float
    """Simulation time [s]."""
    plant: PlantState
    """The truth plant's state (q, q_dot in world ENU / ZYX Euler / joint angles)."""
    on_ground: bool
    """The base stands on the ground."""
    payload_attached: bool
    """The payload is in the gripper."""
    object_position_m: FloatArray | None
    """Payload object's centre of mass, world ENU [m] (``None``: no object)."""
    gripper_angle_rad: float | None
    """Gripper servo shaft angle [rad] (``None``: no gripper)."""
    joint_torques_n_m: FloatArray
    """Joint torques the servos applied over the last step [N m]."""
    true_theta: tuple[float, float, float]
    """(m2 [kg], m3 [kg m], m4 [kg m^2]) of link 2 as it is now."""


class World:
    """Truth plant plus what surrounds it; see the module docstring.

    Parameters
    ----------
    plant
        Underactuated truth plant (``sitl.physics.TruthPlant`` or a backend with its
        interface).
    joints
        (config, servo) for eta1 and eta2, in that order.
    gripper
        (config, servo) of the gripper, or ``None``.
    settings
        Ground, object and start pose.
    """

    def __init__(
        self,
        plant,
        joints: Sequence[tuple[JointConfig, ServoJoint]],
        gripper: tuple[GripperConfig, ServoJoint] | None,
        settings: WorldSettings,
    ) -> None:
        if len(joints) != 2:
            raise ValueError(f"the arm has 2 joints, got {len(joints)} servos")
        self.plant = plant
        self.settings = settings
        self._couplings = [(c.zero_offset_rad, c.direction, servo) for c, servo in joints]
        """(zero offset [rad], direction, servo) of eta1 and eta2: shaft angle = zero offset
        + direction * eta (:meth:`JointConfig.servo_angle_rad
        <arm_driver.joint.JointConfig.servo_angle_rad>`)."""
        self._gripper_servo = gripper[1] if gripper else None
        self._servos = [servo for _, servo in joints] + ([gripper[1]] if gripper else [])
        """Every servo, stepped in this order after the plant."""
        self._arm_start: tuple[list[float], list[float]] | None = ([0.0, 0.0], [0.0, 0.0])
        """(eta [rad], eta_dot [rad/s]) at the start of the step being taken (None: the
        plant coupled the joint servos itself and keeps them, :meth:`_arm_before`)."""
        self.jaw = (
            GripperJaw(gripper[0], closure_on_object=settings.jaw_closure_on_object)
            if gripper
            else None
        )
        self._coupled_servos = self._couple_in_plant(joints, gripper)
        """The servos the plant couples within its own step (an XM430 each, a plant with
        :meth:`TruthPlant.advance_coupled <sitl.physics.TruthPlant.advance_coupled>`):
        the joints', and the gripper's (with the jaw) if it is an XM430; else none."""
        self._coupled = bool(self._coupled_servos)
        self._gripper_coupled = len(self._coupled_servos) == 3
        self._settled_servos = [s for s in self._servos if s not in self._coupled_servos]
        """The servos the World steps after a coupled step."""
        self.dt_s = 1.0 / plant.rate_hz
        scenario = plant.scenario
        self._mount = np.array(scenario.arm.mount_point_m, dtype=np.float64)
        self._l1 = scenario.arm.link1.length_m
        self._lc = scenario.payload.position_m
        self._jaw_at = (
            scenario.arm.link2.length_m - JAWS_INSIDE_TIP_M
            if settings.jaw_point_m is None
            else settings.jaw_point_m
        )
        self._gravity = scenario.environment.gravity_m_s2
        self._object = (
            np.array(settings.payload_position_m, dtype=np.float64)
            if settings.payload_position_m is not None
            else None
        )
        self._object_rest_z = None if self._object is None else float(self._object[2])
        self._was_closed = self.jaw.closed if self.jaw else False
        self._torques = [0.0, 0.0]
        self.on_ground = True
        self._ground_pose: tuple[float, float, float] | None = None
        self.grasps = 0
        self._grasped_at_s = math.nan
        self._lift_from_z: float | None = None
        """Height of the payload point where the jaws closed on the object, while it has
        not left the ground [m] (None: not grasped, or carried)."""
        self.slipped_at_s: float | None = None
        """Simulation time the grasped object slipped out of the gripper [s], if it did."""
        plant.reset(start_state(settings))
        self._motors_off = AttitudeSetpoint(quaternion_from_euler(0.0, 0.0, 0.0), 0.0)

    def _couple_in_plant(
        self,
        joints: Sequence[tuple[JointConfig, ServoJoint]],
        gripper: tuple[GripperConfig, ServoJoint] | None,
    ) -> list[XM430Servo]:
        """Couple the servos to the plant's own step where it can; returns those coupled."""
        servos = [s for _, s in joints if isinstance(s, XM430Servo)]
        if not hasattr(self.plant, "advance_coupled") or len(servos) != 2:
            return []
        gripper_buffers = None
        if gripper is not None and isinstance(gripper[1], XM430Servo) and self.jaw is not None:
            servos.append(gripper[1])
            gripper_buffers = (*gripper[1].physics_buffers, self.jaw.buffer)
        couplings = [
            (c.zero_offset_rad, c.direction, s.physics_buffers)
            for (c, _), s in zip(joints, servos[:2], strict=True)
        ]
        self.plant.couple_servos(couplings, gripper_buffers)
        return servos

    # ------------------------------------------------------------------ stepping

    @property
    def state(self) -> PlantState:
        """The plant's current truth state (built when read: :attr:`RotorPlant.state
        <sitl.physics.rotor_plant.RotorPlant.state>`)."""
        return self.plant.state

    @property
    def time_s(self) -> float:
        """Simulation time [s]."""
        return self.plant.time_s

    def step(self, setpoint: AttitudeSetpoint | None) -> PlantState:
        """Advance one plant step; ``None`` means disarmed (rotors commanded to zero thrust).
        Returns the new state.

        Raises the plant's errors (:class:`~sitl.physics.PlantError`) if it diverges.
        """
        self.advance(setpoint)
        return self.plant.state

    def advance(self, setpoint: AttitudeSetpoint | None) -> None:
        """:meth:`step` without building the new state for the caller (the SITL's loop,
        which reads :attr:`state` only when it needs it). The joint servos are coupled in
        the plant's own step where it can (:meth:`TruthPlant.advance_coupled
        <sitl.physics.TruthPlant.advance_coupled>`), with the gripper and its jaw when it
        is an XM430 too (else here, first)."""
        setpoint = setpoint if setpoint is not None else self._motors_off
        if self._coupled:
            if not self._gripper_coupled:
                self._couple_gripper()
            self._arm_start = None
            overloads = self.plant.advance_coupled(setpoint)
            if overloads is not None:  # the gripper's flag is False when not coupled
                for servo, over in zip(self._coupled_servos, overloads, strict=False):
                    if over:
                        servo.overloaded()
        else:
            self.plant.advance(setpoint, self._couple())
        self._settle()

    def step_motors(self, motor_commands: Sequence[float]) -> PlantState:
        """Advance one plant step with six motor commands in [0, 1] held (rotor order of
        :mod:`sitl.physics.rotors`): an autopilot outside the simulation flies the
        vehicle, the plant's own attitude loop does not run. Returns the new state; raises
        the plant's errors."""
        torques = self._couple()
        self.plant.advance_motors(motor_commands, torques)
        self._settle()
        return self.plant.state

    def _couple(self) -> list[float]:
        """The start of a step: each joint servo gets its shaft's angle and rate, the jaw
        moves under the gripper servo; returns the joint torques [N m] the plant applies
        over the step (the joints' angles and rates are kept for :meth:`_settle`)."""
        q, q_dot = self.plant.coordinates
        e1, e2 = float(q[ETA1]), float(q[ETA2])
        r1, r2 = float(q_dot[ETA1]), float(q_dot[ETA2])
        self._arm_start = ([e1, e2], [r1, r2])
        (zero1, sign1, servo1), (zero2, sign2, servo2) = self._couplings
        torques = self._torques
        torques[0] = sign1 * servo1.couple(zero1 + sign1 * e1, sign1 * r1)
        torques[1] = sign2 * servo2.couple(zero2 + sign2 * e2, sign2 * r2)
        self._couple_gripper()
        return torques

    def _couple_gripper(self) -> None:
        """The jaw moves under the gripper servo over the step (none without a gripper)."""
        gripper, jaw = self._gripper_servo, self.jaw
        if gripper is not None and jaw is not None:
            jaw.advance(gripper.couple(jaw.angle_rad, jaw.rate_rad_s), self.dt_s)

    def _arm_before(self) -> tuple[list[float], list[float], list[float]]:
        """(eta [rad], eta_dot [rad/s], the servos' torques on the joints [N m]) at the
        start of the last step."""
        if self._arm_start is None:
            return self.plant.coupled_arm
        return (*self._arm_start, list(self._torques))

    def _settle(self) -> None:
        """The end of a step: the servos' loops advance (those the plant's step has not
        advanced), then ground contact and payload."""
        dt = self.dt_s
        for servo in self._servos if self._arm_start is not None else self._settled_servos:
            servo.step(dt)
        self._ground_contact()
        self._update_payload()

    @property
    def battery(self) -> BatteryReading:
        """The battery's voltage, current and charge now (the plant's, or
        :data:`IDEAL_SUPPLY`)."""
        reading = self.plant.battery if self.plant.flies_rotors else None
        return IDEAL_SUPPLY if reading is None else reading

    def _ground_contact(self) -> None:
        """Stand the base on the ground (see the module docstring); the arm takes the step
        again on the standing base from its angles and rates at the start of the step,
        under the step's torques (:meth:`_arm_before`)."""
        height = self.settings.landing_gear_height_m
        q, q_dot = self.plant.coordinates
        if self.plant.has_ground:  # the plant's own gear holds it (JSBSim)
            self.on_ground = q[Z] <= height + _CONTACT_SLACK_M and abs(q_dot[Z]) < 0.1
            return
        if q[Z] >= height:
            self.on_ground = False
            self._ground_pose = None
            return
        self.on_ground = True
        if self._ground_pose is None:  # touch-down: stay where the gear met the ground
            self._ground_pose = (float(q[X]), float(q[Y]), float(q[PSI]))
        x, y, yaw = self._ground_pose
        self.plant.hold_base((x, y, height), yaw, self._arm_before())

    # ------------------------------------------------------------------- payload

    def payload_point_m(self) -> FloatArray:
        """World ENU position [m] of the payload point of link 2 (where a grasped CoM sits)."""
        return self._link2_point_m(self._lc)

    def jaw_point_m(self) -> FloatArray:
        """World ENU position [m] of the jaws on link 2 (where they hold an object)."""
        return self._link2_point_m(self._jaw_at)

    def _link2_point_m(self, along_m: float) -> FloatArray:
        state = self.plant.state
        q = state.q
        e1, e2 = float(q[ETA1]), float(q[ETA2])
        arm_b = self._mount + np.array(
            [
                self._l1 * math.cos(e1) + along_m * math.cos(e1 + e2),
                0.0,
                self._l1 * math.sin(e1) + along_m * math.sin(e1 + e2),
            ]
        )
        return q[POSITION] + state.rotation_world_body @ arm_b

    @property
    def object_position_m(self) -> FloatArray | None:
        """Where the object is held, world ENU [m]: at the jaws while grasped, else where
        it rests."""
        if self._object is None:
            return None
        return self.jaw_point_m() if self.plant.payload_attached else self._object.copy()

    def _update_payload(self) -> None:
        jaw = self.jaw
        if jaw is None:
            return
        closed = jaw.closed
        settings = self.settings
        if closed and not self._was_closed and self._object is not None:
            if not self.plant.payload_attached and not settings.grasp_fails:
                gap = float(np.linalg.norm(self.jaw_point_m() - self._object))
                if gap <= settings.grasp_tolerance_m:
                    self._lift_from_z = float(self.jaw_point_m()[2])
                    self.plant.attach_payload(share=0.0)  # the ground holds it still
                    self.grasps += 1
                    self._grasped_at_s = self.time_s
                    jaw.hold(True)
        elif not closed and self._was_closed and self.plant.payload_attached:
            self._drop()
        if self._lift_from_z is not None and self.plant.payload_attached:
            rise = float(self.jaw_point_m()[2]) - self._lift_from_z
            self.plant.set_payload_share(rise / LIFT_SPAN_M)
            if rise >= CLEAR_M:
                self._lift_from_z = None  # off the ground: carried
        slip = settings.payload_slip_after_s
        if (
            slip is not None
            and self.plant.payload_attached
            and self.time_s - self._grasped_at_s >= slip
        ):
            self._drop()
            self.slipped_at_s = self.time_s
        self._was_closed = closed

    def _drop(self) -> None:
        """Detach the payload: the object falls straight down to its resting height and
        the jaws hold nothing."""
        released = self.jaw_point_m()
        self.plant.detach_payload()
        self._lift_from_z = None
        assert self._object_rest_z is not None
        released[2] = min(released[2], self._object_rest_z)
        self._object = released
        assert self.jaw is not None
        self.jaw.hold(False)

    # --------------------------------------------------------------------- truth

    def specific_force_flu_m_s2(self) -> FloatArray:
        """What an accelerometer on the base reads: R^T (a - g), body FLU [m/s^2]."""
        state = self.plant.state
        accel = np.zeros(3) if self.on_ground else np.array(state.q_ddot[POSITION])
        accel[2] += self._gravity
        return state.rotation_world_body.T @ accel

    def truth(self) -> WorldTruth:
        """Ground truth now."""
        state = self.plant.state
        theta = self.plant.true_theta
        return WorldTruth(
            time_s=state.time_s,
            plant=state,
            on_ground=self.on_ground,
            payload_attached=self.plant.payload_attached,
            object_position_m=self.object_position_m,
            gripper_angle_rad=None if self.jaw is None else self.jaw.angle_rad,
            joint_torques_n_m=np.array(self._arm_before()[2]),
            true_theta=(theta.m2_kg, theta.m3_kg_m, theta.m4_kg_m2),
        )


def start_state(settings: WorldSettings) -> ArrayLike:
    """q at the start: standing on the ground at the configured position, yaw and joints."""
    return [
        *settings.start_position_m[:2],
        settings.landing_gear_height_m,
        0.0,
        0.0,
        settings.start_yaw_rad,
        *settings.start_joints_rad,
    ]

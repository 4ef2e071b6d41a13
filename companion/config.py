"""The companion's configuration: TOML files validated into frozen, typed objects (SI units).

A scenario file holds two owners' sections. The companion's (:class:`CompanionConfig`:
vehicle, arm with link 2 empty, gains, estimator, state filter, ``[flight]``,
``[arm_bus]``) are what it believes and how it flies; the simulator's
(:data:`SIMULATOR_SECTIONS`: the payload, the truth plant, the world, the offline runs) are
read by ``sitl.scenario`` and skipped here, so the companion's types cannot hold the truth.
This module is the one place where configuration is parsed. Every key carries its unit in its
name (``mass_kg``, ``length_m``) or, for gain vectors whose rows have mixed units, in the
docstring of its field. Vectors of 8 follow the state order of DESIGN.md section 2:
``q = [x, y, z, phi, theta, psi, eta1, eta2]``.

Errors are raised as :class:`ConfigError`, whose message names the file, the dotted key
and the reason; nothing is read unless a path is passed explicitly. Numbers are finite and
bounded by what a real vehicle can have (a multirotor of 0.1-100 kg, an arm within 5 m,
gains below 1e6, ...); a number outside says the range and why.
"""

from __future__ import annotations

import difflib
import tomllib
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, ValidationError
from pydantic_core import ErrorDetails

from arm_driver.joint import GripperConfig, JointConfig
from arm_driver.url import parse_bus_url
from companion.coordinates import N_Q
from companion.user_files import SMALL_FILE_LIMIT_BYTES, UserFileError, read_small_file

__all__ = [
    "SIMULATOR_SECTIONS",
    "TOML_LIMIT_BYTES",
    "Arm",
    "ArmBusGripper",
    "ArmBusJoint",
    "ArmBusSection",
    "AttitudeFeedforward",
    "CompanionConfig",
    "Confidence",
    "ConfigError",
    "Controller",
    "Environment",
    "Estimator",
    "Flight",
    "Link",
    "Rls",
    "Rotors",
    "Sensors",
    "SlidingMode",
    "Theta",
    "ThrustScale",
    "TomlDocument",
    "Vehicle",
    "arm_bus_configs",
    "check_companion",
    "check_theta",
    "load_config",
    "parse_config",
    "read_toml",
    "read_toml_document",
    "validate",
]


_REL_TOL = 1e-9
"""Relative tolerance for the consistency check m4 >= m3^2 / m2 (equality is a point mass)."""


class ConfigError(ValueError):
    """A configuration file is missing, malformed or physically impossible.

    Attributes
    ----------
    path : str
        The file (or ``"<string>"``).
    problems : tuple of (key, reason)
        Every problem found; ``key`` is dotted inside the file (``"arm.link2.com_m"``),
        empty for file-level errors.
    key, reason : str
        The first problem.
    """

    def __init__(self, path: str, key: str, reason: str, *more: tuple[str, str]) -> None:
        self.path = path
        self.problems = ((key, reason), *more)
        self.key, self.reason = key, reason
        super().__init__(
            "\n".join(f"{path}: {k}: {r}" if k else f"{path}: {r}" for k, r in self.problems)
        )


Real = Annotated[float, Field(strict=True, allow_inf_nan=False)]
Positive = Annotated[float, Field(strict=True, gt=0.0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(strict=True, ge=0.0, allow_inf_nan=False)]
Vec3 = Annotated[tuple[Real, ...], Field(min_length=3, max_length=3)]
PositiveVec3 = Annotated[tuple[Positive, ...], Field(min_length=3, max_length=3)]
VecQ = Annotated[tuple[Real, ...], Field(min_length=N_Q, max_length=N_Q)]
PositiveVecQ = Annotated[tuple[Positive, ...], Field(min_length=N_Q, max_length=N_Q)]
NonNegativeVec3 = Annotated[tuple[NonNegative, ...], Field(min_length=3, max_length=3)]
Fraction = Annotated[float, Field(strict=True, ge=0.0, le=1.0, allow_inf_nan=False)]


def _within(high: float, unit: str, why: str, low: float = 0.0) -> AfterValidator:
    """A validator keeping a number within [low, high] ``unit``, the range a real vehicle
    has (``why``); finiteness and the sign are the field type's."""

    def check(value: float) -> float:
        if not low <= value <= high:
            units = f" {unit}" if unit else ""
            raise ValueError(f"must lie within [{low:g}, {high:g}]{units} ({why})")
        return value

    return AfterValidator(check)


_ARM_REACH = "an arm on a multirotor reaches at most 5 m"
Gravity = Annotated[
    Positive, _within(30.0, "m/s^2", "a planet's surface gravity; Earth 9.81", low=1.0)
]
VehicleMass = Annotated[
    Positive,
    _within(100.0, "kg", "a multirotor carrying an arm; small drones stop at 25 kg", low=0.1),
]
VehicleInertia = Annotated[
    Positive, _within(100.0, "kg m^2", "a multirotor of 0.1-100 kg", low=1e-5)
]
Length = Annotated[Positive, _within(5.0, "m", _ARM_REACH, low=0.01)]
Distance = Annotated[NonNegative, _within(5.0, "m", _ARM_REACH)]
Offset = Annotated[Real, _within(5.0, "m", _ARM_REACH, low=-5.0)]
LinkMass = Annotated[
    Positive, _within(50.0, "kg", "an arm link or a payload a multirotor lifts", low=0.001)
]
LinkInertia = Annotated[NonNegative, _within(100.0, "kg m^2", "50 kg at the 5 m reach")]
Thrust = Annotated[Positive, _within(1000.0, "N", "a multirotor rotor's static thrust", low=0.01)]
TimeConstant = Annotated[Positive, _within(10.0, "s", "a motor or filter on a vehicle", low=1e-4)]
SensorRate = Annotated[
    Positive, _within(10000.0, "Hz", "vehicle sensors: 1 Hz GPS to 10 kHz IMUs", low=1.0)
]
Gain = Annotated[Positive, _within(1e6, "", "no vehicle's gain is larger; larger overflows")]
PositiveGains3 = Annotated[tuple[Gain, ...], Field(min_length=3, max_length=3)]
PositiveGainsQ = Annotated[tuple[Gain, ...], Field(min_length=N_Q, max_length=N_Q)]


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


class Environment(_Section):
    """World constants."""

    gravity_m_s2: Gravity
    """Gravitational acceleration along -z of the ENU world frame [m/s^2]."""


class Rotors(_Section):
    """The six rotors of the hexacopter and their thrust model (what the companion believes).

    Layout (fixed, as the AscTec Firefly): rotor i (i = 0..5) sits in the body x-y plane at
    azimuth 30 deg + 60 deg * i, counter-clockwise from body x seen from above (FLU), at
    ``arm_length_m`` from the vehicle CoM; rotor 0 spins counter-clockwise, then the spin
    direction alternates. The truth plant (``sitl.physics``) scales the thrust by
    ``plant.thrust_mismatch``.
    """

    arm_length_m: Length
    """Distance of each rotor axis from the vehicle CoM in the body x-y plane [m]."""
    max_thrust_per_rotor_n: Thrust
    """Static thrust of one rotor at full command u = 1 [N]."""
    thr_mdl_fac: Fraction
    """Shape f of the static thrust curve rel_thrust = f u^2 + (1 - f) u, u the normalized
    motor command in [0, 1] (PX4's THR_MDL_FAC model) [-]. The simulated PX4 does not
    linearize it (PX4 with THR_MDL_FAC = 0), so PX4's normalized thrust setpoint maps to
    thrust through this curve."""
    motor_time_constant_s: TimeConstant
    """Time constant of the first-order lag from commanded to produced thrust [s]."""
    yaw_moment_per_thrust_m: Distance
    """Reaction (drag) moment about the rotor axis per unit thrust [N m / N = m]."""


class Vehicle(_Section):
    """The hexacopter body without the arm."""

    mass_kg: VehicleMass
    """Mass m_b of the vehicle body [kg]."""
    inertia_kg_m2: Annotated[tuple[VehicleInertia, ...], Field(min_length=3, max_length=3)]
    """Principal moments (Ixx, Iyy, Izz) about the body CoM, FLU axes [kg m^2]."""
    rotors: Rotors


class Link(_Section):
    """One arm link whose mass lies on its own axis (DESIGN.md section 3).

    Such a link is described exactly by its mass, first moment ``mass_kg * com_m`` and
    second moment ``mass_kg * com_m**2 + inertia_about_com_kg_m2`` about its joint.
    """

    length_m: Length
    """Joint-to-joint (or joint-to-end-effector) length [m]."""
    mass_kg: LinkMass
    """Link mass [kg]."""
    com_m: Distance
    """Distance of the centre of mass from the link's joint along the link axis [m]."""
    inertia_about_com_kg_m2: LinkInertia
    """Moment of inertia about an axis through the CoM perpendicular to the link [kg m^2]."""
    armature_kg_m2: LinkInertia
    """Reflected rotor inertia of the joint's servo, added on the joint axis [kg m^2]."""

    @property
    def first_moment_kg_m(self) -> float:
        """Mass times CoM distance from the joint [kg m]."""
        return self.mass_kg * self.com_m

    @property
    def second_moment_kg_m2(self) -> float:
        """Moment of inertia about the joint axis, without armature [kg m^2]."""
        return self.mass_kg * self.com_m**2 + self.inertia_about_com_kg_m2


class Arm(_Section):
    """The 2-DOF arm; both joint axes are parallel to the body y axis."""

    mount_point_m: Annotated[tuple[Offset, ...], Field(min_length=3, max_length=3)]
    """Position r_a of joint 1 in the body frame (FLU, from the vehicle CoM) [m]."""
    link1: Link
    link2: Link
    """Link 2 empty (with gripper, without payload): the nominal, known values."""


class Theta(_Section):
    """Link-2 parameters theta = (m2, m3, m4) of the paper's parametrization."""

    m2_kg: LinkMass
    """Total mass of link 2 with payload [kg]."""
    m3_kg_m: NonNegative
    """First moment m2 * lc about joint 2 [kg m]."""
    m4_kg_m2: NonNegative
    """Second moment about joint 2 (m2 * lc^2 for a point mass) [kg m^2]."""

    @property
    def lc_m(self) -> float:
        """Centre of mass of link 2 (with payload) from joint 2 [m]."""
        return self.m3_kg_m / self.m2_kg

    def as_tuple(self) -> tuple[float, float, float]:
        """(m2, m3, m4) in kg, kg m, kg m^2."""
        return (self.m2_kg, self.m3_kg_m, self.m4_kg_m2)


class Confidence(_Section):
    """When an estimate is published as confident
    (companion.estimation.estimator.ExcitationMonitor)."""

    window_s: TimeConstant
    """Time constant of the exponential window [s]."""
    excitation_min: Positive
    """Smallest eigenvalue of the scaled information matrix to call the motion exciting [-]."""
    spread_max: Positive
    """Largest (max - min) / mean of m2 and of lc over the window [-]."""


class Rls(_Section):
    """Recursive least squares with forgetting (companion.estimation.estimator.RlsEstimator)."""

    forgetting: Annotated[float, Field(strict=True, gt=0.0, le=1.0, allow_inf_nan=False)]
    """Forgetting factor per control step, in (0, 1] [-]."""
    initial_std: PositiveVec3
    """Initial standard deviation of (m2 [kg], m3 [kg m], m4 [kg m^2])."""
    row_noise: PositiveGainsQ
    """Noise std of each row's generalized-force residual (N on x, y, z; N m otherwise)."""
    com_from_joints: bool = False
    """Learn m3 and m4 (where link 2's mass sits) from the joint rows alone: on x, y, z
    their columns move to the known side at the current estimate, so those rows learn m2
    (and the thrust scale) only. In flight the arm's share of the x, y, z forces is small
    against forces the model does not have (rotor drag); false: every row learns all."""


ThrustScaleValue = Annotated[Positive, _within(2.0, "", "true over believed thrust", low=0.2)]


class ThrustScale(_Section):
    """The vehicle's thrust scale s (true force = s x the thrust model's force) estimated
    with theta (companion.estimation.estimator): the translational rows' commanded force becomes a
    column of the regressor, the joint rows (servo torque) anchor m2, m3, m4."""

    initial: ThrustScaleValue = 1.0
    """Initial estimate of s [-] (1: the thrust model is exact)."""
    bounds: Annotated[tuple[ThrustScaleValue, ...], Field(min_length=2, max_length=2)] = (
        0.5,
        1.5,
    )
    """Projection bounds [min, max] of s [-]."""
    initial_std: Annotated[Positive, _within(1.0, "", "a thrust model within 100 %")] = 0.1
    """RLS: initial standard deviation of s [-]."""
    drift_std_per_sqrt_s: Annotated[NonNegative, _within(1.0, "1/sqrt(s)", "battery sag")] = 0.01
    """RLS: random-walk process noise of s while it is learnt, std per square root of a
    second [1/sqrt(s)] (battery sag, up to 10 % over 20 s; 0: s is held constant apart from
    the forgetting)."""
    gamma: Gain = 1.0
    """Paper estimator: learning rate of s [-]."""
    window_s: Annotated[NonNegative, _within(120.0, "s", "a hover calibration")] = 10.0
    """Carry s through the flight from the battery's voltage (thrust per command goes with
    the voltage to ``voltage_exponent``): the last this many seconds of the hover
    calibration before the grasp fit s at the calibration's voltage, from the moments the
    vehicle is nearly still; from the grasp on s follows the voltage the vehicle streams
    (SYS_STATUS), and so does the compensated force (companion.estimation.thrust_supply).
    Without a voltage, s is held at the fitted value [s] (0: s is held as the estimator
    has it at the grasp)."""
    voltage_exponent: Annotated[NonNegative, _within(4.0, "", "a motor's thrust law")] = 2.0
    """Thrust per command goes with the battery voltage to this power [-] (2: the rotor
    speed goes with duty cycle x voltage, the thrust with its square)."""
    voltage_exponent_std: Annotated[NonNegative, _within(4.0, "", "a motor's thrust law")] = 0.5
    """Standard deviation of ``voltage_exponent`` in the reported uncertainty of s and of
    the payload's mass [-]."""
    voltage_filter_s: Annotated[NonNegative, _within(10.0, "s", "a battery voltage filter")] = 0.3
    """Time constant of the battery voltage's low-pass [s] (short: a grasp's load step
    drops the voltage, and the thrust, at once)."""
    compensate: bool = True
    """Divide the commanded force (and the tilt torque asked of PX4's attitude loop) by the
    calibrated s before the thrust model maps it to PX4's relative thrust, so that the
    vehicle produces the force the law asks for (as PX4's hover thrust estimate does); the
    estimator still sees the model's force for the command sent. Off, a 5 % weaker thrust
    held the SITL pickup 4.6 cm low at the grasp and it aborted (ground_contact)."""


def _section_or_off(value: object) -> object:
    """An optional section given as a table, or switched with ``false`` (off: None) or
    ``true`` (on, with its defaults)."""
    if value is False:
        return None
    if value is True:
        return {}
    if not isinstance(value, dict) and not isinstance(value, BaseModel):
        raise ValueError(f"must be a table of its keys, true or false, not {value!r}")
    return value


class Estimator(_Section):
    """Gains and initial values of the paper's on-line estimator (eqs. estimator, update)."""

    gamma: PositiveGains3
    """Learning rates (gamma_1, gamma_2, gamma_3) of m2, m3, m4."""
    c_star: PositiveGainsQ
    """Diagonal of the damping-like gain C* (positive definite), one entry per row of q."""
    k_star: PositiveGainsQ
    """Diagonal of the stiffness-like gain K* (positive definite), one entry per row of q."""
    initial_theta: Theta
    """Initial estimates (m2, m3, m4)."""
    initial_qhat_dot: VecQ
    """Initial estimated velocity qhat_dot(0) in the units of q_dot (m/s, rad/s)."""
    kind: Literal["paper", "rls"]
    """Default estimator: the paper's (``paper``) or recursive least squares (``rls``)."""
    rows: Annotated[
        tuple[Annotated[int, Field(strict=True, ge=0, le=N_Q - 1)], ...],
        Field(min_length=1, max_length=N_Q),
    ]
    """Rows of q whose generalized force is known, increasing (flight: [0, 1, 2, 6, 7])."""
    m2_bounds_kg: Annotated[tuple[LinkMass, ...], Field(min_length=2, max_length=2)]
    """Projection bounds [min, max] of m2 [kg]."""
    confidence: Confidence
    rls: Rls
    thrust_scale: Annotated[ThrustScale | None, BeforeValidator(_section_or_off)] = Field(
        default_factory=ThrustScale
    )
    """Estimate the vehicle's thrust scale with theta (absent: with the defaults of
    ``[estimator.thrust_scale]``; ``thrust_scale = false``: the thrust model is taken as
    exact, the paper's assumption)."""
    acceleration_delay_s: Annotated[NonNegative, _within(0.2, "s", "a few control cycles")] = 0.0
    """Run the estimator this long behind the controller [s], on q_ddot from a central
    difference of the filtered q_dot (companion.estimation.inputs: no phase lag, where the
    state filter's accelerations lag 25-80 ms in flight); 0: the filter's q_ddot of the
    current cycle, as the paper. Rounded to whole control periods, at least one."""


class SlidingMode(_Section):
    """Adaptive sliding-mode baseline (eqs. asc1, asc2); the paper gives no gains."""

    k1: PositiveGainsQ
    """Diagonal of K1 (N s/m, N m s/rad)."""
    k2: PositiveGainsQ
    """Diagonal of K2, the switching gain (N, N m)."""
    lambda_: PositiveGainsQ = Field(alias="lambda")
    """Diagonal of Lambda of the sliding surface [1/s]."""
    boundary_layer: PositiveGainsQ
    """Width phi of sat(s / phi) replacing sgn(s) (m/s, rad/s)."""
    gamma_delta: PositiveGainsQ
    """Adaptation rate of Deltahat (N per m/s s, ...)."""
    mass_filter_s: TimeConstant
    """Time constant of the low-pass on the eq. asc2 mass read-out [s]."""


def _one_or_pair(value: object) -> object:
    """A (roll, pitch) pair given as one number for both, or as the pair."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return (value, value)
    return value


Pair = Annotated[tuple[Positive, ...], Field(min_length=2, max_length=2)]
NonNegativePair = Annotated[tuple[NonNegative, ...], Field(min_length=2, max_length=2)]


class AttitudeFeedforward(_Section):
    """PX4's roll and pitch loop as the companion inverts it
    (companion.control.attitude_feedforward): the attitude offset that makes PX4 produce the
    torque the model needs on the tilt rows.
    Each pair is (roll, pitch); the flight app checks the gains against the vehicle's."""

    attitude_p: Pair
    """PX4's MC_ROLL_P, MC_PITCH_P [rad/s per rad]."""
    rate_p: Pair
    """PX4's MC_ROLLRATE_P, MC_PITCHRATE_P times MC_ROLLRATE_K, MC_PITCHRATE_K [-]."""
    rate_i: NonNegativePair
    """PX4's MC_ROLLRATE_I, MC_PITCHRATE_I times MC_ROLLRATE_K, MC_PITCHRATE_K [-]."""
    rate_integrator_limit: NonNegativePair
    """PX4's MC_RR_INT_LIM, MC_PR_INT_LIM [normalized torque]."""
    torque_per_normalized_n_m: Annotated[
        tuple[Annotated[Positive, _within(1000.0, "N m", "a multirotor's torque")], ...],
        Field(min_length=2, max_length=2),
    ]
    """Body torque of a normalized roll or pitch torque of 1 in PX4's control allocation
    for this airframe [N m] (``sitl authority`` prints it for the configured rotors)."""
    max_offset_rad: Annotated[
        tuple[Annotated[NonNegative, _within(0.5, "rad", "a correction, not a manoeuvre")], ...],
        BeforeValidator(_one_or_pair),
        Field(min_length=2, max_length=2),
    ] = (0.3, 0.3)
    """Largest offset of roll and of pitch [rad] (one number: both); 0 sends none on that
    axis."""
    torque_filter_s: TimeConstant = 0.05
    """Time constant of the first-order low-pass on the torque the offset is for [s]."""


class Controller(_Section):
    """Gains of the augmented passivity-based controller (eq. tau2)."""

    k: PositiveGainsQ
    """Diagonal of k (N s/m on positions, N m s/rad on angles and joints)."""
    lambda_: PositiveGainsQ = Field(alias="lambda")
    """Diagonal of Lambda [1/s]."""
    tilt_max_rad: Annotated[float, Field(strict=True, gt=0.0, lt=1.2, allow_inf_nan=False)]
    """Limit of the commanded tilt of the small-angle mapping (eq. phid) [rad]."""
    tilt_reference_bandwidth_rad_s: Positive
    """Natural frequency of the filter that smooths roll/pitch commands [rad/s]."""
    horizontal_trim_gain_n_per_m: NonNegative = 0.0
    """Gain of the flight app's integral trim on x, y (``companion.control.laws.HorizontalTrim``)
    [N/m]; 0: none (the paper's law)."""
    horizontal_trim_limit_n: NonNegative = 1.0
    """Largest trim force per horizontal axis [N]."""
    measured_unactuated_motion: bool = False
    """Eq. tau2 with the measured q_dot and q_ddot in place of the desired ones on the rows
    the companion does not actuate (roll, pitch, yaw in flight: PX4 flies them), so the
    joints' feedforward ``Mhat qd_ddot`` answers the body's actual rotation and not the
    tilt asked of PX4, which it realises about a third of (SITL pickup, real PX4 and the
    imitation alike); false: the desired motion on every row, as the paper."""
    attitude_feedforward: AttitudeFeedforward | None = None
    """Offset the commanded roll and pitch so that PX4's attitude loop makes the torque the
    model needs on the tilt rows (the arm's reaction and the shifted CoM); absent: the tilt
    of eq. phid is sent as it is (the paper)."""
    sliding_mode: SlidingMode


class Sensors(_Section):
    """Measurements the companion gets in noisy runs, and its state filter.

    In noise-free runs q and q_dot are measured exactly at the control rate and only the
    filter's tuning (``jerk_psd``) is used.
    """

    pose_rate_hz: SensorRate
    """Motion-capture rate of position and attitude [Hz]."""
    position_std_m: NonNegative
    attitude_std_rad: NonNegative
    pose_latency_s: Annotated[NonNegative, _within(10.0, "s", "a sensor's latency")]
    gyro_rate_hz: SensorRate
    """Body-rate (IMU gyro) rate [Hz]."""
    gyro_std_rad_s: NonNegative
    joint_rate_hz: SensorRate
    """Servo position read-back rate [Hz]."""
    joint_std_rad: NonNegative
    joint_velocity_unit_rad_s: Positive
    """Resolution of the servo's velocity read-back (XM430: 0.229 rev/min) [rad/s]."""
    joint_torque_std_n_m: NonNegative
    """Noise of the joint torque read back from servo present current [N m]."""
    jerk_psd: PositiveGainsQ
    """Process noise of the constant-acceleration state filter per row (m^2/s^5, rad^2/s^5)."""
    velocity_std_m_s: Positive = 0.05
    """Noise of the vehicle velocity the autopilot reports (ODOMETRY, EKF2), fused by the
    flight app's state filter [m/s]; the offline simulation measures no velocity."""


def _sign(value: int) -> int:
    if value not in (1, -1):
        raise ValueError("must be 1 or -1")
    return value


ServoId = Annotated[int, Field(strict=True, ge=0, le=255)]
"""A servo's id on its bus: Dynamixel ids are 0..252, DroneCAN actuator ids 0..255; the
bus backend rejects ids its protocol cannot address."""


class ArmBusJoint(_Section):
    """One arm joint and its servo (fields of ``arm_driver.joint.JointConfig``, and whether
    its torque constant was calibrated).

    Angles are in the joint frame, counter-clockwise positive about the joint axis;
    ``servo angle = zero_offset_rad + direction * joint angle``, the servo angle 0 at the
    servo's centre position.
    """

    name: Annotated[str, Field(strict=True, min_length=1)]
    """Joint name, the key of joint-space commands and states (e.g. ``"eta1"``)."""
    servo_id: ServoId
    torque_constant_n_m_per_a: Positive
    """Output torque per motor current [N m/A]: the servo's own, measured by ``companion arm
    calibrate``, or the datasheet's until then."""
    torque_calibrated: Annotated[bool, Field(strict=True)] = False
    """Whether ``torque_constant_n_m_per_a`` (and the friction) were measured on this servo
    (``companion arm calibrate --write`` sets it): a mission flown on datasheet values says
    so, since a constant 12 % off moves the payload's estimated centre of mass by a fifth."""
    torque_max_n_m: NonNegative
    """Largest torque magnitude a command may ask for [N m]."""
    direction: Annotated[int, Field(strict=True), AfterValidator(_sign)]
    """+1 if a positive joint angle turns the servo counter-clockwise seen from its front."""
    zero_offset_rad: Real
    """Servo shaft angle where the joint angle is 0 [rad]."""
    position_min_rad: Real
    """Lower joint angle limit [rad]."""
    position_max_rad: Real
    """Upper joint angle limit [rad]."""
    viscous_friction_n_m_s_per_rad: Annotated[
        NonNegative, _within(10.0, "N m s/rad", "a servo gearbox an arm joint turns through")
    ] = 0.0
    """Calibrated viscous friction of the servo's gearbox at the joint [N m s/rad]
    (``companion arm calibrate``); 0: none. The measured joint torque is the motor's less
    ``viscous * rate + coulomb * sign(rate)``."""
    coulomb_friction_n_m: Annotated[
        NonNegative, _within(100.0, "N m", "a servo gearbox an arm joint turns through")
    ] = 0.0
    """Calibrated Coulomb (dry) friction of the servo's gearbox at the joint [N m]; 0: none."""


class ArmBusGripper(_Section):
    """The gripper's servo (fields of ``arm_driver.joint.GripperConfig``)."""

    servo_id: ServoId
    open_position_rad: Real
    """Servo shaft angle of the open gripper (0 at the servo's centre) [rad]."""
    closed_position_rad: Real
    """Servo shaft angle of the closed gripper [rad]."""


class ArmBusSection(_Section):
    """The arm's servo bus for the companion (``arm_driver.open_bus``); optional."""

    url: Annotated[str, Field(strict=True, min_length=1)]
    """Bus URL, e.g. ``dynamixel:///dev/ttyUSB0?baud=1000000`` or
    ``dronecan://can0?interface=socketcan&node_id=10``."""
    joints: Annotated[tuple[ArmBusJoint, ...], Field(min_length=1)]
    """The joints, in the order their states are returned (eta1, eta2 of q)."""
    gripper: ArmBusGripper | None = None


class Flight(_Section):
    """How the flight app hands the vehicle to and from PX4 and watches its navigation
    (``companion mission``); optional, every key has a default."""

    handover_stream_s: Positive = 0.5
    """Vehicle time the safe setpoint is streamed before OFFBOARD is asked for (PX4 wants
    a live stream, > 2 Hz) [s]."""
    settle_climb_rate_m_s: Positive = 0.2
    """After take-off the vehicle counts as settled once its vertical speed stays below
    this for ``settle_s`` (PX4 still climbing to the take-off altitude is not; PX4's own
    position hold wanders 0.2-0.3 m/s horizontally on GPS) [m/s]."""
    settle_s: Positive = 1.0
    """[s], see ``settle_climb_rate_m_s``."""
    nav_max_position_std_m: Positive = 1.0
    """Largest standard deviation of PX4's position estimate (ODOMETRY covariance, any
    axis) that counts as valid navigation [m]."""
    nav_max_velocity_std_m_s: Positive = 0.5
    """Largest standard deviation of PX4's velocity estimate that counts as valid [m/s]."""
    nav_invalid_hold_s: Positive = 0.5
    """Time the navigation may be invalid before the ``navigation`` fault [s]."""
    max_round_trip_s: Positive = 0.1
    """Longest round trip of the link (a pose down, a TIMESYNC request up, in vehicle
    time) the loops fly on; three replies in a row over it are the ``link_latency`` fault
    [s]."""
    ground_margin_m: Positive = 0.05
    """Height above the take-off height below which the vehicle counts as on the ground
    [m] (PX4's land detector says it too, later)."""
    standing_height_m: Positive | None = None
    """Height of the base's centre of mass above the ground when the vehicle stands on its
    landing gear [m]. Set, a mission's heights (its points' Z, the cruise altitude) are
    above the ground the vehicle takes off from, whatever PX4's local origin (with GPS,
    EKF2 puts it at the standing vehicle, this height above the ground); unset, they are
    PX4's local Z."""
    stow_joints_rad: Annotated[tuple[Real, ...], Field(min_length=2, max_length=2)] = (
        0.0,
        -1.5707963267948966,
    )
    """(eta1, eta2) the arm is held at outside the mission (take-off, home, landing)
    [rad]: link 1 forward, link 2 down."""
    excite_eta1_rad: Annotated[Positive, _within(1.0, "rad", "a swing that stays clear")] = 0.5
    """Amplitude of joint 1's swing in the mission's excitation [rad] (what the estimator
    learns m3 and m4 from)."""
    excite_payload_kg: Annotated[Positive, _within(10.0, "kg", "a payload")] = 0.25
    """The payload the swing's amplitudes are for [kg]: a heavier one (the estimate as the
    excitation begins) swings both joints by the square root of this over its mass
    (companion.mission.pickup.PickupMission.swing_scale): the moment of its weight across
    the swing, which pushes the vehicle off its circle, grows less, and the estimator
    still gets enough excitation to be confident. Measured in the SITL with 0.44 kg at
    the tip and a 0.7 rad swing: 36 cm RMS (82 cm max) off the circle at full swing, 23
    cm RMS scaled."""
    global_origin_deg_m: Vec3 = (47.397742, 8.545594, 488.0)
    """(latitude [deg], longitude [deg], altitude AMSL [m]) the app sets as PX4's global
    origin when the vehicle has none (no GPS: motion capture indoors); PX4 SITL's default
    home (Zurich)."""
    gripper_margin_rad: Annotated[Positive, _within(3.2, "rad", "a gripper's travel")] = 0.1
    """The gripper holds an object when its servo stopped more than this short of
    ``arm_bus.gripper.closed_position_rad``, toward open [rad]
    (:mod:`companion.mission.carry_check`)."""
    gripper_current_a: Annotated[NonNegative, _within(10.0, "A", "a gripper servo")] = 0.2
    """... and draws at least this current [A] (buses that report it)."""
    carry_mass_margin_kg: Annotated[Positive, _within(10.0, "kg", "a payload")] = 0.05
    """Once the estimator is confident in the carry, m2 below the empty link 2's plus this
    means the object is not carried [kg]."""
    max_hover_thrust: Annotated[Positive, Field(le=1.0)] = 0.7
    """Largest relative thrust (PX4's, 0-1: a fraction of the maximum, over the calibrated
    thrust scale) the vehicle may need to hover with the payload, or the lift may command;
    beyond it the payload is refused (from the end of the grasp through the lift's first
    centimetres) and let go where it lies (:mod:`companion.mission.authority`). Assumed:
    PX4 keeps the rest for attitude control and the climb."""
    max_joint_torque_fraction: Annotated[Positive, Field(le=1.0)] = 0.8
    """Largest fraction of a joint's ``torque_max_n_m`` the payload's gravity torque may
    take at the arm poses of the mission (arm down, the excitation's extremes); beyond it
    the payload is refused as for the thrust. Assumed: the rest for the arm's motion."""
    carry_check_estimate: Annotated[bool, Field(strict=True)] = True
    """The estimate is a witness of the carry (``carry_mass_margin_kg``); false: the
    gripper alone (a simulator whose arm carries no mass, as PX4 SIH's arm stand)."""
    servo_check: Literal["auto", "always", "off"] = "auto"
    """Measure the joints' torque constants against the empty arm's gravity on the ground
    before every take-off and fly on the measured values (``companion.mission.servo_check``,
    Dynamixel buses; about 8 s): ``auto`` where a joint is not ``torque_calibrated``,
    ``always`` also to confirm calibrated ones, ``off`` never (a mission on datasheet values
    then says so)."""
    realtime_priority: Annotated[int, Field(strict=True, ge=0, le=99)] = 50
    """SCHED_FIFO priority of the control thread for the mission, where Linux permits it
    (root, CAP_SYS_NICE, an rtprio limit); 0: normal scheduling. A process already under
    a real-time policy keeps it (:mod:`companion.mission.scheduling`)."""


SIMULATOR_SECTIONS = ("payload", "plant", "world", "simulation", "trajectory")
"""Top-level sections of a scenario file the simulator owns (``sitl.scenario``): the truth
(the payload, the plant, the world) and the offline runs. The companion skips them: its
types cannot hold what only the simulator may know."""


class CompanionConfig(_Section):
    """What the companion believes and how it flies: vehicle, arm (link 2 empty), gains,
    estimator, state filter, flight settings and the arm's servo bus."""

    name: str
    description: str
    environment: Environment
    vehicle: Vehicle
    arm: Arm
    estimator: Estimator
    controller: Controller
    sensors: Sensors
    arm_bus: ArmBusSection | None = None
    """The arm's servo bus; absent in scenarios that only simulate."""
    flight: Flight = Field(default_factory=Flight)
    """The flight app's PX4 handover and navigation watch (defaults when absent)."""

    @property
    def nominal_theta(self) -> Theta:
        """theta of the empty link 2 (the non-adaptive baseline's parameters)."""
        link = self.arm.link2
        return Theta(
            m2_kg=link.mass_kg,
            m3_kg_m=link.first_moment_kg_m,
            m4_kg_m2=link.second_moment_kg_m2,
        )


def _dotted(loc: tuple[int | str, ...]) -> str:
    """The dotted key of a location; a key with characters that would break the one-line
    message (a newline, a carriage return, ...) is quoted with escapes."""
    key = ""
    for part in loc:
        if isinstance(part, int):
            key += f"[{part}]"
            continue
        name = part if part.isprintable() else repr(part)
        key += f".{name}" if key else name
    return key


def _describe(err: ErrorDetails, root: type[BaseModel]) -> tuple[str, str]:
    """(dotted key, reason) of one pydantic error of a ``root`` document, suggesting the key
    meant for a typo."""
    key = _dotted(err["loc"])
    if err["type"] == "extra_forbidden":
        section = _section_model(err["loc"][:-1], root)
        names = [f.alias or n for n, f in section.model_fields.items()] if section else []
        close = difflib.get_close_matches(str(err["loc"][-1]), names, n=1)
        hint = f"; did you mean '{close[0]}'?" if close else ""
        return key, f"unknown key{hint}"
    if err["type"] == "missing":
        return key, "missing key"
    reason = err["msg"].removeprefix("Value error, ")
    return key, f"{reason} (got {err['input']!r})"


def _section_model(loc: tuple[int | str, ...], root: type[BaseModel]) -> type[BaseModel] | None:
    """The pydantic class validating the table at ``loc`` of a ``root`` document (through
    optional sections and arrays of tables; None if there is none)."""
    model: type[BaseModel] = root
    for part in loc:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(part)
        tables = (
            [
                arg
                for arg in (field.annotation, *typing.get_args(field.annotation))
                if isinstance(arg, type) and issubclass(arg, BaseModel)
            ]
            if field
            else []
        )
        if not tables:
            return None
        model = tables[0]
    return model


def check_theta(theta: Theta, link2_length_m: float, path: str, key: str) -> None:
    """Reject theta that no rigid link 2 can have: lc outside [0, l2] or m4 < m3^2 / m2.

    Raises
    ------
    ConfigError
        Naming ``path`` and ``key`` and the violated condition.
    """
    lc = theta.lc_m
    if not 0.0 <= lc <= link2_length_m:
        raise ConfigError(
            path, key, f"lc = m3/m2 = {lc:.6g} m lies outside [0, l2] = [0, {link2_length_m:g}] m"
        )
    floor = theta.m3_kg_m**2 / theta.m2_kg
    if theta.m4_kg_m2 < floor * (1.0 - _REL_TOL):
        raise ConfigError(
            path,
            key,
            f"m4 = {theta.m4_kg_m2:.6g} kg m^2 < m3^2/m2 = {floor:.6g} kg m^2: "
            "no mass distribution has this second moment",
        )


def _check_arm_bus(section: ArmBusSection, path: str) -> None:
    """Joint names and servo ids unique, angle limits ordered, no friction on a DroneCAN
    bus (its actuators report their output torque: the friction would be ignored)."""
    names: set[str] = set()
    ids: dict[int, str] = {}
    try:
        dronecan = parse_bus_url(section.url).backend == "dronecan"
    except ValueError:  # a malformed URL is open_bus's one-line error, when the bus opens
        dronecan = False
    for i, joint in enumerate(section.joints):
        key = f"arm_bus.joints[{i}]"
        for friction in ("viscous_friction_n_m_s_per_rad", "coulomb_friction_n_m"):
            if dronecan and getattr(joint, friction) != 0.0:
                raise ConfigError(
                    path,
                    f"{key}.{friction}",
                    "a DroneCAN actuator reports its output torque: the bus uses no friction "
                    "(set 0 or remove the key)",
                )
        if joint.name in names:
            raise ConfigError(path, f"{key}.name", f"joint {joint.name!r} is named twice")
        names.add(joint.name)
        if not joint.position_min_rad < joint.position_max_rad:
            raise ConfigError(
                path,
                f"{key}.position_max_rad",
                f"{joint.position_max_rad:g} rad must exceed position_min_rad "
                f"{joint.position_min_rad:g} rad",
            )
        if joint.servo_id in ids:
            raise ConfigError(
                path, f"{key}.servo_id", f"id {joint.servo_id} is also {ids[joint.servo_id]}"
            )
        ids[joint.servo_id] = f"joint {joint.name!r}"
    if section.gripper is not None and section.gripper.servo_id in ids:
        gid = section.gripper.servo_id
        raise ConfigError(path, "arm_bus.gripper.servo_id", f"id {gid} is also {ids[gid]}")


def arm_bus_configs(
    section: ArmBusSection,
) -> tuple[tuple[JointConfig, ...], GripperConfig | None]:
    """The ``arm_driver`` joint and gripper configurations of an ``arm_bus`` section.

    Returns
    -------
    joints, gripper
        ``arm_driver.joint.JointConfig`` per joint in file order, and the
        ``GripperConfig`` or None; ready for ``arm_driver.bus.open_bus(section.url, ...)``.
    """
    joints = tuple(
        JointConfig(**joint.model_dump(exclude={"torque_calibrated"})) for joint in section.joints
    )
    gripper = None if section.gripper is None else GripperConfig(**section.gripper.model_dump())
    return joints, gripper


def check_companion(cfg: CompanionConfig, path: str) -> None:
    """Values no vehicle can have that the types cannot catch: a link CoM beyond its link,
    an initial theta no rigid link 2 has, estimator rows and bounds out of order.

    Raises
    ------
    ConfigError
        Naming ``path``, the key and the reason.
    """
    for name in ("link1", "link2"):
        link: Link = getattr(cfg.arm, name)
        if link.com_m > link.length_m:
            raise ConfigError(
                path,
                f"arm.{name}.com_m",
                f"{link.com_m:g} m lies beyond the link length {link.length_m:g} m",
            )
    l2 = cfg.arm.link2.length_m
    check_theta(cfg.estimator.initial_theta, l2, path, "estimator.initial_theta")
    est = cfg.estimator
    if list(est.rows) != sorted(set(est.rows)):
        raise ConfigError(path, "estimator.rows", f"must be increasing and unique, got {est.rows}")
    low, high = est.m2_bounds_kg
    if not low < high:
        raise ConfigError(path, "estimator.m2_bounds_kg", f"need min < max, got {est.m2_bounds_kg}")
    if not low <= est.initial_theta.m2_kg <= high:
        raise ConfigError(
            path,
            "estimator.initial_theta.m2_kg",
            f"{est.initial_theta.m2_kg:g} kg lies outside m2_bounds_kg {est.m2_bounds_kg}",
        )
    if est.thrust_scale is not None:
        s_low, s_high = est.thrust_scale.bounds
        if not s_low < s_high:
            raise ConfigError(
                path,
                "estimator.thrust_scale.bounds",
                f"need min < max, got {est.thrust_scale.bounds}",
            )
        if not s_low <= est.thrust_scale.initial <= s_high:
            raise ConfigError(
                path,
                "estimator.thrust_scale.initial",
                f"{est.thrust_scale.initial:g} lies outside bounds {est.thrust_scale.bounds}",
            )
    if cfg.arm_bus is not None:
        _check_arm_bus(cfg.arm_bus, path)


Model = typing.TypeVar("Model", bound=BaseModel)


def validate(model: type[Model], data: dict, path: str) -> Model:
    """``model.model_validate(data)``, its errors as one :class:`ConfigError` (unknown keys
    first, with the closest valid name)."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        # A bad item of a tuple also shortens it: that length is no second problem (the
        # item's error lies anywhere below the tuple: its own key, or a key of its table).
        inner = {err["loc"][:n] for err in errors for n in range(len(err["loc"]))}
        errors = [e for e in errors if not (e["type"] == "too_short" and e["loc"] in inner)]
        problems = sorted(
            (_describe(err, model) for err in errors),
            key=lambda kr: not kr[1].startswith("unknown key"),
        )
        raise ConfigError(path, *problems[0], *problems[1:]) from None


TOML_LIMIT_BYTES = SMALL_FILE_LIMIT_BYTES
"""The largest TOML file read (configurations, scenarios, campaign specs) [bytes]: 1 MiB,
a hundred times the largest shipped one. A larger file is refused by its size, unread."""


@dataclass(frozen=True)
class TomlDocument:
    """A TOML file as read: its bytes, its text and its parsed document."""

    path: Path
    raw: bytes
    text: str
    data: dict[str, Any]


def read_toml_document(path: str | Path) -> TomlDocument:
    """A user's TOML file, read and parsed; :class:`ConfigError` (one line naming the file)
    if it cannot be read or parsed.

    Refused before anything is read (:mod:`companion.user_files`): a path that is not a
    regular file (missing, a directory, a FIFO, a device, a socket, a loop of links) and a
    file over :data:`TOML_LIMIT_BYTES`. Refused after: bytes that are not UTF-8, text that
    is not TOML, nesting deeper than the parser goes, and a file without a key (nothing
    any reader takes is empty).
    """
    p = Path(path)
    try:
        raw = read_small_file(p, TOML_LIMIT_BYTES, "a TOML configuration, scenario or spec")
    except UserFileError as exc:
        raise ConfigError(str(p), "", exc.reason) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        reason = f"not a UTF-8 text file ({exc.reason} at byte {exc.start})"
        raise ConfigError(str(p), "", reason) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(p), "", f"invalid TOML: {exc}") from None
    except RecursionError:
        reason = "invalid TOML: arrays or tables nested too deeply to read"
        raise ConfigError(str(p), "", reason) from None
    if not data:
        empty = "an empty file" if not text.strip() else "only comments"
        raise ConfigError(str(p), "", f"holds no TOML keys ({empty})")
    return TomlDocument(p, raw, text, data)


def read_toml(path: str | Path) -> dict:
    """A TOML file's document (:func:`read_toml_document`); :class:`ConfigError` if it
    cannot be read or parsed."""
    return read_toml_document(path).data


def parse_config(data: dict, path: str = "<string>") -> CompanionConfig:
    """Validate the companion's sections of a parsed TOML document (the simulator's,
    :data:`SIMULATOR_SECTIONS`, are skipped) into a :class:`CompanionConfig`.

    Raises
    ------
    ConfigError
        On unknown or missing keys, wrong types, or physically impossible values.
    """
    beliefs = {k: v for k, v in data.items() if k not in SIMULATOR_SECTIONS}
    cfg = validate(CompanionConfig, beliefs, path)
    check_companion(cfg, path)
    return cfg


def load_config(path: str | Path) -> CompanionConfig:
    """Read and validate the companion's part of a TOML file (explicit path only).

    Raises
    ------
    ConfigError
        If the file cannot be read, is not TOML, or does not validate.
    """
    return parse_config(read_toml(path), str(path))

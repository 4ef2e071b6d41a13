"""The simulator's scenario: the companion's configuration plus the truth (SI units).

``sitl`` owns the sections of a scenario file the companion must not see
(:data:`companion.config.SIMULATOR_SECTIONS`): ``[payload]`` (what the gripper will hold),
``[plant]`` (the truth plant and its PX4-like loops), ``[world]`` (ground, start pose,
the object), ``[simulation]`` and ``[trajectory]`` (offline runs). :class:`Scenario` is a
:class:`~companion.config.CompanionConfig` with those sections; :attr:`Scenario.beliefs`
is the companion's part alone, what the simulated companion is given.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field

from arm_driver.url import parse_bus_url
from companion.config import (
    CompanionConfig,
    ConfigError,
    Distance,
    Fraction,
    LinkInertia,
    NonNegative,
    NonNegativeVec3,
    Positive,
    PositiveVec3,
    Real,
    Theta,
    Vec3,
    VecQ,
    _Section,
    _within,
    check_companion,
    read_toml,
    validate,
)

__all__ = [
    "MIN_PLANT_RATE_HZ",
    "AttitudeControl",
    "Battery",
    "Payload",
    "PayloadSlip",
    "Plant",
    "Scenario",
    "Simulation",
    "Trajectory",
    "WorldSection",
    "load_scenario",
    "parse_scenario",
    "servo_watchdog_option",
]

MIN_PLANT_RATE_HZ = 1000.0
"""Lowest accepted integration rate of the SITL truth plant [Hz]."""
MAX_DURATION_S = 3600.0
"""Longest offline run [s]: a multirotor's battery lasts well under an hour."""

WindSpeed = Annotated[Real, _within(30.0, "m/s", "a wind a multirotor flies in", low=-30.0)]
PayloadMass = Annotated[NonNegative, _within(50.0, "kg", "a payload a multirotor lifts")]


class Payload(_Section):
    """A grasped object, rigidly attached to link 2 on its axis."""

    mass_kg: PayloadMass
    """Payload mass [kg]."""
    position_m: Distance
    """Distance of the payload CoM from joint 2 along link 2 [m]."""
    inertia_about_com_kg_m2: LinkInertia
    """Moment of inertia about its CoM, perpendicular to link 2 [kg m^2]."""


class Trajectory(_Section):
    """Desired trajectory q_d(t) (paper section IV); roll and pitch come from eq. phid."""

    kind: Literal["paper_sinusoid"]
    """``paper_sinusoid``: x = ax cos(w t), y = ay cos(w t), eta_i = c_i + a_i sin(w t)."""
    period_s: Positive
    """Period 2 pi / w of every sinusoid [s]."""
    amplitude_x_m: Real
    amplitude_y_m: Real
    altitude_m: Real
    """Constant desired z (ENU, up) [m]."""
    yaw_rad: Real
    eta1_center_rad: Real
    eta1_amplitude_rad: Real
    eta2_center_rad: Real
    eta2_amplitude_rad: Real


class Simulation(_Section):
    """Offline simulation settings."""

    duration_s: Annotated[
        Positive, _within(MAX_DURATION_S, "s", "a multirotor's battery lasts under an hour")
    ]
    initial_q: VecQ
    """Initial generalized coordinates q(0) (m, rad); q_dot(0) = 0."""
    control_rate_hz: Annotated[
        Positive, _within(10000.0, "Hz", "a control loop on a vehicle's computer", low=1.0)
    ]
    """Rate of the companion's control step (a divisor of plant.rate_hz) [Hz]."""
    payload_attached_at_start: bool
    """Start with the payload grasped (the paper's scenario)."""


class AttitudeControl(_Section):
    """Gains of the PX4-like attitude and rate loops inside the SITL plant.

    Vectors are (roll, pitch, yaw) about the body x, y, z axes. The rate loop outputs
    torques normalized as in PX4's control allocation (see ``sitl.physics.rotors``).
    """

    attitude_p: PositiveVec3
    """P gains on the quaternion attitude error (MC_ROLL_P, MC_PITCH_P, MC_YAW_P)
    [rad/s per rad]."""
    yaw_weight: Fraction
    """De-prioritisation of yaw against roll and pitch (MC_YAW_WEIGHT) [-]."""
    rate_max_rad_s: PositiveVec3
    """Body-rate setpoint limits (MC_ROLLRATE_MAX, MC_PITCHRATE_MAX, MC_YAWRATE_MAX) [rad/s]."""
    rate_p: NonNegativeVec3
    """Rate P gains (MC_*RATE_P) [normalized torque per rad/s]."""
    rate_i: NonNegativeVec3
    """Rate I gains (MC_*RATE_I) [normalized torque per rad]."""
    rate_d: NonNegativeVec3
    """Rate D gains on the measured angular acceleration (MC_*RATE_D)
    [normalized torque per rad/s^2]."""
    rate_integrator_limit: NonNegativeVec3
    """Limits of the rate integrators (MC_RR_INT_LIM, MC_PR_INT_LIM, MC_YR_INT_LIM)
    [normalized torque]."""
    rate_d_cutoff_hz: Positive
    """Low-pass cutoff of the angular-acceleration estimate for the D term
    (IMU_DGYRO_CUTOFF) [Hz]."""


class Battery(_Section):
    """The truth battery feeding the rotors (:mod:`sitl.physics.battery`): a LiPo pack whose
    voltage falls with the charge drawn and, at once, with the load current through its
    internal resistance; the thrust a motor command makes follows the voltage squared,
    relative to the pack at 3.85 V a cell (where ``vehicle.rotors.max_thrust_per_rotor_n``
    times ``plant.thrust_mismatch`` holds). The vehicle streams its voltage and current
    (BATTERY_STATUS, SYS_STATUS) as PX4 does; the companion's thrust model does not know
    the battery."""

    cells: Annotated[int, Field(strict=True, ge=1), _within(14, "", "a multirotor pack")] = 4
    """Cells in series [-] (4: a 4S pack, 16.8 V full)."""
    capacity_ah: Annotated[Positive, _within(100.0, "A h", "a multirotor pack")] = 5.0
    """Charge of the full pack [A h]."""
    resistance_ohm: Annotated[NonNegative, _within(1.0, "ohm", "a pack that flies")] = 0.03
    """Internal resistance of the pack with its wiring [ohm] (0.03: a 4S 5 A h pack)."""
    start_charge: Annotated[
        float,
        Field(strict=True, gt=0.0, le=1.0, allow_inf_nan=False),
        _within(1.0, "", "a state of charge"),
    ] = 1.0
    """State of charge at power-on, in (0, 1] [-] (1: fully charged)."""


class Plant(_Section):
    """The SITL truth plant: integration rate, truth-only effects and the PX4-like loops."""

    rate_hz: Annotated[
        float,
        Field(strict=True, ge=MIN_PLANT_RATE_HZ, allow_inf_nan=False),
        _within(1e5, "Hz", "a fixed-step truth integration", low=MIN_PLANT_RATE_HZ),
    ]
    """Fixed integration rate of the truth dynamics, at least 1000 [Hz]."""
    integrator: Literal["semi_implicit_euler", "rk4"]
    """Fixed-step scheme: ``semi_implicit_euler`` (one dynamics evaluation per step, first
    order) or ``rk4`` (four, fourth order); see ``sitl.physics.integration``."""
    thrust_mismatch: Annotated[Positive, _within(10.0, "", "true over believed thrust")]
    """True maximum rotor thrust over the believed ``vehicle.rotors.max_thrust_per_rotor_n``
    (1 = the companion's thrust model is exact) [-]."""
    battery: Battery | None = None
    """The battery feeding the rotors (absent: an ideal supply at the reference voltage,
    the thrust per command constant); Pinocchio and JSBSim plants only (SIH's thrust is
    PX4's own)."""
    linear_drag_n_s_m: NonNegativeVec3
    """Diagonal D of the linear drag force -D (v - w) on the vehicle, v the world-frame
    (ENU) velocity of the vehicle CoM, w the wind [N s/m]; underactuated plant only."""
    wind_m_s: Annotated[tuple[WindSpeed, ...], Field(min_length=3, max_length=3)] = (
        0.0,
        0.0,
        0.0,
    )
    """Steady wind, the air's velocity over the ground, world ENU [m/s] ((3, 0, 0) blows
    toward the east): the linear drag acts on the velocity relative to the air, -D (v - w),
    on both physics (JSBSim: its atmosphere's wind); ``sitl run --wind`` overrides it."""
    servo_torque_limit_n_m: Annotated[
        Positive, _within(1000.0, "N m", "a servo an arm on a multirotor carries")
    ]
    """Magnitude limit of each joint torque the simulated servos can apply [N m]."""
    attitude_control: AttitudeControl
    servo_torque_constant_mismatch: Annotated[
        Positive, _within(2.0, "", "a servo within a factor of two of its datasheet")
    ] = 1.0
    """True torque constant of the simulated joint servos over the believed
    ``arm_bus.joints.torque_constant_n_m_per_a`` (1.1: 10 % more torque per amp than the
    companion thinks) [-]; ``sitl run`` only (the offline simulator has no servos)."""


class PayloadSlip(_Section):
    """The grasped object slips out of the gripper mid-carry (truth; ``sitl run``)."""

    after_grasp_s: Annotated[NonNegative, _within(MAX_DURATION_S, "s", "a multirotor's flight")]
    """Time after the grasp at which the object slips out and falls [s]."""


class WorldSection(_Section):
    """The SITL's world around the vehicle (``sitl run``); optional, not used by the companion.

    Positions are world ENU [m] (z up, ground at z = 0).
    """

    landing_gear_height_m: Positive
    """Height of the base's centre of mass above the ground when it stands [m]."""
    start_position_m: Annotated[tuple[Real, ...], Field(min_length=2, max_length=2)]
    """(x, y) where the vehicle stands at the start [m]."""
    start_yaw_rad: Real
    """Heading at the start, ENU (0 = east, counter-clockwise positive) [rad]."""
    start_joints_rad: Annotated[tuple[Real, ...], Field(min_length=2, max_length=2)]
    """(eta1, eta2) at the start [rad]."""
    payload_position_m: Vec3 | None = None
    """Where the payload object rests, at the point the jaws take hold of it (the
    ``[payload]`` section's mass and inertia); absent: no object in the world."""
    grasp_tolerance_m: Positive
    """Largest distance between the object and the jaws at which closing the gripper
    grasps it [m]."""
    jaw_point_m: Positive | None = None
    """Where along link 2 the jaws hold an object, from joint 2 [m]; absent: 2 cm inside
    link 2's tip. The held object's centre of mass is at ``[payload] position_m`` along
    link 2, which may lie beyond or short of the jaws."""
    jaw_closure_on_object: Annotated[
        float, Field(strict=True, gt=0.5, lt=1.0, allow_inf_nan=False)
    ] = 0.8
    """Fraction of the gripper's travel from open to closed at which its jaws meet a grasped
    object (the object's width; past the middle) [-]: the gripper servo reads short of its
    closed position and draws current."""
    grasp_fails: Annotated[bool, Field(strict=True)] = False
    """Truth fault: closing the gripper never grasps (the jaws close on nothing)."""
    payload_slip: PayloadSlip | None = None
    """Truth fault: the grasped object slips out of the gripper; absent: it stays."""
    autopilot_params: dict[str, Real] = Field(default_factory=dict)
    """PX4 parameter overrides of the simulated autopilot (name -> value), checked against
    the simulated parameter table when the SITL starts."""


class Scenario(CompanionConfig):
    """A complete scenario: the companion's configuration, the payload, the truth plant,
    the world and the offline run settings."""

    payload: Payload
    trajectory: Trajectory
    simulation: Simulation
    plant: Plant
    world: WorldSection | None = None
    """The SITL's world (ground, start pose, payload object); absent: defaults of ``sitl``."""

    @property
    def beliefs(self) -> CompanionConfig:
        """The companion's part alone: what a simulated companion is given."""
        return CompanionConfig.model_validate(
            {name: getattr(self, name) for name in CompanionConfig.model_fields}
        )

    @property
    def true_theta(self) -> Theta:
        """theta of link 2 with the payload attached (the simulation's truth)."""
        link, load = self.arm.link2, self.payload
        return Theta(
            m2_kg=link.mass_kg + load.mass_kg,
            m3_kg_m=link.first_moment_kg_m + load.mass_kg * load.position_m,
            m4_kg_m2=link.second_moment_kg_m2
            + load.mass_kg * load.position_m**2
            + load.inertia_about_com_kg_m2,
        )


def check_simulator(cfg: Scenario, path: str) -> None:
    """The simulator's values no world can have: a payload or the jaws beyond link 2, an
    object below the ground, a control rate that does not divide the plant rate."""
    l2 = cfg.arm.link2.length_m
    if cfg.payload.position_m > l2:
        raise ConfigError(
            path,
            "payload.position_m",
            f"{cfg.payload.position_m:g} m lies beyond link 2 (length {l2:g} m)",
        )
    ratio = cfg.plant.rate_hz / cfg.simulation.control_rate_hz
    if ratio < 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-9:
        raise ConfigError(
            path,
            "simulation.control_rate_hz",
            f"{cfg.simulation.control_rate_hz:g} Hz must divide plant.rate_hz "
            f"({cfg.plant.rate_hz:g} Hz) into a whole number of plant steps",
        )
    jaws = None if cfg.world is None else cfg.world.jaw_point_m
    if jaws is not None and jaws > l2:
        raise ConfigError(
            path, "world.jaw_point_m", f"{jaws:g} m lies beyond link 2 (length {l2:g} m)"
        )
    if cfg.world is not None and cfg.world.payload_position_m is not None:
        if cfg.world.payload_position_m[2] < 0.0:
            raise ConfigError(
                path,
                "world.payload_position_m",
                f"the object lies below the ground (z = {cfg.world.payload_position_m[2]:g} m)",
            )


def parse_scenario(data: dict, path: str = "<string>") -> Scenario:
    """Validate a parsed TOML document into a :class:`Scenario` (both owners' sections).

    Raises
    ------
    ConfigError
        On unknown or missing keys, wrong types, or physically impossible values.
    """
    cfg = validate(Scenario, data, path)
    check_companion(cfg, path)
    check_simulator(cfg, path)
    return cfg


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a whole scenario TOML file (explicit path only).

    Raises
    ------
    ConfigError
        If the file cannot be read, is not TOML, or does not validate.
    """
    return parse_scenario(read_toml(path), str(path))


def servo_watchdog_option(cfg: Scenario) -> str:
    """The scenario's servo Bus Watchdog as a bus URL option (``&watchdog_ms=N``; empty
    without one): the simulated servos fly with the watchdog the vehicle's config arms, so
    a companion that stops talking to them meets what it would in flight."""
    if cfg.arm_bus is None:
        return ""
    watchdog_ms = parse_bus_url(cfg.arm_bus.url).options.get("watchdog_ms")
    return "" if watchdog_ms is None else f"&watchdog_ms={watchdog_ms}"

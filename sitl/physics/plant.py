"""The SITL truth plant: hexacopter + 2-DOF arm + payload, integrated with Pinocchio.

Two modes (DESIGN.md sections 2-4):

``ideal``
    The paper's simulation: a generalized force tau, conjugate to
    q = [x, y, z, phi, theta, psi, eta1, eta2], acts on all 8 coordinates
    (:meth:`TruthPlant.step_ideal`). No drag.
``underactuated``
    The vehicle as flown: a PX4-like attitude/rate loop tracks an
    :class:`~sitl.physics.attitude_control.AttitudeSetpoint` (relative thrust, linearized
    per motor with the autopilot's THR_MDL_FAC, :meth:`TruthPlant.configure_autopilot`),
    six lagged rotors with their own THR_MDL_FAC-shaped curve (scaled by
    ``plant.thrust_mismatch`` and, if set, the ``plant.battery``'s voltage,
    :mod:`sitl.physics.battery`)
    push the body, linear drag -D (v - w) acts on the vehicle CoM (w the steady wind,
    ``plant.wind_m_s``), and the servos apply joint torques clipped to
    ``plant.servo_torque_limit_n_m`` (:meth:`TruthPlant.step`).

Generalized forces. Pinocchio's free-flyer velocity is (v_B, omega_B), body axes, so with
J = blockdiag(R^T, W(Phi), I2) mapping our q_dot to it, power balance gives
tau_pin = J^-T tau: the world force becomes the body force R^T f_W, the Euler-angle
generalized torques become the body torque W^-T tau_Phi (raises
:class:`~sitl.physics.errors.EulerSingularityError` at theta = +-90 deg), the joint torques
pass unchanged (see :mod:`sitl.physics.articulation` for the joint sign).

Integration: fixed step at ``plant.rate_hz`` (>= 1 kHz) with ``plant.integrator``,
semi-implicit Euler or RK4 on the configuration manifold (quaternion base), inputs held
over the step; see :mod:`sitl.physics.integration` for the scheme and its energy
behaviour (tested in tests/test_sitl_physics.py).

The state lives in the vehicle step's buffer (:mod:`sitl.vehicle_step`), and the plant is
its one Python host: every way into it (reset, the ground's hold, a payload change, the
ideal and the rotor steps, the step coupled to the joint servos) is here, which takes the
module a little over 600 lines; split, the buffer would be handed across classes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike, NDArray

from companion.config import Theta
from companion.coordinates import N_Q
from sitl import vehicle_step
from sitl.physics.articulation import ETA2_JOINT, build_articulation, theta_of
from sitl.physics.attitude_control import (
    AttitudeLoopParams,
    AttitudeSetpoint,
    Px4AttitudeLoop,
)
from sitl.physics.battery import LipoPack
from sitl.physics.errors import (
    EulerSingularityError,
    PlantDivergedError,
    PlantError,
    PlantModeError,
)
from sitl.physics.frames import euler_rate_matrix, quaternion_from_euler
from sitl.physics.integration import ArticulatedIntegrator, GeneralizedForce
from sitl.physics.rotor_plant import RotorPlant
from sitl.physics.rotors import (
    N_ROTORS,
    RotorBank,
    RotorGeometry,
    SequentialDesaturationMixer,
    inverse_thrust_curve,
)
from sitl.physics.state import ActuatorState, PlantState
from sitl.scenario import Scenario

__all__ = ["PlantMode", "TruthPlant"]

FloatArray = NDArray[np.float64]
PlantMode = Literal["ideal", "underactuated"]


class TruthPlant(RotorPlant):
    """Truth dynamics of the aerial manipulator; see the module docstring.

    Pure: no I/O, no clock, no randomness. Not thread-safe (it owns Pinocchio data).

    Parameters
    ----------
    scenario : Scenario
        Validated scenario (vehicle, arm, payload, rotors, plant sections).
    mode : {"ideal", "underactuated"}
        Which input the plant takes.
    payload_attached : bool
        Start with the payload grasped (the paper's simulation) or not.

    Examples
    --------
    >>> scenario = load_scenario("configs/paper_sim.toml")
    >>> plant = TruthPlant.from_scenario(scenario, payload_attached=True)
    >>> state = plant.step_ideal(tau)            # one step of 1 / plant.rate_hz s
    >>> state.q, state.q_dot, plant.true_theta   # q_ddot: truth, for tests only

    >>> flyer = TruthPlant.from_scenario(scenario, "underactuated")
    >>> flyer.step(AttitudeSetpoint.from_euler(0.0, 0.1, 0.0, 0.45), [0.0, 0.3])
    >>> flyer.actuators.rotor_thrusts_n          # for logging
    """

    has_ground = False
    """This plant flies in free space: a SITL adds the ground (see :meth:`hold_base`)."""
    _coordinates: tuple[list[float], list[float]] | None
    """q and q_dot of the state, once read (None: not read since it changed)."""

    @property
    def flies_rotors(self) -> bool:
        """The underactuated mode: the rotors move the vehicle (the ideal mode takes tau)."""
        return self.mode == "underactuated"

    @property
    def coordinates(self) -> tuple[list[float], list[float]]:
        """q and q_dot now (:attr:`RotorPlant.coordinates
        <sitl.physics.rotor_plant.RotorPlant.coordinates>`): lists read from the state's
        buffer once per state."""
        if self._coordinates is None:
            self._coordinates = self._integrator.coordinates()
        return self._coordinates

    def _truth(self) -> tuple:
        return (*self._integrator.truth(), self._payload_attached)

    def _attitude(
        self,
    ) -> tuple[tuple[float, float, float, float], tuple[float, float, float]]:
        return self._integrator.attitude()

    def __init__(
        self,
        scenario: Scenario,
        mode: PlantMode = "ideal",
        *,
        payload_attached: bool = False,
        wind_m_s: tuple[float, ...] | None = None,
    ) -> None:
        if mode not in ("ideal", "underactuated"):
            raise ValueError(f"mode must be 'ideal' or 'underactuated', got {mode!r}")
        self.scenario = scenario
        self.mode: PlantMode = mode
        self.rate_hz = float(scenario.plant.rate_hz)
        self.dt_s = 1.0 / self.rate_hz
        self.gravity_m_s2 = scenario.environment.gravity_m_s2

        art = build_articulation(scenario)
        self._model = art.model
        self._integrator = ArticulatedIntegrator(self._model, self.dt_s, scenario.plant.integrator)
        self._link2_empty = art.link2_empty
        self._payload = art.payload
        self._payload_attached = False
        self._payload_share = 0.0

        rotors = scenario.vehicle.rotors
        self._geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
        self._rotor_wrench = self._geometry.wrench_matrix()[:3].tolist()
        self._rotors = RotorBank(
            rotors.max_thrust_per_rotor_n * scenario.plant.thrust_mismatch,
            rotors.thr_mdl_fac,
            rotors.motor_time_constant_s,
            self.dt_s,
        )
        self._max_thrust_n = self._rotors.max_thrust_n
        self._thrust_mismatch = scenario.plant.thrust_mismatch
        self._battery = LipoPack.of(scenario.plant.battery)
        self._battery_buffer = None if self._battery is None else self._battery.buffer
        mixer = SequentialDesaturationMixer(self._geometry, rotors.max_thrust_per_rotor_n)
        self._autopilot = Px4AttitudeLoop.from_params(
            AttitudeLoopParams.from_config(scenario.plant.attitude_control, rotors.thr_mdl_fac),
            mixer,
            self.dt_s,
        )
        self._drag: tuple[float, float, float] = tuple(  # type: ignore[assignment]
            float(d) for d in scenario.plant.linear_drag_n_s_m
        )
        self._wind: tuple[float, float, float] = tuple(  # type: ignore[assignment]
            float(w) for w in (scenario.plant.wind_m_s if wind_m_s is None else wind_m_s)
        )
        self._integrator.set_rotor_wrench(
            self._rotor_wrench, self._drag, self._wind, self._max_thrust_n
        )
        self._servo_limit = scenario.plant.servo_torque_limit_n_m
        self._integrator.set_servo_limit(self._servo_limit)
        self._servo_buffers: tuple | None = None
        """The joint servos' physics buffers (:meth:`couple_servos`)."""
        self._actuators: ActuatorState | None = None
        self._actuator_signals: tuple | None = ()
        """The actuator signals of the last step, or None: in the state's buffer."""

        self._work = self._integrator.work
        """The state (x, u, their kinematics, the last step's q_ddot) in the integrator's
        buffer (:data:`~sitl.vehicle_step.LAYOUT`)."""
        self._state_cache: PlantState | None = None
        self._coordinates = None
        self._steps = 0
        self._t0 = 0.0
        if payload_attached:
            self._set_payload(True)
        self.reset(scenario.simulation.initial_q)

    @classmethod
    def from_scenario(
        cls,
        scenario: Scenario,
        mode: PlantMode = "ideal",
        *,
        payload_attached: bool = False,
        wind_m_s: tuple[float, ...] | None = None,
    ) -> TruthPlant:
        """Plant of a validated scenario, at rest at ``simulation.initial_q``; ``wind_m_s``
        (steady, world ENU [m/s]) replaces the scenario's ``plant.wind_m_s``."""
        return cls(scenario, mode, payload_attached=payload_attached, wind_m_s=wind_m_s)

    # ------------------------------------------------------------------ state

    def reset(
        self,
        q: ArrayLike,
        q_dot: ArrayLike | None = None,
        *,
        time_s: float = 0.0,
        rotor_thrusts_n: ArrayLike | None = None,
    ) -> PlantState:
        """Put the plant in state (q, q_dot) at ``time_s``; returns the state.

        Parameters
        ----------
        q : array_like, shape (8,)
            Generalized coordinates [m, rad] (DESIGN.md section 2).
        q_dot : array_like, shape (8,), optional
            Their rates [m/s, rad/s]; zero by default.
        time_s : float
            Simulation time of this state [s].
        rotor_thrusts_n : array_like, shape (6,), optional
            Underactuated mode: the rotors' produced thrusts [N]; by default each carries
            1/6 of the total weight (hover trim). Ignored in ideal mode.

        The autopilot's integrators and filters are cleared; the payload stays as it is.

        Raises
        ------
        ValueError
            On wrong shapes or non-finite values.
        EulerSingularityError
            At theta = +-90 deg.
        """
        q_arr = np.array(_vector(q, "q"))
        qd_arr = np.zeros(N_Q) if q_dot is None else np.array(_vector(q_dot, "q_dot"))
        phi, theta, psi = (float(a) for a in q_arr[3:6])
        w, x, y, z = quaternion_from_euler(phi, theta, psi).tolist()
        omega = euler_rate_matrix(phi, theta) @ qd_arr[3:6]
        self._load(
            [*q_arr[0:3].tolist(), x, y, z, w, *q_arr[6:8].tolist()],
            [*qd_arr[0:3].tolist(), *omega.tolist(), *qd_arr[6:8].tolist()],
            (phi, theta, psi),
            [0.0] * N_Q,
        )
        self._steps = 0
        self._t0 = float(time_s)
        if self.mode == "underactuated":
            if rotor_thrusts_n is None:
                each = self.total_mass_kg * self.gravity_m_s2 / N_ROTORS
                thrusts = np.full(N_ROTORS, min(each, self._rotors.max_thrust_n))
            else:
                thrusts = np.asarray(rotor_thrusts_n, dtype=np.float64)
            self._rotors.reset(thrusts)
            self._autopilot.reset(self._attitude()[1])
            commands = inverse_thrust_curve(
                np.clip(thrusts / self._rotors.max_thrust_n, 0.0, 1.0), self._rotors.thr_mdl_fac
            )
            self._actuator_signals = (commands, thrusts, (0.0, 0.0), (0.0,) * 3, (0.0,) * 3)
            self._actuators = None
        return self.state

    def hold_base(
        self,
        position_m: tuple[float, float, float],
        yaw_rad: float,
        arm_before: tuple[list[float], list[float], list[float]] | None = None,
    ) -> None:
        """Pin the base level at ``position_m`` (world ENU [m]) and ``yaw_rad``, at rest
        (the new state is :attr:`state`, built when read).

        A rigid contact for a SITL's ground: the rotors keep their thrust, time goes on;
        the autopilot's integrators are cleared, as PX4 does while landed. Cheaper than
        :meth:`reset` (called every step on the ground).

        The joints keep the angles and rates of the free step just taken, or, with
        ``arm_before = (eta [rad], eta_dot [rad/s], joint torques [N m])`` of the start
        of that step (the torques clipped as :meth:`step` clips them), take it again on
        the held base (semi-implicit Euler, whatever
        ``plant.integrator``): gravity then swings the arm as on a stand, and the base's
        own torques (rotors, the ground) do not reach it. Without it a standing arm is
        weightless (the free step falls with the base) and the rotors' torques, cancelled
        on the base each step, pump the joints.
        """
        half = 0.5 * yaw_rad
        work = self._work
        x = [*position_m, 0.0, 0.0, math.sin(half), math.cos(half), work[_X + 7], work[_X + 8]]
        u = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, work[_U + 6], work[_U + 7]]
        q_ddot = None
        if arm_before is not None:
            eta, eta_dot, torques = arm_before
            x[7:9] = eta
            j1, j2 = self._joint_torques(torques)
            dd1, dd2 = self._integrator.fixed_base_joint_accelerations(
                x, (eta_dot[0], eta_dot[1]), (j1, j2)
            )
            rate1, rate2 = eta_dot[0] + self.dt_s * dd1, eta_dot[1] + self.dt_s * dd2
            x[7:9] = (eta[0] + self.dt_s * rate1, eta[1] + self.dt_s * rate2)
            u[6:8] = (rate1, rate2)
            q_ddot = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, dd1, dd2]
        if self.mode == "underactuated":
            self._autopilot.reset()
        self._load(x, u, (0.0, 0.0, yaw_rad), q_ddot)

    # ---------------------------------------------------------------- payload

    @property
    def payload_attached(self) -> bool:
        """Whether link 2 currently carries the payload."""
        return self._payload_attached

    def attach_payload(self, share: float = 1.0) -> None:
        """Grasp the payload: link 2's inertia becomes empty link 2 + ``share`` (0-1) of
        the payload, the ground holding the rest (:meth:`set_payload_share`).

        The payload is taken to be at rest in the world when grasped (an inelastic
        capture): the generalized momentum M(q) v is conserved, so v changes unless the
        gripper was at rest. Raises :class:`PlantError` if it is already attached.
        """
        if self._payload_attached:
            raise PlantError("payload is already attached")
        x, euler = self._field("x"), tuple(self._field("euler"))
        q, v = self._integrator.pinocchio_state(x, self._field("u"))
        momentum = self._mass_matrix(q) @ v
        self._set_payload(True, min(max(share, 0.0), 1.0))
        v = np.linalg.solve(self._mass_matrix(q), momentum).tolist()
        r = self._field("rotation")
        u = [
            r[0] * v[0] + r[1] * v[1] + r[2] * v[2],
            r[3] * v[0] + r[4] * v[1] + r[5] * v[2],
            r[6] * v[0] + r[7] * v[1] + r[8] * v[2],
            *v[3:8],
        ]
        self._load(x, u, euler)  # type: ignore[arg-type]

    def set_payload_share(self, share: float) -> None:
        """Link 2 carries ``share`` (clipped to 0-1) of the grasped payload's inertia, the
        ground the rest: an object still standing on the ground while the jaws lift it.
        Velocities are kept (the share changes while the jaws barely move: the momentum
        this adds or takes is small). Raises :class:`PlantError` if none is attached."""
        if not self._payload_attached:
            raise PlantError("no payload is attached")
        share = min(max(share, 0.0), 1.0)
        if share != self._payload_share:
            self._set_payload(True, share)

    def detach_payload(self) -> None:
        """Release the payload: link 2 goes back to its empty inertia; velocities unchanged.

        Raises :class:`PlantError` if no payload is attached.
        """
        if not self._payload_attached:
            raise PlantError("no payload is attached")
        self._set_payload(False)

    @property
    def true_theta(self) -> Theta:
        """(m2, m3, m4) of link 2 as it is now (with the payload if attached)."""
        return theta_of(self._model.inertias[ETA2_JOINT])

    @property
    def total_mass_kg(self) -> float:
        """Mass of vehicle + arm (+ payload if attached) [kg]."""
        return float(sum(self._model.inertias[j].mass for j in range(1, self._model.njoints)))

    def _set_payload(self, attached: bool, share: float = 1.0) -> None:
        payload = self._payload
        if share != 1.0:
            payload = pin.Inertia(payload.mass * share, payload.lever, payload.inertia * share)
        inertia = self._link2_empty + payload if attached else self._link2_empty
        self._model.inertias[ETA2_JOINT] = inertia
        self._integrator.set_model(self._model)
        self._payload_attached = attached
        self._payload_share = share if attached else 0.0
        self._state_cache = None

    # ----------------------------------------------------------------- energy

    @property
    def kinetic_energy_j(self) -> float:
        """Kinetic energy 1/2 v^T M v, armature included [J]."""
        q, v = self._integrator.pinocchio_state(self._field("x"), self._field("u"))
        return 0.5 * float(v @ self._mass_matrix(q) @ v)

    @property
    def potential_energy_j(self) -> float:
        """Gravitational potential energy, zero at world z = 0 [J]."""
        q = np.array(self._field("x"))
        return float(pin.computePotentialEnergy(self._model, self._model.createData(), q))

    def _mass_matrix(self, q: FloatArray) -> FloatArray:
        m = pin.crba(self._model, self._model.createData(), q)
        return np.triu(m) + np.triu(m, 1).T

    # ------------------------------------------------------------------ steps

    def acceleration(self, tau: ArrayLike) -> FloatArray:
        """q_ddot at the current state under generalized force tau (conjugate to q); no step.

        Pure rigid-body dynamics (no drag, no actuators), valid in both modes:
        M(q) q_ddot + C q_dot + G = tau.
        """
        status = self._integrator.acceleration(GeneralizedForce(_vector(tau, "tau")))
        if status == 0:
            return np.array(self._field("acceleration"))
        if status == _SINGULAR:
            raise EulerSingularityError(self._work[_THETA])
        raise PlantDivergedError(self.time_s)

    def step_ideal(self, tau: ArrayLike) -> PlantState:
        """Advance one step under generalized force tau (ideal mode); returns the new state.

        Parameters
        ----------
        tau : array_like, shape (8,)
            [world force on the vehicle (N, ENU), generalized forces conjugate to
            (phi, theta, psi) (N m), joint torques (N m)] (DESIGN.md section 2).

        Raises
        ------
        PlantModeError
            In underactuated mode.
        EulerSingularityError
            At theta = +-90 deg.
        PlantDivergedError
            If the state became non-finite.
        """
        if self.mode != "ideal":
            raise PlantModeError("step_ideal() needs mode='ideal'; use step() instead")
        self._advance(GeneralizedForce(_vector(tau, "tau")))
        return self.state

    def advance(self, setpoint: AttitudeSetpoint, joint_torques_n_m: ArrayLike) -> None:
        """:meth:`RotorPlant.advance <sitl.physics.rotor_plant.RotorPlant.advance>` in one
        compiled call (:meth:`ArticulatedIntegrator.vehicle_step
        <sitl.physics.integration.ArticulatedIntegrator.vehicle_step>`): the attitude loop,
        the battery, the rotors and the integration step, the joint torques clipped there;
        the actuator signals stay in the state's buffer until read."""
        joint = joint_torques_n_m
        if isinstance(joint, (list, tuple)) and len(joint) == 2:
            self._vehicle_step(setpoint, joint)
        else:  # any other array_like, checked here
            self._vehicle_step(setpoint, self._joint_torques(joint))

    def couple_servos(
        self, couplings: list[tuple[float, float, tuple]], gripper: tuple | None = None
    ) -> None:
        """Couple the joint servos to the joints for :meth:`advance_coupled`: for eta1 and
        eta2, (zero offset [rad], direction +1 or -1, the servo's physics buffers
        (:attr:`XM430Servo.physics_buffers <sitl.servo.XM430Servo.physics_buffers>`)); shaft
        angle = zero offset + direction * eta. ``gripper``: the gripper servo's physics
        buffers and its jaw's buffer (``GripperJaw.buffer``), coupled to each other."""
        self._integrator.set_joint_servos([(zero, sign) for zero, sign, _ in couplings])
        buffers = tuple(b for _, _, servo in couplings for b in servo)
        self._servo_buffers = buffers + (() if gripper is None else tuple(gripper))

    def advance_coupled(self, setpoint: AttitudeSetpoint) -> tuple[bool, bool, bool] | None:
        """:meth:`advance` with the joint torques of the servos coupled in
        (:meth:`couple_servos`): each is given its joint's angle and rate now and applies
        its torque, and after the step their loops advance over it, in the same compiled
        call (and the gripper's servo with its jaw, if coupled). Returns None, or whether
        each servo's (eta1's, eta2's, the gripper's) overload timer ran out (the caller
        sets its Overload bit). The same errors, and the servos' ValueError for an angle, a
        rate or a current they cannot hold."""
        self._vehicle_step(setpoint, None)
        work = self._work
        first, second, third = work[_OVERLOADS], work[_OVERLOADS + 1], work[_OVERLOADS + 2]
        if first + second + third == 0.0:
            return None
        return (first != 0.0, second != 0.0, third != 0.0)

    @property
    def coupled_arm(self) -> tuple[list[float], list[float], list[float]]:
        """(eta [rad], eta_dot [rad/s], the servos' torques on the joints before the limit
        [N m]) at the start of the last :meth:`advance_coupled`."""
        arm = self._field("arm_start")
        return arm[0:2], arm[2:4], self._field("servo_torques")

    def _vehicle_step(self, setpoint: AttitudeSetpoint, joint: Sequence[float] | None) -> None:
        """The vehicle's step under ``joint`` torques, or (None) the coupled servos'."""
        self._need_rotors("step() needs mode='underactuated'; use step_ideal() instead")
        work = self._work
        try:
            status = self._integrator.vehicle_step(
                setpoint,
                joint,
                self._autopilot,
                self._rotors.buffer,
                self._battery_buffer,
                None if joint is not None else self._servo_buffers,
            )
        except ValueError:
            if work[_STEPPED]:  # a servo failed after the plant's step
                self._took_step(0)
            raise
        if status == _BAD_JOINT_TORQUES:  # raises its ValueError
            self._joint_torques(self._field("servo_torques") if joint is None else joint)
        self._took_step(status)
        self._actuator_signals = None
        self._actuators = None

    def _signals(self) -> tuple:
        if self._actuator_signals is None:
            return self._integrator.actuator_signals()
        return self._actuator_signals

    def _step_rotors(
        self,
        motor_commands: list[float],
        joint: list[float],
        rate_setpoint_rad_s: tuple,
        torque_normalized: tuple,
    ) -> None:
        """One step of the rotor plant in one call (:meth:`ArticulatedIntegrator.rotor_step
        <sitl.physics.integration.ArticulatedIntegrator.rotor_step>`): the battery feeds the
        rotors' lagged thrusts, which push with drag and wind, and whose lag then moves
        toward ``motor_commands``; records the actuator signals."""
        thrusts = self._rotors.thrust_list_n
        self._took_step(
            self._integrator.rotor_step(
                motor_commands, joint, self._rotors.buffer, self._battery_buffer
            )
        )
        self._actuator_signals = (
            motor_commands,
            thrusts,
            joint,
            rate_setpoint_rad_s,
            torque_normalized,
        )
        self._actuators = None

    # -------------------------------------------------------------- internals
    # The state lives in the integrator's work buffer (sitl.vehicle_step,
    # compiled where built): its steps read and write it there; Python reads its fields
    # only when asked (coordinates, state, the ground's hold, a payload change).

    def _advance(self, force: GeneralizedForce) -> None:
        """One integration step under ``force``; records the step's q_ddot."""
        self._took_step(self._integrator.step(force))

    def _took_step(self, status: int) -> None:
        """Count a step of the integrator that ended with ``status`` (see
        :meth:`ArticulatedIntegrator.step`); raises the plant's errors for a failed one."""
        self._state_cache = None
        self._coordinates = None
        if status == 0:
            self._steps += 1
            return
        if status == _DIVERGED:
            raise PlantDivergedError(self.time_s)
        if status == _SINGULAR:
            raise EulerSingularityError(self._work[_THETA])
        # the step was taken, the new state cannot be reported
        self._steps += 1
        if status == _SINGULAR + 2:
            raise EulerSingularityError(self._work[_THETA])
        raise PlantDivergedError(self.time_s)

    def _load(
        self,
        x: list[float],
        u: list[float],
        euler_previous: tuple[float, float, float],
        q_ddot: list[float] | None = None,
    ) -> None:
        """Make (x, u) the state (its kinematics next to ``euler_previous``), with
        ``q_ddot`` (None: the last one kept); raises the plant's errors for one that cannot
        be reported."""
        status = self._integrator.load(x, u, euler_previous)
        if status == _SINGULAR:
            raise EulerSingularityError(self._work[_THETA])
        if status != 0:
            raise PlantDivergedError(self.time_s)
        if q_ddot is not None:
            for i in range(N_Q):
                self._work[_QDD + i] = q_ddot[i]
        self._state_cache = None
        self._coordinates = None

    def _field(self, name: str) -> list[float]:
        """A field of the state (:data:`~sitl.vehicle_step.LAYOUT`) as a list."""
        offset, size = vehicle_step.LAYOUT[name]
        return self._work[offset : offset + size].tolist()


_DIVERGED = vehicle_step.DIVERGED
_SINGULAR = vehicle_step.SINGULAR
_BAD_JOINT_TORQUES = vehicle_step.BAD_JOINT_TORQUES
"""Failure codes of the integration step and the state's kinematics (see
:meth:`ArticulatedIntegrator.step <sitl.physics.integration.ArticulatedIntegrator.step>`)."""
_X = vehicle_step.LAYOUT["x"][0]
_U = vehicle_step.LAYOUT["u"][0]
_QDD = vehicle_step.LAYOUT["q_ddot"][0]
_THETA = vehicle_step.LAYOUT["theta"][0]
_STEPPED = vehicle_step.LAYOUT["stepped"][0]
_OVERLOADS = vehicle_step.LAYOUT["servo_overloads"][0]
"""Offsets of the state's fields read or written one float at a time."""


def _vector(values: ArrayLike, name: str) -> list[float]:
    """An (8,) input as a list of floats (cheap on the per-step path)."""
    if isinstance(values, np.ndarray) and values.shape == (N_Q,) and values.dtype == np.float64:
        out = values.tolist()
    else:
        arr = np.asarray(values, dtype=np.float64)
        if arr.shape != (N_Q,):
            raise ValueError(f"{name} must have shape ({N_Q},), got {arr.shape}")
        out = arr.tolist()
    if not math.isfinite(sum(out)):
        raise ValueError(f"{name} must be finite, got {values!r}")
    return out

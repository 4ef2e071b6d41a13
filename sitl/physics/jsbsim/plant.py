"""The JSBSim truth plant: the same vehicle as :class:`sitl.physics.TruthPlant`, other physics.

JSBSim integrates the vehicle (6-DOF rigid body on a non-rotating spherical planet, its own
multistep integrators, ground contact, wind and Dryden turbulence acting through the
drag); this module flies it the way the Pinocchio plant's underactuated mode does: the
PX4-like attitude loop (:class:`~sitl.physics.attitude_control.Px4AttitudeLoop`), PX4's
mixer and THR_MDL_FAC linearization, and six lagged rotors with their own thrust curve
(:class:`~sitl.physics.rotors.RotorBank`), whose thrusts act as JSBSim external forces at
the rotor hubs. The arm is integrated outside JSBSim (:mod:`sitl.physics.jsbsim.arm`).

Why external rotor forces and not JSBSim's propulsion (electric engine + propeller
tables): the rotor forces must be those of the configured rotors, so that a difference
between the backends measures the physics around them, not a re-fitted actuator. JSBSim's
electric engine has no motor time constant (spin-up follows from power and propeller
inertia) and its static thrust grows as throttle^(2/3), not along THR_MDL_FAC; matching
both would take a calibration layer that hides exactly what the comparison should show.
What that leaves out: propeller inflow (thrust loss in climb and in wind) and rotor drag
other than the configured linear drag.

One step of 1 / ``plant.rate_hz`` s. JSBSim's ``run()`` first integrates the step with the
accelerations it computed at the end of the previous ``run()``, then recomputes forces and
accelerations at the new state with the inputs as they are now; so an input written
before ``run()`` acts over the *next* step. The plant therefore writes each input one
step ahead:

1. the autopilot maps the setpoint and the true attitude/rate to motor commands; the rotor
   lags advance, and the thrusts of the next step are written (the current step's were
   written one step earlier), so rotor forces act exactly as in the Pinocchio plant;
2. the arm's joint accelerations follow from the servo torques, the external force on the
   vehicle and JSBSim's angular acceleration for this step (both already computed by
   JSBSim; the CoM's motion does not depend on the arm, so the translational coupling is
   exact); the arm advances and its new pose is written as point masses;
3. the coupling moment of this step is written: it acts over the next step (the one-step
   lag of the coupling);
4. ``run()``.

Where it departs from the Pinocchio plant:

- integration: JSBSim's defaults (body rates and attitude: rectangular Euler; velocity:
  Adams-Bashforth 2; position: Adams-Bashforth 3), Pinocchio's ``plant.integrator`` on
  the other side; the arm always uses semi-implicit Euler;
- the rotational coupling with the arm lags one step (see :mod:`sitl.physics.jsbsim.arm`
  for why it converges: the loop gain is below 1, up to 0.68 for the paper arm with
  payload hanging straight down, 0.29 for the experiment arm); the cross-validation
  (tests/test_sitl_jsbsim_crossval.py) shows the difference is first order in the step;
- the drag acts at the vehicle CoM O on the velocity of the CG relative to the air
  (Pinocchio: the velocity of O over the ground); they differ by omega x (CG - O) and by
  the wind;
- ground contact: four gear feet (:class:`~sitl.physics.jsbsim.airframe.GearGeometry`)
  on flat ground at world z = 0; the arm and payload pass through the ground;
- on a grasp, only the joints' momentum is conserved (the base's share of the impulse is
  neglected); q_ddot is a finite difference over the step for the base rows.

Units and frames: SI, ENU/FLU here; English units, NED/FRD and the CG only inside
:mod:`sitl.physics.jsbsim.fdm` (the JSBSim boundary) and the airframe file.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.config import Theta
from companion.coordinates import ATTITUDE, ETA1, ETA2, JOINTS, N_Q, POSITION
from sitl.physics.attitude_control import (
    AttitudeLoopParams,
    Px4AttitudeLoop,
)
from sitl.physics.battery import LipoPack
from sitl.physics.errors import PlantDivergedError, PlantError, PlantModeError
from sitl.physics.frames import (
    euler_from_rotation9,
    euler_rate_matrix,
    euler_rate_matrix_inverse9,
    quaternion_from_euler,
    rotation_from_euler,
)
from sitl.physics.jsbsim.airframe import FT_M, GearGeometry
from sitl.physics.jsbsim.arm import ArmDynamics
from sitl.physics.jsbsim.fdm import FdmReading, HexarotorFdm, JsbsimError
from sitl.physics.jsbsim.wind import Wind
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

__all__ = ["JsbsimError", "JsbsimPlant"]

FloatArray = NDArray[np.float64]


class JsbsimPlant(RotorPlant):
    """Underactuated truth plant on JSBSim: a :class:`~sitl.physics.Plant`, as
    ``TruthPlant``'s underactuated mode (see the module docstring for what differs); not
    an :class:`~sitl.physics.IdealPlant` (no generalized-force input).

    Pure in the sense of the project (no I/O after construction, no clock); turbulence is
    random with JSBSim's generator, seeded by ``wind.seed``. Not thread-safe.

    Parameters
    ----------
    scenario : Scenario
        Validated scenario.
    mode : {"underactuated"}
        The only mode: JSBSim has no generalized-force input on the Euler rows.
    payload_attached : bool
        Start with the payload grasped.
    wind : Wind, optional
        Steady wind and turbulence (by default the scenario's steady ``plant.wind_m_s``, no
        turbulence).
    gear : GearGeometry, optional
        Landing gear of the airframe.

    Raises
    ------
    PlantModeError
        For ``mode="ideal"``.
    JsbsimError
        If JSBSim cannot load the generated airframe.
    """

    has_ground = True
    """JSBSim's landing gear is the ground contact (a SITL must not add its own)."""

    def __init__(
        self,
        scenario: Scenario,
        mode: str = "underactuated",
        *,
        payload_attached: bool = False,
        wind: Wind | None = None,
        gear: GearGeometry | None = None,
    ) -> None:
        if mode != "underactuated":
            raise PlantModeError(
                f"the JSBSim backend has only mode 'underactuated', got {mode!r}: ideal mode "
                "(tau on all 8 rows) exists only on the Pinocchio plant"
            )
        self.scenario = scenario
        self.mode = "underactuated"
        self.rate_hz = float(scenario.plant.rate_hz)
        self.dt_s = 1.0 / self.rate_hz
        self.gravity_m_s2 = scenario.environment.gravity_m_s2
        self.wind = wind if wind is not None else Wind(scenario.plant.wind_m_s)
        self.gear = gear if gear is not None else GearGeometry()
        self._fdm = HexarotorFdm(scenario, self.gear, self.dt_s)

        rotors = scenario.vehicle.rotors
        geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
        self._yaw_per_thrust = geometry.wrench_matrix()[2].tolist()
        self._rotors = RotorBank(
            rotors.max_thrust_per_rotor_n * scenario.plant.thrust_mismatch,
            rotors.thr_mdl_fac,
            rotors.motor_time_constant_s,
            self.dt_s,
        )
        self._max_thrust_n = self._rotors.max_thrust_n
        self._thrust_mismatch = scenario.plant.thrust_mismatch
        self._battery = LipoPack.of(scenario.plant.battery)
        mixer = SequentialDesaturationMixer(geometry, rotors.max_thrust_per_rotor_n)
        self._autopilot = Px4AttitudeLoop.from_params(
            AttitudeLoopParams.from_config(scenario.plant.attitude_control, rotors.thr_mdl_fac),
            mixer,
            self.dt_s,
        )
        self._servo_limit = scenario.plant.servo_torque_limit_n_m
        self._arm = ArmDynamics(scenario, self.dt_s)
        self._actuators: ActuatorState | None = None
        self._actuator_signals: tuple = ()
        self._state_cache: PlantState | None = None
        self._euler = (0.0, 0.0, 0.0)
        self._grasped = payload_attached
        if payload_attached:
            self._arm.set_payload(True)
        self.reset(scenario.simulation.initial_q)

    @classmethod
    def from_scenario(
        cls,
        scenario: Scenario,
        mode: str = "underactuated",
        *,
        payload_attached: bool = False,
        wind: Wind | None = None,
        gear: GearGeometry | None = None,
    ) -> JsbsimPlant:
        """Plant of a validated scenario, at rest at ``simulation.initial_q``."""
        return cls(scenario, mode, payload_attached=payload_attached, wind=wind, gear=gear)

    # ------------------------------------------------------------------ state

    def reset(
        self,
        q: ArrayLike,
        q_dot: ArrayLike | None = None,
        *,
        time_s: float = 0.0,
        rotor_thrusts_n: ArrayLike | None = None,
    ) -> PlantState:
        """Put the plant in state (q, q_dot) at ``time_s`` (as ``TruthPlant.reset``).

        The height above ground is set explicitly: world z = 0 is the ground, and
        ``ic/h-agl-ft`` puts the CG where q[2] puts the vehicle CoM.

        Raises
        ------
        ValueError
            On wrong shapes or non-finite values.
        JsbsimError
            If JSBSim rejects the initial condition.
        """
        q_arr = _vector(q, "q")
        qd_arr = np.zeros(N_Q) if q_dot is None else _vector(q_dot, "q_dot")
        if rotor_thrusts_n is None:
            each = self.total_mass_kg * self.gravity_m_s2 / N_ROTORS
            thrusts = np.full(N_ROTORS, min(each, self._rotors.max_thrust_n))
        else:
            thrusts = np.asarray(rotor_thrusts_n, dtype=np.float64)
        self._rotors.reset(thrusts)
        self._arm.eta_ddot = [0.0, 0.0]
        # The forces of the IC pass seed JSBSim's multistep integrators: make them the
        # first step's (rotors as reset, no coupling moment yet).
        self._set_rotor_forces(self._rotors.thrust_list_n)
        self._fdm.set_coupling_moment((0.0, 0.0, 0.0))
        self._apply_ic(q_arr, qd_arr)
        self._steps = 0
        self._t0 = float(time_s)
        self._qdd = [0.0] * N_Q
        self._autopilot.reset(self._omega)
        commands = inverse_thrust_curve(
            np.clip(thrusts / self._rotors.max_thrust_n, 0.0, 1.0), self._rotors.thr_mdl_fac
        )
        self._actuator_signals = (commands, thrusts, (0.0, 0.0), (0.0,) * 3, (0.0,) * 3)
        self._actuators = None
        return self.state

    def _apply_ic(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        """Start JSBSim at (q, q_dot): arm pose, CG location and velocity, attitude, rates."""
        phi, theta, psi = (float(a) for a in q[ATTITUDE])
        self._arm.eta = [float(q[ETA1]), float(q[ETA2])]
        self._arm.eta_dot = [float(q_dot[ETA1]), float(q_dot[ETA2])]
        self._fdm.set_point_masses(self._arm.point_masses())
        omega = euler_rate_matrix(phi, theta) @ q_dot[ATTITUDE]
        c, c_dot = (np.array(v) for v in self._arm.centre_of_mass())
        rot = rotation_from_euler(phi, theta, psi)
        p_cg = q[POSITION] + rot @ c
        v_cg = q_dot[POSITION] + rot @ (np.cross(omega, c) + c_dot)
        reading = self._fdm.start(p_cg, v_cg, (phi, theta, psi), omega, self.wind)
        self._euler = (phi, theta, psi)
        self._take(reading)

    def _truth(self) -> tuple:
        return (
            self._q,
            self._qd,
            self._qdd,
            self._quat,
            self._r9,
            self._omega,
            self._grasped,
        )

    def _attitude(
        self,
    ) -> tuple[tuple[float, float, float, float], tuple[float, float, float]]:
        return self._quat, self._omega

    @property
    def height_above_ground_m(self) -> float:
        """JSBSim's height of the CG above the ground [m]."""
        return self._fdm["position/h-agl-ft"] * FT_M

    def property_value(self, path: str) -> float:
        """A JSBSim property in JSBSim's (English) units, for diagnostics."""
        return self._fdm[path]

    @property
    def coupling_ratio(self) -> float:
        """Loop gain of the lagged arm coupling at the current pose (below 1: converges)."""
        return self._arm.coupling_ratio()

    # ---------------------------------------------------------------- payload

    @property
    def payload_attached(self) -> bool:
        """Whether the payload is grasped (link 2 carrying it, or the ground still)."""
        return self._grasped

    def attach_payload(self, share: float = 1.0) -> None:
        """Grasp the payload (joint momentum kept; raises :class:`PlantError` if attached).
        JSBSim restarts whenever link 2 changes, so a ``share`` below 1 leaves the whole
        payload to the ground until :meth:`set_payload_share` reaches 1."""
        if self._grasped:
            raise PlantError("payload is already attached")
        self._grasped = True
        self.set_payload_share(share)

    def set_payload_share(self, share: float) -> None:
        """The share of the grasped payload link 2 carries: none below 1, all of it from 1
        on, each change a restart of JSBSim (see :meth:`attach_payload`)."""
        if not self._grasped:
            raise PlantError("no payload is attached")
        carried = share >= 1.0
        if carried != self._arm.payload_attached:
            self._regrasp(carried)

    def detach_payload(self) -> None:
        """Release the payload (raises :class:`PlantError` if none is attached)."""
        if not self._grasped:
            raise PlantError("no payload is attached")
        self._grasped = False
        if self._arm.payload_attached:
            self._regrasp(False)

    def _regrasp(self, attached: bool) -> None:
        """Change link 2 and restart JSBSim at the same q (JSBSim would keep the CG still
        and move the vehicle instead); the autopilot and rotors carry on."""
        q, q_dot = np.array(self._q), np.array(self._qd)
        self._arm.set_payload(attached)
        q_dot[JOINTS] = self._arm.eta_dot
        self._apply_ic(q, q_dot)

    @property
    def true_theta(self) -> Theta:
        """(m2, m3, m4) of link 2 as it is now (with the payload if attached)."""
        return self._arm.link2.theta

    @property
    def total_mass_kg(self) -> float:
        """Mass of vehicle + arm (+ payload if attached) [kg]."""
        return self._arm.total_mass_kg

    # ------------------------------------------------------------------- step

    def _step_rotors(
        self,
        motor_commands: list[float],
        joint: list[float],
        rate_setpoint_rad_s: tuple,
        torque_normalized: tuple,
    ) -> None:
        """One JSBSim step with the rotors' thrusts after their lag moved toward
        ``motor_commands``, the arm stepped alongside; records the actuator signals."""
        self._feed_rotors()
        thrusts = self._rotors.thrust_list_n  # acting over this step (written last step)
        self._rotors.advance(motor_commands)
        self._set_rotor_forces(self._rotors.thrust_list_n)
        qd_before = self._qd
        moment = self._arm.step(
            (joint[0], joint[1]), self._specific_force, self._omega, self._omega_dot
        )
        self._fdm.set_coupling_moment(moment)
        self._fdm.set_point_masses(self._arm.point_masses())
        reading = self._fdm.run()
        self._steps += 1
        self._take(reading)
        dt = self.dt_s
        qd = self._qd
        self._qdd = [(a - b) / dt for a, b in zip(qd[0:6], qd_before[0:6], strict=True)] + list(
            self._arm.eta_ddot
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

    def _set_rotor_forces(self, thrusts: list[float]) -> None:
        """Rotor thrusts [N] at the hubs and their summed reaction moment about body z."""
        yaw = sum(k * t for k, t in zip(self._yaw_per_thrust, thrusts, strict=True))
        self._fdm.set_rotors(thrusts, yaw)

    def _take(self, reading: FdmReading) -> None:
        """JSBSim's CG state -> our q, q_dot at the vehicle CoM O (ENU/FLU, SI)."""
        if not reading.finite:
            raise PlantDivergedError(self.time_s)
        # what JSBSim integrates over the next step: external force per kg, body rate
        fx, fy, fz = reading.force_n
        total = self._arm.total_mass_kg
        self._specific_force = (fx / total, fy / total, fz / total)
        self._omega_dot = reading.omega_dot_rad_s2
        rot = reading.rotation
        euler = euler_from_rotation9(rot, self._euler)
        self._euler = euler
        self._r9 = rot
        omega = reading.omega_rad_s
        self._omega = omega
        (cx, cy, cz), (ux, uy, uz) = self._arm.centre_of_mass()
        rc = (
            rot[0] * cx + rot[1] * cy + rot[2] * cz,
            rot[3] * cx + rot[4] * cy + rot[5] * cz,
            rot[6] * cx + rot[7] * cy + rot[8] * cz,
        )
        # velocity of the CG relative to O in the body: omega x c + c_dot
        wx = omega[1] * cz - omega[2] * cy + ux
        wy = omega[2] * cx - omega[0] * cz + uy
        wz = omega[0] * cy - omega[1] * cx + uz
        rwc = (
            rot[0] * wx + rot[1] * wy + rot[2] * wz,
            rot[3] * wx + rot[4] * wy + rot[5] * wz,
            rot[6] * wx + rot[7] * wy + rot[8] * wz,
        )
        pg, vg = reading.cg_position_m, reading.cg_velocity_m_s
        position = (pg[0] - rc[0], pg[1] - rc[1], pg[2] - rc[2])
        velocity = (vg[0] - rwc[0], vg[1] - rwc[1], vg[2] - rwc[2])
        phi, theta, psi = euler
        wi = euler_rate_matrix_inverse9(phi, theta)
        ox, oy, oz = omega
        eta, eta_dot = self._arm.eta, self._arm.eta_dot
        self._q = [*position, phi, theta, psi, eta[0], eta[1]]
        self._qd = [
            *velocity,
            ox + wi[1] * oy + wi[2] * oz,
            wi[4] * oy + wi[5] * oz,
            wi[7] * oy + wi[8] * oz,
            eta_dot[0],
            eta_dot[1],
        ]
        self._quat = tuple(quaternion_from_euler(phi, theta, psi).tolist())
        self._state_cache = None


def _vector(values: ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (N_Q,):
        raise ValueError(f"{name} must have shape ({N_Q},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {values!r}")
    return arr

"""The arm on a hovering base: its real joint dynamics under gravity, servos on a pty.

When PX4's own SIH flies the vehicle (``sitl sih``), nothing simulates the arm: SIH is a
rigid body. :class:`ArmStand` gives the companion an arm to talk to: the scenario's
two-link arm (with armature) on a base that hovers still, its XM430 servos on a
pseudo-terminal (:class:`~sitl.servo.PtyServoBus`), stepped in real time by a thread,
as :class:`~sitl.servo.JointRig` does for bare shafts.

Physics: the joint rows of :class:`sitl.physics.jsbsim.arm.ArmDynamics` (independent of
``companion.model``), with the base held level and not accelerating: specific force
``b = (0, 0, g)`` (body FLU, what an accelerometer on a hovering base reads), body rate
and its derivative zero. ArmDynamics solves the joints of a *free* vehicle: the CoM terms
``M J_G^T J_G``, ``c_ddot0`` and ``rho_k = s_k - c`` carry the arm's reaction on the base.
A base of :data:`HELD_BASE_MASS_KG` makes them vanish (they scale with m_arm / M, about
2e-10 here), which leaves the fixed-base equations

    (sum_k m_k J_k^T J_k + diag(armature)) eta_ddot = tau - sum_k m_k J_k^T (b + s_ddot0_k),

the joint rows of the paper's M q_ddot + C q_dot + G = tau (eq. mcg_model) with the base
at rest. The base inertia does not enter the joint rows. Semi-implicit Euler at the
scenario's ``plant.rate_hz``, as the SITL plants.

Coupling (as :mod:`sitl.vehicle.world`): each step, every joint servo gets its shaft angle
``zero_offset + direction * eta`` and rate ``direction * eta_dot``; ``direction`` x its
output torque is the joint torque. The gripper is a :class:`~sitl.vehicle.world.GripperJaw` (jaw
shaft between hard stops) turned by its servo; closed, it holds a weightless stand-in
object (the jaws stop on it, the servo reads short of closed and pushes, as on a real
object), so the companion's gripper check sees a grasp. The joint servos are XM430 models
(:mod:`sitl.servo.xm430`) with the gearbox's viscous friction (torque on or off: a limp
arm swings down and comes to rest hanging, slowly) and the motor's voltage limit; their
torque constant is the ``[arm_bus]`` joint's times ``plant.servo_torque_constant_mismatch``
(as ``sitl run``'s :func:`sitl.vehicle.runner.build_world`), so the stand can stand in for servos
the config's datasheet value does not describe (``companion arm calibrate``).
Simplifications: no payload mass (SIH cannot carry one; a scenario flown here turns the
estimate's carry check off, ``[flight] carry_check_estimate = false``), no Coulomb
friction and no joint stops (neither has ``sitl run``'s plant).

Time: the thread steps (:func:`~sitl.stepping.step_loop`) the fixed plant step
``1 / plant.rate_hz`` as often as the wall clock (times ``speed``) asks
(:class:`~sitl.stepping.WallPacer`), back to back when it woke late; a backlog longer
than ``max_lag_s`` is dropped and counted in :attr:`ArmStand.overruns`. The servos' own
time (current loop, Bus Watchdog) is the stand's: the pty server does not step them.
"""

from __future__ import annotations

import math
import threading

from arm_driver.joint import GripperConfig, JointConfig
from companion.config import arm_bus_configs
from sitl.physics.jsbsim.arm import ArmDynamics
from sitl.scenario import Scenario
from sitl.servo.pty_server import PtyServoBus
from sitl.servo.xm430 import XM430Parameters, XM430Servo
from sitl.stepping import WallPacer, step_loop
from sitl.vehicle.world import GripperJaw

__all__ = ["HELD_BASE_MASS_KG", "ArmStand", "held_base_arm"]

HELD_BASE_MASS_KG = 1e9
"""Base mass [kg] that makes ArmDynamics' free-base joint equations those of a fixed base."""

_DEFAULT_START_RAD = (0.0, -0.5 * math.pi)
"""(eta1, eta2) [rad] without ``[world] start_joints_rad``: link 1 forward, link 2 down."""


def held_base_arm(scenario: Scenario, dt_s: float) -> ArmDynamics:
    """The scenario's arm (no payload) on a base of :data:`HELD_BASE_MASS_KG` [kg], stepping
    ``dt_s`` [s]; see the module docstring."""
    vehicle = scenario.vehicle.model_copy(update={"mass_kg": HELD_BASE_MASS_KG})
    return ArmDynamics(scenario.model_copy(update={"vehicle": vehicle}), dt_s)


class ArmStand:
    """The scenario's arm and servos on a held base, stepped in real time by a thread.

    Parameters
    ----------
    scenario
        Validated scenario with an ``[arm_bus]`` section of two joints (the gripper is
        optional); the start pose is ``[world] start_joints_rad``, the servos' torque
        constants the joints' times ``plant.servo_torque_constant_mismatch``.
    speed
        Simulated seconds per wall-clock second (> 0), as PX4's ``PX4_SIM_SPEED_FACTOR``.
    max_lag_s
        Largest wall-clock backlog [s] caught up at once; a longer one is dropped.

    Nothing is opened in the constructor: :meth:`start` opens the pty and starts the
    thread, :meth:`stop` (idempotent) ends both. Also a context manager. Between the two,
    :attr:`device` is the pty's path for a Dynamixel client.
    """

    def __init__(self, scenario: Scenario, *, speed: float = 1.0, max_lag_s: float = 0.1):
        if scenario.arm_bus is None:
            raise ValueError(f"{scenario.name}: no [arm_bus] section: the stand needs its servos")
        joints, gripper = arm_bus_configs(scenario.arm_bus)
        if len(joints) != 2:
            raise ValueError(
                f"{scenario.name}: the arm has 2 joints, [arm_bus] lists {len(joints)}"
            )
        if not (math.isfinite(speed) and speed > 0.0):
            raise ValueError(f"speed must be a positive factor, got {speed!r}")
        if not max_lag_s > 0.0:
            raise ValueError(f"max_lag_s must be positive, got {max_lag_s!r}")
        self.scenario = scenario
        self.speed = float(speed)
        self.dt_s = 1.0 / scenario.plant.rate_hz
        self._max_lag_s = float(max_lag_s)
        self._gravity = scenario.environment.gravity_m_s2
        world = scenario.world
        start = tuple(world.start_joints_rad) if world is not None else _DEFAULT_START_RAD
        self.arm = held_base_arm(scenario, self.dt_s)
        self.arm.eta = [float(start[0]), float(start[1])]
        mismatch = scenario.plant.servo_torque_constant_mismatch
        self.joints: list[tuple[JointConfig, XM430Servo]] = [
            (j, _servo(j, j.servo_angle_rad(eta), mismatch))
            for j, eta in zip(joints, start, strict=True)
        ]
        self.gripper: tuple[GripperConfig, XM430Servo] | None = None
        self.jaw: GripperJaw | None = None
        if gripper is not None:
            self.gripper = (
                gripper,
                XM430Servo(gripper.servo_id, angle_rad=gripper.open_position_rad),
            )
            self.jaw = GripperJaw(gripper)
        servos = {servo.servo_id: servo for _, servo in self._all_servos()}
        self.bus = PtyServoBus(servos, step_servos=False)
        self.lock = self.bus.lock
        """The servo bus lock: held while stepping; hold it to read the state consistently."""
        self.torques_n_m = [0.0, 0.0]
        """Joint torques the servos applied over the last step [N m]."""
        self.steps = 0
        """Plant steps taken."""
        self.overruns = 0
        """Times the thread fell more than ``max_lag_s`` behind and dropped the backlog
        (counted when it stops)."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _all_servos(self) -> list[tuple[JointConfig | GripperConfig, XM430Servo]]:
        return [*self.joints, *([self.gripper] if self.gripper is not None else [])]

    # ------------------------------------------------------------------ physics

    @property
    def time_s(self) -> float:
        """Simulated time since the start [s]."""
        return self.steps * self.dt_s

    def step(self) -> None:
        """Advance the arm, the jaw and every servo by one plant step (the caller holds
        :attr:`lock` when the bus is running)."""
        arm, dt = self.arm, self.dt_s
        for i, (config, servo) in enumerate(self.joints):
            servo.set_state(config.servo_angle_rad(arm.eta[i]), config.direction * arm.eta_dot[i])
            self.torques_n_m[i] = config.direction * servo.torque_n_m()
        if self.gripper is not None and self.jaw is not None:
            servo = self.gripper[1]
            servo.set_state(self.jaw.angle_rad, self.jaw.rate_rad_s)
            self.jaw.advance(servo.torque_n_m(), dt)
            if self.jaw.closed != self.jaw.holding:
                self.jaw.hold(self.jaw.closed)
        arm.step(
            (self.torques_n_m[0], self.torques_n_m[1]),
            (0.0, 0.0, self._gravity),
            (0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0),
        )
        for _, servo in self._all_servos():
            servo.step(dt)
        self.steps += 1

    def joint_state(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """((eta1, eta2) [rad], (eta1_dot, eta2_dot) [rad/s]) now, read under the lock."""
        with self.lock:
            return (tuple(self.arm.eta), tuple(self.arm.eta_dot))  # type: ignore[return-value]

    # ---------------------------------------------------------------- lifecycle

    @property
    def device(self) -> str:
        """Path of the servo bus pty (after :meth:`start`)."""
        return self.bus.device

    def start(self) -> None:
        """Open the servo bus pty and start stepping in real time."""
        if self._thread is not None:
            raise RuntimeError("the arm stand is already running")
        self.bus.start()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="arm-stand", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread and close the pty; safe to call twice."""
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=5.0)
            self._thread = None
        self.bus.stop()

    def __enter__(self) -> ArmStand:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    paced = True
    """Every step keeps its wall-clock slot (:class:`~sitl.stepping.Stepped`)."""

    def advance(self) -> bool:
        """One step under :attr:`lock` (:class:`~sitl.stepping.Stepped`)."""
        with self.lock:
            self.step()
        return False

    def _run(self) -> None:
        pacer = WallPacer(self.dt_s / self.speed, self._max_lag_s, self._stop)
        self.overruns = step_loop(self, self._stop, pacer=pacer).overruns


def _servo(joint: JointConfig, angle_rad: float, mismatch: float) -> XM430Servo:
    """A joint's XM430 at its start shaft angle (Goal Position there), its torque constant
    times ``mismatch`` (the truth over the config's)."""
    parameters = XM430Parameters(
        torque_constant_n_m_per_a=joint.torque_constant_n_m_per_a * mismatch
    )
    return XM430Servo(joint.servo_id, parameters, angle_rad=angle_rad)

"""Fixed-step integration of the articulated truth model on its configuration manifold.

State. Configuration ``x = [p (3, world), quaternion x, y, z, w (body to world), eta1,
eta2]`` - Pinocchio's free-flyer layout - and velocity ``u = [p_dot (3, world ENU),
omega (3, body FLU), eta1_dot, eta2_dot]``. The base's linear velocity is kept in the
world frame (Pinocchio's LOCAL_WORLD_ALIGNED view) and only rotated into body axes,
v_B = R^T p_dot, for the ABA call: integrating the body-frame components instead would
rotate them by an explicit step, which pumps kinetic energy in at a relative rate of
(|omega| dt)^2 per step.

Acceleration. ``a = ABA(q, v, tau)`` (Pinocchio, armature included) gives
(d/dt v_B, d/dt omega_B, eta_ddot); then p_ddot = R (d/dt v_B + omega x v_B).

Methods (``plant.integrator``), both with the generalized force re-evaluated at each
stage from a held input (see :class:`GeneralizedForce`, :class:`BodyWrench`):

``semi_implicit_euler``
    u+ = u + dt f(x, u); x+ = x (+) dt u+. One ABA per step, first order. Stable at
    1 kHz, but not symplectic here (the mass matrix depends on q), so the energy error
    creeps at a rate proportional to dt: in violent weight-compensated free motion
    (body rates 1.5 rad/s, joints 3 rad/s) 0.35 % of the kinetic energy after 5 s and
    1.2 % after 10 s at 1 kHz.
``rk4``
    Classical Runge-Kutta on (x, u), four ABA per step; stage configurations and the final
    update use the same retraction (so the attitude update is second order in the
    commutator of the stage rates). Energy error 1.6e-6 after 5 s, 3e-6 after 10 s in the
    same test.

The retraction x (+) h u moves p and eta linearly and the attitude by the exact exponential
of the body rate, quaternion <- quaternion * exp(h omega / 2).

The arithmetic is one module, :mod:`sitl.vehicle_step`, which runs as Python
and is compiled as it is into ``sitl._vehicle_step`` (a compiled twin,
:mod:`companion.compiled`): its floats, Pinocchio's ABA called back for every stage.
The state lives in the integrator's work buffer (:attr:`ArticulatedIntegrator.work`, the
fields of :data:`~sitl.vehicle_step.LAYOUT`):
:meth:`ArticulatedIntegrator.step` steps it there and leaves the new state's kinematics
beside it; :meth:`ArticulatedIntegrator.rotor_step` is the rotor plant's whole step in the
same call (the battery's draw, the rotor wrench, the step, the rotors' lag);
:meth:`ArticulatedIntegrator.load` puts a state in; :meth:`ArticulatedIntegrator.acceleration`
evaluates q_ddot without a step.
"""

from __future__ import annotations

import functools
from array import array
from collections.abc import Sequence
from typing import Literal

import numpy as np
import pinocchio as pin

from companion.compiled import twin
from sitl import vehicle_step
from sitl.physics.attitude_control import AttitudeSetpoint, Px4AttitudeLoop
from sitl.physics.frames import rotation9_from_quaternion

__all__ = ["ArticulatedIntegrator", "BodyWrench", "GeneralizedForce", "IntegratorMethod"]

IntegratorMethod = Literal["semi_implicit_euler", "rk4"]

_STEP = twin(vehicle_step)
"""The step's arithmetic: :mod:`sitl.vehicle_step`, compiled where built."""


class GeneralizedForce:
    """Our tau (conjugate to q = [p, phi, theta, psi, eta]) as Pinocchio's generalized force.

    tau_pin = [R^T f_W, W(Phi)^-T tau_Phi, tau_eta], evaluated at each stage's attitude;
    W(Phi) is singular at theta = +-90 deg (the step then fails with status 2).
    """

    __slots__ = ("tau",)
    KIND = vehicle_step.GENERALIZED
    """The step's tag of this force."""

    def __init__(self, tau: list[float]) -> None:
        self.tau = tau

    @property
    def values(self) -> list[float]:
        """tau (8 floats), as the step takes it."""
        return self.tau


class BodyWrench:
    """Rotor thrust and torque (body axes), linear drag on the velocity relative to the air
    (world) and joint torques.

    At each stage the drag force -D (p_dot - w) is rotated into body axes and the thrust
    added along body +z.

    Attributes
    ----------
    thrust_n : float
        Total thrust along body +z [N].
    torque_n_m : tuple of 3 float
        Body torque of the rotors (FLU) [N m].
    drag_n_s_m : tuple of 3 float
        Diagonal D of the world-frame drag force -D (p_dot - w) [N s/m].
    joint_torques_n_m : tuple of 2 float
        Servo torques [N m].
    wind_m_s : tuple of 3 float
        Steady wind w, the air's velocity over the ground, world ENU [m/s].
    """

    __slots__ = ("drag_n_s_m", "joint_torques_n_m", "thrust_n", "torque_n_m", "wind_m_s")
    KIND = vehicle_step.WRENCH
    """The step's tag of this force."""

    def __init__(
        self,
        thrust_n: float,
        torque_n_m: tuple[float, float, float],
        drag_n_s_m: tuple[float, float, float],
        joint_torques_n_m: tuple[float, float],
        wind_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self.thrust_n = thrust_n
        self.torque_n_m = torque_n_m
        self.drag_n_s_m = drag_n_s_m
        self.joint_torques_n_m = joint_torques_n_m
        self.wind_m_s = wind_m_s

    @property
    def values(self) -> tuple[float, ...]:
        """(thrust, torque (3), drag (3), joint torques (2), wind (3)), as the step takes it."""
        return (
            self.thrust_n,
            *self.torque_n_m,
            *self.drag_n_s_m,
            *self.joint_torques_n_m,
            *self.wind_m_s,
        )


class ArticulatedIntegrator:
    """ABA evaluations and fixed steps of a Pinocchio model with a free-flyer base.

    Parameters
    ----------
    model : pinocchio.Model
        nq = 9, nv = 8 (free-flyer + two 1-dof joints).
    dt_s : float
        Step [s].
    method : {"semi_implicit_euler", "rk4"}
        See the module docstring.
    compiled : bool
        Step with the compiled twin of :mod:`sitl.vehicle_step` where it is
        built (False: its Python source).
    """

    def __init__(
        self, model: pin.Model, dt_s: float, method: IntegratorMethod, compiled: bool = True
    ) -> None:
        if method not in ("semi_implicit_euler", "rk4"):
            raise ValueError(f"unknown integrator {method!r}")
        self.dt_s = float(dt_s)
        self.method: IntegratorMethod = method
        self._step = _STEP if compiled else vehicle_step
        self._work = vehicle_step.work_buffer()
        self._q, self._v, self._tau = vehicle_step.aba_arguments(self._work)
        self._zero_a = np.zeros(8)
        """Zero accelerations for :meth:`fixed_base_joint_accelerations`' RNEA (never written)."""
        self.set_model(model)

    def set_model(self, model: pin.Model) -> None:
        """Use ``model`` (e.g. after its inertias changed) with fresh Pinocchio data."""
        self.model = model
        self._data = model.createData()
        self._aba = functools.partial(pin.aba, model, self._data, self._q, self._v, self._tau)

    def pinocchio_state(self, x: list[float], u: list[float]) -> tuple[np.ndarray, np.ndarray]:
        """Pinocchio's (q, v) of (x, u): v = [R^T p_dot, omega, eta_dot] (new arrays)."""
        r = rotation9_from_quaternion(x[6], x[3], x[4], x[5])
        fx, fy, fz = u[0], u[1], u[2]
        v_body = (
            r[0] * fx + r[3] * fy + r[6] * fz,
            r[1] * fx + r[4] * fy + r[7] * fz,
            r[2] * fx + r[5] * fy + r[8] * fz,
        )
        return np.array(x), np.array([*v_body, *u[3:8]])

    def fixed_base_joint_accelerations(
        self, x: list[float], eta_dot: tuple[float, float], joint_torques_n_m: tuple[float, float]
    ) -> tuple[float, float]:
        """eta_ddot [rad/s^2] of the arm on a base held at rest at the pose of ``x``.

        The joint rows of M(q) v_dot + h(q, v) = tau with the base's velocity and
        acceleration zero: M_ee eta_ddot = tau_e - h_e(q, [0, eta_dot]) (Pinocchio's CRBA
        and RNEA, gravity and armature included). The ground's reaction, whatever it is,
        acts on the base rows only.
        """
        self._q[:] = x
        v = self._v
        v[:6] = 0.0
        v[6], v[7] = eta_dot
        m = pin.crba(self.model, self._data, self._q)  # upper triangle filled
        h = pin.rnea(self.model, self._data, self._q, v, self._zero_a)
        a11, a12, a22 = m.item(6, 6), m.item(6, 7), m.item(7, 7)
        b1 = joint_torques_n_m[0] - h.item(6)
        b2 = joint_torques_n_m[1] - h.item(7)
        det = a11 * a22 - a12 * a12
        return ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det)

    @property
    def work(self) -> array:
        """The float64 buffer the steps work in, the state among it
        (:data:`sitl.vehicle_step.LAYOUT`)."""
        return self._work

    def load(
        self, x: list[float], u: list[float], euler_previous: tuple[float, float, float]
    ) -> int:
        """Make (x, u) the state with its kinematics: the quaternion renormalized (w >= 0),
        phi and psi unwrapped next to ``euler_previous``; the last step's q_ddot is kept.
        Returns 0, or 1 (non-finite) / 2 (W(Phi) singular, the pitch in the ``theta``
        field) with the state unchanged."""
        return self._step.load(x, u, euler_previous, self._work)

    def step(self, force: GeneralizedForce | BodyWrench) -> int:
        """One step from the state under ``force``; the new state with its kinematics and
        the step's q_ddot become the state. Returns 0; on failure 1 non-finite
        accelerations or body rate, 2 the force's W(Phi) singular at the pitch in the
        ``theta`` field (the state unchanged); 3 or 4 when the new state itself is
        non-finite (3) or at the singularity (4) (then only x, u and q_ddot are new)."""
        return self._step.step(
            self.method == "rk4", self.dt_s, force.KIND, force.values, self._aba, self._work
        )

    def set_rotor_wrench(
        self,
        rows: list[list[float]],
        drag_n_s_m: tuple[float, float, float],
        wind_m_s: tuple[float, float, float],
        max_thrust_n: float,
    ) -> None:
        """The constants of :meth:`rotor_step`: the rotors' body torque per newton of
        thrust (three rows of six) [N m / N], the world drag diagonal [N s/m], the steady
        wind (world ENU) [m/s] and a rotor's full thrust at the battery's reference
        voltage [N]."""
        vehicle_step.set_rotor_wrench(self._work, rows, drag_n_s_m, wind_m_s, max_thrust_n)

    def set_joint_servos(self, couplings: list[tuple[float, float]]) -> None:
        """(zero offset [rad], direction +1 or -1) of eta1's and eta2's servos: shaft angle
        = zero offset + direction * eta (for :meth:`vehicle_step` coupled to them)."""
        (zero1, direction1), (zero2, direction2) = couplings
        vehicle_step.set_joint_servos(self._work, zero1, direction1, zero2, direction2)

    def set_servo_limit(self, limit_n_m: float) -> None:
        """The servos' torque limit [N m]: :meth:`vehicle_step` clips the joint torques to
        +-limit (none until set)."""
        vehicle_step.set_servo_limit(self._work, limit_n_m)

    def rotor_step(
        self,
        commands: list[float],
        joint_torques_n_m: list[float],
        rotors: array,
        battery: array | None,
    ) -> int:
        """One step of the rotor plant from the state
        (:func:`sitl.vehicle_step.rotor_step`): the ``battery`` buffer (None: an
        ideal supply) feeds the thrusts of the ``rotors`` buffer, which push with drag,
        wind and the joint torques (:meth:`set_rotor_wrench`) over the step and then lag
        toward the six ``commands``. Returns as :meth:`step`."""
        return self._step.rotor_step(
            self.method == "rk4",
            self.dt_s,
            commands,
            joint_torques_n_m,
            rotors,
            battery,
            self._aba,
            self._work,
        )

    def vehicle_step(
        self,
        setpoint: AttitudeSetpoint,
        joint_torques_n_m: Sequence[float] | None,
        autopilot: Px4AttitudeLoop,
        rotors: array,
        battery: array | None,
        servos: tuple | None = None,
    ) -> int:
        """One step of the vehicle from the state in one call
        (:func:`sitl.vehicle_step.vehicle_step`): the joint torques clipped to
        the servos' limit (:meth:`set_servo_limit`), the ``autopilot``'s loop at the
        state's attitude and body rate turns ``setpoint`` into motor commands, then
        :meth:`rotor_step`; the commands, the thrusts, the joint torques and the loop's
        signals stay in the buffer (:meth:`actuator_signals`). Returns as :meth:`step`, or
        5 for joint torques that are not finite (nothing changed).

        ``joint_torques_n_m`` None: the joint servos' torques, the servos (``servos``: the
        control table, loop and parameters of eta1's servo, then of eta2's) coupled first
        to the state's joint angles and rates (:meth:`set_joint_servos`); the buffer keeps
        those (``arm_start``) and the servos' torques (``servo_torques``)."""
        att, rate, rate_state, mixer, saturation, relative = autopilot.buffers
        return self._step.vehicle_step(
            self.method == "rk4",
            self.dt_s,
            setpoint.quaternion_wxyz,
            setpoint.thrust,
            joint_torques_n_m,
            servos,
            att,
            rate,
            rate_state,
            mixer,
            saturation,
            autopilot.thr_mdl_fac,
            relative,
            rotors,
            battery,
            self._aba,
            self._work,
        )

    def actuator_signals(self) -> tuple:
        """(motor commands, rotor thrusts [N], joint torques [N m], rate setpoint [rad/s],
        normalized torques) of the last :meth:`vehicle_step`."""
        return self._step.actuator_signals(self._work)

    def acceleration(self, force: GeneralizedForce | BodyWrench) -> int:
        """Our q_ddot at the state under ``force``, no step, into the ``acceleration``
        field: 0, or 1 / 2 as for :meth:`step`."""
        return self._step.acceleration(force.KIND, force.values, self._aba, self._work)

    def coordinates(self) -> tuple[list[float], list[float]]:
        """q and q_dot of the state (new lists of 8)."""
        return self._step.coordinates(self._work)

    def attitude(self) -> tuple[tuple[float, float, float, float], tuple[float, float, float]]:
        """(quaternion wxyz (body FLU to world ENU), omega (body FLU) [rad/s]) of the state."""
        return self._step.attitude(self._work)

    def truth(self) -> tuple:
        """(q, q_dot, q_ddot (lists of 8), quaternion wxyz, R row-major 9, omega) of the
        state."""
        return self._step.truth(self._work)

"""The arithmetic of the truth plant's step, one plant step at a time: the PX4-like
attitude loop, the rotors and battery, the integration step.

What :class:`~sitl.physics.integration.ArticulatedIntegrator` and
:class:`~sitl.physics.plant.TruthPlant` run at every plant step: :func:`step` (one step of
semi-implicit Euler or RK4 on the configuration manifold under a generalized force or a
body wrench, the accelerations by Pinocchio's own compiled ABA, called back through
Python and never re-implemented here, then the kinematics of the new state and the step's
q_ddot), :func:`load` (a state put in with its kinematics: after a reset, a hold on the
ground, a payload change) and :func:`acceleration` (q_ddot at the state, no step). The
scheme is described in :mod:`sitl.physics.integration`; nothing here knows the arm's
dynamics, which stay Pinocchio's (DESIGN.md section 6).

The rotor plant's whole step is one call, :func:`rotor_step`: the battery feeding the
rotors (the law of :mod:`sitl.physics.battery`), the rotors' wrench (total thrust along
body z, the torque of the rotor geometry, drag on the velocity relative to the wind, the
joint torques), the integration step and the rotors' lag toward the new commands (the law
of :class:`~sitl.physics.rotors.RotorBank`). The rotors and the battery keep their state
in float64 buffers of their own (:func:`rotor_buffer`, :func:`battery_buffer`), which
their classes own and whose arithmetic is here alone (:func:`rotor_lag`,
:func:`battery_draw`, :func:`open_circuit_v`); the wrench's constants are in the work
buffer (:func:`set_rotor_wrench`).

The vehicle's step under the PX4-like attitude loop is one call, :func:`vehicle_step`: the
loop at the buffer's attitude and body rate, then :func:`rotor_step`. The loop's parts:
:func:`rate_setpoint` (PX4 ``AttitudeControl::update``), :func:`rate_update`
(``RateControl::update``), :func:`mix` (the sequential-desaturation allocation of
:class:`~sitl.physics.rotors.SequentialDesaturationMixer`), :func:`motor_command`
(``FunctionMotors``' THR_MDL_FAC linearization) and :func:`attitude_loop` (the four in a
row, for a loop on its own); the classes in :mod:`sitl.physics.attitude_control` and
:mod:`sitl.physics.rotors` describe the behaviour and hold the loop's constants and state
in float64 buffers built here (:func:`attitude_constants`, :func:`rate_constants`,
:func:`rate_state`, read back by :func:`rate_integral` and :func:`rate_acceleration`,
:func:`mixer_constants`; the saturation flags, positive roll, pitch, yaw then negative, are
six floats 0.0 or 1.0). Its quaternions are ``[w, x, y, z]`` body (FLU) to world (ENU),
its vectors (roll, pitch, yaw) about the body axes, torques normalized, thrusts relative
to the rotors' full thrust.

The XM430 servos' per-step physics on their own buffers (the control table, bytes,
Protocol 2.0 little-endian fields; ``loop``, float64, indices ``L_*``, which the servo's
instruction handling partly resets; ``params``, float64, :func:`servo_parameters` of
:class:`~sitl.servo.xm430.XM430Parameters`), the model described in
:mod:`sitl.servo.xm430`: :func:`servo_set_state` (the shaft's angle and rate into Present
Velocity(128) and Present Position(132)), :func:`servo_step` (the bus watchdog, the
velocity profile, the position/current command, the supply's voltage limit, the current
loop's lag, the overload timer and Present Current(126)), :func:`servo_command_a`,
:func:`servo_torque_n_m`; :func:`vehicle_step` couples the two joint servos itself
(:func:`set_joint_servos`) and the gripper's servo to its jaw (:func:`jaw_buffer`,
:func:`jaw_advance`), so the emulator's bytes are those of the same step. A value's
rounding to its entry's units is Python's ``round`` (half to even) in float arithmetic, C
in the compiled build; ``math.expm1`` stays Python's call (once per step size).

One source, two builds: this module runs as Python, and ``setup.py`` compiles the same
file with Cython into ``sitl._vehicle_step`` (:mod:`companion.compiled`); the
arithmetic is written as plain float operations (``x * x``, no ``**``, every sum in index
order) so that both builds compute the same bits (tests/test_sitl_kernel.py compares
them); the square root, the trigonometric functions, ``fmod`` and ``copysign`` are the C
library's in both (Python's ``math`` calls them).

Why one module of more than 600 lines (sitl/'s rule: none without a reason): a twin is
one source whose parts the compiled build calls as C functions (``cython.cfunc``, inlined
where marked). :func:`vehicle_step` calls the attitude loop, the servos' steps, the jaw,
the rotors and battery and the integrator, each of which calls the shared helpers
(``_rotation9``, ``_clip``, the control table's fields); split into several twins, each
of those calls would cross between two extension modules through Python, on every plant
step, which is what this module exists to remove.

Frames and units: world ENU, body FLU, SI. A configuration ``x`` is Pinocchio's free-flyer
layout ``[p (3, world), quaternion x, y, z, w (body to world), eta1, eta2]`` and a velocity
``u = [p_dot (3, world), omega (3, body), eta1_dot, eta2_dot]``; quaternions handed out
are ``[w, x, y, z]``. R (body to world) and W(Phi)^-1 are row-major 9 floats, Euler angles
ZYX (phi, theta, psi) [rad] with phi and psi unwrapped next to the previous ones.

The plant's state lives in one float64 buffer (``array("d")``) the integrator owns, built
by :func:`work_buffer`: the fields of :data:`LAYOUT` (x, u and their kinematics, the last
step's q_ddot), beside the steps' scratch. The steps read the state there and leave the
new one there; nothing is copied between Python lists and the buffer per step, and
Python reads the fields only when asked (:func:`coordinates`, :func:`attitude`,
:func:`truth`). ABA reads its q, v and tau in the same buffer (:func:`aba_arguments`:
numpy arrays over it).

A force is a kind and its floats: :data:`GENERALIZED` (our tau, 8 floats, conjugate to
q = [p, phi, theta, psi, eta]) or :data:`WRENCH` (thrust along body z, body torque (3),
world drag diagonal (3), joint torques (2), wind (3): 12 floats).

Statuses: 0 for a step or state that is whole; DIVERGED (1) for non-finite accelerations
or state, SINGULAR (2) for W(Phi) singular (|cos(theta)| < 1e-6, the pitch theta in the
buffer's ``theta`` field); a step whose new state cannot be reported returns these + 2;
BAD_JOINT_TORQUES (5) for joint torques that are not finite (nothing stepped).
"""

import math
from array import array

import cython
import numpy as np
from cython.cimports.libc.math import (
    acos,
    asin,
    atan2,
    copysign,
    cos,
    fabs,
    floor,
    fmod,
    isfinite,
    sin,
    sqrt,
)

from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units

GENERALIZED = cython.declare(cython.int, 0)
"""The force kind of a generalized force tau (conjugate to our q)."""
WRENCH = cython.declare(cython.int, 1)
"""The force kind of a body wrench (rotor thrust and torque, drag, joint torques, wind)."""

_OK = cython.declare(cython.int, 0)
DIVERGED = cython.declare(cython.int, 1)
"""A failure's status: non-finite accelerations, body rate or state."""
SINGULAR = cython.declare(cython.int, 2)
"""A failure's status: W(Phi) singular at the failure's pitch theta."""
BAD_JOINT_TORQUES = cython.declare(cython.int, 5)
"""A failure's status: joint torques that are not finite (nothing stepped)."""
_COS_THETA_MIN = cython.declare(cython.double, 1e-6)
_TWO_PI = cython.declare(cython.double, 2.0 * 3.141592653589793)

# Offsets in the work buffer (private: :func:`work_buffer` builds it).
_X = cython.declare(cython.Py_ssize_t, 0)  # the state's x (9)
_U = cython.declare(cython.Py_ssize_t, 9)  # its u (8)
_R = cython.declare(cython.Py_ssize_t, 17)  # its R (9)
_E = cython.declare(cython.Py_ssize_t, 26)  # its Euler angles (3)
_QD = cython.declare(cython.Py_ssize_t, 29)  # its q_dot (8)
_WI = cython.declare(cython.Py_ssize_t, 37)  # its W^-1 (9)
_F = cython.declare(cython.Py_ssize_t, 46)  # the force's floats (up to 12)
_K1 = cython.declare(cython.Py_ssize_t, 58)  # du/dt of the stages (8 each)
_K2 = cython.declare(cython.Py_ssize_t, 66)
_K3 = cython.declare(cython.Py_ssize_t, 74)
_K4 = cython.declare(cython.Py_ssize_t, 82)
_U2 = cython.declare(cython.Py_ssize_t, 90)  # the stages' u (8 each)
_U3 = cython.declare(cython.Py_ssize_t, 98)
_U4 = cython.declare(cython.Py_ssize_t, 106)
_MEAN = cython.declare(cython.Py_ssize_t, 114)  # the RK4 mean velocity (8)
_XS = cython.declare(cython.Py_ssize_t, 122)  # a stage's x (9)
_RS = cython.declare(cython.Py_ssize_t, 131)  # a stage's R (9)
_FWI = cython.declare(cython.Py_ssize_t, 140)  # the generalized force's W^-1 (9)
_XN = cython.declare(cython.Py_ssize_t, 149)  # the step's x+ (9)
_UN = cython.declare(cython.Py_ssize_t, 158)  # its u+ (8)
_QDD = cython.declare(cython.Py_ssize_t, 166)  # its q_ddot, the last step's (8)
_KX = cython.declare(cython.Py_ssize_t, 174)  # kinematics: x, quaternion renormalized (9)
_KR = cython.declare(cython.Py_ssize_t, 183)  # R (9)
_KE = cython.declare(cython.Py_ssize_t, 192)  # Euler angles (3)
_KWI = cython.declare(cython.Py_ssize_t, 195)  # W^-1 (9)
_KQ = cython.declare(cython.Py_ssize_t, 204)  # our q (8)
_KQD = cython.declare(cython.Py_ssize_t, 212)  # our q_dot (8)
_THETA = cython.declare(cython.Py_ssize_t, 220)  # the pitch of a singular result
_A = cython.declare(cython.Py_ssize_t, 221)  # ABA's result (8)
_Q = cython.declare(cython.Py_ssize_t, 229)  # ABA's q (9), v (8), tau (8)
_V = cython.declare(cython.Py_ssize_t, 238)
_TAU = cython.declare(cython.Py_ssize_t, 246)
_WRENCH = cython.declare(cython.Py_ssize_t, 254)  # rotor torque rows x, y, z (6 each)
_DRAG = cython.declare(cython.Py_ssize_t, 272)  # world drag diagonal (3)
_WIND = cython.declare(cython.Py_ssize_t, 275)  # wind, world (3)
_TMAX0 = cython.declare(cython.Py_ssize_t, 278)  # a rotor's full thrust at V_ref
_CMD = cython.declare(cython.Py_ssize_t, 279)  # the motor commands (6)
_QO = cython.declare(cython.Py_ssize_t, 285)  # the state's q (8)
_ACC = cython.declare(cython.Py_ssize_t, 293)  # q_ddot at the state, no step (8)
_THR = cython.declare(cython.Py_ssize_t, 301)  # the rotors' thrusts over the last step (6)
_JT = cython.declare(cython.Py_ssize_t, 307)  # the joint torques of the last step (2)
_RSP = cython.declare(cython.Py_ssize_t, 309)  # the attitude loop's rate setpoint (3)
_TQ = cython.declare(cython.Py_ssize_t, 312)  # its normalized torques (3)
_JLIM = cython.declare(cython.Py_ssize_t, 315)  # the servos' torque limit [N m]
_ARM = cython.declare(cython.Py_ssize_t, 316)  # eta (2), eta_dot (2) at a coupled step's start
_ST = cython.declare(cython.Py_ssize_t, 320)  # the joint servos' torques on the joints (2)
_JMAP = cython.declare(cython.Py_ssize_t, 322)  # zero offset [rad], direction of each (2 x 2)
_OVL = cython.declare(cython.Py_ssize_t, 326)  # a coupled servo's overload timer ran out (3)
_STEPPED = cython.declare(cython.Py_ssize_t, 329)  # the coupled step was taken (1)
_SIZE = cython.declare(cython.Py_ssize_t, 330)

# Offsets in a gripper jaw's buffer (:func:`jaw_buffer`).
_J_ANGLE = cython.declare(cython.Py_ssize_t, 0)  # the jaw shaft's angle [rad]
_J_RATE = cython.declare(cython.Py_ssize_t, 1)  # its rate [rad/s]
_J_LOW = cython.declare(cython.Py_ssize_t, 2)  # the lower stop [rad]
_J_HIGH = cython.declare(cython.Py_ssize_t, 3)  # the upper stop [rad]
_J_INERTIA = cython.declare(cython.Py_ssize_t, 4)  # [kg m^2]
_J_FRICTION = cython.declare(cython.Py_ssize_t, 5)  # viscous [N m s/rad]
JAW_ANGLE = _J_ANGLE
JAW_RATE = _J_RATE
JAW_LOW = _J_LOW
JAW_HIGH = _J_HIGH
"""Where a jaw's buffer holds its angle, rate and stops."""

LAYOUT = {
    "x": (_X, 9),
    "u": (_U, 8),
    "rotation": (_R, 9),
    "euler": (_E, 3),
    "q": (_QO, 8),
    "q_dot": (_QD, 8),
    "w_inv": (_WI, 9),
    "q_ddot": (_QDD, 8),
    "acceleration": (_ACC, 8),
    "theta": (_THETA, 1),
    "commands": (_CMD, 6),
    "thrusts": (_THR, 6),
    "joint_torques": (_JT, 2),
    "rate_setpoint": (_RSP, 3),
    "torque": (_TQ, 3),
    "arm_start": (_ARM, 4),
    "servo_torques": (_ST, 2),
    "servo_overloads": (_OVL, 3),
    "stepped": (_STEPPED, 1),
}
"""The plant's state in the work buffer, field -> (offset, length): Pinocchio's x and u,
R (row-major), the Euler angles, our q and q_dot, W(Phi)^-1 (row-major), the last step's
q_ddot; the q_ddot of :func:`acceleration`; the pitch of a failure at the singularity; the
last rotor step's actuator signals: motor commands in [0, 1], the rotors' thrusts acting
over it [N], the joint torques [N m], and of :func:`vehicle_step` the attitude loop's
body-rate setpoint (FLU) [rad/s] and normalized torques; of a step coupled to the joint
servos, the joints' angles [rad] and rates [rad/s] at its start and the servos' torques on
the joints before the limit [N m], whether each servo's overload timer ran out in its step
after the plant's (1.0, see :func:`servo_step`), and whether the plant's step was taken
(1.0: a servo's error after it leaves the new state)."""

# Offsets in a rotor bank's buffer (:func:`rotor_buffer`).
_T = cython.declare(cython.Py_ssize_t, 0)  # each rotor's thrust now [N] (6)
_TMAX = cython.declare(cython.Py_ssize_t, 6)  # a rotor's full thrust now [N]
_FAC = cython.declare(cython.Py_ssize_t, 7)  # THR_MDL_FAC
_DECAY = cython.declare(cython.Py_ssize_t, 8)  # exp(-dt / time constant)
_N_ROTORS = cython.declare(cython.Py_ssize_t, 6)

# Offsets in a battery's buffer (:func:`battery_buffer`).
_B_CELLS = cython.declare(cython.Py_ssize_t, 0)  # cells in series
_B_CAPACITY = cython.declare(cython.Py_ssize_t, 1)  # [A h]
_B_RESISTANCE = cython.declare(cython.Py_ssize_t, 2)  # [ohm]
_B_REFERENCE = cython.declare(cython.Py_ssize_t, 3)  # V_ref [V]
_B_AVIONICS = cython.declare(cython.Py_ssize_t, 4)  # avionics power [W]
_B_ROTOR_POWER = cython.declare(cython.Py_ssize_t, 5)  # rotor power per N^1.5 [W / N^1.5]
_B_CHARGE = cython.declare(cython.Py_ssize_t, 6)  # state of charge [-]
_B_VOLTAGE = cython.declare(cython.Py_ssize_t, 7)  # terminal voltage [V]
_B_CURRENT = cython.declare(cython.Py_ssize_t, 8)  # current [A]
_B_POINTS = cython.declare(cython.Py_ssize_t, 9)  # points of the OCV curve (n)
_B_CURVE = cython.declare(cython.Py_ssize_t, 10)  # n states of charge, then n cell volts
BATTERY_CHARGE = _B_CHARGE
BATTERY_VOLTAGE = _B_VOLTAGE
BATTERY_CURRENT = _B_CURRENT
"""Where a battery buffer holds its state of charge, terminal voltage and current."""
ROTOR_MAX_THRUST = _TMAX
"""Where a rotor buffer holds a rotor's full thrust now (after the thrusts, 0 to 5)."""


def work_buffer() -> array:
    """The float64 buffer one integrator's steps work in (zeros, no servo torque limit)."""
    work = array("d", bytes(8 * _SIZE))
    work[_JLIM] = float("inf")
    return work


def jaw_buffer(angle_rad: float, low_rad: float, high_rad: float, inertia, friction) -> array:
    """A gripper jaw's float64 buffer: its shaft's angle [rad], rate (0) [rad/s], stops
    [rad], inertia [kg m^2] and viscous friction [N m s/rad]."""
    return array("d", [angle_rad, 0.0, low_rad, high_rad, inertia, friction])


def set_joint_servos(work, zero1: float, direction1: float, zero2: float, direction2: float):
    """How the joint servos turn with the joints, into ``work``: shaft angle = zero offset
    [rad] + direction (+1 or -1) * eta, for eta1 and eta2 (as
    :meth:`arm_driver.joint.JointConfig.servo_angle_rad`)."""
    work[_JMAP] = zero1
    work[_JMAP + 1] = direction1
    work[_JMAP + 2] = zero2
    work[_JMAP + 3] = direction2


def set_servo_limit(work, limit_n_m: float) -> None:
    """The servos' torque limit [N m] into ``work``: :func:`vehicle_step` clips the joint
    torques to +-limit."""
    work[_JLIM] = limit_n_m


def rotor_buffer(max_thrust_n: float, thr_mdl_fac: float, decay: float) -> array:
    """A rotor bank's float64 buffer: six thrusts now [N] (zeros), a rotor's full thrust now
    [N], THR_MDL_FAC, the lag's decay per step exp(-dt / time constant)."""
    return array("d", [0.0] * 6 + [max_thrust_n, thr_mdl_fac, decay])


def battery_buffer(constants, charge: float, curve) -> array:
    """A battery's float64 buffer: its ``constants`` (cells, capacity [A h], resistance
    [ohm], reference voltage [V], avionics power [W], rotor power per thrust^1.5
    [W / N^1.5]), its state (``charge`` [-], terminal voltage [V] and current [A], both 0
    until set) and its open-circuit curve ``curve`` ((state of charge, cell volts) points,
    rising charge)."""
    n = len(curve)
    return array(
        "d",
        [*constants, charge, 0.0, 0.0, float(n)]
        + [point[0] for point in curve]
        + [point[1] for point in curve],
    )


def set_rotor_wrench(work, rows, drag, wind, max_thrust_n: float) -> None:
    """The rotor step's constants into ``work``: the rotors' torque per thrust (``rows``,
    three rows of six, body FLU [N m / N]), the world drag diagonal [N s/m], the wind (world
    ENU [m/s]) and a rotor's full thrust at the battery's reference voltage [N]."""
    for axis in range(3):
        for i in range(6):
            work[_WRENCH + 6 * axis + i] = rows[axis][i]
    for i in range(3):
        work[_DRAG + i] = drag[i]
        work[_WIND + i] = wind[i]
    work[_TMAX0] = max_thrust_n


def aba_arguments(work) -> tuple:
    """(q (9), v (8), tau (8)): numpy arrays over ``work`` where every step writes the
    arguments of its ABA calls (Pinocchio's q, v = [R^T p_dot, omega, eta_dot], tau)."""
    return (
        np.frombuffer(work, count=9, offset=8 * _Q),
        np.frombuffer(work, count=8, offset=8 * _V),
        np.frombuffer(work, count=8, offset=8 * _TAU),
    )


# ------------------------------------------------------------------ frames


@cython.cfunc
@cython.inline
def _rotation9(
    qw: cython.double,
    qx: cython.double,
    qy: cython.double,
    qz: cython.double,
    w: cython.double[:],
    o: cython.Py_ssize_t,
):
    """R (body to world) of the unit quaternion qw + qx i + qy j + qz k into w[o:o + 9]."""
    w[o] = 1.0 - 2.0 * (qy * qy + qz * qz)
    w[o + 1] = 2.0 * (qx * qy - qw * qz)
    w[o + 2] = 2.0 * (qx * qz + qw * qy)
    w[o + 3] = 2.0 * (qx * qy + qw * qz)
    w[o + 4] = 1.0 - 2.0 * (qx * qx + qz * qz)
    w[o + 5] = 2.0 * (qy * qz - qw * qx)
    w[o + 6] = 2.0 * (qx * qz - qw * qy)
    w[o + 7] = 2.0 * (qy * qz + qw * qx)
    w[o + 8] = 1.0 - 2.0 * (qx * qx + qy * qy)


@cython.cfunc
@cython.inline
def _clamp_unit(v: cython.double) -> cython.double:
    """v clipped to [-1, 1] (1 for NaN, as Python's max(-1.0, min(1.0, v)))."""
    m: cython.double = v if v < 1.0 else 1.0
    return m if m > -1.0 else -1.0


@cython.cfunc
@cython.inline
def _nearest(v: cython.double) -> cython.double:
    """The integer nearest to a finite v, halves to even, as a float with v's sign (C's
    nearbyint): the fractional part fmod(v, 1) and v minus it are exact."""
    fraction: cython.double = fmod(v, 1.0)
    whole: cython.double = v - fraction
    odd: cython.bint = fmod(whole, 2.0) != 0.0
    if fraction > 0.5 or (fraction == 0.5 and odd):
        whole = whole + 1.0
    elif fraction < -0.5 or (fraction == -0.5 and odd):
        whole = whole - 1.0
    return copysign(whole, v)


@cython.cfunc
def _euler_rate_inverse9(
    phi: cython.double, theta: cython.double, w: cython.double[:], o: cython.Py_ssize_t
) -> cython.bint:
    """W(Phi)^-1 into w[o:o + 9]; False (nothing written) when |cos(theta)| < 1e-6."""
    ct: cython.double = cos(theta)
    if fabs(ct) < _COS_THETA_MIN:
        return False
    cf: cython.double = cos(phi)
    sf: cython.double = sin(phi)
    tt: cython.double = sin(theta) / ct
    w[o] = 1.0
    w[o + 1] = sf * tt
    w[o + 2] = cf * tt
    w[o + 3] = 0.0
    w[o + 4] = cf
    w[o + 5] = -sf
    w[o + 6] = 0.0
    w[o + 7] = sf / ct
    w[o + 8] = cf / ct
    return True


# ------------------------------------------------------------------ the step


@cython.cfunc
def _force(
    w: cython.double[:], kind: cython.int, r: cython.Py_ssize_t, u: cython.Py_ssize_t
) -> cython.int:
    """Pinocchio's generalized force into the buffer's tau at rotation w[r:r + 9] and
    velocity w[u:u + 8]: [R^T f_W, W(Phi)^-T tau_Phi, tau_eta] of a generalized force (the
    pitch of a singular W to the buffer's theta), [R^T (drag) + thrust e_z, torque, joint
    torques] of a wrench."""
    fx: cython.double
    fy: cython.double
    fz: cython.double
    if kind == GENERALIZED:
        phi: cython.double = atan2(w[r + 7], w[r + 8])
        theta: cython.double = asin(_clamp_unit(-w[r + 6]))
        if not _euler_rate_inverse9(phi, theta, w, _FWI):
            w[_THETA] = theta
            return SINGULAR
        fx = w[_F]
        fy = w[_F + 1]
        fz = w[_F + 2]
        tp: cython.double = w[_F + 3]
        tt: cython.double = w[_F + 4]
        ts: cython.double = w[_F + 5]
        w[_TAU] = w[r] * fx + w[r + 3] * fy + w[r + 6] * fz
        w[_TAU + 1] = w[r + 1] * fx + w[r + 4] * fy + w[r + 7] * fz
        w[_TAU + 2] = w[r + 2] * fx + w[r + 5] * fy + w[r + 8] * fz
        w[_TAU + 3] = tp
        w[_TAU + 4] = w[_FWI + 1] * tp + w[_FWI + 4] * tt + w[_FWI + 7] * ts
        w[_TAU + 5] = w[_FWI + 2] * tp + w[_FWI + 5] * tt + w[_FWI + 8] * ts
        w[_TAU + 6] = w[_F + 6]
        w[_TAU + 7] = w[_F + 7]
        return _OK
    fx = -w[_F + 4] * (w[u] - w[_F + 9])
    fy = -w[_F + 5] * (w[u + 1] - w[_F + 10])
    fz = -w[_F + 6] * (w[u + 2] - w[_F + 11])
    w[_TAU] = w[r] * fx + w[r + 3] * fy + w[r + 6] * fz
    w[_TAU + 1] = w[r + 1] * fx + w[r + 4] * fy + w[r + 7] * fz
    w[_TAU + 2] = w[r + 2] * fx + w[r + 5] * fy + w[r + 8] * fz + w[_F]
    w[_TAU + 3] = w[_F + 1]
    w[_TAU + 4] = w[_F + 2]
    w[_TAU + 5] = w[_F + 3]
    w[_TAU + 6] = w[_F + 7]
    w[_TAU + 7] = w[_F + 8]
    return _OK


@cython.cfunc
def _accelerations(
    w: cython.double[:],
    x: cython.Py_ssize_t,
    u: cython.Py_ssize_t,
    r: cython.Py_ssize_t,
    kind: cython.int,
    aba,
    k: cython.Py_ssize_t,
) -> cython.int:
    """du/dt = [p_ddot (world), omega_dot (body), eta_ddot] at (w[x:x + 9], w[u:u + 8])
    into w[k:k + 8]: a = ABA(q, [R^T p_dot, omega, eta_dot], tau), p_ddot = R (a_v +
    omega x v_B). ``r`` is the offset of the rotation of x, or -1 to compute it. Returns
    OK, DIVERGED (non-finite a) or SINGULAR."""
    i: cython.Py_ssize_t
    if r < 0:
        _rotation9(w[x + 6], w[x + 3], w[x + 4], w[x + 5], w, _RS)
        r = _RS
    fx: cython.double = w[u]
    fy: cython.double = w[u + 1]
    fz: cython.double = w[u + 2]
    w[_V] = w[r] * fx + w[r + 3] * fy + w[r + 6] * fz
    w[_V + 1] = w[r + 1] * fx + w[r + 4] * fy + w[r + 7] * fz
    w[_V + 2] = w[r + 2] * fx + w[r + 5] * fy + w[r + 8] * fz
    for i in range(3, 8):
        w[_V + i] = w[u + i]
    status: cython.int = _force(w, kind, r, u)
    if status != _OK:
        return status
    for i in range(9):
        w[_Q + i] = w[x + i]
    a: cython.double[:] = aba()
    for i in range(8):
        w[_A + i] = a[i]
    total: cython.double = 0.0
    for i in range(8):
        total += w[_A + i]
    if not isfinite(total):
        return DIVERGED
    ox: cython.double = w[u + 3]
    oy: cython.double = w[u + 4]
    oz: cython.double = w[u + 5]
    bx: cython.double = w[_A] + oy * w[_V + 2] - oz * w[_V + 1]
    by: cython.double = w[_A + 1] + oz * w[_V] - ox * w[_V + 2]
    bz: cython.double = w[_A + 2] + ox * w[_V + 1] - oy * w[_V]
    w[k] = w[r] * bx + w[r + 1] * by + w[r + 2] * bz
    w[k + 1] = w[r + 3] * bx + w[r + 4] * by + w[r + 5] * bz
    w[k + 2] = w[r + 6] * bx + w[r + 7] * by + w[r + 8] * bz
    for i in range(3, 8):
        w[k + i] = w[_A + i]
    return _OK


@cython.cfunc
def _retract(
    w: cython.double[:],
    x: cython.Py_ssize_t,
    u: cython.Py_ssize_t,
    h: cython.double,
    out: cython.Py_ssize_t,
) -> cython.int:
    """x (+) h u into w[out:out + 9]: p and eta linearly, the attitude by the exact
    exponential of the body rate (quaternion * exp(h omega / 2)); DIVERGED on a
    non-finite body rate."""
    qx: cython.double = w[x + 3]
    qy: cython.double = w[x + 4]
    qz: cython.double = w[x + 5]
    qw: cython.double = w[x + 6]
    hx: cython.double = 0.5 * h * w[u + 3]
    hy: cython.double = 0.5 * h * w[u + 4]
    hz: cython.double = 0.5 * h * w[u + 5]
    half: cython.double = sqrt(hx * hx + hy * hy + hz * hz)
    if not isfinite(half):
        return DIVERGED
    c: cython.double
    k: cython.double
    if half > 1e-8:
        c = cos(half)
        k = sin(half) / half
    else:
        c = 1.0 - 0.5 * half * half
        k = 1.0 - half * half / 6.0
    hx = k * hx
    hy = k * hy
    hz = k * hz
    w[out] = w[x] + h * w[u]
    w[out + 1] = w[x + 1] + h * w[u + 1]
    w[out + 2] = w[x + 2] + h * w[u + 2]
    w[out + 3] = qw * hx + qx * c + qy * hz - qz * hy
    w[out + 4] = qw * hy - qx * hz + qy * c + qz * hx
    w[out + 5] = qw * hz + qx * hy - qy * hx + qz * c
    w[out + 6] = qw * c - qx * hx - qy * hy - qz * hz
    w[out + 7] = w[x + 7] + h * w[u + 6]
    w[out + 8] = w[x + 8] + h * w[u + 7]
    return _OK


@cython.cfunc
def _stage_velocity(
    w: cython.double[:],
    u: cython.Py_ssize_t,
    h: cython.double,
    k: cython.Py_ssize_t,
    out: cython.Py_ssize_t,
):
    """u + h k into w[out:out + 8]."""
    i: cython.Py_ssize_t
    for i in range(8):
        w[out + i] = w[u + i] + h * w[k + i]


@cython.cfunc
def _rk4_stage(
    w: cython.double[:],
    h: cython.double,
    u_before: cython.Py_ssize_t,
    k_before: cython.Py_ssize_t,
    u_stage: cython.Py_ssize_t,
    k_stage: cython.Py_ssize_t,
    kind: cython.int,
    aba,
) -> cython.int:
    """One RK4 stage ``h`` [s] on from the buffer's state: its velocity u + h k_before
    into u_stage, its configuration x (+) h u_before, and its du/dt into k_stage."""
    _stage_velocity(w, _U, h, k_before, u_stage)
    s: cython.int = _retract(w, _X, u_before, h, _XS)
    if s != _OK:
        return s
    return _accelerations(w, _XS, u_stage, -1, kind, aba, k_stage)


@cython.cfunc
def _integrate(
    w: cython.double[:], rk4: cython.bint, dt: cython.double, kind: cython.int, aba
) -> cython.int:
    """One step from the buffer's state into (x+, u+), its first stage's du/dt in K1:
    semi-implicit Euler (u+ = u + dt f(x, u), x+ = x (+) dt u+) or classical RK4 with the
    stage configurations and the final update by the same retraction."""
    i: cython.Py_ssize_t
    s: cython.int = _accelerations(w, _X, _U, _R, kind, aba, _K1)
    if s != _OK:
        return s
    if not rk4:
        _stage_velocity(w, _U, dt, _K1, _UN)
        return _retract(w, _X, _UN, dt, _XN)
    h: cython.double = 0.5 * dt
    s = _rk4_stage(w, h, _U, _K1, _U2, _K2, kind, aba)
    if s != _OK:
        return s
    s = _rk4_stage(w, h, _U2, _K2, _U3, _K3, kind, aba)
    if s != _OK:
        return s
    s = _rk4_stage(w, dt, _U3, _K3, _U4, _K4, kind, aba)
    if s != _OK:
        return s
    sixth: cython.double = dt / 6.0
    for i in range(8):
        w[_UN + i] = w[_U + i] + sixth * (
            w[_K1 + i] + 2.0 * w[_K2 + i] + 2.0 * w[_K3 + i] + w[_K4 + i]
        )
        w[_MEAN + i] = (w[_U + i] + 2.0 * w[_U2 + i] + 2.0 * w[_U3 + i] + w[_U4 + i]) / 6.0
    return _retract(w, _X, _MEAN, dt, _XN)


# ------------------------------------------------------------------ the plant's kinematics


@cython.cfunc
def _kinematics(
    w: cython.double[:], x: cython.Py_ssize_t, u: cython.Py_ssize_t, euler: cython.Py_ssize_t
) -> cython.int:
    """The plant's kinematics of (w[x:x + 9], w[u:u + 8]) into the buffer's K block: x with
    the quaternion renormalized (w >= 0), R, Euler angles unwrapped next to
    w[euler:euler + 3], W^-1, our q and q_dot. DIVERGED for a non-finite state or a zero
    quaternion, SINGULAR (pitch to the buffer's theta) at the singularity."""
    i: cython.Py_ssize_t
    total: cython.double = 0.0
    for i in range(9):
        total += w[x + i]
    total_u: cython.double = 0.0
    for i in range(8):
        total_u += w[u + i]
    if not isfinite(total + total_u):
        return DIVERGED
    qx: cython.double = w[x + 3]
    qy: cython.double = w[x + 4]
    qz: cython.double = w[x + 5]
    qw: cython.double = w[x + 6]
    n: cython.double = sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if n == 0.0:
        return DIVERGED
    if qw < 0.0:
        n = -n
    qx = qx / n
    qy = qy / n
    qz = qz / n
    qw = qw / n
    for i in range(9):
        w[_KX + i] = w[x + i]
    w[_KX + 3] = qx
    w[_KX + 4] = qy
    w[_KX + 5] = qz
    w[_KX + 6] = qw
    _rotation9(qw, qx, qy, qz, w, _KR)
    phi: cython.double = atan2(w[_KR + 7], w[_KR + 8])
    theta: cython.double = asin(_clamp_unit(-w[_KR + 6]))
    psi: cython.double = atan2(w[_KR + 3], w[_KR])
    phi += _TWO_PI * _nearest((w[euler] - phi) / _TWO_PI)
    psi += _TWO_PI * _nearest((w[euler + 2] - psi) / _TWO_PI)
    w[_KE] = phi
    w[_KE + 1] = theta
    w[_KE + 2] = psi
    if not _euler_rate_inverse9(phi, theta, w, _KWI):
        w[_THETA] = theta
        return SINGULAR
    ox: cython.double = w[u + 3]
    oy: cython.double = w[u + 4]
    oz: cython.double = w[u + 5]
    w[_KQ] = w[x]
    w[_KQ + 1] = w[x + 1]
    w[_KQ + 2] = w[x + 2]
    w[_KQ + 3] = phi
    w[_KQ + 4] = theta
    w[_KQ + 5] = psi
    w[_KQ + 6] = w[x + 7]
    w[_KQ + 7] = w[x + 8]
    w[_KQD] = w[u]
    w[_KQD + 1] = w[u + 1]
    w[_KQD + 2] = w[u + 2]
    w[_KQD + 3] = ox + w[_KWI + 1] * oy + w[_KWI + 2] * oz
    w[_KQD + 4] = w[_KWI + 4] * oy + w[_KWI + 5] * oz
    w[_KQD + 5] = w[_KWI + 7] * oy + w[_KWI + 8] * oz
    w[_KQD + 6] = w[u + 6]
    w[_KQD + 7] = w[u + 7]
    return _OK


@cython.cfunc
def _q_ddot(w: cython.double[:], k: cython.Py_ssize_t, out: cython.Py_ssize_t):
    """Our q_ddot into w[out:out + 8] from du/dt w[k:k + 8] at the buffer's state (its
    Euler angles, q_dot and W^-1): Phi_ddot = W^-1 (omega_dot - W_dot Phi_dot)."""
    phi: cython.double = w[_E]
    theta: cython.double = w[_E + 1]
    pd: cython.double = w[_QD + 3]
    td: cython.double = w[_QD + 4]
    sd: cython.double = w[_QD + 5]
    cf: cython.double = cos(phi)
    sf: cython.double = sin(phi)
    ct: cython.double = cos(theta)
    st: cython.double = sin(theta)
    c0: cython.double = -ct * td * sd
    c1: cython.double = -sf * pd * td + (cf * ct * pd - sf * st * td) * sd
    c2: cython.double = -cf * pd * td - (sf * ct * pd + cf * st * td) * sd
    d0: cython.double = w[k + 3] - c0
    d1: cython.double = w[k + 4] - c1
    d2: cython.double = w[k + 5] - c2
    w[out] = w[k]
    w[out + 1] = w[k + 1]
    w[out + 2] = w[k + 2]
    w[out + 3] = d0 + w[_WI + 1] * d1 + w[_WI + 2] * d2
    w[out + 4] = w[_WI + 4] * d1 + w[_WI + 5] * d2
    w[out + 5] = w[_WI + 7] * d1 + w[_WI + 8] * d2
    w[out + 6] = w[k + 6]
    w[out + 7] = w[k + 7]


# ------------------------------------------------------------------ battery and rotors


@cython.cfunc
def _open_circuit_v(b: cython.double[:]) -> cython.double:
    """Pack voltage at rest at the buffer's charge [V]: the cell curve, linear between its
    points (the charge clipped to [0, 1]), times the cells."""
    charge: cython.double = b[_B_CHARGE]
    soc: cython.double = charge if not (0.0 > charge) else 0.0
    soc = soc if not (1.0 < soc) else 1.0
    n: cython.Py_ssize_t = cython.cast(cython.Py_ssize_t, b[_B_POINTS])
    i: cython.Py_ssize_t = 0
    while i < n and not (soc < b[_B_CURVE + i]):
        i += 1
    if i > n - 1:
        i = n - 1
    s0: cython.double = b[_B_CURVE + i - 1]
    s1: cython.double = b[_B_CURVE + i]
    v0: cython.double = b[_B_CURVE + n + i - 1]
    v1: cython.double = b[_B_CURVE + n + i]
    return b[_B_CELLS] * (v0 + (v1 - v0) * (soc - s0) / (s1 - s0))


@cython.cfunc
def _draw(b: cython.double[:], t: cython.double[:], n: cython.Py_ssize_t, dt: cython.double):
    """Feed rotors producing thrusts t[0:n] [N] (and the avionics) for ``dt`` [s]: power
    P = P_avionics + k sum T^1.5, terminal voltage the larger root of V^2 - OCV V + P R = 0
    (OCV / 2 beyond the pack's maximum power OCV^2 / 4R), current P / V, then the charge
    drawn, I dt / (3600 capacity), down to 0."""
    i: cython.Py_ssize_t
    power: cython.double = b[_B_AVIONICS]
    thrust: cython.double
    for i in range(n):
        thrust = t[i]
        if thrust > 0.0:
            power += b[_B_ROTOR_POWER] * thrust * sqrt(thrust)
    ocv: cython.double = _open_circuit_v(b)
    r: cython.double = b[_B_RESISTANCE]
    disc: cython.double = ocv * ocv - 4.0 * power * r
    if disc > 0.0:
        b[_B_VOLTAGE] = 0.5 * (ocv + sqrt(disc))
    else:
        b[_B_VOLTAGE] = 0.5 * ocv
    b[_B_CURRENT] = power / b[_B_VOLTAGE]
    charge: cython.double = b[_B_CHARGE] - b[_B_CURRENT] * dt / (3600.0 * b[_B_CAPACITY])
    b[_B_CHARGE] = charge if not (0.0 > charge) else 0.0


@cython.cfunc
def _lag(rotors: cython.double[:], w: cython.double[:], c: cython.Py_ssize_t):
    """Each rotor's thrust one step on toward the static thrust of its command w[c + i]
    held: T+ = decay T + (1 - decay) T_max (f u^2 + (1 - f) u)."""
    i: cython.Py_ssize_t
    f: cython.double = rotors[_FAC]
    t_max: cython.double = rotors[_TMAX]
    decay: cython.double = rotors[_DECAY]
    gain: cython.double = 1.0 - decay
    u: cython.double
    for i in range(_N_ROTORS):
        u = w[c + i]
        rotors[_T + i] = decay * rotors[_T + i] + gain * t_max * (f * u * u + (1.0 - f) * u)


@cython.ccall
def open_circuit_v(battery: cython.double[:]) -> cython.double:
    """The battery buffer's pack voltage at rest at its charge [V]."""
    return _open_circuit_v(battery)


@cython.ccall
def battery_draw(battery: cython.double[:], thrusts, dt: cython.double):
    """The battery buffer fed the rotors producing ``thrusts`` [N] (a sequence of floats)
    for ``dt`` [s] (see :func:`_draw`)."""
    t: cython.double[:] = array("d", thrusts)
    _draw(battery, t, len(thrusts), dt)


@cython.ccall
def rotor_lag(rotors: cython.double[:], commands, work: cython.double[:]):
    """The rotor buffer's thrusts one step on under six ``commands`` in [0, 1] held
    (``work``: an integrator's work buffer, :func:`work_buffer`)."""
    _read(work, _CMD, commands, 6)
    _lag(rotors, work, _CMD)


# ------------------------------------------------------------------ the attitude loop

# Offsets in the attitude loop's buffers (private: :func:`attitude_constants`,
# :func:`rate_constants`, :func:`rate_state` and :func:`mixer_constants` build them).
_A_GAIN = cython.declare(cython.Py_ssize_t, 0)
_A_YAW_WEIGHT = cython.declare(cython.Py_ssize_t, 3)
_A_RATE_MAX = cython.declare(cython.Py_ssize_t, 4)
_R_P = cython.declare(cython.Py_ssize_t, 0)
_R_I = cython.declare(cython.Py_ssize_t, 3)
_R_D = cython.declare(cython.Py_ssize_t, 6)
_R_LIMIT = cython.declare(cython.Py_ssize_t, 9)
_R_ALPHA = cython.declare(cython.Py_ssize_t, 12)
_R_DT = cython.declare(cython.Py_ssize_t, 13)
_R_I_FACTOR_RATE = cython.declare(cython.Py_ssize_t, 14)
_S_INTEGRAL = cython.declare(cython.Py_ssize_t, 0)
_S_PREVIOUS_RATE = cython.declare(cython.Py_ssize_t, 3)
_S_ACCEL = cython.declare(cython.Py_ssize_t, 6)
_M_ROLL = cython.declare(cython.Py_ssize_t, 0)
_M_PITCH = cython.declare(cython.Py_ssize_t, 6)
_M_YAW = cython.declare(cython.Py_ssize_t, 12)
_M_THRUST = cython.declare(cython.Py_ssize_t, 18)
_M_ROWS = cython.declare(cython.Py_ssize_t, 24)
_M_HI_YAW = cython.declare(cython.Py_ssize_t, 42)
_M_SIZE = cython.declare(cython.Py_ssize_t, 43)


def attitude_constants(gains, yaw_weight: float, rate_max_rad_s) -> array:
    """The attitude controller's constants: P gains (roll, pitch, yaw: the yaw gain already
    divided by the yaw weight) [rad/s per rad], the yaw weight, the rate limits [rad/s]."""
    return array("d", [*gains, yaw_weight, *rate_max_rad_s])


def rate_constants(
    p, i, d, integrator_limit, alpha: float, dt_s: float, i_factor_rate_rad_s: float
) -> array:
    """The rate controller's constants: P, I, D gains and integrator limits (3 each), the
    angular-acceleration filter's factor, the step [s] and the rate error at which the I
    gain has faded out [rad/s]."""
    return array("d", [*p, *i, *d, *integrator_limit, alpha, dt_s, i_factor_rate_rad_s])


def rate_state(previous_rate_rad_s) -> array:
    """The rate controller's state from rest: integrators 0, the previous body rates, the
    filtered angular accelerations 0."""
    return array("d", [0.0, 0.0, 0.0, *previous_rate_rad_s, 0.0, 0.0, 0.0])


def rate_integral(state) -> tuple:
    """The integrators of a rate controller's state [normalized torque]."""
    return (state[_S_INTEGRAL], state[_S_INTEGRAL + 1], state[_S_INTEGRAL + 2])


def rate_acceleration(state) -> tuple:
    """The filtered angular accelerations of a rate controller's state [rad/s^2]."""
    return (state[_S_ACCEL], state[_S_ACCEL + 1], state[_S_ACCEL + 2])


def mixer_constants(roll, pitch, yaw, thrust, allocated_rows, hi_yaw: float) -> array:
    """The allocation's constants: the roll, pitch, yaw and thrust columns (6 each), the
    allocated-torque rows (3 x 6, flat) and the raised upper bound of the yaw
    desaturation."""
    values = array("d", [*roll, *pitch, *yaw, *thrust, *allocated_rows, hi_yaw])
    assert len(values) == _M_SIZE
    return values


_USABLE = 1e-7
"""A direction component smaller than this does not desaturate (PX4)."""
_SATURATION_TOL = 1e-6
"""Torque shortfall that counts as saturation [normalized torque]."""


@cython.cfunc
@cython.inline
def _clip(v: cython.double, lo: cython.double, hi: cython.double) -> cython.double:
    """Python's min(max(v, lo), hi)."""
    m: cython.double = lo if lo > v else v
    return hi if hi < m else m


@cython.ccall
def rate_setpoint(q_wxyz, q_setpoint_wxyz, att: cython.double[:]) -> tuple:
    """Body-rate setpoint (FLU) [rad/s] for attitude ``q_wxyz`` and its setpoint: P control
    on the quaternion error, roll and pitch before yaw (PX4 AttitudeControl)."""
    qw: cython.double = q_wxyz[0]
    qx: cython.double = q_wxyz[1]
    qy: cython.double = q_wxyz[2]
    qz: cython.double = q_wxyz[3]
    dw: cython.double = q_setpoint_wxyz[0]
    dx: cython.double = q_setpoint_wxyz[1]
    dy: cython.double = q_setpoint_wxyz[2]
    dz: cython.double = q_setpoint_wxyz[3]
    # the body z axes in the world (third column of each rotation)
    sx: cython.double = 2.0 * (qx * qz + qw * qy)
    sy: cython.double = 2.0 * (qy * qz - qw * qx)
    sz: cython.double = 1.0 - 2.0 * (qx * qx + qy * qy)
    tx: cython.double = 2.0 * (dx * dz + dw * dy)
    ty: cython.double = 2.0 * (dy * dz - dw * dx)
    tz: cython.double = 1.0 - 2.0 * (dx * dx + dy * dy)
    # the shortest rotation taking the one to the other (PX4 Quaternion(src, dst))
    c0: cython.double = sy * tz - sz * ty
    c1: cython.double = sz * tx - sx * tz
    c2: cython.double = sx * ty - sy * tx
    dot: cython.double = sx * tx + sy * ty + sz * tz
    rw: cython.double
    a0: cython.double
    a1: cython.double
    a2: cython.double
    e0: cython.double = 0.0
    e1: cython.double = 0.0
    e2: cython.double = 0.0
    if sqrt(c0 * c0 + c1 * c1 + c2 * c2) < 1e-5 and dot < 0.0:
        a0, a1, a2 = abs(sx), abs(sy), abs(sz)
        if a0 < a1:
            if a0 < a2:
                e0 = 1.0
            else:
                e2 = 1.0
        elif a1 < a2:
            e1 = 1.0
        else:
            e2 = 1.0
        c0 = sy * e2 - sz * e1
        c1 = sz * e0 - sx * e2
        c2 = sx * e1 - sy * e0
        rw = 0.0
    else:
        rw = dot + sqrt((sx * sx + sy * sy + sz * sz) * (tx * tx + ty * ty + tz * tz))
    n: cython.double = sqrt(rw * rw + c0 * c0 + c1 * c1 + c2 * c2)
    rx: cython.double = c0 / n
    ry: cython.double = c1 / n
    rz: cython.double = c2 / n
    rw = rw / n
    # the reduced setpoint: tilt only, unless it is (nearly) upside down
    pw: cython.double
    px: cython.double
    py: cython.double
    pz: cython.double
    if abs(rx) > 1.0 - 1e-5 or abs(ry) > 1.0 - 1e-5:
        pw, px, py, pz = dw, dx, dy, dz
    else:
        pw = rw * qw - rx * qx - ry * qy - rz * qz
        px = rw * qx + rx * qw + ry * qz - rz * qy
        py = rw * qy - rx * qz + ry * qw + rz * qx
        pz = rw * qz + rx * qy - ry * qx + rz * qw
    # the yaw left: inv(reduced) * setpoint, canonical, its w and z clipped
    yw: cython.double = pw * dw + px * dx + py * dy + pz * dz
    yz: cython.double = pw * dz - px * dy + py * dx - pz * dw
    if yw < 0.0:
        yw, yz = -yw, -yz
    w: cython.double = _clip(yw, -1.0, 1.0)
    z: cython.double = _clip(yz, -1.0, 1.0)
    weight: cython.double = att[_A_YAW_WEIGHT]
    kw: cython.double = cos(weight * acos(w))
    kz: cython.double = sin(weight * asin(z))
    # the setpoint with its yaw weighted: reduced * (kw, 0, 0, kz), every product kept
    fw: cython.double = pw * kw - px * 0.0 - py * 0.0 - pz * kz
    fx: cython.double = pw * 0.0 + px * kw + py * kz - pz * 0.0
    fy: cython.double = pw * 0.0 - px * kz + py * kw + pz * 0.0
    fz: cython.double = pw * kz + px * 0.0 - py * 0.0 + pz * kw
    # the error inv(q) * weighted, canonical
    ew: cython.double = qw * fw + qx * fx + qy * fy + qz * fz
    ex: cython.double = qw * fx - qx * fw - qy * fz + qz * fy
    ey: cython.double = qw * fy + qx * fz - qy * fw - qz * fx
    ez: cython.double = qw * fz - qx * fy + qy * fx - qz * fw
    if ew < 0.0:
        ex, ey, ez = -ex, -ey, -ez
    return (
        _clip(2.0 * ex * att[_A_GAIN], -att[_A_RATE_MAX], att[_A_RATE_MAX]),
        _clip(2.0 * ey * att[_A_GAIN + 1], -att[_A_RATE_MAX + 1], att[_A_RATE_MAX + 1]),
        _clip(2.0 * ez * att[_A_GAIN + 2], -att[_A_RATE_MAX + 2], att[_A_RATE_MAX + 2]),
    )


@cython.ccall
def rate_update(
    rate_rad_s,
    rate_setpoint_rad_s,
    rate: cython.double[:],
    state: cython.double[:],
    saturation: cython.double[:],
) -> tuple:
    """One PID step on the body rates (PX4 RateControl): normalized torques (roll, pitch,
    yaw). The D term acts on the filtered angular acceleration; the integrators stop
    growing toward a side the mixer saturated last step and fade with the rate error (PX4's
    i-factor), clipped to their limits. ``state`` is updated in place."""
    torque = [0.0, 0.0, 0.0]
    i: cython.Py_ssize_t
    r: cython.double
    a: cython.double
    error: cython.double
    e: cython.double
    i_factor: cython.double
    dt: cython.double = rate[_R_DT]
    for i in range(3):
        r = rate_rad_s[i]
        a = state[_S_ACCEL + i]
        a += rate[_R_ALPHA] * ((r - state[_S_PREVIOUS_RATE + i]) / dt - a)
        state[_S_ACCEL + i] = a
        state[_S_PREVIOUS_RATE + i] = r
        error = rate_setpoint_rad_s[i] - r
        torque[i] = rate[_R_P + i] * error + state[_S_INTEGRAL + i] - rate[_R_D + i] * a
        if saturation[i] != 0.0 and error > 0.0:
            error = 0.0
        if saturation[3 + i] != 0.0 and 0.0 > error:
            error = 0.0
        e = error / rate[_R_I_FACTOR_RATE]
        i_factor = 1.0 - e * e
        if not i_factor > 0.0:
            i_factor = 0.0
        state[_S_INTEGRAL + i] = _clip(
            state[_S_INTEGRAL + i] + i_factor * rate[_R_I + i] * error * dt,
            -rate[_R_LIMIT + i],
            rate[_R_LIMIT + i],
        )
    return (torque[0], torque[1], torque[2])


@cython.cfunc
def _gain(
    u: cython.double[:], m: cython.double[:], column: cython.Py_ssize_t, hi: cython.double
) -> cython.double:
    """PX4 computeDesaturationGain: k_min + k_max over the rotors outside [0, hi]."""
    k_min: cython.double = 0.0
    k_max: cython.double = 0.0
    k: cython.double
    d: cython.double
    i: cython.Py_ssize_t
    for i in range(6):
        d = m[column + i]
        if -_USABLE < d < _USABLE:
            continue
        if u[i] < 0.0:
            k = -u[i] / d
        elif u[i] > hi:
            k = (hi - u[i]) / d
        else:
            continue
        if k < k_min:
            k_min = k
        if k > k_max:
            k_max = k
    return k_min + k_max


@cython.cfunc
def _desaturate(
    u: cython.double[:],
    m: cython.double[:],
    column: cython.Py_ssize_t,
    hi: cython.double,
    reduce_only: cython.bint,
):
    """Shift u along a column of the mix back into [0, hi] (PX4 desaturateActuators): the
    full gain, then half the gain that remains; with ``reduce_only`` only downward along a
    positive column (airmode disabled never raises thrust)."""
    i: cython.Py_ssize_t
    gain: cython.double = _gain(u, m, column, hi)
    if reduce_only and gain > 0.0:
        return
    for i in range(6):
        u[i] += gain * m[column + i]
    gain = 0.5 * _gain(u, m, column, hi)
    if reduce_only and gain > 0.0:
        return
    for i in range(6):
        u[i] += gain * m[column + i]


@cython.cfunc
def _outside(u: cython.double[:], hi: cython.double) -> cython.bint:
    lo: cython.double = u[0]
    up: cython.double = u[0]
    i: cython.Py_ssize_t
    for i in range(1, 6):
        if u[i] < lo:
            lo = u[i]
        if u[i] > up:
            up = u[i]
    return lo < 0.0 or up > hi


@cython.ccall
def mix(
    m: cython.double[:],
    torque,
    thrust: cython.double,
    u: cython.double[:],
    saturation: cython.double[:],
) -> None:
    """Allocate normalized torques (roll, pitch, yaw) and the relative collective thrust to
    six relative rotor thrusts ``u`` in [0, 1] (PX4 mixAirmodeDisabled + mixYaw): roll,
    pitch and thrust; desaturate by lowering thrust, then scaling roll, then pitch; add
    yaw and desaturate it alone against the raised bound; lower thrust again and clip.
    ``saturation`` gets the flags of the torques the rotors fell short of."""
    c0: cython.double = torque[0]
    c1: cython.double = torque[1]
    c2: cython.double = torque[2]
    i: cython.Py_ssize_t
    axis: cython.Py_ssize_t
    x: cython.double
    row: cython.Py_ssize_t
    for i in range(6):
        u[i] = m[_M_ROLL + i] * c0 + m[_M_PITCH + i] * c1 + m[_M_THRUST + i] * thrust
    if _outside(u, 1.0):
        _desaturate(u, m, _M_THRUST, 1.0, True)
        _desaturate(u, m, _M_ROLL, 1.0, False)
        _desaturate(u, m, _M_PITCH, 1.0, False)
    for i in range(6):
        u[i] = u[i] + m[_M_YAW + i] * c2
    if _outside(u, m[_M_HI_YAW]):
        _desaturate(u, m, _M_YAW, m[_M_HI_YAW], False)
    if _outside(u, 1.0):
        _desaturate(u, m, _M_THRUST, 1.0, True)
        for i in range(6):
            u[i] = 0.0 if u[i] < 0.0 else (1.0 if u[i] > 1.0 else u[i])
    for axis in range(3):
        row = _M_ROWS + 6 * axis
        x = torque[axis] - (
            m[row] * u[0]
            + m[row + 1] * u[1]
            + m[row + 2] * u[2]
            + m[row + 3] * u[3]
            + m[row + 4] * u[4]
            + m[row + 5] * u[5]
        )
        saturation[axis] = 1.0 if x > _SATURATION_TOL else 0.0
        saturation[3 + axis] = 1.0 if x < -_SATURATION_TOL else 0.0


@cython.ccall
def motor_command(relative: cython.double, thr_mdl_fac: cython.double) -> cython.double:
    """The motor command giving relative thrust ``relative`` on PX4's THR_MDL_FAC curve
    (FunctionMotors)."""
    if thr_mdl_fac < 1e-9:
        return relative
    b: cython.double = 1.0 - thr_mdl_fac
    return (sqrt(b * b + 4.0 * thr_mdl_fac * relative) - b) * (0.5 / thr_mdl_fac)


def attitude_loop(
    q_wxyz,
    rate_rad_s,
    q_setpoint_wxyz,
    thrust: cython.double,
    att: cython.double[:],
    rate: cython.double[:],
    state: cython.double[:],
    m: cython.double[:],
    saturation: cython.double[:],
    thr_mdl_fac: cython.double,
    relative: cython.double[:],
) -> tuple:
    """One step of the loop: (motor commands (list of 6), rate setpoint [rad/s], normalized
    torques); the rotors' relative thrusts go to ``relative``, the rate controller's state
    and the mixer's saturation flags (fed back next step, as PX4 does) are updated."""
    rate_sp = rate_setpoint(q_wxyz, q_setpoint_wxyz, att)
    torque = rate_update(rate_rad_s, rate_sp, rate, state, saturation)
    mix(m, torque, thrust, relative, saturation)
    commands = []
    i: cython.Py_ssize_t
    for i in range(6):
        commands.append(motor_command(relative[i], thr_mdl_fac))
    return commands, rate_sp, torque


# ------------------------------------------------------------------ the XM430 servos

L_ANGLE = 0
"""Shaft angle [rad] (0 at tick 2048)."""
L_RATE = 1
"""Shaft rate [rad/s]."""
L_CURRENT = 2
"""Present current [A]."""
L_LAG_DT = 3
"""Time step the current loop's factor was computed for [s] (NaN: none yet)."""
L_LAG = 4
"""The current loop's factor 1 - exp(-dt / tau) for that step."""
L_OVERLOAD = 5
"""Time the command has been at overload [s]."""
L_SILENT = 6
"""Time since the last instruction packet while the bus watchdog is armed [s]."""
L_HOLD = 7
"""Angle held after the bus watchdog tripped [rad]."""
L_PROFILE = 8
"""The velocity profile's position [rad]."""
SERVO_LOOP_SIZE = 9

# Offsets in ``params`` (private: :func:`servo_parameters` builds it).
_P_TORQUE_CONSTANT = cython.declare(cython.Py_ssize_t, 0)
_P_CURRENT_TIME_CONSTANT = cython.declare(cython.Py_ssize_t, 1)
_P_KP = cython.declare(cython.Py_ssize_t, 2)
_P_KD = cython.declare(cython.Py_ssize_t, 3)
_P_OVERLOAD_FRACTION = cython.declare(cython.Py_ssize_t, 4)
_P_OVERLOAD_TIME = cython.declare(cython.Py_ssize_t, 5)
_P_RESISTANCE = cython.declare(cython.Py_ssize_t, 6)
_P_BACK_EMF = cython.declare(cython.Py_ssize_t, 7)
_P_FRICTION = cython.declare(cython.Py_ssize_t, 8)

_TORQUE_ENABLE = cython.declare(cython.Py_ssize_t, ct.TORQUE_ENABLE.address)
_OPERATING_MODE = cython.declare(cython.Py_ssize_t, ct.OPERATING_MODE.address)
_CURRENT_LIMIT = cython.declare(cython.Py_ssize_t, ct.CURRENT_LIMIT.address)
_GOAL_CURRENT = cython.declare(cython.Py_ssize_t, ct.GOAL_CURRENT.address)
_GOAL_POSITION = cython.declare(cython.Py_ssize_t, ct.GOAL_POSITION.address)
_PRESENT_CURRENT = cython.declare(cython.Py_ssize_t, ct.PRESENT_CURRENT.address)
_PRESENT_VELOCITY = cython.declare(cython.Py_ssize_t, ct.PRESENT_VELOCITY.address)
_PRESENT_POSITION = cython.declare(cython.Py_ssize_t, ct.PRESENT_POSITION.address)
_PRESENT_INPUT_VOLTAGE = cython.declare(cython.Py_ssize_t, ct.PRESENT_INPUT_VOLTAGE.address)
_PROFILE_VELOCITY = cython.declare(cython.Py_ssize_t, ct.PROFILE_VELOCITY.address)
_BUS_WATCHDOG = cython.declare(cython.Py_ssize_t, ct.BUS_WATCHDOG.address)
_TRIPPED = cython.declare(cython.int, ct.BUS_WATCHDOG_TRIPPED & 0xFF)
_WATCHDOG_MAX = cython.declare(cython.int, ct.BUS_WATCHDOG_MAX)
_WATCHDOG_UNIT_S = cython.declare(cython.double, ct.BUS_WATCHDOG_UNIT_S)
_CURRENT_MODE = cython.declare(cython.int, int(ct.OperatingMode.CURRENT))
_CURRENT_BASED_POSITION_MODE = cython.declare(
    cython.int, int(ct.OperatingMode.CURRENT_BASED_POSITION)
)
_CENTER_TICKS = cython.declare(cython.longlong, units.POSITION_CENTER_TICKS)
_RAD_PER_TICK = cython.declare(cython.double, units.RAD_PER_TICK)
_VELOCITY_UNIT = cython.declare(cython.double, units.VELOCITY_RAD_S_PER_UNIT)
_CURRENT_UNIT = cython.declare(cython.double, units.CURRENT_A_PER_UNIT)
_VOLTAGE_UNIT = cython.declare(cython.double, units.VOLTAGE_V_PER_UNIT)

assert ct.TORQUE_ENABLE.size == ct.OPERATING_MODE.size == ct.BUS_WATCHDOG.size == 1
assert not ct.CURRENT_LIMIT.signed and ct.GOAL_CURRENT.signed and ct.GOAL_POSITION.signed
assert (ct.CURRENT_LIMIT.size, ct.GOAL_CURRENT.size, ct.PRESENT_CURRENT.size) == (2, 2, 2)
assert ct.PRESENT_CURRENT.signed and ct.GOAL_POSITION.size == 4
assert not ct.PRESENT_INPUT_VOLTAGE.signed and ct.PRESENT_INPUT_VOLTAGE.size == 2
assert ct.PRESENT_VELOCITY.size == ct.PRESENT_POSITION.size == 4
assert ct.PRESENT_VELOCITY.signed and ct.PRESENT_POSITION.signed
assert ct.PROFILE_VELOCITY.size == 4 and not ct.PROFILE_VELOCITY.signed


def servo_parameters(
    torque_constant_n_m_per_a: float,
    current_time_constant_s: float,
    position_kp_a_per_rad: float,
    position_kd_a_s_per_rad: float,
    overload_current_fraction: float,
    overload_time_s: float,
    winding_resistance_ohm: float,
    back_emf_v_s_per_rad: float,
    viscous_friction_n_m_s_per_rad: float,
) -> array:
    """The ``params`` buffer of a servo (see :class:`~sitl.servo.xm430.XM430Parameters`)."""
    return array(
        "d",
        [
            torque_constant_n_m_per_a,
            current_time_constant_s,
            position_kp_a_per_rad,
            position_kd_a_s_per_rad,
            overload_current_fraction,
            overload_time_s,
            winding_resistance_ohm,
            back_emf_v_s_per_rad,
            viscous_friction_n_m_s_per_rad,
        ],
    )


@cython.cfunc
@cython.inline
def _u16(table: cython.uchar[:], at: cython.Py_ssize_t) -> cython.longlong:
    return table[at] | table[at + 1] << 8


@cython.cfunc
@cython.inline
def _u32(table: cython.uchar[:], at: cython.Py_ssize_t) -> cython.longlong:
    value: cython.longlong = table[at] | table[at + 1] << 8
    return value | table[at + 2] << 16 | cython.cast(cython.longlong, table[at + 3]) << 24


@cython.cfunc
@cython.inline
def _i16(table: cython.uchar[:], at: cython.Py_ssize_t) -> cython.longlong:
    value: cython.longlong = _u16(table, at)
    return value - 0x10000 if value >= 0x8000 else value


@cython.cfunc
@cython.inline
def _i32(table: cython.uchar[:], at: cython.Py_ssize_t) -> cython.longlong:
    value: cython.longlong = _u32(table, at)
    return value - 0x100000000 if value >= 0x80000000 else value


@cython.cfunc
def _put(table: cython.uchar[:], at: cython.Py_ssize_t, size: cython.int, value: cython.longlong):
    i: cython.int
    for i in range(size):
        table[at + i] = (value >> (8 * i)) & 0xFF


@cython.cfunc
def _units(
    value: cython.double,
    unit: cython.double,
    low: cython.longlong,
    high: cython.longlong,
    what: str,
) -> cython.longlong:
    """round(value / unit) as Python rounds it (half to even), within [low, high]."""
    if not isfinite(value):
        raise ValueError(f"{what} {value} is not finite")
    x: cython.double = value / unit
    n: cython.double = floor(x)
    rest: cython.double = x - n  # exact, or (-1 < x < 0) rounded on the right side of 0.5
    if rest > 0.5 or (rest == 0.5 and fmod(n, 2.0) != 0.0):
        n += 1.0
    if not low <= n <= high:
        raise ValueError(f"{what} {value}: {int(n)} is outside [{low}, {high}]")
    return cython.cast(cython.longlong, n)


@cython.ccall
def servo_set_state(
    table: cython.uchar[:],
    loop: cython.double[:],
    angle_rad: cython.double,
    rate_rad_s: cython.double,
) -> None:
    """Present Position(132) and Present Velocity(128) from the shaft's angle [rad] and rate
    [rad/s]. ValueError (and nothing changed) for a value that is not finite or does not
    fit its 32-bit entry."""
    ticks: cython.longlong = _CENTER_TICKS + _units(
        angle_rad,
        _RAD_PER_TICK,
        -0x80000000 - _CENTER_TICKS,
        0x7FFFFFFF - _CENTER_TICKS,
        "angle [rad]",
    )
    velocity: cython.longlong = _units(
        rate_rad_s, _VELOCITY_UNIT, -0x80000000, 0x7FFFFFFF, "angular rate [rad/s]"
    )
    loop[L_ANGLE] = angle_rad
    loop[L_RATE] = rate_rad_s
    _put(table, _PRESENT_VELOCITY, 4, velocity)
    _put(table, _PRESENT_POSITION, 4, ticks)


def servo_couple(
    table: cython.uchar[:],
    loop: cython.double[:],
    params: cython.double[:],
    angle_rad: cython.double,
    rate_rad_s: cython.double,
) -> cython.double:
    """:func:`servo_set_state`, then :func:`servo_torque_n_m` [N m]: a physics joint's
    exchange with its servo at the start of a plant step, in one call."""
    servo_set_state(table, loop, angle_rad, rate_rad_s)
    return servo_torque_n_m(table, loop, params)


@cython.cfunc
def _command(
    table: cython.uchar[:],
    loop: cython.double[:],
    params: cython.double[:],
    limit_a: cython.double,
    profile_rad: cython.double,
    hold_rad: cython.double,
    tripped: cython.bint,
) -> cython.double:
    """The current the active mode asks for with torque on [A], clamped to ``limit_a``."""
    goal_a: cython.double = _i16(table, _GOAL_CURRENT) * _CURRENT_UNIT
    mode: cython.int = table[_OPERATING_MODE]
    command: cython.double
    goal_rad: cython.double
    if mode == _CURRENT_MODE:
        command = 0.0 if tripped else goal_a
    else:
        if tripped:
            goal_rad = hold_rad
        elif _u32(table, _PROFILE_VELOCITY) == 0:
            goal_rad = (_i32(table, _GOAL_POSITION) - _CENTER_TICKS) * _RAD_PER_TICK
        else:
            goal_rad = profile_rad
        command = params[_P_KP] * (goal_rad - loop[L_ANGLE])
        command -= params[_P_KD] * loop[L_RATE]
        if mode == _CURRENT_BASED_POSITION_MODE:
            limit_a = min(limit_a, abs(goal_a))
    return max(-limit_a, min(limit_a, command))


def servo_command_a(
    table: cython.uchar[:], loop: cython.double[:], params: cython.double[:]
) -> cython.double:
    """The current the active control mode asks for now [A], clamped to the limits (0 with
    torque off)."""
    if table[_TORQUE_ENABLE] != 1:
        return 0.0
    limit_a: cython.double = _u16(table, _CURRENT_LIMIT) * _CURRENT_UNIT
    tripped: cython.bint = table[_BUS_WATCHDOG] == _TRIPPED
    return _command(table, loop, params, limit_a, loop[L_PROFILE], loop[L_HOLD], tripped)


@cython.ccall
def servo_torque_n_m(
    table: cython.uchar[:], loop: cython.double[:], params: cython.double[:]
) -> cython.double:
    """Output torque [N m]: torque constant x present current (0 with torque off) minus the
    gearbox's viscous friction."""
    friction: cython.double = params[_P_FRICTION] * loop[L_RATE]
    if table[_TORQUE_ENABLE] != 1:
        return -friction
    return params[_P_TORQUE_CONSTANT] * loop[L_CURRENT] - friction


@cython.ccall
def servo_step(
    table: cython.uchar[:], loop: cython.double[:], params: cython.double[:], dt_s: cython.double
) -> cython.bint:
    """Advance the bus watchdog, the profile, the current loop and the overload timer by
    ``dt_s`` [s] and write Present Current(126).

    True when the overload timer has reached Overload time: then Present Current is not
    written; the caller sets the Overload bit (with its shutdown, which may turn torque
    off) and calls :func:`servo_write_current`. ValueError for a negative step (nothing changed)
    or a current outside its entry.
    """
    if not dt_s >= 0.0:
        raise ValueError(f"time step {dt_s} s must be >= 0")
    angle: cython.double = loop[L_ANGLE]
    torque_on: cython.bint = table[_TORQUE_ENABLE] == 1
    timeout: cython.int = table[_BUS_WATCHDOG]
    if not torque_on or not 0 < timeout <= _WATCHDOG_MAX:
        loop[L_SILENT] = 0.0
    else:
        loop[L_SILENT] += dt_s
        if loop[L_SILENT] > timeout * _WATCHDOG_UNIT_S:
            table[_BUS_WATCHDOG] = _TRIPPED
            loop[L_HOLD] = angle
    profile: cython.double = loop[L_PROFILE]
    rate: cython.double
    goal_rad: cython.double
    step_rad: cython.double
    if not torque_on:
        profile = angle
    elif table[_OPERATING_MODE] != _CURRENT_MODE:
        goal_rad = (_i32(table, _GOAL_POSITION) - _CENTER_TICKS) * _RAD_PER_TICK
        rate = _u32(table, _PROFILE_VELOCITY) * _VELOCITY_UNIT
        if rate == 0.0:
            profile = goal_rad
        else:
            step_rad = rate * dt_s
            profile += max(-step_rad, min(step_rad, goal_rad - profile))
    loop[L_PROFILE] = profile
    limit_a: cython.double = _u16(table, _CURRENT_LIMIT) * _CURRENT_UNIT
    command: cython.double = 0.0
    if torque_on:
        tripped: cython.bint = table[_BUS_WATCHDOG] == _TRIPPED
        command = _command(table, loop, params, limit_a, profile, loop[L_HOLD], tripped)
    volts: cython.double = _u16(table, _PRESENT_INPUT_VOLTAGE) * _VOLTAGE_UNIT
    emf: cython.double = params[_P_BACK_EMF] * loop[L_RATE]
    low: cython.double = (-volts - emf) / params[_P_RESISTANCE]
    high: cython.double = (volts - emf) / params[_P_RESISTANCE]
    driven: cython.double = max(low, min(high, command))
    if dt_s != loop[L_LAG_DT]:  # the current loop's factor, once per step size
        loop[L_LAG_DT] = dt_s
        loop[L_LAG] = -math.expm1(-dt_s / params[_P_CURRENT_TIME_CONSTANT])
    loop[L_CURRENT] += (driven - loop[L_CURRENT]) * loop[L_LAG]
    overloaded: cython.bint = abs(command) >= params[_P_OVERLOAD_FRACTION] * limit_a > 0.0
    loop[L_OVERLOAD] = loop[L_OVERLOAD] + dt_s if overloaded else 0.0
    if loop[L_OVERLOAD] >= params[_P_OVERLOAD_TIME]:
        return True
    servo_write_current(table, loop)
    return False


@cython.ccall
def servo_write_current(table: cython.uchar[:], loop: cython.double[:]) -> None:
    """Present Current(126) from the loop's current (0 A with torque off)."""
    if table[_TORQUE_ENABLE] != 1:
        loop[L_CURRENT] = 0.0
    units_: cython.longlong = _units(loop[L_CURRENT], _CURRENT_UNIT, -0x8000, 0x7FFF, "current [A]")
    _put(table, _PRESENT_CURRENT, 2, units_)


# ------------------------------------------------------------------ the state in the buffer


@cython.cfunc
def _commit(w: cython.double[:], u: cython.Py_ssize_t):
    """The buffer's kinematics (K block) with the velocity w[u:u + 8] become its state."""
    i: cython.Py_ssize_t
    for i in range(9):
        w[_X + i] = w[_KX + i]
        w[_R + i] = w[_KR + i]
        w[_WI + i] = w[_KWI + i]
    for i in range(8):
        w[_U + i] = w[u + i]
        w[_QO + i] = w[_KQ + i]
        w[_QD + i] = w[_KQD + i]
    for i in range(3):
        w[_E + i] = w[_KE + i]


@cython.cfunc
def _read(w: cython.double[:], o: cython.Py_ssize_t, values, n: cython.Py_ssize_t):
    """The first n floats of ``values`` into w[o:o + n]."""
    i: cython.Py_ssize_t
    for i in range(n):
        w[o + i] = values[i]


@cython.cfunc
def _list(w: cython.double[:], o: cython.Py_ssize_t, n: cython.Py_ssize_t) -> list:
    """w[o:o + n] as a list of floats."""
    values = []
    i: cython.Py_ssize_t
    for i in range(n):
        values.append(w[o + i])
    return values


@cython.cfunc
def _step_state(
    w: cython.double[:], rk4: cython.bint, dt: cython.double, kind: cython.int, aba
) -> cython.int:
    """One step from the buffer's state under its force; the new state, its kinematics and
    the step's q_ddot become the buffer's state. Returns OK, a failure of the step (the
    state unchanged), or the failure + 2 of the new state (non-finite 3, at the singularity
    4: only x, u and q_ddot are the new state's)."""
    w[_THETA] = 0.0
    s: cython.int = _integrate(w, rk4, dt, kind, aba)
    if s != _OK:
        return s
    _q_ddot(w, _K1, _QDD)
    s = _kinematics(w, _XN, _UN, _E)
    i: cython.Py_ssize_t
    if s != _OK:
        for i in range(9):
            w[_X + i] = w[_XN + i]
        for i in range(8):
            w[_U + i] = w[_UN + i]
        return s + 2
    _commit(w, _UN)
    return _OK


@cython.ccall
def load(x, u, euler_previous, work: cython.double[:]) -> cython.int:
    """Put the state (x, u) in the buffer with its kinematics (the quaternion renormalized,
    w >= 0, Euler angles unwrapped next to ``euler_previous``); the q_ddot kept. Returns OK,
    or DIVERGED / SINGULAR (pitch to the buffer's theta) with the buffer's state unchanged."""
    w: cython.double[:] = work
    _read(w, _KE, euler_previous, 3)
    _read(w, _XN, x, 9)
    _read(w, _UN, u, 8)
    w[_THETA] = 0.0
    s: cython.int = _kinematics(w, _XN, _UN, _KE)
    if s == _OK:
        _commit(w, _UN)
    return s


@cython.ccall
def step(
    rk4: cython.bint, dt: cython.double, kind: cython.int, force, aba, work: cython.double[:]
) -> cython.int:
    """One step of ``dt`` [s] (RK4 if ``rk4``, else semi-implicit Euler) from the buffer's
    state under a force held over the step; ``aba()`` returns Pinocchio's ABA of the
    buffer's q, v, tau (:func:`aba_arguments`). Returns as :func:`_step_state`."""
    w: cython.double[:] = work
    _read(w, _F, force, 8 if kind == GENERALIZED else 12)
    return _step_state(w, rk4, dt, kind, aba)


@cython.cfunc
def _rotor_step(
    w: cython.double[:],
    rk4: cython.bint,
    dt: cython.double,
    t: cython.double[:],
    battery,
    aba,
) -> cython.int:
    """One step of the rotor plant from the buffer's state under its motor commands and
    joint torques (see :func:`rotor_step`)."""
    i: cython.Py_ssize_t
    b: cython.double[:]
    ratio: cython.double
    if battery is not None:
        b = battery
        _draw(b, t, _N_ROTORS, dt)
        ratio = b[_B_VOLTAGE] / b[_B_REFERENCE]
        t[_TMAX] = w[_TMAX0] * (ratio * ratio)
    total: cython.double = 0.0
    for i in range(_N_ROTORS):
        w[_THR + i] = t[_T + i]
        total += t[_T + i]
    w[_F] = total
    axis: cython.Py_ssize_t
    torque: cython.double
    for axis in range(3):
        torque = w[_WRENCH + 6 * axis] * t[_T]
        for i in range(1, _N_ROTORS):
            torque += w[_WRENCH + 6 * axis + i] * t[_T + i]
        w[_F + 1 + axis] = torque
    for i in range(3):
        w[_F + 4 + i] = w[_DRAG + i]
        w[_F + 9 + i] = w[_WIND + i]
    w[_F + 7] = w[_JT]
    w[_F + 8] = w[_JT + 1]
    s: cython.int = _step_state(w, rk4, dt, WRENCH, aba)
    if s == _OK:
        _lag(t, w, _CMD)
    return s


@cython.ccall
def rotor_step(
    rk4: cython.bint,
    dt: cython.double,
    commands,
    joint,
    rotors: cython.double[:],
    battery,
    aba,
    work: cython.double[:],
) -> cython.int:
    """One step of the rotor plant from the buffer's state.

    The battery buffer (None: an ideal supply) feeds the thrusts of the rotor buffer, and a
    rotor's full thrust becomes its full thrust at V_ref times (V / V_ref)^2; those thrusts
    push (their sum along body z, the torque of the work buffer's rows, each sum in rotor
    order), with the world drag -D (p_dot - w) and the two ``joint`` torques, held over the
    step; when the step is whole the rotors lag toward the six ``commands``. Returns as
    :func:`step`."""
    w: cython.double[:] = work
    _read(w, _CMD, commands, 6)
    _read(w, _JT, joint, 2)
    return _rotor_step(w, rk4, dt, rotors, battery, aba)


@cython.cfunc
def _jaw_advance(jaw: cython.double[:], torque_n_m: cython.double, dt: cython.double):
    """Semi-implicit Euler step of the jaw's shaft under the gripper servo's torque [N m]
    for ``dt`` [s], stopped (rate 0) at the stops."""
    accel: cython.double = (torque_n_m - jaw[_J_FRICTION] * jaw[_J_RATE]) / jaw[_J_INERTIA]
    jaw[_J_RATE] = jaw[_J_RATE] + accel * dt
    jaw[_J_ANGLE] = jaw[_J_ANGLE] + jaw[_J_RATE] * dt
    if jaw[_J_ANGLE] <= jaw[_J_LOW] or jaw[_J_ANGLE] >= jaw[_J_HIGH]:
        jaw[_J_ANGLE] = _clip(jaw[_J_ANGLE], jaw[_J_LOW], jaw[_J_HIGH])
        jaw[_J_RATE] = 0.0


@cython.ccall
def jaw_advance(jaw: cython.double[:], torque_n_m: cython.double, dt: cython.double):
    """The jaw's buffer one step of ``dt`` [s] on under the gripper servo's torque [N m]."""
    _jaw_advance(jaw, torque_n_m, dt)


@cython.cfunc
def _couple(
    w: cython.double[:],
    table: cython.uchar[:],
    loop: cython.double[:],
    params: cython.double[:],
    j: cython.Py_ssize_t,
) -> cython.double:
    """Joint j's servo given its shaft's angle (zero offset + direction * eta) and rate
    (direction * eta_dot) from the buffer's state (:func:`servo_set_state`); returns its
    torque on the joint, direction * the servo's output torque [N m]."""
    direction: cython.double = w[_JMAP + 2 * j + 1]
    servo_set_state(
        table, loop, w[_JMAP + 2 * j] + direction * w[_QO + 6 + j], direction * w[_QD + 6 + j]
    )
    return direction * servo_torque_n_m(table, loop, params)


@cython.ccall
def vehicle_step(
    rk4: cython.bint,
    dt: cython.double,
    q_setpoint_wxyz,
    thrust: cython.double,
    joint,
    servos,
    att: cython.double[:],
    rate: cython.double[:],
    state: cython.double[:],
    m: cython.double[:],
    saturation: cython.double[:],
    thr_mdl_fac: cython.double,
    relative: cython.double[:],
    rotors: cython.double[:],
    battery,
    aba,
    work: cython.double[:],
) -> cython.int:
    """One step of the vehicle under an attitude setpoint (quaternion wxyz, relative
    collective ``thrust``) and two ``joint`` torques [N m], clipped to the servos' limit
    (:func:`set_servo_limit`): the attitude loop (:func:`attitude_loop`, on the loop's
    buffers) at the buffer's attitude and body rate gives the motor commands, then
    :func:`rotor_step`; the loop's rate setpoint, torques and commands stay in the buffer
    (:data:`LAYOUT`). Returns as :func:`step`, or BAD_JOINT_TORQUES (nothing changed).

    ``joint`` None: the joint torques are the joint servos' (``servos``: the control
    table, loop and parameters of eta1's servo, then of eta2's, see
    :func:`servo_couple`), each coupled first to its joint's angle and rate now
    (:func:`set_joint_servos`), and after a whole step their loops advance by ``dt``
    (:func:`servo_step`); the buffer keeps the angles, rates and torques, and the
    servos' overloads. With a gripper (``servos`` then also its servo's table, loop and
    parameters, and the jaw's buffer), the gripper's servo is coupled to the jaw, which
    moves under it (:func:`jaw_advance`) before the step, and its loop advances after."""
    w: cython.double[:] = work
    i: cython.Py_ssize_t
    j1: cython.double
    j2: cython.double
    # the servos' buffers, each taken once (t: control table, l: loop, p: parameters)
    t1: cython.uchar[:]
    l1: cython.double[:]
    p1: cython.double[:]
    t2: cython.uchar[:]
    l2: cython.double[:]
    p2: cython.double[:]
    t3: cython.uchar[:]
    l3: cython.double[:]
    p3: cython.double[:]
    jaw: cython.double[:]
    gripper: cython.bint = False
    w[_STEPPED] = 0.0
    if joint is None:
        t1, l1, p1, t2, l2, p2 = servos[0], servos[1], servos[2], servos[3], servos[4], servos[5]
        for i in range(2):
            w[_ARM + i] = w[_QO + 6 + i]
            w[_ARM + 2 + i] = w[_QD + 6 + i]
        j1 = _couple(w, t1, l1, p1, 0)
        w[_ST] = j1
        j2 = _couple(w, t2, l2, p2, 1)
        w[_ST + 1] = j2
        gripper = len(servos) > 6
        if gripper:
            t3, l3, p3, jaw = servos[6], servos[7], servos[8], servos[9]
            servo_set_state(t3, l3, jaw[_J_ANGLE], jaw[_J_RATE])
            _jaw_advance(jaw, servo_torque_n_m(t3, l3, p3), dt)
    else:
        j1 = joint[0]
        j2 = joint[1]
    if not isfinite(j1 + j2):
        return BAD_JOINT_TORQUES
    w[_JT] = _clip(j1, -w[_JLIM], w[_JLIM])
    w[_JT + 1] = _clip(j2, -w[_JLIM], w[_JLIM])
    rate_sp = rate_setpoint((w[_X + 6], w[_X + 3], w[_X + 4], w[_X + 5]), q_setpoint_wxyz, att)
    torque = rate_update((w[_U + 3], w[_U + 4], w[_U + 5]), rate_sp, rate, state, saturation)
    mix(m, torque, thrust, relative, saturation)
    for i in range(3):
        w[_RSP + i] = rate_sp[i]
        w[_TQ + i] = torque[i]
    for i in range(6):
        w[_CMD + i] = motor_command(relative[i], thr_mdl_fac)
    s: cython.int = _rotor_step(w, rk4, dt, rotors, battery, aba)
    if joint is None and s == _OK:
        w[_STEPPED] = 1.0
        w[_OVL] = 1.0 if servo_step(t1, l1, p1, dt) else 0.0
        w[_OVL + 1] = 1.0 if servo_step(t2, l2, p2, dt) else 0.0
        w[_OVL + 2] = 0.0
        if gripper:
            w[_OVL + 2] = 1.0 if servo_step(t3, l3, p3, dt) else 0.0
    return s


@cython.ccall
def actuator_signals(work: cython.double[:]) -> tuple:
    """(motor commands, rotor thrusts [N], joint torques [N m] (lists), rate setpoint
    [rad/s], normalized torques (tuples)) of the buffer's last :func:`vehicle_step`."""
    w: cython.double[:] = work
    return (
        _list(w, _CMD, 6),
        _list(w, _THR, 6),
        _list(w, _JT, 2),
        (w[_RSP], w[_RSP + 1], w[_RSP + 2]),
        (w[_TQ], w[_TQ + 1], w[_TQ + 2]),
    )


@cython.ccall
def acceleration(kind: cython.int, force, aba, work: cython.double[:]) -> cython.int:
    """Our q_ddot at the buffer's state under a force, no step, into its ``acceleration``
    field: OK, or DIVERGED / SINGULAR (pitch to the buffer's theta)."""
    w: cython.double[:] = work
    _read(w, _F, force, 8 if kind == GENERALIZED else 12)
    w[_THETA] = 0.0
    s: cython.int = _accelerations(w, _X, _U, _R, kind, aba, _K1)
    if s == _OK:
        _q_ddot(w, _K1, _ACC)
    return s


@cython.ccall
def coordinates(work: cython.double[:]) -> tuple:
    """(q, q_dot) of the buffer's state, two lists of 8 floats."""
    return (_list(work, _QO, 8), _list(work, _QD, 8))


@cython.ccall
def attitude(work: cython.double[:]) -> tuple:
    """(quaternion wxyz (body FLU to world ENU), omega (body FLU) [rad/s]) of the buffer's
    state, two tuples of floats."""
    w: cython.double[:] = work
    return ((w[_X + 6], w[_X + 3], w[_X + 4], w[_X + 5]), (w[_U + 3], w[_U + 4], w[_U + 5]))


@cython.ccall
def truth(work: cython.double[:]) -> tuple:
    """(q, q_dot, q_ddot (lists of 8), quaternion wxyz, R row-major 9, omega (tuples)) of the
    buffer's state."""
    w: cython.double[:] = work
    rotation = (
        w[_R],
        w[_R + 1],
        w[_R + 2],
        w[_R + 3],
        w[_R + 4],
        w[_R + 5],
        w[_R + 6],
        w[_R + 7],
        w[_R + 8],
    )
    quaternion, omega = attitude(w)
    return (
        _list(w, _QO, 8),
        _list(w, _QD, 8),
        _list(w, _QDD, 8),
        quaternion,
        rotation,
        omega,
    )

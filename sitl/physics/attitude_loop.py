"""The arithmetic of the PX4-like attitude loop, one plant step at a time.

What :class:`~sitl.physics.attitude_control.Px4AttitudeLoop` runs at every plant step, and
its parts on their own: :func:`rate_setpoint` (PX4 ``AttitudeControl::update``),
:func:`rate_update` (``RateControl::update``), :func:`mix` (the sequential-desaturation
allocation of :class:`~sitl.physics.rotors.SequentialDesaturationMixer`),
:func:`motor_command` (``FunctionMotors``' THR_MDL_FAC linearization) and
:func:`attitude_loop` (the four in a row). The classes in
:mod:`sitl.physics.attitude_control` and :mod:`sitl.physics.rotors` describe the
behaviour and hold the constants and the state.

One source, two builds: this module runs as Python, and ``setup.py`` compiles the same
file with Cython into ``sitl.physics._attitude_loop`` (:mod:`companion.compiled`); the
arithmetic is written as plain float operations (``x * x``, no ``**``) so that both
builds compute the same bits (tests/test_sitl_kernel.py compares them); the square root
and the trigonometric functions are the C library's in both (Python's ``math`` calls
them).

Quaternions ``[w, x, y, z]`` body (FLU) to world (ENU); vectors (roll, pitch, yaw) about
the body axes; torques normalized; thrusts relative to the rotors' full thrust.

Constants and state are float64 buffers (``array("d")``) owned by the classes and built
here: :func:`attitude_constants`, :func:`rate_constants` and :func:`rate_state` (read back
by :func:`rate_integral` and :func:`rate_acceleration`), :func:`mixer_constants`; the
saturation flags (positive roll, pitch, yaw; negative) are six floats, 0.0 or 1.0.
"""

from array import array

import cython
from cython.cimports.libc.math import acos, asin, cos, sin, sqrt

# Offsets in the buffers (private: :func:`attitude_constants`, :func:`rate_constants`,
# :func:`rate_state` and :func:`mixer_constants` build them).
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

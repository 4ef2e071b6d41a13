"""The XM430 servo's per-step physics, on its control table and loop state.

What :class:`~sitl.servo.xm430.XM430Servo` runs for every servo at every plant step:
:func:`set_state` (the shaft's angle and rate into Present Velocity(128) and Present
Position(132)), :func:`step` (the bus watchdog, the velocity profile, the position/current
command, the supply's voltage limit, the current loop's lag, the overload timer and Present
Current(126)), :func:`command_a` and :func:`torque_n_m`. The model is described in
:mod:`sitl.servo.xm430`.

One source, two builds: this module runs as Python, and ``setup.py`` compiles the same file
with Cython (pure-Python mode: the annotations type the locals) into
``sitl.servo._xm430_loop``, which :mod:`sitl.compiled` loads when it was built from this
file as it is now. ``round`` and ``math.expm1`` stay Python's calls in the compiled build,
so both builds compute the same bits (tests/test_xm430_model.py compares them).

The state lives in buffers the servo owns: ``table`` (the control table, bytes, Protocol
2.0 little-endian fields), ``loop`` (float64, indices ``L_*``: the servo's instruction handling
resets some of it) and ``params`` (float64, built by :func:`loop_parameters` from
:class:`~sitl.servo.xm430.XM430Parameters`).
"""

import math
from array import array

import cython

from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units

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
LOOP_SIZE = 9

# Offsets in ``params`` (private: :func:`loop_parameters` builds it).
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


def loop_parameters(
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
    if not math.isfinite(value):
        raise ValueError(f"{what} {value} is not finite")
    n = round(value / unit)
    if not low <= n <= high:
        raise ValueError(f"{what} {value}: {n} is outside [{low}, {high}]")
    return n


@cython.ccall
def set_state(
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


def couple(
    table: cython.uchar[:],
    loop: cython.double[:],
    params: cython.double[:],
    angle_rad: cython.double,
    rate_rad_s: cython.double,
) -> cython.double:
    """:func:`set_state`, then :func:`torque_n_m` [N m]: a physics joint's exchange with its
    servo at the start of a plant step, in one call."""
    set_state(table, loop, angle_rad, rate_rad_s)
    return torque_n_m(table, loop, params)


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


def command_a(
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
def torque_n_m(
    table: cython.uchar[:], loop: cython.double[:], params: cython.double[:]
) -> cython.double:
    """Output torque [N m]: torque constant x present current (0 with torque off) minus the
    gearbox's viscous friction."""
    friction: cython.double = params[_P_FRICTION] * loop[L_RATE]
    if table[_TORQUE_ENABLE] != 1:
        return -friction
    return params[_P_TORQUE_CONSTANT] * loop[L_CURRENT] - friction


def step(
    table: cython.uchar[:], loop: cython.double[:], params: cython.double[:], dt_s: cython.double
) -> cython.bint:
    """Advance the bus watchdog, the profile, the current loop and the overload timer by
    ``dt_s`` [s] and write Present Current(126).

    True when the overload timer has reached Overload time: then Present Current is not
    written; the caller sets the Overload bit (with its shutdown, which may turn torque
    off) and calls :func:`write_current`. ValueError for a negative step (nothing changed)
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
    write_current(table, loop)
    return False


def write_current(table: cython.uchar[:], loop: cython.double[:]) -> None:
    """Present Current(126) from the loop's current (0 A with torque off)."""
    if table[_TORQUE_ENABLE] != 1:
        loop[L_CURRENT] = 0.0
    units_: cython.longlong = _units(loop[L_CURRENT], _CURRENT_UNIT, -0x8000, 0x7FFF, "current [A]")
    _put(table, _PRESENT_CURRENT, 2, units_)

"""XM430-W350 raw control-table units <-> SI: the one place these conversions live.

Scales (ROBOTIS e-Manual, XM430-W350 control table, "Unit" column and the Goal
Position / Goal Velocity / Goal Current / Profile Acceleration descriptions):

=========================  =====================  ===================================
quantity                   one raw count          SI per count
=========================  =====================  ===================================
position                   1 pulse, 4096 per rev  2 pi / 4096 = 1.534e-3 rad
velocity                   0.229 rev/min          0.229 * 2 pi / 60 = 2.398e-2 rad/s
profile acceleration       214.577 rev/min^2      214.577 * 2 pi / 3600 = 0.3745 rad/s^2
current                    about 2.69 mA          2.69e-3 A
input voltage              0.1 V                  0.1 V
temperature                1 degC                 1 degC
=========================  =====================  ===================================

Position convention: angles are measured from a *zero tick*, by default
:data:`POSITION_CENTER_TICKS` = 2048, the middle of the 0-4095 range of Position
Control Mode (half a turn, 180 deg at 0.088 deg per pulse). A joint whose zero sits
there can travel +-pi rad in Position Control Mode without crossing the 0/4095 wrap.
The arm's configuration gives each joint its own zero tick (its calibration) and
direction (Drive Mode(10) bit 0, or a sign in the bus); these functions take the zero
as an argument and do not guess. Positive is counter-clockwise seen from the front of
the servo (increasing Goal Position, Drive Mode bit 0 clear).

Torque is not converted here: torque from current needs a calibrated torque constant
[N m / A] per servo (and depends on supply voltage), which belongs to the bus's
configuration.

Conversions to raw counts round to the nearest count (Python's ``round``); range
checks against the field size happen when the value is encoded.
"""

from __future__ import annotations

import math

__all__ = [
    "ACCELERATION_RAD_S2_PER_UNIT",
    "CURRENT_A_PER_UNIT",
    "POSITION_CENTER_TICKS",
    "POSITION_TICKS_PER_REV",
    "RAD_PER_TICK",
    "TEMPERATURE_C_PER_UNIT",
    "VELOCITY_RAD_S_PER_UNIT",
    "VOLTAGE_V_PER_UNIT",
    "a_to_current_units",
    "acceleration_units_to_rad_s2",
    "current_units_to_a",
    "rad_s2_to_acceleration_units",
    "rad_s_to_velocity_units",
    "rad_to_ticks",
    "temperature_units_to_c",
    "ticks_to_rad",
    "velocity_units_to_rad_s",
    "voltage_units_to_v",
]

POSITION_TICKS_PER_REV = 4096
"""Encoder pulses per output revolution [1/rev]."""
POSITION_CENTER_TICKS = 2048
"""Default zero of the angle [pulse]: middle of Position Control Mode's 0-4095 range."""
RAD_PER_TICK = 2.0 * math.pi / POSITION_TICKS_PER_REV
"""Angle of one position pulse [rad]."""
VELOCITY_RAD_S_PER_UNIT = 0.229 * 2.0 * math.pi / 60.0
"""Goal/Present Velocity, Velocity Limit, Profile Velocity: one count [rad/s]."""
ACCELERATION_RAD_S2_PER_UNIT = 214.577 * 2.0 * math.pi / 3600.0
"""Profile Acceleration (velocity-based profile): one count [rad/s^2]."""
CURRENT_A_PER_UNIT = 2.69e-3
"""Goal/Present Current, Current Limit: one count [A] (the e-Manual says "about")."""
VOLTAGE_V_PER_UNIT = 0.1
"""Present Input Voltage, Min/Max Voltage Limit: one count [V]."""
TEMPERATURE_C_PER_UNIT = 1.0
"""Present Temperature, Temperature Limit: one count [degC]."""


def _to_units(value: float, per_unit: float, what: str) -> int:
    if not math.isfinite(value):
        raise ValueError(f"{what} {value} is not finite")
    return round(value / per_unit)


def ticks_to_rad(ticks: int, zero_ticks: int = POSITION_CENTER_TICKS) -> float:
    """Position [pulse] -> joint angle [rad], counter-clockwise positive.

    Parameters
    ----------
    ticks
        Present/Goal Position [pulse] (any value in extended-position modes).
    zero_ticks
        Position [pulse] that is 0 rad.
    """
    return (ticks - zero_ticks) * RAD_PER_TICK


def rad_to_ticks(angle_rad: float, zero_ticks: int = POSITION_CENTER_TICKS) -> int:
    """Joint angle [rad] -> nearest position [pulse]; inverse of :func:`ticks_to_rad`.

    Raises
    ------
    ValueError
        If the angle is not finite.
    """
    return zero_ticks + _to_units(angle_rad, RAD_PER_TICK, "angle [rad]")


def velocity_units_to_rad_s(units: int) -> float:
    """Velocity [0.229 rev/min] -> angular rate [rad/s]."""
    return units * VELOCITY_RAD_S_PER_UNIT


def rad_s_to_velocity_units(rate_rad_s: float) -> int:
    """Angular rate [rad/s] -> nearest velocity count [0.229 rev/min]."""
    return _to_units(rate_rad_s, VELOCITY_RAD_S_PER_UNIT, "angular rate [rad/s]")


def acceleration_units_to_rad_s2(units: int) -> float:
    """Profile Acceleration [214.577 rev/min^2] -> angular acceleration [rad/s^2]."""
    return units * ACCELERATION_RAD_S2_PER_UNIT


def rad_s2_to_acceleration_units(acceleration_rad_s2: float) -> int:
    """Angular acceleration [rad/s^2] -> nearest Profile Acceleration count."""
    return _to_units(acceleration_rad_s2, ACCELERATION_RAD_S2_PER_UNIT, "acceleration")


def current_units_to_a(units: int) -> float:
    """Current [2.69 mA] -> motor current [A]."""
    return units * CURRENT_A_PER_UNIT


def a_to_current_units(current_a: float) -> int:
    """Motor current [A] -> nearest current count [2.69 mA]."""
    return _to_units(current_a, CURRENT_A_PER_UNIT, "current [A]")


def voltage_units_to_v(units: int) -> float:
    """Present Input Voltage [0.1 V] -> supply voltage [V]."""
    return units * VOLTAGE_V_PER_UNIT


def temperature_units_to_c(units: int) -> float:
    """Present Temperature [1 degC] -> internal temperature [degC]."""
    return units * TEMPERATURE_C_PER_UNIT

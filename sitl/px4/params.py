"""The PX4 parameters the simulated vehicle has, their table, and their MAVLink encoding.

Every parameter below exists in PX4 with the same name, unit and meaning; defaults are
PX4's except MPC_THR_HOVER and THR_MDL_FAC, which come from the scenario (what a PX4 user
would have configured for this airframe). Ranges are PX4's metadata; PX4 itself does not
enforce them on PARAM_SET, this vehicle does (see :meth:`Px4Params.set`).

Wire encoding (PX4 ``mavlink_parameters.cpp``): PARAM_VALUE.param_value is a float field;
PX4 copies an INT32 parameter's four bytes into it unchanged ("bytewise", announced by
MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE) and reads PARAM_SET the same way, whatever
``param_type`` the sender put in the message. So an INT32 value 4 travels as the float
with bit pattern 0x00000004, not as 4.0.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from pymavlink.dialects.v20 import common as mavlink

from companion.config import Scenario
from sitl.physics.rotors import N_ROTORS, inverse_thrust_curve

__all__ = [
    "OFFBOARD_LOSS_ACTIONS",
    "PARAMETERS",
    "ParamError",
    "ParamSpec",
    "Px4Params",
    "UnknownParamError",
    "hover_thrust_from_scenario",
]

Kind = Literal["REAL32", "INT32"]


class ParamError(ValueError):
    """A parameter value was refused (out of range, not supported, not finite)."""


class UnknownParamError(ParamError, KeyError):
    """No parameter of that name (PX4: ``[pm] unknown param: NAME``)."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, MAVLink type, default, PX4 range, unit and meaning."""

    name: str
    kind: Kind
    default: float
    minimum: float
    maximum: float
    unit: str
    description: str
    allowed: tuple[int, ...] | None = None
    """For enumerated INT32 parameters: the values this vehicle implements."""

    @property
    def mav_type(self) -> int:
        """MAV_PARAM_TYPE_REAL32 or MAV_PARAM_TYPE_INT32."""
        if self.kind == "INT32":
            return mavlink.MAV_PARAM_TYPE_INT32
        return mavlink.MAV_PARAM_TYPE_REAL32


OFFBOARD_LOSS_ACTIONS: dict[int, str] = {0: "POSCTL", 4: "AUTO.LAND", 5: "AUTO.LOITER"}
"""COM_OBL_RC_ACT values implemented (PX4: 0 Position, 1 Altitude, 2 Stabilized, 3 Return,
4 Land, 5 Hold, 6 Terminate, 7 Disarm) and the mode each one switches to. Without sticks,
PX4's Position mode holds position, as AUTO.LOITER does."""

_SPECS = (
    ParamSpec("COM_DISARM_LAND", "REAL32", 2.0, -1.0, 20.0, "s",
              "Auto-disarm this long after landing (after a takeoff since arming); <= 0 disables"),
    ParamSpec("COM_OBL_RC_ACT", "INT32", 0, 0, 7, "",
              "Offboard loss action: 0 Position (hold), 4 Land, 5 Hold",
              allowed=tuple(OFFBOARD_LOSS_ACTIONS)),
    ParamSpec("COM_OF_LOSS_T", "REAL32", 1.0, 0.0, 60.0, "s",
              "Offboard proof of life times out this long after the last setpoint"),
    ParamSpec("MAV_SYS_ID", "INT32", 1, 1, 250, "",
              "MAVLink system id (as in PX4, used from the next start)"),
    ParamSpec("MIS_TAKEOFF_ALT", "REAL32", 2.5, 0.0, 80.0, "m",
              "Takeoff altitude above home when NAV_TAKEOFF gives none (param7 NaN)"),
    ParamSpec("MPC_LAND_SPEED", "REAL32", 0.7, 0.6, 10.0, "m/s",
              "Descent speed of AUTO.LAND"),
    ParamSpec("MPC_THR_HOVER", "REAL32", 0.5, 0.1, 0.8, "norm",
              "Normalized collective thrust that hovers (feed-forward of the position loop)"),
    ParamSpec("MPC_THR_MIN", "REAL32", 0.12, 0.05, 0.5, "norm",
              "Smallest collective thrust the position controller commands in flight"),
    ParamSpec("MPC_TILTMAX_AIR", "REAL32", 45.0, 20.0, 89.0, "deg",
              "Largest tilt the position controller commands"),
    ParamSpec("MPC_TKO_SPEED", "REAL32", 1.5, 1.0, 5.0, "m/s",
              "Climb speed of AUTO.TAKEOFF"),
    ParamSpec("MPC_XY_P", "REAL32", 0.95, 0.0, 2.0, "1/s",
              "Horizontal position gain (position error to velocity setpoint)"),
    ParamSpec("MPC_XY_VEL_I_ACC", "REAL32", 0.4, 0.0, 60.0, "1/s^2",
              "Horizontal velocity integral gain (to acceleration)"),
    ParamSpec("MPC_XY_VEL_MAX", "REAL32", 12.0, 0.0, 20.0, "m/s",
              "Largest horizontal velocity setpoint"),
    ParamSpec("MPC_XY_VEL_P_ACC", "REAL32", 1.8, 1.2, 5.0, "1/s",
              "Horizontal velocity gain (velocity error to acceleration)"),
    ParamSpec("MPC_Z_P", "REAL32", 1.0, 0.1, 1.5, "1/s",
              "Vertical position gain"),
    ParamSpec("MPC_Z_VEL_I_ACC", "REAL32", 2.0, 0.2, 3.0, "1/s^2",
              "Vertical velocity integral gain (learns the hover thrust error)"),
    ParamSpec("MPC_Z_VEL_MAX_DN", "REAL32", 1.5, 0.5, 4.0, "m/s",
              "Largest descent velocity setpoint"),
    ParamSpec("MPC_Z_VEL_MAX_UP", "REAL32", 3.0, 0.5, 8.0, "m/s",
              "Largest climb velocity setpoint"),
    ParamSpec("MPC_Z_VEL_P_ACC", "REAL32", 4.0, 2.0, 15.0, "1/s",
              "Vertical velocity gain"),
    ParamSpec("NAV_MC_ALT_RAD", "REAL32", 0.8, 0.05, 200.0, "m",
              "Takeoff is complete within this distance of the takeoff altitude"),
    ParamSpec("THR_MDL_FAC", "REAL32", 0.0, 0.0, 1.0, "",
              "Thrust curve shape of the airframe (informative: the world owns the motors)"),
)  # fmt: skip

PARAMETERS: dict[str, ParamSpec] = {spec.name: spec for spec in _SPECS}
"""The parameter table, in PARAM_VALUE index order (alphabetical, as PX4 lists them)."""


def hover_thrust_from_scenario(scenario: Scenario) -> float:
    """MPC_THR_HOVER of the scenario's airframe with the empty arm (no payload).

    The hover thrust PX4 would have been tuned to: weight of vehicle + arm links over the
    believed maximum thrust of six rotors, through the THR_MDL_FAC curve
    (:func:`sitl.physics.rotors.inverse_thrust_curve`), clipped to the parameter range.
    """
    rotors = scenario.vehicle.rotors
    mass = scenario.vehicle.mass_kg + scenario.arm.link1.mass_kg + scenario.arm.link2.mass_kg
    relative = mass * scenario.environment.gravity_m_s2 / (N_ROTORS * rotors.max_thrust_per_rotor_n)
    spec = PARAMETERS["MPC_THR_HOVER"]
    if relative >= 1.0:
        return spec.maximum
    command = float(inverse_thrust_curve(relative, rotors.thr_mdl_fac))
    return min(max(command, spec.minimum), spec.maximum)


class Px4Params:
    """Current values of :data:`PARAMETERS` (INT32 as int, REAL32 as float).

    Parameters
    ----------
    overrides : mapping of str to float, optional
        Start values replacing the defaults; each is checked as by :meth:`set`.

    Raises
    ------
    ParamError
        On an unknown name or a refused value in ``overrides``.
    """

    def __init__(self, overrides: Mapping[str, float] | None = None) -> None:
        self._values: dict[str, float | int] = {
            name: (int(spec.default) if spec.kind == "INT32" else float(spec.default))
            for name, spec in PARAMETERS.items()
        }
        for name, value in (overrides or {}).items():
            self.set(name, value)

    @classmethod
    def from_scenario(
        cls, scenario: Scenario, overrides: Mapping[str, float] | None = None
    ) -> Px4Params:
        """Parameters of a scenario's airframe: MPC_THR_HOVER (see
        :func:`hover_thrust_from_scenario`) and THR_MDL_FAC from ``vehicle.rotors``, then
        ``overrides``."""
        merged: dict[str, float] = {
            "MPC_THR_HOVER": hover_thrust_from_scenario(scenario),
            "THR_MDL_FAC": scenario.vehicle.rotors.thr_mdl_fac,
        }
        merged.update(overrides or {})
        return cls(merged)

    def __getitem__(self, name: str) -> float:
        try:
            return self._values[name]
        except KeyError:
            raise UnknownParamError(name) from None

    @property
    def names(self) -> list[str]:
        """Parameter names in index order."""
        return list(self._values)

    def index(self, name: str) -> int:
        """PARAM_VALUE.param_index of ``name`` (raises UnknownParamError)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise UnknownParamError(name) from None

    def set(self, name: str, value: float) -> float | int:
        """Set a parameter; returns the value stored.

        Raises
        ------
        UnknownParamError
            No such parameter.
        ParamError
            Value not finite, outside [min, max], not an integer for INT32, or an
            enumerated value this vehicle does not implement.
        """
        spec = PARAMETERS.get(name)
        if spec is None:
            raise UnknownParamError(name)
        value = float(value)
        if not math.isfinite(value) or not spec.minimum <= value <= spec.maximum:
            raise ParamError(f"{name}: {value!r} outside [{spec.minimum:g}, {spec.maximum:g}]")
        stored: float | int = value
        if spec.kind == "INT32":
            if value != int(value):
                raise ParamError(f"{name}: {value!r} is not an integer")
            stored = int(value)
            if spec.allowed is not None and stored not in spec.allowed:
                raise ParamError(f"{name}: {stored} not supported (supported: {spec.allowed})")
        self._values[name] = stored
        return stored

    def wire_value(self, name: str) -> float:
        """PARAM_VALUE.param_value of ``name``: REAL32 as is, INT32 bytewise."""
        value = self[name]
        if PARAMETERS[name].kind == "INT32":
            return struct.unpack("<f", struct.pack("<i", int(value)))[0]
        return float(value)

    @staticmethod
    def decode_wire(name: str, wire: float) -> float:
        """The value a PARAM_SET.param_value means for ``name`` (bytewise for INT32).

        Raises UnknownParamError for an unknown name.
        """
        spec = PARAMETERS.get(name)
        if spec is None:
            raise UnknownParamError(name)
        if spec.kind == "INT32":
            return float(struct.unpack("<i", struct.pack("<f", wire))[0])
        return float(wire)

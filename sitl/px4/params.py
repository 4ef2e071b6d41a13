"""The PX4 parameters the simulated vehicle has, their table, and their MAVLink encoding.

Every parameter below exists in PX4 main (v1.17.0-alpha1, measured on the real SITL build)
with the same name, type, unit and meaning; defaults are PX4's, except those of a
configured airframe, which come from the scenario: THR_MDL_FAC (the motors' own curve,
``vehicle.rotors.thr_mdl_fac``), the attitude and rate gains and IMU_DGYRO_CUTOFF
(``[plant.attitude_control]``, whose defaults are PX4's), MAV_TYPE (13, hexarotor, as PX4's
hexacopter airframes set it; PX4's SIH hex reports the multicopter default 2) and
CA_ROTOR_COUNT (6). MPC_THR_HOVER is PX4's 0.5 whatever the vehicle: the hover thrust
estimator (:mod:`sitl.px4.hover_thrust`) learns the real one in flight.

Set semantics (PX4 ``mavlink_parameters.cpp``, measured): PARAM_SET stores any value of the
parameter's type, ranges are metadata only (PX4 accepts MPC_THR_HOVER 5, then
mc_pos_control constrains what it uses), enumerations are not checked (COM_OBL_RC_ACT 42 is
stored; the failsafe treats an unknown action as its default case), and a PARAM_SET whose
``param_type`` is not the parameter's is ignored without a reply. This vehicle refuses
non-finite values (PX4 stores a NaN; nothing here would fly with one).

Wire encoding: PARAM_VALUE.param_value is a float field; PX4 copies an INT32 parameter's
four bytes into it unchanged ("bytewise", announced by
MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE) and reads PARAM_SET the same way. So an
INT32 value 4 travels as the float with bit pattern 0x00000004, not as 4.0.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from pymavlink.dialects.v20 import common as mavlink

from sitl.physics.attitude_control import AttitudeLoopParams
from sitl.scenario import Scenario

__all__ = [
    "PARAMETERS",
    "ParamError",
    "ParamSpec",
    "Px4Params",
    "UnknownParamError",
    "attitude_loop_params",
]

Kind = Literal["REAL32", "INT32"]


class ParamError(ValueError):
    """A parameter value was refused (not finite, or not an integer for INT32)."""


class UnknownParamError(ParamError, KeyError):
    """No parameter of that name (PX4 does not answer)."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, MAVLink type, PX4 default, PX4's metadata range, unit, meaning."""

    name: str
    kind: Kind
    default: float
    minimum: float
    maximum: float
    unit: str
    description: str

    @property
    def mav_type(self) -> int:
        """MAV_PARAM_TYPE_REAL32 or MAV_PARAM_TYPE_INT32."""
        if self.kind == "INT32":
            return mavlink.MAV_PARAM_TYPE_INT32
        return mavlink.MAV_PARAM_TYPE_REAL32


_INF = math.inf
_SPECS = (
    ParamSpec("CA_AIRFRAME", "INT32", 0, 0, 15, "",
              "Control allocation airframe: 0 multirotor (informative)"),
    ParamSpec("CA_ROTOR_COUNT", "INT32", 6, 0, 12, "",
              "Rotors the control allocation uses (informative: six, fixed geometry)"),
    ParamSpec("COM_DISARM_LAND", "REAL32", 2.0, -1.0, 20.0, "s",
              "Auto-disarm this long after landing; <= 0 disables"),
    ParamSpec("COM_DISARM_PRFLT", "REAL32", 10.0, -1.0, 20.0, "s",
              "Auto-disarm this long after arming without a takeoff; <= 0 disables"),
    ParamSpec("COM_OBL_RC_ACT", "INT32", 0, 0, 7, "",
              "Offboard loss action: 0 Position, 1 Altitude, 2 Stabilized, 3 Return, "
              "4 Land, 5 Hold, 6 Terminate, 7 Disarm"),
    ParamSpec("COM_OF_LOSS_T", "REAL32", 1.0, 0.0, 60.0, "s",
              "Offboard proof of life times out this long after the last setpoint"),
    ParamSpec("COM_SPOOLUP_TIME", "REAL32", 1.0, 0.0, 30.0, "s",
              "Delay between arming and further navigation (starts the preflight disarm)"),
    ParamSpec("HTE_ACC_GATE", "REAL32", 3.0, 1.0, 10.0, "SD",
              "Hover thrust estimator: innovation gate of the acceleration fusion"),
    ParamSpec("HTE_HT_ERR_INIT", "REAL32", 0.1, 0.0, 1.0, "norm",
              "Hover thrust estimator: 1-sigma initial hover thrust uncertainty"),
    ParamSpec("HTE_HT_NOISE", "REAL32", 0.0036, 0.0001, 1.0, "norm/s",
              "Hover thrust estimator: process noise"),
    ParamSpec("HTE_THR_RANGE", "REAL32", 0.2, 0.01, 0.4, "norm",
              "Hover thrust estimator: largest deviation from MPC_THR_HOVER"),
    ParamSpec("HTE_VXY_THR", "REAL32", 10.0, 1.0, 20.0, "m/s",
              "Hover thrust estimator: horizontal speed above which it trusts less"),
    ParamSpec("HTE_VZ_THR", "REAL32", 2.0, 1.0, 10.0, "m/s",
              "Hover thrust estimator: vertical speed above which it trusts less"),
    ParamSpec("IMU_DGYRO_CUTOFF", "REAL32", 20.0, 0.0, 1000.0, "Hz",
              "Low-pass cutoff of the angular acceleration of the rate D terms"),
    ParamSpec("IMU_GYRO_RATEMAX", "INT32", 800, 100, 2000, "Hz",
              "Rate loop rate (informative: the loop runs at the plant rate)"),
    ParamSpec("IMU_INTEG_RATE", "INT32", 250, 100, 1000, "Hz",
              "IMU integration rate: the estimator's sample grid (used from the next start)"),
    ParamSpec("MAV_SYS_ID", "INT32", 1, 1, 250, "",
              "MAVLink system id (used from the next start)"),
    ParamSpec("MAV_TYPE", "INT32", 13, 0, 22, "",
              "MAVLink airframe type reported in HEARTBEAT (13: hexarotor)"),
    ParamSpec("MC_AIRMODE", "INT32", 0, 0, 2, "",
              "Airmode (informative: the mixer implements 0, disabled)"),
    ParamSpec("MC_BAT_SCALE_EN", "INT32", 0, 0, 1, "",
              "Battery thrust scaling (informative: not modelled, flown as 0; the companion "
              "refuses 1, carrying the thrust scale with the voltage itself)"),
    ParamSpec("MC_PITCHRATE_D", "REAL32", 0.003, 0.0, _INF, "", "Pitch rate D gain"),
    ParamSpec("MC_PITCHRATE_I", "REAL32", 0.2, 0.0, _INF, "", "Pitch rate I gain"),
    ParamSpec("MC_PITCHRATE_K", "REAL32", 1.0, 0.01, 5.0, "",
              "Pitch rate controller gain (scales P, I, D)"),
    ParamSpec("MC_PITCHRATE_MAX", "REAL32", 220.0, 0.0, 1800.0, "deg/s", "Max pitch rate"),
    ParamSpec("MC_PITCHRATE_P", "REAL32", 0.15, 0.01, 0.6, "", "Pitch rate P gain"),
    ParamSpec("MC_PITCH_P", "REAL32", 4.0, 0.0, 12.0, "1/s", "Pitch P gain"),
    ParamSpec("MC_PR_INT_LIM", "REAL32", 0.3, 0.0, _INF, "", "Pitch rate integrator limit"),
    ParamSpec("MC_ROLLRATE_D", "REAL32", 0.003, 0.0, 0.01, "", "Roll rate D gain"),
    ParamSpec("MC_ROLLRATE_I", "REAL32", 0.2, 0.0, _INF, "", "Roll rate I gain"),
    ParamSpec("MC_ROLLRATE_K", "REAL32", 1.0, 0.01, 5.0, "",
              "Roll rate controller gain (scales P, I, D)"),
    ParamSpec("MC_ROLLRATE_MAX", "REAL32", 220.0, 0.0, 1800.0, "deg/s", "Max roll rate"),
    ParamSpec("MC_ROLLRATE_P", "REAL32", 0.15, 0.01, 0.5, "", "Roll rate P gain"),
    ParamSpec("MC_ROLL_P", "REAL32", 4.0, 0.0, 12.0, "1/s", "Roll P gain"),
    ParamSpec("MC_RR_INT_LIM", "REAL32", 0.3, 0.0, _INF, "", "Roll rate integrator limit"),
    ParamSpec("MC_YAWRATE_D", "REAL32", 0.0, 0.0, _INF, "", "Yaw rate D gain"),
    ParamSpec("MC_YAWRATE_I", "REAL32", 0.1, 0.0, _INF, "", "Yaw rate I gain"),
    ParamSpec("MC_YAWRATE_K", "REAL32", 1.0, 0.01, 5.0, "",
              "Yaw rate controller gain (scales P, I, D)"),
    ParamSpec("MC_YAWRATE_MAX", "REAL32", 200.0, 0.0, 1800.0, "deg/s", "Max yaw rate"),
    ParamSpec("MC_YAWRATE_P", "REAL32", 0.2, 0.0, 0.6, "", "Yaw rate P gain"),
    ParamSpec("MC_YAW_P", "REAL32", 2.8, 0.0, 5.0, "1/s", "Yaw P gain"),
    ParamSpec("MC_YAW_WEIGHT", "REAL32", 0.4, 0.0, 1.0, "",
              "Yaw weight: yaw against roll and pitch priority"),
    ParamSpec("MC_YR_INT_LIM", "REAL32", 0.3, 0.0, _INF, "", "Yaw rate integrator limit"),
    ParamSpec("MIS_TAKEOFF_ALT", "REAL32", 2.5, 0.0, _INF, "m",
              "Takeoff altitude above home when NAV_TAKEOFF gives none (param7 NaN)"),
    ParamSpec("MPC_ACC_DOWN_MAX", "REAL32", 3.0, 2.0, 15.0, "m/s^2",
              "Largest downward acceleration of the AUTO modes' trajectory"),
    ParamSpec("MPC_ACC_UP_MAX", "REAL32", 4.0, 2.0, 15.0, "m/s^2",
              "Largest upward acceleration of the AUTO modes' trajectory"),
    ParamSpec("MPC_JERK_AUTO", "REAL32", 4.0, 1.0, 80.0, "m/s^3",
              "Largest jerk of the AUTO modes' trajectory"),
    ParamSpec("MPC_LAND_SPEED", "REAL32", 0.7, 0.6, _INF, "m/s", "Descent speed of AUTO.LAND"),
    ParamSpec("MPC_THR_HOVER", "REAL32", 0.5, 0.1, 0.8, "norm",
              "Relative thrust that hovers: the hover thrust estimator's start value"),
    ParamSpec("MPC_THR_MAX", "REAL32", 1.0, 0.0, 1.0, "norm",
              "Largest collective thrust the position controller commands"),
    ParamSpec("MPC_THR_MIN", "REAL32", 0.12, 0.05, 0.5, "norm",
              "Smallest collective thrust the position controller commands in flight"),
    ParamSpec("MPC_TILTMAX_AIR", "REAL32", 45.0, 20.0, 89.0, "deg",
              "Largest tilt the position controller commands"),
    ParamSpec("MPC_TKO_RAMP_T", "REAL32", 3.0, 0.0, 5.0, "s",
              "Takeoff ramp: time the climb velocity setpoint takes to reach MPC_TKO_SPEED"),
    ParamSpec("MPC_TKO_SPEED", "REAL32", 1.5, 1.0, 5.0, "m/s", "Climb speed of AUTO.TAKEOFF"),
    ParamSpec("MPC_XY_P", "REAL32", 0.95, 0.0, 2.0, "1/s",
              "Horizontal position gain (position error to velocity setpoint)"),
    ParamSpec("MPC_XY_VEL_I_ACC", "REAL32", 0.4, 0.0, 60.0, "1/s^2",
              "Horizontal velocity integral gain (to acceleration)"),
    ParamSpec("MPC_XY_VEL_MAX", "REAL32", 12.0, 0.0, 20.0, "m/s",
              "Largest horizontal velocity setpoint"),
    ParamSpec("MPC_XY_VEL_P_ACC", "REAL32", 1.8, 1.2, 5.0, "1/s",
              "Horizontal velocity gain (velocity error to acceleration)"),
    ParamSpec("MPC_Z_P", "REAL32", 1.0, 0.1, 1.5, "1/s", "Vertical position gain"),
    ParamSpec("MPC_Z_VEL_I_ACC", "REAL32", 2.0, 0.2, 3.0, "1/s^2",
              "Vertical velocity integral gain"),
    ParamSpec("MPC_Z_VEL_MAX_DN", "REAL32", 1.5, 0.5, 4.0, "m/s",
              "Largest descent velocity setpoint"),
    ParamSpec("MPC_Z_VEL_MAX_UP", "REAL32", 3.0, 0.5, 8.0, "m/s",
              "Largest climb velocity setpoint"),
    ParamSpec("MPC_Z_VEL_P_ACC", "REAL32", 4.0, 2.0, 15.0, "1/s", "Vertical velocity gain"),
    ParamSpec("NAV_MC_ALT_RAD", "REAL32", 0.8, 0.05, 200.0, "m",
              "Takeoff is complete within this distance of the takeoff altitude"),
    ParamSpec("RTL_CONE_ANG", "INT32", 45, 0, 90, "deg",
              "Return: half-angle of the cone above home that sets the return altitude"),
    ParamSpec("RTL_MIN_DIST", "REAL32", 10.0, 0.5, _INF, "m",
              "Return: within this horizontal distance of home the cone applies"),
    ParamSpec("RTL_RETURN_ALT", "REAL32", 30.0, 0.0, _INF, "m",
              "Return: altitude above home to fly back at (multicopter default)"),
    ParamSpec("THR_MDL_FAC", "REAL32", 0.0, 0.0, 1.0, "",
              "Thrust curve PX4 linearizes each motor's relative thrust with"),
)  # fmt: skip

PARAMETERS: dict[str, ParamSpec] = {spec.name: spec for spec in _SPECS}
"""The parameter table, in PARAM_VALUE index order (alphabetical, as PX4 lists them)."""

_GAIN_NAMES = (
    ("attitude_p", ("MC_ROLL_P", "MC_PITCH_P", "MC_YAW_P")),
    ("rate_p", ("MC_ROLLRATE_P", "MC_PITCHRATE_P", "MC_YAWRATE_P")),
    ("rate_i", ("MC_ROLLRATE_I", "MC_PITCHRATE_I", "MC_YAWRATE_I")),
    ("rate_d", ("MC_ROLLRATE_D", "MC_PITCHRATE_D", "MC_YAWRATE_D")),
    ("rate_k", ("MC_ROLLRATE_K", "MC_PITCHRATE_K", "MC_YAWRATE_K")),
    ("rate_integrator_limit", ("MC_RR_INT_LIM", "MC_PR_INT_LIM", "MC_YR_INT_LIM")),
)
"""AttitudeLoopParams fields and the PX4 parameters of their (roll, pitch, yaw) entries."""
_RATE_MAX = ("MC_ROLLRATE_MAX", "MC_PITCHRATE_MAX", "MC_YAWRATE_MAX")


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
        self.revision = 0
        """Incremented by every :meth:`set` (who caches derived values watches it)."""
        for name, value in (overrides or {}).items():
            self.set(name, value)

    @classmethod
    def from_scenario(
        cls, scenario: Scenario, overrides: Mapping[str, float] | None = None
    ) -> Px4Params:
        """Parameters of a scenario's configured airframe: THR_MDL_FAC from
        ``vehicle.rotors``, the attitude and rate gains from ``[plant.attitude_control]``
        (PX4 stores the rate limits in deg/s), then ``overrides``."""
        control = scenario.plant.attitude_control
        merged: dict[str, float] = {
            "THR_MDL_FAC": scenario.vehicle.rotors.thr_mdl_fac,
            "MC_YAW_WEIGHT": control.yaw_weight,
            "IMU_DGYRO_CUTOFF": control.rate_d_cutoff_hz,
        }
        for field_name, names in _GAIN_NAMES:
            if field_name != "rate_k":
                merged.update(zip(names, getattr(control, field_name), strict=True))
        merged.update(
            zip(_RATE_MAX, (math.degrees(r) for r in control.rate_max_rad_s), strict=True)
        )
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
            Value not finite, or not an integer for INT32.
        """
        spec = PARAMETERS.get(name)
        if spec is None:
            raise UnknownParamError(name)
        value = float(value)
        if not math.isfinite(value):
            raise ParamError(f"{name}: {value!r} is not finite")
        stored: float | int = value
        if spec.kind == "INT32":
            if value != int(value):
                raise ParamError(f"{name}: {value!r} is not an integer")
            stored = int(value)
        self._values[name] = stored
        self.revision += 1
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


def attitude_loop_params(params: Px4Params) -> AttitudeLoopParams:
    """The attitude loop's and mixer's parameters (gains, rate limits in rad/s, THR_MDL_FAC)
    as they stand in ``params``."""
    fields: dict = {
        field_name: tuple(float(params[n]) for n in names) for field_name, names in _GAIN_NAMES
    }
    return AttitudeLoopParams(
        yaw_weight=float(params["MC_YAW_WEIGHT"]),
        rate_max_rad_s=tuple(math.radians(params[n]) for n in _RATE_MAX),  # type: ignore[arg-type]
        d_cutoff_hz=float(params["IMU_DGYRO_CUTOFF"]),
        thr_mdl_fac=float(params["THR_MDL_FAC"]),
        **fields,
    )

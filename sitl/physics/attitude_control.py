"""PX4-like attitude and rate control of the simulated hexacopter (in our ENU / FLU frames).

The loop that PX4 closes on the vehicle when the companion streams SET_ATTITUDE_TARGET:

1. :class:`AttitudeController` - PX4 ``AttitudeControl::update``: P control on the quaternion
   error, with roll/pitch prioritized over yaw (the yaw part of the error is scaled by
   MC_YAW_WEIGHT and the yaw gain divided by it), producing body-rate setpoints clipped to
   MC_*RATE_MAX. No reference model, no yaw-rate feed-forward.
2. :class:`RateController` - PX4 ``RateControl::update``: PID on the body rates, the D term
   on the measured angular acceleration (finite difference of the rates through a first-order
   low-pass at IMU_DGYRO_CUTOFF; PX4 uses a second-order one), integrators clipped to
   MC_*_INT_LIM, with PX4's i-factor and its anti-windup from the mixer's saturation flags.
   The gains are PX4's ``MC_*RATE_K`` times ``MC_*RATE_P``, ``_I``, ``_D`` (mc_rate_control).
   The vehicle is never "landed", so the integrators always run. No yaw-torque low-pass.
3. :class:`~sitl.physics.rotors.SequentialDesaturationMixer` allocates the normalized
   torques and the relative collective thrust to six relative rotor thrusts, and PX4's
   ``FunctionMotors`` turns each into a motor command through the inverse of the
   THR_MDL_FAC curve (:func:`~sitl.physics.rotors.inverse_thrust_curve`) with the
   autopilot's THR_MDL_FAC. The motors themselves (:class:`~sitl.physics.rotors.RotorBank`)
   have their own curve: when the parameter matches it, thrust is linear in the setpoint.

The autopilot's parameters (:class:`AttitudeLoopParams`: the PX4 gains and THR_MDL_FAC)
start from the scenario's ``[plant.attitude_control]`` and ``vehicle.rotors.thr_mdl_fac``
and change at run time through :meth:`Px4AttitudeLoop.configure` (PARAM_SET in the SITL).

Both loops run at the plant rate. PX4 works in NED / FRD; the control laws are frame
covariant, so running them on ENU / FLU quantities with the same per-axis gains gives the
same physical behaviour. Quaternions are ``[w, x, y, z]``, body to world.

References: PX4-Autopilot ``src/modules/mc_att_control/AttitudeControl/AttitudeControl.cpp``,
``src/modules/mc_rate_control/RateControl/RateControl.cpp`` and their parameter files.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from companion.compiled import twin
from sitl import vehicle_step
from sitl.physics.frames import quaternion_from_euler
from sitl.physics.rotors import SequentialDesaturationMixer
from sitl.scenario import AttitudeControl as AttitudeControlConfig

__all__ = [
    "AttitudeController",
    "AttitudeLoopParams",
    "AttitudeSetpoint",
    "ControllerOutput",
    "Px4AttitudeLoop",
    "RateController",
]

FloatArray = NDArray[np.float64]
Quat = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]

_I_FACTOR_RATE_RAD_S = math.radians(400.0)
"""PX4: the I gain fades to zero as the rate error approaches 400 deg/s."""
_LOOP = twin(vehicle_step)
"""The loop's arithmetic: :mod:`sitl.vehicle_step`, compiled where built."""


@dataclass(frozen=True)
class AttitudeSetpoint:
    """What the companion asks of the autopilot: an attitude and a collective thrust.

    Attributes
    ----------
    quaternion_wxyz : ndarray, shape (4,)
        Desired attitude, body (FLU) to world (ENU), ``[w, x, y, z]``; normalized on
        construction.
    thrust : float
        Relative collective thrust in [0, 1]: the fraction of the six motors' full thrust
        (PX4's thrust setpoint, SET_ATTITUDE_TARGET.thrust). PX4 linearizes it per motor
        with THR_MDL_FAC, so it maps to newtons linearly when that parameter matches the
        motors' curve.

    Raises
    ------
    ValueError
        On a non-finite or zero quaternion or a thrust outside [0, 1].
    """

    quaternion_wxyz: FloatArray
    thrust: float

    def __post_init__(self) -> None:
        q = np.array(self.quaternion_wxyz, dtype=np.float64)
        if q.ndim != 1:
            q = q.reshape(-1)
        # np.linalg.norm of a real vector is sqrt(q.dot(q)): the same float, less overhead
        norm = math.sqrt(float(q.dot(q))) if q.shape == (4,) else 0.0
        if not math.isfinite(norm) or norm < 1e-9:
            raise ValueError(f"quaternion_wxyz must be 4 finite values, not all zero: {q!r}")
        q /= norm
        q.flags.writeable = False
        object.__setattr__(self, "quaternion_wxyz", q)
        thrust = float(self.thrust)
        if not 0.0 <= thrust <= 1.0:
            raise ValueError(f"thrust must lie in [0, 1], got {self.thrust!r}")
        object.__setattr__(self, "thrust", thrust)

    @classmethod
    def from_euler(cls, phi: float, theta: float, psi: float, thrust: float) -> AttitudeSetpoint:
        """Setpoint from ZYX Euler angles [rad] (R = Rz(psi) Ry(theta) Rx(phi)) and thrust."""
        return cls(quaternion_from_euler(phi, theta, psi), thrust)


def _as_quat(q: Iterable[float]) -> Quat:
    """Four Python floats of a quaternion given as an array, tuple or list."""
    w, x, y, z = q.tolist() if isinstance(q, np.ndarray) else map(float, q)
    return (w, x, y, z)


def _vec3(values: Iterable[float]) -> Vec3:
    a, b, c = (float(v) for v in values)
    return (a, b, c)


@dataclass(frozen=True)
class AttitudeLoopParams:
    """The autopilot parameters of the attitude loop and the mixer (PX4 names).

    Vectors are (roll, pitch, yaw) about the body axes.

    Attributes
    ----------
    attitude_p : tuple of 3 float
        MC_ROLL_P, MC_PITCH_P, MC_YAW_P [rad/s per rad].
    yaw_weight : float
        MC_YAW_WEIGHT [-].
    rate_max_rad_s : tuple of 3 float
        MC_ROLLRATE_MAX, MC_PITCHRATE_MAX, MC_YAWRATE_MAX [rad/s] (PX4 stores deg/s).
    rate_p, rate_i, rate_d : tuple of 3 float
        MC_*RATE_P [per rad/s], MC_*RATE_I [per rad], MC_*RATE_D [per rad/s^2], in
        normalized torque.
    rate_k : tuple of 3 float
        MC_*RATE_K: scales the P, I and D gains [-].
    rate_integrator_limit : tuple of 3 float
        MC_RR_INT_LIM, MC_PR_INT_LIM, MC_YR_INT_LIM [normalized torque].
    d_cutoff_hz : float
        IMU_DGYRO_CUTOFF [Hz].
    thr_mdl_fac : float
        THR_MDL_FAC: the thrust curve the autopilot linearizes the motors with [-].
    """

    attitude_p: Vec3
    yaw_weight: float
    rate_max_rad_s: Vec3
    rate_p: Vec3
    rate_i: Vec3
    rate_d: Vec3
    rate_k: Vec3
    rate_integrator_limit: Vec3
    d_cutoff_hz: float
    thr_mdl_fac: float

    @classmethod
    def from_config(cls, config: AttitudeControlConfig, thr_mdl_fac: float) -> AttitudeLoopParams:
        """The parameters of a validated ``[plant.attitude_control]`` section (rate K = 1)
        with THR_MDL_FAC ``thr_mdl_fac`` (a configured airframe: the motors' own curve)."""
        return cls(
            attitude_p=_vec3(config.attitude_p),
            yaw_weight=float(config.yaw_weight),
            rate_max_rad_s=_vec3(config.rate_max_rad_s),
            rate_p=_vec3(config.rate_p),
            rate_i=_vec3(config.rate_i),
            rate_d=_vec3(config.rate_d),
            rate_k=(1.0, 1.0, 1.0),
            rate_integrator_limit=_vec3(config.rate_integrator_limit),
            d_cutoff_hz=float(config.rate_d_cutoff_hz),
            thr_mdl_fac=float(thr_mdl_fac),
        )


class AttitudeController:
    """PX4 attitude P controller: quaternion error to body-rate setpoint.

    Parameters
    ----------
    attitude_p : array_like, shape (3,)
        Roll, pitch, yaw P gains [rad/s per rad] (MC_ROLL_P, MC_PITCH_P, MC_YAW_P).
    yaw_weight : float
        MC_YAW_WEIGHT in [0, 1].
    rate_max_rad_s : array_like, shape (3,)
        Rate setpoint limits [rad/s].
    """

    def __init__(
        self, attitude_p: Iterable[float], yaw_weight: float, rate_max_rad_s: Iterable[float]
    ) -> None:
        gains = [float(g) for g in attitude_p]
        self.yaw_weight = min(max(float(yaw_weight), 0.0), 1.0)
        if self.yaw_weight > 1e-4:
            gains[2] /= self.yaw_weight
        self._constants = vehicle_step.attitude_constants(
            gains, self.yaw_weight, [float(r) for r in rate_max_rad_s]
        )

    def rate_setpoint(
        self, q_wxyz: Iterable[float], q_setpoint_wxyz: Iterable[float]
    ) -> tuple[float, float, float]:
        """Body-rate setpoint (FLU) [rad/s] for attitude q and its setpoint (both wxyz)."""
        return _LOOP.rate_setpoint(_as_quat(q_wxyz), _as_quat(q_setpoint_wxyz), self._constants)


class RateController:
    """PX4 body-rate PID producing normalized torques.

    Parameters
    ----------
    rate_p, rate_i, rate_d : array_like, shape (3,)
        Gains (MC_*RATE_P, _I, _D) [normalized torque per rad/s, per rad, per rad/s^2].
    integrator_limit : array_like, shape (3,)
        |integral| limits (MC_*_INT_LIM) [normalized torque].
    d_cutoff_hz : float
        Low-pass cutoff of the angular-acceleration estimate [Hz].
    dt_s : float
        Update period [s].
    """

    def __init__(
        self,
        rate_p: Iterable[float],
        rate_i: Iterable[float],
        rate_d: Iterable[float],
        integrator_limit: Iterable[float],
        d_cutoff_hz: float,
        dt_s: float,
    ) -> None:
        self._dt = float(dt_s)
        self._state = vehicle_step.rate_state((0.0, 0.0, 0.0))
        """Integrators, previous rates, filtered angular accelerations."""
        self.set_gains(rate_p, rate_i, rate_d, integrator_limit, d_cutoff_hz)

    def set_gains(
        self,
        rate_p: Iterable[float],
        rate_i: Iterable[float],
        rate_d: Iterable[float],
        integrator_limit: Iterable[float],
        d_cutoff_hz: float,
    ) -> None:
        """New gains, limits and D cutoff (as the constructor's); the integrators and the
        acceleration filter keep their state, as PX4's on a parameter change."""
        self._constants = vehicle_step.rate_constants(
            [float(g) for g in rate_p],
            [float(g) for g in rate_i],
            [float(g) for g in rate_d],
            [float(g) for g in integrator_limit],
            1.0 - math.exp(-2.0 * math.pi * d_cutoff_hz * self._dt),
            self._dt,
            _I_FACTOR_RATE_RAD_S,
        )

    @property
    def integral(self) -> FloatArray:
        """Integrator states [normalized torque], shape (3,) (a new array)."""
        return np.array(vehicle_step.rate_integral(self._state))

    @property
    def angular_acceleration_estimate(self) -> FloatArray:
        """Filtered angular acceleration used by the D term [rad/s^2], shape (3,)."""
        return np.array(vehicle_step.rate_acceleration(self._state))

    def reset(self, rate_rad_s: Iterable[float] = (0.0, 0.0, 0.0)) -> None:
        """Zero the integrators and the acceleration filter; start from body rate ``rate_rad_s``."""
        self._state = vehicle_step.rate_state([float(r) for r in rate_rad_s])

    def update(
        self,
        rate_rad_s: tuple[float, float, float],
        rate_setpoint_rad_s: tuple[float, float, float],
        saturation_positive: tuple[bool, bool, bool],
        saturation_negative: tuple[bool, bool, bool],
    ) -> tuple[float, float, float]:
        """One PID step; returns normalized torques (roll, pitch, yaw).

        The saturation flags are the mixer's from the previous step (PX4 feeds back the
        control allocator status the same way).
        """
        flags = array("d", (float(bool(f)) for f in (*saturation_positive, *saturation_negative)))
        return _LOOP.rate_update(
            rate_rad_s, rate_setpoint_rad_s, self._constants, self._state, flags
        )


@dataclass(frozen=True)
class ControllerOutput:
    """Signals of one autopilot step (for logging; units in the names).

    Attributes
    ----------
    motor_commands : list of 6 float
        Motor commands u in [0, 1] (after the THR_MDL_FAC linearization).
    relative_thrusts : list of 6 float
        The mixer's allocation: each rotor's relative thrust in [0, 1] [-].
    rate_setpoint_rad_s : tuple of 3 float
        Body-rate setpoint (FLU) [rad/s].
    torque_normalized : tuple of 3 float
        Rate-controller output (roll, pitch, yaw) before allocation [-].
    thrust_normalized : float
        Relative collective thrust setpoint passed to the mixer [-].
    """

    motor_commands: list[float]
    relative_thrusts: list[float]
    rate_setpoint_rad_s: tuple[float, float, float]
    torque_normalized: tuple[float, float, float]
    thrust_normalized: float


@dataclass
class Px4AttitudeLoop:
    """Attitude P -> rate PID -> mixer -> THR_MDL_FAC linearization, one :meth:`update` per
    plant step.

    :meth:`update` is :func:`sitl.vehicle_step.attitude_loop` (compiled where its
    twin is built) on the constants of the three parts and the state of :attr:`rate` (its
    integrators and filter, updated in place). Change gains through :meth:`configure`.
    """

    attitude: AttitudeController
    rate: RateController
    mixer: SequentialDesaturationMixer
    thr_mdl_fac: float = 0.0
    """The autopilot's THR_MDL_FAC: relative rotor thrust -> motor command."""
    _saturation: array = field(default_factory=lambda: array("d", [0.0] * 6), repr=False)
    """The mixer's last saturation flags (positive roll, pitch, yaw; negative), 0 or 1."""
    _relative: array = field(default_factory=lambda: array("d", [0.0] * 6), repr=False)
    """The rotors' relative thrusts of the last step."""

    @classmethod
    def from_params(
        cls, params: AttitudeLoopParams, mixer: SequentialDesaturationMixer, dt_s: float
    ) -> Px4AttitudeLoop:
        """Loop with the gains and THR_MDL_FAC of ``params`` at step ``dt_s`` [s]."""
        k = params.rate_k
        return cls(
            attitude=AttitudeController(
                params.attitude_p, params.yaw_weight, params.rate_max_rad_s
            ),
            rate=RateController(
                [g * s for g, s in zip(params.rate_p, k, strict=True)],
                [g * s for g, s in zip(params.rate_i, k, strict=True)],
                [g * s for g, s in zip(params.rate_d, k, strict=True)],
                params.rate_integrator_limit,
                params.d_cutoff_hz,
                dt_s,
            ),
            mixer=mixer,
            thr_mdl_fac=params.thr_mdl_fac,
        )

    def configure(self, params: AttitudeLoopParams) -> None:
        """Take new parameters at once (PARAM_SET); integrators and filters carry on."""
        self.attitude = AttitudeController(
            params.attitude_p, params.yaw_weight, params.rate_max_rad_s
        )
        k = params.rate_k
        self.rate.set_gains(
            [g * s for g, s in zip(params.rate_p, k, strict=True)],
            [g * s for g, s in zip(params.rate_i, k, strict=True)],
            [g * s for g, s in zip(params.rate_d, k, strict=True)],
            params.rate_integrator_limit,
            params.d_cutoff_hz,
        )
        self.thr_mdl_fac = params.thr_mdl_fac

    def reset(self, rate_rad_s: Iterable[float] = (0.0, 0.0, 0.0)) -> None:
        """Clear integrators, filters and the saturation feedback."""
        self.rate.reset(rate_rad_s)
        self._saturation = array("d", [0.0] * 6)

    @property
    def buffers(self) -> tuple[array, array, array, array, array, array]:
        """The loop's float64 buffers in the order the vehicle's step takes them
        (:func:`sitl.vehicle_step.vehicle_step`): the attitude controller's and
        the rate controller's constants, the rate controller's state, the mixer's
        constants, the saturation flags and the relative thrusts (the last two written)."""
        rate = self.rate
        return (
            self.attitude._constants,
            rate._constants,
            rate._state,
            self.mixer._constants,
            self._saturation,
            self._relative,
        )

    def update(
        self,
        q_wxyz: tuple[float, float, float, float],
        rate_rad_s: tuple[float, float, float],
        setpoint: AttitudeSetpoint,
    ) -> ControllerOutput:
        """Motor commands for measured attitude ``q_wxyz`` and body rate ``rate_rad_s`` (FLU)."""
        commands, rate_sp, torque = self.commands(q_wxyz, rate_rad_s, setpoint)
        return ControllerOutput(commands, self._relative.tolist(), rate_sp, torque, setpoint.thrust)

    def commands(
        self,
        q_wxyz: tuple[float, float, float, float],
        rate_rad_s: tuple[float, float, float],
        setpoint: AttitudeSetpoint,
    ) -> tuple[list[float], tuple[float, float, float], tuple[float, float, float]]:
        """:meth:`update`'s motor commands, body-rate setpoint (FLU) [rad/s] and normalized
        torques, without building its :class:`ControllerOutput` (the plant's step)."""
        rate = self.rate
        return _LOOP.attitude_loop(
            q_wxyz,
            rate_rad_s,
            setpoint.quaternion_wxyz,
            setpoint.thrust,
            self.attitude._constants,
            rate._constants,
            rate._state,
            self.mixer._constants,
            self._saturation,
            self.thr_mdl_fac,
            self._relative,
        )

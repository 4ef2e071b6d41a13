"""Rotors of the simulated hexacopter: geometry, thrust curve, motor lag and a PX4-like mixer.

Geometry (FLU body frame, fixed, as the AscTec Firefly of the paper and its RotorS model):
rotor i = 0..5 sits at azimuth ``30 deg + 60 deg * i`` counter-clockwise from body x seen
from above, at ``arm_length_m`` from the vehicle CoM in the body x-y plane; rotor 0 (front
left) spins counter-clockwise seen from above, then the direction alternates. A rotor with
thrust T pushes along body +z and applies the reaction moment ``-s_i k_m T`` about body z,
with s_i = +1 for counter-clockwise spin and k_m = ``yaw_moment_per_thrust_m``.

Thrust model (PX4's THR_MDL_FAC curve): a normalized motor command u in [0, 1] produces the
static thrust ``T_max * (f u^2 + (1 - f) u)``; the produced thrust follows it through a
first-order lag (time constant ``motor_time_constant_s``), discretized exactly for a
command held over each step.

Mixer: PX4's control allocation for multicopters (``ControlAllocationPseudoInverse`` with
its normalization, ``ControlAllocationSequentialDesaturation`` with MC_AIRMODE = 0), redone
in FLU. It works in relative thrust, as PX4's allocation does: its inputs are normalized
torques (roll, pitch, yaw) and the relative collective thrust in [0, 1]; its outputs are
the six rotors' relative thrusts in [0, 1] (fractions of one rotor's full thrust). PX4's
``FunctionMotors`` then turns each into a motor command with :func:`inverse_thrust_curve`
and the autopilot's THR_MDL_FAC (see :mod:`sitl.physics.attitude_control`); the motors
answer with their own curve, so thrust is linear in the setpoint when the two agree. The
normalization pins what a normalized torque means physically: for small commands around a
trim the mixer produces the body torque ``torque_per_normalized_n_m * c`` (N m, at the
believed maximum thrust), i.e. the torque-to-thrust map is PX4's, derived from rotor
geometry: for the Firefly layout (0.215 m arms, 6 N rotors, k_m = 0.016 m) a normalized
roll or pitch torque of 1 is 3.16 N m and a normalized yaw torque of 1 is 0.576 N m.

References: PX4-Autopilot ``src/modules/control_allocator/ControlAllocation/``
(ControlAllocationPseudoInverse.cpp, ControlAllocationSequentialDesaturation.cpp) and
``src/lib/mixer_module/functions/FunctionMotors.hpp`` (thrust curve).
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.compiled import twin
from sitl import vehicle_step

__all__ = [
    "FIRST_ROTOR_AZIMUTH_RAD",
    "N_ROTORS",
    "MixerOutput",
    "RotorBank",
    "RotorGeometry",
    "SequentialDesaturationMixer",
    "inverse_thrust_curve",
    "thrust_curve",
]

FloatArray = NDArray[np.float64]

N_ROTORS = 6
FIRST_ROTOR_AZIMUTH_RAD = math.pi / 6.0
"""Azimuth of rotor 0 from body x, counter-clockwise seen from above (30 deg)."""

MINIMUM_YAW_MARGIN = 0.15
"""PX4: yaw may push the upper command bound by this fraction before thrust is cut."""

_SMALL = 1e-3
"""PX4 zeroes allocation entries below this magnitude and ignores them when counting."""

_STEP = twin(vehicle_step)
"""The allocation's and the rotors' lag's arithmetic: :mod:`sitl.vehicle_step`,
compiled where built."""
_MAX_THRUST = vehicle_step.ROTOR_MAX_THRUST


def thrust_curve(u: ArrayLike, thr_mdl_fac: float) -> FloatArray:
    """Relative thrust f u^2 + (1 - f) u of normalized commands u (PX4's THR_MDL_FAC model)."""
    u = np.asarray(u, dtype=np.float64)
    return thr_mdl_fac * u * u + (1.0 - thr_mdl_fac) * u


def inverse_thrust_curve(rel_thrust: ArrayLike, thr_mdl_fac: float) -> FloatArray:
    """Command u in [0, 1] giving relative thrust ``rel_thrust`` in [0, 1] (inverse of the curve).

    Raises
    ------
    ValueError
        If a relative thrust lies outside [0, 1].
    """
    r = np.asarray(rel_thrust, dtype=np.float64)
    if np.any(r < 0.0) or np.any(r > 1.0):
        raise ValueError(f"relative thrust must lie in [0, 1], got {rel_thrust!r}")
    f = thr_mdl_fac
    if f < 1e-9:
        return r.copy()
    b = 1.0 - f
    return (-b + np.sqrt(b * b + 4.0 * f * r)) / (2.0 * f)


@dataclass(frozen=True)
class RotorGeometry:
    """Positions, spin directions and yaw-moment ratio of the six rotors.

    Attributes
    ----------
    positions_m : ndarray, shape (6, 3)
        Rotor hub positions in the body frame (FLU, from the vehicle CoM) [m].
    spin : ndarray, shape (6,)
        +1 for a rotor spinning counter-clockwise seen from above, -1 otherwise.
    yaw_moment_per_thrust_m : float
        Reaction moment per unit thrust k_m [m].
    """

    positions_m: FloatArray
    spin: FloatArray
    yaw_moment_per_thrust_m: float

    @classmethod
    def hexa_x(cls, arm_length_m: float, yaw_moment_per_thrust_m: float) -> RotorGeometry:
        """The Firefly layout described in the module docstring."""
        azimuth = FIRST_ROTOR_AZIMUTH_RAD + np.arange(N_ROTORS) * (math.pi / 3.0)
        positions = np.column_stack(
            (arm_length_m * np.cos(azimuth), arm_length_m * np.sin(azimuth), np.zeros(N_ROTORS))
        )
        spin = np.array([1.0, -1.0] * (N_ROTORS // 2))
        positions.flags.writeable = False
        spin.flags.writeable = False
        return cls(positions, spin, float(yaw_moment_per_thrust_m))

    def wrench_matrix(self) -> FloatArray:
        """Body torque (x, y, z) [N m] and force z [N] per newton of each rotor's thrust, (4, 6).

        ``torque = r_i x (0, 0, T_i) - s_i k_m T_i e_z``.
        """
        x, y = self.positions_m[:, 0], self.positions_m[:, 1]
        return np.vstack((y, -x, -self.spin * self.yaw_moment_per_thrust_m, np.ones(N_ROTORS)))


class RotorBank:
    """Six motors: thrust curve and first-order lag from command to thrust.

    Parameters
    ----------
    max_thrust_n : float
        True static thrust of one rotor at u = 1 [N].
    thr_mdl_fac : float
        Thrust-curve shape f in [0, 1].
    time_constant_s : float
        Lag time constant [s].
    dt_s : float
        Step [s]; the lag is discretized exactly for a command held over the step:
        T+ = T_cmd + (T - T_cmd) exp(-dt / time_constant).
    """

    def __init__(
        self, max_thrust_n: float, thr_mdl_fac: float, time_constant_s: float, dt_s: float
    ) -> None:
        self.thr_mdl_fac = float(thr_mdl_fac)
        self.time_constant_s = float(time_constant_s)
        decay = math.exp(-dt_s / time_constant_s)
        self.buffer = vehicle_step.rotor_buffer(float(max_thrust_n), self.thr_mdl_fac, decay)
        """Thrusts, full thrust, THR_MDL_FAC and decay, as
        :func:`~sitl.vehicle_step.rotor_buffer` lays them out (the truth
        plant's step advances them)."""
        self._work = vehicle_step.work_buffer()

    @property
    def max_thrust_n(self) -> float:
        """A rotor's static thrust at u = 1 now [N] (the battery's voltage changes it)."""
        return self.buffer[_MAX_THRUST]

    @max_thrust_n.setter
    def max_thrust_n(self, value: float) -> None:
        self.buffer[_MAX_THRUST] = value

    @property
    def thrusts_n(self) -> FloatArray:
        """Thrust each rotor produces now [N], shape (6,) (a new array)."""
        return np.array(self.buffer[:N_ROTORS])

    @property
    def thrust_list_n(self) -> list[float]:
        """The same as a list of floats (a copy)."""
        return self.buffer[:N_ROTORS].tolist()

    @property
    def total_thrust_n(self) -> float:
        """Sum of the produced thrusts [N], added in rotor order (as numpy adds six)."""
        return sum(self.buffer[:N_ROTORS])

    def reset(self, thrusts_n: ArrayLike) -> None:
        """Set the produced thrusts [N] (the lag states)."""
        t = np.asarray(thrusts_n, dtype=np.float64)
        if t.shape != (N_ROTORS,) or not np.all(np.isfinite(t)) or np.any(t < 0.0):
            raise ValueError(f"rotor thrusts must be 6 finite values >= 0 N, got {thrusts_n!r}")
        self.buffer[:N_ROTORS] = array("d", t.tolist())

    def commanded_thrusts_n(self, commands: ArrayLike) -> FloatArray:
        """Static thrust [N] of commands u (clipped to [0, 1]), shape (6,)."""
        u = np.clip(np.asarray(commands, dtype=np.float64), 0.0, 1.0)
        return self.max_thrust_n * thrust_curve(u, self.thr_mdl_fac)

    def advance(self, commands: list[float]) -> None:
        """Advance the lag by one step with the commands (6 floats in [0, 1]) held."""
        _STEP.rotor_lag(self.buffer, commands, self._work)


@dataclass(frozen=True)
class MixerOutput:
    """Result of one allocation.

    Attributes
    ----------
    relative_thrusts : list of 6 float
        Each rotor's relative thrust in [0, 1] (before PX4's THR_MDL_FAC linearization).
    saturation_positive, saturation_negative : tuple of 3 bool
        Per torque axis (roll, pitch, yaw): the allocated torque fell short of a positive
        (negative) request; the rate controller stops integrating further that way.
    """

    relative_thrusts: list[float]
    saturation_positive: tuple[bool, bool, bool]
    saturation_negative: tuple[bool, bool, bool]


class SequentialDesaturationMixer:
    """PX4's multicopter allocation with sequential desaturation, airmode disabled.

    Order (PX4 ``mixAirmodeDisabled`` + ``mixYaw``): mix roll, pitch and thrust; desaturate
    by lowering thrust only (never raising it); then by scaling roll, then pitch; add yaw
    and desaturate it alone against an upper bound raised by 15 % (MINIMUM_YAW_MARGIN);
    finally lower thrust again if needed and clip to [0, 1]. Roll and pitch thus win over
    yaw and thrust.

    Parameters
    ----------
    geometry : RotorGeometry
        Rotor layout.
    max_thrust_per_rotor_n : float
        The full thrust of one rotor that the autopilot assumes (PX4's CA_ROTORx_CT role)
        [N]; it only scales ``torque_per_normalized_n_m``.
    """

    def __init__(self, geometry: RotorGeometry, max_thrust_per_rotor_n: float) -> None:
        wrench = geometry.wrench_matrix() * max_thrust_per_rotor_n
        mix = np.linalg.pinv(wrench)  # (6, 4): columns roll, pitch, yaw, thrust
        scale = np.empty(4)
        n_roll = max(int(np.count_nonzero(np.abs(mix[:, 0]) > _SMALL)), 1)
        n_pitch = max(int(np.count_nonzero(np.abs(mix[:, 1]) > _SMALL)), 1)
        roll_scale = math.sqrt(float(mix[:, 0] @ mix[:, 0]) / (n_roll / 2.0))
        pitch_scale = math.sqrt(float(mix[:, 1] @ mix[:, 1]) / (n_pitch / 2.0))
        scale[0] = scale[1] = max(roll_scale, pitch_scale)
        scale[2] = float(np.max(np.abs(mix[:, 2])))
        thrust = np.abs(mix[:, 3])
        scale[3] = float(thrust[thrust > 1e-12].mean())
        mix = mix / scale
        mix[np.abs(mix) < _SMALL] = 0.0
        self._mix = mix
        self._scale = scale
        self._constants = vehicle_step.mixer_constants(
            mix[:, 0].tolist(),
            mix[:, 1].tolist(),
            mix[:, 2].tolist(),
            mix[:, 3].tolist(),
            [a for i in range(3) for a in (scale[i] * wrench[i]).tolist()],
            1.0 + MINIMUM_YAW_MARGIN,
        )

    @property
    def mix_matrix(self) -> FloatArray:
        """Normalized allocation (6, 4): relative rotor thrusts = mix @ (roll, pitch, yaw,
        thrust), unsaturated."""
        return self._mix.copy()

    @property
    def torque_per_normalized_n_m(self) -> FloatArray:
        """Body torque (x, y, z) [N m] per unit normalized torque, unsaturated, at the
        believed maximum thrust."""
        return 1.0 / self._scale[:3]

    def mix(self, torque_normalized: Iterable[float], thrust_normalized: float) -> MixerOutput:
        """Allocate normalized torques (roll, pitch, yaw) and the relative collective thrust
        to six relative rotor thrusts in [0, 1]; see the class docstring for the priorities.
        """
        torque = tuple(float(c) for c in torque_normalized)
        u = array("d", [0.0] * N_ROTORS)
        flags = array("d", [0.0] * 6)
        _STEP.mix(self._constants, torque, float(thrust_normalized), u, flags)
        return MixerOutput(
            relative_thrusts=u.tolist(),
            saturation_positive=(flags[0] != 0.0, flags[1] != 0.0, flags[2] != 0.0),
            saturation_negative=(flags[3] != 0.0, flags[4] != 0.0, flags[5] != 0.0),
        )

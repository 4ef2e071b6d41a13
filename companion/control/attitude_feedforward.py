"""The roll/pitch offset that makes PX4's attitude loop produce the torque the model asks for.

SET_ATTITUDE_TARGET carries an attitude and a thrust, no torque: PX4 makes the roll and
pitch torque from its own attitude error. Against a slow disturbance torque ``d`` (an arm
swinging a payload: its reaction and the shift of the combined CoM) it therefore holds a
tilt error. With PX4's attitude P ``k_a`` (MC_ROLL_P, MC_PITCH_P), rate PI ``k_p``, ``k_i``
(MC_*RATE_P, _I, times MC_*RATE_K) and the allocation's body torque per unit normalized
torque ``T`` [N m], the quasi-static loop per axis is

    torque / T = k_p (k_a e - w) + I,    dI/dt = k_i (k_a e - w),

with ``e`` the attitude error [rad] and ``w`` the body rate [rad/s]. Measured on
``paper_sim_flight`` with PX4's loop in the plant (no offsets sent), this predicts the held
pitch error with a correlation of 0.99 (slope 0.92); without the ``w`` terms, 0.97 (the
held error 1.5 times the prediction). :class:`AttitudeLoopInverse` inverts it for ``w = 0``:
for the torque ``d`` the model needs on the tilt rows, it returns the offset ``e`` to add
to the commanded roll and pitch (``k_a e = (d / T - I) / k_p``), and integrates its own
copy of the part of PX4's integrator that the offset drives (``dI/dt = k_i k_a e``; PX4's
loop is linear there, so the rest of its integrator answers the rest of the error as
before). A copy started at zero converges to PX4's with the time constant ``k_p / k_i``
(0.75 s with PX4's defaults; the flight app steps the control from the ground on, so a
steady torque's offset has faded by the OFFBOARD handover). PX4's damping of the
reference's own rate (the ``w`` term) is left alone: compensated too, it made the lateral
loop oscillate at 0.8 Hz, growing, in a SITL pickup of 0.4 kg (125 Hz control on PX4's pose
stream). The torque is low-passed (``torque_filter_s``): it holds the body's and the arm's
inertia times the tilt reference's acceleration, a lead that, unfiltered, kept the arm and
the commanded pitch in a 10 Hz oscillation (+-0.5 rad) under the real PX4 in the loop.

Small angles: roll and pitch rows' generalized forces are taken as body torques (FLU x, y).
Pure (no I/O, no clock).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.config import AttitudeFeedforward

__all__ = ["AttitudeLoopInverse"]

FloatArray = NDArray[np.float64]


def _pair(values: ArrayLike, name: str) -> FloatArray:
    out = np.array(values, dtype=np.float64).reshape(-1)
    if out.shape != (2,) or not np.all(np.isfinite(out)):
        raise ValueError(f"{name} must be two finite values (roll, pitch)")
    return out


class AttitudeLoopInverse:
    """Roll/pitch offsets [rad] for the torque the model needs; see the module docstring.

    Parameters
    ----------
    attitude_p : array_like, shape (2,)
        PX4's attitude P of roll and pitch [rad/s per rad].
    rate_p, rate_i : array_like, shape (2,)
        PX4's rate P [per rad/s] and I [per rad] (normalized torque), times MC_*RATE_K.
    integrator_limit : array_like, shape (2,)
        PX4's rate integrator limit (MC_RR_INT_LIM, MC_PR_INT_LIM) [normalized torque].
    torque_per_normalized_n_m : array_like, shape (2,)
        Body torque of a normalized roll or pitch torque of 1 on this airframe [N m].
    max_offset_rad : float or array_like, shape (2,)
        Largest offset of each axis (roll, pitch), or of both [rad]; 0 sends none on
        that axis.
    torque_filter_s : float
        Time constant of the first-order low-pass on the torque [s].
    """

    def __init__(
        self,
        attitude_p: ArrayLike,
        rate_p: ArrayLike,
        rate_i: ArrayLike,
        integrator_limit: ArrayLike,
        torque_per_normalized_n_m: ArrayLike,
        max_offset_rad: ArrayLike,
        torque_filter_s: float,
    ) -> None:
        self.attitude_p = _pair(attitude_p, "attitude_p")
        self.rate_p = _pair(rate_p, "rate_p")
        self.rate_i = _pair(rate_i, "rate_i")
        self.integrator_limit = _pair(integrator_limit, "integrator_limit")
        self.torque_per_normalized_n_m = _pair(
            torque_per_normalized_n_m, "torque_per_normalized_n_m"
        )
        if not (
            np.all(self.attitude_p > 0.0)
            and np.all(self.rate_p > 0.0)
            and np.all(self.torque_per_normalized_n_m > 0.0)
        ):
            raise ValueError("attitude_p, rate_p and torque_per_normalized_n_m must be positive")
        if np.any(self.rate_i < 0.0) or np.any(self.integrator_limit < 0.0):
            raise ValueError("rate_i and integrator_limit must not be negative")
        self.max_offset_rad = _pair(np.broadcast_to(max_offset_rad, 2), "max_offset_rad")
        if np.any(self.max_offset_rad < 0.0):
            raise ValueError("max_offset_rad must not be negative")
        if not torque_filter_s > 0.0:
            raise ValueError("torque_filter_s must be positive")
        self.torque_filter_s = float(torque_filter_s)
        self.reset()

    @classmethod
    def from_config(cls, section: AttitudeFeedforward) -> AttitudeLoopInverse:
        """From ``[controller.attitude_feedforward]``."""
        return cls(
            section.attitude_p,
            section.rate_p,
            section.rate_i,
            section.rate_integrator_limit,
            section.torque_per_normalized_n_m,
            section.max_offset_rad,
            section.torque_filter_s,
        )

    def reset(self) -> None:
        """Start from no torque and an empty integrator copy."""
        self.torque_n_m = np.zeros(2)
        """The low-passed torque (roll, pitch) [N m]."""
        self.integral = np.zeros(2)
        """The copy of PX4's rate integrator driven by the offsets [normalized torque]."""

    def offset(self, dt_s: float, torque_n_m: FloatArray) -> FloatArray:
        """Offset (roll, pitch) [rad] for the body torque ``torque_n_m`` (FLU x, y) [N m]
        the rotors must make, low-passed; advances the filter and the integrator copy by
        ``dt_s`` [s]."""
        alpha = dt_s / (self.torque_filter_s + dt_s)
        self.torque_n_m = self.torque_n_m + alpha * (torque_n_m - self.torque_n_m)
        v = (self.torque_n_m / self.torque_per_normalized_n_m - self.integral) / self.rate_p
        e = np.clip(v / self.attitude_p, -self.max_offset_rad, self.max_offset_rad)
        v = self.attitude_p * e
        self.integral = np.clip(
            self.integral + self.rate_i * v * dt_s, -self.integrator_limit, self.integrator_limit
        )
        return e

"""The roll/pitch reference of the tilt mapping.

The desired q_d (the mission's, or the paper's in the offline runs) leaves roll and pitch to
eq. phid: they follow the controller's own translational force. :class:`TiltReference`
turns those raw commands into a smooth reference with the first two derivatives the
controller's feedforward needs.
"""

from __future__ import annotations

import math

from companion.control.laws import DesiredState
from companion.coordinates import PHI, THETA

__all__ = ["TiltReference"]


class TiltReference:
    """Critically damped third-order filter per axis: raw (phi_d, theta_d) -> smooth
    angle, rate and acceleration [rad, rad/s, rad/s^2].

    ``jerk = w^3 (raw - x) - 3 w^2 v - 3 w a`` (triple pole at -w), integrated with
    semi-implicit Euler at the caller's dt. Third order, not second: the raw command comes
    from the controller's own force, and the feedforward ``Mhat qd_ddot`` feeds the
    reference acceleration back into that force through the translation-attitude coupling
    of M. With a second-order filter the acceleration jumps with the command (gain w^2)
    and that loop oscillates at the control rate; through the jerk its one-step gain is
    only w^3 dt.

    Parameters
    ----------
    bandwidth_rad_s : float
        Pole w [rad/s]; long steps are sub-stepped (see :meth:`step`).
    """

    def __init__(self, bandwidth_rad_s: float) -> None:
        if bandwidth_rad_s <= 0.0:
            raise ValueError("bandwidth_rad_s must be positive")
        self.w = bandwidth_rad_s
        self.reset()

    def reset(self, roll_rad: float = 0.0, pitch_rad: float = 0.0) -> None:
        self.x = [roll_rad, pitch_rad]
        self.v = [0.0, 0.0]
        self.a = [0.0, 0.0]

    def step(self, dt: float, raw: tuple[float, float]) -> None:
        """Advance by dt [s] toward the raw command (roll, pitch) [rad].

        Steps longer than 0.1 / w (a late control cycle in flight) are split into equal
        sub-steps, so the explicit integration stays stable (w dt_sub <= 0.1).
        """
        w = self.w
        if not dt > 0.0:
            raise ValueError(f"dt must be positive, got {dt}")
        n = max(1, math.ceil(w * dt / 0.1 - 1e-9))
        h = dt / n
        w2, w3 = w * w, w * w * w
        for _ in range(n):
            for i in (0, 1):
                jerk = w3 * (raw[i] - self.x[i]) - 3.0 * w2 * self.v[i] - 3.0 * w * self.a[i]
                self.a[i] += h * jerk
                self.v[i] += h * self.a[i]
                self.x[i] += h * self.v[i]

    def apply(self, desired: DesiredState) -> DesiredState:
        """``desired`` with rows phi, theta replaced by this reference."""
        q, q_dot, q_ddot = desired.q.copy(), desired.q_dot.copy(), desired.q_ddot.copy()
        q[PHI], q[THETA] = self.x
        q_dot[PHI], q_dot[THETA] = self.v
        q_ddot[PHI], q_ddot[THETA] = self.a
        return DesiredState(q=q, q_dot=q_dot, q_ddot=q_ddot)

"""Is the autopilot's navigation estimate still one to fly on? (pure, vehicle time)

The companion closes its position loop on PX4's estimate (ODOMETRY). Two things about that
estimate matter besides its value:

- a **reset**: EKF2 moves its position (a GPS glitch, a new vision origin, a height
  reset) and counts it in ODOMETRY's ``reset_counter``. The jump is not motion: the state
  filter must start its position rows again from the new value, not differentiate it;
- **validity**: the estimate's variances (ODOMETRY pose and velocity covariance) growing
  past what a position loop can fly on (dead reckoning after the position aiding stopped),
  or the velocity reported invalid (NaN). If that lasts ``hold_s``, the flight app raises
  the ``navigation`` fault (:mod:`companion.mission.failsafe`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.link.telemetry import VehiclePose

__all__ = ["NavigationCheck", "NavigationWatch"]


@dataclass(frozen=True)
class NavigationCheck:
    """What one pose says about the navigation."""

    reset: bool
    """The estimator's reset counter changed since the previous pose."""
    problem: str | None
    """Why the estimate is not valid now; None when it is."""
    fault: str | None
    """The problem, once it has lasted ``hold_s`` (reported once per episode)."""


class NavigationWatch:
    """Watches reset counter and variances of the autopilot's pose estimate.

    Parameters
    ----------
    max_position_std_m
        Largest standard deviation of the position on any axis [m].
    max_velocity_std_m_s
        Largest standard deviation of the velocity on any axis [m/s].
    hold_s
        Time the estimate may stay invalid before it is a fault [s].
    """

    def __init__(
        self, max_position_std_m: float, max_velocity_std_m_s: float, hold_s: float
    ) -> None:
        if not (max_position_std_m > 0.0 and max_velocity_std_m_s > 0.0 and hold_s > 0.0):
            raise ValueError("limits and hold time must be positive")
        self.max_position_var = max_position_std_m**2
        self.max_velocity_var = max_velocity_std_m_s**2
        self.hold_s = hold_s
        self.resets = 0
        """Resets seen since the first pose."""
        self._counter: int | None = None
        self._invalid_since = math.nan
        self._reported = False

    def update(self, t_s: float, pose: VehiclePose) -> NavigationCheck:
        """Check the pose of vehicle time ``t_s`` [s]."""
        counter = pose.reset_counter
        reset = counter is not None and self._counter is not None and counter != self._counter
        if counter is not None:
            self._counter = counter
        self.resets += reset
        problem = self._problem(pose)
        fault = None
        if problem is None:
            self._invalid_since, self._reported = math.nan, False
        else:
            if math.isnan(self._invalid_since):
                self._invalid_since = t_s
            if not self._reported and t_s - self._invalid_since >= self.hold_s:
                self._reported = True
                fault = f"{problem} for {t_s - self._invalid_since:.1f} s"
        return NavigationCheck(reset, problem, fault)

    def _problem(self, pose: VehiclePose) -> str | None:
        if pose.velocity_enu_m_s is None:
            return "the autopilot reports no valid velocity"
        for what, var, limit in (
            ("position", pose.position_var_m2, self.max_position_var),
            ("velocity", pose.velocity_var_m2_s2, self.max_velocity_var),
        ):
            if var is not None and max(var) > limit:
                unit = "m" if what == "position" else "m/s"
                return (
                    f"{what} estimate std {math.sqrt(max(var)):.2f} {unit} above the "
                    f"{math.sqrt(limit):.2f} {unit} limit"
                )
        return None

"""Exceptions of :mod:`sitl.physics`: one tree rooted at :class:`PlantError`."""

from __future__ import annotations

import math

__all__ = ["EulerSingularityError", "PlantDivergedError", "PlantError", "PlantModeError"]


class PlantError(Exception):
    """Base class of every error raised by the truth plant."""


class EulerSingularityError(PlantError, ValueError):
    """The ZYX Euler angles are singular (pitch at +-90 deg): W(Phi) cannot be inverted.

    Raised when Euler-angle generalized forces are converted to body torques, or body
    rates to Euler rates, at |cos(theta)| below ``sitl.physics.frames.COS_THETA_MIN``.

    Attributes
    ----------
    theta_rad : float
        The pitch angle at which the conversion was attempted [rad].
    """

    def __init__(self, theta_rad: float) -> None:
        self.theta_rad = theta_rad
        super().__init__(
            f"pitch theta = {math.degrees(theta_rad):.6g} deg is at the ZYX Euler singularity "
            "(+-90 deg): generalized forces/rates conjugate to the Euler angles are undefined"
        )


class PlantModeError(PlantError):
    """A method of one plant mode (``ideal`` / ``underactuated``) was called in the other."""


class PlantDivergedError(PlantError, FloatingPointError):
    """The integrated state is no longer finite (an input or the dynamics blew up).

    Attributes
    ----------
    time_s : float
        Simulation time of the step that produced the non-finite state [s].
    """

    def __init__(self, time_s: float) -> None:
        self.time_s = time_s
        super().__init__(f"truth plant state became non-finite at t = {time_s:.6g} s")

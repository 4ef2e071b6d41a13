"""The paper's desired trajectory (section IV) for the offline runs."""

from __future__ import annotations

import math

import numpy as np

from companion.control.laws import DesiredState
from sitl.scenario import Trajectory

__all__ = ["PaperSinusoid"]


class PaperSinusoid:
    """The paper's desired trajectory (section IV), roll and pitch rows left at zero:

    x = ax cos(w t), y = ay cos(w t), z = z0, psi = psi0,
    eta_i = c_i + a_i sin(w t), with w = 2 pi / period.
    """

    def __init__(self, cfg: Trajectory) -> None:
        w = 2.0 * math.pi / cfg.period_s
        cos_amp = np.array([cfg.amplitude_x_m, cfg.amplitude_y_m, 0, 0, 0, 0, 0, 0.0])
        sin_amp = np.array([0, 0, 0, 0, 0, 0, cfg.eta1_amplitude_rad, cfg.eta2_amplitude_rad])
        offset = np.array(
            [0, 0, cfg.altitude_m, 0, 0, cfg.yaw_rad, cfg.eta1_center_rad, cfg.eta2_center_rad]
        )
        zero = np.zeros(8)
        # [q; q_dot; q_ddot] = basis @ [1, cos(w t), sin(w t)]
        self.basis = np.column_stack(
            [
                np.concatenate([offset, zero, zero]),
                np.concatenate([cos_amp, w * sin_amp, -w * w * cos_amp]),
                np.concatenate([sin_amp, -w * cos_amp, -w * w * sin_amp]),
            ]
        )
        self.w = w

    def __call__(self, t_s: float) -> DesiredState:
        """q_d, q_d_dot, q_d_ddot at time t [s]."""
        wt = self.w * t_s
        values = self.basis @ np.array((1.0, math.cos(wt), math.sin(wt)))
        return DesiredState(q=values[0:8], q_dot=values[8:16], q_ddot=values[16:24])

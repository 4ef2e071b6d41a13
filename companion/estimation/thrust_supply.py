"""The thrust scale s carried through the flight from its measured cause, the battery
(DESIGN.md section 4).

With the payload on, the translation rows see ``s T = (M + m2) a``: s and m2 cannot be told
apart after the grasp, so m2 is only as good as the model of s carried from the hover
before it. A brushless motor's thrust per command follows its supply voltage squared (the
command sets the duty cycle, the rotor speed goes with duty x V), so

    s(t) = k (V(t) / V_cal)^n,

with V the battery voltage the vehicle streams (low-passed), n the exponent (2 by the
physics), and k and V_cal fitted in the hover calibration before the grasp: k the mean of
``s_i (V_cal / V_i)^n`` over the calibration's still samples, V_cal their mean voltage.
A grasp's load step drops the voltage at once, and s with it; so does the charge drawn over
the flight. Without a voltage (a vehicle with no power module) s is held at k.

The uncertainty of s (relative): the standard error of k, its samples' correlation counted
(an AR(1) effective sample size, :func:`mean_and_error`), and the exponent's uncertainty
times the log of the voltage ratio: ``sd(s)/s = sqrt((sd(k)/k)^2 + (sd(n) ln(V/V_cal))^2)``.

:meth:`SupplyScale.before` and :meth:`SupplyScale.after` go around each estimator step
(they read and write only its ``calibrating``, ``thrust_scale``, ``compensation_scale``,
``scale_held`` and ``scale``); on the compiled control step the step itself runs
:meth:`~SupplyScale.before`'s voltage filter and hand-off of s, on the scale's state in its
buffer (:mod:`companion.control.compiled_step`), and only the fit stays here. Pure: no I/O,
no clock; times are the sum of the control periods handed in [s].
"""

from __future__ import annotations

import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from companion.estimation.estimator import Estimator

__all__ = ["SupplyScale", "mean_and_error"]

FloatArray = NDArray[np.float64]


def mean_and_error(x: FloatArray) -> tuple[float, float]:
    """The mean of the time-ordered samples ``x`` and its standard error, counted with the
    effective sample size of AR(1) residuals, n_eff = n (1 - r1) / (1 + r1) with r1 their
    lag-1 autocorrelation (n when r1 <= 0; Santer et al. 2000, J. Geophys. Res. 105(D6)),
    n_eff at least 2: the estimator's s is a smoothed signal whose successive samples are
    far from independent."""
    mean = float(x.mean())
    e = x - mean
    ee = float(e @ e)
    if ee == 0.0 or len(x) < 2:
        return mean, 0.0
    r1 = float(e[1:] @ e[:-1]) / ee
    n = len(x)
    n_eff = max(n * (1.0 - r1) / (1.0 + r1) if r1 > 0.0 else float(n), 2.0)
    return mean, math.sqrt(ee / (n - 1) / n_eff)


class SupplyScale:
    """s from the battery voltage (module docstring).

    Parameters
    ----------
    window_s : float
        The calibration's last seconds whose still samples fit k [s].
    exponent : float
        n: thrust per command goes with the voltage to this power [-].
    exponent_std : float
        Standard deviation of n [-].
    filter_s : float
        Time constant of the voltage's low-pass [s].
    still_m_s : float
        Samples are taken while the vehicle's speed is below this [m/s]: moving, the drag
        the model lacks biases s.
    """

    def __init__(
        self,
        window_s: float,
        exponent: float = 2.0,
        exponent_std: float = 0.5,
        filter_s: float = 0.3,
        still_m_s: float = 0.1,
    ) -> None:
        if not window_s > 0.0:
            raise ValueError(f"window_s must be > 0, got {window_s}")
        if not (exponent >= 0.0 and exponent_std >= 0.0 and filter_s >= 0.0):
            raise ValueError("need exponent >= 0, exponent_std >= 0 and filter_s >= 0")
        self.window_s = window_s
        self.exponent = exponent
        self.exponent_std = exponent_std
        self.filter_s = filter_s
        self.still_m_s = still_m_s
        self.level: float | None = None
        """k: s at the calibration's voltage [-] (None before a fit)."""
        self.level_std = 0.0
        """Standard error of k [-]."""
        self.calibration_v: float | None = None
        """V_cal: the mean filtered voltage of the fitted samples [V] (None: no voltage)."""
        self.voltage_v: float | None = None
        """The low-passed battery voltage now [V] (None before any)."""
        self._measured: float | None = None
        self._t_s = 0.0
        self._samples: deque[tuple[float, float, float]] = deque()

    def supply(self, voltage_v: float | None) -> None:
        """The latest measured battery voltage [V]; None or a non-positive value: unknown."""
        self._measured = voltage_v if voltage_v is not None and voltage_v > 0.0 else None

    def voltage_factor(self) -> float:
        """(V / V_cal)^n now [-]; 1 without a voltage."""
        if self.calibration_v is None or self.voltage_v is None:
            return 1.0
        return (self.voltage_v / self.calibration_v) ** self.exponent

    def scale(self) -> float | None:
        """s now, k (V / V_cal)^n [-]; None before a fit."""
        return None if self.level is None else self.level * self.voltage_factor()

    def relative_std(self) -> float | None:
        """sd(s) / s now [-]; None before a fit."""
        if self.level is None:
            return None
        log_ratio = (
            0.0
            if self.calibration_v is None or self.voltage_v is None
            else math.log(self.voltage_v / self.calibration_v)
        )
        return math.hypot(self.level_std / self.level, self.exponent_std * log_ratio)

    def before(self, dt: float, estimator: Estimator) -> None:
        """Before a step of ``dt`` [s]: filter the voltage; outside a calibration, fit k if
        one just ended, and hand the estimator s from the voltage (held: theta alone is
        learnt)."""
        measured = self._measured
        if measured is not None:
            v = self.voltage_v
            a = dt / (self.filter_s + dt)
            self.voltage_v = measured if v is None else v + a * (measured - v)
        scale = estimator.scale
        if scale is None or estimator.calibrating:
            return
        if self._samples:
            self.fit()
        s = self.scale()
        if s is not None:
            estimator.thrust_scale = estimator.compensation_scale = scale.clip(s)
            estimator.scale_held = True

    def after(self, dt: float, estimator: Estimator, velocity_m_s: FloatArray) -> None:
        """After a step of ``dt`` [s] at the vehicle's ``velocity_m_s`` (x, y, z first): in a
        calibration, record its estimate of s with the voltage if the vehicle is nearly
        still."""
        if not estimator.calibrating:
            return
        self._t_s += dt
        samples = self._samples
        vx, vy, vz = float(velocity_m_s[0]), float(velocity_m_s[1]), float(velocity_m_s[2])
        if math.sqrt(vx * vx + vy * vy + vz * vz) < self.still_m_s:
            v = math.nan if self.voltage_v is None else self.voltage_v
            samples.append((self._t_s, estimator.thrust_scale, v))
        while samples and samples[0][0] < self._t_s - self.window_s:
            samples.popleft()

    def fit(self) -> None:
        """Fit k and V_cal over the recorded window and start a new one. A window holding
        less than half of ``window_s`` is too short to tell: the fit before it (if any) is
        kept."""
        samples = self._samples
        if samples and samples[-1][0] - samples[0][0] >= 0.5 * self.window_s:
            s = np.array([sample[1] for sample in samples])
            v = np.array([sample[2] for sample in samples])
            if np.all(np.isfinite(v)):
                v_cal = float(v.mean())
                ratio = s * (v_cal / v) ** self.exponent
                self.calibration_v = v_cal
            else:
                ratio = s
                self.calibration_v = None
            self.level, self.level_std = mean_and_error(ratio)
        samples.clear()

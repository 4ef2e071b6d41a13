"""On-line estimators of the link-2 parameters theta = (m2, m3, m4) (paper section III-A).

Both estimators work on the regressor of :mod:`companion.model`,
``Y(q, q_dot, q_dot, q_ddot) [m2, m3, m4, 1]^T = M q_ddot + C q_dot + G = tau``, restricted
to the rows of q whose generalized force is known (in flight: the translational rows, from
the thrust model and measured attitude, and the joint rows, from servo current).

- :class:`PaperEstimator`: the paper's state observer (eq. estimator) and gradient update
  (eq. update), integrated with forward Euler at the control period.
- :class:`RlsEstimator`: recursive least squares with exponential forgetting on the same
  regression ``tau - Y[:, 3] = Y[:, :3] theta`` (beyond the paper).

Beyond the paper, both can estimate the vehicle's thrust scale s with theta
(:class:`ThrustScaleModel`): the force on the translational rows is then ``s`` times the
commanded one, which moves to the unknown side as a fourth column of the regressor,
``Y_theta theta - s f_cmd = -Y_4`` on x, y, z and ``Y_theta theta = tau - Y_4`` on the
joints; the joint rows, whose torque comes from the servos and not from the thrust, are
what separates m2 from s.

Beyond the paper, both project onto physically consistent values after every step
(:class:`ThetaBounds`), can be frozen (take-off, landing: tau is not what the model assumes
while touching the ground), resumed and reset (payload released), and publish an
:class:`Estimate` with an excitation measure and a confidence flag. Neither ever sees truth.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.model import ModelTerms

if TYPE_CHECKING:
    from companion.config import CompanionConfig

__all__ = [
    "JOINT_ROWS",
    "TRANSLATION_AND_JOINT_ROWS",
    "Estimate",
    "Estimator",
    "ExcitationMonitor",
    "PaperEstimator",
    "RlsEstimator",
    "Skip",
    "ThetaBounds",
    "ThrustScaleModel",
    "estimator_from_config",
]

FloatArray = NDArray[np.float64]

ALL_ROWS = (0, 1, 2, 3, 4, 5, 6, 7)
TRANSLATION_AND_JOINT_ROWS = (0, 1, 2, 6, 7)
"""Rows of q with a known generalized force in flight (x, y, z, eta1, eta2)."""
JOINT_ROWS = (6, 7)
"""Rows of the joints (eta1, eta2): the known force when PX4's position controller flies
the vehicle (its thrust is not the companion's)."""


class Skip(StrEnum):
    """Why an estimator step is skipped (theta held), passed instead of the applied force
    or found in it; :attr:`_Base.skipped` counts each."""

    NO_FORCE = "no_force"
    """The force applied over the last period is not known: PX4 flew its own thrust
    (take-off, hold, landing), or nothing had been commanded yet."""
    NO_SERVO_READ = "no_servo_read"
    """No servo torque read-back arrived since the last cycle (the arm task was still on
    the bus, or its read failed)."""
    LATE_CYCLE = "late_cycle"
    """The period was far longer than the control period the forward-Euler step is tuned
    for (a gap in the pose stream)."""
    NOT_FINITE = "not_finite"
    """The force or the regressor on the used rows is not finite (a corrupt read-back)."""
    WARMING_UP = "warming_up"
    """The delay line of ``estimator.acceleration_delay_s`` is not full yet (the first 2n
    cycles)."""


@dataclass(frozen=True)
class ThetaBounds:
    """Physically consistent set for theta = (m2 [kg], m3 [kg m], m4 [kg m^2]).

    m2 in [m2_min_kg, m2_max_kg]; lc = m3/m2 in [0, l2]; m3^2/m2 <= m4 <= m2 l2^2 (a mass
    distribution on [0, l2] of link 2). The set is convex; :meth:`project` clips in that
    order, which always lands inside it.
    """

    m2_min_kg: float
    m2_max_kg: float
    link2_length_m: float

    def __post_init__(self) -> None:
        if not 0.0 < self.m2_min_kg < self.m2_max_kg:
            raise ValueError("need 0 < m2_min_kg < m2_max_kg")
        if self.link2_length_m <= 0.0:
            raise ValueError("link2_length_m must be positive")

    def project(self, theta: ArrayLike) -> FloatArray:
        """The clipped copy of theta; raises FloatingPointError on NaN or infinity."""
        m2, m3, m4 = np.asarray(theta, dtype=float).tolist()
        return np.array(self.clip(m2, m3, m4))

    def clip(self, m2: float, m3: float, m4: float) -> tuple[float, float, float]:
        """:meth:`project` on the three parameters as floats."""
        if not (math.isfinite(m2) and math.isfinite(m3) and math.isfinite(m4)):
            raise FloatingPointError(f"non-finite parameter estimate {(m2, m3, m4)}")
        l2 = self.link2_length_m
        m2 = min(max(m2, self.m2_min_kg), self.m2_max_kg)
        m3 = min(max(m3, 0.0), m2 * l2)
        m4 = min(max(m4, m3 * m3 / m2), m2 * l2 * l2)
        return m2, m3, m4

    def contains(self, theta: Iterable[float], rel_tol: float = 1e-9) -> bool:
        """True if theta lies in the set (with a relative tolerance for rounding)."""
        m2, m3, m4 = (float(v) for v in theta)
        l2 = self.link2_length_m
        tol = 1.0 + rel_tol
        return bool(
            self.m2_min_kg / tol <= m2 <= self.m2_max_kg * tol
            and -rel_tol <= m3 <= m2 * l2 * tol
            and m3 * m3 / m2 / tol <= m4 <= m2 * l2 * l2 * tol
        )


@dataclass(frozen=True)
class ThrustScaleModel:
    """The thrust scale s as an unknown: true force = s x commanded force on x, y, z.

    Parameters
    ----------
    initial : float
        Initial (and after :meth:`_Base.reset_thrust_scale`) estimate of s [-].
    low, high : float
        Projection bounds of s [-].
    initial_std : float
        RLS: initial standard deviation of s, also the cap on its variance [-].
    drift_std_per_sqrt_s : float
        RLS: random-walk std of s per square root of a second [1/sqrt(s)].
    gamma : float
        Paper estimator: learning rate of s [-].
    """

    initial: float = 1.0
    low: float = 0.5
    high: float = 1.5
    initial_std: float = 0.1
    drift_std_per_sqrt_s: float = 0.0
    gamma: float = 1.0

    def __post_init__(self) -> None:
        if not 0.0 < self.low <= self.initial <= self.high:
            raise ValueError("need 0 < low <= initial <= high")
        if not (self.initial_std > 0.0 and self.drift_std_per_sqrt_s >= 0.0 and self.gamma > 0):
            raise ValueError("need initial_std > 0, drift_std_per_sqrt_s >= 0, gamma > 0")

    def clip(self, s: float) -> float:
        """s within [low, high]; raises FloatingPointError on NaN or infinity."""
        if not math.isfinite(s):
            raise FloatingPointError(f"non-finite thrust scale estimate {s}")
        return min(max(s, self.low), self.high)


@dataclass(frozen=True)
class Estimate:
    """What an estimator publishes each step."""

    theta: FloatArray
    """(m2 [kg], m3 [kg m], m4 [kg m^2])."""
    excitation: float
    """Smallest eigenvalue of the windowed, scaled information matrix (dimensionless);
    near zero when the recent motion cannot distinguish the parameters."""
    spread: float
    """Settling of the estimate over the monitor's window (dimensionless): the larger of
    (max - min) / mean of m2 and of lc = m3 / m2; infinite until the window is full."""
    confident: bool
    """Excitation above its threshold, spread below its threshold, and not frozen."""
    frozen: bool
    thrust_scale: float = 1.0
    """Estimated true over commanded thrust s [-] (1 when it is not estimated)."""

    @property
    def m2_kg(self) -> float:
        return float(self.theta[0])

    @property
    def lc_m(self) -> float:
        """Centre of mass of link 2 with payload, from joint 2 [m]."""
        return float(self.theta[1] / self.theta[0])


def _relative_range(values: deque[float]) -> float:
    """(max - min) / mean of positive samples."""
    low, high = min(values), max(values)
    return (high - low) / max(0.5 * (high + low), 1e-12)


class ExcitationMonitor:
    """Excitation and settling of an estimate over an exponential window.

    Information: ``I <- I + (dt/T)(S Y_theta^T W Y_theta S - I)`` with S = diag(scale) so the
    three parameters weigh alike, W = diag(1/row_scale^2); excitation = lambda_min(I).
    Spread: (max - min) / mean over the samples of the last T seconds, the larger of m2's
    and lc's, i.e. how steady the mass and the centre of mass have been over the window
    (infinite until the window is full). Both are
    held in :attr:`excitation` and :attr:`spread` between samples.

    Parameters
    ----------
    window_s : float
        Window time constant T [s].
    theta_scale : array_like, shape (3,)
        Typical magnitudes of (m2, m3, m4) (for example the bounds' maxima).
    row_scale : array_like, shape (n_rows,)
        Typical generalized-force magnitude of each used row (N or N m).
    excitation_min, spread_max : float
        Thresholds of the confidence flag.
    sample_period_s : float
        The window is sampled at most this often, and the smallest eigenvalue recomputed
        at most every 5 samples: both change on the scale of the window, and doing them
        every control step costs more than the estimator itself.
    """

    def __init__(
        self,
        window_s: float,
        theta_scale: ArrayLike,
        row_scale: ArrayLike,
        excitation_min: float,
        spread_max: float,
        sample_period_s: float = 0.01,
    ) -> None:
        self.window_s = window_s
        self.sample_period_s = sample_period_s
        self.weight = np.outer(
            1.0 / np.asarray(row_scale, dtype=float), np.asarray(theta_scale, dtype=float)
        )
        self.excitation_min = excitation_min
        self.spread_max = spread_max
        self._window_samples = max(2, round(window_s / sample_period_s))
        self.reset()

    def reset(self) -> None:
        self.info = np.zeros((3, 3))
        self._m2: deque[float] = deque(maxlen=self._window_samples)
        self._lc: deque[float] = deque(maxlen=self._window_samples)
        self.excitation = 0.0
        self.spread = float("inf")
        self._since_sample = float("inf")
        self._samples = 0

    def update(self, dt: float, y_theta: FloatArray, m2: float, lc: float) -> tuple[float, float]:
        """Add one step (sampled at most every ``sample_period_s``); returns (excitation,
        spread)."""
        self._since_sample += dt
        if self._since_sample < self.sample_period_s:
            return self.excitation, self.spread
        elapsed = dt if math.isinf(self._since_sample) else self._since_sample
        self._since_sample = 0.0
        a = min(elapsed / self.window_s, 1.0)
        scaled = y_theta * self.weight
        self.info += a * (scaled.T @ scaled - self.info)
        self._m2.append(m2)
        self._lc.append(lc)
        if len(self._m2) == self._window_samples:
            self.spread = max(_relative_range(self._m2), _relative_range(self._lc))
        self._samples += 1
        if self._samples % 5 == 0:
            self.excitation = float(np.linalg.eigvalsh(self.info)[0])
        return self.excitation, self.spread

    def confident(self) -> bool:
        return self.excitation >= self.excitation_min and self.spread <= self.spread_max


def _all_finite(values: FloatArray) -> bool:
    """True if values hold no NaN or infinity, read from their sum (finite values large
    enough for the sum to overflow are not forces or regressors either)."""
    return math.isfinite(values.sum())


class Estimator(Protocol):
    """What the flight cycle needs of an on-line payload estimator (paper section III-A, or
    RLS): theta = (m2 [kg], m3 [kg m], m4 [kg m^2]) advanced once per control period on
    the rows of q whose generalized force is known."""

    theta: FloatArray
    """Current estimate, inside the bounds."""
    frozen: bool
    """True while theta is held."""
    skipped: Counter[Skip]
    """Steps skipped while not frozen, by reason."""
    thrust_scale: float
    """Current estimate of the thrust scale s (1 when it is not estimated)."""
    scale: ThrustScaleModel | None
    """The thrust scale's model, or None: the commanded force is taken as exact."""
    scale_held: bool
    """True while s is held after a :meth:`reset`."""
    calibrating: bool
    """True while theta is held and s learnt (:meth:`calibrate`)."""
    compensation_scale: float
    """The last calibrated s, which a compensated mapping divides the force by."""

    @property
    def skipped_steps(self) -> int:
        """Steps skipped while not frozen, all reasons."""
        ...

    def freeze(self) -> None:
        """Hold theta."""
        ...

    def resume(self) -> None:
        """Continue estimating from the held theta."""
        ...

    def calibrate(self) -> None:
        """Hold theta and learn the thrust scale alone."""
        ...

    def reset(self, theta: ArrayLike) -> None:
        """Restart from theta."""
        ...

    def update(
        self,
        dt: float,
        terms: ModelTerms,
        q: FloatArray,
        q_dot: FloatArray,
        q_ddot: FloatArray,
        tau: FloatArray | Skip,
    ) -> Estimate:
        """Advance one control period of ``dt`` [s] (see :meth:`_Base.update`)."""
        ...


class _Base(ABC):
    """Shared policy: row selection, projection, freeze/resume/reset, publication."""

    def __init__(
        self,
        theta0: ArrayLike,
        bounds: ThetaBounds,
        monitor: ExcitationMonitor,
        rows: tuple[int, ...],
        scale: ThrustScaleModel | None = None,
    ) -> None:
        if not rows or sorted(set(rows)) != list(rows) or rows[0] < 0 or rows[-1] > 7:
            raise ValueError(f"rows must be increasing indices into q (0..7), got {rows}")
        self.rows = np.asarray(rows)
        contiguous = rows[-1] - rows[0] + 1 == len(rows)
        # A slice takes a view (no copy) of the rows of Y, q, q_dot and tau each step.
        self._select = slice(rows[0], rows[-1] + 1) if contiguous else self.rows
        self.bounds = bounds
        self.monitor = monitor
        self.frozen = False
        self.skipped: Counter[Skip] = Counter()
        """Skipped steps by reason."""
        self.theta = bounds.project(np.asarray(theta0, dtype=float))
        self.scale = scale
        """The thrust scale model, or None: the commanded force is taken as exact."""
        self.thrust_scale = 1.0 if scale is None else scale.initial
        self.scale_held = False
        """True while s is held and theta alone is learnt: from a :meth:`reset` until the
        monitor is confident again."""
        self.calibrating = False
        """True while theta is held and s alone is learnt (:meth:`calibrate`)."""
        self.compensation_scale = self.thrust_scale
        """The s that ``[estimator.thrust_scale] compensate`` divides the force by: the last
        one calibrated (the initial one before any calibration; carried on with the battery's
        voltage by :class:`~companion.estimation.thrust_supply.SupplyScale` where one is
        fitted). Not the running estimate: with theta and
        s learnt together, dividing by it closed a loop that ran s to its bound (offline,
        ``configs/sitl_pickup.toml`` from the start: the thrust fell to 0)."""
        # The used rows whose force is the thrust's (x, y, z).
        self._thrust_rows = self.rows < 3
        if scale is not None and not self._thrust_rows.any():
            raise ValueError("a thrust scale needs at least one of the rows x, y, z")

    @property
    def skipped_steps(self) -> int:
        """Steps skipped while not frozen, all reasons."""
        return self.skipped.total()

    def freeze(self) -> None:
        """Hold theta and s (for example on the ground, where tau is not the model's)."""
        self.frozen = True
        self.calibrating = False

    def resume(self) -> None:
        """Continue estimating from the held theta."""
        self.frozen = False
        self.calibrating = False
        self._restart()

    def calibrate(self) -> None:
        """Hold theta and learn the thrust scale alone: the hover calibration against a
        known arm (the empty one before a grasp), as PX4's hover thrust estimator does.
        Without a thrust scale, or where the estimator cannot hold theta alone, it holds
        both (:meth:`freeze`)."""
        self.freeze()

    def reset(self, theta: ArrayLike) -> None:
        """Restart from theta (for example the empty-arm values after a release). The
        thrust scale, the vehicle's and not the payload's, is kept with its confidence:
        learnt with the known empty arm before a grasp, it is a hover calibration. It is
        held (:attr:`scale_held`) until the monitor is confident in theta again: with s
        free, a grasp's transient and the payload's weight went into s (offline pickup at
        8 s, ``paper_sim_flight``, noise: s 20 % low and m2 at -65 % 2 s after the grasp,
        against -5 % with s held)."""
        self.theta = self.bounds.project(np.asarray(theta, dtype=float))
        self.monitor.reset()
        self.calibrating = False
        self.scale_held = self.scale is not None
        self._restart()

    def reset_thrust_scale(self) -> None:
        """Restart the thrust scale from its initial value (another vehicle or battery)."""
        if self.scale is not None:
            self.thrust_scale = self.compensation_scale = self.scale.initial
            self._restart_scale()

    @abstractmethod
    def _restart_scale(self) -> None:
        """Reset internal states of the thrust scale's estimate other than its value."""

    @abstractmethod
    def _restart(self) -> None:
        """Reset internal states other than theta."""

    def _publish(self, dt: float, y_theta: FloatArray) -> Estimate:
        m2 = float(self.theta[0])
        excitation, spread = self.monitor.update(dt, y_theta, m2, float(self.theta[1]) / m2)
        confident = (not self.frozen) and self.monitor.confident()
        if confident:
            self.scale_held = False
        return Estimate(
            theta=self.theta.copy(),
            excitation=excitation,
            spread=spread,
            confident=confident,
            frozen=self.frozen,
            thrust_scale=self.thrust_scale,
        )

    def update(
        self,
        dt: float,
        terms: ModelTerms,
        q: FloatArray,
        q_dot: FloatArray,
        q_ddot: FloatArray,
        tau: FloatArray | Skip,
    ) -> Estimate:
        """Advance one control period.

        Parameters
        ----------
        dt : float
            Control period [s].
        terms : ModelTerms
            ``model.terms(q, q_dot)`` at this step (shared with the controller).
        q, q_dot, q_ddot : ndarray, shape (8,)
            Measured/filtered state and derivatives (m, rad and their rates).
        tau : ndarray, shape (8,), or Skip
            Generalized force applied over the last period (only ``rows`` are read), or
            why it is not known. With a thrust scale, x, y, z are the commanded force
            (the thrust model's), of which s times acted. A skipped step holds theta and
            is counted in :attr:`skipped` by reason; so is a force or regressor that is
            not finite.
        """
        select = self._select
        y = terms.regressor(q_dot, q_ddot)[select]
        if not self.frozen:
            if isinstance(tau, Skip):
                self.skipped[tau] += 1
            elif _all_finite(tau[select]) and _all_finite(y):
                self._step(dt, y, q[select], q_dot[select], tau[select])
            else:
                self.skipped[Skip.NOT_FINITE] += 1
            if self.calibrating:
                self.compensation_scale = self.thrust_scale
        return self._publish(dt, y[:, :3])

    @abstractmethod
    def _step(self, dt, y, q, q_dot, tau) -> None:
        """Update ``self.theta`` from the used rows of Y, q, q_dot and tau."""


class PaperEstimator(_Base):
    """The paper's estimator (eqs. estimator, update) on the selected rows.

    Observer: ``C* qhat_dot = U - sum_i mhat_i Y_i + C* q_dot + K* (q - qhat)`` with
    ``U = tau - Y_4`` (the known part), and update ``mhat_i_dot = gamma_i e^T Y_i``,
    ``e = qhat - q``; forward Euler at the control period, then projection.

    Parameters
    ----------
    gamma : array_like, shape (3,)
        Learning rates of m2, m3, m4.
    c_star, k_star : array_like, shape (8,)
        Diagonals of C* and K* (only ``rows`` are used).
    qhat_dot0 : array_like, shape (8,)
        Initial qhat_dot. The observer is first order, so after the start qhat_dot is set by
        the observer equation; qhat_dot0 is the rate of the first step from qhat = q, which
        makes e != 0 when qhat_dot0 != q_dot (the paper's condition for estimation).
    scale : ThrustScaleModel, optional
        Estimate the thrust scale s too: its column of the regressor is ``-f_cmd`` (the
        commanded force on x, y, z), so ``s_dot = -gamma_s e^T f_cmd``, and the observer
        uses ``s f_cmd`` as the force on those rows.
    """

    def __init__(
        self,
        theta0: ArrayLike,
        bounds: ThetaBounds,
        monitor: ExcitationMonitor,
        gamma: ArrayLike,
        c_star: ArrayLike,
        k_star: ArrayLike,
        qhat_dot0: ArrayLike,
        rows: tuple[int, ...] = ALL_ROWS,
        scale: ThrustScaleModel | None = None,
    ) -> None:
        super().__init__(theta0, bounds, monitor, rows, scale)
        self.gamma = np.asarray(gamma, dtype=float)
        self._gamma = tuple(self.gamma.tolist())
        self.c_star = np.asarray(c_star, dtype=float)[self.rows]
        self.k_star = np.asarray(k_star, dtype=float)[self.rows]
        self.qhat_dot0 = np.asarray(qhat_dot0, dtype=float)[self.rows]
        yaw = np.flatnonzero(self.rows == 5)
        self.yaw = int(yaw[0]) if yaw.size else None
        self.qhat: FloatArray | None = None
        # Forward Euler factors dt C*^-1 and 1 - dt C*^-1 K*, and the dt they are for.
        self._euler_dt = math.nan
        self._dt_over_c = self._e_gain = np.zeros_like(self.c_star)

    def _restart(self) -> None:
        self.qhat = None

    def _restart_scale(self) -> None:
        """The paper's update has no state of s besides its value."""

    def _step(self, dt, y, q, q_dot, tau) -> None:
        if self.qhat is None:
            self.qhat = q + dt * self.qhat_dot0
            return
        e = self.qhat - q
        if self.yaw is not None:
            e[self.yaw] = (float(e[self.yaw]) + math.pi) % (2.0 * math.pi) - math.pi
        # theta first, with the error of this step (eq. update), as floats.
        m2, m3, m4 = self.theta.tolist()
        g2, g3, g4 = self._gamma
        ey2, ey3, ey4, _ = (e @ y).tolist()
        m2, m3, m4 = self.bounds.clip(m2 + dt * g2 * ey2, m3 + dt * g3 * ey3, m4 + dt * g4 * ey4)
        xi = np.array((m2, m3, m4, 1.0))
        self.theta = xi[:3]
        if self.scale is not None:
            thrust = self._thrust_rows
            if not self.scale_held:
                force = np.where(thrust, tau, 0.0)
                ef = float(e @ force)
                self.thrust_scale = self.scale.clip(self.thrust_scale - dt * self.scale.gamma * ef)
            tau = np.where(thrust, self.thrust_scale * tau, tau)
        # Then the observer (eq. estimator) with this theta, forward Euler from qhat = q + e:
        # qhat + dt C*^-1 (tau - Y xi + C* q_dot - K* e)
        #   = q + dt q_dot + (1 - dt C*^-1 K*) e + dt C*^-1 (tau - Y xi),
        # with the two diagonal factors computed again only when dt changes.
        if dt != self._euler_dt:
            self._euler_dt = dt
            self._dt_over_c = dt / self.c_star
            self._e_gain = 1.0 - self._dt_over_c * self.k_star
        self.qhat = q + dt * q_dot + self._e_gain * e + self._dt_over_c * (tau - y @ xi)


class RlsEstimator(_Base):
    """Recursive least squares with exponential forgetting on ``tau - Y_4 = Y_theta theta``.

    Each step fuses the used rows as one vector measurement with per-row noise std
    ``row_noise`` (N or N m):
    ``K = P H^T (H P H^T + R / lambda)^-1``, ``theta += K (z - H theta)``,
    ``P = (P - K H P) / lambda``, then projection. To avoid covariance wind-up while the
    motion is not exciting, P is bounded by its initial value ``p0`` (trace-limited).

    Parameters
    ----------
    forgetting : float
        lambda in (0, 1]; memory about ``dt / (1 - lambda)`` seconds.
    p0 : array_like, shape (3,)
        Initial variances of (m2, m3, m4), also the cap on P's trace.
    row_noise : array_like, shape (8,)
        Noise std of each row's generalized-force residual.
    com_from_joints : bool
        The x, y, z rows learn m2 (and s) only: their m3 and m4 columns move to the known
        side at the current theta, so m3 and m4 come from the joint rows.
    scale : ThrustScaleModel, optional
        Estimate the thrust scale s too, as a fourth state (x = (theta, s),
        ``H = [Y_theta, -f_cmd]``, ``z = -Y_4`` on x, y, z and ``tau - Y_4`` on the joints).
        P is then 4 x 4; the variance of s grows by ``drift_std_per_sqrt_s^2 dt`` each step
        (a random walk: battery sag) and is capped at ``initial_std^2``, theta's block at
        ``p0``'s trace as before. While :attr:`scale_held`, s takes no gain and only its
        variance grows (drift and forgetting); while :attr:`calibrating`, theta's block and
        its covariance with s are zero, so that s alone is learnt.
    """

    def __init__(
        self,
        theta0: ArrayLike,
        bounds: ThetaBounds,
        monitor: ExcitationMonitor,
        forgetting: float,
        p0: ArrayLike,
        row_noise: ArrayLike,
        rows: tuple[int, ...] = ALL_ROWS,
        scale: ThrustScaleModel | None = None,
        com_from_joints: bool = False,
    ) -> None:
        super().__init__(theta0, bounds, monitor, rows, scale)
        self.com_from_joints = com_from_joints and bool(self._thrust_rows.any())
        if not 0.0 < forgetting <= 1.0:
            raise ValueError("forgetting must lie in (0, 1]")
        self.forgetting = forgetting
        self.p0 = np.diag(np.asarray(p0, dtype=float))
        self.p_trace_max = float(np.trace(self.p0))
        self.r = np.diag(np.asarray(row_noise, dtype=float)[self.rows] ** 2)
        self._r_forgotten = self.r / forgetting
        self.p = self.p0.copy()
        if scale is not None:
            self.s_var_max = scale.initial_std**2
            self.p_s = np.zeros(3)
            """Covariance of theta with s."""
            self.var_s = self.s_var_max
            """Variance of s."""

    def _restart(self) -> None:
        """theta's covariance back to p0, uncorrelated with s (whose variance is kept)."""
        self.p = self.p0.copy()
        if self.scale is not None:
            self.p_s = np.zeros(3)

    def _restart_scale(self) -> None:
        self.p_s = np.zeros(3)
        self.var_s = self.s_var_max

    def calibrate(self) -> None:
        if self.scale is None:
            self.freeze()
            return
        self.frozen = False
        self.scale_held = False
        self.calibrating = True
        self.p = np.zeros((3, 3))
        self.p_s = np.zeros(3)

    @property
    def std(self) -> FloatArray:
        """Standard deviations of (m2, m3, m4) from the covariance."""
        return np.sqrt(np.diag(self.p))

    def _mass_only(self, y: FloatArray) -> FloatArray:
        """Y with the m3, m4 columns of x, y, z moved into the known column at theta."""
        y = y.copy()
        t = self._thrust_rows
        y[t, 3] += y[t, 1] * self.theta[1] + y[t, 2] * self.theta[2]
        y[t, 1:3] = 0.0
        return y

    def _step(self, dt, y, q, q_dot, tau) -> None:
        if self.com_from_joints:
            y = self._mass_only(y)
        if self.scale is not None:
            self._step_with_scale(dt, y, tau)
            return
        h = y[:, :3]
        z = tau - y[:, 3]
        ph = self.p @ h.T
        s = h @ ph + self._r_forgotten
        gain = np.linalg.solve(s, ph.T).T
        self.theta = self.bounds.project(self.theta + gain @ (z - h @ self.theta))
        p = (self.p - gain @ ph.T) / self.forgetting
        p = 0.5 * (p + p.T)
        trace = p[0, 0] + p[1, 1] + p[2, 2]
        if trace > self.p_trace_max:
            p *= self.p_trace_max / trace
        self.p = p

    def _step_with_scale(self, dt: float, y: FloatArray, tau: FloatArray) -> None:
        """The RLS step on x = (theta, s): the regressor gains the column -f_cmd."""
        assert self.scale is not None
        thrust = self._thrust_rows
        force = np.where(thrust, tau, 0.0)
        h = np.column_stack((y[:, :3], -force))
        z = np.where(thrust, 0.0, tau) - y[:, 3]
        p = np.empty((4, 4))
        p[:3, :3] = self.p
        p[:3, 3] = p[3, :3] = self.p_s
        var_s = self.var_s + self.scale.drift_std_per_sqrt_s**2 * dt
        p[3, 3] = 0.0 if self.scale_held else var_s
        x = np.append(self.theta, self.thrust_scale)
        ph = p @ h.T
        gain = np.linalg.solve(h @ ph + self._r_forgotten, ph.T).T
        x = x + gain @ (z - h @ x)
        self.theta = self.bounds.project(x[:3])
        self.thrust_scale = self.scale.clip(float(x[3]))
        p = (p - gain @ ph.T) / self.forgetting
        p = 0.5 * (p + p.T)
        # Caps as congruences D P D (D diagonal), which keep P positive semi-definite.
        d = np.ones(4)
        trace = p[0, 0] + p[1, 1] + p[2, 2]
        if trace > self.p_trace_max:
            d[:3] = math.sqrt(self.p_trace_max / trace)
        if p[3, 3] > self.s_var_max:
            d[3] = math.sqrt(self.s_var_max / p[3, 3])
        p *= np.outer(d, d)
        self.p = p[:3, :3].copy()
        self.p_s = p[:3, 3].copy()
        held = min(var_s / self.forgetting, self.s_var_max)
        self.var_s = held if self.scale_held else float(p[3, 3])


def estimator_from_config(config: CompanionConfig, kind: str, rows: tuple[int, ...]) -> Estimator:
    """The configuration's estimator of ``kind`` (``"paper"`` or ``"rls"``) on ``rows``, with its
    bounds, confidence monitor and gains from the ``[estimator]`` section; with its thrust
    scale if ``[estimator.thrust_scale]`` is set and a row of x, y, z is used."""
    est = config.estimator
    bounds = ThetaBounds(est.m2_bounds_kg[0], est.m2_bounds_kg[1], config.arm.link2.length_m)
    m2_max, l2 = est.m2_bounds_kg[1], config.arm.link2.length_m
    monitor = ExcitationMonitor(
        window_s=est.confidence.window_s,
        theta_scale=(m2_max, m2_max * l2, m2_max * l2 * l2),
        row_scale=np.asarray(est.rls.row_noise)[list(rows)] * 10.0,
        excitation_min=est.confidence.excitation_min,
        spread_max=est.confidence.spread_max,
    )
    theta0 = est.initial_theta.as_tuple()
    ts = est.thrust_scale
    scale = None
    if ts is not None and any(r < 3 for r in rows):
        scale = ThrustScaleModel(
            initial=ts.initial,
            low=ts.bounds[0],
            high=ts.bounds[1],
            initial_std=ts.initial_std,
            drift_std_per_sqrt_s=ts.drift_std_per_sqrt_s,
            gamma=ts.gamma,
        )
    if kind == "paper":
        return PaperEstimator(
            theta0,
            bounds,
            monitor,
            est.gamma,
            est.c_star,
            est.k_star,
            est.initial_qhat_dot,
            rows,
            scale,
        )
    return RlsEstimator(
        theta0,
        bounds,
        monitor,
        forgetting=est.rls.forgetting,
        p0=np.square(est.rls.initial_std),
        row_noise=est.rls.row_noise,
        rows=rows,
        scale=scale,
        com_from_joints=est.rls.com_from_joints,
    )

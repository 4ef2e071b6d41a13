"""State filtering: q, q_dot, q_ddot from noisy, irregular, delayed measurements of q.

The estimator (paper eq. estimator and update) and the controller (eq. tau2) need q,
q_dot and q_ddot. In flight, and in every noisy simulation, they come from this filter,
which only ever sees measurements of q (and optionally of q_dot, e.g. body rates turned
into Euler rates by the caller) -- never truth derivatives.

Model
-----
Each row k of q is an independent constant-acceleration (white-jerk) Kalman filter with
state ``[q_k, q_dot_k, q_ddot_k]``::

    F(dt) = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]]
    Q(dt) = s_k * [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]]

with ``s_k`` the jerk power spectral density of row k (``jerk_psd``; [m^2/s^5] for rows
0-2, [rad^2/s^5] for rows 3-7), ``Q`` from :func:`filterpy.common.Q_continuous_white_noise`.
Constant acceleration is the smallest model that has q_ddot as a state. It was chosen over
constant jerk (white snap, four states) on single-row tests with 1 mm noise at 100 Hz, each
model with its best jerk/snap PSD: on the paper's slow trajectory (0.5 cos(pi t / 5))
constant jerk is better (q_ddot RMS error 0.012 against 0.023 m/s^2), but on
piecewise-constant accelerations (a new level every 0.5 s) constant acceleration is
(0.26 against 0.31 m/s^2), and on 3-7 rad/s motion too (0.15 against 0.17 m/s^2). In
closed loop, accelerations jump with controller corrections, gusts and payload pickup,
which is the second and third case; the smaller model is also cheaper.

Implementation
--------------
The equations are filterpy's ``KalmanFilter.predict`` / ``update`` (tests/test_filters.py
checks the result against a bank of :class:`filterpy.kalman.KalmanFilter` objects), run on
all rows at once. Running filterpy itself was measured too slow for the <= 50 us budget
of a whole control step (filters + estimator + controller): a bank of eight
``KalmanFilter(3, 1)`` costs about 320 us per predict + update and one block-diagonal
``KalmanFilter(24, 8)`` about 55-100 us (benchmarks/bench_filters.py, development machine).
Here the per-row states, covariances and constants are stacked column by column (see the
layout notes below), so a predict is a single (17 x 17) @ (17 x n) product (F and Q cached
per dt) and an update is one (25 x 17) @ (17 x n) product plus three element-wise
operations; the covariance update is ``P <- P - K (P h)^T`` (filterpy uses the Joseph
form, equal in exact arithmetic; a test checks that P stays symmetric positive definite).
Measured on the development machine (median / p99, us): predict 1.5 / 3, estimate
3.5 / 6.5, predict + update 12 / 25 whether all rows or a subset are measured; a 1 kHz
control step with 100 Hz motion capture, 100 Hz encoders and 250 Hz gyro rates costs
7 / 30 (most steps only predict and read the estimate). Where the compiled twin of
:mod:`companion.control.control_step` is built, the update's product and element-wise
steps run there in one call (``control_step.fuse``, the same operations as
:meth:`StateFilter._fuse`, which stays the reference; tests/test_compiled_step.py compares
them call by call): an update of all rows costs 3-5 us instead of 13-16
(``benchmarks/bench_filters.py`` on a loaded 2-core machine: predict + update 5.5 us
median); so does the predict's product (``control_step.predict``, a plain loop: OpenBLAS's
call for a 17 x 17 by 17 x 8 product cost 7 us inside the offline simulator). The common
update (default variance, every row started) is one compiled call, ``control_step.update``:
it places the measurement and the variance row and builds G itself, bit for bit as the
numpy steps around ``control_step.fuse`` do (the joints' ages are continuous, so their G
was never in the cache; in flight, after the idle wait between poses, each numpy call of
the glue cost 3-5 us).

Angles
------
Rows in ``wrap_rows`` (default the Euler angles phi, theta, psi) have their position
innovations wrapped to [-pi, pi), so a yaw measurement of -3.14 rad against an estimate of
+3.14 rad is a small correction. Internally the angle is kept continuous (unwrapped),
which keeps the prediction linear across +-pi; :attr:`StateFilter.estimate` reports it
wrapped to [-pi, pi).

Latency
-------
A measurement taken ``latency_s`` before the current filter time is fused with the
measurement row ``h = e^T F(-latency_s)`` (``[1, -L, L^2/2]`` for a position, ``[0, 1, -L]``
for a rate): it is compared with the current estimate propagated back to when it was
taken, and the correction is applied to the current state. This is exact except for the
process noise inside the latency window, which is ignored (for jerk PSD s it would add
about s L^5 / 20 to the position variance, 1.6e-10 s m^2 for L = 20 ms: negligible against
a 1 mm sensor). The same mechanism places a measurement taken between two control steps:
pass its age at the time of the update. No fixed-lag buffer or re-filtering is needed.

Initialisation
--------------
A row is initialised by its first position measurement: ``q = z``, ``q_dot = q_ddot = 0``,
covariance ``diag(std^2, initial_velocity_std^2, initial_acceleration_std^2)``; until then
velocity measurements of that row are ignored and :attr:`StateFilter.estimate` raises.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_continuous_white_noise
from numpy.typing import ArrayLike, NDArray

from companion.control.native import native_module
from companion.coordinates import N_Q

__all__ = [
    "DEFAULT_JERK_PSD",
    "FilterNotReadyError",
    "FilteredState",
    "StateFilter",
    "transition_matrix",
]

FloatArray = NDArray[np.float64]


DEFAULT_JERK_PSD = (0.1, 0.1, 0.1, 1.0, 1.0, 1.0, 1.0, 1.0)
"""Default jerk power spectral density per row of q: [m^2/s^5] for x, y, z, [rad^2/s^5]
for phi, theta, psi, eta1, eta2. See :class:`StateFilter` for how it was chosen."""

_CACHE_SIZE = 32
"""Entries kept per cache (transition matrices per dt, measurement rows per latency)."""

_TWO_PI = 2.0 * math.pi
_EULER_ROWS = (3, 4, 5)
"""The rows of q's ZYX Euler angles (phi, theta, psi), the default angle rows."""


class FilterNotReadyError(RuntimeError):
    """The estimate was read before every row had its first position measurement."""


@dataclass(frozen=True, slots=True)
class FilteredState:
    """Filtered generalized coordinates and their derivatives (arrays are read-only).

    Rows follow q = [x, y, z, phi, theta, psi, eta1, eta2] (DESIGN.md section 2).
    """

    q: FloatArray
    """Shape (n,): position [m] world ENU, Euler angles ZYX [rad] in [-pi, pi) (rows in
    ``wrap_rows``), joint angles [rad]."""
    q_dot: FloatArray
    """Shape (n,): time derivative of q [m/s, rad/s] (Euler rates, not body rates)."""
    q_ddot: FloatArray
    """Shape (n,): second time derivative of q [m/s^2, rad/s^2]."""


def _per_row(value: ArrayLike, n: int, name: str, *, positive: bool = False) -> FloatArray:
    try:
        a = np.broadcast_to(np.asarray(value, dtype=np.float64), (n,)).copy()
    except ValueError:
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {value!r}") from None
    bad = a <= 0.0 if positive else a < 0.0
    if not np.all(np.isfinite(a)) or np.any(bad):
        limit = "> 0" if positive else ">= 0"
        raise ValueError(f"{name} must be finite and {limit} per row, got {value!r}")
    return a


def transition_matrix(dt_s: float) -> FloatArray:
    """Constant-acceleration transition matrix F(dt) of one row, shape (3, 3).

    Parameters
    ----------
    dt_s : float
        Time step [s]; negative values propagate backwards.
    """
    return np.array([[1.0, dt_s, 0.5 * dt_s * dt_s], [0.0, 1.0, dt_s], [0.0, 0.0, 1.0]])


# Layout of the stacked state X, shape (17, n). Column k holds row k of q:
#   X[4 i, k]          x_i, the i-th derivative (i = 0..2)
#   X[4 i + 1 + j, k]  P_ij (i, j = 0..2)
#   X[12, k]           jerk PSD of the row (constant)
#   X[13, k]           the measurement being fused (scratch)
#   X[14, k], X[15, k] default position / rate measurement variance R (constant)
#   X[16, k]           R of the measurement being fused when not the default (scratch)
# so that one (17 x 17) product applies F and adds Q, and one (25 x 17) product yields
# everything a scalar-per-row update needs (see StateFilter._fuse). Every update runs on
# all columns: a row that is not measured gets R = _R_UNMEASURED, hence K ~ 1e-150 P h
# (below the float resolution of any state: no change), which is cheaper than gathering
# and scattering a subset of columns. (Not inf: 0 * inf would be NaN in the products.)
_N_STACK = 17
_X_ROWS = slice(0, 12, 4)
"""Stacked indices of q, q_dot, q_ddot."""
_P_DIAG = [1, 6, 11]
"""Stacked indices of P_00, P_11, P_22."""
_PSD, _Z, _R_POS, _R_VEL, _R_CALL = 12, 13, 14, 15, 16
_R_UNMEASURED = 1e150
"""Measurement variance standing for 'not measured' (see the layout notes)."""


@dataclass(frozen=True)
class _Selection:
    """Measured rows of one update call (cached per ``rows`` argument)."""

    idx: NDArray[np.intp]
    """The measured rows, in the order of the measurement vector."""
    rows: tuple[int, ...]
    """``idx`` as a tuple (the compiled update's argument)."""
    columns: slice | NDArray[np.intp]
    """``idx`` as a slice when the rows are contiguous and increasing (faster)."""
    all_rows: bool
    """True when every row is measured, in order."""
    mask: NDArray[np.bool_]
    """Shape (n,): True on measured rows."""
    wrap: tuple[int, ...]
    """Measured rows that are angles."""
    default_var: tuple[FloatArray, FloatArray]
    """Shape (n,) each: default position / rate variance on measured rows,
    ``_R_UNMEASURED`` elsewhere."""


def _propagate(A: FloatArray, X: FloatArray, X_next: FloatArray) -> None:
    """X_next = A X, the predict's product (numpy, the reference of
    ``control_step.predict``)."""
    np.dot(A, X, out=X_next)


def _wrap_scalar(a: float) -> float:
    w = (a + math.pi) % _TWO_PI - math.pi
    return w - _TWO_PI if w >= math.pi else w  # (a + pi) % 2 pi can round up to 2 pi


class StateFilter:
    """Kalman filters for q, q_dot, q_ddot, one constant-acceleration filter per row.

    Call :meth:`predict` once per control step with the step's dt (this brings the
    filter to the current time), then :meth:`update_position` / :meth:`update_velocity`
    for each measurement that arrived, with its age at that time as ``latency_s``, then
    read :attr:`estimate`. The filter has no clock: time is the sum of the dts.

    Parameters
    ----------
    n : int
        Number of rows (8 for q).
    jerk_psd : float or array_like, shape (n,)
        Process noise: jerk power spectral density per row [m^2/s^5 or rad^2/s^5].
        Larger values follow faster changes of acceleration and pass more noise: with
        measurement noise sigma every T seconds the filter's bandwidth is about
        ``(jerk_psd / (sigma^2 T))^(1/6)`` rad/s. The defaults
        (:data:`DEFAULT_JERK_PSD`) give about 15 rad/s for translation with 1 mm at
        100 Hz (12 rad/s at 40 Hz) and about 21 rad/s for angles with 1 mrad at 100 Hz:
        well above the paper's closed-loop and trajectory bandwidths (about 2 rad/s and
        0.63 rad/s), while the q_ddot error on the paper's trajectory stays near
        0.05 m/s^2 at 40-100 Hz (tests/test_filters.py). A smaller PSD lowers that
        error on such a slow trajectory but lags acceleration changes.
    position_std : float or array_like, shape (n,)
        Default standard deviation of position measurements per row [m or rad].
    velocity_std : float or array_like, shape (n,)
        Default standard deviation of rate measurements per row [m/s or rad/s].
    wrap_rows : sequence of int
        Rows that are angles: innovations are wrapped to [-pi, pi) and the estimate is
        reported in [-pi, pi). Default: the Euler angles (3, 4, 5).
    initial_velocity_std : float or array_like, shape (n,)
        Standard deviation of the zero initial rate [m/s or rad/s].
    initial_acceleration_std : float or array_like, shape (n,)
        Standard deviation of the zero initial acceleration [m/s^2 or rad/s^2].
    compiled : bool, optional
        Fuse measurements compiled (``companion.control.control_step.fuse``, the same
        operations as :meth:`_fuse`, which stays the reference) or in numpy [default:
        compiled where the twin is built, unless ``COMPANION_STEP=python``; see
        :mod:`companion.control.native`].
    """

    def __init__(
        self,
        n: int = N_Q,
        *,
        jerk_psd: ArrayLike = DEFAULT_JERK_PSD,
        position_std: ArrayLike = 1e-3,
        velocity_std: ArrayLike = 1e-2,
        wrap_rows: Sequence[int] = _EULER_ROWS,
        initial_velocity_std: ArrayLike = 1.0,
        initial_acceleration_std: ArrayLike = 5.0,
        compiled: bool | None = None,
    ) -> None:
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n!r}")
        self._n = n
        wrap = sorted({int(r) for r in wrap_rows})
        if any(not 0 <= r < n for r in wrap):
            raise ValueError(f"wrap_rows must lie in [0, {n}), got {wrap_rows!r}")
        self._wrap = tuple(wrap)
        self._is_angle = np.zeros(n, dtype=bool)
        self._is_angle[wrap] = True
        self._v0_var = _per_row(initial_velocity_std, n, "initial_velocity_std") ** 2
        self._a0_var = _per_row(initial_acceleration_std, n, "initial_acceleration_std") ** 2
        # Two buffers: predict writes A X into the other one and swaps (no copy).
        self._X = np.zeros((_N_STACK, n))
        self._X[_PSD] = _per_row(jerk_psd, n, "jerk_psd", positive=True)
        self._X[_R_POS] = _per_row(position_std, n, "position_std", positive=True) ** 2
        self._X[_R_VEL] = _per_row(velocity_std, n, "velocity_std", positive=True) ** 2
        self._X_next = self._X.copy()
        self._initialised = np.zeros(n, dtype=bool)
        self._ready = False
        self._predict_cache: dict[float, FloatArray] = {}
        self._update_cache: dict[tuple[int, float, int], FloatArray] = {}
        self._selection_cache: dict[tuple[int, ...] | None, _Selection] = {}
        native = native_module(compiled)
        self._fuse_columns = self._fuse if native is None else native.fuse
        """The scalar updates of every column: compiled, or the numpy reference."""
        self._propagate = _propagate if native is None else native.predict
        """The prediction product ``X_next = A X``: compiled, or the numpy reference."""
        self._native_update = None if native is None else native.update
        """The common update (default variance, every row started) in one compiled call,
        or None: the numpy steps of :meth:`_update` then run, which stay its reference."""
        self._native_body_rates = (
            None if native is None or self._wrap != _EULER_ROWS else native.update_body_rates
        )
        """:meth:`update_body_rates` in one compiled call, or None."""
        self._native_cycle = (
            None if native is None or self._wrap != _EULER_ROWS or n != N_Q else native.fuse_cycle
        )
        """:meth:`fuse_cycle` in one compiled call, or None."""

    # -- properties -------------------------------------------------------------------

    @property
    def n(self) -> int:
        """Number of rows."""
        return self._n

    @property
    def ready(self) -> bool:
        """True once every row has had a position measurement."""
        return self._ready

    @property
    def estimate(self) -> FilteredState:
        """Current estimate of q, q_dot, q_ddot (angles in ``wrap_rows`` in [-pi, pi)).

        Raises
        ------
        FilterNotReadyError
            If some row has not had a position measurement yet.
        """
        if not self._ready:
            missing = np.flatnonzero(~self._initialised).tolist()
            raise FilterNotReadyError(f"no position measurement yet for rows {missing}")
        out = self._X[_X_ROWS].copy()
        if self._wrap:
            q = out[0]
            values = q.tolist()
            for r in self._wrap:
                a = values[r]
                if not -math.pi <= a < math.pi:
                    q[r] = _wrap_scalar(a)
        out.flags.writeable = False
        return FilteredState(out[0], out[1], out[2])

    def value(self, row: int) -> float:
        """The estimate of row ``row`` of q, as :attr:`estimate` reports it (without
        building the whole estimate). FilterNotReadyError before :attr:`ready`."""
        if not self._ready:
            return float(self.estimate.q[row])  # raises
        a = float(self._X[0, row])
        if self._is_angle[row] and not -math.pi <= a < math.pi:
            return _wrap_scalar(a)
        return a

    @property
    def std(self) -> FilteredState:
        """Standard deviations of the estimate (square roots of the covariance diagonal).

        Same units as :attr:`estimate`, row by row; meaningless for rows without a
        position measurement yet.
        """
        out = np.sqrt(np.maximum(self._X[_P_DIAG], 0.0))
        out.flags.writeable = False
        return FilteredState(out[0], out[1], out[2])

    @property
    def covariance(self) -> FloatArray:
        """Covariance of ``[q_k, q_dot_k, q_ddot_k]`` per row k, shape (n, 3, 3) (a copy).

        Units are products of the units of the two entries (e.g. m^2, m^2/s, m^2/s^2
        in the first row of a translational row).
        """
        P = self._X[:12].reshape(3, 4, self._n)[:, 1:, :]  # [i, j, k] = P_ij of row k
        return np.ascontiguousarray(P.transpose(2, 0, 1))

    # -- operations -------------------------------------------------------------------

    def reset(self) -> None:
        """Forget everything: every row waits for its first position measurement."""
        self._X[:12] = 0.0
        self._initialised[:] = False
        self._ready = False

    def reset_rows(self, q_meas: ArrayLike, *, rows: ArrayLike) -> None:
        """Start ``rows`` again from a position measurement ``q_meas`` [m or rad]: zero
        derivatives, the initial covariance (the source of those rows jumped, e.g. an
        estimator reset). ValueError on a wrong shape or a non-finite value."""
        idx = np.asarray(rows, dtype=np.intp).reshape(-1)
        z = np.asarray(q_meas, dtype=np.float64)
        if z.shape != idx.shape or not np.all(np.isfinite(z)):
            raise ValueError(f"need {idx.size} finite values, got {q_meas!r}")
        if np.any(idx < 0) or np.any(idx >= self._n):
            raise ValueError(f"rows must lie in [0, {self._n}), got {rows!r}")
        self._initialise(idx, z, self._X[_R_POS, idx])

    def predict(self, dt_s: float) -> None:
        """Propagate the estimate by ``dt_s`` (filterpy ``KalmanFilter.predict``).

        Parameters
        ----------
        dt_s : float
            Time since the last predict [s], > 0. F and Q are cached per value: a
            fixed-rate control loop should pass its nominal period (a cache miss costs
            a few tens of microseconds).
        """
        A = self._predict_cache.get(dt_s)
        if A is None:
            A = self._predict_matrix(dt_s)
        self._propagate(A, self._X, self._X_next)
        self._X, self._X_next = self._X_next, self._X

    def update_position(
        self,
        q_meas: ArrayLike,
        std: ArrayLike | None = None,
        *,
        latency_s: float = 0.0,
        rows: ArrayLike | None = None,
    ) -> None:
        """Fuse a measurement of q (or of some of its rows).

        Parameters
        ----------
        q_meas : array_like, shape (n,) or (len(rows),)
            Measured values [m or rad], taken ``latency_s`` before the current filter
            time. Angles may be given in any 2 pi range.
        std : float or array_like, optional
            Measurement standard deviation per measured row [m or rad]; default the
            constructor's ``position_std``.
        latency_s : float
            Age of the measurement at the current filter time [s], >= 0 (see the module
            notes on latency).
        rows : array_like of int, optional
            The rows measured (all rows if omitted).

        Raises
        ------
        ValueError
            On a wrong shape or a non-finite value; the estimate is then unchanged.
        """
        self._update(0, q_meas, std, latency_s, rows)

    def update_velocity(
        self,
        q_dot_meas: ArrayLike,
        std: ArrayLike | None = None,
        *,
        latency_s: float = 0.0,
        rows: ArrayLike | None = None,
    ) -> None:
        """Fuse a measurement of q_dot (or of some of its rows), e.g. gyro Euler rates.

        The caller converts body rates to Euler rates (q_dot rows 3-5) with the measured
        attitude. Rows without a position measurement yet are skipped.

        Parameters
        ----------
        q_dot_meas : array_like, shape (n,) or (len(rows),)
            Measured rates [m/s or rad/s], taken ``latency_s`` before the current time.
        std : float or array_like, optional
            Measurement standard deviation per measured row [m/s or rad/s]; default the
            constructor's ``velocity_std``.
        latency_s : float
            Age of the measurement at the current filter time [s], >= 0.
        rows : array_like of int, optional
            The rows measured (all rows if omitted).

        Raises
        ------
        ValueError
            On a wrong shape or a non-finite value; the estimate is then unchanged.
        """
        self._update(1, q_dot_meas, std, latency_s, rows)

    def update_body_rates(
        self, omega_flu_rad_s: Iterable[float], *, latency_s: float = 0.0
    ) -> bool:
        """Fuse gyro body rates (FLU) [rad/s], ``latency_s`` [s] old, as the Euler rates of
        rows 3, 4, 5 (phi, theta, psi; ZYX), turned into them with this filter's roll and
        pitch (:meth:`value`), in one compiled call (``control_step.update_body_rates``:
        the operations of :func:`companion.estimation.state.euler_rates_from_body_rates`
        and :meth:`update_velocity`). Returns False, nothing fused, where that call does not
        run (no compiled twin, a row not started, other angle rows than the Euler
        angles): the caller converts and calls :meth:`update_velocity`, the reference.

        Raises ValueError as :meth:`update_velocity`.
        """
        if self._native_body_rates is None or not self._ready:
            return False
        self._native_body_rates(self._X, latency_s, omega_flu_rad_s)
        return True

    def fuse_cycle(
        self,
        dt_s: float,
        pose: Sequence[float],
        velocity_enu_m_s: ArrayLike | None,
        omega_flu_rad_s: Iterable[float] | None,
        eta_rad: Sequence[float] | None,
        eta_dot_rad_s: Sequence[float] | None,
        joint_age_s: float,
    ) -> bool:
        """One control cycle of the filter of q (8 rows, the Euler angles' innovations
        wrapped) in one compiled call (``control_step.fuse_cycle``): :meth:`predict` by
        ``dt_s`` [s], then with their default variances the ``pose`` (rows 0-5: ENU
        position [m], ZYX angles [rad]), the velocity (rows 0-2 of q_dot, ENU [m/s]), the
        gyro body rates (:meth:`update_body_rates`), the joint angles [rad] and rates
        [rad/s] (rows 6, 7, ``joint_age_s`` [s] old); None: not measured this cycle.
        Returns False, nothing done, where that call does not run (no compiled twin, a row
        not started, another layout): the caller predicts and updates one by one, the
        reference.

        Raises ValueError as :meth:`predict` and :meth:`update_position` (the prediction
        and the updates before the refused one done).
        """
        if self._native_cycle is None or not self._ready:
            return False
        A = self._predict_cache.get(dt_s)
        if A is None:
            A = self._predict_matrix(dt_s)
        try:
            self._native_cycle(
                A, self._X, self._X_next, pose, velocity_enu_m_s, omega_flu_rad_s, eta_rad,
                eta_dot_rad_s, joint_age_s,
            )  # fmt: skip
        finally:
            self._X, self._X_next = self._X_next, self._X
        return True

    # -- internals --------------------------------------------------------------------

    def _predict_matrix(self, dt_s: float) -> FloatArray:
        """(17, 17) matrix mapping the stacked state to F x, F P F^T + Q (rest kept)."""
        dt = float(dt_s)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt_s must be finite and > 0, got {dt_s!r}")
        F = transition_matrix(dt)
        Qu = Q_continuous_white_noise(dim=3, dt=dt, spectral_density=1.0)
        A4 = np.zeros((3, 4, 3, 4))  # [i, c, k, d] -> A[4 i + c, 4 k + d]
        A4[:, 0, :, 0] = F  # x_i' = F_ik x_k
        A4[:, 1:, :, 1:] = np.einsum("ik,jl->ijkl", F, F)  # P_ij' = F_ik P_kl F_jl
        Q4 = np.zeros((3, 4))
        Q4[:, 1:] = Qu  # P_ij' += Q_ij * psd
        A = np.eye(_N_STACK)  # rows 12.. (psd, R, scratch) are kept
        A[:12, :12] = A4.reshape(12, 12)
        A[:12, _PSD] = Q4.reshape(12)
        if len(self._predict_cache) >= _CACHE_SIZE:
            del self._predict_cache[next(iter(self._predict_cache))]
        self._predict_cache[dt_s] = A
        return A

    def _measurement_matrix(self, order: int, latency_s: float, r_row: int) -> FloatArray:
        """(25, 17) matrix G; with h = e_order^T F(-latency) and W = G X (per column):

        ``W[4 i + c] = [h.x - z, (P h)_0, (P h)_1, (P h)_2][c]`` for i = 0..2,
        ``W[12 + 4 i + c] = (P h)_i`` and ``W[24] = -(h^T P h + R) = -S``.
        """
        key = (order, latency_s, r_row)
        G = self._update_cache.get(key)
        if G is not None:
            return G
        lat = float(latency_s)
        if not (math.isfinite(lat) and lat >= 0.0):
            raise ValueError(f"latency_s must be finite and >= 0, got {latency_s!r}")
        h = transition_matrix(-lat)[order]
        v = np.zeros((4, _N_STACK))  # [h.x - z, (P h)_0..2] over the stacked state
        v[0, _X_ROWS] = h
        v[0, _Z] = -1.0
        for j in range(3):
            v[1 + j, 4 * j + 1 : 4 * j + 4] = h
        G = np.zeros((25, _N_STACK))
        for i in range(3):
            G[4 * i : 4 * i + 4] = v
            G[12 + 4 * i : 16 + 4 * i] = v[1 + i]
            G[24, 4 * i + 1 : 4 * i + 4] = -h[i] * h
        G[24, r_row] = -1.0
        if len(self._update_cache) >= _CACHE_SIZE:
            del self._update_cache[next(iter(self._update_cache))]
        self._update_cache[key] = G
        return G

    def _selection(self, rows: ArrayLike | None) -> _Selection:
        """Validated, cached description of the measured rows."""
        if rows is None:
            key: tuple[int, ...] | None = None
        elif isinstance(rows, tuple):
            key = rows
        else:
            key = tuple(np.asarray(rows).reshape(-1).tolist())
        sel = self._selection_cache.get(key)
        if sel is not None:
            return sel
        n = self._n
        idx = np.arange(n) if key is None else np.asarray(key, dtype=np.intp).reshape(-1)
        if idx.size == 0:
            raise ValueError("rows must not be empty")
        if idx.min() < 0 or idx.max() >= n:
            raise ValueError(f"rows must lie in [0, {n}), got {rows!r}")
        if np.unique(idx).size != idx.size:
            raise ValueError(f"rows must not repeat, got {rows!r}")
        mask = np.zeros(n, dtype=bool)
        mask[idx] = True
        first = int(idx[0])
        contiguous = bool(np.array_equal(idx, np.arange(first, first + idx.size)))
        sel = _Selection(
            idx=idx,
            rows=tuple(idx.tolist()),
            columns=slice(first, first + idx.size) if contiguous else idx,
            all_rows=contiguous and idx.size == n,
            mask=mask,
            wrap=tuple(np.flatnonzero(mask & self._is_angle).tolist()),
            default_var=(
                np.where(mask, self._X[_R_POS], _R_UNMEASURED),
                np.where(mask, self._X[_R_VEL], _R_UNMEASURED),
            ),
        )
        if len(self._selection_cache) >= _CACHE_SIZE:
            del self._selection_cache[next(iter(self._selection_cache))]
        self._selection_cache[key] = sel
        return sel

    def _update(
        self,
        order: int,
        z_in: ArrayLike,
        std: ArrayLike | None,
        latency_s: float,
        rows: ArrayLike | None,
    ) -> None:
        sel = self._selection(rows)
        if std is None and self._ready and self._native_update is not None:
            wrap = sel.wrap if order == 0 else ()
            self._native_update(self._X, order, latency_s, sel.rows, z_in, wrap)
            return
        z = np.asarray(z_in, dtype=np.float64)
        if z.shape != sel.idx.shape:
            raise ValueError(f"measurement must have shape {sel.idx.shape}, got {z.shape}")
        X = self._X
        X[_Z, sel.columns] = z
        if std is None and self._ready:  # the common, fast case
            if sel.all_rows:
                r_row = _R_POS + order
            else:
                r_row = _R_CALL
                X[_R_CALL] = sel.default_var[order]
        else:
            r_row = _R_CALL
            if std is None:
                var = sel.default_var[order].copy()
            else:
                var = np.full(self._n, _R_UNMEASURED)
                var[sel.idx] = _per_row(std, z.size, "std", positive=True) ** 2
            if not self._ready:
                if not np.all(np.isfinite(z)):
                    raise ValueError(f"measurement must be finite, got {z!r}")
                fresh = sel.mask & ~self._initialised
                if order == 0 and fresh.any():  # a first position initialises its row
                    self._initialise(np.flatnonzero(fresh), X[_Z, fresh], var[fresh])
                var[fresh] = (
                    _R_UNMEASURED  # not fused: just initialised, or a rate before any position
                )
            X[_R_CALL] = var
        try:
            self._fuse_columns(
                X, self._measurement_matrix(order, latency_s, r_row), sel.wrap if order == 0 else ()
            )
        except ValueError:
            X[_Z] = 0.0  # a rejected measurement must not stay in the unmeasured columns
            raise

    def _initialise(self, idx: NDArray[np.intp], z: FloatArray, var: FloatArray) -> None:
        """Start rows ``idx`` at ``q = z``, zero derivatives, ``P = diag(var, v0^2, a0^2)``."""
        X = self._X
        X[:12, idx] = 0.0
        X[0, idx] = z
        X[1, idx] = var
        X[6, idx] = self._v0_var[idx]
        X[11, idx] = self._a0_var[idx]
        self._initialised[idx] = True
        self._ready = bool(self._initialised.all())

    @staticmethod
    def _fuse(X: FloatArray, G: FloatArray, wrap: tuple[int, ...]) -> None:
        """One scalar Kalman update per column of the stacked state X, in place.

        With S = h^T P h + R and K = P h / S (filterpy ``KalmanFilter.update`` for
        a scalar measurement): x += K (z - h.x), P -= K (P h)^T, both as one product
        ``X[4 i + c] += (-K_i) [h.x - z, (P h)_0..2][c]`` with everything from W = G X.
        """
        W = G.dot(X)
        innovation = W[0].tolist()  # h.x - z per column (= -innovation)
        if not math.isfinite(sum(innovation)):
            raise ValueError("measurement or state is not finite")
        for r in wrap:
            a = innovation[r]
            if not -math.pi <= a < math.pi:
                W[_X_ROWS, r] = _wrap_scalar(a)
        neg_k = W[12:24]
        np.divide(neg_k, W[24], out=neg_k)  # (P h)_i / -S = -K_i
        np.multiply(neg_k, W[:12], out=neg_k)
        x = X[:12]
        np.add(x, neg_k, out=x)

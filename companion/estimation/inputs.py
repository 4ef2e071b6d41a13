"""The estimator's inputs n control cycles late, with a zero-phase acceleration (pure).

The state filter's accelerations lag the truth, and by different amounts per row: in the
SITL pickup (125 Hz loop, 50 Hz pose, jerk PSD 1), against the truth log during the
excitation, x and z 75-80 ms, pitch 25 ms and the joints 40 ms, while q and q_dot lag
0-10 ms. Fed to the regressor with the force and the servo torque of the same cycle, that
lag biased theta: least squares over the excitation of a 0.4 kg pickup gave m3 -7 % and
m4 -60 % from the joint rows alone, and m3 -73 % from x, y, z (the truth states with the
logged torques gave both exactly).

:class:`DelayedInputs` hands the estimator the cycle n steps back instead: q, q_dot and the
applied force of that cycle, and q_ddot as the central difference of the filter's q_dot
over n cycles either side, ``(q_dot[k] - q_dot[k - 2n]) / (t[k] - t[k - 2n])``, which has
no phase lag at the delayed cycle (for a sinusoid of frequency w it is the derivative times
``sin(w T) / (w T)``, T = n periods). On the same logs with n = 3 at 125 Hz (24 ms): the
joint rows give m3 within 0.3 % and m4 within 2-10 %. The estimate is n cycles older;
the controller still uses the current state.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.estimation.estimator import Skip

__all__ = ["DelayedInputs", "EstimatorInputs", "delay_cycles"]

FloatArray = NDArray[np.float64]
EstimatorInputs = tuple[FloatArray, FloatArray, FloatArray, FloatArray | Skip]
"""(q, q_dot, q_ddot, applied force or why it is not known) of the cycle the estimator
runs on."""


def delay_cycles(delay_s: float, dt_s: float) -> int:
    """The delay in whole control periods of ``dt_s`` [s]: ``delay_s`` rounded, at least 1."""
    return max(1, round(delay_s / dt_s))


def _read_only(values: ArrayLike) -> FloatArray:
    """A read-only float64 copy of 8 values (ValueError for another shape)."""
    a = np.array(values, dtype=float)
    if a.shape != (8,):
        raise ValueError(f"expected 8 values, got shape {a.shape}")
    a.flags.writeable = False
    return a


_ZERO = _read_only(np.zeros(8))


class DelayedInputs:
    """A delay line of (q, q_dot, applied force, period) over 2n + 1 cycles.

    Parameters
    ----------
    n : int
        The delay in control cycles (>= 1).
    """

    def __init__(self, n: int) -> None:
        if n < 1:
            raise ValueError(f"the delay must be at least one cycle, got {n}")
        self.n = n
        size = 2 * n + 1
        # Read-only copies, handed out as they are (fewer array operations per cycle).
        self._q: list[FloatArray] = [_ZERO] * size
        self._q_dot: list[FloatArray] = [_ZERO] * size
        self._tau: list[FloatArray | Skip] = [Skip.NO_FORCE] * size
        self._dt = np.zeros(size)
        self._head = 0
        self._count = 0

    def reset(self) -> None:
        """Forget the history (for example after a jump of the state estimate)."""
        self._count = 0

    def push(
        self, dt_s: float, q: ArrayLike, q_dot: ArrayLike, tau: FloatArray | Skip
    ) -> EstimatorInputs | None:
        """Add this cycle (period ``dt_s`` [s] since the last); return the cycle n back as
        ``(q, q_dot, q_ddot, tau)``, q_ddot the central difference, or None until 2n + 1
        cycles are in the line."""
        size = len(self._dt)
        head = self._head
        self._q[head] = _read_only(q)
        self._q_dot[head] = q_dot_now = _read_only(q_dot)
        self._tau[head] = tau if isinstance(tau, Skip) else np.array(tau, dtype=float)
        self._dt[head] = dt_s
        self._head = (head + 1) % size
        self._count = min(self._count + 1, size)
        if self._count < size:
            return None
        oldest = self._head
        mid = (head - self.n) % size
        # The periods after the oldest cycle, up to and including this one.
        span_s = float(self._dt.sum() - self._dt[oldest])
        q_ddot = (q_dot_now - self._q_dot[oldest]) / span_s
        return self._q[mid], self._q_dot[mid], q_ddot, self._tau[mid]

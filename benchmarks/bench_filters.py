"""Cost of the state filter per control step, against filterpy's own KalmanFilter.

Prints median and 99th-percentile microseconds per operation (one ``perf_counter_ns``
pair around each call, so about 0.1 us of timer overhead is included):

- ``StateFilter`` (companion.estimation.filters): predict, estimate, the update variants, a full
  predict + update + estimate cycle, and a 1 kHz control loop with 100 Hz motion capture
  (rows 0-5), 100 Hz encoders (rows 6-7) and 250 Hz gyro Euler rates (rows 3-5), where
  most steps only predict and read the estimate;
- the alternatives it replaces: a bank of eight ``filterpy.kalman.KalmanFilter(3, 1)``
  and one block-diagonal ``filterpy.kalman.KalmanFilter(24, 8)``, each predict + update.

Run: ``python benchmarks/bench_filters.py [--steps N]``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import KalmanFilter

from companion.estimation.filters import DEFAULT_JERK_PSD, StateFilter, transition_matrix

DT_S = 1e-3
"""Control period [s] (1 kHz, the paper's on-board rate)."""


def _time(fn: Callable[[int], object], steps: int) -> tuple[float, float]:
    """Median and p99 of ``fn(k)`` over ``steps`` calls [us], after a warm-up."""
    for k in range(min(steps, 1000)):
        fn(k)
    t = np.empty(steps)
    clock = time.perf_counter_ns
    for k in range(steps):
        t0 = clock()
        fn(k)
        t[k] = clock() - t0
    return float(np.median(t)) / 1e3, float(np.percentile(t, 99)) / 1e3


def _trajectory(steps: int, rng: np.random.Generator) -> np.ndarray:
    """Noisy samples of the paper's q_d (1 mm / 1 mrad), shape (steps, 8)."""
    t = np.arange(steps) * DT_S
    w = np.pi / 5.0
    q = np.zeros((steps, 8))
    q[:, 0] = 0.5 * np.cos(w * t)
    q[:, 1] = -0.5 * np.cos(w * t)
    q[:, 2] = 0.7
    q[:, 6] = -np.pi / 2 + np.pi / 4 * np.sin(w * t)
    q[:, 7] = np.pi / 8 * np.sin(w * t)
    return q + 1e-3 * rng.standard_normal(q.shape)


def _state_filter(z: np.ndarray) -> StateFilter:
    f = StateFilter()
    f.update_position(z[0])
    for k in range(1, 200):
        f.predict(DT_S)
        f.update_position(z[k])
    return f


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000, help="calls timed per row")
    steps = parser.parse_args().steps
    rng = np.random.default_rng(0)
    z = _trajectory(steps + 1000, rng)
    rates = 0.01 * rng.standard_normal((steps + 1000, 3))
    rows: list[tuple[str, tuple[float, float]]] = []

    f = _state_filter(z)
    rows.append(("StateFilter.predict", _time(lambda k: f.predict(DT_S), steps)))
    f = _state_filter(z)
    rows.append(("StateFilter.estimate", _time(lambda k: f.estimate, steps)))

    def cycle_full(k: int) -> None:
        f.predict(DT_S)
        f.update_position(z[k])

    f = _state_filter(z)
    rows.append(("StateFilter predict + update_position (8 rows)", _time(cycle_full, steps)))

    def cycle_pose(k: int) -> None:
        f.predict(DT_S)
        f.update_position(z[k, :6], rows=(0, 1, 2, 3, 4, 5), latency_s=0.01)

    f = _state_filter(z)
    rows.append(("StateFilter predict + update_position (rows 0-5)", _time(cycle_pose, steps)))

    def cycle_rates(k: int) -> None:
        f.predict(DT_S)
        f.update_velocity(rates[k], rows=(3, 4, 5))

    f = _state_filter(z)
    rows.append(("StateFilter predict + update_velocity (rows 3-5)", _time(cycle_rates, steps)))

    def cycle_estimate(k: int) -> None:
        f.predict(DT_S)
        f.update_position(z[k])
        f.estimate  # noqa: B018

    f = _state_filter(z)
    rows.append(("StateFilter predict + update + estimate", _time(cycle_estimate, steps)))

    def control_step(k: int) -> None:
        f.predict(DT_S)
        if k % 10 == 0:
            f.update_position(z[k, :6], rows=(0, 1, 2, 3, 4, 5))
        if k % 10 == 5:
            f.update_position(z[k, 6:], rows=(6, 7))
        if k % 4 == 0:
            f.update_velocity(rates[k], rows=(3, 4, 5))
        f.estimate  # noqa: B018

    f = _state_filter(z)
    rows.append(("StateFilter 1 kHz step (mocap, encoders, gyro)", _time(control_step, steps)))

    F = transition_matrix(DT_S)
    Qu = Q_continuous_white_noise(dim=3, dt=DT_S, spectral_density=1.0)
    bank = []
    for k in range(8):
        kf = KalmanFilter(dim_x=3, dim_z=1)
        kf.F, kf.Q = F.copy(), Qu * DEFAULT_JERK_PSD[k]
        kf.H, kf.R = np.array([[1.0, 0.0, 0.0]]), np.array([[1e-6]])
        kf.x = np.array([[z[0, k]], [0.0], [0.0]])
        bank.append(kf)

    def bank_cycle(k: int) -> None:
        for i, kf in enumerate(bank):
            kf.predict()
            kf.update(z[k, i])

    rows.append(("filterpy: 8 x KalmanFilter(3, 1) predict + update", _time(bank_cycle, steps)))

    big = KalmanFilter(dim_x=24, dim_z=8)
    big.F = np.kron(np.eye(8), F)
    big.Q = np.kron(np.diag(DEFAULT_JERK_PSD), Qu)
    big.H = np.kron(np.eye(8), np.array([[1.0, 0.0, 0.0]]))
    big.R = 1e-6 * np.eye(8)
    big.x[::3, 0] = z[0]

    def big_cycle(k: int) -> None:
        big.predict()
        big.update(z[k])

    rows.append(("filterpy: KalmanFilter(24, 8) predict + update", _time(big_cycle, steps)))

    width = max(len(name) for name, _ in rows)
    print(f"{'operation':<{width}}  {'median us':>9}  {'p99 us':>8}")
    for name, (med, p99) in rows:
        print(f"{name:<{width}}  {med:9.1f}  {p99:8.1f}")


if __name__ == "__main__":
    main()

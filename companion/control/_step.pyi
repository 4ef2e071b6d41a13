"""Type stub of the C extension ``_step`` (source ``_step.c``): the control step in one call.
Buffers are C-contiguous float64; ValueError on a wrong number of values."""

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

PARAMS_SIZE: int
STATE_SIZE: int
OUT_SIZE: int
LAYOUT: dict[str, tuple[int, int]]
"""``"Params.<field>"`` / ``"State.<field>"`` -> (offset, number of values)."""

def step(
    params: NDArray[np.float64],
    state: NDArray[np.float64],
    dt: float,
    skip: int,
    q: NDArray[np.float64],
    q_dot: NDArray[np.float64],
    q_ddot: NDArray[np.float64],
    qd: NDArray[np.float64],
    qd_dot: NDArray[np.float64],
    qd_ddot: NDArray[np.float64],
    tau: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """One control step; ``state`` and ``out`` are written (see ``_step.c``)."""

def predict(a: NDArray[np.float64], x: NDArray[np.float64], x_next: NDArray[np.float64]) -> None:
    """The state filter's prediction ``x_next = a @ x`` (17 x 17 times 17 x n)."""

def fuse(x: NDArray[np.float64], g: NDArray[np.float64], wrap: tuple[int, ...]) -> None:
    """The state filter's scalar update of every column of ``x`` (17 x n) in place, with the
    (25 x 17) matrix ``g``; ValueError (``x`` unchanged) if the innovation is not finite."""

def update(
    x: NDArray[np.float64],
    order: int,
    latency_s: float,
    rows: tuple[int, ...],
    z: Sequence[float] | NDArray[np.float64],
    wrap: tuple[int, ...],
) -> None:
    """The state filter's update of derivative ``order`` (0: q, 1: q_dot) of ``rows`` with
    their default variance, ``latency_s`` old, in place: the measurement and variance rows
    placed, G built and fused as ``fuse``; ValueError (``x``'s measurement row zeroed) for
    a non-finite value, a bad latency or ``z`` not one value per row."""

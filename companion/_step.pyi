"""Type stub of the C extension ``_step`` (source ``_step.c``): the control step in one call.
Buffers are C-contiguous float64; ValueError on a wrong number of values."""

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

def terms(
    q: NDArray[np.float64],
    q_dot: NDArray[np.float64],
    p: NDArray[np.float64],
    xi: NDArray[np.float64],
    qr_dot: NDArray[np.float64],
    qr_ddot: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """M (8 x 8), C (8 x 8), G (8) for xi and Y^T (4 x 8), 168 values, into ``out``."""

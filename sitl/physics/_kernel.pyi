"""Type stub of the C extension ``_kernel`` (source ``_kernel.c``): the truth plant's
per-step arithmetic; see :mod:`sitl.physics.integration` and :mod:`sitl.physics.plant` for
the layouts."""

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

def step(
    rk4: bool,
    dt: float,
    x: Sequence[float],
    u: Sequence[float],
    r9: Sequence[float],
    euler: Sequence[float],
    q_dot: Sequence[float],
    w_inv9: Sequence[float],
    kind: int,
    force: Sequence[float],
    aba: Callable[..., NDArray[np.float64]],
    model: object,
    data: object,
    q: NDArray[np.float64],
    v: NDArray[np.float64],
    tau: NDArray[np.float64],
) -> tuple:
    """One integration step and the new state's kinematics (status first)."""

def kinematics(x: Sequence[float], u: Sequence[float], euler_previous: Sequence[float]) -> tuple:
    """The plant's kinematics of a state (status first)."""

def pack(*sequences: Sequence[float]) -> bytes:
    """The floats of the sequences, in order, as the bytes of float64 values (at most 64)."""

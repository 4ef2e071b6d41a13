"""Type stub of the generated C extension ``_mcg`` (source ``_mcg.c``, from
:mod:`companion.model.derive`). Each function writes into ``out`` (C-contiguous float64) and
raises ValueError on a wrong number of values; see :mod:`companion.model.layout`."""

import numpy as np
from numpy.typing import NDArray

def mcg(
    q: NDArray[np.float64],
    qd: NDArray[np.float64],
    p: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Stacked M, C, G pieces at (q, qd), shape (N_XI, N_Q * ROW), into ``out``."""

def potential(q: NDArray[np.float64], p: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """The N_XI pieces of the potential energy V(q) into ``out``."""

def combine(pieces: NDArray[np.float64], xi: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """``xi @ pieces`` (M, C, G rows for one theta), N_Q * ROW values, into ``out``."""

def regress(
    pieces: NDArray[np.float64],
    qr_dot: NDArray[np.float64],
    qr_ddot: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Y^T (N_XI x N_Q) into ``out``."""

def all(
    q: NDArray[np.float64],
    qd: NDArray[np.float64],
    p: NDArray[np.float64],
    theta: NDArray[np.float64],
    qr_dot: NDArray[np.float64],
    qr_ddot: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """M (8 x 8), C (8 x 8), G (8) for theta (3 values) and Y^T (4 x 8): 168 values into
    ``out``."""

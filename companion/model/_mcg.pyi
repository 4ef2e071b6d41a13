"""Type stub of the generated C extension ``_mcg`` (source ``_mcg.c``, from
:mod:`companion.model.derive`). Each function writes into ``out``; every argument must be
C-contiguous native float64 values of the right count, one-dimensional where a vector is
meant (else ValueError; TypeError for an object without a buffer), checked before anything
is written; see :mod:`companion.model.layout`."""

import numpy as np
from numpy.typing import NDArray

_Values = NDArray[np.float64] | memoryview
"""Contiguous float64 values: an array, or a view of an ``array("d")``."""

def mcg(
    q: _Values,
    qd: _Values,
    p: _Values,
    out: _Values,
) -> None:
    """Stacked M, C, G pieces at (q, qd), shape (N_XI, N_Q * ROW), into ``out``."""

def potential(q: _Values, p: _Values, out: _Values) -> None:
    """The N_XI pieces of the potential energy V(q) into ``out``."""

def combine(pieces: _Values, xi: _Values, out: _Values) -> None:
    """``xi @ pieces`` (M, C, G rows for one theta), N_Q * ROW values, into ``out``."""

def regress(
    pieces: _Values,
    qr_dot: _Values,
    qr_ddot: _Values,
    out: _Values,
) -> None:
    """Y^T (N_XI x N_Q) into ``out``."""

def all(
    q: _Values,
    qd: _Values,
    p: _Values,
    theta: _Values,
    qr_dot: _Values,
    qr_ddot: _Values,
    out: _Values,
) -> None:
    """M (8 x 8), C (8 x 8), G (8) for theta (3 values) and Y^T (4 x 8): 168 values into
    ``out``."""

mcg_eval: object
"""The capsule ``companion.model._mcg.mcg_eval``: the address of the C function behind
:func:`mcg`, for compiled callers (its C type: ``mcg_eval.pxd``)."""

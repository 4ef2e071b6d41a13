"""Seeded designs of experiments: points of the unit cube scaled onto the axes' ranges.

Pure functions over numpy arrays; the randomness is a ``numpy.random.Generator`` made from
the spec's seed, never the global one, so that a spec expands to the same flights on every
machine. The Latin hypercube is SciPy's (``scipy.stats.qmc.LatinHypercube``, installed with
filterpy); where SciPy is missing the same stratification is drawn with numpy alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import NDArray

__all__ = ["DesignKind", "latin_hypercube", "sample_ranges", "unit_design"]

DesignKind = Literal["latin_hypercube", "random"]


def latin_hypercube(n: int, d: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``n`` points in [0, 1)^d, one in each of the ``n`` equal slices of every axis
    (McKay, Beckman, Conover 1979), shape (n, d)."""
    try:
        from scipy.stats import qmc  # type: ignore[import-untyped]
    except ImportError:
        slices = np.stack([rng.permutation(n) for _ in range(d)], axis=1)
        return (slices + rng.random((n, d))) / n
    return np.asarray(qmc.LatinHypercube(d=d, rng=rng).random(n), dtype=np.float64)


def unit_design(kind: DesignKind, n: int, d: int, seed: int) -> NDArray[np.float64]:
    """``n`` points of the unit cube [0, 1)^d of the design ``kind`` (``latin_hypercube``
    or ``random``: independent uniform draws), shape (n, d), from ``seed``."""
    if n < 1 or d < 0:
        raise ValueError(f"a design needs n >= 1 points in d >= 0 dimensions, got {n}, {d}")
    rng = np.random.default_rng(seed)
    if d == 0:
        return np.zeros((n, 0))
    if kind == "latin_hypercube":
        return latin_hypercube(n, d, rng)
    if kind == "random":
        return rng.random((n, d))
    raise ValueError(f"unknown design {kind!r}: latin_hypercube or random")


def sample_ranges(
    kind: DesignKind, n: int, ranges: Sequence[tuple[float, float]], seed: int
) -> NDArray[np.float64]:
    """``n`` draws over the ``ranges`` [(low, high), ...] (one per axis), shape
    (n, len(ranges)): the unit design scaled, low + u (high - low)."""
    unit = unit_design(kind, n, len(ranges), seed)
    if not ranges:
        return unit
    low = np.array([r[0] for r in ranges], dtype=np.float64)
    high = np.array([r[1] for r in ranges], dtype=np.float64)
    return low + unit * (high - low)

"""What the companion knows of the vehicle and the payload: the state and the parameters.

- :mod:`~companion.estimation.filters`: the state filter (q, q_dot, q_ddot from noisy,
  late measurements);
- :mod:`~companion.estimation.state`: measurements in, the filtered state out, and the
  generalized force the estimator can trust;
- :mod:`~companion.estimation.estimator`: the paper's on-line payload parameter estimator
  (eq. theta) with its excitation monitor and thrust-scale state;
- :mod:`~companion.estimation.inputs`: the estimator's inputs assembled per step.
"""

from importlib import import_module
from typing import TYPE_CHECKING

__all__ = [
    "FilteredState",
    "Skip",
    "StateAssembler",
    "StateFilter",
]

_HOME = {
    "Skip": "companion.estimation.estimator",
    "FilteredState": "companion.estimation.filters",
    "StateFilter": "companion.estimation.filters",
    "StateAssembler": "companion.estimation.state",
}
"""Where each public name lives (imported on first use: the modules import one another's
concrete modules, never this package, so no import cycle runs through here)."""

if TYPE_CHECKING:
    from companion.estimation.estimator import Skip
    from companion.estimation.filters import FilteredState, StateFilter
    from companion.estimation.state import StateAssembler


def __getattr__(name: str) -> object:
    if name in _HOME:
        return getattr(import_module(_HOME[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

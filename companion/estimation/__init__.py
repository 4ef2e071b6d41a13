"""What the companion knows of the vehicle and the payload: the state and the parameters.

- :mod:`~companion.estimation.filters`: the state filter (q, q_dot, q_ddot from noisy,
  late measurements);
- :mod:`~companion.estimation.state`: measurements in, the filtered state out, and the
  generalized force the estimator can trust;
- :mod:`~companion.estimation.estimator`: the paper's on-line payload parameter estimator
  (eq. theta) with its excitation monitor and thrust-scale state;
- :mod:`~companion.estimation.inputs`: the estimator's inputs assembled per step.
"""

from typing import TYPE_CHECKING

from companion.lazy import lazy_attributes

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
"""Where each public name lives (:mod:`companion.lazy`)."""

if TYPE_CHECKING:
    from companion.estimation.estimator import Skip
    from companion.estimation.filters import FilteredState, StateFilter
    from companion.estimation.state import StateAssembler

__getattr__ = lazy_attributes(__name__, _HOME)

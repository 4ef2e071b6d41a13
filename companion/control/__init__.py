"""The control step: the paper's laws and what turns their force into PX4's setpoint.

- :mod:`~companion.control.laws`: the augmented passivity-based law (eq. tau2), its
  non-adaptive baseline and the adaptive sliding-mode controller;
- :mod:`~companion.control.flight`: one flight step (model terms, estimator, tilt reference,
  the law, the setpoint), the same offline, in SITL and in flight (:class:`FlightControl`);
- :mod:`~companion.control.setpoints`: the small-angle tilt mapping to attitude + thrust;
- :mod:`~companion.control.attitude_feedforward`: PX4's attitude loop inverted;
- :mod:`~companion.control.trajectory`: reference trajectories;
- :mod:`~companion.control.control_step`, :mod:`~companion.control.compiled_step`,
  :mod:`~companion.control.native`: the step's arithmetic (a compiled twin), the compiled
  step around it and the switch to the Python reference.
"""

from typing import TYPE_CHECKING

from companion.lazy import lazy_attributes

__all__ = [
    "AttitudeThrustSetpoint",
    "ControlOutput",
    "ControlRateError",
    "DesiredState",
    "FlightControl",
    "FlightControllerName",
    "PassivityController",
    "ThrustModel",
]

_HOME = {
    "ControlOutput": "companion.control.flight",
    "FlightControl": "companion.control.flight",
    "FlightControllerName": "companion.control.flight",
    "ControlRateError": "companion.control.laws",
    "DesiredState": "companion.control.laws",
    "PassivityController": "companion.control.laws",
    "AttitudeThrustSetpoint": "companion.control.setpoints",
    "ThrustModel": "companion.control.setpoints",
}
"""Where each public name lives (:mod:`companion.lazy`)."""

if TYPE_CHECKING:
    from companion.control.flight import ControlOutput, FlightControl, FlightControllerName
    from companion.control.laws import ControlRateError, DesiredState, PassivityController
    from companion.control.setpoints import AttitudeThrustSetpoint, ThrustModel

__getattr__ = lazy_attributes(__name__, _HOME)

"""Simulated Dynamixel servos: a pure XM430-W350 model and a pty bus that serves it.

- :mod:`sitl.servo.xm430`: :class:`XM430Servo`, the control table and loops, and the
  :class:`ServoJoint` interface that couples a servo to a physics joint;
- :mod:`sitl.servo.pty_server`: :class:`PtyServoBus`, servos on a pseudo-terminal that
  any Protocol 2.0 client can open, with fault injection (:class:`Faults`).
"""

from sitl.servo.pty_server import Faults, PtyServoBus
from sitl.servo.xm430 import (
    EXAMPLE_TORQUE_CONSTANT_N_M_PER_A,
    ServoJoint,
    ServoReply,
    XM430Parameters,
    XM430Servo,
)

__all__ = [
    "EXAMPLE_TORQUE_CONSTANT_N_M_PER_A",
    "Faults",
    "PtyServoBus",
    "ServoJoint",
    "ServoReply",
    "XM430Parameters",
    "XM430Servo",
]

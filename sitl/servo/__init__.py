"""Simulated servos that speak the real protocols, and a bench rig to move their shafts.

- :mod:`sitl.servo.xm430`: :class:`XM430Servo`, the control table and loops, and the
  :class:`ServoJoint` interface that couples a servo to a physics joint;
- :mod:`sitl.servo.pty_server`: :class:`PtyServoBus`, servos on a pseudo-terminal that
  any Protocol 2.0 client can open, with fault injection (:class:`Faults`);
- :mod:`sitl.servo.can_actuator`: :class:`CanActuator`, a DroneCAN servo actuator model
  (force and position commands, arming, overload), also a :class:`ServoJoint`;
- :mod:`sitl.servo.dronecan_node`: :class:`DroneCanActuatorNode`, actuators behind a
  DroneCAN node on a python-can bus, with the same :class:`Faults`;
- :mod:`sitl.servo.rig`: :class:`JointRig`, each shaft on an inertia, stepped in real time.
"""

from sitl.servo.can_actuator import CanActuator, CanActuatorParameters, CommandType
from sitl.servo.dronecan_node import RESTART_MAGIC, DroneCanActuatorNode
from sitl.servo.pty_server import Faults, PtyServoBus
from sitl.servo.rig import JointRig
from sitl.servo.xm430 import (
    EXAMPLE_TORQUE_CONSTANT_N_M_PER_A,
    ServoJoint,
    ServoReply,
    XM430Parameters,
    XM430Servo,
)

__all__ = [
    "EXAMPLE_TORQUE_CONSTANT_N_M_PER_A",
    "RESTART_MAGIC",
    "CanActuator",
    "CanActuatorParameters",
    "CommandType",
    "DroneCanActuatorNode",
    "Faults",
    "JointRig",
    "PtyServoBus",
    "ServoJoint",
    "ServoReply",
    "XM430Parameters",
    "XM430Servo",
]

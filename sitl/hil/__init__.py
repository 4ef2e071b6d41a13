"""PX4 in the loop: the real PX4 SITL build flies our physics through ``simulator_mavlink``.

``sitl run --autopilot px4``. PX4's own EKF2, commander, position, attitude and
rate loops, control allocation and motor linearization fly the scenario's hexacopter with
its arm, gripper and payload object; the arm's servos stay on the emulated Dynamixel bus
and the companion talks to PX4 as on the real vehicle. Modules:
:mod:`~sitl.hil.airframe` (PX4's parameters of the scenario), :mod:`~sitl.hil.sensors`
(IMU, magnetometer, barometer, GPS), :mod:`~sitl.hil.messages` (the simulator link's
MAVLink), :mod:`~sitl.hil.link` (its TCP socket), :mod:`~sitl.hil.options` (how to run
it, what a run achieved), :mod:`~sitl.hil.boot` (PX4's way to ready),
:mod:`~sitl.hil.vehicle` (PX4, world and the lockstep loop). See ``docs/px4_in_the_loop.md``.
"""

from sitl.hil.options import HilOptions, HilStats
from sitl.hil.vehicle import Px4Exited, Px4InTheLoop

__all__ = ["HilOptions", "HilStats", "Px4Exited", "Px4InTheLoop"]

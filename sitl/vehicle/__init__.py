"""The simulated vehicle (``sitl run``): the PX4 imitation flying the truth world, on the
wall clock or in lockstep with the companion on simulated time.

- :mod:`~sitl.vehicle.world`: the truth world: plant, arm servos, gripper, payload object,
  ground and battery (:class:`World`);
- :mod:`~sitl.vehicle.navigation`: the autopilot's estimate of its state (EKF2-like errors);
- :mod:`~sitl.vehicle.sensors`: sensor models (pose, gyro, joint encoders);
- :mod:`~sitl.vehicle.runner`: the vehicle process: one clock driving world, autopilot,
  links, servo bus and logs (:class:`SitlVehicle`);
- :mod:`~sitl.vehicle.options`: how a run of it is set up and what it achieved
  (:class:`RunOptions`);
- :mod:`~sitl.vehicle.lockstep`: the companion and the vehicle in one event loop on
  simulated time (:func:`run_lockstep`);
- :mod:`~sitl.vehicle.virtual_flight`: a pickup on simulated time (:func:`fly_virtual`);
- :mod:`~sitl.vehicle.launch`: ``sitl run`` / ``sitl sih`` started as child processes
  (:func:`start_sitl`).
"""

from typing import TYPE_CHECKING

from companion.lazy import lazy_attributes

__all__ = [
    "Navigation",
    "RunOptions",
    "SitlNotReadyError",
    "SitlVehicle",
    "World",
    "WorldSettings",
    "fly_virtual",
    "run_lockstep",
    "start_sih",
    "start_sitl",
]

_HOME = {
    "Navigation": "sitl.vehicle.navigation",
    "RunOptions": "sitl.vehicle.options",
    "SitlNotReadyError": "sitl.vehicle.launch",
    "SitlVehicle": "sitl.vehicle.runner",
    "World": "sitl.vehicle.world",
    "WorldSettings": "sitl.vehicle.world",
    "fly_virtual": "sitl.vehicle.virtual_flight",
    "run_lockstep": "sitl.vehicle.lockstep",
    "start_sih": "sitl.vehicle.launch",
    "start_sitl": "sitl.vehicle.launch",
}
"""Where each public name lives (:mod:`companion.lazy`)."""

if TYPE_CHECKING:
    from sitl.vehicle.launch import SitlNotReadyError, start_sih, start_sitl
    from sitl.vehicle.lockstep import run_lockstep
    from sitl.vehicle.navigation import Navigation
    from sitl.vehicle.options import RunOptions
    from sitl.vehicle.runner import SitlVehicle
    from sitl.vehicle.virtual_flight import fly_virtual
    from sitl.vehicle.world import World, WorldSettings

__getattr__ = lazy_attributes(__name__, _HOME)

"""The simulated vehicle's PX4 personality over MAVLink 2.

Pure logic driven by simulation time, plus a thin UDP endpoint::

    from sitl.px4 import MavlinkEndpoint, Px4Params, Px4Vehicle, VehicleMeasurement

    vehicle = Px4Vehicle(Px4Params.from_scenario(scenario), aiding="vision")
    links = {"onboard": MavlinkEndpoint(14580, 14540), "gcs": MavlinkEndpoint(18570, 14550)}
    for endpoint in links.values():
        endpoint.open()
    # every plant step (simulation time t, measurement m in ENU / FLU):
    for name, endpoint in links.items():
        for msg in endpoint.receive():
            for link, reply in vehicle.handle(msg, name, t):
                links[link].send(reply)
    setpoint = vehicle.control(t, m)          # AttitudeSetpoint or None (disarmed)
    for link, msg in vehicle.telemetry(t, m):
        links[link].send(msg)
    plant.configure_autopilot(attitude_loop_params(vehicle.params))  # after a PARAM_SET

Modules: :mod:`~sitl.px4.vehicle` (message handling, the facade),
:mod:`~sitl.px4.commander` (arming, modes, offboard, failsafe, return, landing),
:mod:`~sitl.px4.position_control` (AUTO position loop),
:mod:`~sitl.px4.hover_thrust` (PX4's hover thrust estimator),
:mod:`~sitl.px4.streams` (streams, their rates per link and schedule),
:mod:`~sitl.px4.telemetry` (the NED / FRD messages),
:mod:`~sitl.px4.params` (parameter table and encoding), :mod:`~sitl.px4.modes`
(custom_mode encoding), :mod:`~sitl.px4.geo` (flat-earth lat / lon),
:mod:`~sitl.px4.measurement` (input), :mod:`~sitl.px4.endpoint` (UDP, signing).
"""

from sitl.px4.commander import ConsoleLine
from sitl.px4.endpoint import (
    GCS_PORTS,
    ONBOARD_PORTS,
    MavlinkEndpoint,
    SigningKeyError,
    load_signing_key,
)
from sitl.px4.geo import GeoReference
from sitl.px4.measurement import EstimatorReport, VehicleMeasurement
from sitl.px4.modes import Px4Mode
from sitl.px4.params import (
    PARAMETERS,
    ParamError,
    ParamSpec,
    Px4Params,
    UnknownParamError,
    attitude_loop_params,
)
from sitl.px4.streams import GCS_RATES_HZ, ONBOARD_RATES_HZ
from sitl.px4.telemetry import Home
from sitl.px4.vehicle import FLIGHT_SW_VERSION, Px4Vehicle

__all__ = [
    "FLIGHT_SW_VERSION",
    "GCS_PORTS",
    "GCS_RATES_HZ",
    "ONBOARD_PORTS",
    "ONBOARD_RATES_HZ",
    "PARAMETERS",
    "ConsoleLine",
    "EstimatorReport",
    "GeoReference",
    "Home",
    "MavlinkEndpoint",
    "ParamError",
    "ParamSpec",
    "Px4Mode",
    "Px4Params",
    "Px4Vehicle",
    "SigningKeyError",
    "UnknownParamError",
    "VehicleMeasurement",
    "attitude_loop_params",
    "load_signing_key",
]

"""JSBSim physics backend of the SITL: the same vehicle as ``sitl.physics.TruthPlant``
in underactuated mode, integrated by JSBSim, with atmosphere, wind, turbulence and ground.

Entry point::

    from sitl.physics.jsbsim import JsbsimPlant, Wind
    plant = JsbsimPlant.from_scenario(scenario, payload_attached=True,
                                      wind=Wind((3.0, 0.0, 0.0), "milspec", 7.7))
    state = plant.step(AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, 0.45), [0.0, 0.0])

Modules: :mod:`~sitl.physics.jsbsim.plant` (the plant and its stepping),
:mod:`~sitl.physics.jsbsim.fdm` (the JSBSim boundary: frames and units),
:mod:`~sitl.physics.jsbsim.airframe` (the aircraft file from a scenario),
:mod:`~sitl.physics.jsbsim.arm` (arm dynamics and the coupling wrench),
:mod:`~sitl.physics.jsbsim.wind` (wind and turbulence). ``aircraft/hexarotor/hexarotor.xml``
is the airframe of ``configs/paper_sim_flight.toml`` as generated (a reference copy that
JSBSim loads stand-alone; the plant generates its own for each scenario).
"""

from sitl.physics.jsbsim.airframe import GearGeometry, airframe_xml
from sitl.physics.jsbsim.plant import JsbsimError, JsbsimPlant
from sitl.physics.jsbsim.wind import Wind

__all__ = ["GearGeometry", "JsbsimError", "JsbsimPlant", "Wind", "airframe_xml"]

"""The hexacopter airframe for JSBSim, written from a scenario (JSBSim-ML, English units).

What goes into the aircraft file (``<fdm_config name="hexarotor">``):

``<planet>``
    A sphere of the WGS84 equatorial radius that does not rotate, with GM chosen so that
    gravity on the ground is ``environment.gravity_m_s2`` and J2 = 0: JSBSim's Earth
    would add latitude-dependent gravity (9.78-9.83 m/s^2), Coriolis and centrifugal
    terms that the rest of the project (and the Pinocchio plant) does not have.
``<mass_balance>``
    The vehicle body: ``vehicle.mass_kg`` and ``vehicle.inertia_kg_m2`` with its CG at the
    structural origin O (so O is the vehicle CoM, the origin of our q[0:3]). Four point
    masses stand for the arm (two per link, see :mod:`sitl.physics.jsbsim.arm`); the plant
    moves them every step through ``inertia/pointmass-*`` properties.
``<ground_reactions>``
    STRUCTURE contacts: the four feet of the landing gear, ``gear.height_m`` below O on a
    square of half-diagonal ``gear.radius_m``, and the six rotor hubs (so that a vehicle
    that flips over lands on them instead of hanging from its feet below the ground).
    Spring and damping carry the whole vehicle with a few millimetres of deflection, near
    critical damping.
``<aerodynamics>``
    Empty body axes: no aerodynamic model (the drag is an external reaction below).
``<external_reactions>``
    ``rotor0`` .. ``rotor5``: body-frame forces at the rotor hubs (geometry of
    :class:`sitl.physics.rotors.RotorGeometry`), along body -z of JSBSim (FRD), i.e. up;
    ``rotor-yaw``: the rotors' summed reaction moment; ``arm-moment``: the arm's coupling
    moment (:mod:`sitl.physics.jsbsim.arm`); ``drag-north`` /
    ``drag-east`` / ``drag-down``: the linear drag ``-D (v - w)`` of
    ``plant.linear_drag_n_s_m`` on the velocity relative to the air, in the local NED
    frame, evaluated by JSBSim from its own wind and turbulence (``atmosphere/total-wind-*``).

Frames: JSBSim's structural frame has X aft, Y right, Z up (inches); its body frame is FRD.
A point p = (x, y, z) of our FLU body frame, from O, is at structural (-x, -y, z).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from sitl.physics.rotors import N_ROTORS, RotorGeometry
from sitl.scenario import Scenario

__all__ = [
    "AIRCRAFT_NAME",
    "ARM_POINT_MASSES",
    "FT_M",
    "LBF_N",
    "LBM_KG",
    "PACKAGE_ROOT",
    "SEA_LEVEL_RADIUS_M",
    "GearGeometry",
    "airframe_xml",
    "structural_in",
]

AIRCRAFT_NAME = "hexarotor"
PACKAGE_ROOT = Path(__file__).parent
"""JSBSim root directory of this backend: ``aircraft/hexarotor/hexarotor.xml`` lives here."""

FT_M = 0.3048
"""One foot [m]."""
IN_M = 0.0254
"""One inch [m]."""
LBF_N = 4.4482216152605
"""One pound-force [N]."""
LBM_KG = 0.45359237
"""One pound-mass [kg] (JSBSim weights are pounds of mass)."""
SLUG_PER_LBM_INV = 32.174049
"""Pounds of mass in a slug (JSBSim's lbtoslug is its inverse)."""
SEA_LEVEL_RADIUS_M = 6378137.0
"""Radius of the spherical planet: the WGS84 equatorial radius [m]."""
ARM_POINT_MASSES = 4
"""Point masses that stand for the arm: two per link."""


@dataclass(frozen=True)
class GearGeometry:
    """Landing gear of the airframe (not in the scenario config: assumed values).

    Attributes
    ----------
    height_m : float
        Height of the feet below the vehicle CoM O [m]. Default 0.2 m: a Firefly-class
        gear; the arm, which hangs lower, has no ground contact (see the plant docstring).
    radius_m : float
        Distance of each foot from the vertical through O [m] (feet at 45, 135, 225 and
        315 deg azimuth).
    spring_n_m, damping_n_s_m : float
        Stiffness [N/m] and damping [N s/m] of each foot.
    static_friction, dynamic_friction : float
        Friction coefficients of a foot on the ground.
    """

    height_m: float = 0.2
    radius_m: float = 0.15
    spring_n_m: float = 3000.0
    damping_n_s_m: float = 60.0
    static_friction: float = 0.8
    dynamic_friction: float = 0.5

    def __post_init__(self) -> None:
        for name in ("height_m", "radius_m", "spring_n_m", "damping_n_s_m"):
            value = getattr(self, name)
            if not value > 0.0:
                raise ValueError(f"GearGeometry.{name} must be positive, got {value!r}")


def structural_in(p_flu_m: tuple[float, float, float]) -> tuple[float, float, float]:
    """Structural-frame coordinates [in] of a body point given in FLU from O [m]."""
    return (-p_flu_m[0] / IN_M, -p_flu_m[1] / IN_M, p_flu_m[2] / IN_M)


def _sub(parent: ET.Element, tag: str, text: float | str | None = None, **attrs: str) -> ET.Element:
    el = ET.SubElement(parent, tag, attrs)
    if text is not None:
        el.text = f"{text + 0.0:.15g}" if isinstance(text, float) else str(text)
    return el


def _triplet(parent: ET.Element, tag: str, xyz: tuple[float, float, float], **attrs: str) -> None:
    el = _sub(parent, tag, **attrs)
    for axis, value in zip("xyz", xyz, strict=True):
        _sub(el, axis, float(value))


def _planet(root: ET.Element, gravity_m_s2: float) -> None:
    planet = _sub(root, "planet", name="flat-nonrotating")
    radius_ft = SEA_LEVEL_RADIUS_M / FT_M
    _sub(planet, "semimajor_axis", radius_ft, unit="FT")
    _sub(planet, "semiminor_axis", radius_ft, unit="FT")
    _sub(planet, "rotation_rate", 0.0, unit="RAD/SEC")
    _sub(planet, "GM", gravity_m_s2 / FT_M * radius_ft**2, unit="FT3/SEC2")
    _sub(planet, "J2", 0.0)


def _metrics(root: ET.Element, scenario: Scenario) -> None:
    span = 2.0 * scenario.vehicle.rotors.arm_length_m
    metrics = _sub(root, "metrics")
    _sub(metrics, "wingarea", span * span, unit="M2")
    _sub(metrics, "wingspan", span, unit="M")
    _sub(metrics, "chord", span, unit="M")
    for name in ("AERORP", "EYEPOINT", "VRP"):
        _triplet(metrics, "location", (0.0, 0.0, 0.0), name=name, unit="M")


def _mass_balance(root: ET.Element, scenario: Scenario) -> None:
    vehicle = scenario.vehicle
    mass = _sub(root, "mass_balance")
    # English units written here: JSBSim's own KG*M2 -> SLUG*FT2 factor is off by 1e-4.
    slug_ft2 = LBM_KG * SLUG_PER_LBM_INV * FT_M * FT_M
    for axis, value in zip(("ixx", "iyy", "izz"), vehicle.inertia_kg_m2, strict=True):
        _sub(mass, axis, float(value) / slug_ft2, unit="SLUG*FT2")
    for axis in ("ixy", "ixz", "iyz"):
        _sub(mass, axis, 0.0, unit="SLUG*FT2")
    _sub(mass, "emptywt", float(vehicle.mass_kg) / LBM_KG, unit="LBS")
    _triplet(mass, "location", (0.0, 0.0, 0.0), name="CG", unit="M")
    mount = structural_in(tuple(scenario.arm.mount_point_m))  # type: ignore[arg-type]
    for i in range(ARM_POINT_MASSES):
        pm = _sub(mass, "pointmass", name=f"arm{i}")
        _sub(pm, "weight", 0.0, unit="LBS")
        _triplet(pm, "location", mount, unit="IN")


def _ground_reactions(root: ET.Element, gear: GearGeometry, hubs: list[tuple]) -> None:
    ground = _sub(root, "ground_reactions")
    r = gear.radius_m / 2.0**0.5
    feet = [(r, r, -gear.height_m), (-r, r, -gear.height_m)]
    feet += [(-r, -r, -gear.height_m), (r, -r, -gear.height_m)]
    points = [(f"foot{i}", p) for i, p in enumerate(feet)]
    points += [(f"hub{i}", p) for i, p in enumerate(hubs)]
    for name, p in points:
        contact = _sub(ground, "contact", type="STRUCTURE", name=name)
        _triplet(contact, "location", structural_in(p), unit="IN")
        _sub(contact, "static_friction", gear.static_friction)
        _sub(contact, "dynamic_friction", gear.dynamic_friction)
        _sub(contact, "spring_coeff", gear.spring_n_m, unit="N/M")
        _sub(contact, "damping_coeff", gear.damping_n_s_m, unit="N/M/SEC")


def _drag_function(parent: ET.Element, axis: str, drag_n_s_m: float) -> None:
    """magnitude [lbf] = -D [lbf s/ft] * (v_axis - wind_axis) [ft/s]."""
    product = _sub(_sub(parent, "function"), "product")
    _sub(product, "value", -drag_n_s_m * FT_M / LBF_N)
    difference = _sub(product, "difference")
    _sub(difference, "property", f"velocities/v-{axis}-fps")
    _sub(difference, "property", f"atmosphere/total-wind-{axis}-fps")


def _external_reactions(root: ET.Element, scenario: Scenario) -> None:
    rotors = scenario.vehicle.rotors
    geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
    ext = _sub(root, "external_reactions")
    for i in range(N_ROTORS):
        force = _sub(ext, "force", name=f"rotor{i}", frame="BODY")
        hub = tuple(float(c) for c in geometry.positions_m[i])
        _triplet(force, "location", structural_in(hub), unit="IN")  # type: ignore[arg-type]
        _triplet(force, "direction", (0.0, 0.0, -1.0))
    _triplet(_sub(ext, "moment", name="rotor-yaw", frame="BODY"), "direction", (0.0, 0.0, 1.0))
    _triplet(_sub(ext, "moment", name="arm-moment", frame="BODY"), "direction", (0.0, 0.0, 1.0))
    # linear_drag_n_s_m is (world x = east, y = north, z = up); NED axes here.
    d_east, d_north, d_up = (float(d) for d in scenario.plant.linear_drag_n_s_m)
    for axis, drag, direction in (
        ("north", d_north, (1.0, 0.0, 0.0)),
        ("east", d_east, (0.0, 1.0, 0.0)),
        ("down", d_up, (0.0, 0.0, 1.0)),
    ):
        force = _sub(ext, "force", name=f"drag-{axis}", frame="LOCAL")
        _drag_function(force, axis, drag)
        _triplet(force, "location", (0.0, 0.0, 0.0), unit="IN")
        _triplet(force, "direction", direction)


def airframe_xml(scenario: Scenario, gear: GearGeometry = GearGeometry()) -> str:
    """The JSBSim aircraft file of a validated scenario (see the module docstring)."""
    root = ET.Element("fdm_config", name=AIRCRAFT_NAME, version="2.0", release="BETA")
    header = _sub(root, "fileheader")
    _sub(header, "author", "sitl.physics.jsbsim.airframe")
    _sub(header, "description", f"Hexacopter of scenario '{scenario.name}' (generated)")
    _planet(root, scenario.environment.gravity_m_s2)
    _metrics(root, scenario)
    _mass_balance(root, scenario)
    rotors = scenario.vehicle.rotors
    geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
    _ground_reactions(root, gear, [tuple(float(c) for c in p) for p in geometry.positions_m])
    _sub(root, "propulsion")
    aero = _sub(root, "aerodynamics")  # no aerodynamic model: drag is an external reaction
    for axis in ("X", "Y", "Z", "ROLL", "PITCH", "YAW"):
        _sub(aero, "axis", name=axis)
    _external_reactions(root, scenario)
    ET.indent(root, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"

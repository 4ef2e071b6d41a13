"""The JSBSim boundary: one FGFDMExec with the hexarotor airframe, in our frames and SI units.

Everything that crosses into JSBSim goes through :class:`HexarotorFdm`, which converts once:
world ENU <-> JSBSim's local NED, body FLU <-> FRD, metres/newtons/kilograms <->
feet/pounds/inches. World position: the planet is a non-rotating sphere
(:mod:`sitl.physics.jsbsim.airframe`), the world origin is at latitude = longitude = 0 on
the ground, x east = R * longitude, y north = R * latitude, z up = height above the ground
(flat to 1e-7 over a kilometre).

JSBSim's location and velocity are those of the CG of the whole vehicle (arm point masses
included); attitude ZYX Euler angles in NED/FRD (phi_n, theta_n, psi_n) are
R_ENU<-FLU = Rz(pi/2 - psi_n) Ry(-theta_n) Rx(phi_n) in ours.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import jsbsim
import numpy as np

from sitl.physics.errors import PlantError
from sitl.physics.frames import Rot9, rotation_from_euler
from sitl.physics.jsbsim.airframe import (
    AIRCRAFT_NAME,
    ARM_POINT_MASSES,
    FT_M,
    LBF_N,
    LBM_KG,
    PACKAGE_ROOT,
    SEA_LEVEL_RADIUS_M,
    GearGeometry,
    airframe_xml,
    structural_in,
)
from sitl.physics.jsbsim.wind import Wind
from sitl.physics.rotors import N_ROTORS
from sitl.scenario import Scenario

__all__ = ["FdmReading", "HexarotorFdm", "JsbsimError"]

Vec3 = tuple[float, float, float]
_LBF_FT_N_M = LBF_N * FT_M
_HALF_PI = 0.5 * math.pi
_TWO_PI = 2.0 * math.pi

_READ = (
    "position/lat-geod-rad",
    "position/long-gc-rad",
    "position/h-sl-ft",
    "velocities/v-north-fps",
    "velocities/v-east-fps",
    "velocities/v-down-fps",
    "velocities/p-rad_sec",
    "velocities/q-rad_sec",
    "velocities/r-rad_sec",
    "accelerations/pdot-rad_sec2",
    "accelerations/qdot-rad_sec2",
    "accelerations/rdot-rad_sec2",
    "forces/fbx-total-lbs",
    "forces/fby-total-lbs",
    "forces/fbz-total-lbs",
    "attitude/phi-rad",
    "attitude/theta-rad",
    "attitude/psi-rad",
)
"""Read after every ``run()``: CG position and velocity (NED), body rates (FRD), JSBSim's
accelerations for the next step, total non-gravitational body force, attitude."""


class JsbsimError(PlantError):
    """JSBSim refused the generated airframe or an initial condition."""


@dataclass(frozen=True)
class FdmReading:
    """JSBSim's state after a ``run()``, in our frames and SI units.

    Attributes
    ----------
    finite : bool
        False if JSBSim's state is no longer finite (the other fields are then garbage).
    cg_position_m, cg_velocity_m_s : tuple of 3 float
        CG of the whole vehicle, world ENU [m, m/s].
    rotation : tuple of 9 float
        R (body FLU to world ENU), row-major.
    omega_rad_s, omega_dot_rad_s2 : tuple of 3 float
        Body rate and the angular acceleration JSBSim integrates over the next step, FLU.
    force_n : tuple of 3 float
        Total non-gravitational external force (rotors, drag, gear, coupling) acting over
        the next step, body FLU [N].
    """

    finite: bool
    cg_position_m: Vec3
    cg_velocity_m_s: Vec3
    rotation: Rot9
    omega_rad_s: Vec3
    omega_dot_rad_s2: Vec3
    force_n: Vec3


class HexarotorFdm:
    """An FGFDMExec with a scenario's airframe, rooted in this package's directory.

    The airframe is generated into a temporary aircraft directory that only lives while
    JSBSim parses it (JSBSim has no load-from-string); the engine and systems paths point
    into the package, so nothing of JSBSim's shipped aircraft is used.

    Raises
    ------
    JsbsimError
        If JSBSim cannot load the airframe.
    """

    def __init__(self, scenario: Scenario, gear: GearGeometry, dt_s: float) -> None:
        jsbsim.FGJSBBase().debug_lvl = 0  # JSBSim prints its banner and load log otherwise
        fdm = jsbsim.FGFDMExec(str(PACKAGE_ROOT))
        fdm.set_debug_level(0)
        with tempfile.TemporaryDirectory(prefix="hexarotor-") as tmp:
            folder = Path(tmp) / AIRCRAFT_NAME
            folder.mkdir()
            (folder / f"{AIRCRAFT_NAME}.xml").write_text(airframe_xml(scenario, gear))
            root = str(PACKAGE_ROOT)
            if not fdm.load_model_with_paths(AIRCRAFT_NAME, tmp, root, root):
                raise JsbsimError(
                    f"JSBSim could not load the airframe of scenario {scenario.name!r}"
                )
        fdm.set_dt(dt_s)
        self._fdm = fdm
        self._properties = fdm.get_property_manager()
        self._read = [self._node(p) for p in _READ]
        self._rotors = [
            self._node(f"external_reactions/rotor{i}/magnitude") for i in range(N_ROTORS)
        ]
        self._yaw = self._node("external_reactions/rotor-yaw/magnitude-lbsft")
        self._moment = [self._node(f"external_reactions/arm-moment/{c}") for c in "lmn"]
        self._node("external_reactions/arm-moment/magnitude-lbsft").set_double_value(1.0)
        self._masses = [
            [
                self._node(f"inertia/pointmass-weight-lbs[{i}]"),
                self._node(f"inertia/pointmass-location-X-inches[{i}]"),
                self._node(f"inertia/pointmass-location-Y-inches[{i}]"),
                self._node(f"inertia/pointmass-location-Z-inches[{i}]"),
            ]
            for i in range(ARM_POINT_MASSES)
        ]

    def _node(self, path: str) -> jsbsim.FGPropertyNode:
        node = self._properties.get_node(path, True)
        if node is None:  # not with create=True; JSBSim's stub allows it
            raise JsbsimError(f"JSBSim cannot create the property {path}")
        return node

    def __getitem__(self, path: str) -> float:
        """Any JSBSim property, in JSBSim's units (diagnostics and tests)."""
        return float(self._fdm[path])

    # ------------------------------------------------------------------ inputs

    def set_rotors(self, thrusts_n: list[float], yaw_moment_n_m: float) -> None:
        """Six rotor thrusts [N] (at the hubs, along body z) and their summed reaction
        moment about body z (FLU) [N m]."""
        for node, thrust in zip(self._rotors, thrusts_n, strict=True):
            node.set_double_value(thrust / LBF_N)
        self._yaw.set_double_value(-yaw_moment_n_m / _LBF_FT_N_M)

    def set_coupling_moment(self, moment_n_m: Vec3) -> None:
        """The arm's coupling moment, body FLU [N m]."""
        mx, my, mz = moment_n_m
        for node, value in zip(self._moment, (mx, -my, -mz), strict=True):
            node.set_double_value(value / _LBF_FT_N_M)

    def set_point_masses(self, masses: list[tuple[float, Vec3]]) -> None:
        """The arm's point masses: (mass [kg], position from O in body FLU [m])."""
        for nodes, (mass, s) in zip(self._masses, masses, strict=True):
            x, y, z = structural_in(s)
            nodes[0].set_double_value(mass / LBM_KG)
            nodes[1].set_double_value(x)
            nodes[2].set_double_value(y)
            nodes[3].set_double_value(z)

    # ------------------------------------------------------------------- state

    def start(
        self,
        cg_position_m: np.ndarray,
        cg_velocity_m_s: np.ndarray,
        euler_rad: tuple[float, float, float],
        omega_rad_s: np.ndarray,
        wind: Wind,
    ) -> FdmReading:
        """Initial condition (CG in world ENU, ZYX Euler ENU/FLU, body rate FLU) and wind;
        height above ground set explicitly (terrain at world z = 0)."""
        phi, theta, psi = euler_rad
        p, v = cg_position_m, cg_velocity_m_s
        for path, value in (
            ("ic/phi-rad", phi),
            ("ic/theta-rad", -theta),
            ("ic/psi-true-rad", (_HALF_PI - psi) % _TWO_PI),
            ("ic/lat-geod-rad", p[1] / SEA_LEVEL_RADIUS_M),
            ("ic/long-gc-rad", p[0] / SEA_LEVEL_RADIUS_M),
            ("ic/terrain-elevation-ft", 0.0),
            ("ic/h-agl-ft", p[2] / FT_M),
            ("ic/vn-fps", v[1] / FT_M),
            ("ic/ve-fps", v[0] / FT_M),
            ("ic/vd-fps", -v[2] / FT_M),
            ("ic/p-rad_sec", omega_rad_s[0]),
            ("ic/q-rad_sec", -omega_rad_s[1]),
            ("ic/r-rad_sec", -omega_rad_s[2]),
        ):
            self._fdm[path] = float(value)
        if not self._fdm.run_ic():
            raise JsbsimError("JSBSim rejected the initial condition")
        for path, value in wind.properties().items():  # run_ic resets the wind
            self._fdm[path] = value
        return self.read()

    def run(self) -> FdmReading:
        """One JSBSim step (see the plant docstring for its timing)."""
        self._fdm.run()
        return self.read()

    def read(self) -> FdmReading:
        """The state now, converted (see :class:`FdmReading`)."""
        values = [n.get_double_value() for n in self._read]
        lat, lon, h, vn, ve, vd, p, q, r, pd, qd, rd, fx, fy, fz, phi, theta, psi = values
        rot = rotation_from_euler(phi, -theta, _HALF_PI - psi).reshape(9).tolist()
        return FdmReading(
            finite=math.isfinite(sum(values)),
            cg_position_m=(lon * SEA_LEVEL_RADIUS_M, lat * SEA_LEVEL_RADIUS_M, h * FT_M),
            cg_velocity_m_s=(ve * FT_M, vn * FT_M, -vd * FT_M),
            rotation=tuple(rot),  # type: ignore[arg-type]
            omega_rad_s=(p, -q, -r),
            omega_dot_rad_s2=(pd, -qd, -rd),
            force_n=(fx * LBF_N, -fy * LBF_N, -fz * LBF_N),
        )

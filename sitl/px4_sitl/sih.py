"""PX4's SIH vehicle (``simulator_sih``) matched to a scenario's hexacopter.

SIH is PX4's built-in rigid body: no arm, a hexacopter whose six motors make thrust
``SIH_T_MAX * u`` each (linear in the command u, as PX4 with ``THR_MDL_FAC = 0``) through
a first-order lag ``SIH_T_TAU``, yaw moment ``SIH_Q_MAX * u``, roll and pitch arms from
``SIH_L_ROLL`` / ``SIH_L_PITCH`` (rotor 0 at (sqrt 3 / 2, 1 / 2) x arm, FRD), and linear
drag ``SIH_KDV`` (PX4 ``src/modules/simulation/simulator_sih/sih.cpp``). The arm is rigid
at its start pose: its mass adds to ``SIH_MASS`` and its links to the inertia about the
common centre of mass. The truth values are the scenario's (``plant.thrust_mismatch``
scales the rotors' maximum thrust). Plain geometry here, independent of
``companion.model``.
"""

from __future__ import annotations

import math

import numpy as np

from sitl.scenario import Scenario

__all__ = ["SihMismatchError", "sih_parameters"]


class SihMismatchError(ValueError):
    """The scenario's vehicle is one SIH cannot represent."""


def _rod_inertia(about_com_kg_m2: float, direction: np.ndarray) -> np.ndarray:
    """Inertia tensor [kg m^2] of a thin rod about its CoM: ``about_com`` about every axis
    perpendicular to ``direction`` (unit), none about the rod's axis."""
    return about_com_kg_m2 * (np.eye(3) - np.outer(direction, direction))


def sih_parameters(scenario: Scenario, joints_rad: tuple[float, float] | None = None) -> dict:
    """``SIH_*`` parameters of the scenario's vehicle with its arm held at ``joints_rad``
    (eta1, eta2) [rad] (default ``[world] start_joints_rad``, else link 1 forward and link
    2 down).

    Raises :class:`SihMismatchError` when the rotors' thrust curve is not linear
    (``vehicle.rotors.thr_mdl_fac`` > 0): SIH's motors are; and when the scenario has a
    ``plant.battery`` or a ``plant.wind_m_s``, which SIH does not model.
    """
    rotors = scenario.vehicle.rotors
    if rotors.thr_mdl_fac > 0.0:
        raise SihMismatchError(
            f"{scenario.name}: vehicle.rotors.thr_mdl_fac = {rotors.thr_mdl_fac:g}, but SIH "
            "motors are linear in the command: use a scenario with thr_mdl_fac = 0"
        )
    if scenario.plant.battery is not None:
        raise SihMismatchError(
            f"{scenario.name}: plant.battery is a truth model of sitl's own plants; SIH's "
            "thrust is PX4's: remove the section to fly SIH"
        )
    if any(scenario.plant.wind_m_s):
        raise SihMismatchError(
            f"{scenario.name}: plant.wind_m_s is a truth model of sitl's own plants; SIH "
            "flies PX4's own physics: set it to [0, 0, 0] to fly SIH"
        )
    if joints_rad is None:
        world = scenario.world
        eta1, eta2 = world.start_joints_rad if world else (0.0, -0.5 * math.pi)
    else:
        eta1, eta2 = joints_rad
    arm = scenario.arm
    u1 = np.array([math.cos(eta1), 0.0, math.sin(eta1)])
    u2 = np.array([math.cos(eta1 + eta2), 0.0, math.sin(eta1 + eta2)])
    mount = np.asarray(arm.mount_point_m, dtype=float)
    bodies = [
        (scenario.vehicle.mass_kg, np.zeros(3), np.diag(scenario.vehicle.inertia_kg_m2)),
        (
            arm.link1.mass_kg,
            mount + arm.link1.com_m * u1,
            _rod_inertia(arm.link1.inertia_about_com_kg_m2, u1),
        ),
        (
            arm.link2.mass_kg,
            mount + arm.link1.length_m * u1 + arm.link2.com_m * u2,
            _rod_inertia(arm.link2.inertia_about_com_kg_m2, u2),
        ),
    ]
    mass = sum(m for m, _, _ in bodies)
    com = sum(m * r for m, r, _ in bodies) / mass
    inertia = np.zeros((3, 3))
    for m, r, i_c in bodies:
        d = r - com
        inertia += i_c + m * (float(d @ d) * np.eye(3) - np.outer(d, d))
    # FLU -> FRD: y and z change sign, so the xy and xz products do too; yz does not.
    t_max = rotors.max_thrust_per_rotor_n * scenario.plant.thrust_mismatch
    drag = scenario.plant.linear_drag_n_s_m
    return {
        "SIH_MASS": round(mass, 6),
        "SIH_IXX": round(float(inertia[0, 0]), 7),
        "SIH_IYY": round(float(inertia[1, 1]), 7),
        "SIH_IZZ": round(float(inertia[2, 2]), 7),
        "SIH_IXY": round(-float(inertia[0, 1]), 7),
        "SIH_IXZ": round(-float(inertia[0, 2]), 7),
        "SIH_IYZ": round(float(inertia[1, 2]), 7),
        "SIH_T_MAX": round(t_max, 6),
        "SIH_Q_MAX": round(rotors.yaw_moment_per_thrust_m * t_max, 6),
        "SIH_L_ROLL": rotors.arm_length_m,
        "SIH_L_PITCH": rotors.arm_length_m,
        "SIH_T_TAU": rotors.motor_time_constant_s,
        "SIH_KDV": round(float(np.mean(drag[0:2])), 6),
    }

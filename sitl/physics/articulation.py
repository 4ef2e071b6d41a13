"""The Pinocchio model of the hexacopter + 2-DOF arm (truth; independent of companion.model).

Kinematic tree (DESIGN.md sections 2-3):

- ``base``: free-flyer joint whose frame is the vehicle body frame (FLU) at the vehicle
  CoM p; the vehicle body (m_b, diag(Ixx, Iyy, Izz)) sits at its origin. Pinocchio's
  configuration of it is ``[p (world), quaternion x, y, z, w]``, its velocity
  ``[v, omega]`` with both the linear velocity of p and the angular velocity in body axes.
- ``eta1``: revolute joint at body point r_a. Its placement is rotated by Rx(pi), so that
  the joint frame's y axis is body -y and Pinocchio's plain RY joint turns about body -y:
  the joint angle *is* eta1 (no sign flip) and the link frame's x axis is
  u1 = (cos eta1, 0, sin eta1) in the body frame.
- ``eta2``: RY joint at l1 along link 1's x axis (its y axis already is body -y); link 2's x
  axis is u2 = (cos(eta1 + eta2), 0, sin(eta1 + eta2)).

Each link is a mass on its own axis: mass m, CoM at ``com_m`` on the link x axis, inertia
about the CoM diag(0, I, I) in the link frame (``inertia_about_com_kg_m2``). Servo armature
goes in ``model.armature`` on the two joint dofs. A payload is the same kind of body,
rigidly on link 2's axis; attaching it adds its spatial inertia to link 2's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from companion.config import Link, Theta
from sitl.scenario import Scenario

__all__ = ["Articulation", "build_articulation", "line_inertia", "theta_of"]

BASE_JOINT = 1
ETA1_JOINT = 2
ETA2_JOINT = 3
"""Pinocchio joint indices (0 is the universe)."""

_RX_PI = np.diag([1.0, -1.0, -1.0])
"""Rotation by pi about x: maps y to -y and z to -z."""


def line_inertia(mass_kg: float, com_m: float, inertia_about_com_kg_m2: float) -> pin.Inertia:
    """Spatial inertia of a body on the frame's x axis (CoM at ``com_m``, diag(0, I, I))."""
    i = inertia_about_com_kg_m2
    return pin.Inertia(mass_kg, np.array([com_m, 0.0, 0.0]), np.diag([0.0, i, i]))


def theta_of(inertia: pin.Inertia) -> Theta:
    """(m2, m3, m4) of a body on the x axis of its joint frame (whose axis is y).

    m2 is the mass, m3 the first moment along x, m4 the moment of inertia about the
    joint's y axis (parallel-axis theorem).
    """
    mass = float(inertia.mass)
    lever = np.asarray(inertia.lever)
    m4 = float(inertia.inertia[1, 1]) + mass * float(lever[0] ** 2 + lever[2] ** 2)
    return Theta(m2_kg=mass, m3_kg_m=mass * float(lever[0]), m4_kg_m2=m4)


def _link_inertia(link: Link) -> pin.Inertia:
    return line_inertia(link.mass_kg, link.com_m, link.inertia_about_com_kg_m2)


@dataclass(frozen=True)
class Articulation:
    """A built model plus the pieces needed to change link 2 at run time.

    Attributes
    ----------
    model : pinocchio.Model
        nq = 9 (position, quaternion xyzw, eta1, eta2), nv = 8 (v_body, omega_body, eta_dot).
        Link 2's inertia in it is mutable (payload attach/detach).
    link2_empty : pinocchio.Inertia
        Link 2 without payload, in link 2's joint frame.
    payload : pinocchio.Inertia
        The configured payload, in link 2's joint frame.
    """

    model: pin.Model
    link2_empty: pin.Inertia
    payload: pin.Inertia


def build_articulation(scenario: Scenario) -> Articulation:
    """Pinocchio model of a validated scenario, link 2 empty (no payload)."""
    model = pin.Model()
    model.name = f"truth:{scenario.name}"
    model.gravity.linear = np.array([0.0, 0.0, -scenario.environment.gravity_m_s2])

    vehicle = scenario.vehicle
    base = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.appendBodyToJoint(
        base,
        pin.Inertia(vehicle.mass_kg, np.zeros(3), np.diag(vehicle.inertia_kg_m2)),
        pin.SE3.Identity(),
    )

    arm = scenario.arm
    eta1 = model.addJoint(
        base, pin.JointModelRY(), pin.SE3(_RX_PI, np.array(arm.mount_point_m)), "eta1"
    )
    model.appendBodyToJoint(eta1, _link_inertia(arm.link1), pin.SE3.Identity())
    eta2 = model.addJoint(
        eta1,
        pin.JointModelRY(),
        pin.SE3(np.eye(3), np.array([arm.link1.length_m, 0.0, 0.0])),
        "eta2",
    )
    link2_empty = _link_inertia(arm.link2)
    model.appendBodyToJoint(eta2, link2_empty, pin.SE3.Identity())
    assert (base, eta1, eta2) == (BASE_JOINT, ETA1_JOINT, ETA2_JOINT)

    armature = np.zeros(model.nv)
    armature[6] = arm.link1.armature_kg_m2
    armature[7] = arm.link2.armature_kg_m2
    model.armature = armature

    load = scenario.payload
    payload = line_inertia(load.mass_kg, load.position_m, load.inertia_about_com_kg_m2)
    return Articulation(model=model, link2_empty=link2_empty, payload=payload)

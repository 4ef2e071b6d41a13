"""An independent reference for the aerial manipulator, built with Pinocchio's own joints.

The base is Translation -> RZ -> RY -> RX revolute joints (massless intermediates, the
vehicle body on RX), not JointModelSphericalZYX, whose Coriolis matrix is wrong
(pinocchio#2053). Pinocchio orders the Euler angles (psi, theta, phi); our joints rotate
about body -y, so they are RevoluteUnaligned joints with axis (0, -1, 0) and need no sign
change. Link 2 is given by theta = (m2, m3, m4), a mass distribution on its axis.
Shared by the model and truth-plant tests and by benchmarks/bench_model.py.
"""

import numpy as np
import pinocchio as pin

from sitl.scenario import Scenario

PERM = np.array([0, 1, 2, 5, 4, 3, 6, 7])
"""Our q index -> Pinocchio's index (and back: the permutation is its own inverse)."""


def line_inertia(mass: float, first: float, second: float) -> pin.Inertia:
    """A mass distribution on the frame's x axis: mass, first and second moment about 0."""
    com = first / mass
    i_com = second - mass * com**2
    return pin.Inertia(mass, np.array([com, 0.0, 0.0]), np.diag([0.0, i_com, i_com]))


def reference_model(cfg: Scenario, theta: tuple[float, float, float]) -> pin.Model:
    model = pin.Model()
    model.gravity.linear = np.array([0.0, 0.0, -cfg.environment.gravity_m_s2])
    parent = 0
    for joint in (
        pin.JointModelTranslation(),
        pin.JointModelRZ(),
        pin.JointModelRY(),
        pin.JointModelRX(),
    ):
        parent = model.addJoint(parent, joint, pin.SE3.Identity(), f"base_{joint.shortname()}")
    base = parent
    model.appendBodyToJoint(
        base,
        pin.Inertia(cfg.vehicle.mass_kg, np.zeros(3), np.diag(cfg.vehicle.inertia_kg_m2)),
        pin.SE3.Identity(),
    )
    axis = np.array([0.0, -1.0, 0.0])
    link1 = cfg.arm.link1
    j1 = model.addJoint(
        base,
        pin.JointModelRevoluteUnaligned(axis),
        pin.SE3(np.eye(3), np.array(cfg.arm.mount_point_m)),
        "eta1",
    )
    model.appendBodyToJoint(
        j1,
        line_inertia(link1.mass_kg, link1.first_moment_kg_m, link1.second_moment_kg_m2),
        pin.SE3.Identity(),
    )
    j2 = model.addJoint(
        j1,
        pin.JointModelRevoluteUnaligned(axis),
        pin.SE3(np.eye(3), np.array([link1.length_m, 0.0, 0.0])),
        "eta2",
    )
    model.appendBodyToJoint(j2, line_inertia(*theta), pin.SE3.Identity())
    model.armature = np.array([0.0] * 6 + [link1.armature_kg_m2, cfg.arm.link2.armature_kg_m2])
    return model

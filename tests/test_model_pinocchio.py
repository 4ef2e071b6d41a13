"""companion.model against an independent rigid-body library (Pinocchio).

The reference is built here from the configs with Pinocchio's own joints: the base as
Translation -> RZ -> RY -> RX revolute joints (massless intermediates, the vehicle body on
RX), not JointModelSphericalZYX, whose Coriolis matrix is wrong (pinocchio#2053). Pinocchio
orders the Euler angles (psi, theta, phi); our joints rotate about body -y, so they use
RevoluteUnaligned joints with axis (0, -1, 0) and need no sign change.
"""

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from companion.config import Scenario, load_scenario
from companion.model import ManipulatorModel

CONFIGS = Path(__file__).parent.parent / "configs"
PERM = np.array([0, 1, 2, 5, 4, 3, 6, 7])
"""Our q index -> Pinocchio's index (and back: the permutation is its own inverse)."""
N_STATES = 200


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


def thetas(cfg: Scenario) -> list[tuple[float, float, float]]:
    rng = np.random.default_rng(7)
    out = [cfg.true_theta.as_tuple(), cfg.nominal_theta.as_tuple()]
    for _ in range(2):
        m2 = rng.uniform(0.05, 1.0)
        lc = rng.uniform(0.0, cfg.arm.link2.length_m)
        out.append((m2, m2 * lc, m2 * lc**2 + rng.uniform(0.0, 1e-3)))
    return out


def random_states(rng: np.random.Generator, n: int) -> list[tuple[np.ndarray, ...]]:
    states = []
    for _ in range(n):
        q = np.concatenate(
            [
                rng.uniform(-5.0, 5.0, 3),
                rng.uniform(-1.2, 1.2, 2),
                rng.uniform(-np.pi, np.pi, 1),
                rng.uniform(-np.pi, np.pi, 2),
            ]
        )
        states.append((q, rng.normal(0.0, 1.5, 8), rng.normal(0.0, 1.5, 8)))
    return states


@pytest.mark.parametrize("config", ["paper_sim.toml", "experiment_arm.toml"])
def test_matches_pinocchio(config: str) -> None:
    cfg = load_scenario(CONFIGS / config)
    ours = ManipulatorModel.from_scenario(cfg)
    rng = np.random.default_rng(2024)
    checked = 0
    for theta in thetas(cfg):
        ref = reference_model(cfg, theta)
        data = ref.createData()
        for q, q_dot, qr_dot in random_states(rng, N_STATES // 4 + 1):
            qp, vp, vrp = q[PERM], q_dot[PERM], qr_dot[PERM]
            m_ref = pin.crba(ref, data, qp)
            m_ref = np.triu(m_ref) + np.triu(m_ref, 1).T
            c_ref = pin.computeCoriolisMatrix(ref, data, qp, vp).copy()
            g_ref = pin.computeGeneralizedGravity(ref, data, qp)
            nle = pin.nonLinearEffects(ref, data, qp, vp)

            terms = ours.terms(q, q_dot)
            m = terms.mass_matrix(theta)
            c = terms.coriolis_matrix(theta)
            g = terms.gravity(theta)
            np.testing.assert_allclose(m[np.ix_(PERM, PERM)], m_ref, rtol=0, atol=1e-9)
            np.testing.assert_allclose((c @ q_dot)[PERM], c_ref @ vp, rtol=0, atol=1e-9)
            np.testing.assert_allclose((c @ qr_dot)[PERM], c_ref @ vrp, rtol=0, atol=1e-9)
            np.testing.assert_allclose(g[PERM], g_ref, rtol=0, atol=1e-9)
            np.testing.assert_allclose((c @ q_dot + g)[PERM], nle, rtol=0, atol=1e-9)
            checked += 1
    assert checked >= N_STATES


def test_reference_includes_armature() -> None:
    """Guards the reference itself: Pinocchio's CRBA must add the armature we set."""
    cfg = load_scenario(CONFIGS / "paper_sim.toml")
    theta = cfg.true_theta.as_tuple()
    ref = reference_model(cfg, theta)
    without = reference_model(cfg, theta)
    without.armature = np.zeros(8)
    q = np.zeros(8)
    delta = pin.crba(ref, ref.createData(), q) - pin.crba(without, without.createData(), q)
    expected = np.diag([0.0] * 6 + [cfg.arm.link1.armature_kg_m2, cfg.arm.link2.armature_kg_m2])
    np.testing.assert_allclose(np.triu(delta), expected, atol=1e-12)

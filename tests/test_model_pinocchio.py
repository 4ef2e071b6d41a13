"""companion.model against an independent rigid-body library (Pinocchio).

The reference (tests/pinocchio_reference.py) is built from the configs with Pinocchio's
own joints; see there for the joint layout and conventions.
"""

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from pinocchio_reference import PERM, reference_model

from companion.model import ManipulatorModel
from sitl.scenario import Scenario, load_scenario

CONFIGS = Path(__file__).parent.parent / "configs"
N_STATES = 200


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
    ours = ManipulatorModel.from_config(cfg)
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

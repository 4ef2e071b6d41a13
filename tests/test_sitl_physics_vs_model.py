"""The truth plant against companion.model: two independent derivations must agree.

sitl.physics shares no code with companion.model (Pinocchio's ABA on a free-flyer vs the
sympy-derived M, C, G in Euler coordinates); agreement here checks both. Only public APIs
of the two packages are used.
"""

from pathlib import Path

import numpy as np
import pytest

from companion.model import ManipulatorModel
from sitl.physics import TruthPlant
from sitl.scenario import load_scenario

CONFIGS = Path(__file__).parent.parent / "configs"


@pytest.mark.parametrize("name", ["paper_sim.toml", "experiment_arm.toml"])
@pytest.mark.parametrize("payload", [False, True])
def test_plant_acceleration_solves_the_model_equation(name, payload) -> None:
    """M(q) q_ddot + C(q, q_dot) q_dot + G(q) = tau with the plant's q_ddot and true theta."""
    cfg = load_scenario(CONFIGS / name)
    model = ManipulatorModel.from_config(cfg)
    plant = TruthPlant.from_scenario(cfg, payload_attached=payload)
    theta = plant.true_theta.as_tuple()
    rng = np.random.default_rng(21)
    for _ in range(30):
        q = np.concatenate(
            (
                rng.uniform(-2, 2, 3),
                rng.uniform(-1.2, 1.2, 2),
                rng.uniform(-3, 3, 1),
                rng.uniform(-2.5, 0.5, 2),
            )
        )
        q_dot = rng.normal(size=8)
        tau = rng.normal(scale=5.0, size=8)
        plant.reset(q, q_dot)
        q_ddot = plant.acceleration(tau)
        m, c, g = model.terms(q, q_dot).evaluate(theta)
        np.testing.assert_allclose(m @ q_ddot + c @ q_dot + g, tau, rtol=1e-9, atol=1e-9)


def test_potential_energy_agrees() -> None:
    cfg = load_scenario(CONFIGS / "paper_sim.toml")
    model = ManipulatorModel.from_config(cfg)
    plant = TruthPlant.from_scenario(cfg, payload_attached=True)
    q = np.array([0.3, -0.2, 1.1, 0.2, -0.3, 0.7, -0.6, 1.1])
    plant.reset(q, np.linspace(-1.0, 1.0, 8))
    theta = plant.true_theta.as_tuple()
    assert plant.potential_energy_j == pytest.approx(model.potential_energy(q, theta), rel=1e-12)
    assert plant.kinetic_energy_j == pytest.approx(
        model.kinetic_energy(q, np.linspace(-1.0, 1.0, 8), theta), rel=1e-12
    )

"""companion.calibration.servo: the plan and the least-squares fits, on synthetic readings."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from companion.calibration.servo import (
    fit_friction,
    fit_torque_constant,
    model_torque_n_m,
    static_poses,
    sweep_corners,
)
from companion.config import load_config
from companion.model import ManipulatorModel

CONFIG = Path(__file__).parent.parent / "configs" / "sitl_pickup.toml"
STEP_A = 2.69e-3
"""The XM430's current reading step [A]."""
LIMITS = [(-2.618, 0.524), (-2.094, 2.094)]


@pytest.fixture(scope="module")
def arm():
    cfg = load_config(CONFIG)
    return ManipulatorModel.from_config(cfg), cfg.nominal_theta.as_tuple()


def quantized(current_a: np.ndarray) -> np.ndarray:
    """What a servo reports: the current rounded to its step."""
    return np.round(current_a / STEP_A) * STEP_A


def test_static_poses_are_a_serpentine_grid_inside_the_limits_with_a_margin() -> None:
    poses = static_poses(LIMITS, levels=3, margin=0.1)
    assert len(poses) == 9
    for k, (low, high) in enumerate(LIMITS):
        angles = [pose[k] for pose in poses]
        span = high - low
        assert min(angles) == pytest.approx(low + 0.1 * span)
        assert max(angles) == pytest.approx(high - 0.1 * span)
    assert [p[1] for p in poses[:6]] == [p[1] for p in poses[:3]] + [p[1] for p in poses[:3]][::-1]
    low, high = sweep_corners(LIMITS, margin=0.1)
    assert low == (poses[0][0], poses[0][1]) and high[0] == poses[-1][0]


def test_model_torque_at_rest_is_the_gravity_of_the_joint_rows(arm) -> None:
    model, theta = arm
    eta = np.array([[-0.3, 0.8], [-1.5, -0.2]])
    tau = model_torque_n_m(model, theta, eta, np.zeros_like(eta))
    for k in range(2):
        q = np.zeros(8)
        q[6:8] = eta[k]
        np.testing.assert_allclose(tau[k], model.gravity(q, theta)[6:8])
    # link 1 forward, link 2 down: joint 1 carries link 2's weight at l1, joint 2 none
    level = model_torque_n_m(model, theta, [[0.0, -math.pi / 2]], [[0.0, 0.0]])[0]
    assert level[0] > 0.1 and abs(level[1]) < 1e-9


def test_model_torque_follows_the_vehicle_attitude(arm) -> None:
    """Pitched by 0.2 rad the arm's gravity torque is the model's at that attitude: the
    level arm's torque at the joint angles turned by the pitch."""
    model, theta = arm
    eta = np.array([[0.0, -0.8]])
    pitched = model_torque_n_m(model, theta, eta, np.zeros_like(eta), [[0.0, 0.2]])[0]
    q = np.zeros(8)
    q[4], q[6:8] = 0.2, eta[0]
    np.testing.assert_allclose(pitched, model.gravity(q, theta)[6:8])
    level = model_torque_n_m(model, theta, eta, np.zeros_like(eta))[0]
    assert abs(pitched[1] - level[1]) > 0.01 * abs(level[1])


@pytest.mark.parametrize("kt", [1.6, 1.96])
def test_the_torque_constant_comes_back_from_rounded_currents(arm, kt: float) -> None:
    model, theta = arm
    eta = np.array(static_poses(LIMITS))
    tau = model_torque_n_m(model, theta, eta, np.zeros_like(eta))
    for k in range(2):
        fit = fit_torque_constant(tau[:, k], quantized(tau[:, k] / kt), STEP_A)
        assert fit.problem is None
        assert fit.torque_constant_n_m_per_a == pytest.approx(kt, rel=0.01)
        assert fit.relative_standard_error < 0.01
        assert fit.residual_rms_n_m < kt * STEP_A


def test_too_little_gravity_torque_is_refused() -> None:
    tau = np.linspace(-0.01, 0.01, 8)  # a joint whose axis is nearly vertical
    fit = fit_torque_constant(tau, quantized(tau / 1.78), STEP_A)
    assert fit.problem is not None and "too little gravity torque" in fit.problem


def test_a_current_against_gravity_is_refused() -> None:
    tau = np.linspace(-0.2, 0.2, 8)
    fit = fit_torque_constant(tau, quantized(-tau / 1.78), STEP_A)  # direction flipped
    assert fit.problem is not None and "positive constant" in fit.problem


def test_a_scattered_current_is_a_poor_fit() -> None:
    rng = np.random.default_rng(4)
    tau = np.linspace(-0.2, 0.2, 8)
    fit = fit_torque_constant(tau, tau / 1.78 + rng.normal(0.0, 0.02, 8), STEP_A)
    assert fit.problem is not None and fit.problem.startswith("poor fit")


def sweep(speeds: tuple[float, ...], samples: int = 200) -> np.ndarray:
    return np.concatenate([np.full(samples, s * d) for s in speeds for d in (1.0, -1.0)])


def rounded(torque_n_m: np.ndarray, kt: float = 1.78) -> np.ndarray:
    """A friction torque as read through a rounded current (plus a gravity torque that
    sweeps the rounding), less that gravity torque."""
    gravity = np.linspace(-0.2, 0.2, torque_n_m.size)
    return kt * quantized((torque_n_m + gravity) / kt) - gravity


def test_viscous_friction_alone_drops_the_coulomb_term() -> None:
    rate = sweep((0.5, 1.5))
    fit = fit_friction(rate, rounded(0.02 * rate), 1.78 * STEP_A)
    assert fit.problem is None
    assert fit.viscous_friction_n_m_s_per_rad == pytest.approx(0.02, rel=0.05)
    assert fit.coulomb_friction_n_m == 0.0
    assert abs(fit.coulomb_estimate_n_m) < 3 * fit.coulomb_standard_error + 1e-3


def test_coulomb_friction_is_kept_where_the_data_show_it() -> None:
    rate = sweep((0.5, 1.5))
    fit = fit_friction(rate, rounded(0.02 * rate + 0.03 * np.sign(rate)), 1.78 * STEP_A)
    assert fit.problem is None
    assert fit.coulomb_friction_n_m == pytest.approx(0.03, rel=0.05)
    assert fit.viscous_friction_n_m_s_per_rad == pytest.approx(0.02, rel=0.1)


@pytest.mark.parametrize(
    ("rate", "message"),
    [
        (sweep((0.5,)), "one speed"),
        (np.concatenate([np.full(200, 0.5), np.full(200, 1.5)]), "did not sweep"),
        (np.zeros(400), "did not sweep"),
    ],
)
def test_sweeps_that_cannot_tell_the_friction_are_refused(rate: np.ndarray, message: str) -> None:
    fit = fit_friction(rate, 0.02 * rate, 1.78 * STEP_A)
    assert fit.problem is not None and message in fit.problem


def test_negative_friction_is_refused() -> None:
    rate = sweep((0.5, 1.5))
    fit = fit_friction(rate, rounded(-0.05 * rate), 1.78 * STEP_A)
    assert fit.problem is not None and "negative viscous friction" in fit.problem

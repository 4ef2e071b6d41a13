"""companion.mission.servo_check: the poses, the walk through them and the fit, on a
synthetic arm that follows its target and draws the model's gravity current."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from companion.calibration.servo import model_torque_n_m
from companion.config import load_config
from companion.mission.servo_check import (
    CANDIDATE_POSES_RAD,
    ServoCheck,
    ServoCheckTimes,
    check_poses,
    fit_servo_check,
)
from companion.model import ManipulatorModel

CONFIG = Path(__file__).parent.parent / "configs" / "sitl_pickup.toml"
LIMITS = [(-2.618, 0.524), (-2.094, 2.094)]
LENGTHS = (0.135, 0.17)
STOW = (0.0, -0.5 * math.pi)
STEP_A = 2.69e-3
BELIEVED_KT = 1.78
DT_S = 0.004


@pytest.fixture(scope="module")
def arm():
    cfg = load_config(CONFIG)
    return ManipulatorModel.from_config(cfg), cfg.nominal_theta.as_tuple()


def test_every_candidate_lies_within_the_sitl_arms_limits_above_the_stowed_arm() -> None:
    assert check_poses(LIMITS, LENGTHS, STOW) == list(CANDIDATE_POSES_RAD)


def test_poses_below_the_stowed_arm_or_past_a_limit_are_left_out() -> None:
    # stowed with link 2 only 0.5 rad down: the ground may be 8 cm below joint 1
    high_stow = check_poses(LIMITS, LENGTHS, (0.0, -0.5))
    assert (0.0, -0.8) not in high_stow and STOW not in high_stow
    assert (0.0, 0.0) in high_stow and (-0.35, 0.35) in high_stow
    # joint 1 may not rise past 0.2 rad: nothing above a straight arm there either
    low_top = check_poses([(-2.618, 0.2), LIMITS[1]], LENGTHS, STOW)
    assert (0.35, -0.35) not in low_top and (0.0, 0.0) in low_top


def walk(check: ServoCheck, model, theta, kt_ratio: float, still: bool = True):
    """Cycles at 250 Hz of an arm at its target (moving while the target moves), drawing
    the current of the gravity torque at the true torque constant ``kt_ratio`` x the
    believed one, with a step of noise, rounded to the servo's step and read back through
    the believed constant."""
    rng = np.random.default_rng(0)
    t = 0.0
    for _ in range(20_000):
        if check.finished:
            return t
        eta, eta_dot, _ = check.target(t)
        tau = model_torque_n_m(model, theta, [eta], [[0.0, 0.0]])[0]
        noisy_a = tau / (kt_ratio * BELIEVED_KT) + rng.normal(0.0, STEP_A, 2)
        current = np.round(noisy_a / STEP_A) * STEP_A
        rate = eta_dot if still else np.full(2, 0.2)
        check.update(t, eta, rate, [0.0, 0.0], current * BELIEVED_KT)
        t += DT_S
    raise AssertionError("the check never ended")


@pytest.mark.parametrize("kt_ratio", [0.88, 1.0, 1.12])
def test_the_check_visits_each_pose_and_finds_the_true_torque_constant(arm, kt_ratio) -> None:
    model, theta = arm
    poses = check_poses(LIMITS, LENGTHS, STOW)
    check = ServoCheck(poses, STOW, 0.0)
    duration_s = walk(check, model, theta, kt_ratio)
    times = ServoCheckTimes()
    per_pose_s = times.move_s + times.settle_s + times.average_s
    assert duration_s == pytest.approx(len(poses) * per_pose_s, abs=0.1)
    np.testing.assert_allclose([r[0] for r in check.readings], poses, atol=1e-12)
    assert not check.missed
    fits = fit_servo_check(check.readings, model, theta, [BELIEVED_KT] * 2, STEP_A)
    for fit in fits:
        assert fit.problem is None
        assert fit.torque_constant_n_m_per_a == pytest.approx(kt_ratio * BELIEVED_KT, rel=0.01)


def test_the_target_is_a_minimum_jerk_move_from_where_the_arm_was() -> None:
    check = ServoCheck([(0.0, 0.0), (0.35, -0.35)], (0.0, -1.0), 2.0)
    start, rate, _ = check.target(2.0)
    np.testing.assert_allclose(start, [0.0, -1.0])
    np.testing.assert_allclose(rate, 0.0)
    middle, rate, _ = check.target(2.5)
    np.testing.assert_allclose(middle, [0.0, -0.5])
    assert rate[1] > 0.0
    end, rate, _ = check.target(3.0)
    np.testing.assert_allclose(end, [0.0, 0.0])
    np.testing.assert_allclose(rate, 0.0, atol=1e-12)


def test_an_arm_that_never_comes_to_rest_is_not_fitted(arm) -> None:
    model, theta = arm
    poses = check_poses(LIMITS, LENGTHS, STOW)
    check = ServoCheck(poses, STOW, 0.0)
    walk(check, model, theta, 1.0, still=False)
    assert check.missed == poses and check.readings == []
    fits = fit_servo_check(check.readings, model, theta, [BELIEVED_KT] * 2, STEP_A)
    assert all(fit.problem == "0 poses (< 4)" for fit in fits)

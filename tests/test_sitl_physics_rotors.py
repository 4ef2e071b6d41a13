"""sitl.physics.rotors and sitl.physics.attitude_control: thrust curve, lag, mixer, PX4 loops."""

import math

import numpy as np
import pytest

from sitl.physics.attitude_control import (
    AttitudeController,
    AttitudeLoopParams,
    AttitudeSetpoint,
    Px4AttitudeLoop,
    RateController,
)
from sitl.physics.frames import quaternion_from_euler, rotation_from_euler, rotation_from_quaternion
from sitl.physics.rotors import (
    RotorBank,
    RotorGeometry,
    SequentialDesaturationMixer,
    inverse_thrust_curve,
    thrust_curve,
)
from sitl.scenario import load_scenario

GEOMETRY = RotorGeometry.hexa_x(0.215, 0.016)
T_MAX = 6.0


@pytest.fixture
def mixer() -> SequentialDesaturationMixer:
    return SequentialDesaturationMixer(GEOMETRY, T_MAX)


def body_torque(commands) -> np.ndarray:
    """Physical torque of commands with a linear thrust curve [N m]."""
    return GEOMETRY.wrench_matrix()[:3] @ (T_MAX * np.asarray(commands))


def test_layout_is_the_firefly_hexa_x() -> None:
    azimuth = np.degrees(np.arctan2(GEOMETRY.positions_m[:, 1], GEOMETRY.positions_m[:, 0]))
    np.testing.assert_allclose(azimuth, [30, 90, 150, -150, -90, -30])
    np.testing.assert_allclose(np.linalg.norm(GEOMETRY.positions_m, axis=1), 0.215)
    np.testing.assert_array_equal(GEOMETRY.spin, [1, -1, 1, -1, 1, -1])
    wrench = GEOMETRY.wrench_matrix()
    # rotor 1 (left, +y) lifts the left side: positive roll about body x (FLU)
    assert wrench[0, 1] == pytest.approx(0.215)
    # rotor 0 (front left) pushes the nose up: negative pitch about body y (FLU)
    assert wrench[1, 0] < 0.0
    # a counter-clockwise rotor yaws the body clockwise
    assert wrench[2, 0] == pytest.approx(-0.016)


def test_thrust_curve_and_inverse() -> None:
    u = np.linspace(0.0, 1.0, 11)
    for f in (0.0, 0.3, 1.0):
        np.testing.assert_allclose(inverse_thrust_curve(thrust_curve(u, f), f), u, atol=1e-12)
    assert thrust_curve(1.0, 0.3) == pytest.approx(1.0)
    assert thrust_curve(0.5, 0.3) == pytest.approx(0.3 * 0.25 + 0.7 * 0.5)
    with pytest.raises(ValueError):
        inverse_thrust_curve(1.2, 0.3)


def test_rotor_lag_is_exact_first_order() -> None:
    bank = RotorBank(T_MAX, 0.3, 0.025, 0.001)
    bank.reset(np.zeros(6))
    for _ in range(25):
        bank.advance([1.0] * 6)
    np.testing.assert_allclose(bank.thrusts_n, T_MAX * (1.0 - math.exp(-1.0)), rtol=1e-12)
    with pytest.raises(ValueError):
        bank.reset(-np.ones(6))


def test_px4_normalization_of_the_mix_matrix(mixer) -> None:
    mix = mixer.mix_matrix
    np.testing.assert_allclose(mix[:, 3], 1.0)  # collective thrust t puts every motor at t
    np.testing.assert_allclose(np.abs(mix[:, 2]), 1.0)  # yaw: max entry 1, all rotors used
    # roll and pitch share one scale (PX4 normalizes them together)
    np.testing.assert_allclose(np.abs(mix[:, 1]).max(), math.sqrt(0.5))
    np.testing.assert_allclose(mixer.torque_per_normalized_n_m, [3.1598, 3.1598, 0.576], rtol=1e-4)


def test_unsaturated_mix_produces_the_requested_torque(mixer) -> None:
    c = np.array([0.05, -0.08, 0.1])
    out = mixer.mix(c, 0.5)
    np.testing.assert_allclose(np.mean(out.relative_thrusts), 0.5)
    np.testing.assert_allclose(
        body_torque(out.relative_thrusts) - body_torque(np.full(6, 0.5)),
        mixer.torque_per_normalized_n_m * c,
        atol=1e-12,
    )
    assert not any(out.saturation_positive) and not any(out.saturation_negative)


def test_roll_wins_over_yaw(mixer) -> None:
    out = mixer.mix([0.3, 0.0, 1.0], 0.5)
    u = np.array(out.relative_thrusts)
    assert np.all((u >= 0.0) & (u <= 1.0))
    roll = body_torque(u)[0] / mixer.torque_per_normalized_n_m[0]
    assert roll == pytest.approx(0.3, abs=1e-9)
    assert out.saturation_positive == (False, False, True)


def test_thrust_is_cut_to_keep_roll_near_full_throttle(mixer) -> None:
    out = mixer.mix([0.3, 0.0, 0.0], 0.95)
    u = np.array(out.relative_thrusts)
    assert u.max() == pytest.approx(1.0)
    assert u.mean() < 0.95
    assert body_torque(u)[0] / mixer.torque_per_normalized_n_m[0] == pytest.approx(0.3)


def test_thrust_is_never_raised_at_low_throttle(mixer) -> None:
    """Airmode disabled: near zero thrust the roll request is scaled down instead."""
    out = mixer.mix([0.3, 0.0, 0.0], 0.05)
    u = np.array(out.relative_thrusts)
    assert u.min() == pytest.approx(0.0)
    assert u.mean() == pytest.approx(0.05)
    assert body_torque(u)[0] / mixer.torque_per_normalized_n_m[0] < 0.3
    assert out.saturation_positive[0]


def test_quaternion_and_euler_agree() -> None:
    for angles in [(0.1, -0.2, 0.3), (-1.0, 0.5, 3.0), (0.0, 1.5, -2.0)]:
        q = quaternion_from_euler(*angles)
        np.testing.assert_allclose(
            rotation_from_quaternion(q), rotation_from_euler(*angles), atol=1e-15
        )


@pytest.fixture
def attitude() -> AttitudeController:
    cfg = load_scenario("configs/paper_sim.toml").plant.attitude_control
    return AttitudeController(cfg.attitude_p, cfg.yaw_weight, cfg.rate_max_rad_s)


def test_attitude_p_on_small_errors(attitude) -> None:
    level = quaternion_from_euler(0.0, 0.0, 0.0)
    assert attitude.rate_setpoint(level, level) == pytest.approx((0.0, 0.0, 0.0))
    e = 0.01
    np.testing.assert_allclose(
        attitude.rate_setpoint(level, quaternion_from_euler(e, 0.0, 0.0)),
        (4.0 * e, 0, 0),  # MC_ROLL_P of PX4 main
        rtol=1e-4,
    )
    np.testing.assert_allclose(
        attitude.rate_setpoint(level, quaternion_from_euler(0.0, -e, 0.0)),
        (0, -4.0 * e, 0),
        rtol=1e-4,
        atol=1e-12,
    )
    # yaw: MC_YAW_P, whatever the yaw weight (PX4 divides the gain by it)
    np.testing.assert_allclose(
        attitude.rate_setpoint(level, quaternion_from_euler(0.0, 0.0, e)),
        (0, 0, 2.8 * e),
        rtol=1e-4,
        atol=1e-12,
    )


def test_attitude_rate_setpoints_are_limited(attitude) -> None:
    level = quaternion_from_euler(0.0, 0.0, 0.0)
    rates = attitude.rate_setpoint(level, quaternion_from_euler(1.5, 0.0, 0.0))
    assert rates[0] == pytest.approx(math.radians(220.0))


def test_rate_pid_integrates_and_respects_saturation_flags() -> None:
    pid = RateController([0.15] * 3, [0.2] * 3, [0.0] * 3, [0.3] * 3, 20.0, 0.001)
    pid.reset()
    none = (False, False, False)
    torque = pid.update((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), none, none)
    assert torque == pytest.approx((0.15, 0.0, 0.0))
    assert pid.integral[0] == pytest.approx(0.2 * 1.0 * 0.001 * (1 - (1 / math.radians(400)) ** 2))
    # saturated positive: a positive error does not wind the integrator up further
    before = pid.integral[0]
    pid.update((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (True, False, False), none)
    assert pid.integral[0] == before
    for _ in range(10000):
        pid.update((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), none, none)
    assert pid.integral[0] == pytest.approx(0.3)  # MC_RR_INT_LIM


def _loop(thr_mdl_fac: float) -> Px4AttitudeLoop:
    cfg = load_scenario("configs/paper_sim.toml").plant.attitude_control
    params = AttitudeLoopParams.from_config(cfg, thr_mdl_fac)
    return Px4AttitudeLoop.from_params(params, SequentialDesaturationMixer(GEOMETRY, T_MAX), 1e-3)


@pytest.mark.parametrize("f", [0.0, 0.3, 0.7])
def test_relative_thrust_is_linearized_with_the_autopilots_thr_mdl_fac(f) -> None:
    """PX4 FunctionMotors: relative rotor thrust -> u = inverse curve (THR_MDL_FAC); motors on
    the same curve make thrust linear in the setpoint."""
    loop = _loop(f)
    level = quaternion_from_euler(0.0, 0.0, 0.0)
    for thrust in (0.1, 0.33, 0.8):
        out = loop.update(tuple(level), (0.0, 0.0, 0.0), AttitudeSetpoint(level, thrust))
        np.testing.assert_allclose(out.relative_thrusts, thrust, atol=1e-12)
        np.testing.assert_allclose(thrust_curve(out.motor_commands, f), thrust, atol=1e-12)


def test_parameters_change_the_running_loop() -> None:
    loop = _loop(0.3)
    level = quaternion_from_euler(0.0, 0.0, 0.0)
    tilted = AttitudeSetpoint(quaternion_from_euler(0.01, 0.0, 0.0), 0.5)
    before = loop.update(tuple(level), (0.0, 0.0, 0.0), tilted)
    cfg = load_scenario("configs/paper_sim.toml").plant.attitude_control
    params = AttitudeLoopParams.from_config(cfg, 0.0)
    doubled = AttitudeLoopParams(**{**params.__dict__, "attitude_p": (8.0, 4.0, 2.8)})
    loop.configure(doubled)
    after = loop.update(tuple(level), (0.0, 0.0, 0.0), tilted)
    assert after.rate_setpoint_rad_s[0] == pytest.approx(2.0 * before.rate_setpoint_rad_s[0])
    # THR_MDL_FAC = 0 now: the command is the relative thrust
    np.testing.assert_allclose(after.motor_commands, after.relative_thrusts, atol=1e-12)
    # MC_ROLLRATE_K scales the rate gains
    k2 = AttitudeLoopParams(**{**params.__dict__, "rate_k": (2.0, 1.0, 1.0)})
    fresh, scaled = _loop(0.0), _loop(0.0)
    scaled.configure(k2)
    t1 = fresh.update(tuple(level), (0.0, 0.0, 0.0), tilted).torque_normalized[0]
    t2 = scaled.update(tuple(level), (0.0, 0.0, 0.0), tilted).torque_normalized[0]
    assert t2 == pytest.approx(2.0 * t1)

"""companion.control.laws, companion.control.setpoints and companion.control.trajectory."""

import math
from pathlib import Path

import numpy as np
import pytest

from companion.control.laws import (
    ControlRateError,
    DesiredState,
    PassivityController,
    SlidingModeController,
    check_control_rate,
    damping_step_ratio,
)
from companion.control.setpoints import (
    ThrustModel,
    attitude_thrust_setpoint,
    fixed_setpoint,
    tilt_from_force,
)
from companion.control.trajectory import TiltReference
from companion.model import ManipulatorModel
from sitl.offline.trajectory import PaperSinusoid
from sitl.scenario import load_scenario

CFG = load_scenario(Path(__file__).parent.parent / "configs" / "paper_sim.toml")
MODEL = ManipulatorModel.from_config(CFG)
TRUE = np.array(CFG.true_theta.as_tuple())
NOMINAL = np.array(CFG.nominal_theta.as_tuple())


def rot(phi, theta, psi):
    cx, sx, cy, sy, cz, sz = (f(a) for a in (phi, theta, psi) for f in (math.cos, math.sin))
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return rz @ ry @ rx


def test_passivity_is_exact_inverse_dynamics_on_the_trajectory() -> None:
    """At q = q_d, q_dot = q_d_dot with the true theta, the plant accelerates at q_d_ddot."""
    traj = PaperSinusoid(CFG.trajectory)
    ctl = PassivityController(CFG.controller.k, CFG.controller.lambda_)
    for t in (0.3, 2.1, 7.7):
        d = traj(t)
        terms = MODEL.terms(d.q, d.q_dot)
        tau = ctl.torque(terms, d.q, d.q_dot, d, TRUE)
        m, c, g = terms.evaluate(TRUE)
        np.testing.assert_allclose(np.linalg.solve(m, tau - c @ d.q_dot - g), d.q_ddot, atol=1e-9)


def test_passivity_feedback_opposes_errors_and_wraps_yaw() -> None:
    ctl = PassivityController(CFG.controller.k, CFG.controller.lambda_)
    zero = np.zeros(8)
    desired = DesiredState(
        q=np.array([0, 0, 1, 0, 0, -math.pi + 0.01, 0, 0]), q_dot=zero, q_ddot=zero
    )
    q = desired.q.copy()
    terms = MODEL.terms(q, zero)
    base = ctl.torque(terms, q, zero, desired, TRUE)
    q_off = q.copy()
    q_off[0] += 0.1
    assert ctl.torque(MODEL.terms(q_off, zero), q_off, zero, desired, TRUE)[0] < base[0]
    q_wrap = q.copy()
    q_wrap[5] = math.pi - 0.01  # 0.02 rad from the target across the +-pi seam
    tau = ctl.torque(MODEL.terms(q_wrap, zero), q_wrap, zero, desired, TRUE)
    k_lam = CFG.controller.k[5] * CFG.controller.lambda_[5]
    assert abs(tau[5] - base[5]) < 0.05 * k_lam


def test_nonadaptive_ignores_the_estimate() -> None:
    ctl = PassivityController.nonadaptive(CFG.controller.k, CFG.controller.lambda_, NOMINAL)
    d = PaperSinusoid(CFG.trajectory)(1.0)
    terms = MODEL.terms(d.q, d.q_dot)
    np.testing.assert_array_equal(
        ctl.torque(terms, d.q, d.q_dot, d, TRUE), ctl.torque(terms, d.q, d.q_dot, d, NOMINAL)
    )


def smc() -> SlidingModeController:
    return SlidingModeController(
        k1=CFG.controller.k,
        k2=np.full(8, 0.5),
        lam=CFG.controller.lambda_,
        boundary_layer=np.full(8, 0.05),
        gamma_delta=np.full(8, 0.5),
        known_mass_kg=CFG.vehicle.mass_kg + CFG.arm.link1.mass_kg,
        gravity_m_s2=CFG.environment.gravity_m_s2,
        nominal_lc_m=CFG.nominal_theta.lc_m,
        m2_0=0.1,
        m2_bounds_kg=(0.05, 2.0),
        mass_filter_s=0.2,
    )


def test_sliding_mode_mass_readout_finds_the_hover_mass() -> None:
    """Holding still with the true weight applied, the read-out converges to m2."""
    ctl = smc()
    q = np.array([0, 0, 1.0, 0, 0, 0, -math.pi / 2, 0])
    zero = np.zeros(8)
    desired = DesiredState(q=q, q_dot=zero, q_ddot=zero)
    weight = MODEL.gravity(q, TRUE)[2]
    for _ in range(2000):
        ctl.torque(1e-3, MODEL.terms(q, zero), q, zero, zero, desired, weight)
    assert ctl.m2 == pytest.approx(0.5, rel=1e-3)


def test_sliding_mode_readout_waits_for_a_known_force() -> None:
    ctl = smc()
    q = np.array([0, 0, 1.0, 0, 0, 0, -math.pi / 2, 0])
    zero = np.zeros(8)
    desired = DesiredState(q=q, q_dot=zero, q_ddot=zero)
    ctl.torque(1e-3, MODEL.terms(q, zero), q, zero, zero, desired, float("nan"))
    assert ctl.m2 == 0.1


def test_tilt_mapping_small_angle_matches_rotation() -> None:
    """R(phi_d, theta_d, psi) e3 points along the desired force, to first order."""
    for psi in (0.0, 0.7, -2.5):
        force = np.array([0.4, -0.3, 15.0])
        phi, theta, sat = tilt_from_force(force, psi, 0.6)
        assert not sat
        direction = rot(phi, theta, psi) @ np.array([0, 0, 1.0])
        np.testing.assert_allclose(direction, force / force[2], atol=2e-3)


def test_tilt_limit_keeps_direction() -> None:
    phi, theta, sat = tilt_from_force(np.array([10.0, 10.0, 10.0]), 0.0, 0.3)
    assert sat
    assert math.hypot(phi, theta) == pytest.approx(0.3)
    assert theta / -phi == pytest.approx(1.0)
    assert tilt_from_force(np.array([1.0, 0.0, -5.0]), 0.0, 0.3) == (0.0, 0.0, True)


def test_relative_thrust_is_linear_in_newtons_with_a_floor() -> None:
    """PX4 linearizes the relative thrust itself (THR_MDL_FAC in its mixer): one newton
    more is 1 / max_thrust more relative thrust, whatever the motors' curve."""
    model = ThrustModel(max_thrust_n=36.0, min_relative=0.12)
    assert model.relative(12.0) == (pytest.approx(12.0 / 36.0), False)
    assert model.thrust_n(0.5) == pytest.approx(18.0)
    assert model.relative(40.0) == (1.0, True)
    assert model.relative(1.0) == (0.12, True)  # the floor keeps roll/pitch authority
    assert model.min_thrust_n == pytest.approx(0.12 * 36.0)
    with pytest.raises(ValueError):
        ThrustModel(max_thrust_n=36.0, min_relative=1.0)


def test_attitude_thrust_setpoint_vertical_component_is_exact() -> None:
    model = ThrustModel(max_thrust_n=40.0)
    sp = attitude_thrust_setpoint(np.array([1.0, -0.5, 15.7]), 0.2, 0.1, 0.6, model)
    thrust_w = rot(sp.roll_rad, sp.pitch_rad, 0.2) @ np.array([0, 0, sp.thrust_n])
    assert thrust_w[2] == pytest.approx(15.7)
    assert sp.yaw_rad == 0.1
    assert model.thrust_n(sp.thrust_relative) == pytest.approx(sp.thrust_n)
    assert sp.thrust_relative == pytest.approx(sp.thrust_n / 40.0)


def test_a_force_that_does_not_lift_is_flown_at_the_floor_and_keeps_its_direction() -> None:
    """Without a floor a non-positive vertical force meant thrust 0 and a level attitude:
    with PX4's airmode off that leaves no roll or pitch authority at all."""
    model = ThrustModel(max_thrust_n=36.0, min_relative=0.12)
    sp = attitude_thrust_setpoint(np.array([0.5, 0.0, -2.0]), 0.0, 0.0, 0.6, model)
    assert sp.thrust_relative == pytest.approx(0.12) and sp.thrust_saturated
    assert sp.pitch_rad == pytest.approx(math.atan(0.5 / (0.12 * 36.0)), rel=0.05)
    assert sp.pitch_rad > 0.0 and sp.tilt_saturated
    fixed = fixed_setpoint(0.0, 0.0, 1.0, 0.0, model)
    assert fixed.thrust_relative == pytest.approx(0.12) and fixed.yaw_rad == 1.0


def test_paper_trajectory_formula_and_derivatives() -> None:
    traj = PaperSinusoid(CFG.trajectory)
    t, h = 1.7, 1e-5
    d = traj(t)
    w = math.pi / 5
    expected = [
        0.5 * math.cos(w * t),
        -0.5 * math.cos(w * t),
        0.7,
        0,
        0,
        0,
        -math.pi / 2 + math.pi / 4 * math.sin(w * t),
        math.pi / 8 * math.sin(w * t),
    ]
    np.testing.assert_allclose(d.q, expected, atol=1e-12)
    np.testing.assert_allclose((traj(t + h).q - traj(t - h).q) / (2 * h), d.q_dot, atol=1e-8)
    np.testing.assert_allclose(
        (traj(t + h).q_dot - traj(t - h).q_dot) / (2 * h), d.q_ddot, atol=1e-8
    )


def test_tilt_reference_settles_and_stays_stable_on_late_cycles() -> None:
    ref = TiltReference(20.0)
    for _ in range(1000):
        ref.step(1e-3, (0.1, -0.05))
    assert ref.x == pytest.approx([0.1, -0.05], abs=1e-5)
    assert ref.v == pytest.approx([0.0, 0.0], abs=1e-3)
    # A 50 ms gap (w dt = 5: explicit Euler alone would diverge) is sub-stepped.
    late = TiltReference(100.0)
    for _ in range(40):
        late.step(0.05, (0.2, 0.0))
    assert late.x == pytest.approx([0.2, 0.0], abs=1e-6)
    with pytest.raises(ValueError, match="positive"):
        late.step(0.0, (0.0, 0.0))


def test_control_rate_check_predicts_the_discrete_damping_limit() -> None:
    """experiment_arm's attitude damping diverged on the ideal plant at 250 Hz, not at 1 kHz."""
    cfg = load_scenario(Path(__file__).parent.parent / "configs" / "experiment_arm.toml")
    model = ManipulatorModel.from_config(cfg)
    m = model.mass_matrix(cfg.simulation.initial_q, cfg.estimator.initial_theta.as_tuple())
    k, every = cfg.controller.k, tuple(range(8))
    assert check_control_rate(m, k, 1e-3, every) == pytest.approx(0.6, abs=0.05)
    with pytest.raises(ControlRateError, match=r"at least 5[0-9][0-9] Hz"):
        check_control_rate(m, k, 4e-3, every)
    # with PX4 closing the attitude loop only translation and joints are the companion's
    assert damping_step_ratio(m, k, 4e-3, (0, 1, 2, 6, 7)) < 1.0


def test_horizontal_trim_learns_a_constant_force_bias_and_stays_limited() -> None:
    """A 1-D double integrator under eq. tau2's x row with a 0.45 N bias (an attitude
    estimate 2 deg off at 1.2 kg): without the trim it sits 10 cm off, with it the error
    goes to zero; the trim never exceeds its limit."""
    from companion.control.laws import HorizontalTrim

    def settle(trim):
        m, k, lam, dt = 1.22, 4.5, 1.0, 0.008
        x = v = 0.0
        for _ in range(int(60.0 / dt)):
            s = np.array([v, 0.0]) + lam * np.array([x, 0.0])
            force = -k * v - k * lam * x - 0.45
            if trim is not None:
                force += trim.update(dt, s)[0]
            v += dt * force / m
            x += dt * v
        return x

    assert settle(None) == pytest.approx(-0.1, abs=1e-3)
    trim = HorizontalTrim(gain_n_per_m=1.0, limit_n=1.0)
    assert abs(settle(trim)) < 1e-3 and trim.force_n[0] == pytest.approx(0.45, abs=1e-3)
    small = HorizontalTrim(gain_n_per_m=1.0, limit_n=0.2)
    settle(small)
    assert small.force_n[0] == pytest.approx(0.2)

"""FlightControl: the companion's control cycle in flight (estimator rows, force, setpoint)."""

import math

import numpy as np
import pytest

from companion.config import load_config
from companion.control.flight import FlightControl
from companion.control.laws import DesiredState
from companion.estimation.filters import FilteredState

SCENARIO = load_config("configs/sitl_pickup.toml")
G = SCENARIO.environment.gravity_m_s2


def hover(q):
    zero = np.zeros(8)
    return FilteredState(q=np.asarray(q, float), q_dot=zero, q_ddot=zero.copy())


def test_hover_at_rest_asks_for_the_weight_level():
    fc = FlightControl(SCENARIO)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, -math.pi / 2, 0.0])
    desired = DesiredState(q.copy(), np.zeros(8), np.zeros(8))
    out = fc.step(0.004, hover(q), desired, np.full(8, np.nan))
    mass = SCENARIO.vehicle.mass_kg + SCENARIO.arm.link1.mass_kg + fc.estimator.theta[0]
    assert out.setpoint.thrust_n == pytest.approx(mass * G, rel=1e-6)
    assert abs(out.setpoint.roll_rad) < 1e-9 and abs(out.setpoint.pitch_rad) < 1e-9
    assert 0.0 < out.setpoint.thrust_relative < 1.0


def test_estimator_uses_only_rows_known_in_flight():
    fc = FlightControl(SCENARIO)
    assert set(fc.rows) <= {0, 1, 2, 6, 7}


def test_applied_force_is_thrust_along_attitude_and_servo_torque():
    fc = FlightControl(SCENARIO)
    q = np.array([0, 0, 1, 0.0, 0.2, 0.0, 0, 0])
    tau = fc.applied_force(q, 20.0, np.array([0.3, -0.1]))
    # Pitch up (theta > 0, FLU) tilts the thrust toward +x (ENU east when yaw = 0).
    np.testing.assert_allclose(tau[0:3], [20 * math.sin(0.2), 0.0, 20 * math.cos(0.2)], atol=1e-12)
    assert np.isnan(tau[3:6]).all()
    np.testing.assert_allclose(tau[6:8], [0.3, -0.1])


def test_nonadaptive_ignores_the_estimate():
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, -math.pi / 2, 0.0])
    desired = DesiredState(q.copy(), np.zeros(8), np.zeros(8))
    fc = FlightControl(SCENARIO, "nonadaptive")
    fc.estimator.reset([0.8, 0.1, 0.02])
    out = fc.step(0.004, hover(q), desired, np.full(8, np.nan))
    np.testing.assert_allclose(out.theta_hat, SCENARIO.nominal_theta.as_tuple())
    with pytest.raises(ValueError, match="controller"):
        FlightControl(SCENARIO, "pid")


def test_with_px4_flying_position_the_law_drives_the_joints_and_learns_from_them_alone():
    """``px4_position``: PX4's thrust is not the companion's, so the estimator runs on the
    joint rows without a thrust scale, the rate check covers the joints only, and the
    joint torques are eq. tau2's with the estimate (as the adaptive law's)."""
    fc = FlightControl(SCENARIO, "px4_position")
    adaptive = FlightControl(SCENARIO, "passivity")
    assert fc.px4_flies_position and not adaptive.px4_flies_position
    assert fc.rows == (6, 7) and fc.actuated_rows == (6, 7)
    assert fc.estimator.scale is None and SCENARIO.estimator.thrust_scale is not None
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, -1.2, 0.3])
    desired = DesiredState(q + 0.1, np.zeros(8), np.zeros(8))
    theta = [0.3, 0.03, 0.004]
    for law in (fc, adaptive):
        law.estimator.reset(theta)
    outs = [law.step(0.004, hover(q), desired, np.full(8, np.nan)) for law in (fc, adaptive)]
    np.testing.assert_allclose(outs[0].tau[6:8], outs[1].tau[6:8], rtol=1e-9)
    assert abs(outs[0].tau[7]) > 0.01

"""The estimator's delayed inputs (companion.estimation.inputs) and the law's measured
attitude motion (``[controller] measured_unactuated_motion``)."""

import math

import numpy as np
import pytest

from companion.config import load_config
from companion.control.flight import FlightControl
from companion.control.laws import DesiredState
from companion.estimation.estimator import Skip
from companion.estimation.filters import FilteredState
from companion.estimation.inputs import DelayedInputs, delay_cycles

SCENARIO = load_config("configs/sitl_pickup.toml")


def test_delay_in_whole_cycles_at_least_one():
    assert delay_cycles(0.024, 0.008) == 3
    assert delay_cycles(0.001, 0.008) == 1
    assert delay_cycles(0.024, 0.001) == 24
    with pytest.raises(ValueError, match="at least one cycle"):
        DelayedInputs(0)


def test_hands_back_the_cycle_n_ago_with_a_zero_lag_acceleration():
    """A sinusoid's acceleration at the delayed cycle: the central difference over +-n
    cycles is the derivative times sin(w T) / (w T), in phase (no lag)."""
    n, dt, w = 3, 0.008, 2.0 * math.pi * 0.5
    line = DelayedInputs(n)
    t = np.arange(40) * dt
    out = []
    for k, tk in enumerate(t):
        q = np.full(8, math.sin(w * tk))
        q_dot = np.full(8, w * math.cos(w * tk))
        tau = np.full(8, float(k))
        result = line.push(dt, q, q_dot, tau)
        assert (result is None) == (k < 2 * n)
        out.append(result)
    for k in range(2 * n, len(t)):
        q, q_dot, q_ddot, tau = out[k]
        tm = t[k - n]
        np.testing.assert_allclose(q, math.sin(w * tm), atol=1e-15)
        np.testing.assert_allclose(q_dot, w * math.cos(w * tm), atol=1e-15)
        np.testing.assert_allclose(tau, k - n)
        shrink = math.sin(w * n * dt) / (w * n * dt)
        np.testing.assert_allclose(q_ddot, -w * w * math.sin(w * tm) * shrink, atol=1e-12)


def test_a_skipped_cycle_is_skipped_when_its_turn_comes_and_reset_refills():
    line = DelayedInputs(1)
    zero = np.zeros(8)
    assert line.push(0.01, zero, zero, np.ones(8)) is None
    assert line.push(0.01, zero, zero, Skip.NO_SERVO_READ) is None
    assert line.push(0.01, zero, zero, np.ones(8))[3] is Skip.NO_SERVO_READ
    line.reset()
    assert line.push(0.01, zero, zero, np.ones(8)) is None


def test_a_stored_force_is_a_copy():
    line = DelayedInputs(1)
    zero, tau = np.zeros(8), np.ones(8)
    line.push(0.01, zero, zero, tau)
    line.push(0.01, zero, zero, tau)
    tau[:] = 5.0  # the caller reuses its array
    assert line.push(0.01, zero, zero, tau)[3][0] == 1.0


def test_stored_states_are_copies_handed_out_read_only():
    line = DelayedInputs(1)
    zero = np.zeros(8)
    q, q_dot = np.arange(8.0), np.ones(8)
    line.push(0.01, zero, zero, Skip.NO_FORCE)
    line.push(0.01, q, q_dot, Skip.NO_FORCE)
    q[:] = -1.0  # the caller reuses its arrays
    q_dot[:] = -1.0
    q_old, q_dot_old, _, _ = line.push(0.01, zero, zero, Skip.NO_FORCE)
    np.testing.assert_array_equal(q_old, np.arange(8.0))
    np.testing.assert_array_equal(q_dot_old, np.ones(8))
    assert not q_old.flags.writeable and not q_dot_old.flags.writeable
    with pytest.raises(ValueError, match="expected 8 values"):
        line.push(0.01, np.zeros(7), zero, Skip.NO_FORCE)


@pytest.mark.parametrize("compiled", [False, True])
def test_the_estimator_warms_up_then_runs_behind(compiled):
    config = SCENARIO.model_copy(
        update={"estimator": SCENARIO.estimator.model_copy(update={"acceleration_delay_s": 0.024})}
    )
    fc = FlightControl(config, compiled=compiled)
    assert fc.compiled is compiled
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, -math.pi / 2, 0.0])
    state = FilteredState(q=q, q_dot=np.zeros(8), q_ddot=np.zeros(8))
    desired = DesiredState(q.copy(), np.zeros(8), np.zeros(8))
    force = fc.applied_force(q, fc.weight_n(), np.zeros(2))
    for _ in range(6):
        fc.step(0.008, state, desired, force)
    assert fc.estimator.skipped == {Skip.WARMING_UP: 6}
    fc.step(0.008, state, desired, force)
    assert fc.estimator.skipped_steps == 6
    fc.restart_estimator_inputs()  # a navigation reset: the line refills
    for _ in range(7):
        fc.step(0.008, state, desired, force)
    assert fc.estimator.skipped == {Skip.WARMING_UP: 12}


@pytest.mark.parametrize("compiled", [False, True])
def test_the_law_takes_the_measured_attitude_motion(compiled):
    """With ``measured_unactuated_motion`` eq. tau2 sees the body's measured roll, pitch
    and yaw rates and accelerations (PX4 flies them), not the tilt asked: the joints'
    torque answers the pitch acceleration the body has."""
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.05, 0.0, -1.2, 0.3])
    q_dot = np.array([0.0, 0.0, 0.0, 0.1, -0.4, 0.05, 0.2, 0.0])
    q_ddot = np.array([0.0, 0.0, 0.0, 0.5, 3.0, -0.2, 0.0, 0.0])
    state = FilteredState(q=q, q_dot=q_dot, q_ddot=q_ddot)
    desired = DesiredState(q.copy(), np.zeros(8), np.zeros(8))
    force = np.full(8, np.nan)
    taus = {}
    for measured in (False, True):
        ctl = SCENARIO.controller.model_copy(update={"measured_unactuated_motion": measured})
        fc = FlightControl(SCENARIO.model_copy(update={"controller": ctl}), compiled=compiled)
        taus[measured] = fc.step(0.008, state, desired, force).tau
        theta = fc.estimator.theta
    reference = FlightControl(SCENARIO, compiled=False)
    law_q_dot, law_q_ddot = np.zeros(8), np.zeros(8)
    law_q_dot[3:6], law_q_ddot[3:6] = q_dot[3:6], q_ddot[3:6]
    expected = reference.controller.torque(
        reference.model.terms(q, q_dot), q, q_dot, DesiredState(q, law_q_dot, law_q_ddot), theta
    )
    np.testing.assert_allclose(taus[True][6:8], expected[6:8], atol=1e-12)
    assert np.max(np.abs(taus[True][6:8] - taus[False][6:8])) > 1e-3

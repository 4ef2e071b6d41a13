"""sitl.px4.hover_thrust: PX4's hover thrust estimator against a seeded truth model."""

import numpy as np
import pytest

from sitl.px4 import Px4Params
from sitl.px4.hover_thrust import HoverThrustEstimator, ZeroOrderHoverThrustEkf

G = 9.80665
DT = 0.008  # the estimator's output period (125 Hz)


def fly(estimator, true_hover, seconds, rng, t0=0.0, thrust_noise=0.02, accel_noise=0.5):
    """A vehicle hovering near ``true_hover``: the thrust wanders, the accelerometer reads
    g (T / Th_true - 1) plus noise. Returns the time at the end."""
    t = t0
    for _ in range(round(seconds / DT)):
        thrust = true_hover + thrust_noise * rng.standard_normal()
        accel = G * (thrust / true_hover - 1.0) + accel_noise * rng.standard_normal()
        t += DT
        estimator.update(t, DT, accel, thrust, (0.0, 0.0, 0.0))
    return t


def test_given_px4_defaults_when_hovering_then_it_learns_the_hover_thrust_and_turns_valid():
    rng = np.random.default_rng(1)
    estimator = HoverThrustEstimator(Px4Params())
    assert estimator.estimate.hover_thrust == 0.5 and not estimator.estimate.valid
    fly(estimator, 0.33, 1.0, rng)
    assert not estimator.estimate.valid  # the variance takes a while, then 2 s hysteresis
    fly(estimator, 0.33, 5.0, rng, t0=1.0)
    estimate = estimator.estimate
    assert estimate.valid
    assert estimate.hover_thrust == pytest.approx(0.33, abs=0.01)
    assert estimate.variance < 1e-3


def test_given_a_grasped_payload_when_the_hover_thrust_jumps_then_it_follows():
    """GIVEN a converged estimate WHEN a payload makes the vehicle 50 % heavier THEN the
    measurements fall outside the gate, the recovery bumps the variance and the estimate
    follows within seconds. (A change whose acceleration stays inside the gate, 3 sigma of
    at least 1 m/s^2, is followed only as slowly as the tiny process noise allows: PX4's
    position loop integral carries it meanwhile.)"""
    rng = np.random.default_rng(2)
    estimator = HoverThrustEstimator(Px4Params())
    t = fly(estimator, 0.33, 6.0, rng)
    t = fly(estimator, 0.495, 4.0, rng, t0=t)
    assert estimator.estimate.hover_thrust == pytest.approx(0.495, abs=0.015)


def test_estimate_stays_within_mpc_thr_hover_plus_minus_hte_thr_range():
    rng = np.random.default_rng(3)
    estimator = HoverThrustEstimator(Px4Params({"HTE_THR_RANGE": 0.1}))
    fly(estimator, 0.25, 10.0, rng)
    assert estimator.estimate.hover_thrust == pytest.approx(0.4)


def test_reset_returns_to_mpc_thr_hover():
    rng = np.random.default_rng(4)
    params = Px4Params()
    estimator = HoverThrustEstimator(params)
    fly(estimator, 0.33, 6.0, rng)
    params.set("MPC_THR_HOVER", 0.45)
    estimator.reset()
    assert estimator.estimate.hover_thrust == 0.45 and not estimator.estimate.valid


def test_measurement_model_and_gate_are_pxs():
    """One fusion by hand: H = -g T / Th^2, innovation a - (g T / Th - g), gain P H / S."""
    ekf = ZeroOrderHoverThrustEkf(0.5, 0.1, 0.0036, 3.0)
    ekf.predict(DT)
    p = 0.01 + 0.0036**2 * DT**2
    thrust, accel = 0.4, -1.0
    h = -G * thrust / 0.25
    s = h * p * h + 5.0
    innovation = accel - (G * thrust / 0.5 - G)
    ekf.fuse(accel, thrust)
    assert ekf.innovation == pytest.approx(innovation)
    assert ekf.hover_thrust == pytest.approx(0.5 + p * h / s * innovation)
    assert ekf.test_ratio == pytest.approx(innovation**2 / (9.0 * s))
    # far outside the gate: rejected, the state stays
    before = ekf.hover_thrust
    ekf.fuse(60.0, thrust)
    assert ekf.hover_thrust == before

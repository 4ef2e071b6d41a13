"""companion.estimation.estimator on prescribed motions with exactly known generalized forces.

These are algorithm tests: the motion q(t) is prescribed analytically and tau is computed
from companion.model with the true theta, so a correct estimator must converge. The
closed-loop tests against the independent truth plant live in tests/test_simulation.py.
"""

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.estimation.estimator import (
    TRANSLATION_AND_JOINT_ROWS,
    ExcitationMonitor,
    PaperEstimator,
    RlsEstimator,
    Skip,
    ThetaBounds,
)
from companion.model import ManipulatorModel
from sitl.scenario import load_scenario

CFG = load_scenario(Path(__file__).parent.parent / "configs" / "paper_sim.toml")
MODEL = ManipulatorModel.from_config(CFG)
TRUE = np.array(CFG.true_theta.as_tuple())
BOUNDS = ThetaBounds(0.05, 2.0, CFG.arm.link2.length_m)
DT = 2e-3


def motion(t: float, amplitude: float = 1.0):
    """An exciting prescribed motion: q, q_dot, q_ddot at t."""
    w = np.array([1.3, 0.9, 1.7, 2.1, 1.5, 0.7, 2.3, 3.1])
    a = amplitude * np.array([0.5, 0.5, 0.3, 0.15, 0.15, 0.3, 0.6, 0.8])
    q0 = np.array([0, 0, 1.0, 0, 0, 0, -math.pi / 2, 0])
    return q0 + a * np.sin(w * t), a * w * np.cos(w * t), -a * w * w * np.sin(w * t)


def exact_tau(q, q_dot, q_ddot, theta=TRUE):
    return MODEL.terms(q, q_dot).regressor(q_dot, q_ddot) @ np.append(theta, 1.0)


def monitor(n_rows: int) -> ExcitationMonitor:
    return ExcitationMonitor(
        window_s=2.0,
        theta_scale=(2.0, 0.4, 0.08),
        row_scale=np.ones(n_rows),
        excitation_min=1e-2,
        spread_max=0.02,
    )


def paper(rows=tuple(range(8)), gamma=(0.2, 0.1, 0.1)) -> PaperEstimator:
    return PaperEstimator(
        CFG.estimator.initial_theta.as_tuple(),
        BOUNDS,
        monitor(len(rows)),
        gamma=gamma,
        c_star=CFG.estimator.c_star,
        k_star=CFG.estimator.k_star,
        qhat_dot0=CFG.estimator.initial_qhat_dot,
        rows=rows,
    )


def rls(rows=tuple(range(8)), com_from_joints: bool = False) -> RlsEstimator:
    return RlsEstimator(
        CFG.estimator.initial_theta.as_tuple(),
        BOUNDS,
        monitor(len(rows)),
        forgetting=0.999,
        p0=(1.0, 0.01, 1e-3),
        row_noise=np.full(8, 0.1),
        rows=rows,
        com_from_joints=com_from_joints,
    )


def run(estimator, duration_s: float, theta=TRUE, t0: float = 0.0, amplitude: float = 1.0):
    est = None
    for i in range(int(duration_s / DT)):
        q, q_dot, q_ddot = motion(t0 + i * DT, amplitude)
        tau = exact_tau(q, q_dot, q_ddot, theta)
        est = estimator.update(DT, MODEL.terms(q, q_dot), q, q_dot, q_ddot, tau)
    return est


@pytest.mark.parametrize("rows", [tuple(range(8)), TRANSLATION_AND_JOINT_ROWS])
def test_paper_estimator_converges(rows) -> None:
    est = run(paper(rows, gamma=(2.0, 1.0, 1.0)), 30.0)
    assert est.m2_kg == pytest.approx(0.5, rel=0.02)
    assert est.lc_m == pytest.approx(0.16, rel=0.05)


@pytest.mark.parametrize("rows", [tuple(range(8)), TRANSLATION_AND_JOINT_ROWS])
def test_rls_converges_and_reports_confidence(rows) -> None:
    estimator = rls(rows)
    est = run(estimator, 10.0)
    np.testing.assert_allclose(est.theta, TRUE, rtol=1e-3)
    assert est.confident
    assert estimator.std[0] < 0.01


def test_rls_com_from_joints_keeps_x_y_z_off_m3_and_m4() -> None:
    """With ``com_from_joints`` the x, y, z rows learn m2 alone (m3, m4 held at their
    initial values when they are the only rows), and with the joints all of theta still
    converges on exact data."""
    alone = rls((0, 1, 2), com_from_joints=True)
    start = alone.theta.copy()
    est = run(alone, 5.0)
    np.testing.assert_array_equal(est.theta[1:], start[1:])
    assert est.theta[0] != start[0]
    both = rls(TRANSLATION_AND_JOINT_ROWS, com_from_joints=True)
    np.testing.assert_allclose(run(both, 10.0).theta, TRUE, rtol=1e-3)


def test_unused_rows_are_never_read() -> None:
    estimator = rls(TRANSLATION_AND_JOINT_ROWS)
    for i in range(int(5.0 / DT)):
        q, q_dot, q_ddot = motion(i * DT)
        tau = exact_tau(q, q_dot, q_ddot)
        tau[3:6] = np.nan  # the attitude torques PX4 applies are unknown in flight
        est = estimator.update(DT, MODEL.terms(q, q_dot), q, q_dot, q_ddot, tau)
    np.testing.assert_allclose(est.theta, TRUE, rtol=1e-3)


def test_no_excitation_no_confidence() -> None:
    estimator = rls()
    q = np.array([0, 0, 1.0, 0, 0, 0, -math.pi / 2, 0])
    zero = np.zeros(8)
    for _ in range(int(5.0 / DT)):
        est = estimator.update(DT, MODEL.terms(q, zero), q, zero, zero, exact_tau(q, zero, zero))
    assert not est.confident
    assert est.excitation < 1e-2


def test_freeze_resume_reset() -> None:
    estimator = rls()
    before = run(estimator, 1.0).theta
    estimator.freeze()
    frozen = run(estimator, 2.0, t0=1.0)
    assert frozen.frozen and not frozen.confident
    np.testing.assert_array_equal(frozen.theta, before)
    estimator.resume()
    assert not np.array_equal(run(estimator, 0.5, t0=3.0).theta, before)
    nominal = CFG.nominal_theta.as_tuple()
    estimator.reset(nominal)
    np.testing.assert_allclose(estimator.theta, nominal)


def test_follows_pickup_and_release() -> None:
    """The estimate follows a payload picked up and released mid-run (rls forgets)."""
    nominal = np.array(CFG.nominal_theta.as_tuple())
    estimator = rls()
    np.testing.assert_allclose(run(estimator, 10.0, theta=nominal).theta, nominal, rtol=2e-2)
    np.testing.assert_allclose(run(estimator, 15.0, t0=10.0).theta, TRUE, rtol=2e-2)
    np.testing.assert_allclose(run(estimator, 15.0, nominal, t0=25.0).theta, nominal, rtol=2e-2)


def test_estimates_stay_in_bounds_under_garbage() -> None:
    rng = np.random.default_rng(0)
    for estimator in (paper(), rls()):
        for i in range(2000):
            q, q_dot, q_ddot = motion(i * DT)
            tau = exact_tau(q, q_dot, q_ddot) + rng.normal(0.0, 50.0, 8)
            est = estimator.update(DT, MODEL.terms(q, q_dot), q, q_dot, q_ddot, tau)
            assert BOUNDS.contains(est.theta)


def test_rejects_bad_rows() -> None:
    with pytest.raises(ValueError, match="rows"):
        rls(rows=(0, 9))
    with pytest.raises(ValueError, match="rows"):
        rls(rows=(2, 1))


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@given(finite, finite, finite)
def test_projection_lands_inside_and_is_idempotent(m2, m3, m4) -> None:
    projected = BOUNDS.project((m2, m3, m4))
    assert BOUNDS.contains(projected)
    np.testing.assert_array_equal(BOUNDS.project(projected), projected)


def test_projection_rejects_nan() -> None:
    with pytest.raises(FloatingPointError):
        BOUNDS.project((np.nan, 0.0, 0.0))


@pytest.mark.parametrize("rows", [tuple(range(8)), (2, 3, 4, 5, 6, 7), TRANSLATION_AND_JOINT_ROWS])
def test_non_finite_force_on_a_used_row_skips_the_step(rows) -> None:
    """Contiguous rows are read as a slice, others by index: both skip the same steps."""
    for estimator in (paper(rows), rls(rows)):
        run(estimator, 0.5)
        q, q_dot, q_ddot = motion(0.5)
        held = estimator.theta.copy()
        for bad in (np.nan, np.inf, -np.inf):
            tau = exact_tau(q, q_dot, q_ddot)
            tau[rows[-1]] = bad
            est = estimator.update(DT, MODEL.terms(q, q_dot), q, q_dot, q_ddot, tau)
            np.testing.assert_array_equal(est.theta, held)
        assert estimator.skipped == {Skip.NOT_FINITE: 3}
        tau = exact_tau(q, q_dot, q_ddot)
        tau[[r for r in range(8) if r not in rows]] = np.nan
        estimator.update(DT, MODEL.terms(q, q_dot), q, q_dot, q_ddot, tau)
        assert estimator.skipped_steps == 3


def test_a_step_without_a_known_force_is_skipped_with_its_reason() -> None:
    """The app passes why the force is unknown instead of a force: theta is held, the
    reason counted; a frozen estimator counts nothing (it does not step anyway)."""
    estimator = paper(TRANSLATION_AND_JOINT_ROWS)
    run(estimator, 0.5)
    q, q_dot, q_ddot = motion(0.5)
    held = estimator.theta.copy()
    terms = MODEL.terms(q, q_dot)
    for reason in (Skip.NO_FORCE, Skip.LATE_CYCLE, Skip.LATE_CYCLE):
        est = estimator.update(DT, terms, q, q_dot, q_ddot, reason)
        np.testing.assert_array_equal(est.theta, held)
    assert estimator.skipped == {Skip.NO_FORCE: 1, Skip.LATE_CYCLE: 2}
    estimator.freeze()
    estimator.update(DT, terms, q, q_dot, q_ddot, Skip.NO_FORCE)
    assert estimator.skipped_steps == 3


def test_monitor_spread_is_the_range_over_a_full_window() -> None:
    mon = ExcitationMonitor(
        window_s=1.0,
        theta_scale=(1.0, 1.0, 1.0),
        row_scale=np.ones(1),
        excitation_min=0.5,
        spread_max=0.02,
        sample_period_s=0.1,
    )
    y = np.array([[1.0, 1.0, 1.0]]) * np.array([1.0, 0.0, 0.0])  # excites m2 only
    for _ in range(9):
        mon.update(0.1, y, 0.5, 0.16)
    assert mon.spread == float("inf")  # window not full yet
    mon.update(0.1, y, 0.5, 0.16)
    assert mon.spread == 0.0
    mon.update(0.1, y, 0.505, 0.16)  # m2 moves by 1 %
    assert mon.spread == pytest.approx(0.01, rel=1e-2)
    mon.update(0.1, y, 0.505, 0.168)  # lc moves by 5 %: the larger range counts
    assert mon.spread == pytest.approx(0.049, rel=2e-2)
    assert not mon.confident()  # and m3, m4 were never excited

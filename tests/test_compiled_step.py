"""The compiled control step (companion.control._step) against the Python reference.

Both paths of :class:`companion.control.flight.FlightControl` are run on the same inputs:
whole offline runs (every logged column but the step time) and long sequences of seeded
random cycles that drive the parts a run rarely reaches (skipped steps of every reason,
freeze/resume/reset, the bounds of theta and of the thrust scale, the trim, tilt and
thrust saturation, late cycles that sub-step the tilt reference). They agree to 1e-12,
relative where values exceed 1. The state filter's compiled update is compared with its
numpy reference step by step (1e-12) and, with everything compiled, over whole noisy runs
(1e-10: see test_offline_runs_agree_with_the_compiled_filter_too).
"""

from __future__ import annotations

import logging
import math
import tomllib
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from companion.config import load_config
from companion.control import compiled_step, native
from companion.control.flight import FlightControl
from companion.control.laws import DesiredState
from companion.control.setpoints import ThrustModel
from companion.estimation import filters
from companion.estimation.estimator import Skip
from companion.estimation.filters import FilteredState, StateFilter
from companion.frames import quaternion_ned_frd_from_enu_flu_floats
from companion.link.setpoint import quaternion_from_euler_zyx
from sitl.offline.simulation import COLUMNS, SimOptions, simulate
from sitl.scenario import load_scenario, parse_scenario

pytestmark = pytest.mark.skipif(
    native.python_reason() is not None, reason=f"compiled step not used: {native.python_reason()}"
)

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
TOL = 1e-12


def close(a, b, what: str, tol: float = TOL) -> None:
    """Equal NaN patterns and |a - b| <= tol max(1, |a|)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert np.array_equal(np.isnan(a), np.isnan(b)), what
    ok = np.isnan(a) | (np.abs(a - b) <= tol * np.maximum(1.0, np.abs(a)))
    assert ok.all(), f"{what}: largest difference {np.nanmax(np.abs(a - b))}"


def flight_scenario(
    delay_s: float = 0.0, measured: bool = False, com_from_joints: bool = False, **thrust_scale
):
    """paper_sim_flight with a 5 % thrust mismatch, a draining battery and, if given, the thrust
    scale as an unknown, the estimator ``delay_s`` behind and the law on the measured
    attitude motion."""
    data = tomllib.loads((CONFIGS / "paper_sim_flight.toml").read_text())
    data["plant"]["thrust_mismatch"] = 0.95
    data["plant"]["battery"] = {"capacity_ah": 0.2, "start_charge": 0.6}
    if thrust_scale:
        data["estimator"]["thrust_scale"] = thrust_scale
    data["estimator"]["acceleration_delay_s"] = delay_s
    data["controller"]["measured_unactuated_motion"] = measured
    data["estimator"]["rls"]["com_from_joints"] = com_from_joints
    return parse_scenario(data)


RUNS = {
    "paper ideal 10 s": (
        lambda: load_scenario(CONFIGS / "paper_sim.toml"),
        SimOptions(controller="passivity", estimator="paper"),
    ),
    "rls ideal": (
        lambda: load_scenario(CONFIGS / "paper_sim.toml"),
        SimOptions(controller="passivity", estimator="rls", duration_s=4.0),
    ),
    "nonadaptive rls flight pickup": (
        lambda: load_scenario(CONFIGS / "paper_sim_flight.toml"),
        SimOptions(
            controller="nonadaptive",
            estimator="rls",
            plant="underactuated",
            noise=True,
            duration_s=4.0,
            release_at_s=1.5,
            pickup_at_s=2.5,
        ),
    ),
    "paper + thrust scale flight": (
        lambda: flight_scenario(initial=1.0, bounds=[0.8, 1.2], gamma=2.0),
        SimOptions(
            controller="passivity",
            estimator="paper",
            plant="underactuated",
            noise=True,
            duration_s=4.0,
        ),
    ),
    "rls + thrust scale flight": (
        lambda: flight_scenario(initial=1.0, bounds=[0.8, 1.2], drift_std_per_sqrt_s=0.01),
        SimOptions(
            controller="passivity",
            estimator="rls",
            plant="underactuated",
            noise=True,
            duration_s=4.0,
        ),
    ),
    "rls + thrust scale flight pickup, compensated": (
        lambda: flight_scenario(
            initial=1.0, bounds=[0.8, 1.2], drift_std_per_sqrt_s=0.01, compensate=True
        ),
        SimOptions(
            controller="passivity",
            estimator="rls",
            plant="underactuated",
            noise=True,
            duration_s=4.0,
            release_at_s=1.5,
            pickup_at_s=2.5,
        ),
    ),
    "rls, delayed estimator, measured attitude motion, pickup": (
        lambda: flight_scenario(
            delay_s=0.024,
            measured=True,
            com_from_joints=True,
            drift_std_per_sqrt_s=0.01,
            compensate=True,
        ),
        SimOptions(
            controller="passivity",
            estimator="rls",
            plant="underactuated",
            noise=True,
            duration_s=4.0,
            release_at_s=1.5,
            pickup_at_s=2.5,
        ),
    ),
    "rls, m3 and m4 from the joints": (
        lambda: flight_scenario(com_from_joints=True),
        SimOptions(
            controller="passivity",
            estimator="rls",
            plant="underactuated",
            noise=True,
            duration_s=3.0,
        ),
    ),
    "paper estimator, delayed, measured attitude motion": (
        lambda: flight_scenario(delay_s=0.01, measured=True),
        SimOptions(
            controller="passivity",
            estimator="paper",
            plant="underactuated",
            noise=True,
            duration_s=3.0,
        ),
    ),
}


def run_both(scenario, options, monkeypatch) -> tuple[np.ndarray, np.ndarray]:
    """The run's columns (all but the step time) with the Python and the compiled step."""
    data = {}
    for mode in ("python", "compiled"):
        monkeypatch.setenv("COMPANION_STEP", mode)
        assert FlightControl(scenario.beliefs).compiled is (mode == "compiled")
        data[mode] = simulate(scenario, options).data
    keep = [i for i, c in enumerate(COLUMNS) if c != "step_time_us"]
    return data["python"][:, keep], data["compiled"][:, keep]


NAMES = [c for c in COLUMNS if c != "step_time_us"]


@pytest.mark.parametrize("name", list(RUNS))
def test_offline_runs_agree_column_by_column(name, monkeypatch):
    """The step, compiled and Python, behind the same (numpy) state filter: 1e-12, and
    5e-12 on the attitude rows' tau, which the underactuated plant does not use: after the
    compensated pickup the pitch row's tau (0.13 N m) is a difference of larger terms, and
    numpy's dot products round them in another order (measured 2.0e-12; every other
    column at most 6.4e-13)."""
    make, options = RUNS[name]
    monkeypatch.setattr(filters, "native_module", lambda compiled=None: None)
    reference, compiled = run_both(make(), options, monkeypatch)
    attitude_tau = ("tau_phi", "tau_theta", "tau_psi")
    for j, column in enumerate(NAMES):
        tol = 5 * TOL if options.plant == "underactuated" and column in attitude_tau else TOL
        close(reference[:, j], compiled[:, j], column, tol)
    # the run moved: the estimate left its start, and (flight) the thrust scale too
    m2 = reference[:, NAMES.index("m2_hat")]
    assert np.nanmax(m2) - np.nanmin(m2) > 1e-3
    if "thrust scale" in name:
        s = reference[:, NAMES.index("thrust_scale_hat")]
        assert np.nanmax(np.abs(s - 1.0)) > 1e-3


@pytest.mark.parametrize("name", ["nonadaptive rls flight pickup", "paper + thrust scale flight"])
def test_offline_runs_agree_with_the_compiled_filter_too(name, monkeypatch):
    """Everything compiled against everything Python. The filter's C update and numpy's
    product (OpenBLAS, with fused multiply-adds) round differently in the last bit
    (test_filter_updates_agree: 1e-12 step by step); a noisy closed loop carries those
    bits through the estimator for seconds (measured 1.3e-11 at most): 1e-10 here."""
    make, options = RUNS[name]
    reference, compiled = run_both(make(), options, monkeypatch)
    for j, column in enumerate(NAMES):
        close(reference[:, j], compiled[:, j], column, tol=1e-10)


def estimator_state(control: FlightControl) -> list:
    est = control.estimator
    values = [est.theta, est.thrust_scale, float(est.frozen), est.monitor.excitation]
    values.append(est.monitor.spread if math.isfinite(est.monitor.spread) else -1.0)
    qhat = getattr(est, "qhat", None)
    if qhat is not None:
        values.append(qhat)
    if hasattr(est, "p"):
        values += [est.p, est.p_s if est.scale is not None else 0.0]
        values.append(est.var_s if est.scale is not None else 0.0)
    values += [float(est.scale_held), float(est.calibrating), est.compensation_scale]
    return values


def random_cycles(control: FlightControl, seed: int, n: int) -> tuple[list, dict]:
    """Outputs of ``n`` seeded random cycles, and how often each rare case occurred."""
    rng = np.random.default_rng(seed)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.3, -1.2, 0.4])
    seen = dict.fromkeys(
        ("skip", "tilt", "thrust", "bound", "trim", "substep", "spread", "excitation", "held"), 0
    )
    outputs = []
    control.trim_active = True
    control.trim.start(np.array([0.3, -2.0]))
    skips = list(Skip)
    for i in range(n):
        q = q + rng.normal(0.0, 0.01, 8)
        q[5] = (q[5] + math.pi) % (2 * math.pi) - math.pi  # yaw wraps
        q_dot = rng.normal(0.0, 0.5, 8)
        state = FilteredState(q.copy(), q_dot, rng.normal(0.0, 2.0, 8))
        desired = DesiredState(
            q + rng.normal(0.0, 0.3, 8) * (1 + 5 * (i % 97 == 0)),  # large errors: tilt
            rng.normal(0.0, 0.3, 8),
            rng.normal(0.0, 1.0, 8),
        )
        dt = 0.004 if i % 50 else rng.uniform(0.001, 0.03)  # late cycles sub-step
        seen["substep"] += dt * control.tilt.w > 0.1
        roll = rng.integers(20)
        if roll == 0:
            applied: np.ndarray | Skip = skips[rng.integers(len(skips))]
        else:
            thrust = rng.uniform(-5.0, 40.0) if roll < 3 else rng.uniform(10.0, 20.0)
            applied = control.applied_force(q, thrust, rng.normal(0.0, 0.3, 2))
            if roll == 3:
                applied[2] = math.nan  # a corrupt read-back: NOT_FINITE
            elif roll == 4:
                applied = applied * 50.0  # garbage: the projection bounds theta
        if i == n // 6:
            control.estimator.calibrate()
        elif i == n // 6 + 200:
            control.estimator.resume()
        elif i == n // 3:
            control.estimator.freeze()
        elif i == n // 3 + 40:
            control.estimator.resume()
        elif i == 2 * n // 3:
            control.estimator.reset(control.nominal_theta)
        out = control.step(dt, state, desired, applied)
        est = out.estimate
        b = control.estimator.bounds  # type: ignore[attr-defined]
        seen["skip"] += isinstance(applied, Skip)
        seen["tilt"] += out.setpoint.tilt_saturated
        seen["thrust"] += out.setpoint.thrust_saturated
        seen["bound"] += est.theta[0] in (b.m2_min_kg, b.m2_max_kg)
        seen["trim"] += bool(np.any(np.abs(control.trim.force_n) == control.trim.limit))
        seen["spread"] += math.isfinite(est.spread)  # the monitor's window is full
        seen["excitation"] += est.excitation > 0.0
        seen["held"] += control.estimator.scale_held or control.estimator.scale is None  # type: ignore[attr-defined]
        outputs.append(
            (
                out.tau,
                [getattr(out.setpoint, f.name) for f in fields(out.setpoint) if f.compare],
                [est.theta, est.excitation, est.confident, est.frozen, est.thrust_scale],
                [est.spread if math.isfinite(est.spread) else -1.0],
                out.theta_hat,
                [out.desired.q, out.desired.q_dot, out.desired.q_ddot],
                control.trim.force_n,
                estimator_state(control),
                sorted((k.value, v) for k, v in control.estimator.skipped.items()),
                out.setpoint,
            )
        )
    return outputs, seen


CASES = {
    "passivity paper": ("passivity", "paper", None),
    "passivity rls": ("passivity", "rls", None),
    "nonadaptive paper": ("nonadaptive", "paper", None),
    "passivity rls + scale": ("passivity", "rls", {"initial": 1.0, "bounds": [0.9, 1.1]}),
    "passivity paper + scale": ("passivity", "paper", {"initial": 1.0, "bounds": [0.9, 1.1]}),
    "passivity rls + scale, compensated": (
        "passivity",
        "rls",
        {"initial": 1.0, "bounds": [0.9, 1.1], "compensate": True},
    ),
    "passivity paper + scale, compensated": (
        "passivity",
        "paper",
        {"initial": 1.0, "bounds": [0.9, 1.1], "compensate": True},
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_random_cycles_agree(case):
    controller, kind, scale = CASES[case]
    data = tomllib.loads((CONFIGS / "sitl_pickup.toml").read_text())
    if scale is not None:
        data["estimator"]["thrust_scale"] = scale
    config = parse_scenario(data).beliefs
    runs = []
    for compiled in (False, True):
        control = FlightControl(config, controller, estimator_kind=kind, compiled=compiled)
        assert control.compiled is compiled
        control.thrust = ThrustModel(control.thrust.max_thrust_n, 0.1)  # a thrust floor
        runs.append(random_cycles(control, seed=7, n=3000))
    (reference, seen), (compiled_out, seen_c) = runs
    assert seen == seen_c
    assert all(count > 0 for count in seen.values()), seen
    for i, (a, b) in enumerate(zip(reference, compiled_out, strict=True)):
        assert a[8] == b[8], f"cycle {i}: skipped"
        for k, (x, y) in enumerate(zip(a[:8], b[:8], strict=True)):
            if isinstance(x, list):
                for u, v in zip(x, y, strict=True):
                    close(u, v, f"cycle {i}, item {k}")
            else:
                close(x, y, f"cycle {i}, item {k}")


def test_the_compiled_setpoint_carries_the_links_quaternion_bit_for_bit():
    """GIVEN the compiled step WHEN seeded random cycles run (tilt and thrust saturated
    among them) THEN every setpoint carries the quaternion body FRD -> world NED that the
    link computes from its Euler angles, with the same bits (the link sends it as it is);
    the Python step leaves it to the link."""
    config = load_config(CONFIGS / "sitl_pickup.toml")
    for compiled in (True, False):
        control = FlightControl(config, compiled=compiled)
        control.thrust = ThrustModel(control.thrust.max_thrust_n, 0.1)
        outputs, _ = random_cycles(control, seed=3, n=600)
        for i, output in enumerate(outputs):
            sp = output[9]
            if not compiled:
                assert sp.q_ned_frd is None
                continue
            q_enu = quaternion_from_euler_zyx(sp.roll_rad, sp.pitch_rad, sp.yaw_rad)
            link = quaternion_ned_frd_from_enu_flu_floats(q_enu)
            assert sp.q_ned_frd is not None
            assert [v.hex() for v in sp.q_ned_frd] == [v.hex() for v in link], f"cycle {i}"


def test_the_python_step_when_the_extension_is_missing(monkeypatch, caplog):
    config = load_config(CONFIGS / "sitl_pickup.toml")
    monkeypatch.setattr(native, "_step", None)
    monkeypatch.setattr(native, "_warned", False)
    with caplog.at_level(logging.WARNING):
        first, second = FlightControl(config), FlightControl(config)
    assert not first.compiled and not second.compiled
    [record] = caplog.records  # once per process, one line
    assert "runs in Python" in record.getMessage() and "\n" not in record.getMessage()
    with pytest.raises(RuntimeError, match="not built"):
        FlightControl(config, compiled=True)
    assert StateFilter().ready is False  # the filter falls back alike


def test_filter_updates_agree():
    """The state filter's C update and predict product against their numpy references,
    call by call on the same stacked state: positions with latencies, subsets of rows,
    rates, yaw across +-pi (wrapped innovations), a rejected non-finite measurement.
    (Over thousands of updates both drift apart by more: the covariance update
    ``P - K (P h)^T`` walks with rounding whichever way it is rounded.)"""
    fuse = native.native_module(True).fuse
    seen = {"calls": 0, "wrapped": 0, "rejected": 0}

    def both(X, G, wrap):
        compiled = X.copy()
        try:
            fuse(compiled, G, wrap)
        except ValueError:
            seen["rejected"] += 1
            with pytest.raises(ValueError, match="not finite"):
                StateFilter._fuse(X.copy(), G, wrap)
            np.testing.assert_array_equal(compiled, X)  # unchanged
            raise
        innovation = G[0] @ X  # h.x - z per column
        StateFilter._fuse(X, G, wrap)
        seen["calls"] += 1
        seen["wrapped"] += any(not -math.pi <= innovation[r] < math.pi for r in wrap)
        scale = np.maximum(1.0, np.abs(X).max(axis=1, keepdims=True))
        assert (np.abs(X - compiled) <= TOL * scale).all()

    predict = native.native_module(True).predict

    def both_predict(A, X, X_next):
        compiled = np.empty_like(X_next)
        predict(A, X, compiled)
        np.dot(A, X, out=X_next)  # the reference
        seen["predicts"] += 1
        scale = np.maximum(1.0, np.abs(X_next).max(axis=1, keepdims=True))
        assert (np.abs(X_next - compiled) <= TOL * scale).all()

    seen["predicts"] = 0
    rng = np.random.default_rng(3)
    f = StateFilter(compiled=False)
    f._fuse_columns = both
    f._propagate = both_predict
    truth = np.array([0.0, 0.0, 1.0, 0.1, -0.1, 3.1, -1.0, 0.5])
    for i in range(3000):
        truth = truth + rng.normal(0.0, 0.02, 8)
        z = truth + rng.normal(0.0, 1e-3, 8)
        z[5] = (z[5] + math.pi) % (2 * math.pi) - math.pi
        latency = float(rng.choice([0.0, 0.004, 0.0137]))
        rows = [None, (0, 1, 2, 3, 4, 5), (6, 7), (3, 4, 5)][i % 4]
        f.predict(0.004 if i % 7 else 0.011)
        f.update_position(z if rows is None else z[list(rows)], latency_s=latency, rows=rows)
        if f.ready:
            f.update_velocity(rng.normal(0.0, 0.1, 3), latency_s=latency, rows=(3, 4, 5))
        if i == 1500:
            with pytest.raises(ValueError, match="not finite"), np.errstate(invalid="ignore"):
                f.update_position(np.full(8, math.inf))
    assert seen["calls"] > 5000 and seen["wrapped"] > 0 and seen["rejected"] == 1, seen
    assert seen["predicts"] == 3000


def test_filter_update_in_one_call_is_the_compiled_fuse():
    """``_step.update`` (the measurement placed, the variance row, G built in C) leaves the
    stacked state bit for bit where the numpy steps of ``StateFilter._update`` around the
    C fuse leave it: subsets of rows out of order, latencies drawn from a continuous range
    (the joints' ages), rates, yaw across +-pi, and the rejected measurements (non-finite,
    negative latency, wrong length, not numbers: ValueError on both paths) that must leave
    the estimate alone."""
    rng = np.random.default_rng(5)
    one_call = StateFilter(compiled=True)
    steps = StateFilter(compiled=True)
    steps._native_update = None  # the numpy steps around _step.fuse
    assert one_call._native_update is not None
    truth = np.array([0.0, 0.0, 1.0, 0.1, -0.1, 3.1, -1.0, 0.5])
    rejected = 0
    for i in range(2000):
        truth = truth + rng.normal(0.0, 0.02, 8)
        z = truth + rng.normal(0.0, 1e-3, 8)
        z[5] = (z[5] + math.pi) % (2 * math.pi) - math.pi
        latency = float(rng.uniform(0.0, 0.02)) if i % 3 else 0.0
        rows = [None, (0, 1, 2, 3, 4, 5), (6, 7), (3, 4, 5), (7, 2)][i % 5]
        rates = rng.normal(0.0, 0.1, 3)
        bad = [
            ([math.nan, 1.0], {"rows": (6, 7)}),
            ([1.0, 2.0], {"rows": (6, 7), "latency_s": -0.001}),
            ([1.0, 2.0, 3.0], {"rows": (6, 7)}),
            (1.0, {"rows": (6, 7)}),
            (["a", "b"], {"rows": (6, 7)}),
        ][i % 5]
        for f in (one_call, steps):
            f.predict(0.004 if i % 7 else 0.011)
            meas = z if rows is None else tuple(z[list(rows)])
            f.update_position(meas, latency_s=latency, rows=rows)
            if f.ready:
                f.update_velocity(rates, latency_s=latency, rows=(3, 4, 5))
            if f.ready and i % 97 == 0:
                with pytest.raises(ValueError), np.errstate(invalid="ignore"):
                    f.update_position(bad[0], **bad[1])
                rejected += f is steps
        np.testing.assert_array_equal(one_call._X, steps._X)
    assert rejected > 15
    assert one_call.value(5) == one_call.estimate.q[5]


def test_selection(monkeypatch):
    config = load_config(CONFIGS / "sitl_pickup.toml")
    assert FlightControl(config).compiled
    assert not FlightControl(config, compiled=False).compiled
    assert not FlightControl(config, "asmc").compiled  # eq. asc1 runs in Python
    monkeypatch.setenv("COMPANION_STEP", "python")
    assert not FlightControl(config).compiled
    assert FlightControl(config, compiled=True).compiled


def test_compiled_state_is_the_objects_state():
    """freeze, reset, tilt.reset, trim.start and the thrust floor reach the C step (the
    estimator on the cycle's own inputs, so that a skip counts at once)."""
    config = load_config(CONFIGS / "sitl_pickup.toml")
    estimator = config.estimator.model_copy(update={"acceleration_delay_s": 0.0})
    control = FlightControl(config.model_copy(update={"estimator": estimator}))
    est = control.estimator
    est.freeze()
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, -1.2, 0.4])
    zero = np.zeros(8)
    state = FilteredState(q, zero, zero)
    out = control.step(0.004, state, DesiredState(q, zero, zero), np.full(8, 1.0))
    assert out.estimate.frozen and est.skipped_steps == 0
    est.resume()
    control.step(0.004, state, DesiredState(q, zero, zero), Skip.NO_SERVO_READ)
    assert est.skipped == {Skip.NO_SERVO_READ: 1}
    est.reset((0.3, 0.03, 0.004))  # inside the bounds: kept as is
    np.testing.assert_array_equal(est.theta, (0.3, 0.03, 0.004))
    control.tilt.reset(0.1, -0.2)
    control.trim.start(np.array([5.0, -0.25]))
    np.testing.assert_array_equal(control.trim.force_n, (control.trim.limit, -0.25))
    out = control.step(0.004, state, DesiredState(q, zero, zero), Skip.NO_FORCE)
    np.testing.assert_array_equal(out.desired.q[3:5], (0.1, -0.2))
    control.thrust = ThrustModel(control.thrust.max_thrust_n, 0.9)
    out = control.step(0.004, state, DesiredState(q, zero, zero), Skip.NO_FORCE)
    assert out.setpoint.thrust_relative == 0.9 and out.setpoint.thrust_saturated


def test_inputs_that_are_not_contiguous_float64_are_converted():
    config = load_config(CONFIGS / "sitl_pickup.toml")
    a, b = FlightControl(config), FlightControl(config)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.3, -1.2, 0.4])
    wide = np.zeros((8, 2))
    wide[:, 0] = q  # a strided view
    zero = np.zeros(8)
    tau = np.array([0, 0, 12, 0, 0, 0, 0, 0])  # integers
    out_a = a.step(0.004, FilteredState(q, zero, zero), DesiredState(q, zero, zero), tau)
    out_b = b.step(0.004, FilteredState(wide[:, 0], zero, zero), DesiredState(q, zero, zero), tau)
    np.testing.assert_array_equal(out_a.tau, out_b.tau)
    with pytest.raises(ValueError, match="8"):
        a.step(0.004, FilteredState(q[:7], zero, zero), DesiredState(q, zero, zero), tau)


def test_frozen_record_builds_what_the_constructor_builds():
    from dataclasses import dataclass

    from companion.control.setpoints import AttitudeThrustSetpoint

    fields = dict(
        roll_rad=0.1,
        pitch_rad=-0.2,
        yaw_rad=0.3,
        thrust_n=12.0,
        thrust_relative=0.4,
        tilt_saturated=False,
        thrust_saturated=True,
        q_ned_frd=(0.5, 0.5, -0.5, 0.5),
    )
    made = compiled_step.frozen_record(AttitudeThrustSetpoint, **fields)
    assert made == AttitudeThrustSetpoint(**fields) and hash(made) is not None
    with pytest.raises(TypeError, match="fields"):
        compiled_step.frozen_record(AttitudeThrustSetpoint, roll_rad=0.1)

    @dataclass(frozen=True)
    class Checked:
        value: float

        def __post_init__(self) -> None:
            assert self.value > 0

    with pytest.raises(TypeError, match="__init__"):
        compiled_step.frozen_record(Checked, value=-1.0)

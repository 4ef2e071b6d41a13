"""The compiled control step (companion._step) against the Python reference.

Both paths of :class:`companion.flight_control.FlightControl` are run on the same inputs:
whole offline runs (every logged column but the step time) and long sequences of seeded
random cycles that drive the parts a run rarely reaches (skipped steps of every reason,
freeze/resume/reset, the bounds of theta and of the thrust scale, the trim, tilt and
thrust saturation, late cycles that sub-step the tilt reference). They agree to 1e-12,
relative where values exceed 1.
"""

from __future__ import annotations

import logging
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from companion import compiled_step
from companion.config import load_config
from companion.control import DesiredState
from companion.estimation import Skip
from companion.filters import FilteredState
from companion.flight_control import FlightControl
from companion.setpoints import ThrustModel
from sitl.offline import COLUMNS, SimOptions, simulate
from sitl.scenario import load_scenario, parse_scenario

pytestmark = pytest.mark.skipif(
    compiled_step.compiled_step_module() is None, reason="companion._step is not built"
)

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
TOL = 1e-12


def close(a, b, what: str) -> None:
    """Equal NaN patterns and |a - b| <= TOL max(1, |a|)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert np.array_equal(np.isnan(a), np.isnan(b)), what
    ok = np.isnan(a) | (np.abs(a - b) <= TOL * np.maximum(1.0, np.abs(a)))
    assert ok.all(), f"{what}: largest difference {np.nanmax(np.abs(a - b))}"


def flight_scenario(**thrust_scale):
    """paper_sim_flight with a 5 % thrust mismatch, 10 % sag and, if given, the thrust
    scale as an unknown."""
    data = tomllib.loads((CONFIGS / "paper_sim_flight.toml").read_text())
    data["plant"]["thrust_mismatch"] = 0.95
    data["plant"]["battery_sag"] = {"thrust_loss": 0.1, "over_s": 20.0}
    if thrust_scale:
        data["estimator"]["thrust_scale"] = thrust_scale
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
}


@pytest.mark.parametrize("name", list(RUNS))
def test_offline_runs_agree_column_by_column(name, monkeypatch):
    make, options = RUNS[name]
    scenario = make()
    data = {}
    for mode in ("python", "compiled"):
        monkeypatch.setenv("COMPANION_STEP", mode)
        assert FlightControl(scenario.beliefs).compiled is (mode == "compiled")
        data[mode] = simulate(scenario, options).data
    keep = [i for i, c in enumerate(COLUMNS) if c != "step_time_us"]
    reference, compiled = data["python"][:, keep], data["compiled"][:, keep]
    for j, i in enumerate(keep):
        close(reference[:, j], compiled[:, j], COLUMNS[i])
    # the run moved: the estimate left its start, and (flight) the thrust scale too
    m2 = reference[:, keep.index(COLUMNS.index("m2_hat"))]
    assert np.nanmax(m2) - np.nanmin(m2) > 1e-3
    if "thrust scale" in name:
        s = reference[:, keep.index(COLUMNS.index("thrust_scale_hat"))]
        assert np.nanmax(np.abs(s - 1.0)) > 1e-3


def estimator_state(control: FlightControl) -> list:
    est = control.estimator
    values = [est.theta, est.thrust_scale, float(est.frozen), est.monitor.excitation]
    values.append(est.monitor.spread if math.isfinite(est.monitor.spread) else -1.0)
    qhat = getattr(est, "qhat", None)
    if qhat is not None:
        values.append(qhat)
    if hasattr(est, "p"):
        values.append(est.p)
    return values


def random_cycles(control: FlightControl, seed: int, n: int) -> tuple[list, dict]:
    """Outputs of ``n`` seeded random cycles, and how often each rare case occurred."""
    rng = np.random.default_rng(seed)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.3, -1.2, 0.4])
    seen = dict.fromkeys(("skip", "tilt", "thrust", "bound", "trim", "substep"), 0)
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
        if i == n // 3:
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
        outputs.append(
            (
                out.tau,
                [getattr(out.setpoint, f) for f in out.setpoint.__dataclass_fields__],
                [est.theta, est.excitation, est.confident, est.frozen, est.thrust_scale],
                [est.spread if math.isfinite(est.spread) else -1.0],
                out.theta_hat,
                [out.desired.q, out.desired.q_dot, out.desired.q_ddot],
                control.trim.force_n,
                estimator_state(control),
                sorted((k.value, v) for k, v in control.estimator.skipped.items()),
            )
        )
    return outputs, seen


CASES = {
    "passivity paper": ("passivity", "paper", None),
    "passivity rls": ("passivity", "rls", None),
    "nonadaptive paper": ("nonadaptive", "paper", None),
    "passivity rls + scale": ("passivity", "rls", {"initial": 1.0, "bounds": [0.9, 1.1]}),
    "passivity paper + scale": ("passivity", "paper", {"initial": 1.0, "bounds": [0.9, 1.1]}),
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


def test_the_python_step_when_the_extension_is_missing(monkeypatch, caplog):
    config = load_config(CONFIGS / "sitl_pickup.toml")
    monkeypatch.setattr(compiled_step, "_step", None)
    monkeypatch.setattr(compiled_step, "_warned", False)
    with caplog.at_level(logging.WARNING):
        first, second = FlightControl(config), FlightControl(config)
    assert not first.compiled and not second.compiled
    [record] = caplog.records  # once per process, one line
    assert "runs in Python" in record.getMessage() and "\n" not in record.getMessage()
    with pytest.raises(RuntimeError, match="not built"):
        FlightControl(config, compiled=True)


def test_selection(monkeypatch):
    config = load_config(CONFIGS / "sitl_pickup.toml")
    assert FlightControl(config).compiled
    assert not FlightControl(config, compiled=False).compiled
    assert not FlightControl(config, "asmc").compiled  # eq. asc1 runs in Python
    monkeypatch.setenv("COMPANION_STEP", "python")
    assert not FlightControl(config).compiled
    assert FlightControl(config, compiled=True).compiled


def test_compiled_state_is_the_objects_state():
    """freeze, reset, tilt.reset, trim.start and the thrust floor reach the C step."""
    config = load_config(CONFIGS / "sitl_pickup.toml")
    control = FlightControl(config)
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

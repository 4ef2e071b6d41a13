"""The control cycle's compiled twin (``companion.control.control_step``) against its Python
source: one source built twice, the two builds agree bit for bit.

The step runs through :class:`~companion.control.flight.FlightControl`, once over the
compiled twin and once over the Python source, on seeded random cycles that reach what runs
rarely (every skip reason, calibrate/freeze/resume/reset, theta and the thrust scale on
their bounds, tilt and thrust saturation, the trim at its limit, late cycles that sub-step
the tilt reference, a non-finite estimate, the estimator on delayed inputs); the state
filter's ``fuse``, ``update`` and ``predict`` on random stacked states, rejections included.
How the compiled step compares with the numpy reference classes is
tests/test_compiled_step.py.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import fields
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from companion.compiled import twin, twin_reason
from companion.control import control_step, flight
from companion.control.flight import FlightControl
from companion.control.laws import DesiredState
from companion.control.setpoints import ThrustModel
from companion.estimation.estimator import Skip
from companion.estimation.filters import FilteredState
from companion.estimation.inputs import DelayedInputs, delay_cycles
from companion.estimation.state import euler_rates_from_body_rates
from sitl.scenario import parse_scenario

CONFIGS = Path(__file__).resolve().parent.parent / "configs"

pytestmark = pytest.mark.skipif(
    twin_reason(control_step) is not None, reason=f"twin not used: {twin_reason(control_step)}"
)


def bits(values) -> list[str]:
    """The float bits of arrays, floats and booleans, flattened."""
    return [float(v).hex() for v in np.ravel(np.asarray(values, dtype=float))]


def control_over(module: ModuleType, config, controller: str, kind: str, monkeypatch):
    """A FlightControl whose step runs on ``module`` (the twin or its source), with a
    thrust floor and the trim on."""
    monkeypatch.setattr(flight, "native_module", lambda compiled=None: module)
    control = FlightControl(config, controller, estimator_kind=kind)
    assert control.compiled
    control.thrust = ThrustModel(control.thrust.max_thrust_n, 0.1)
    control.trim_active = True
    control.trim.start(np.array([0.3, -2.0]))
    return control


SCALE = {"initial": 1.0, "bounds": [0.9, 1.1], "compensate": True, "window_s": 0.2}
"""A thrust scale carried with the battery's voltage after a short calibration."""
CASES = {
    "paper, feed-forward": ("passivity", "paper", None, True, 0.0),
    "rls, no feed-forward, delayed inputs": ("passivity", "rls", None, False, 0.02),
    "nonadaptive rls": ("nonadaptive", "rls", None, True, 0.0),
    "paper + thrust scale, compensated, delayed inputs": ("passivity", "paper", SCALE, False, 0.02),
    "rls + thrust scale, compensated": ("passivity", "rls", SCALE, True, 0.0),
}


@pytest.mark.parametrize("case", list(CASES))
def test_the_step_twin_is_its_python_source_bit_for_bit(case: str, monkeypatch) -> None:
    """GIVEN the same FlightControl twice, its step over the compiled twin and over its
    Python source WHEN 600 seeded random cycles run with events between them and battery
    voltages (the thrust scale carried with them after its calibration) THEN every output,
    the whole compiled state after every cycle, and the errors (a non-finite estimate from
    forces near overflow) have the same bits."""
    controller, kind, scale, feedforward, delay_s = CASES[case]
    data = tomllib.loads((CONFIGS / "sitl_pickup.toml").read_text())
    if scale is not None:
        data["estimator"]["thrust_scale"] = scale
    if not feedforward:
        del data["controller"]["attitude_feedforward"]
    data["estimator"]["acceleration_delay_s"] = delay_s
    config = parse_scenario(data).beliefs
    compiled = twin(control_step)
    assert compiled is not control_step
    fast, slow = (
        control_over(module, config, controller, kind, monkeypatch)
        for module in (compiled, control_step)
    )
    rng = np.random.default_rng(11)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.3, -1.2, 0.4])
    skips = list(Skip)
    seen = dict.fromkeys(("skip", "tilt", "thrust", "bound", "trim", "substep", "error"), 0)
    n = 600
    for i in range(n):
        q = q + rng.normal(0.0, 0.01, 8)
        q[5] = (q[5] + math.pi) % (2 * math.pi) - math.pi
        state = FilteredState(q.copy(), rng.normal(0.0, 0.5, 8), rng.normal(0.0, 2.0, 8))
        desired = DesiredState(
            q + rng.normal(0.0, 0.3, 8) * (1 + 5 * (i % 97 == 0)),
            rng.normal(0.0, 0.3, 8),
            rng.normal(0.0, 1.0, 8),
        )
        dt = 0.004 if i % 50 else float(rng.uniform(0.001, 0.03))
        volts = None if i % 23 == 0 else float(rng.uniform(14.0, 16.8))
        roll = rng.integers(20)
        applied: np.ndarray | Skip
        if roll == 0:
            applied = skips[rng.integers(len(skips))]
        else:
            thrust = rng.uniform(-5.0, 40.0) if roll < 3 else rng.uniform(10.0, 20.0)
            applied = fast.applied_force(q, thrust, rng.normal(0.0, 0.3, 2))
            if roll == 3:
                applied[2] = math.nan
            elif roll == 4:
                applied = applied * 50.0
            elif roll == 5 and i % 5 == 0:
                applied = applied * 1e200
        results = []
        for control in (fast, slow):
            if i == n // 6:
                control.estimator.calibrate()
            elif i in (n // 6 + 100, n // 3 + 40):
                control.estimator.resume()
            elif i == n // 3:
                control.estimator.freeze()
            elif i == n // 2:
                control.tilt.reset(0.2, -0.1)
            elif i == 2 * n // 3:
                control.estimator.reset(control.nominal_theta)
            assert control._compiled is not None
            control.supply(volts)
            try:
                out = control.step(dt, state, desired, applied)
            except FloatingPointError as error:
                results.append([str(error), *bits(control._compiled.state)])
                continue
            setpoint, estimate = out.setpoint, out.estimate
            values = [out.tau, [getattr(setpoint, f.name) for f in fields(setpoint) if f.compare]]
            values += [setpoint.q_ned_frd]
            values += [estimate.theta, estimate.excitation, estimate.spread]
            values += [estimate.confident, estimate.thrust_scale, out.theta_hat]
            values += [out.desired.q, out.desired.q_dot, out.desired.q_ddot]
            results.append([b for v in values for b in bits(v)] + bits(control._compiled.state))
        assert results[0] == results[1], f"cycle {i}"
        if not results[0][0].startswith("0x"):
            seen["error"] += 1
            continue
        b = fast.estimator.bounds  # type: ignore[attr-defined]
        seen["skip"] += isinstance(applied, Skip)
        seen["tilt"] += out.setpoint.tilt_saturated
        seen["thrust"] += out.setpoint.thrust_saturated
        seen["bound"] += float(out.estimate.theta[0]) in (b.m2_min_kg, b.m2_max_kg)
        seen["trim"] += bool(np.any(np.abs(fast.trim.force_n) == fast.trim.limit))
        seen["substep"] += dt * fast.tilt.w > 0.1
    assert all(count > 0 for count in seen.values()), seen


@pytest.mark.parametrize("delay_s", [0.004, 0.012, 0.05, 0.2])
@pytest.mark.parametrize("build", ["twin", "python"])
def test_the_steps_delay_line_is_delayed_inputs_bit_for_bit(
    delay_s: float, build: str, monkeypatch
) -> None:
    """GIVEN a FlightControl whose step keeps the estimator's delay line (n = 3, 8, 33, 133
    cycles of the first 1.5 ms period: numpy's sum of the periods sequential, in blocks of
    eight, and split beyond 128 values)
    and the same step without a delay fed :class:`DelayedInputs` as the step's reference
    did WHEN seeded cycles of irregular periods with skips and a restart of the line run
    THEN outputs and the whole state have the same bits."""
    data = tomllib.loads((CONFIGS / "sitl_pickup.toml").read_text())
    data["estimator"]["acceleration_delay_s"] = delay_s
    with_line = parse_scenario(data).beliefs
    data["estimator"]["acceleration_delay_s"] = 0.0
    without = parse_scenario(data).beliefs
    module = twin(control_step) if build == "twin" else control_step
    line_step = control_over(module, with_line, "passivity", "paper", monkeypatch)
    fed_step = control_over(module, without, "passivity", "paper", monkeypatch)
    assert line_step._compiled is not None and fed_step._compiled is not None
    line: DelayedInputs | None = None
    rng = np.random.default_rng(5)
    skips = list(Skip)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.3, -1.2, 0.4])
    for i in range(800):
        q = q + rng.normal(0.0, 0.01, 8)
        state = FilteredState(q.copy(), rng.normal(0.0, 0.5, 8), rng.normal(0.0, 2.0, 8))
        desired = DesiredState(q + rng.normal(0.0, 0.1, 8), np.zeros(8), np.zeros(8))
        dt = 0.0015 if i == 0 else 0.004 if i % 7 else float(rng.uniform(0.001, 0.03))
        applied: np.ndarray | Skip = (
            skips[rng.integers(len(skips))]
            if rng.integers(10) == 0
            else line_step.applied_force(q, float(rng.uniform(10.0, 20.0)), rng.normal(0, 0.3, 2))
        )
        if i == 450:
            line_step.restart_estimator_inputs()
            assert line is not None
            line.reset()
        if line is None:
            line = DelayedInputs(delay_cycles(delay_s, dt))
        inputs = line.push(dt, state.q, state.q_dot, applied)
        fed = Skip.WARMING_UP if inputs is None else applied
        results = []
        for control, tau, given in ((line_step, applied, None), (fed_step, fed, inputs)):
            assert control._compiled is not None
            tau_out, setpoint, estimate, _, _ = control._compiled.step(
                dt, state.q, state.q_dot, state.q_ddot, desired, tau, given
            )
            values = [tau_out, [getattr(setpoint, f.name) for f in fields(setpoint) if f.compare]]
            values += [setpoint.q_ned_frd]
            values += [estimate.theta, estimate.excitation, estimate.spread]
            results.append([b for v in values for b in bits(v)] + bits(own_state(control)))
        assert results[0] == results[1], f"cycle {i}"
    assert line_step.estimator.skipped == fed_step.estimator.skipped


def own_state(control: FlightControl) -> np.ndarray:
    """The compiled state before the windows but the delay line's counters."""
    assert control._compiled is not None
    layout = control._compiled.layout
    line = [layout[f"State.delay_{name}"][0] for name in ("count", "head")]
    return np.delete(control._compiled.state[: layout["State.ring"][0]], line)


def stacked_state(rng: np.random.Generator, n: int) -> np.ndarray:
    """A random stacked filter state (17 x n): per column an estimate, a symmetric positive
    definite covariance, the jerk PSD, a measurement and the variances."""
    x = np.zeros((17, n))
    for c in range(n):
        a = rng.normal(0.0, 0.1, (3, 3))
        p = a @ a.T + 1e-3 * np.eye(3)
        estimate = rng.normal(0.0, 2.0, 3)
        for i in range(3):
            x[4 * i, c] = estimate[i]
            x[4 * i + 1 : 4 * i + 4, c] = p[i]
    x[12] = 1.0
    x[14:17] = rng.uniform(1e-6, 1e-3, (3, n))
    return x


def test_the_filter_functions_twin_is_their_python_source_bit_for_bit() -> None:
    """GIVEN random stacked states WHEN the compiled twin and the Python source each
    predict, fuse (random G, angles a turn off) and update (random rows in any order,
    latencies, rates, and rejected measurements: non-finite, a negative latency, a wrong
    count, not numbers) THEN the states and the errors have the same bits."""
    compiled = twin(control_step)
    rng = np.random.default_rng(3)
    rejected = 0
    for i in range(400):
        n = int(rng.integers(1, 9))
        x = stacked_state(rng, n)
        a = rng.normal(0.0, 1.0, (17, 17))
        nexts = [np.empty_like(x) for _ in range(2)]
        for module, x_next in zip((compiled, control_step), nexts, strict=True):
            module.predict(a, x, x_next)
        assert bits(nexts[0]) == bits(nexts[1])
        g = rng.normal(0.0, 1.0, (25, 17))
        g[24] = -np.abs(g[24]) - 1.0
        wrap = tuple(range(min(n, 3)))
        x[0, : len(wrap)] += 7.0
        states = [x.copy() for _ in range(2)]
        for module, state in zip((compiled, control_step), states, strict=True):
            module.fuse(state, g, wrap)
        assert bits(states[0]) == bits(states[1])
        rows = tuple(int(r) for r in rng.permutation(n)[: rng.integers(1, n + 1)])
        z: list = rng.normal(0.0, 2.0, len(rows)).tolist()
        latency = float(rng.choice([0.0, rng.uniform(0.0, 0.03)]))
        bad = i % 10
        if bad == 1:
            z[0] = math.nan
        elif bad == 2:
            latency = -0.001
        elif bad == 3:
            z = [*z, 1.0]
        elif bad == 4:
            z = ["a"] * len(rows)
        order = int(rng.integers(2))
        wrap = tuple(r for r in rows if r < 3) if order == 0 else ()
        states = [x.copy() for _ in range(2)]
        errors = []
        for module, state in zip((compiled, control_step), states, strict=True):
            try:
                module.update(state, order, latency, rows, z, wrap)
                errors.append(None)
            except ValueError as error:
                errors.append(str(error))
        assert errors[0] == errors[1]
        assert bits(states[0]) == bits(states[1])
        rejected += errors[0] is not None
    assert rejected >= 150


def value_of_angle(a: float) -> float:
    """An angle [rad] as StateFilter.value reads it: wrapped to [-pi, pi) only outside."""
    if -math.pi <= a < math.pi:
        return a
    w = (a + math.pi) % (2.0 * math.pi) - math.pi
    return w - 2.0 * math.pi if w >= math.pi else w


@pytest.mark.parametrize("build", ["twin", "python"])
def test_the_body_rate_update_is_the_conversion_and_the_update_bit_for_bit(build: str) -> None:
    """GIVEN random stacked states of 8 rows (roll and pitch a turn off now and then) WHEN
    ``update_body_rates`` fuses gyro body rates THEN the state has the bits of
    ``euler_rates_from_body_rates`` at the filter's wrapped roll and pitch followed by
    ``update`` of the Euler rates (what StateAssembler.body_rates did in two steps), and
    a bad measurement is refused alike."""
    module = twin(control_step) if build == "twin" else control_step
    rng = np.random.default_rng(5)
    for i in range(300):
        x = stacked_state(rng, 8)
        if i % 3 == 0:
            x[0, 3:5] += 2.0 * math.pi * rng.choice([-1.0, 1.0], 2)
        omega = rng.normal(0.0, 1.0, 3).tolist()
        latency = float(rng.choice([0.0, rng.uniform(0.0, 0.03)]))
        if i % 10 == 1:
            omega[1] = math.nan
        phi, theta = (value_of_angle(a) for a in x[0, 3:5].tolist())
        rates = euler_rates_from_body_rates(phi, theta, omega)
        states = [x.copy() for _ in range(2)]
        errors = []
        for k, state in enumerate(states):
            try:
                if k == 0:
                    module.update_body_rates(state, latency, omega)
                else:
                    module.update(state, 1, latency, (3, 4, 5), rates, ())
                errors.append(None)
            except ValueError as error:
                errors.append(str(error))
        assert errors[0] == errors[1]
        assert bits(states[0]) == bits(states[1]), f"case {i}"
    with pytest.raises(ValueError, match="3 numbers"):
        module.update_body_rates(stacked_state(rng, 8), 0.0, [0.1, 0.2])


@pytest.mark.parametrize("build", ["twin", "python"])
def test_the_cycle_in_one_call_is_the_prediction_and_the_updates_bit_for_bit(build: str) -> None:
    """GIVEN random stacked states of q's 8 rows and a prediction matrix WHEN
    ``fuse_cycle`` takes a cycle's pose, velocity, body rates and joints (each there or
    not; now and then a non-finite one) THEN the predicted state has the bits of
    ``predict`` followed by the updates one by one in StateAssembler's order, and a bad
    measurement is refused alike, the steps before it done."""
    module = twin(control_step) if build == "twin" else control_step
    rng = np.random.default_rng(8)
    seen = dict.fromkeys(("velocity", "omega", "joints", "refused"), 0)
    for i in range(300):
        x = stacked_state(rng, 8)
        a = np.eye(17) + rng.normal(0.0, 0.01, (17, 17))
        pose = rng.normal(0.0, 2.0, 6).tolist()
        velocity = rng.normal(0.0, 1.0, 3) if i % 2 else None
        omega = rng.normal(0.0, 1.0, 3).tolist() if i % 3 else None
        joints = rng.normal(0.0, 1.0, 2).tolist() if i % 5 else None
        rates = rng.normal(0.0, 1.0, 2).tolist()
        age = float(rng.uniform(0.0, 0.05))
        if i % 11 == 1:
            pose[2] = math.nan
        states = [np.empty_like(x) for _ in range(2)]
        errors = []
        for k, state in enumerate(states):
            try:
                if k == 0:
                    module.fuse_cycle(a, x, state, pose, velocity, omega, joints, rates, age)
                else:
                    module.predict(a, x, state)
                    module.update(state, 0, 0.0, (0, 1, 2, 3, 4, 5), pose, (3, 4, 5))
                    if velocity is not None:
                        module.update(state, 1, 0.0, (0, 1, 2), velocity, ())
                    if omega is not None:
                        module.update_body_rates(state, 0.0, omega)
                    if joints is not None:
                        module.update(state, 0, age, (6, 7), joints, ())
                        module.update(state, 1, age, (6, 7), rates, ())
                errors.append(None)
            except ValueError as error:
                errors.append(str(error))
        assert errors[0] == errors[1]
        assert bits(states[0]) == bits(states[1]), f"case {i}"
        seen["velocity"] += velocity is not None
        seen["omega"] += omega is not None
        seen["joints"] += joints is not None
        seen["refused"] += errors[0] is not None
    assert all(count > 0 for count in seen.values()), seen


@pytest.mark.parametrize("build", ["twin", "python"])
def test_the_filter_product_leaving_out_zeros_is_the_whole_sum(build: str) -> None:
    """GIVEN sparse A (exact zeros of both signs, as the filter's F, Q and G have) and
    stacked states with zeros, negative values and, in some, an infinity or a NaN WHEN
    predict forms A X THEN every value has the bits of the whole sum over k in order,
    begun at 0.0 (the NaN of 0 x inf included)."""
    module = twin(control_step) if build == "twin" else control_step
    rng = np.random.default_rng(9)
    for i in range(200):
        n = int(rng.integers(1, 9))
        a = rng.normal(0.0, 1.0, (17, 17)) * (rng.random((17, 17)) < 0.3)
        a[rng.random((17, 17)) < 0.1] = -0.0
        x = rng.normal(0.0, 1.0, (17, n)) * (rng.random((17, n)) < 0.7)
        x[rng.random((17, n)) < 0.05] = -0.0
        if i % 7 == 0:
            x[int(rng.integers(17)), int(rng.integers(n))] = [math.inf, -math.inf, math.nan][i % 3]
        expected = np.empty((17, n))
        for r in range(17):
            for c in range(n):
                acc = 0.0
                for k in range(17):
                    acc += float(a[r, k]) * float(x[k, c])
                expected[r, c] = acc
        got = np.empty_like(x)
        with np.errstate(invalid="ignore"):  # 0 x inf in the Python build's numpy floats
            module.predict(a, x, got)
        assert bits(got) == bits(expected), f"case {i}"


def test_the_step_refuses_what_it_cannot_read_as_8_float64_values(monkeypatch) -> None:
    """GIVEN the default scenario's step over the compiled twin and over its Python source
    WHEN an input is 7 values, a 2 x 4 array or a value with no buffer (and, for the
    compiled build, which reads the values' memory, integers, big-endian or strided
    float64) THEN ValueError or TypeError, and the step's buffer is untouched
    (CompiledStep converts such inputs and calls again: tests/test_compiled_step.py)."""
    config = parse_scenario(tomllib.loads((CONFIGS / "sitl_pickup.toml").read_text())).beliefs
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.3, -1.2, 0.4])
    wide = np.zeros((8, 2))
    wide[:, 0] = q
    common = {"7 values": q[:7], "2 x 4": q.reshape(2, 4).copy(), "a string": "abcdefgh"}
    memory = {
        "integers": np.arange(8),
        "big-endian": q.astype(">f8"),
        "strided": wide[:, 0],
    }
    for module, bad_inputs in ((twin(control_step), common | memory), (control_step, common)):
        step = control_over(module, config, "passivity", "paper", monkeypatch)._compiled
        values = np.frombuffer(step._work[0], dtype=np.float64)
        module.step(step._work, 0.004, -1, *[q] * 7)  # the good inputs run
        before = values.copy()
        for name, bad in bad_inputs.items():
            for position in range(7):
                args = [q] * 7
                args[position] = bad
                with pytest.raises((ValueError, TypeError)):
                    module.step(step._work, 0.004, -1, *args)
                np.testing.assert_array_equal(values, before, err_msg=f"{module.__name__}: {name}")

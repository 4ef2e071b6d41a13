"""Tests of sitl.vehicle.sensors: noise statistics, rates, latency, reproducibility, angles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.vehicle.sensors import (
    GyroSensor,
    JointEncoders,
    PoseSensor,
    StateSensor,
    wrap_angle,
)

Q0 = np.array([0.3, -0.2, 0.7, 0.05, -0.04, 1.0, -1.2, 0.4])


def ramp_q(t: float) -> np.ndarray:
    """A truth that changes every step, so a delayed sample is recognisable."""
    return Q0 + t * np.array([1.0, -2.0, 0.5, 0.01, 0.02, 0.1, 0.3, -0.2])


def collect(sensor, truth, *, rate_hz: float, duration_s: float = 1.0) -> list:
    """Call ``sensor.sample`` every 1 ms over [0, duration_s); keep what it publishes."""
    out = []
    for k in range(round(duration_s * 1000)):
        t = k * 1e-3
        m = sensor.sample(t, truth(t))
        if m is not None:
            out.append(m)
    return out


# -- noise statistics -------------------------------------------------------------------
#
# With N samples the sample standard deviation has a relative standard error of
# 1 / sqrt(2 N) (0.5 % for N = 20000); the bounds are 4 % (8 standard errors), and the
# means must lie within 5 sigma / sqrt(N) of the truth.

N_STAT = 20_000


def _samples_at_rate(sensor, truth: np.ndarray, rate_hz: float) -> list:
    return [sensor.sample(k / rate_hz, truth) for k in range(N_STAT)]


def test_pose_noise_matches_configured_std() -> None:
    sensor = PoseSensor(
        np.random.default_rng(1), position_std_m=1e-3, attitude_std_rad=(2e-3, 3e-3, 5e-3)
    )
    ms = _samples_at_rate(sensor, Q0, 100.0)
    assert all(m is not None for m in ms)
    pos = np.array([m.position_m for m in ms]) - Q0[:3]
    att = wrap_angle(np.array([m.euler_rad for m in ms]) - Q0[3:6])
    expected = np.array([1e-3, 1e-3, 1e-3, 2e-3, 3e-3, 5e-3])
    err = np.hstack([pos, att])
    np.testing.assert_allclose(err.std(axis=0), expected, rtol=0.04)
    assert np.all(np.abs(err.mean(axis=0)) < 5 * expected / math.sqrt(N_STAT))
    # Channels are independent.
    corr = np.corrcoef(err.T)
    assert np.all(np.abs(corr - np.eye(6)) < 0.05)


def test_state_sensor_noise_per_row() -> None:
    std = np.array([1e-3, 2e-3, 3e-3, 1e-3, 1e-3, 2e-3, 4e-3, 5e-3])
    sensor = StateSensor(np.random.default_rng(2), q_std=std)
    ms = _samples_at_rate(sensor, Q0, 40.0)
    err = np.array([m.q for m in ms]) - Q0
    err[:, 3:6] = wrap_angle(err[:, 3:6])
    np.testing.assert_allclose(err.std(axis=0), std, rtol=0.04)


def test_gyro_noise_and_bias() -> None:
    bias = np.array([0.01, -0.02, 0.005])
    sensor = GyroSensor(np.random.default_rng(3), rate_std_rad_s=3e-3, bias_rad_s=bias)
    omega = np.array([0.1, 0.2, -0.3])
    ms = _samples_at_rate(sensor, omega, 250.0)
    err = np.array([m.omega_body_rad_s for m in ms]) - omega
    np.testing.assert_allclose(err.std(axis=0), 3e-3, rtol=0.04)
    assert np.all(np.abs(err.mean(axis=0) - bias) < 5 * 3e-3 / math.sqrt(N_STAT))


def test_zero_noise_is_exact() -> None:
    sensor = StateSensor(np.random.default_rng(4), q_std=0.0)
    m = sensor.sample(0.0, Q0)
    assert m is not None
    np.testing.assert_array_equal(m.q, Q0)


# -- rate -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("make", "truth", "rate_hz"),
    [
        (lambda rng: PoseSensor(rng), ramp_q, 100.0),
        (lambda rng: GyroSensor(rng), lambda t: np.zeros(3), 250.0),
        (lambda rng: JointEncoders(rng), lambda t: ramp_q(t)[6:], 100.0),
        (lambda rng: StateSensor(rng), ramp_q, 40.0),
        (lambda rng: StateSensor(rng, rate_hz=300.0), ramp_q, 300.0),  # not a divisor of 1 kHz
    ],
)
def test_samples_per_second(make, truth, rate_hz: float) -> None:
    ms = collect(make(np.random.default_rng(5)), truth, rate_hz=rate_hz)
    assert len(ms) == round(rate_hz)
    t = np.array([m.t_s for m in ms])
    # Each sample is published at the first step at or after its scheduled time.
    scheduled = np.arange(len(ms)) / rate_hz
    assert np.all(t >= scheduled - 1e-9)
    assert np.all(t < scheduled + 1e-3)


def test_coarse_steps_publish_at_most_one_sample_per_call() -> None:
    sensor = GyroSensor(np.random.default_rng(6), rate_hz=1000.0)
    published = [sensor.sample(k * 0.01, np.zeros(3)) for k in range(100)]
    assert all(m is not None for m in published)


def test_start_time_sets_the_phase() -> None:
    sensor = StateSensor(np.random.default_rng(7), rate_hz=100.0, start_s=0.004)
    ms = collect(sensor, ramp_q, rate_hz=100.0, duration_s=0.05)
    np.testing.assert_allclose([m.t_s for m in ms], [0.004, 0.014, 0.024, 0.034, 0.044])


# -- latency ----------------------------------------------------------------------------


@pytest.mark.parametrize("latency_s", [0.0, 0.02, 0.0255])
def test_measurement_is_the_truth_delayed(latency_s: float) -> None:
    sensor = StateSensor(np.random.default_rng(8), q_std=0.0, rate_hz=100.0, latency_s=latency_s)
    ms = collect(sensor, ramp_q, rate_hz=100.0)
    assert ms
    # Nothing is published before the buffer reaches back latency_s.
    assert ms[0].t_s >= latency_s - 1e-9
    for m in ms:
        # Zero-order hold: the latest 1 ms truth step at or before t - latency.
        stamp = math.floor((m.t_s - latency_s) * 1000 + 1e-6) / 1000
        assert m.stamp_s == pytest.approx(stamp, abs=1e-12)
        np.testing.assert_allclose(m.q, wrap_angle_rows(ramp_q(stamp)), atol=1e-12)
    assert len(ms) == 100 - math.ceil(latency_s * 100 - 1e-9)


def wrap_angle_rows(q: np.ndarray) -> np.ndarray:
    out = q.copy()
    out[3:6] = wrap_angle(out[3:6])
    return out


def test_pose_and_encoder_latency() -> None:
    pose = PoseSensor(
        np.random.default_rng(9), position_std_m=0.0, attitude_std_rad=0.0, latency_s=0.01
    )
    enc = JointEncoders(np.random.default_rng(9), ticks_per_rev=None, latency_s=0.03)
    for k in range(200):
        t = k * 1e-3
        mp = pose.sample(t, ramp_q(t))
        me = enc.sample(t, ramp_q(t)[6:])
        if mp is not None:
            np.testing.assert_allclose(mp.position_m, ramp_q(t - 0.01)[:3], atol=1e-12)
            np.testing.assert_allclose(mp.euler_rad, ramp_q(t - 0.01)[3:6], atol=1e-12)
        if me is not None:
            np.testing.assert_allclose(me.eta_rad, ramp_q(t - 0.03)[6:], atol=1e-12)


# -- reproducibility --------------------------------------------------------------------


def _run(seed: int) -> np.ndarray:
    sensor = PoseSensor(np.random.default_rng(seed), latency_s=0.01)
    return np.array(
        [np.hstack([m.position_m, m.euler_rad]) for m in collect(sensor, ramp_q, rate_hz=100)]
    )


def test_same_seed_same_measurements() -> None:
    a, b = _run(11), _run(11)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, _run(12))


def test_randomness_only_from_the_generator_passed_in() -> None:
    # Seeding the legacy global generator must not change anything.
    np.random.seed(0)  # noqa: NPY002
    a = _run(13)
    np.random.seed(1)  # noqa: NPY002
    b = _run(13)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(TypeError, match="Generator"):
        PoseSensor(None)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="Generator"):
        PoseSensor(np.random.RandomState(0))  # type: ignore[arg-type]


# -- angles, quantization ----------------------------------------------------------------


def test_yaw_noise_near_pi_wraps() -> None:
    sensor = PoseSensor(np.random.default_rng(14), position_std_m=0.0, attitude_std_rad=0.01)
    q = Q0.copy()
    q[5] = math.pi - 1e-3
    ms = _samples_at_rate(sensor, q, 100.0)[:2000]
    psi = np.array([m.euler_rad[2] for m in ms])
    assert np.all((psi >= -math.pi) & (psi < math.pi))
    assert np.any(psi < 0.0) and np.any(psi > 0.0)  # both sides of the cut
    err = wrap_angle(psi - q[5])
    assert np.std(err) == pytest.approx(0.01, rel=0.1)


def test_wrap_angle() -> None:
    a = np.array([0.0, math.pi, -math.pi, 3 * math.pi / 2, -7.0, 1e-3])
    w = wrap_angle(a)
    assert np.all((w >= -math.pi) & (w < math.pi))
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)


def test_encoder_quantization() -> None:
    enc = JointEncoders(np.random.default_rng(15), ticks_per_rev=4096)
    res = 2 * math.pi / 4096
    assert enc.resolution_rad == pytest.approx(res)
    for k in range(50):
        eta = np.array([-1.2 + 0.0123 * k, 0.4 - 0.0071 * k])
        m = enc.sample(k / 100.0, eta)
        assert m is not None
        ticks = m.eta_rad / res
        np.testing.assert_allclose(ticks, np.round(ticks), atol=1e-9)
        assert np.all(np.abs(m.eta_rad - eta) <= res / 2 + 1e-12)


# -- interface ---------------------------------------------------------------------------


def test_measurements_are_read_only() -> None:
    m = StateSensor(np.random.default_rng(16)).sample(0.0, Q0)
    assert m is not None
    with pytest.raises(ValueError, match="read-only"):
        m.q[0] = 0.0
    with pytest.raises(AttributeError):
        m.t_s = 1.0  # type: ignore[misc]


def test_time_must_not_go_backwards() -> None:
    sensor = GyroSensor(np.random.default_rng(17))
    sensor.sample(1.0, np.zeros(3))
    with pytest.raises(ValueError, match="backwards"):
        sensor.sample(0.5, np.zeros(3))


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda rng: PoseSensor(rng, position_std_m=-1.0), "position_std_m"),
        (lambda rng: PoseSensor(rng, attitude_std_rad=(1.0, 2.0)), "attitude_std_rad"),
        (lambda rng: GyroSensor(rng, rate_hz=0.0), "rate_hz"),
        (lambda rng: GyroSensor(rng, bias_rad_s=(0.0, 0.0)), "bias_rad_s"),
        (lambda rng: StateSensor(rng, latency_s=-0.01), "latency_s"),
        (lambda rng: JointEncoders(rng, ticks_per_rev=0), "ticks_per_rev"),
    ],
)
def test_bad_parameters_are_rejected(make, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make(np.random.default_rng(18))


def test_truth_shape_is_checked() -> None:
    with pytest.raises(ValueError, match="shape"):
        StateSensor(np.random.default_rng(19)).sample(0.0, np.zeros(6))
    with pytest.raises(ValueError, match="shape"):
        PoseSensor(np.random.default_rng(19)).sample(0.0, np.zeros(6))

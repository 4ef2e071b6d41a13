"""Structural properties of companion.model that any correct derivation must have."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from companion.model import ManipulatorModel, _mcg
from sitl.scenario import load_scenario

ROOT = Path(__file__).parent.parent
CONFIGS = ROOT / "configs"


@pytest.fixture(params=["paper_sim.toml", "experiment_arm.toml"])
def setup(request):
    cfg = load_scenario(CONFIGS / request.param)
    return cfg, ManipulatorModel.from_config(cfg)


def states(seed: int, n: int = 50):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        q = np.concatenate(
            [rng.uniform(-3, 3, 3), rng.uniform(-1.2, 1.2, 2), rng.uniform(-3, 3, 3)]
        )
        yield q, rng.normal(0.0, 1.0, 8)


def test_mass_matrix_symmetric_positive_definite(setup) -> None:
    cfg, model = setup
    for q, _ in states(1):
        m = model.mass_matrix(q, cfg.true_theta.as_tuple())
        np.testing.assert_allclose(m, m.T, atol=1e-14)
        assert np.linalg.eigvalsh(m).min() > 0.0


def test_mdot_minus_2c_is_skew_symmetric(setup) -> None:
    """M_dot by central differences along q_dot (error O(h^2) ~ 1e-10)."""
    cfg, model = setup
    theta = cfg.true_theta.as_tuple()
    h = 1e-5
    for q, q_dot in states(2):
        m_dot = (
            model.mass_matrix(q + h * q_dot, theta) - model.mass_matrix(q - h * q_dot, theta)
        ) / (2 * h)
        n = m_dot - 2.0 * model.coriolis_matrix(q, q_dot, theta)
        np.testing.assert_allclose(n + n.T, 0.0, atol=1e-8)


def test_exactly_linear_in_theta(setup) -> None:
    _, model = setup
    rng = np.random.default_rng(3)
    for q, q_dot in states(3, 10):
        terms = model.terms(q, q_dot)
        qr_dot, qr_ddot = rng.normal(size=8), rng.normal(size=8)
        a, b = np.array([0.3, 0.02, 0.004]), np.array([0.7, 0.1, 0.02])
        for matrix in (terms.mass_matrix, terms.coriolis_matrix, terms.gravity):
            # affine in theta: f(a + b) - f(a) - f(b) + f(0) == 0
            np.testing.assert_allclose(
                matrix(a + b) - matrix(a) - matrix(b) + matrix(np.zeros(3)), 0.0, atol=1e-12
            )
        y = terms.regressor(qr_dot, qr_ddot)
        xi = np.array([*b, 1.0])
        expected = (
            terms.mass_matrix(b) @ qr_ddot + terms.coriolis_matrix(b) @ qr_dot + terms.gravity(b)
        )
        np.testing.assert_allclose(y @ xi, expected, atol=1e-12)
        np.testing.assert_array_equal(terms.G[2], 0.0)  # m4 does not enter the gravity


def test_total_weight_and_translational_mass(setup) -> None:
    cfg, model = setup
    rng = np.random.default_rng(4)
    g = cfg.environment.gravity_m_s2
    known = cfg.vehicle.mass_kg + cfg.arm.link1.mass_kg
    for q, _ in states(4, 20):
        theta = (rng.uniform(0.05, 2.0), rng.uniform(0, 0.1), rng.uniform(0.01, 0.1))
        total = known + theta[0]
        np.testing.assert_allclose(model.gravity(q, theta)[2], total * g, rtol=1e-13)
        np.testing.assert_allclose(model.gravity(q, theta)[0:2], 0.0, atol=1e-13)
        np.testing.assert_allclose(
            model.mass_matrix(q, theta)[0:3, 0:3], total * np.eye(3), atol=1e-13
        )


def rk4_unforced(model, theta, q, q_dot, dt, steps):
    def accel(q, q_dot):
        terms = model.terms(q, q_dot)
        rhs = -terms.coriolis_matrix(theta) @ q_dot - terms.gravity(theta)
        return np.linalg.solve(terms.mass_matrix(theta), rhs)

    x = np.concatenate([q, q_dot])

    def f(x):
        return np.concatenate([x[8:], accel(x[:8], x[8:])])

    for _ in range(steps):
        k1 = f(x)
        k2 = f(x + 0.5 * dt * k1)
        k3 = f(x + 0.5 * dt * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x[:8], x[8:]


def energy(model, theta, q, q_dot):
    return model.kinetic_energy(q, q_dot, theta) + model.potential_energy(q, theta)


def test_unforced_motion_conserves_energy(setup) -> None:
    """Classic RK4, dt = 1 ms, 2 s of free flight in gravity with a tumbling arm.

    Measured drift: 4.7e-11 J (paper_sim) and 8.9e-12 J (experiment_arm) while about
    290 J and 240 J move from potential to kinetic energy; asserted below 1e-7 J.
    """
    cfg, model = setup
    theta = cfg.true_theta.as_tuple()
    q0 = np.array([0.0, 0.0, 1.0, 0.2, -0.1, 0.3, -1.0, 0.5])
    q_dot0 = np.array([0.3, -0.2, 0.5, 1.0, -0.8, 0.6, 2.0, -3.0])
    e0 = energy(model, theta, q0, q_dot0)
    q, q_dot = rk4_unforced(model, theta, q0, q_dot0, 1e-3, 2000)
    assert q[2] < q0[2] - 10.0  # it did fall: the energy really moved between terms
    assert abs(energy(model, theta, q, q_dot) - e0) < 1e-7


def test_potential_energy_gradient_is_gravity(setup) -> None:
    cfg, model = setup
    theta = cfg.true_theta.as_tuple()
    h = 1e-6
    for q, _ in states(5, 10):
        grad = [
            (model.potential_energy(q + h * e, theta) - model.potential_energy(q - h * e, theta))
            / (2 * h)
            for e in np.eye(8)
        ]
        np.testing.assert_allclose(grad, model.gravity(q, theta), atol=1e-7)


def test_one_call_evaluate_equals_the_pieces(setup) -> None:
    """ManipulatorModel.evaluate (one C call) gives what terms, evaluate and regressor give."""
    cfg, model = setup
    theta = cfg.true_theta.as_tuple()
    rng = np.random.default_rng(4)
    for q, q_dot in states(5):
        qr_dot, qr_ddot = rng.normal(size=8), rng.normal(size=8)
        terms = model.terms(q, q_dot)
        expected = (*terms.evaluate(theta), terms.regressor(qr_dot, qr_ddot))
        for got, want in zip(
            model.evaluate(q, q_dot, theta, qr_dot, qr_ddot), expected, strict=True
        ):
            np.testing.assert_array_equal(got, want)


def test_rejects_wrong_shapes(setup) -> None:
    _, model = setup
    with pytest.raises(ValueError, match=r"q must have shape \(8,\)"):
        model.terms(np.zeros(7), np.zeros(8))
    with pytest.raises(ValueError, match="q_dot"):
        model.terms(np.zeros(8), np.zeros((8, 1)))


def test_one_call_evaluate_converts_what_the_extension_cannot_read(setup) -> None:
    """GIVEN lists, integers, a tuple theta and strided views WHEN evaluate THEN the same
    M, C, G, Y as from float64 arrays; a wrong shape is refused with the argument's name."""
    cfg, model = setup
    theta = np.array(cfg.true_theta.as_tuple())
    q = np.array([0.0, 1.0, 2.0, 0.0, -1.0, 1.0, -1.0, 1.0])  # integers, for astype(int)
    wide = np.zeros((8, 2))
    wide[:, 0] = q
    expected = model.evaluate(q, q, theta, q, q)
    for args in (
        (q.tolist(), q.astype(int), tuple(theta), wide[:, 0], q.astype(">f8")),
        (wide[:, 0], wide[:, 0], theta.tolist(), q.tolist(), q),
    ):
        for got, want in zip(model.evaluate(*args), expected, strict=True):
            np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match=r"qr_dot must have shape \(8,\)"):
        model.evaluate(q, q, theta, q.reshape(2, 4), q)
    with pytest.raises(ValueError, match=r"theta must have shape \(3,\)"):
        model.evaluate(q, q, theta[:2], q, q)


def test_the_extension_refuses_what_is_not_native_float64(setup) -> None:
    """GIVEN the generated extension WHEN an argument is integers, big-endian, two-
    dimensional where a vector is asked, bytes, too short, or not a buffer THEN ValueError
    or TypeError and ``out`` unwritten."""
    _, model = setup
    q = np.linspace(-1.0, 1.0, 8)
    for bad in (q.astype(np.int64), q.astype(">f8"), q.reshape(2, 4), q.tobytes(), q[:7], "q"):
        out = np.full(4 * 136, 7.0)
        with pytest.raises((ValueError, TypeError)):
            _mcg.mcg(bad, q, model._p, out)
        assert (out == 7.0).all()
    with pytest.raises(TypeError, match="takes 4 arguments"):
        _mcg.mcg(q, q, model._p)
    readonly = np.full(4 * 136, 7.0)
    readonly.flags.writeable = False
    with pytest.raises((ValueError, BufferError)):
        _mcg.mcg(q, q, model._p, readonly)


def test_generated_code_is_up_to_date() -> None:
    """The committed C file is exactly what the sympy derivation produces (about 40 s)."""
    pytest.importorskip("sympy")
    result = subprocess.run(
        [sys.executable, "-m", "companion.model.derive", "--check"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr

"""Dynamics of the hexacopter + 2-DOF arm, linear in the link-2 parameters (paper section II).

``M(q) q_ddot + C(q, q_dot) q_dot + G(q) = tau`` (eq. mcg_model) with
q = [x, y, z, phi, theta, psi, eta1, eta2] (ENU world, FLU body, R = Rz Ry Rx; DESIGN.md
section 2) and tau conjugate to q (world force, Euler-angle generalized torques, joint
torques). With xi = [m2, m3, m4, 1] (eq. reg):

    M = M1 + m2 M2 + m3 M3 + m4 M4,   C = C1 + m2 C2 + m3 C3 + m4 C4,   G = G1 + m2 G2 + m3 G3

(eq. mcg_param). C is built from the Christoffel symbols of the first kind, so M_dot - 2C is
skew-symmetric. The expressions come from :mod:`companion.model.derive` (sympy) and are
evaluated by the generated C extension ``_mcg``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.config import CompanionConfig, load_config
from companion.coordinates import N_Q
from companion.model import _mcg
from companion.model.layout import N_XI, PARAM_NAMES, ROW

__all__ = ["ManipulatorModel", "ModelParameters", "ModelTerms"]

FloatArray = NDArray[np.float64]
_ALL_ROWS = 2 * N_Q + 1 + N_XI
"""``_mcg.all``'s output as rows of N_Q values: M (N_Q rows), C (N_Q rows), G, Y^T (N_XI
rows)."""


@dataclass(frozen=True)
class ModelParameters:
    """The known physical parameters of the model (SI units).

    Link 1 is described by its mass, first and second moment about joint 1 (DESIGN.md
    section 3); ``armature_kg_m2`` is the reflected servo-rotor inertia on each joint.
    """

    vehicle_mass_kg: float
    vehicle_inertia_kg_m2: tuple[float, float, float]
    """Principal moments (Ixx, Iyy, Izz) about the vehicle CoM, FLU axes."""
    link1_mass_kg: float
    link1_first_moment_kg_m: float
    link1_second_moment_kg_m2: float
    link1_length_m: float
    armature_kg_m2: tuple[float, float]
    mount_point_m: tuple[float, float, float]
    """Joint 1 position r_a in the body frame (FLU, from the vehicle CoM)."""
    gravity_m_s2: float

    @classmethod
    def from_config(cls, config: CompanionConfig) -> ModelParameters:
        """Known parameters of a validated configuration (link 2 stays unknown)."""
        scenario = config
        link1 = scenario.arm.link1
        return cls(
            vehicle_mass_kg=scenario.vehicle.mass_kg,
            vehicle_inertia_kg_m2=_vec3(scenario.vehicle.inertia_kg_m2),
            link1_mass_kg=link1.mass_kg,
            link1_first_moment_kg_m=link1.first_moment_kg_m,
            link1_second_moment_kg_m2=link1.second_moment_kg_m2,
            link1_length_m=link1.length_m,
            armature_kg_m2=(link1.armature_kg_m2, scenario.arm.link2.armature_kg_m2),
            mount_point_m=_vec3(scenario.arm.mount_point_m),
            gravity_m_s2=scenario.environment.gravity_m_s2,
        )

    def vector(self) -> FloatArray:
        """The parameters in the order of ``derive.PARAM_NAMES``."""
        values = {
            "mb": self.vehicle_mass_kg,
            "ixx": self.vehicle_inertia_kg_m2[0],
            "iyy": self.vehicle_inertia_kg_m2[1],
            "izz": self.vehicle_inertia_kg_m2[2],
            "m1": self.link1_mass_kg,
            "s1": self.link1_first_moment_kg_m,
            "j1": self.link1_second_moment_kg_m2,
            "a1": self.armature_kg_m2[0],
            "a2": self.armature_kg_m2[1],
            "l1": self.link1_length_m,
            "rax": self.mount_point_m[0],
            "ray": self.mount_point_m[1],
            "raz": self.mount_point_m[2],
            "g": self.gravity_m_s2,
        }
        return np.array([values[name] for name in PARAM_NAMES], dtype=np.float64)


@dataclass(frozen=True)
class ModelTerms:
    """M, C, G pieces at one state, as coefficients of xi = [m2, m3, m4, 1].

    ``pieces`` has shape (4, 136) in the layout of :mod:`companion.model.layout`; piece
    k = 0, 1, 2 belongs to m2, m3, m4 (M2, M3, M4, the unknown parts), k = 3 to the known
    part (M1). ``M``, ``C`` (4, 8, 8) and ``G`` (4, 8) are views on it; ``G[2]`` is zero.
    """

    pieces: FloatArray

    @property
    def M(self) -> FloatArray:
        return self.pieces.reshape(N_XI, N_Q, ROW)[:, :, :N_Q]

    @property
    def C(self) -> FloatArray:
        return self.pieces.reshape(N_XI, N_Q, ROW)[:, :, N_Q : 2 * N_Q]

    @property
    def G(self) -> FloatArray:
        return self.pieces.reshape(N_XI, N_Q, ROW)[:, :, 2 * N_Q]

    def evaluate(self, theta: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(M, C, G) for theta = (m2, m3, m4), shapes (8, 8), (8, 8), (8,)."""
        m2, m3, m4 = np.asarray(theta, dtype=np.float64).tolist()
        out = np.empty(N_Q * ROW)
        _mcg.combine(self.pieces, np.array((m2, m3, m4, 1.0)), out)
        rows = out.reshape(N_Q, ROW)
        return rows[:, :N_Q], rows[:, N_Q : 2 * N_Q], rows[:, 2 * N_Q]

    def mass_matrix(self, theta: ArrayLike) -> FloatArray:
        """M(q) for theta = (m2, m3, m4), shape (8, 8)."""
        return self.evaluate(theta)[0]

    def coriolis_matrix(self, theta: ArrayLike) -> FloatArray:
        """C(q, q_dot) for theta, shape (8, 8)."""
        return self.evaluate(theta)[1]

    def gravity(self, theta: ArrayLike) -> FloatArray:
        """G(q) for theta, shape (8,)."""
        return self.evaluate(theta)[2]

    def regressor(self, qr_dot: ArrayLike, qr_ddot: ArrayLike) -> FloatArray:
        """Y with Y xi = M qr_ddot + C qr_dot + G (paper eq. reg), shape (8, 4).

        Columns multiply [m2, m3, m4, 1]; with qr = q this is also the estimator's
        M_i q_ddot + C_i q_dot + G_i (eqs. estimator, update).
        """
        out = np.empty((N_XI, N_Q))
        _mcg.regress(self.pieces, _vector(qr_dot, "qr_dot"), _vector(qr_ddot, "qr_ddot"), out)
        return out.T


class ManipulatorModel:
    """M, C, G and the regressor of the aerial manipulator, for any theta = (m2, m3, m4).

    Pure: no I/O, no clock; safe to share between threads (each call allocates its output).

    Examples
    --------
    >>> model = ManipulatorModel.from_file("configs/paper_sim.toml")
    >>> terms = model.terms(q, q_dot)
    >>> M = terms.mass_matrix((0.5, 0.08, 0.0128))
    >>> Y = terms.regressor(qr_dot, qr_ddot)        # (8, 4), Y @ [m2, m3, m4, 1]
    """

    def __init__(self, params: ModelParameters) -> None:
        self.params = params
        self._p = params.vector()

    @classmethod
    def from_config(cls, config: CompanionConfig) -> ManipulatorModel:
        """Model of a validated configuration's vehicle and arm."""
        return cls(ModelParameters.from_config(config))

    @classmethod
    def from_file(cls, path: str | Path) -> ManipulatorModel:
        """Load and validate a configuration TOML file (raises ``ConfigError``) and build
        the model."""
        return cls.from_config(load_config(path))

    def terms(self, q: ArrayLike, q_dot: ArrayLike) -> ModelTerms:
        """All pieces of M(q), C(q, q_dot), G(q) at one state.

        Parameters
        ----------
        q : array_like, shape (8,)
            [x, y, z (m, ENU), phi, theta, psi (rad, ZYX), eta1, eta2 (rad)].
        q_dot : array_like, shape (8,)
            Time derivative of q (m/s, rad/s).
        """
        out = np.empty((N_XI, N_Q * ROW))
        _mcg.mcg(_vector(q, "q"), _vector(q_dot, "q_dot"), self._p, out)
        return ModelTerms(out)

    def evaluate(
        self,
        q: ArrayLike,
        q_dot: ArrayLike,
        theta: ArrayLike,
        qr_dot: ArrayLike,
        qr_ddot: ArrayLike,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """M(q), C(q, q_dot), G(q) for theta = (m2, m3, m4) and the regressor
        Y(q, q_dot, qr_dot, qr_ddot) (paper eq. reg), shapes (8, 8), (8, 8), (8,), (8, 4),
        in one call of the generated C: ``terms(q, q_dot).evaluate(theta)`` and
        ``.regressor(qr_dot, qr_ddot)`` without the pieces in between."""
        out = np.empty((_ALL_ROWS, N_Q))
        try:
            _mcg.all(q, q_dot, self._p, theta, qr_dot, qr_ddot, out)  # type: ignore[arg-type]
        except (BufferError, TypeError, ValueError):
            # Not native float64 vectors of the right size (the extension refuses them before
            # it writes anything): converted, and refused with the argument's name if wrong.
            _mcg.all(
                _vector(q, "q"),
                _vector(q_dot, "q_dot"),
                self._p,
                _vector(theta, "theta", 3),
                _vector(qr_dot, "qr_dot"),
                _vector(qr_ddot, "qr_ddot"),
                out,
            )
        return out[:N_Q], out[N_Q : 2 * N_Q], out[2 * N_Q], out[2 * N_Q + 1 :].T

    def mass_matrix(self, q: ArrayLike, theta: ArrayLike) -> FloatArray:
        """M(q) for theta = (m2, m3, m4), shape (8, 8)."""
        return self.terms(q, np.zeros(N_Q)).mass_matrix(theta)

    def coriolis_matrix(self, q: ArrayLike, q_dot: ArrayLike, theta: ArrayLike) -> FloatArray:
        """C(q, q_dot) for theta, shape (8, 8)."""
        return self.terms(q, q_dot).coriolis_matrix(theta)

    def gravity(self, q: ArrayLike, theta: ArrayLike) -> FloatArray:
        """G(q) = dV/dq for theta, shape (8,) (G[2] is the total weight, z up)."""
        return self.terms(q, np.zeros(N_Q)).gravity(theta)

    def regressor(
        self, q: ArrayLike, q_dot: ArrayLike, qr_dot: ArrayLike, qr_ddot: ArrayLike
    ) -> FloatArray:
        """Y(q, q_dot, qr_dot, qr_ddot), shape (8, 4), with Y [m2, m3, m4, 1]^T
        = M qr_ddot + C qr_dot + G (paper eq. reg, Slotine-Li reference velocity)."""
        return self.terms(q, q_dot).regressor(qr_dot, qr_ddot)

    def potential_energy(self, q: ArrayLike, theta: ArrayLike) -> float:
        """Gravitational potential energy V(q) [J], zero at z = 0 of the world frame."""
        out = np.empty(N_XI)
        _mcg.potential(_vector(q, "q"), self._p, out)
        return float(np.dot(theta, out[:3]) + out[3])

    def kinetic_energy(self, q: ArrayLike, q_dot: ArrayLike, theta: ArrayLike) -> float:
        """Kinetic energy 1/2 q_dot^T M(q) q_dot [J]."""
        v = _vector(q_dot, "q_dot")
        return 0.5 * float(v @ self.mass_matrix(q, theta) @ v)


def _vec3(values: Sequence[float]) -> tuple[float, float, float]:
    """A validated 3-vector of the configuration as a 3-tuple."""
    x, y, z = values
    return (x, y, z)


def _vector(values: ArrayLike, name: str, size: int = N_Q) -> FloatArray:
    """``values`` as ``size`` C-contiguous float64 values; ValueError for another shape."""
    arr = np.ascontiguousarray(values, dtype=np.float64)
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got {arr.shape}")
    return arr

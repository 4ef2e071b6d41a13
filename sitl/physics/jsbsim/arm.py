"""The 2-DOF arm outside JSBSim: joint dynamics on a moving base, and its coupling moment.

Written from first principles, independent of :mod:`companion.model` and of the Pinocchio
plant (DESIGN.md section 6). Geometry (DESIGN.md section 3): joint 1 at body point r_a,
both axes along body -y (FLU), link directions u1 = (cos eta1, 0, sin eta1) and
u2 = (cos(eta1 + eta2), 0, sin(eta1 + eta2)).

Point masses. A link is a mass m on its axis with its CoM at distance c from its joint and
inertia I about the CoM across the axis (zero along it). Two masses m/2 on the axis at
c +- sqrt(I / m) have the same mass, CoM and inertia tensor, hence exactly the same
rigid-body dynamics; link 2 with a grasped payload is first combined into one such body
(parallel-axis theorem). So the arm is four point masses s_k(eta) in body axes, and JSBSim
carries them as ``inertia/pointmass-*`` (its mass, CG and inertia are then those of the
whole vehicle frozen in the current arm pose).

Joint equations (d'Alembert, for the moving base). Let b = R^T (a_G - g) be the
non-gravitational external force on the whole vehicle per unit mass (body axes; a_G the
CoM acceleration, which no internal motion changes), c the CoM from O, rho_k = s_k - c,
omega and omega_dot the body rate and its derivative. Point k accelerates at
R (b + omega_dot x rho + omega x (omega x rho) + 2 omega x rho_dot + rho_ddot) relative to
free fall, with s_ddot = J_k eta_ddot + s_ddot0 (J_k = ds_k / deta) and
c_ddot = J_G eta_ddot + c_ddot0 (J_G = sum_k m_k J_k / M). Projecting on the joint
directions, with the eta_ddot terms of c_ddot moved to the left:

    (A - M J_G^T J_G) eta_ddot = tau - sum_k m_k J_k^T (b + omega_dot x rho_k
        + omega x (omega x rho_k) + 2 omega x rho_dot_k + s_ddot0_k - c_ddot0),
    A = sum_k m_k J_k^T J_k + diag(armature).

The translational coupling is thus solved exactly; only omega_dot comes from the previous
step (see below). These are the joint rows of the paper's M(q) q_ddot + C q_dot + G = tau
(eq. mcg_model) with the base motion given. The servo armature acts on the joint rows
only, as in the Pinocchio plant.

Coupling moment. JSBSim integrates the vehicle as a rigid body frozen in the current arm
pose: its state is the location and velocity of the CG (of vehicle + arm) and the body
rate, with M dv/dt = F + M g and J omega_dot + omega x J omega = M_c. When the arm moves,
JSBSim keeps the CG where it is (no external force moves a CoM; JSBSim's GitHub
issues/230) and the structure around it moves instead. So the translational equation is
already exact; the rotational one misses the terms of the moving mass distribution, which
the plant adds as an external moment about the CG (body axes):

    M_corr = -(J_dot omega + sum_k m_k rho_k x s_ddot_k + omega x sum_k m_k rho_k x s_dot_k),

with rho_k = s_k - c and c the CG from O (the vehicle body counts as a mass at O, with
s_dot = 0, in J_dot). It depends on eta_ddot, which depends on omega_dot: the plant closes
this loop with the omega_dot that JSBSim integrates over the step, computed by JSBSim with
the moment of the previous step (one-step lag). The lagged loop contracts by the spectral radius of
A_G^-1 C^T J_G^-1 C (A_G = A - M J_G^T J_G, C = sum_k m_k rho_k x J_k, J_G the frozen
inertia about the CoM), which is below 1 whenever the full mass matrix is positive definite
(Schur complement); :meth:`ArmDynamics.coupling_ratio` computes it.

Integration: semi-implicit Euler at the plant rate, like the Pinocchio plant's default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.config import Theta
from sitl.scenario import Scenario

__all__ = ["ArmDynamics", "LinkBody"]

Vec3 = tuple[float, float, float]
_PointKinematics = tuple[float, Vec3, Vec3, Vec3, Vec3, Vec3]
"""(m, s, s_dot, s_ddot0, J column 1, J column 2) of one point mass (see _kinematics)."""


@dataclass(frozen=True)
class LinkBody:
    """A rigid body on a link axis: mass [kg], CoM distance from its joint [m], inertia about
    the CoM across the axis [kg m^2]."""

    mass_kg: float
    com_m: float
    inertia_kg_m2: float

    def __add__(self, other: LinkBody) -> LinkBody:
        """The two bodies rigidly together (parallel-axis theorem)."""
        m = self.mass_kg + other.mass_kg
        c = (self.mass_kg * self.com_m + other.mass_kg * other.com_m) / m
        i = (
            self.inertia_kg_m2
            + other.inertia_kg_m2
            + self.mass_kg * (self.com_m - c) ** 2
            + other.mass_kg * (other.com_m - c) ** 2
        )
        return LinkBody(m, c, i)

    @property
    def theta(self) -> Theta:
        """(m2, m3, m4) of this body about its joint: mass, first and second moment."""
        m, c = self.mass_kg, self.com_m
        return Theta(m2_kg=m, m3_kg_m=m * c, m4_kg_m2=self.inertia_kg_m2 + m * c * c)

    def point_masses(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """Two (mass [kg], distance along the axis [m]) with this body's dynamics."""
        half = 0.5 * self.mass_kg
        d = math.sqrt(self.inertia_kg_m2 / self.mass_kg) if self.mass_kg > 0.0 else 0.0
        return ((half, self.com_m - d), (half, self.com_m + d))


class ArmDynamics:
    """Joint state, joint accelerations on a moving base, and the coupling moment.

    Parameters
    ----------
    scenario : Scenario
        Validated scenario (vehicle mass, arm, payload).
    dt_s : float
        Integration step [s].
    """

    def __init__(self, scenario: Scenario, dt_s: float) -> None:
        arm = scenario.arm
        self.dt_s = float(dt_s)
        self.mount_m: Vec3 = tuple(float(c) for c in arm.mount_point_m)  # type: ignore[assignment]
        self.l1_m = float(arm.link1.length_m)
        self.armature = (float(arm.link1.armature_kg_m2), float(arm.link2.armature_kg_m2))
        self.base_mass_kg = float(scenario.vehicle.mass_kg)
        self.base_inertia = tuple(float(i) for i in scenario.vehicle.inertia_kg_m2)
        self.link1 = LinkBody(arm.link1.mass_kg, arm.link1.com_m, arm.link1.inertia_about_com_kg_m2)
        self.link2_empty = LinkBody(
            arm.link2.mass_kg, arm.link2.com_m, arm.link2.inertia_about_com_kg_m2
        )
        load = scenario.payload
        self.payload = LinkBody(load.mass_kg, load.position_m, load.inertia_about_com_kg_m2)
        self.eta = [0.0, 0.0]
        self.eta_dot = [0.0, 0.0]
        self.eta_ddot = [0.0, 0.0]
        self.payload_attached = False
        self._kin_key: tuple | None = None
        self._kin: list[_PointKinematics] = []
        self._set_masses()

    # ------------------------------------------------------------------ bodies

    @property
    def link2(self) -> LinkBody:
        """Link 2 as it is now (with the payload if attached)."""
        return self.link2_empty + self.payload if self.payload_attached else self.link2_empty

    @property
    def total_mass_kg(self) -> float:
        """Vehicle + arm (+ payload) [kg]."""
        return self.base_mass_kg + self.link1.mass_kg + self.link2.mass_kg

    def set_payload(self, attached: bool) -> None:
        """Grasp or release: link 2's body changes; the joint momentum A eta_dot is kept."""
        before = self._joint_inertia()
        self.payload_attached = attached
        self._set_masses()
        after = self._joint_inertia()
        self.eta_dot = np.linalg.solve(after, before @ self.eta_dot).tolist()

    def _set_masses(self) -> None:
        # (mass, distance along its link, link index 1 or 2)
        self._masses = [(m, a, 1) for m, a in self.link1.point_masses()] + [
            (m, a, 2) for m, a in self.link2.point_masses()
        ]

    # -------------------------------------------------------------- kinematics

    def _kinematics(self) -> list[_PointKinematics]:
        """Per point mass: (m, s, s_dot, s_ddot0, J column 1, J column 2), body FLU.

        Cached for the current (eta, eta_dot, masses): the plant asks several times a step.
        """
        e1, e2 = self.eta
        d1, d2 = self.eta_dot
        key = (e1, e2, d1, d2, self._masses)
        if key == self._kin_key:
            return self._kin
        c1, s1 = math.cos(e1), math.sin(e1)
        c2, s2 = math.cos(e1 + e2), math.sin(e1 + e2)
        p2 = d1 + d2
        rx, ry, rz = self.mount_m
        l1 = self.l1_m
        out: list[_PointKinematics] = []
        for m, a, link in self._masses:
            if link == 1:
                s = (rx + a * c1, ry, rz + a * s1)
                sd = (-a * s1 * d1, 0.0, a * c1 * d1)
                s0 = (-a * c1 * d1 * d1, 0.0, -a * s1 * d1 * d1)
                j1 = (-a * s1, 0.0, a * c1)
                j2 = (0.0, 0.0, 0.0)
            else:
                s = (rx + l1 * c1 + a * c2, ry, rz + l1 * s1 + a * s2)
                sd = (-l1 * s1 * d1 - a * s2 * p2, 0.0, l1 * c1 * d1 + a * c2 * p2)
                s0 = (
                    -l1 * c1 * d1 * d1 - a * c2 * p2 * p2,
                    0.0,
                    -l1 * s1 * d1 * d1 - a * s2 * p2 * p2,
                )
                j2 = (-a * s2, 0.0, a * c2)
                j1 = (-l1 * s1 + j2[0], 0.0, l1 * c1 + j2[2])
            out.append((m, s, sd, s0, j1, j2))
        self._kin_key, self._kin = key, out
        self._com = _centre(self.base_mass_kg, out)
        total = self.base_mass_kg + sum(k[0] for k in out)
        # c_ddot0 and the columns of J_G = sum m J / M
        masses = [k[0] for k in out]
        self._com_terms = tuple(
            [sum(m * v[i] for m, v in zip(masses, column, strict=True)) / total for i in range(3)]
            for column in ([k[3] for k in out], [k[4] for k in out], [k[5] for k in out])
        )
        self._total = total
        return out

    def point_masses(self) -> list[tuple[float, Vec3]]:
        """(mass [kg], position from O in body FLU [m]) of the four point masses now."""
        return [(k[0], k[1]) for k in self._kinematics()]

    def _joint_inertia(self) -> np.ndarray:
        a11 = a12 = a22 = 0.0
        for m, _, _, _, j1, j2 in self._kinematics():
            a11 += m * (j1[0] ** 2 + j1[2] ** 2)
            a12 += m * (j1[0] * j2[0] + j1[2] * j2[2])
            a22 += m * (j2[0] ** 2 + j2[2] ** 2)
        return np.array([[a11 + self.armature[0], a12], [a12, a22 + self.armature[1]]])

    # ---------------------------------------------------------------- dynamics

    def step(
        self,
        joint_torques_n_m: tuple[float, float],
        specific_force_body: Vec3,
        omega: Vec3,
        omega_dot: Vec3,
    ) -> Vec3:
        """Joint accelerations at the current state, the coupling moment, then one step.

        Parameters
        ----------
        joint_torques_n_m : tuple of 2 float
            Servo torques [N m] (conjugate to eta).
        specific_force_body : tuple of 3 float
            b = R^T (a_G - g): external non-gravitational force on the whole vehicle per
            unit mass, body FLU [m/s^2].
        omega, omega_dot : tuple of 3 float
            Body rate [rad/s] and its derivative [rad/s^2], body FLU.

        Returns M_corr [N m] (body FLU, about the CoM) for the current state (before the
        step), with eta_ddot stored in :attr:`eta_ddot`; then advances (eta, eta_dot) by
        semi-implicit Euler.
        """
        kin = self._kinematics()
        total = self._total
        c, cd = self._com
        cdd0, jg1, jg2 = self._com_terms
        a11 = a12 = a22 = 0.0
        r1, r2 = joint_torques_n_m
        wx, wy, wz = omega
        ax, ay, az = omega_dot
        wsq = wx * wx + wy * wy + wz * wz
        for m, s, sd, s0, j1, j2 in kin:
            a11 += m * (j1[0] ** 2 + j1[2] ** 2)
            a12 += m * (j1[0] * j2[0] + j1[2] * j2[2])
            a22 += m * (j2[0] ** 2 + j2[2] ** 2)
            r0, r1_, r2_ = s[0] - c[0], s[1] - c[1], s[2] - c[2]
            v0, v1, v2 = sd[0] - cd[0], sd[1] - cd[1], sd[2] - cd[2]
            # f = b + omega_dot x rho + omega x (omega x rho) + 2 omega x rho_dot + s0 - c0
            w0 = wx * r0 + wy * r1_ + wz * r2_  # omega . rho
            f = [
                specific_force_body[0]
                + (ay * r2_ - az * r1_)
                + (wx * w0 - wsq * r0)
                + 2.0 * (wy * v2 - wz * v1)
                + s0[0]
                - cdd0[0],
                specific_force_body[1]
                + (az * r0 - ax * r2_)
                + (wy * w0 - wsq * r1_)
                + 2.0 * (wz * v0 - wx * v2)
                + s0[1]
                - cdd0[1],
                specific_force_body[2]
                + (ax * r1_ - ay * r0)
                + (wz * w0 - wsq * r2_)
                + 2.0 * (wx * v1 - wy * v0)
                + s0[2]
                - cdd0[2],
            ]
            r1 -= m * (j1[0] * f[0] + j1[1] * f[1] + j1[2] * f[2])
            r2 -= m * (j2[0] * f[0] + j2[1] * f[1] + j2[2] * f[2])
        a11 += self.armature[0] - total * (jg1[0] ** 2 + jg1[1] ** 2 + jg1[2] ** 2)
        a12 -= total * (jg1[0] * jg2[0] + jg1[1] * jg2[1] + jg1[2] * jg2[2])
        a22 += self.armature[1] - total * (jg2[0] ** 2 + jg2[1] ** 2 + jg2[2] ** 2)
        det = a11 * a22 - a12 * a12
        dd1 = (a22 * r1 - a12 * r2) / det
        dd2 = (a11 * r2 - a12 * r1) / det
        self.eta_ddot = [dd1, dd2]
        moment = self._moment(kin, omega, dd1, dd2)
        dt = self.dt_s
        self.eta_dot = [self.eta_dot[0] + dt * dd1, self.eta_dot[1] + dt * dd2]
        self.eta = [self.eta[0] + dt * self.eta_dot[0], self.eta[1] + dt * self.eta_dot[1]]
        return moment

    def centre_of_mass(self) -> tuple[Vec3, Vec3]:
        """CG of vehicle + arm from O and its rate relative to the body (body FLU) [m, m/s]."""
        self._kinematics()
        return self._com

    def _moment(self, kin, omega: Vec3, dd1: float, dd2: float) -> Vec3:
        """M_corr = -(J_dot omega + sum m rho x s_ddot + omega x sum m rho x s_dot)."""
        c, cd = self._com
        wx, wy, wz = omega
        # J_dot omega of the vehicle body: a mass at O, rho = -c, rho_dot = -c_dot.
        t0, t1, t2 = _jdot_omega(
            self.base_mass_kg, (-c[0], -c[1], -c[2]), (-cd[0], -cd[1], -cd[2]), omega
        )
        h0 = h1 = h2 = 0.0
        for m, s, sd, s0, j1, j2 in kin:
            a0 = j1[0] * dd1 + j2[0] * dd2 + s0[0]
            a1 = j1[1] * dd1 + j2[1] * dd2 + s0[1]
            a2 = j1[2] * dd1 + j2[2] * dd2 + s0[2]
            r0, r1, r2 = s[0] - c[0], s[1] - c[1], s[2] - c[2]
            v0, v1, v2 = sd[0] - cd[0], sd[1] - cd[1], sd[2] - cd[2]
            rr = r0 * v0 + r1 * v1 + r2 * v2
            rw = r0 * wx + r1 * wy + r2 * wz
            vw = v0 * wx + v1 * wy + v2 * wz
            t0 += m * (2.0 * rr * wx - v0 * rw - r0 * vw + r1 * a2 - r2 * a1)
            t1 += m * (2.0 * rr * wy - v1 * rw - r1 * vw + r2 * a0 - r0 * a2)
            t2 += m * (2.0 * rr * wz - v2 * rw - r2 * vw + r0 * a1 - r1 * a0)
            h0 += m * (r1 * sd[2] - r2 * sd[1])
            h1 += m * (r2 * sd[0] - r0 * sd[2])
            h2 += m * (r0 * sd[1] - r1 * sd[0])
        return (
            -(t0 + wy * h2 - wz * h1),
            -(t1 + wz * h0 - wx * h2),
            -(t2 + wx * h1 - wy * h0),
        )

    # ---------------------------------------------------------------- analysis

    def coupling_ratio(self) -> float:
        """Spectral radius of the lagged loop A_G^-1 C^T J_G^-1 C at the current pose.

        Below 1 means the one-step-lag coupling converges (module docstring); an error in
        omega_dot shrinks by this factor per step.
        """
        kin = self._kinematics()
        total = self.base_mass_kg + sum(k[0] for k in kin)
        c = np.array(_centre(self.base_mass_kg, kin)[0])
        inertia = np.diag(self.base_inertia) + self.base_mass_kg * (
            c @ c * np.eye(3) - np.outer(c, c)
        )
        coupling = np.zeros((3, 2))
        jg = np.zeros((3, 2))
        for m, s, _, _, j1, j2 in kin:
            rho = np.array(s) - c
            jac = np.column_stack((j1, j2))
            inertia += m * (rho @ rho * np.eye(3) - np.outer(rho, rho))
            coupling += m * np.cross(rho, jac.T).T
            jg += m * jac / total
        joint = self._joint_inertia() - total * jg.T @ jg
        loop = np.linalg.solve(joint, coupling.T @ np.linalg.solve(inertia, coupling))
        return float(np.max(np.abs(np.linalg.eigvals(loop))))


def _centre(base_mass_kg: float, kin) -> tuple[Vec3, Vec3]:
    total = base_mass_kg
    c = [0.0, 0.0, 0.0]
    cd = [0.0, 0.0, 0.0]
    for m, s, sd, *_ in kin:
        total += m
        for i in range(3):
            c[i] += m * s[i]
            cd[i] += m * sd[i]
    return (c[0] / total, c[1] / total, c[2] / total), (cd[0] / total, cd[1] / total, cd[2] / total)


def _jdot_omega(m: float, rho: Vec3, rho_dot: Vec3, omega: Vec3) -> Vec3:
    """d/dt[m (|rho|^2 I - rho rho^T)] omega for one point mass."""
    rr = rho[0] * rho_dot[0] + rho[1] * rho_dot[1] + rho[2] * rho_dot[2]
    rw = rho[0] * omega[0] + rho[1] * omega[1] + rho[2] * omega[2]
    dw = rho_dot[0] * omega[0] + rho_dot[1] * omega[1] + rho_dot[2] * omega[2]
    return tuple(m * (2.0 * rr * omega[i] - rho_dot[i] * rw - rho[i] * dw) for i in range(3))  # type: ignore[return-value]

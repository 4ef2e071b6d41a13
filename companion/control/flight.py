"""One control cycle of the companion: estimator, control law and setpoint mapping.

Pure (no I/O, no clock). The same step runs everywhere: the flight application
(:mod:`companion.mission.app`, against PX4 or the SITL) and the offline simulator
(``sitl.offline.simulation``) call :meth:`FlightControl.step` once per control period with the
filtered state, the desired state and the generalized force applied over the last period,
and send the result to PX4 (or the plant) and the servos. The pieces are the paper's
(section III):

- the on-line estimator (eq. est1-est3, or RLS) on the rows whose force is known: in flight
  x, y, z from the commanded thrust along the measured attitude and the joints from the
  servos' present current (DESIGN.md section 4); all rows on the offline ideal plant,
- a control law (:class:`~companion.control.laws.ControlLaw`): the augmented passivity-based
  controller (eq. tau2) with the estimate, or frozen at the empty-arm values (the
  non-adaptive baseline), or the adaptive sliding-mode baseline (eq. asc1); plus a slow
  horizontal integral trim (:class:`~companion.control.laws.HorizontalTrim`, off in the
  paper's configs),
- the small-angle tilt mapping (eq. phid) and PX4's relative thrust (:class:`ThrustModel`),
  with the tilt fed back as the attitude reference through a third-order filter
  (:class:`TiltReference`); optionally the roll/pitch offset that makes PX4's attitude loop
  produce the torque the model needs on the tilt rows at the reference attitude
  (:class:`~companion.control.attitude_feedforward.AttitudeLoopInverse`).

Compiled and reference paths
----------------------------
Where the compiled twin of :mod:`companion.control.control_step` is built from its source
(``pip install .`` always builds it), the step of the passivity and non-adaptive laws, with
the paper or the RLS estimator (with or without the thrust scale), runs in one compiled
call per cycle (:mod:`companion.control.compiled_step`); the Python classes remain the
reference it is tested against to 1e-12 (tests/test_compiled_step.py). The sliding-mode
law (eq. asc1) always runs in Python. ``FlightControl(..., compiled=False)`` or the
environment variable ``COMPANION_STEP=python`` selects the Python step; if the twin is
missing or stale the Python step runs after a one-line warning. The state filter
(:mod:`companion.estimation.filters`) runs before the step, in Python, on either path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from companion.config import CompanionConfig
from companion.control.attitude_feedforward import AttitudeLoopInverse
from companion.control.compiled_step import CompiledStep, frozen_record
from companion.control.laws import (
    ControlLaw,
    DesiredState,
    HorizontalTrim,
    PassivityController,
    SlidingModeController,
    check_control_rate,
    damping_step_ratio,
)
from companion.control.native import native_module
from companion.control.setpoints import (
    AttitudeThrustSetpoint,
    ThrustModel,
    attitude_thrust_setpoint,
)
from companion.control.trajectory import TiltReference
from companion.coordinates import HORIZONTAL, JOINTS, N_Q, PHI, POSITION, PSI, THETA, TILT
from companion.estimation.estimator import (
    JOINT_ROWS,
    TRANSLATION_AND_JOINT_ROWS,
    Estimate,
    Skip,
    estimator_from_config,
)
from companion.estimation.filters import FilteredState
from companion.estimation.inputs import DelayedInputs, EstimatorInputs, delay_cycles
from companion.estimation.state import thrust_force_world
from companion.estimation.thrust_supply import SupplyScale
from companion.model import ManipulatorModel, ModelTerms

__all__ = ["ControlOutput", "FlightControl", "FlightControllerName"]

FloatArray = NDArray[np.float64]
FlightControllerName = Literal["passivity", "nonadaptive", "asmc", "px4_position"]


@dataclass(frozen=True)
class ControlOutput:
    """Result of one control cycle (arrays shape (8,) follow q's order)."""

    tau: FloatArray
    """Generalized force of eq. tau2 [N, N m]."""
    setpoint: AttitudeThrustSetpoint
    """Attitude (ENU/FLU, ZYX) and thrust for PX4."""
    estimate: Estimate
    """The estimator's output this cycle (theta, excitation, confidence)."""
    theta_hat: FloatArray
    """theta the controller used, shape (3,): the estimate, or the nominal values."""
    desired: DesiredState
    """The desired state after the tilt reference replaced phi_d and theta_d."""


class FlightControl:
    """Estimator + control law + tilt/thrust mapping; see the module docstring.

    Parameters
    ----------
    config
        Gains, estimator settings, vehicle thrust model (the companion's configuration).
    controller
        ``"passivity"`` (eq. tau2 with the estimate), ``"nonadaptive"`` (eq. tau2 with the
        empty-arm theta; the estimator still runs, for the log), ``"asmc"`` (eq. asc1) or
        ``"px4_position"``: PX4's own position controller flies the vehicle (the app streams
        the desired position, velocity and acceleration, :attr:`px4_flies_position`) and
        eq. tau2 with the estimate drives the joints only; the estimator runs on the joint
        rows (the thrust PX4 commands is not known to the companion) and without a thrust
        scale.
    rows
        Rows of q the estimator uses [default: the configuration's ``estimator.rows``
        whose force is known in flight: x, y, z and the joints].
    actuated_rows
        Rows whose force reaches the vehicle (the control-rate check): in flight x, y, z
        and the joints (PX4 closes the attitude loop); all on the ideal plant.
    estimator_kind
        ``"paper"`` or ``"rls"`` [default: ``estimator.kind``].
    compiled
        Run the step compiled (True; RuntimeError if the twin is not built from its
        source) or in Python, the reference (False) [default: compiled where it is built
        and the law is eq. tau2, unless the environment variable ``COMPANION_STEP`` is
        ``python``]. The attribute :attr:`compiled` says which runs.
    """

    def __init__(
        self,
        config: CompanionConfig,
        controller: FlightControllerName = "passivity",
        *,
        rows: tuple[int, ...] | None = None,
        actuated_rows: tuple[int, ...] = TRANSLATION_AND_JOINT_ROWS,
        estimator_kind: str | None = None,
        compiled: bool | None = None,
    ) -> None:
        if controller not in ("passivity", "nonadaptive", "asmc", "px4_position"):
            raise ValueError(
                "controller must be 'passivity', 'nonadaptive', 'asmc' or 'px4_position', "
                f"got {controller!r}"
            )
        self.px4_flies_position = controller == "px4_position"
        """PX4's position controller flies the vehicle; the law's force and attitude setpoint
        are not flown (``"px4_position"``)."""
        self.scenario = config
        self.model = ManipulatorModel.from_config(config)
        known = JOINT_ROWS if self.px4_flies_position else TRANSLATION_AND_JOINT_ROWS
        if self.px4_flies_position:
            actuated_rows = JOINT_ROWS
        if rows is None:
            rows = tuple(r for r in config.estimator.rows if r in known)
        if not rows:
            raise ValueError(
                "estimator.rows has no row with a force known in flight "
                f"({', '.join(map(str, known))})"
            )
        self.rows = rows
        self.actuated_rows = actuated_rows
        kind = estimator_kind or config.estimator.kind
        self.estimator = estimator_from_config(config, kind, rows)
        ctl = config.controller
        self.nominal_theta = np.array(config.nominal_theta.as_tuple())
        self.controller: ControlLaw
        if controller == "nonadaptive":
            self.controller = PassivityController.nonadaptive(
                ctl.k, ctl.lambda_, self.nominal_theta
            )
        elif controller == "asmc":
            self.controller = SlidingModeController.from_config(config)
        else:
            self.controller = PassivityController(ctl.k, ctl.lambda_)
        self.tilt = TiltReference(ctl.tilt_reference_bandwidth_rad_s)
        rotors = config.vehicle.rotors
        self._compiled: CompiledStep | None = None
        self.thrust = ThrustModel(6 * rotors.max_thrust_per_rotor_n)
        self.tilt_max_rad = ctl.tilt_max_rad
        self.trim = HorizontalTrim(ctl.horizontal_trim_gain_n_per_m, ctl.horizontal_trim_limit_n)
        self._trim_active = False
        scale = config.estimator.thrust_scale
        self.compensate_thrust = scale is not None and scale.compensate
        """Map the law's force divided by the calibrated thrust scale (``compensate``)."""
        self.supply_scale = (
            SupplyScale(
                scale.window_s,
                exponent=scale.voltage_exponent,
                exponent_std=scale.voltage_exponent_std,
                filter_s=scale.voltage_filter_s,
            )
            if scale is not None and scale.window_s > 0.0 and self.estimator.scale is not None
            else None
        )
        """The thrust scale carried from the hover calibration with the battery's voltage
        (``window_s``), or None."""
        unactuated = [r for r in range(N_Q) if r not in actuated_rows]
        self._unactuated = (
            np.array(unactuated) if unactuated and ctl.measured_unactuated_motion else None
        )
        """Rows on which eq. tau2 takes the measured motion (``measured_unactuated_motion``)."""
        self.attitude_inverse = (
            None
            if ctl.attitude_feedforward is None
            else AttitudeLoopInverse.from_config(ctl.attitude_feedforward)
        )
        """PX4's tilt loop inverted (``[controller.attitude_feedforward]``), or None."""
        self.estimator_delay_s = config.estimator.acceleration_delay_s
        """The estimator's delay behind the controller [s] (``acceleration_delay_s``)."""
        self._delayed: DelayedInputs | None = None
        module = native_module(compiled)
        if module is not None and CompiledStep.supports(self.controller, self.estimator):
            assert isinstance(self.controller, PassivityController)
            self._compiled = CompiledStep(
                module,
                self.model.params.vector(),
                self.estimator,
                self.controller,
                np.asarray(ctl.lambda_, dtype=float),
                self.tilt,
                self.trim,
                self.thrust,
                self.tilt_max_rad,
                self.compensate_thrust,
                () if self._unactuated is None else tuple(self._unactuated.tolist()),
                self.attitude_inverse,
                self.estimator_delay_s,
                self.supply_scale,
            )
            self.estimator = self._compiled.estimator
            self.attitude_inverse = self._compiled.attitude_inverse
            self.supply_scale = self._compiled.supply
            self.tilt = self._compiled.tilt
            self.trim = self._compiled.trim

    @property
    def compiled(self) -> bool:
        """True if the step runs compiled (:mod:`companion.control.compiled_step`)."""
        return self._compiled is not None

    @property
    def thrust(self) -> ThrustModel:
        """Newtons <-> PX4 relative thrust; the flight app sets its floor from the vehicle."""
        return self._thrust if self._compiled is None else self._compiled.thrust

    @thrust.setter
    def thrust(self, model: ThrustModel) -> None:
        self._thrust = model
        if self._compiled is not None:
            self._compiled.thrust = model

    @property
    def tilt_max_rad(self) -> float:
        """Tilt limit of eq. phid [rad]."""
        return self._tilt_max_rad

    @tilt_max_rad.setter
    def tilt_max_rad(self, value: float) -> None:
        self._tilt_max_rad = value
        if self._compiled is not None:
            self._compiled.tilt_max_rad = value

    @property
    def trim_active(self) -> bool:
        """The trim integrates only while the vehicle flies these setpoints (the app)."""
        return self._trim_active

    @trim_active.setter
    def trim_active(self, value: bool) -> None:
        self._trim_active = value
        if self._compiled is not None:
            self._compiled.trim_active = value

    def check_rate(self, rate_hz: float, q: FloatArray) -> float:
        """Raise :class:`~companion.control.laws.ControlRateError` if ``rate_hz`` is too low for
        the law's velocity gains on the actuated rows at configuration ``q``; returns the
        damping step ratio (see :func:`~companion.control.laws.check_control_rate`)."""
        m = self.model.mass_matrix(q, tuple(self.estimator.theta))
        return check_control_rate(
            m, self.controller.velocity_gain, 1.0 / rate_hz, self.actuated_rows
        )

    def max_period_s(self, q: FloatArray) -> float:
        """Longest control period [s] the velocity gains tolerate with margin at ``q``: where
        the damping step ratio reaches 1, half its stability bound (the limit of
        :meth:`check_rate`)."""
        m = self.model.mass_matrix(q, tuple(self.estimator.theta))
        return 1.0 / damping_step_ratio(m, self.controller.velocity_gain, 1.0, self.actuated_rows)

    def step(
        self,
        dt_s: float,
        state: FilteredState,
        desired: DesiredState,
        applied_tau: FloatArray | Skip,
    ) -> ControlOutput:
        """One control cycle of ``dt_s`` [s].

        ``applied_tau`` is the generalized force applied over the last cycle (see
        :meth:`applied_force`), or why it is not known: the estimator skips the step.
        Runs compiled when :attr:`compiled`, with the same result (see the module
        docstring).
        The thrust scale from the battery (:attr:`supply_scale`) goes around the step.
        """
        supply = self.supply_scale
        if supply is None:
            return self._step(dt_s, state, desired, applied_tau)
        supply.before(dt_s, self.estimator)
        out = self._step(dt_s, state, desired, applied_tau)
        supply.after(dt_s, self.estimator, state.q_dot)
        return out

    def supply(self, voltage_v: float | None) -> None:
        """The battery voltage the vehicle reports [V] (None: unknown), for the thrust
        scale (:attr:`supply_scale`); ignored without one."""
        if self.supply_scale is not None:
            self.supply_scale.supply(voltage_v)

    def supply_summary(self) -> dict[str, float | None] | None:
        """The thrust scale carried with the battery now, for the summary: ``value`` s,
        ``relative_std`` sd(s)/s, ``calibration_v`` V_cal and ``voltage_v`` V (None: no
        voltage) [V]; None before it is fitted, or without one."""
        supply = self.supply_scale
        if supply is None or supply.level is None:
            return None
        return {
            "value": supply.scale(),
            "relative_std": supply.relative_std(),
            "calibration_v": supply.calibration_v,
            "voltage_v": supply.voltage_v,
        }

    def payload_mass_std_kg(self) -> float | None:
        """Standard deviation of m2 [kg] with the thrust scale's in it: the estimator's own
        (RLS covariance; 0 for the paper observer, which has none) and, with s carried by
        :attr:`supply_scale`, the mass its uncertainty moves: in a hover s T = (M + m2) g,
        so m2 is off by (M + m2) sd(s)/s. None before the thrust scale is fitted, or
        without a thrust scale."""
        supply = self.supply_scale
        relative = None if supply is None else supply.relative_std()
        if relative is None:
            return None
        own = getattr(self.estimator, "std", None)
        m2_std = 0.0 if own is None else float(own[0])
        total_kg = self.weight_n() / self.scenario.environment.gravity_m_s2
        return math.hypot(m2_std, total_kg * relative)

    def _step(
        self,
        dt_s: float,
        state: FilteredState,
        desired: DesiredState,
        applied_tau: FloatArray | Skip,
    ) -> ControlOutput:
        q, q_dot, q_ddot = state.q, state.q_dot, state.q_ddot
        if self._compiled is not None:
            tau, setpoint, estimate, theta_hat, reference = self._compiled.step(
                dt_s, q, q_dot, q_ddot, desired, applied_tau
            )
            return frozen_record(
                ControlOutput,
                tau=tau,
                setpoint=setpoint,
                estimate=estimate,
                theta_hat=theta_hat,
                desired=reference,
            )
        terms = self.model.terms(q, q_dot)
        estimate = self._estimate(dt_s, terms, q, q_dot, q_ddot, applied_tau)
        reference = self.tilt.apply(desired)
        law_reference = reference
        if self._unactuated is not None:
            law_q_dot, law_q_ddot = reference.q_dot.copy(), reference.q_ddot.copy()
            law_q_dot[self._unactuated] = q_dot[self._unactuated]
            law_q_ddot[self._unactuated] = q_ddot[self._unactuated]
            law_reference = DesiredState(q=reference.q, q_dot=law_q_dot, q_ddot=law_q_ddot)
        tau, theta_hat = self.controller.control(
            dt_s, terms, state, law_reference, estimate.theta, applied_tau
        )
        if self._trim_active:
            lam = self.scenario.controller.lambda_
            e = q[HORIZONTAL] - reference.q[HORIZONTAL]
            e_dot = q_dot[HORIZONTAL] - reference.q_dot[HORIZONTAL]
            sliding = e_dot + np.asarray(lam[HORIZONTAL]) * e
            self.trim.update(dt_s, sliding)
        tau[HORIZONTAL] += self.trim.force_n
        force = tau[POSITION]
        if self.compensate_thrust:
            force = force / self.estimator.compensation_scale
        setpoint = attitude_thrust_setpoint(
            force, float(q[PSI]), float(reference.q[PSI]), self.tilt_max_rad, self.thrust
        )
        self.tilt.step(dt_s, (setpoint.roll_rad, setpoint.pitch_rad))
        if self.attitude_inverse is not None:
            offset = self._attitude_offset(dt_s, q, q_dot, reference, theta_hat)
            setpoint = replace(
                setpoint,
                roll_rad=setpoint.roll_rad + float(offset[0]),
                pitch_rad=setpoint.pitch_rad + float(offset[1]),
            )
        return ControlOutput(
            tau=tau,
            setpoint=setpoint,
            estimate=estimate,
            theta_hat=np.asarray(theta_hat, dtype=np.float64),
            desired=reference,
        )

    def _attitude_offset(
        self,
        dt_s: float,
        q: FloatArray,
        q_dot: FloatArray,
        reference: DesiredState,
        theta_hat: FloatArray,
    ) -> FloatArray:
        """Roll/pitch offset [rad] for the torque of eq. tau2's model part on the tilt rows,
        ``(Mhat qd_ddot + Chat qd_dot + Ghat)[roll, pitch]``, with roll and pitch (and their
        rates) at the tilt reference, not the measured ones: evaluated at the measured tilt
        it would cancel the hanging arm's own restoring torque (positive feedback through
        PX4's loop, unstable with 0.4 kg at 0.41 m). Compensated (``compensate``), over the
        calibrated thrust scale, as the force: rotors a fraction s as strong make a fraction
        s of the torque per unit of PX4's normalized torque (uncompensated, a 10 % weaker
        thrust doubled the paper trajectory's RMS error, all of it along the arm's swing)."""
        assert self.attitude_inverse is not None
        q_ref, q_dot_ref = q.copy(), q_dot.copy()
        q_ref[TILT] = reference.q[TILT]
        q_dot_ref[TILT] = reference.q_dot[TILT]
        xi = np.append(theta_hat, 1.0)
        y = self.model.terms(q_ref, q_dot_ref).regressor(reference.q_dot, reference.q_ddot)
        torque = y[TILT] @ xi
        if self.compensate_thrust:
            torque = torque / self.estimator.compensation_scale
        return self.attitude_inverse.offset(dt_s, torque)

    def _estimate(
        self,
        dt_s: float,
        terms: ModelTerms,
        q: FloatArray,
        q_dot: FloatArray,
        q_ddot: FloatArray,
        applied_tau: FloatArray | Skip,
    ) -> Estimate:
        """The estimator's step on this cycle, or with ``acceleration_delay_s`` on the cycle
        that far back (:mod:`companion.estimation.inputs`; the line's length is set by the
        first cycle's period)."""
        if self.estimator_delay_s == 0.0:
            return self.estimator.update(dt_s, terms, q, q_dot, q_ddot, applied_tau)
        inputs = self._delayed_inputs(dt_s, q, q_dot, applied_tau)
        if inputs is None:
            return self.estimator.update(dt_s, terms, q, q_dot, q_ddot, Skip.WARMING_UP)
        q_old, q_dot_old, q_ddot_old, tau_old = inputs
        terms_old = self.model.terms(q_old, q_dot_old)
        return self.estimator.update(dt_s, terms_old, q_old, q_dot_old, q_ddot_old, tau_old)

    def restart_estimator_inputs(self) -> None:
        """Forget the estimator's delay line (``acceleration_delay_s``): the state estimate
        jumped (a navigation reset), so a central difference across the jump would be a
        spike. The estimator skips the cycles it takes to refill."""
        if self._compiled is not None:
            self._compiled.restart_delay_line()
        elif self._delayed is not None:
            self._delayed.reset()

    def _delayed_inputs(
        self, dt_s: float, q: FloatArray, q_dot: FloatArray, applied_tau: FloatArray | Skip
    ) -> EstimatorInputs | None:
        """This cycle into the delay line; the estimator's inputs n cycles back, or None
        while the line fills."""
        if self._delayed is None:
            self._delayed = DelayedInputs(delay_cycles(self.estimator_delay_s, dt_s))
        return self._delayed.push(dt_s, q, q_dot, applied_tau)

    def weight_n(self, theta: FloatArray | None = None) -> float:
        """Weight of vehicle + arm [N] with link 2's mass from ``theta`` (default: the
        estimator's current theta): the hover thrust the model believes in."""
        m2 = float((self.estimator.theta if theta is None else theta)[0])
        s = self.scenario
        mass = s.vehicle.mass_kg + s.arm.link1.mass_kg + m2
        return mass * s.environment.gravity_m_s2

    def applied_force(
        self, q: FloatArray, thrust_n: float, joint_torques_n_m: FloatArray
    ) -> FloatArray:
        """Generalized force applied over a cycle, NaN on rows not known in flight.

        x, y, z: the thrust [N] PX4 was commanded, along the measured attitude of ``q``;
        joints: the servos' torque read-back [N m] (present current x torque constant).
        """
        tau = np.full(N_Q, math.nan)
        tau[POSITION] = thrust_force_world(float(q[PHI]), float(q[THETA]), float(q[PSI]), thrust_n)
        tau[JOINTS] = joint_torques_n_m
        return tau

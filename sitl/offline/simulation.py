"""Offline closed-loop simulation: the companion's math against the SITL truth plant.

One loop, two sides. The truth side (``sitl.physics.TruthPlant`` at ``plant.rate_hz``,
``sitl.vehicle.sensors`` for noisy measurements) shares no code with ``companion.model``. The
companion side sees only measurements and its own commands: it filters them
(:class:`companion.estimation.state.StateAssembler`), estimates theta, runs the controller and maps
the force to setpoints, every ``1 / simulation.control_rate_hz`` seconds.

Plants: ``ideal`` applies the controller's tau on all 8 coordinates (the paper's
simulation); ``underactuated`` sends attitude + normalized thrust to the PX4-like loop and
torques to the servos, and the estimator then uses only the rows with a known force
(x, y, z from the commanded thrust and the measured attitude; joints from the servo torque
read-back).

Physics (``SimOptions.physics``): ``pinocchio`` (``sitl.physics.TruthPlant``) or ``jsbsim``
(``sitl.physics.jsbsim.JsbsimPlant``: underactuated only, with optional wind and
turbulence), built by ``sitl.physics.make_plant``.

Gripper events (pick-up, release) are commands of the companion, so it may act on them:
on a release the estimator restarts from the empty-arm values, on a pick-up it restarts
its confidence (and RLS covariance) from its current estimate.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from companion.control.flight import FlightControl
from companion.control.laws import SlidingModeController
from companion.control.setpoints import attitude_thrust_setpoint
from companion.coordinates import JOINTS, POSITION, PSI
from companion.estimation.estimator import TRANSLATION_AND_JOINT_ROWS, PaperEstimator, Skip
from companion.estimation.state import StateAssembler
from sitl.offline.trajectory import PaperSinusoid
from sitl.physics import (
    AttitudeSetpoint,
    IdealPlant,
    PhysicsBackend,
    Plant,
    PlantCore,
    make_plant,
)
from sitl.physics.jsbsim.wind import Wind
from sitl.scenario import Scenario
from sitl.stepping import step_loop
from sitl.vehicle.sensors import GyroSensor, JointEncoders, PoseSensor

__all__ = ["COLUMNS", "SimOptions", "SimResult", "simulate"]

ControllerName = Literal["passivity", "nonadaptive", "asmc"]
EstimatorName = Literal["paper", "rls"]
PlantName = Literal["ideal", "underactuated"]

_Q = ("x", "y", "z", "phi", "theta", "psi", "eta1", "eta2")
COLUMNS: tuple[str, ...] = (
    "t_s",
    *(f"q_{n}" for n in _Q),
    *(f"qd_{n}" for n in _Q),
    *(f"qfilt_{n}" for n in _Q),
    *(f"qhat_{n}" for n in _Q),
    *("m2_hat", "m3_hat", "m4_hat", "lc_hat", "excitation", "confident", "thrust_scale_hat"),
    *("m2_true", "m3_true", "m4_true", "lc_true", "payload_attached", "thrust_scale_true"),
    *(f"tau_{n}" for n in _Q),
    *("sp_roll_rad", "sp_pitch_rad", "sp_yaw_rad", "sp_thrust_n", "sp_thrust_rel"),
    "step_time_us",
)
"""Time-series columns: truth q, desired q_d, filtered q, the paper observer's qhat (NaN
for unused rows or other estimators), estimates (with the thrust scale s, 1 when not
estimated), truth theta and s (true over believed thrust per command: thrust mismatch x
the battery's voltage factor; 1 on the ideal plant), tau, setpoint, step cost."""
_COL = {name: i for i, name in enumerate(COLUMNS)}


@dataclass(frozen=True)
class SimOptions:
    """What to run; ``None`` fields take the scenario's values."""

    controller: ControllerName = "passivity"
    estimator: EstimatorName | None = None
    plant: PlantName = "ideal"
    duration_s: float | None = None
    seed: int = 0
    noise: bool = False
    pickup_at_s: float | None = None
    release_at_s: float | None = None
    physics: PhysicsBackend = "pinocchio"
    wind: Wind | None = None


@dataclass
class SimResult:
    """Per-control-step records (``data[:, COLUMNS.index(name)]``) and the summary."""

    options: SimOptions
    data: np.ndarray
    summary: dict = field(default_factory=dict)

    def column(self, name: str) -> np.ndarray:
        return self.data[:, _COL[name]]


class _Measurements:
    """Truth -> what the companion receives this control step (noisy or exact)."""

    def __init__(self, scenario: Scenario, noise: bool, rng: np.random.Generator) -> None:
        s = scenario.sensors
        self.noise = noise
        self.rng = rng
        self.torque_std = s.joint_torque_std_n_m if noise else 0.0
        if not noise:
            self.assembler = StateAssembler.noise_free(s.jerk_psd)
            return
        self.assembler = StateAssembler.from_sensors(s)
        if noise:
            self.pose = PoseSensor(
                rng,
                position_std_m=s.position_std_m,
                attitude_std_rad=s.attitude_std_rad,
                rate_hz=s.pose_rate_hz,
                latency_s=s.pose_latency_s,
            )
            self.gyro = GyroSensor(rng, rate_std_rad_s=s.gyro_std_rad_s, rate_hz=s.gyro_rate_hz)
            self.joints = JointEncoders(rng, angle_std_rad=s.joint_std_rad, rate_hz=s.joint_rate_hz)
            # Servo Present Velocity: the same delayed, quantised sampler on the joint rates,
            # in units of the XM430's 0.229 rev/min (2 pi / 262 rad/s).
            self.joint_rates = JointEncoders(
                rng,
                angle_std_rad=0.0,
                ticks_per_rev=round(2.0 * math.pi / s.joint_velocity_unit_rad_s),
                rate_hz=s.joint_rate_hz,
            )

    def feed(self, t: float, state, dt: float | None) -> None:
        a = self.assembler
        if dt is not None:
            a.predict(dt)
        if not self.noise:
            a.exact(state.q, state.q_dot)
            return
        pose = self.pose.sample(t, state.q)
        if pose is not None:
            a.pose(pose.position_m, pose.euler_rad, t - pose.stamp_s)
        joints = self.joints.sample(t, state.q[JOINTS])
        if joints is not None:
            a.joints(joints.eta_rad, t - joints.stamp_s)
        rates = self.joint_rates.sample(t, state.q_dot[JOINTS])
        if rates is not None:
            a.joint_rates(rates.eta_rad, t - rates.stamp_s)
        gyro = self.gyro.sample(t, state.omega_body_rad_s)
        if gyro is not None:
            a.body_rates(gyro.omega_body_rad_s, t - gyro.stamp_s)

    def joint_torques(self, applied_n_m: np.ndarray) -> np.ndarray:
        """Servo torque read-back (present current x torque constant), with noise."""
        if self.torque_std == 0.0:
            return applied_n_m
        return applied_n_m + self.rng.normal(0.0, self.torque_std, 2)


def simulate(
    scenario: Scenario,
    options: SimOptions = SimOptions(),
    progress: Callable[[float], None] | None = None,
) -> SimResult:
    """Run one closed-loop simulation; see the module docstring.

    Parameters
    ----------
    progress : callable, optional
        Called about every simulated second with the simulated time [s].
    """
    loop = _ClosedLoop(scenario, options, progress)
    step_loop(loop, until_s=loop.periods * loop.dt_s)
    result = SimResult(options=options, data=loop.data)
    elapsed_s = time.perf_counter() - loop.start
    result.summary = summarize(result, scenario, loop.kind, loop.rows, elapsed_s)
    return result


class _ClosedLoop:
    """One offline run's two sides and what it carries from one control period to the
    next: the truth plant stepped ``sub`` times per period under the companion's last
    command (:meth:`step_plant`), the companion fed the period's measurements and run once
    (:meth:`control`), the gripper's events at their times (:meth:`gripper_events`); one
    control period is one step of :func:`~sitl.stepping.step_loop` (:meth:`advance`), back
    to back."""

    paced = False
    """The periods run back to back (:class:`~sitl.stepping.Stepped`)."""

    def __init__(
        self,
        scenario: Scenario,
        opts: SimOptions,
        progress: Callable[[float], None] | None = None,
    ) -> None:
        duration = (
            opts.duration_s if opts.duration_s is not None else scenario.simulation.duration_s
        )
        self.kind = opts.estimator or scenario.estimator.kind
        rows = tuple(scenario.estimator.rows)
        if opts.plant == "underactuated":
            rows = tuple(r for r in rows if r in TRANSLATION_AND_JOINT_ROWS)
        if not rows:
            raise ValueError("no estimator row has a known generalized force on this plant")
        self.rows = rows
        self.scenario = scenario
        self.opts = opts
        attached = scenario.simulation.payload_attached_at_start
        self.ideal: IdealPlant | None = None
        self.flown: Plant | None = None
        self.plant: PlantCore
        if opts.plant == "ideal":
            self.plant = self.ideal = make_plant(
                scenario, opts.physics, "ideal", payload_attached=attached, wind=opts.wind
            )
        else:
            self.plant = self.flown = make_plant(
                scenario, opts.physics, "underactuated", payload_attached=attached, wind=opts.wind
            )
        # The rows the companion actuates: all on the ideal plant; on the underactuated one
        # PX4 closes the attitude loop itself.
        actuated = tuple(range(8)) if opts.plant == "ideal" else TRANSLATION_AND_JOINT_ROWS
        # The companion's one control step (the flight app runs the same), given only the
        # companion's part of the scenario.
        self.companion = control = FlightControl(
            scenario.beliefs, opts.controller, rows=rows, actuated_rows=actuated,
            estimator_kind=self.kind,
        )  # fmt: skip
        q0 = np.asarray(scenario.simulation.initial_q)
        control.check_rate(scenario.simulation.control_rate_hz, q0)
        self.estimator = estimator = control.estimator
        if opts.pickup_at_s is not None and not attached:
            # The arm is known empty until the pickup: the thrust scale alone is learnt (as
            # the mission does before its grasp; an estimator without one holds theta).
            estimator.calibrate()
        self.trajectory = PaperSinusoid(scenario.trajectory)
        self.sensing = _Measurements(scenario, opts.noise, np.random.default_rng(opts.seed))
        self.nominal = scenario.nominal_theta.as_tuple()
        self.sub = round(self.plant.rate_hz / scenario.simulation.control_rate_hz)
        self.dt_s = self.sub * self.plant.dt_s
        """The control period [s]."""
        self.periods = math.floor(duration / self.dt_s + 1e-9)
        self.data = np.empty((self.periods, len(COLUMNS)))
        self.observer = estimator if isinstance(estimator, PaperEstimator) else None
        # columns qd_x..thrust_scale_hat
        self.not_ready = (math.nan,) * (_COL["thrust_scale_hat"] + 1 - _COL["qd_x"])
        self.start = time.perf_counter()
        # Until the filter has a first measurement of every row, hold gravity compensation
        # at the scenario's start pose with the initial estimate (a few ms with latency).
        self.tau = control.model.gravity(q0, scenario.estimator.initial_theta.as_tuple())
        self.setpoint = attitude_thrust_setpoint(
            self.tau[POSITION], q0[PSI], q0[PSI], control.tilt_max_rad, control.thrust
        )
        self.applied: np.ndarray | Skip = Skip.NO_FORCE
        self.q_filtered: np.ndarray | None = None
        """The filter's q of the last period (None: not ready)."""
        self.events = sorted(
            (t, name)
            for t, name in ((opts.pickup_at_s, "pickup"), (opts.release_at_s, "release"))
            if t is not None
        )
        self.truth_row = _truth_row(self.plant)
        self.period = 0
        """Control periods run."""
        self._progress = progress
        self._next_progress_s = 1.0

    @property
    def time_s(self) -> float:
        """The start of the next control period [s]."""
        return self.period * self.dt_s

    def advance(self) -> bool:
        """One control period (:class:`~sitl.stepping.Stepped`): the gripper's events, the
        companion's step on the period's measurements (its row logged), the plant's steps
        under its command; the progress callback about every simulated second."""
        i = self.period
        t = i * self.dt_s
        self.gripper_events(t)
        self.data[i] = self.control(t, first=i == 0)
        self.step_plant()
        if self._progress is not None and t >= self._next_progress_s:
            self._progress(t)
            self._next_progress_s += 1.0
        self.period += 1
        return False

    def gripper_events(self, t: float) -> None:
        """The pick-up and release due by ``t`` [s]: the plant's payload, and the
        estimator restarted (module docstring)."""
        plant, estimator = self.plant, self.estimator
        while self.events and self.events[0][0] <= t:
            _, name = self.events.pop(0)
            if name == "pickup":
                plant.attach_payload()
                estimator.reset(estimator.theta)
                if estimator.frozen:
                    estimator.resume()
            else:
                plant.detach_payload()
                estimator.reset(self.nominal)
            self.truth_row = _truth_row(plant)

    def control(self, t: float, first: bool) -> tuple[float, ...]:
        """The companion's control step at ``t`` [s] on this period's measurements (the
        held gravity compensation until the filter is ready); the period's row, in the
        order of :data:`COLUMNS`."""
        state = self.plant.state
        tick = time.perf_counter_ns()
        sensing = self.sensing
        sensing.feed(t, state, None if first else self.dt_s)
        self.q_filtered = None
        if sensing.assembler.ready:
            f = sensing.assembler.estimate
            q = self.q_filtered = f.q
            out = self.companion.step(self.dt_s, f, self.trajectory(t), self.applied)
            self.tau, self.setpoint = out.tau, out.setpoint
            est, desired = out.estimate, out.desired
            # The estimate logged: the law's own for the sliding-mode baseline (eq. asc2),
            # the estimator's otherwise (it runs beside the non-adaptive law too).
            own = isinstance(self.companion.controller, SlidingModeController)
            theta_hat = out.theta_hat if own else est.theta
            step_us = (time.perf_counter_ns() - tick) / 1e3
            qhat = [math.nan] * 8  # the paper observer's qhat on its rows
            observer = self.observer
            if observer is not None and observer.qhat is not None:
                for r, value in zip(self.rows, observer.qhat.tolist(), strict=True):
                    qhat[r] = value
            m2_hat, m3_hat, m4_hat = theta_hat.tolist()
            companion = (
                *desired.q.tolist(),
                *q.tolist(),
                *qhat,
                m2_hat,
                m3_hat,
                m4_hat,
                m3_hat / m2_hat,
                est.excitation,
                est.confident,
                est.thrust_scale,
            )
        else:
            companion, step_us = self.not_ready, math.nan
        setpoint = self.setpoint
        return (
            t,
            *state.q.tolist(),
            *companion,
            *self.truth_row,
            1.0 if self.flown is None else self.flown.thrust_per_command,
            *self.tau.tolist(),
            setpoint.roll_rad,
            setpoint.pitch_rad,
            setpoint.yaw_rad,
            setpoint.thrust_n,
            setpoint.thrust_relative,
            step_us,
        )

    def step_plant(self) -> None:
        """The truth plant's steps of one control period under the companion's command;
        the force the estimator takes as applied in the next period."""
        tau, sub = self.tau, self.sub
        if self.ideal is not None:
            for _ in range(sub):
                self.ideal.step_ideal(tau)
            self.applied = tau
        elif self.flown is not None:
            setpoint = self.setpoint
            command = AttitudeSetpoint.from_euler(
                setpoint.roll_rad, setpoint.pitch_rad, setpoint.yaw_rad, setpoint.thrust_relative
            )
            for _ in range(sub):
                self.flown.step(command, tau[JOINTS])
            read_back = self.sensing.joint_torques(self.flown.actuators.joint_torques_n_m)
            # The thrust along the filtered attitude of this step, the servos' read-back.
            q = self.q_filtered
            self.applied = (
                Skip.NO_FORCE
                if q is None
                else self.companion.applied_force(q, setpoint.thrust_n, read_back)
            )


def _truth_row(plant: PlantCore) -> tuple[float, ...]:
    """(m2, m3, m4, lc, attached) of the plant's link 2 now (logged, never shown to the
    companion side)."""
    truth = plant.true_theta
    return (*truth.as_tuple(), truth.lc_m, float(plant.payload_attached))


def _settle_time(t: np.ndarray, estimate: np.ndarray, truth: np.ndarray) -> float | None:
    """Time after which |estimate - truth| <= 5 % of truth for good; None if never."""
    bad = ~(np.abs(estimate - truth) <= 0.05 * np.abs(truth))
    if bad[-1]:
        return None
    idx = np.flatnonzero(bad)
    return float(t[idx[-1] + 1]) if idx.size else float(t[0])


def summarize(
    result: SimResult, scenario: Scenario, kind: str, rows: tuple[int, ...], wall_s: float
) -> dict:
    """The summary.json content of one run.

    ``estimated_parameters`` lists what the run actually estimated: the sliding-mode law
    reads out m2 only and keeps lc at the empty-arm value, so its m3, m4, lc "estimates"
    are that fixed lc times its m2.
    """
    c = result.column
    t = c("t_s")
    pos_err = np.linalg.norm(
        np.column_stack([c(f"q_{n}") - c(f"qd_{n}") for n in ("x", "y", "z")]), axis=1
    )
    joint_err = np.column_stack([c(f"q_{n}") - c(f"qd_{n}") for n in ("eta1", "eta2")])
    valid = ~np.isnan(pos_err)
    names = ("m2", "m3", "m4", "lc")
    final = {n: float(c(f"{n}_hat")[-1]) for n in names}
    truth = {n: float(c(f"{n}_true")[-1]) for n in names}
    steps = c("step_time_us")
    steps = steps[~np.isnan(steps)]
    opts = result.options
    return {
        "scenario": scenario.name,
        "controller": opts.controller,
        "estimator": "asmc_readout" if opts.controller == "asmc" else kind,
        "estimator_rows": list(rows),
        "plant": opts.plant,
        "physics": opts.physics,
        "wind": None if opts.wind is None else dataclasses.asdict(opts.wind),
        "noise": opts.noise,
        "seed": opts.seed,
        "duration_s": float(t[-1] + (t[1] - t[0])) if t.size > 1 else 0.0,
        "estimated_parameters": ["m2"] if opts.controller == "asmc" else ["m2", "m3", "m4"],
        "estimates": final,
        "truth": truth,
        "errors_pct": {n: 100.0 * (final[n] - truth[n]) / truth[n] for n in names},
        "settle_time_s": {n: _settle_time(t, c(f"{n}_hat"), c(f"{n}_true")) for n in ("m2", "lc")},
        "confident_at_end": bool(c("confident")[-1] == 1.0),
        "rms_position_error_m": float(np.sqrt(np.mean(pos_err[valid] ** 2))),
        "max_position_error_m": float(np.max(pos_err[valid])),
        "rms_joint_error_rad": float(np.sqrt(np.nanmean(joint_err**2))),
        "step_time_us": {
            "median": float(np.median(steps)),
            "p99": float(np.percentile(steps, 99)),
        },
        "wall_time_s": wall_s,
    }

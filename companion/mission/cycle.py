"""One control cycle of the pickup, on each new pose: what the app does between a pose and
its setpoint, and after it.

Sense (the navigation watch, the state filter, the joint state the arm task read, fused with
its age), ask the mission for q_d (with the carry check from the grasp to the release, and
the mission's word on the estimator), run :class:`~companion.control.flight.FlightControl`,
stream the setpoint of the current OFFBOARD stage (:mod:`companion.mission.offboard`), hand the
joint torques to the arm task, watch the faults of a flown cycle, log one row. The app
(:mod:`companion.mission.app`) calls :meth:`ControlCycle.run` from its control loop and owns the
links, the clock and the tasks.

The generalized force handed to the estimator is the one applied over the last cycle: the
thrust commanded to PX4 along the measured attitude while the stream is ``CONTROL`` (PX4
flies it), and the servos' torque read-back; otherwise the reason it is not known
(:class:`~companion.estimation.estimator.Skip`).
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from arm_driver.bus import JointState
from arm_driver.dynamixel.units import CURRENT_A_PER_UNIT
from companion.config import CompanionConfig
from companion.control.flight import ControlOutput, FlightControl
from companion.control.laws import DesiredState
from companion.control.setpoints import AttitudeThrustSetpoint, PositionSetpoint
from companion.coordinates import HORIZONTAL, JOINTS, N_Q, PHI, PSI, THETA, TILT, Z
from companion.estimation.estimator import Skip
from companion.estimation.state import StateAssembler, thrust_force_world
from companion.link import MavlinkLink
from companion.link.telemetry import (
    BatteryState,
    BodyRates,
    LandedState,
    TimesyncReply,
    VehiclePose,
    VehicleStatus,
)
from companion.logs import columns
from companion.mission.arm_supervisor import ArmSupervisor
from companion.mission.authority import (
    AuthorityLimits,
    AuthorityWatch,
    lift_thrust_reason,
    payload_authority,
)
from companion.mission.carry_check import CarryThresholds, CarryVerdict, CarryWatch, gripper_holds
from companion.mission.failsafe import CARRY_REACTIONS, FailsafeMonitor, Fault, FaultEvent
from companion.mission.loop_period import CyclePeriod, GapTimes, LoopPeriodMonitor
from companion.mission.navigation import NavigationWatch
from companion.mission.offboard import HoldBias, Offboard, Stream
from companion.mission.pickup import EstimatorAction, MissionCommand, Outcome, Phase, PickupMission
from companion.mission.report import FlightFigures, MissionReport, carrying
from companion.mission.round_trip import RoundTripWatch
from companion.mission.sequence import Observation
from companion.mission.servo_check import MIN_POSES, ServoCheck, check_poses, fit_servo_check

__all__ = ["ControlCycle", "CycleLog", "log_cycle"]

FloatArray = NDArray[np.float64]


_Pair = Sequence[float] | FloatArray
"""The two joints' values."""


class CycleLog(Protocol):
    """Where each cycle's row goes: a row of :data:`~companion.logs.columns.ROW` to fill,
    the codes of its texts, and the commit of the filled row
    (:class:`~companion.logs.flightlog.FlightLogWriter`)."""

    def row(self) -> FloatArray: ...

    def code(self, text: str) -> float: ...

    def commit(self) -> None: ...


_HOLD_WINDOW_S = 3.0
"""Vehicle time of PX4's hold before the handover the horizontal bias is taken over [s]."""
_MAX_JOINT_AGE_S = 0.05
"""Age [s] a joint state is fused with at most (a cycle that waited on the link)."""
NOT_ARMED = object()
"""``ControlCycle.status_at_arm`` before the app armed the vehicle."""


def log_cycle(
    log: CycleLog,
    t_s: float,
    state,
    out: ControlOutput,
    setpoint: AttitudeThrustSetpoint | None,
    servos: tuple[_Pair, _Pair, _Pair],
    timing: tuple[float, float | None, float, float | None],
    *,
    px4_mode: str,
    armed: bool,
    phase: str,
    faults: Sequence[str],
) -> None:
    """One flight-log row of a control cycle at vehicle time ``t_s`` [s], filled in place
    and committed: the filtered ``state``, the step's ``out``, the ``setpoint`` sent (or
    None), ``servos`` (joint torques commanded, measured [N m], positions [rad]) and
    ``timing`` (period [ms], pose -> setpoint [us] or None, pose -> joint torques [us], CPU
    time to the setpoint [us] or None); the flight and the onboard timing check log alike,
    the same numbers :func:`~companion.logs.flightlog.fill_row` writes of a record."""
    row = log.row()
    row[columns.T] = t_s
    row[columns.Q] = state.q
    row[columns.Q_DOT] = state.q_dot
    row[columns.Q_DDOT] = state.q_ddot
    row[columns.Q_D] = out.desired.q
    estimate = out.estimate
    m2, m3, m4 = estimate.theta.tolist()
    row[columns.THETA.start : columns.THRUST_SCALE + 1] = (
        m2, m3, m4, m3 / m2 if m2 != 0.0 else math.nan, estimate.excitation, estimate.spread,
        estimate.confident, estimate.frozen, estimate.thrust_scale,
    )  # fmt: skip
    row[columns.TAU] = out.tau
    if setpoint is not None:
        sp = setpoint
        row[columns.SETPOINT] = (
            sp.roll_rad, sp.pitch_rad, sp.yaw_rad, sp.thrust_n, sp.thrust_relative,
            sp.tilt_saturated, sp.thrust_saturated,
        )  # fmt: skip
    (c1, c2), (m1, m2_), (p1, p2) = servos
    period_ms, setpoint_us, cycle_us, setpoint_cpu_us = timing
    row[columns.SERVO_CMD.start :] = (
        c1, c2, m1, m2_, p1, p2, period_ms, log.code(px4_mode), armed, log.code(phase),
        log.code(";".join(faults)), time.time(),
        math.nan if setpoint_us is None else setpoint_us, cycle_us,
        math.nan if setpoint_cpu_us is None else setpoint_cpu_us,
    )  # fmt: skip
    log.commit()


class ControlCycle:
    """The per-pose work of one pickup (module docstring) and the state it carries from one
    cycle to the next.

    Parameters
    ----------
    config
        The companion's configuration.
    link, arm
        The MAVLink link (setpoints out, latest telemetry) and the arm task.
    control, mission, offboard, failsafe, report
        The flight's parts, shared with the app.
    q_stow
        The state with the arm stowed (the joints' target before the mission).
    loop_period
        The loop's period watch (replaced once preflight has measured the pose rate).
    ground_z, note, fault, on_fault, log
        The ground height [m] taken before arming; where events, raised faults, raised
        fault events and rows go (None: no rows).
    """

    def __init__(
        self,
        config: CompanionConfig,
        link: MavlinkLink,
        arm: ArmSupervisor,
        control: FlightControl,
        mission: PickupMission,
        offboard: Offboard,
        failsafe: FailsafeMonitor,
        report: MissionReport,
        *,
        q_stow: FloatArray,
        loop_period: LoopPeriodMonitor,
        ground_z: Callable[[], float],
        note: Callable[[str, str], None],
        fault: Callable[[Fault, str], None],
        on_fault: Callable[[FaultEvent], None],
        log: CycleLog | None,
    ) -> None:
        self.config = config
        self.link = link
        self.arm = arm
        self.control = control
        self.mission = mission
        self.offboard = offboard
        self.failsafe = failsafe
        self.report = report
        self.q_stow = q_stow
        """The state with the arm stowed (the joints' target before the mission)."""
        self.loop_period = loop_period
        self._ground_z = ground_z
        self._note = note
        self._fault = fault
        self._on_fault = on_fault
        self._log = log
        flight = config.flight
        self.assembler = StateAssembler.from_sensors(config.sensors)
        self.navigation = NavigationWatch(
            flight.nav_max_position_std_m,
            flight.nav_max_velocity_std_m_s,
            flight.nav_invalid_hold_s,
        )
        self.round_trip = RoundTripWatch(flight.max_round_trip_s)
        """The link's round trip (:mod:`companion.mission.round_trip`)."""
        self._timesync_taken: TimesyncReply | None = None
        """The last TIMESYNC reply taken (the link keeps the latest until the next)."""
        self.hold_bias = HoldBias(_HOLD_WINDOW_S)
        self._empty_m2_kg = config.nominal_theta.m2_kg
        """m2 of the empty link 2 [kg]."""
        self.carry = CarryWatch(
            CarryThresholds(
                flight.gripper_margin_rad, flight.gripper_current_a, flight.carry_mass_margin_kg
            ),
            config.nominal_theta.m2_kg,
        )
        """Whether the object is in the gripper (:mod:`companion.mission.carry_check`)."""
        self.authority = AuthorityLimits.from_config(config)
        """What the payload may ask of the thrust and the servos
        (:mod:`companion.mission.authority`)."""
        self.authority_watch = AuthorityWatch()
        self._grasp_holds: bool | None = None
        """The gripper's last reading in the grasp phase (None: none)."""
        self.figures = FlightFigures()
        self._t_us = -1
        self.t_s = math.nan
        """Vehicle time of the last control cycle [s]."""
        self._last_output: ControlOutput | None = None
        self._last_desired: DesiredState | None = None
        self._last_thrust_n = math.nan
        """Thrust PX4 flew over the last cycle [N] (NaN: PX4 flew its own)."""
        self._late_noted_s = -math.inf
        self._gap_noted_s = -math.inf
        self.collecting = True
        """Whether automatic garbage collection was on when this cycle began: no
        collection starts between a pose and its setpoint (young-generation collections
        measured 0.06-1.3 ms in flight, once 18 ms); it is enabled again once the setpoint
        is sent."""
        self.status_at_arm: object = NOT_ARMED
        """The latest HEARTBEAT when PX4 acknowledged the arm command."""
        self.servo_check: ServoCheck | None = None
        """The servos' torque-constant check on the ground, once started
        (:mod:`companion.mission.servo_check`)."""
        self.servos_checked = False
        """The servo check is over (fitted, or given up with a note)."""

    def mode(self) -> str | None:
        status = self.link.latest(VehicleStatus)
        return None if status is None else status.mode.name

    def armed(self) -> bool:
        """PX4 is armed: its latest HEARTBEAT says so, or it acknowledged the app's arm
        command after that HEARTBEAT (at 1 Hz they lag an arming by up to 1 s)."""
        status = self.link.latest(VehicleStatus)
        return status is self.status_at_arm or bool(status and status.armed)

    def observe(self, watches_height: bool) -> Observation:
        """What the flight sequence decides on, after the last cycle (the height only
        while ``watches_height``: the estimate is not copied every cycle of the mission)."""
        status = self.link.latest(VehicleStatus)
        ready = self.assembler.ready
        state = self.assembler.estimate if ready and watches_height else None
        return Observation(
            t_s=self.t_s,
            ready=ready,
            altitude_m=-math.inf if state is None else float(state.q[Z]),
            climb_rate_m_s=math.inf if state is None else float(state.q_dot[Z]),
            heartbeat=status,
            mission_done=self.mission.phase == Phase.DONE,
            left_offboard=self.offboard.left(status),
            link_lost=self.link.lost is not None,
            servos_checked=self.servos_checked,
        )

    def _mass_kg(self) -> float:
        """Mass of vehicle + arm the model believes [kg]."""
        return self.control.weight_n() / self.config.environment.gravity_m_s2

    def start_mission(self) -> None:
        """PX4 acknowledged OFFBOARD (it flies the streamed setpoint from that moment):
        the mission starts from the state the vehicle has, the trim from PX4's hold."""
        state = self.assembler.estimate
        q = state.q
        self.control.tilt.reset(float(q[PHI]), float(q[THETA]))
        self.mission.start(self.t_s, q, state.q_dot)
        if self.control.trim.gain > 0.0:
            self.control.trim.start(self.hold_bias.force_n(self._mass_kg()))
        self.control.trim_active = True
        self.figures.handover(self.t_s, q)
        self.offboard.accept(self.t_s)

    def attribute_gap(self, gap: GapTimes, late: int, dropped: int) -> None:
        """Count ``late`` cycles and ``dropped`` poses under their cause (:class:`GapCause`,
        from the control thread's last two cycles) and say why, at most once a second."""
        cause = gap.cause(self.loop_period.period_s)
        report = self.report
        for counts, n in (
            (report.late_cycles_by_cause, late),
            (report.poses_dropped_by_cause, dropped),
        ):
            if n > 0:
                counts[cause.value] = counts.get(cause.value, 0) + n
        if self.t_s - self._gap_noted_s < 1.0:
            return
        self._gap_noted_s = self.t_s
        what = " and ".join(
            f"{n} {noun}{'s' if n > 1 else ''}"
            for n, noun in ((late, "late cycle"), (dropped, "dropped pose"))
            if n > 0
        )

        def ms(value_s: float | None) -> str:
            return "?" if value_s is None else f"{value_s * 1e3:.1f} ms"

        self._note(
            "loop",
            f"{what}: {cause.value} (over the control thread's last two cycles it ran "
            f"{ms(gap.run_s)}, waited {ms(gap.cpu_wait_s)} for a CPU; datagrams waited up "
            f"to {ms(gap.socket_wait_s)} in the socket)",
        )

    def run(
        self, pose: VehiclePose, received: float, received_cpu: float, received_process: float
    ) -> None:
        """One control cycle on a new pose (see the module docstring), taken off the link
        at ``received`` (perf_counter), ``received_cpu`` (thread_time) and
        ``received_process`` (process_time) [s]."""
        if pose.time_usec <= self._t_us:
            return
        self._t_us = pose.time_usec
        t_s = self.t_s = pose.time_s
        period = self.loop_period.update(t_s)
        dt = period.period_s if period is not None else None
        if period is not None and period.late and t_s - self._late_noted_s >= 1.0:
            self._late_noted_s = t_s
            self._note("loop", f"late cycle: {period.period_s * 1e3:.1f} ms since the last")
        joints = self._sense(pose, dt)
        a = self.assembler
        if not a.ready or dt is None:
            return
        state = a.estimate
        command = None
        if self.offboard.flying:
            command = self._check_carry(
                t_s,
                self.mission.update(
                    t_s, state.q, self._confident(), self._payload_kg(self._last_output)
                ),
                float(state.q[Z]),
            )
            desired = command.desired
            self._apply_estimator(command)
        else:
            desired = self._hold_desired(state.q)
        out = self.control.step(dt, state, desired, self._applied_force(state.q, period, joints))
        self._servo_check_cycle(t_s, state.q, joints)
        self._last_output = out
        if self.offboard.flying:
            self._last_desired = out.desired
        sp, target = self._setpoints(state.q, out, desired)
        if self.offboard.stream in (Stream.OFF, Stream.HOLD) and self._in_hold():
            q = state.q
            force = thrust_force_world(
                float(q[PHI]), float(q[THETA]), float(q[PSI]), self.control.weight_n()
            )
            self.hold_bias.record(t_s, force[HORIZONTAL], state.q_dot[HORIZONTAL])
        setpoint_us = setpoint_cpu_us = None
        if target is not None:
            self.link.send_position_target(target, pose.time_boot_ms)
        elif sp is not None:
            self.link.send_setpoint(sp, pose.time_boot_ms)
        if sp is not None or target is not None:
            # CPU clock read first: its interval lies inside the wall clock's (read
            # the other way round at the start), so CPU <= latency holds per cycle.
            setpoint_cpu_us = (time.thread_time() - received_cpu) * 1e6
            setpoint_us = (time.perf_counter() - received) * 1e6
            self.report.setpoint_latency_us.append(setpoint_us)
            self.report.setpoint_cpu_us.append(setpoint_cpu_us)
        if self.collecting:
            gc.enable()  # garbage collection may run from here on, after the setpoint
        self._last_thrust_n = sp.thrust_n if sp is not None and self.offboard.flying else math.nan
        self._time_link(pose.time_usec)
        tau_cmd = self.arm.command(out.tau[JOINTS])
        if command is not None:
            self.arm.grip(command.gripper)
        cycle_us = (time.perf_counter() - received) * 1e6
        self.report.cycle_latency_us.append(cycle_us)
        self.report.control_cycles += 1
        if self.offboard.flying:
            self.watch_flight(t_s, state.q, out, period, command)
        phase = command.phase.value if command else self.offboard.stream.value
        timing = (dt * 1e3, setpoint_us, cycle_us, setpoint_cpu_us)
        self._log_row(t_s, state, out, sp, joints, phase, tau_cmd, timing)
        self.report.cycle_cpu_us.append((time.process_time() - received_process) * 1e6)

    def _time_link(self, pose_us: int) -> None:
        """Take the vehicle's latest TIMESYNC reply and send the next request when due
        (:mod:`companion.mission.round_trip`), after the setpoint; a link too slow for the
        loops in flight is the ``link_latency`` fault."""
        watch = self.round_trip
        reply = self.link.latest(TimesyncReply)
        if reply is not None and reply is not self._timesync_taken:
            self._timesync_taken = reply
            trip = watch.reply(reply.tc1_ns, reply.ts1_ns)
            if trip is not None and trip.fault is not None and self.offboard.flying:
                self._fault(Fault.LINK_LATENCY, trip.fault)
        ts1_ns = watch.request(pose_us)
        if ts1_ns is not None:
            self.link.send_timesync(ts1_ns)

    def _setpoints(
        self, q: FloatArray, out: ControlOutput, desired: DesiredState
    ) -> tuple[AttitudeThrustSetpoint | None, PositionSetpoint | None]:
        """This cycle's stream (:class:`~companion.mission.offboard.Offboard`): an attitude
        setpoint, or a position setpoint where PX4's position controller flies the vehicle
        (``px4_position``) and the stage is in the air; (None, None): nothing."""
        if self.control.px4_flies_position:
            target = self.offboard.position_setpoint(q, desired)
            if target is not None:
                return None, target
        sp = self.offboard.setpoint(out.setpoint, q, self.control.weight_n(), self.control.thrust)
        return sp, None

    # ------------------------------------------------------------ servo check

    def start_servo_check(self) -> None:
        """Hold the empty arm at the servo check's poses from now on (the vehicle on the
        ground, disarmed); too few poses within the limits end it at once, with a note."""
        arm = self.config.arm
        limits = [(j.position_min_rad, j.position_max_rad) for j in self.arm.bus.joints]
        stow = (float(self.q_stow[JOINTS][0]), float(self.q_stow[JOINTS][1]))
        poses = check_poses(limits, (arm.link1.length_m, arm.link2.length_m), stow)
        if len(poses) < MIN_POSES:
            self._note(
                "preflight",
                f"servo check skipped: {len(poses)} of its poses lie within the joint limits "
                f"and above the stowed arm (< {MIN_POSES}); the joints fly on the config's "
                "torque constants",
            )
            self.servos_checked = True
            return
        start = self.assembler.estimate.q[JOINTS]
        self.servo_check = ServoCheck(poses, start, self.t_s)
        self._note("preflight", f"servo check: the arm holds {len(poses)} poses on the ground")

    def _servo_check_cycle(
        self, t_s: float, q: FloatArray, joints: dict[str, JointState] | None
    ) -> None:
        check = self.servo_check
        if check is None or check.finished or joints is None:
            return
        names = self.arm.names
        check.update(
            t_s,
            [joints[n].position_rad for n in names],
            [joints[n].velocity_rad_s for n in names],
            q[TILT],
            [joints[n].torque_n_m for n in names],
        )
        if check.finished:
            self._finish_servo_check(check)

    def _finish_servo_check(self, check: ServoCheck) -> None:
        """Fit each joint's torque constant; fly on the fits that can be trusted, say which
        do not and why (:func:`~companion.mission.servo_check.fit_servo_check`)."""
        bus = self.arm.bus
        joints = bus.joints
        fits = fit_servo_check(
            check.readings,
            self.control.model,
            self.config.nominal_theta.as_tuple(),
            [j.torque_constant_n_m_per_a for j in joints],
            CURRENT_A_PER_UNIT,
        )
        measured, words = {}, []
        for joint, fit in zip(joints, fits, strict=True):
            config_kt = joint.torque_constant_n_m_per_a
            entry = self.report.servo_torque.setdefault(joint.name, {})
            if fit.problem is not None:
                words.append(f"{joint.name} not measured ({fit.problem}): config value")
                continue
            kt = fit.torque_constant_n_m_per_a
            measured[joint.name] = kt
            entry.update(
                source="measured",
                n_m_per_a=kt,
                config_n_m_per_a=config_kt,
                uncertainty=fit.relative_standard_error,
            )
            words.append(
                f"{joint.name} {kt:.3f} N m/A ({100 * (kt / config_kt - 1):+.1f} % of the "
                f"config's {config_kt:.3f}, +-{100 * fit.relative_standard_error:.1f} %)"
            )
        bus.set_torque_constants(measured)
        missed = f"; poses not reached: {check.missed}" if check.missed else ""
        self._note("preflight", f"servo check: {'; '.join(words)}{missed}")
        self.servos_checked = True

    def _sense(self, pose: VehiclePose, dt: float | None) -> dict[str, JointState] | None:
        """Feed one pose, the body rates, and the joint state the arm task read since the
        last cycle (fused with its age, bounded) to the state filter, after the navigation
        watch: an estimator reset restarts the position rows, a lasting invalid estimate is
        the navigation fault. Returns the joint state, or None if none came. A started
        filter takes the cycle in one call (:meth:`StateAssembler.cycle`)."""
        a = self.assembler
        check = self.navigation.update(pose.time_s, pose)
        rates = self.link.latest(BodyRates)
        omega = None if rates is None else rates.omega_flu_rad_s
        joints = eta = eta_dot = None
        age_s = 0.0
        taken = self.arm.take()
        if taken is not None:
            joints, age_s = taken
            age_s = min(age_s, _MAX_JOINT_AGE_S)
            names = self.arm.names
            eta = [joints[n].position_rad for n in names]
            eta_dot = [joints[n].velocity_rad_s for n in names]
        if dt is not None and a.ready and not check.reset:
            a.cycle(
                dt, pose.position_enu_m, pose.euler_zyx_rad(), pose.velocity_enu_m_s, omega,
                eta, eta_dot, age_s,
            )  # fmt: skip
        else:
            if dt is not None and a.ready:
                a.predict(dt)
            if check.reset and a.ready:
                a.reset_position(pose.position_enu_m)
                self.control.restart_estimator_inputs()
                self._note(
                    "navigation",
                    f"PX4's estimate jumped (reset counter {pose.reset_counter}): "
                    "the position filter starts again from it",
                )
            a.pose(pose.position_enu_m, pose.euler_zyx_rad())
            if pose.velocity_enu_m_s is not None and a.ready:
                a.velocity(pose.velocity_enu_m_s)
            if omega is not None:
                a.body_rates(omega)
            if eta is not None and eta_dot is not None:
                a.joints(eta, age_s)
                a.joint_rates(eta_dot, age_s)
        battery = self.link.latest(BatteryState)
        self.control.supply(None if battery is None else battery.voltage_v)
        if check.fault is not None and self.offboard.flying:
            self._fault(Fault.NAVIGATION, check.fault)
        return joints

    def _applied_force(
        self, q: FloatArray, period: CyclePeriod | None, joints: dict[str, JointState] | None
    ) -> FloatArray | Skip:
        """The force applied over the last cycle for the estimator, or why it is unknown:
        outside CONTROL PX4 flies its own thrust; a late cycle is not the period the
        estimator's forward-Euler step is tuned for. Where PX4's position controller flies
        the vehicle only the joints' torques are known (the estimator uses only them)."""
        if period is None or period.late:
            return Skip.LATE_CYCLE
        if not math.isfinite(self._last_thrust_n) and not self.control.px4_flies_position:
            return Skip.NO_FORCE
        if joints is None:
            return Skip.NO_SERVO_READ
        servo_tau = np.array([joints[n].torque_n_m for n in self.arm.names])
        return self.control.applied_force(q, self._last_thrust_n, servo_tau)

    def _in_hold(self) -> bool:
        """PX4 holds the vehicle in the air in its own Hold (before the handover)."""
        return self.mode() == "LOITER" and self.armed()

    def watch_flight(
        self,
        t_s: float,
        q: FloatArray,
        out: ControlOutput,
        period: CyclePeriod | None,
        command: MissionCommand | None,
    ) -> None:
        """Faults and figures of one OFFBOARD cycle: loop overrun, ground contact, the
        monitor's lasting conditions, tilt and tracking error."""
        if self.loop_period.overrun:
            watch = self.loop_period
            this_ms = math.nan if period is None else period.period_s * 1e3
            self._fault(
                Fault.LOOP_OVERRUN,
                f"{watch.long_cycles} control periods in {watch.window_s:g} s longer than "
                f"the {watch.max_period_s * 1e3:.1f} ms the velocity gains tolerate "
                f"(this one {this_ms:.0f} ms)",
            )
        landed = self.link.latest(LandedState)
        ground = self._ground_z() + self.config.flight.ground_margin_m
        if landed is not None and landed.on_ground:
            self._fault(Fault.GROUND_CONTACT, "PX4's land detector reports the vehicle landed")
        elif float(q[Z]) < ground:
            self._fault(
                Fault.GROUND_CONTACT,
                f"height {q[Z]:.2f} m below the take-off height + margin ({ground:.2f} m)",
            )
        sp = out.setpoint
        flown = not self.control.px4_flies_position  # else PX4 flies its own attitude
        for event in self.failsafe.update(
            t_s,
            on_bound=self._on_bound(out),
            tilt_saturated=flown and sp.tilt_saturated,
            thrust_saturated=flown and sp.thrust_saturated,
        ):
            self._on_fault(event)
        self.figures.update(t_s, q, command)

    def _hold_desired(self, q: FloatArray) -> DesiredState:
        """Outside CONTROL: the controller tracks where the vehicle is (its output is not
        flown) and the joints where the mission last put them (stowed before; the servo
        check's poses while it runs)."""
        target = np.array(q, dtype=float)
        target[TILT] = 0.0
        last = self._last_desired
        target[JOINTS] = self.q_stow[JOINTS] if last is None else last.q[JOINTS]
        rate, acceleration = np.zeros(N_Q), np.zeros(N_Q)
        check = self.servo_check
        if check is not None and not check.finished:
            target[JOINTS], rate[JOINTS], acceleration[JOINTS] = check.target(self.t_s)
        return DesiredState(target, rate, acceleration)

    def _check_carry(self, t_s: float, command: MissionCommand, z_m: float) -> MissionCommand:
        """Watch the gripper from the grasp to the release and whether the object is carried
        (:mod:`companion.mission.carry_check`), and from the end of the grasp through the
        lift's first centimetres whether it can be (:mod:`companion.mission.authority`;
        ``z_m``: the base's height [m]); an object not carried, or refused, abandons the
        pickup: this cycle's command is the mission's way home."""
        phase, arm = command.phase, self.arm
        if command.phase_changed and phase in (Phase.GRASP, Phase.RELEASE):
            arm.watch_gripper(phase == Phase.GRASP)
        reading = arm.take_gripper()
        gripper = self.config.arm_bus.gripper if self.config.arm_bus else None
        holds = None
        if reading is not None and gripper is not None:
            holds = gripper_holds(
                reading.position_rad,
                reading.current_a,
                gripper.open_position_rad,
                gripper.closed_position_rad,
                self.carry.thresholds,
            )
        verdict: CarryVerdict | None = None
        if phase == Phase.GRASP and holds is not None:
            self._grasp_holds = holds
        elif command.phase_changed and phase == Phase.LIFT:
            verdict = self.carry.grasp(self._grasp_holds)
        if verdict is None and self.mission.weighing(z_m):
            verdict = self._beyond_authority(t_s)
        if verdict is None and carrying(phase) and not command.phase_changed:
            if holds is not None:
                verdict = self.carry.gripper(holds)
            out = self._last_output
            if verdict is None and out is not None and self.config.flight.carry_check_estimate:
                verdict = self.carry.estimate(float(out.estimate.theta[0]), self._confident())
        if verdict is None:
            return command
        arm.watch_gripper(False)
        self.report.faults.append(
            {
                "t_s": t_s,
                "fault": verdict.outcome.value,
                "detail": verdict.detail,
                "reactions": [r.value for r in CARRY_REACTIONS[verdict.outcome]],
            }
        )
        self._note("fault", f"{verdict.outcome.value}: {verdict.detail}")
        return self.mission.abandon(t_s, verdict.outcome, verdict.detail)

    def _beyond_authority(self, t_s: float) -> CarryVerdict | None:
        """A payload whose estimated weight has needed more hover thrust or servo torque
        than ``[flight]`` allows for a while (:mod:`companion.mission.authority`); the lift's
        thrust only where it is the companion's (PX4's position controller flies its own,
        unknown here: the law's thrust, not flown, grew with the height lost while PX4's
        hover thrust estimator learnt the payload, and refused a 0.40 kg payload on PX4
        that the adaptive law carried on the same draw)."""
        out = self._last_output
        if out is None:
            return None
        control = self.control
        flown = out.setpoint.thrust_relative if not control.px4_flies_position else None
        why = payload_authority(
            control.model,
            control.thrust.max_thrust_n,
            self.authority,
            float(out.estimate.theta[0]),
            self.config.nominal_theta.as_tuple(),
            self.mission.grasp_point_m,
            control.estimator.compensation_scale,
            self.mission.loaded_poses(self._payload_kg(out)),
        ) or (None if flown is None else lift_thrust_reason(flown, self.authority))
        refused = self.authority_watch.update(t_s, why)
        return None if refused is None else CarryVerdict(Outcome.BEYOND_AUTHORITY, refused)

    def _confident(self) -> bool:
        return bool(self._last_output is not None and self._last_output.estimate.confident)

    def _payload_kg(self, out: ControlOutput | None) -> float:
        """The payload ``out`` estimates: m2 over the empty link 2's [kg] (0: no output yet)."""
        if out is None:
            return 0.0
        return float(out.estimate.theta[0]) - self._empty_m2_kg

    def _on_bound(self, out: ControlOutput) -> bool:
        low, high = self.config.estimator.m2_bounds_kg
        m2 = float(out.estimate.theta[0])
        return m2 <= low * (1 + 1e-6) or m2 >= high * (1 - 1e-6)

    def _apply_estimator(self, command: MissionCommand) -> None:
        """The mission's word on the estimator: restart, reset to the empty arm, hold,
        calibrate the thrust scale or run (held while the estimate sits on its bound, never
        resumed after an abort)."""
        est = self.control.estimator
        if command.phase_changed:
            self._note("phase", command.phase.value)
            self.report.phases.append((self.t_s, command.phase.value))
            if command.phase == Phase.TO_PLACE and self._last_output is not None:
                self._record_estimate(self._last_output)
        if command.estimator == EstimatorAction.RESTART:
            est.reset(est.theta)
        elif command.estimator in (EstimatorAction.RESET_EMPTY, EstimatorAction.EMPTY):
            est.reset(self.config.estimator.initial_theta.as_tuple())
        hold = command.estimator in (
            EstimatorAction.FREEZE,
            EstimatorAction.EMPTY,
        ) or self.failsafe.has(Fault.ESTIMATE_BOUND)
        if hold:
            if not est.frozen:
                est.freeze()
        elif command.estimator == EstimatorAction.CALIBRATE:
            if not est.calibrating:
                est.calibrate()
        elif est.frozen and not self.failsafe.aborted:
            est.resume()

    def _record_estimate(self, out: ControlOutput) -> None:
        theta = out.estimate.theta
        empty = self.config.nominal_theta
        self.report.theta_hat = [float(v) for v in theta]
        self.report.payload_mass_kg = mass = self._payload_kg(out)
        self.report.payload_mass_std_kg = self.control.payload_mass_std_kg()
        self.report.thrust_scale = self.control.supply_summary()
        # Payload CoM along link 2: (m3 - m3_empty) / (m2 - m2_empty), a point mass.
        self.report.payload_com_m = (
            (float(theta[1]) - empty.m3_kg_m) / mass if mass > 1e-6 else None
        )
        self.report.confident = bool(out.estimate.confident)

    def _log_row(
        self,
        t_s: float,
        state,
        out: ControlOutput,
        sp: AttitudeThrustSetpoint | None,
        joints: dict[str, JointState] | None,
        phase: str,
        tau_cmd: FloatArray,
        timing: tuple[float, float | None, float, float | None],
    ) -> None:
        """One row of the flight log; ``timing`` is (period [ms], pose -> setpoint sent
        [us] or None, pose -> joint torques handed over [us], CPU time up to the setpoint
        [us] or None)."""
        if self._log is None:
            return
        names = self.arm.names
        nan = [math.nan] * len(names)
        torques = nan if joints is None else [joints[n].torque_n_m for n in names]
        positions = nan if joints is None else [joints[n].position_rad for n in names]
        log_cycle(
            self._log,
            t_s,
            state,
            out,
            sp,
            (tau_cmd, torques, positions),
            timing,
            px4_mode=self.mode() or "",
            armed=self.armed(),
            phase=phase,
            faults=[e.fault.value for e in self.failsafe.raised],
        )

    def finish_report(self) -> None:
        report = self.report
        report.late_cycles = self.loop_period.late_cycles
        report.longest_period_ms = self.loop_period.longest_period_s * 1e3
        estimator = self.control.estimator
        report.estimator_skipped_steps = estimator.skipped_steps
        report.estimator_skipped = {reason.value: n for reason, n in estimator.skipped.items()}
        report.navigation_resets = self.navigation.resets
        report.round_trip_ms = [t * 1e3 for t in self.round_trip.round_trips_s]
        self.figures.finish(report)
        report.phases = [(t, p.value) for t, p in self.mission.phase_log] or report.phases
        outcome = self.mission.outcome
        if outcome != Outcome.COMPLETED:
            report.outcome = outcome.value
        elif report.completed:
            report.outcome = Outcome.COMPLETED.value
        else:
            report.outcome = "aborted" if self.failsafe.aborted else "failed"

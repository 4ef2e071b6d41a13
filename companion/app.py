"""The flight application: a payload-pickup mission over MAVLink and the arm's servo bus.

Tasks (asyncio, one event loop):

- the MAVLink link's own reader, heartbeat and watchdog tasks (:mod:`companion.link`);
- the **control loop**: clocked by the vehicle's ODOMETRY stream, so a cycle runs on every
  new pose at the rate PX4 publishes it (measured at preflight: PX4 sends ODOMETRY no
  faster than its estimator, 125 Hz, whatever is asked), timestamped with the estimate's
  ``time_usec`` (a SITL faster than real time just makes the cycles come faster). Each
  cycle watches the navigation (:mod:`companion.navigation`), filters q, q_dot, q_ddot
  (pose, the autopilot's velocity, body rates, and the joint state the arm task read
  after the previous cycle, fused with its age), asks the mission for q_d, runs
  :class:`~companion.flight_control.FlightControl`, streams the setpoint of the current
  OFFBOARD stage, hands the joint torques to the arm task, and logs one row;
- the **arm task** (:class:`~companion.arm_supervisor.ArmSupervisor`): after each cycle it
  writes that cycle's joint torques (and a gripper action), then reads the joints (one
  Sync Read): the setpoint never waits for the bus;
- the **mission sequence**: preflight (streams, the vehicle's parameters against the
  config, the pose rate against the gains, a global origin, the arm), then the flight as
  the pure state machine :mod:`companion.flight_sequence` decides it (arm, PX4 take-off,
  the OFFBOARD handover, the pickup of :mod:`companion.mission`, PX4 landing and disarm,
  and each aborting fault's reactions): the app observes after every control cycle and
  carries out its commands.

The app is the composition of parts with one job each:

- :mod:`companion.px4_preflight`: what is asked of PX4 before arming;
- :mod:`companion.offboard`: the OFFBOARD handover as an explicit state (what is streamed:
  OFF, HOLD, CONTROL, LEVEL, GROUND; PX4 flies the last SET_ATTITUDE_TARGET the moment it
  accepts OFFBOARD, and its HEARTBEAT shows the mode up to 1 s later), and the force PX4's
  Hold needed, which the trim starts from;
- :mod:`companion.arm_supervisor`: the servo bus in its own task, its failures and its
  safe state;
- :mod:`companion.flight_control`: the control step the offline simulator runs too;
- :mod:`companion.mission_report`: the report and the flight figures.

Faults (:mod:`companion.failsafe`: each fault's reactions in one table) are raised by the
control loop and carried out by the sequence. Whether the object is carried (:mod:`companion.carry_check`: the gripper servo's
position and current, read from the grasp to the release, and the confident estimate) is
checked every cycle from the end of the grasp to the release; an object not carried
(``grasp_failed``, ``payload_lost``) ends the pickup where it is
(:meth:`~companion.mission.PickupMission.abandon`): climb, estimator back at the empty arm,
home, land; the report says which and ``run`` raises :class:`MissionError` after the
landing, so the mission never reports ``completed`` for an object it did not carry.

The generalized force handed to the estimator is the one applied over the last
cycle: the thrust commanded to PX4 along the measured attitude while the stream is
``CONTROL`` (PX4 flies it), and the servos' torque read-back; otherwise the reason it is
not known (:class:`~companion.estimation.Skip`).
"""

from __future__ import annotations

import asyncio
import gc
import math
import time
from collections.abc import Awaitable, Callable
from contextlib import closing
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import common as mavlink2

from arm_driver.bus import ArmBus, JointState
from arm_driver.errors import ArmDriverError, BusTimeoutError
from companion.arm_supervisor import BUS_FAILURES, SERVO_FAILURE_S, ArmSupervisor
from companion.carry_check import CarryThresholds, CarryVerdict, CarryWatch, gripper_holds
from companion.config import CompanionConfig
from companion.control import ControlRateError, DesiredState
from companion.coordinates import HORIZONTAL, JOINTS, N_Q, PHI, PSI, THETA, TILT, Z
from companion.estimation import Skip
from companion.failsafe import FailsafeMonitor, Fault, FaultEvent, Reaction
from companion.flight_control import ControlOutput, FlightControl, FlightControllerName
from companion.flight_sequence import (
    WAIT,
    AwaitLink,
    Command,
    FlightSequence,
    Landed,
    Note,
    Observation,
    OffboardLost,
    Px4Request,
    Request,
    SequenceFailed,
    SequenceTimes,
    Stage,
    StartMission,
    StreamTo,
)
from companion.flightlog import CycleRecord
from companion.link import LinkLost, LinkRegained, MavlinkLink
from companion.link.errors import CommandError, ParamError
from companion.link.px4_modes import px4_mode
from companion.link.telemetry import BodyRates, LandedState, VehiclePose, VehicleStatus
from companion.loop_period import CyclePeriod, CycleWindow, GapTimes, LoopPeriodMonitor
from companion.mission import (
    EstimatorAction,
    MissionCommand,
    Outcome,
    Phase,
    PickupMission,
    PickupPlan,
)
from companion.mission_report import FlightFigures, MissionReport, carrying
from companion.navigation import NavigationWatch
from companion.offboard import HoldBias, Offboard, Stream
from companion.px4_preflight import (
    PreflightError,
    ensure_global_origin,
    ensure_hold,
    measure_pose_period,
    read_vehicle_params,
    wait_ready_to_arm,
)
from companion.scheduling import ThreadTimes, enter_real_time
from companion.setpoints import AttitudeThrustSetpoint, ThrustModel
from companion.state import StateAssembler, thrust_force_world
from companion.vehicle_params import contradictions

__all__ = [
    "BUS_FAILURES",
    "SERVO_FAILURE_S",
    "MissionAborted",
    "MissionError",
    "MissionReport",
    "PickupApp",
    "Stream",
]

FloatArray = NDArray[np.float64]
_ODOMETRY_ID = mavlink2.MAVLINK_MSG_ID_ODOMETRY
_HOLD_WINDOW_S = 3.0
"""Vehicle time of PX4's hold before the handover the horizontal bias is taken over [s]."""
_MAX_JOINT_AGE_S = 0.05
"""Age [s] a joint state is fused with at most (a cycle that waited on the link)."""
_NO_REPLY_HINT = (
    "check the servos' power, ids and baud rate, and the USB adapter's latency timer "
    "(1 ms: README, 'Deploying on an onboard computer')"
)
"""Added to a preflight servo timeout: replies held by an FTDI adapter's default 16 ms
latency timer come after the bus's deadline as surely as none at all."""
_NOT_ARMED = object()
"""``PickupApp._status_at_arm`` before the app armed the vehicle."""


class MissionError(RuntimeError):
    """The mission could not start or go on (preflight, rejected command); one line."""


class MissionAborted(RuntimeError):
    """A failsafe ended the mission; the report says which."""


LogSink = Callable[[CycleRecord], None]
EventSink = Callable[[str, str, float], None]
"""(kind, detail, vehicle time [s]), as :meth:`FlightLogWriter.event`."""


class PickupApp:
    """One pickup mission; ``await app.run()`` returns the report.

    Parameters
    ----------
    config
        The companion's configuration: vehicle, arm, gains, estimator, sensors and flight
        settings (its type holds no truth about the payload or the plant).
    link
        An open MAVLink link with the vehicle detected.
    bus
        An open arm bus (joints eta1, eta2 and a gripper); its torque limits and watchdog
        timeout, final once it is open, are read here once.
    plan
        Mission geometry.
    controller
        ``"passivity"``, ``"nonadaptive"`` or ``"asmc"``.
    control_rate_hz
        Rate of the ODOMETRY stream asked of PX4 [Hz]; the loop runs at the rate that
        arrives (measured at preflight, the gains checked for it).
    log, event
        Where each cycle's row and each event (kind, text, vehicle time [s]) go.
    """

    def __init__(
        self,
        config: CompanionConfig,
        link: MavlinkLink,
        bus: ArmBus,
        plan: PickupPlan,
        *,
        controller: FlightControllerName = "passivity",
        control_rate_hz: float = 250.0,
        log: LogSink | None = None,
        event: EventSink | None = None,
        takeoff_timeout_s: float = 30.0,
        land_timeout_s: float = 60.0,
    ) -> None:
        if not control_rate_hz > 0.0:
            raise ValueError(f"control_rate_hz must be positive, got {control_rate_hz}")
        self.config = config
        self.link = link
        self.plan = plan
        self.control_rate_hz = control_rate_hz
        self.control = FlightControl(config, controller)
        self._q_stow = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, *plan.stow_joints_rad])
        self.control.check_rate(control_rate_hz, self._q_stow)
        self.loop_period = LoopPeriodMonitor(
            1.0 / control_rate_hz, self.control.max_period_s(self._q_stow)
        )
        self.mission = PickupMission(plan, config)
        self.failsafe = FailsafeMonitor()
        self.assembler = StateAssembler.from_sensors(config.sensors)
        flight = config.flight
        self.navigation = NavigationWatch(
            flight.nav_max_position_std_m,
            flight.nav_max_velocity_std_m_s,
            flight.nav_invalid_hold_s,
        )
        self.offboard = Offboard()
        """What the control loop streams to PX4 (the handover state)."""
        self.hold_bias = HoldBias(_HOLD_WINDOW_S)
        self.arm = ArmSupervisor(
            bus,
            vehicle_time=lambda: self.t_s,
            note=self._note,
            on_failure=lambda reason: self._fault(Fault.SERVO_BUS, reason),
        )
        self.carry = CarryWatch(
            CarryThresholds(
                flight.gripper_margin_rad, flight.gripper_current_a, flight.carry_mass_margin_kg
            ),
            config.nominal_theta.m2_kg,
        )
        """Whether the object is in the gripper (:mod:`companion.carry_check`)."""
        self._grasp_holds: bool | None = None
        """The gripper's last reading in the grasp phase (None: none)."""
        self.report = MissionReport(controller=controller)
        self.figures = FlightFigures()
        self._log = log or (lambda row: None)
        self._event = event or (lambda kind, detail, t_s: None)
        self.takeoff_timeout_s = takeoff_timeout_s
        self.land_timeout_s = land_timeout_s
        self.sequence = FlightSequence(
            SequenceTimes(
                plan.cruise_altitude_m,
                flight.settle_climb_rate_m_s,
                flight.settle_s,
                flight.handover_stream_s,
                takeoff_timeout_s,
                land_timeout_s,
            ),
            lambda ground_z_m: self.mission.unreachable(ground_z_m, flight.ground_margin_m),
        )
        """Arming, take-off, handover, landing and fault reactions (pure)."""
        self._mission_clock: tuple[float, float] | None = None
        """(process_time, perf_counter) [s] at the handover, for the CPU share of the
        mission."""
        self._t_us = -1
        self.t_s = math.nan
        """Vehicle time of the last control cycle [s]."""
        self._last_output: ControlOutput | None = None
        self._last_desired: DesiredState | None = None
        self._last_thrust_n = math.nan
        """Thrust PX4 flew over the last cycle [N] (NaN: PX4 flew its own)."""
        self._faults: asyncio.Queue[FaultEvent] = asyncio.Queue()
        self._late_noted_s = -math.inf
        self._gap_noted_s = -math.inf
        self._collecting = True
        """Whether automatic garbage collection was on when this cycle began: no
        collection starts between a pose and its setpoint (young-generation collections
        measured 0.06-1.3 ms in flight, once 18 ms); it is enabled again once the setpoint
        is sent."""
        self.control.estimator.freeze()  # until the mission flies in OFFBOARD
        self._tick = asyncio.Condition()
        """Notified after every control cycle (vehicle time advanced)."""
        self._status_at_arm: object = _NOT_ARMED
        """The latest HEARTBEAT when PX4 acknowledged the arm command."""

    # ----------------------------------------------------------------- events

    def _note(self, kind: str, text: str) -> None:
        self._event(kind, text, self.t_s)

    def _fault(self, fault: Fault, detail: str) -> None:
        event = self.failsafe.raise_fault(self.t_s, fault, detail)
        if event is not None:
            self._on_fault(event)

    def _on_fault(self, event: FaultEvent) -> None:
        self.report.faults.append(
            {
                "t_s": event.t_s,
                "fault": event.fault.value,
                "detail": event.detail,
                "reactions": [r.value for r in event.reactions],
            }
        )
        self._note("fault", f"{event.fault.value}: {event.detail}")
        if Reaction.FREEZE_ESTIMATE in event.reactions:
            self.control.estimator.freeze()
        if event.aborts:
            self._faults.put_nowait(event)

    # ------------------------------------------------------------------- run

    async def run(self) -> MissionReport:
        """Fly the mission; returns the report, raises MissionError or MissionAborted.
        The calling thread runs it under real-time scheduling where permitted
        (``flight.realtime_priority``, :mod:`companion.scheduling`), its policy given back
        at the end."""
        scheduling = enter_real_time(self.config.flight.realtime_priority)
        self.report.scheduling = scheduling.policy
        self._note("loop", scheduling.note or f"control loop under {scheduling.policy}")
        try:
            return await self._fly()
        finally:
            scheduling.restore()

    async def _fly(self) -> MissionReport:
        await self._preflight()
        control = asyncio.create_task(self._control_loop(), name="control-loop")
        arm = asyncio.create_task(self.arm.run(), name="arm")
        watch = asyncio.create_task(self._watch_link(), name="link-watch")
        try:
            sequence = asyncio.create_task(self._sequence(), name="mission-sequence")
            fault_wait = asyncio.create_task(self._faults.get(), name="failsafe")
            done, _ = await asyncio.wait(
                {sequence, fault_wait, control, arm}, return_when=asyncio.FIRST_COMPLETED
            )
            if control in done or arm in done:
                sequence.cancel()
                fault_wait.cancel()
                (control if control in done else arm).result()
                raise MissionError("the control loop stopped")
            if fault_wait in done or self.failsafe.aborted:
                sequence.cancel()
                await asyncio.gather(sequence, return_exceptions=True)
                event = await fault_wait
                await self._react(event)
                raise MissionAborted(f"{event.fault.value}: {event.detail}")
            fault_wait.cancel()
            try:
                sequence.result()
            except MissionError:
                if self._armed():
                    self._note("mode", "mission failed in the air: landing")
                    await self._land(Stream.LEVEL)
                raise
            mission = self.mission
            if mission.outcome != Outcome.COMPLETED:
                raise MissionError(
                    f"{mission.outcome.value}: {mission.outcome_detail}; flew home and landed"
                )
            self.report.completed = True
            return self.report
        finally:
            self.offboard.to(Stream.OFF)
            for task in (control, arm, watch):
                task.cancel()
            await asyncio.gather(control, arm, watch, return_exceptions=True)
            self._finish_report()

    # ------------------------------------------------------------- preflight

    async def _preflight(self) -> None:
        """Checks before arming (:mod:`companion.px4_preflight`): the vehicle's parameters
        fit the config, the pose stream comes fast enough for the gains, the vehicle is on
        the ground, disarmed, has a global origin and is ready to arm in Hold, the joints
        answer."""
        link = self.link
        try:
            await link.set_message_interval(_ODOMETRY_ID, self.control_rate_hz)
            await link.set_message_interval(mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 5.0)
            await self._check_vehicle_params()
            await self._check_pose_rate()
            landed = link.latest(LandedState)
            if landed is not None and not landed.on_ground:
                raise PreflightError(f"the vehicle is not on the ground ({landed.name})")
            status = link.latest(VehicleStatus)
            if status is not None and status.armed:
                raise PreflightError("the vehicle is already armed")
            await ensure_global_origin(link, self.config.flight.global_origin_deg_m, self._note)
            await ensure_hold(link, self._note)
            await wait_ready_to_arm(link)
        except PreflightError as exc:
            raise MissionError(f"preflight: {exc}") from None
        try:
            states = await self.arm.prepare()
        except BusTimeoutError as exc:
            raise MissionError(f"preflight: arm bus: {exc}; {_NO_REPLY_HINT}") from None
        except ArmDriverError as exc:
            raise MissionError(f"preflight: arm bus: {exc}") from None
        missing = set(self.arm.names) - set(states)
        if missing:
            raise MissionError(f"preflight: joints {sorted(missing)} did not answer")

    async def _check_vehicle_params(self) -> None:
        """Refuse a vehicle whose PX4 parameters contradict the config; take PX4's
        MPC_THR_MIN as the thrust floor."""
        params = await read_vehicle_params(self.link)
        problems = contradictions(params, self.config)
        for problem in problems[1:]:
            self._note("preflight", problem)
        if problems:
            raise PreflightError(problems[0])
        self.control.thrust = ThrustModel(
            self.control.thrust.max_thrust_n, params.thrust_min_relative
        )
        self.report.vehicle_params = params.describe()
        self._note("preflight", f"vehicle parameters: {self.report.vehicle_params}")

    async def _check_pose_rate(self) -> None:
        """The loop runs at the rate the pose stream arrives (PX4 publishes no faster than
        its estimator, whatever was asked): its mean period becomes the nominal period,
        and the gains are checked for it."""
        limit = self.loop_period
        try:
            period_s = await measure_pose_period(self.link)
        except PreflightError as exc:
            raise MissionError(f"preflight: {exc}") from None
        rate_hz = 1.0 / period_s
        self.report.control_rate_hz = rate_hz
        try:
            self.control.check_rate(rate_hz, self._q_stow)
        except ControlRateError as exc:
            raise MissionError(
                f"preflight: ODOMETRY arrives at {rate_hz:.0f} Hz (vehicle time): {exc}; "
                "raise the link's data rate (MAV_1_RATE, SER_TEL2_BAUD) or lower the gains k"
            ) from None
        if period_s > 1.2 * limit.period_s:
            self._note(
                "loop",
                f"ODOMETRY arrives at {rate_hz:.0f} Hz, not the {self.control_rate_hz:g} Hz "
                "asked (PX4 sends it at its estimator's rate): the loop runs at that rate",
            )
        self.loop_period = LoopPeriodMonitor(period_s, max(limit.max_period_s, period_s))
        self.report.late_cycles_by_cause.clear()  # the new monitor counts from zero

    # -------------------------------------------------------------- sequence

    async def _sequence(self) -> None:
        """The pickup from the ground to the landing (:mod:`companion.flight_sequence`)."""
        self.sequence.begin()
        await self._drive()

    async def _land(self, stream: Stream) -> None:
        """Land, streaming ``stream`` until PX4 acknowledges; until disarmed."""
        self.sequence.land(stream, self.t_s)
        await self._drive()

    async def _react(self, event: FaultEvent) -> None:
        """Carry out an aborting fault's reactions (the pickup has stopped)."""
        self.sequence.react(event, event.fault == Fault.LINK_LOST, self.t_s)
        await self._drive()

    async def _drive(self) -> None:
        """Carry out the sequence's commands, observing after every control cycle, until
        it is finished; its failure is a MissionError."""
        sequence = self.sequence
        while not sequence.finished:
            try:
                command = sequence.next(self._observe())
            except SequenceFailed as exc:
                raise MissionError(str(exc)) from None
            if command is WAIT:
                async with self._tick:
                    await self._tick.wait()
            elif isinstance(command, Px4Request):
                error = await self._ask_px4(command)
                sequence.done(self._observe(), error)
            elif isinstance(command, AwaitLink):
                sequence.done(self._observe(), await self._await_link(command.timeout_s))
            else:
                self._carry_out(command)
            if self._mission_clock is not None and sequence.stage != Stage.MISSION:
                cpu0, wall0 = self._mission_clock
                self.report.cpu_share = (time.process_time() - cpu0) / (time.perf_counter() - wall0)
                self._mission_clock = None

    def _carry_out(self, command: Command) -> None:
        """A command of the sequence that takes no time."""
        if isinstance(command, Note):
            self._note(command.kind, command.text)
        elif isinstance(command, StreamTo):
            self.offboard.to(command.stream)
        elif isinstance(command, StartMission):
            self._start_mission()
        elif isinstance(command, Landed):
            self.report.landed = self.report.disarmed = True
        elif isinstance(command, OffboardLost):
            self._fault(Fault.OFFBOARD_LOST, command.detail)

    async def _ask_px4(self, command: Px4Request) -> str | None:
        """Ask PX4 and wait for its acknowledgement, streaming ``command.stream`` meanwhile
        (OFF after it); returns PX4's refusal, None when accepted."""
        link, request = self.link, command.request
        unset = [0, 0, 0] + [math.nan] * 4  # params of NAV_TAKEOFF, NAV_LAND: PX4's own
        asks: dict[Request, Callable[[], Awaitable[Any]]] = {
            Request.ARM: link.arm,
            Request.TAKEOFF_ALTITUDE: lambda: link.param_set("MIS_TAKEOFF_ALT", command.value),
            Request.TAKEOFF: lambda: link.command_long(mavlink2.MAV_CMD_NAV_TAKEOFF, unset),
            Request.OFFBOARD: lambda: link.set_mode_px4(*px4_mode("OFFBOARD")),
            Request.HOLD: lambda: link.set_mode_px4(*px4_mode("LOITER")),
            Request.LAND: lambda: link.command_long(mavlink2.MAV_CMD_NAV_LAND, unset),
        }
        if request == Request.ARM:
            gc.freeze()  # collections in flight skip everything built before it
        if command.stream is not None:
            self.offboard.to(command.stream)
            self.control.trim_active = False
        try:
            await asks[request]()
        except (CommandError, ParamError) as exc:
            return str(exc)
        finally:
            if command.stream is not None:
                self.offboard.to(Stream.OFF)
        if request == Request.ARM:
            self._status_at_arm = link.latest(VehicleStatus)
        return None

    async def _await_link(self, timeout_s: float) -> str | None:
        """Wait until the link returns (None), at most ``timeout_s`` (why not)."""
        try:
            async with asyncio.timeout(timeout_s):
                with self.link.subscribe(LinkRegained) as regained:
                    await regained.get()
        except TimeoutError:
            return "timed out"
        return None

    def _start_mission(self) -> None:
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
        self._mission_clock = (time.process_time(), time.perf_counter())

    def _observe(self) -> Observation:
        """What the sequence decides on, after the last control cycle."""
        status = self.link.latest(VehicleStatus)
        ready = self.assembler.ready
        state = self.assembler.estimate if ready else None
        return Observation(
            t_s=self.t_s,
            ready=ready,
            altitude_m=-math.inf if state is None else float(state.q[Z]),
            climb_rate_m_s=math.inf if state is None else float(state.q_dot[Z]),
            heartbeat=status,
            mission_done=self.mission.phase == Phase.DONE,
            left_offboard=self.offboard.left(status),
            link_lost=self.link.lost is not None,
        )

    # ---------------------------------------------------------------- helpers

    def _mode(self) -> str | None:
        status = self.link.latest(VehicleStatus)
        return None if status is None else status.mode.name

    def _armed(self) -> bool:
        """PX4 is armed: its latest HEARTBEAT says so, or it acknowledged the app's arm
        command after that HEARTBEAT (at 1 Hz they lag an arming by up to 1 s)."""
        status = self.link.latest(VehicleStatus)
        return status is self._status_at_arm or bool(status and status.armed)

    def _mass_kg(self) -> float:
        """Mass of vehicle + arm the model believes [kg]."""
        return self.control.weight_n() / self.config.environment.gravity_m_s2

    async def _watch_link(self) -> None:
        """Raise link_lost when the link's watchdog reports a loss."""
        with self.link.subscribe(LinkLost) as losses:
            lost = await losses.get()
            self._fault(Fault.LINK_LOST, f"{lost.reason} silent for {lost.silent_s:.1f} s")

    # ----------------------------------------------------------- control loop

    async def _control_loop(self) -> None:
        window = CycleWindow()
        with (
            self.link.subscribe(VehiclePose, maxsize=4) as poses,
            closing(ThreadTimes()) as thread_times,
        ):
            while True:
                pose = await poses.get()
                received = time.perf_counter()
                received_cpu = time.thread_time()
                dropped = poses.dropped - self.report.poses_dropped
                self.report.poses_dropped = poses.dropped
                late = self.loop_period.late_cycles
                if self.link.lost is None:
                    self._collecting = gc.isenabled()
                    gc.disable()  # _cycle enables it again once the setpoint is sent
                    try:
                        self._cycle(pose, received, received_cpu)
                    finally:
                        if self._collecting:
                            gc.enable()
                    self.arm.due()  # write this cycle's torques, read for the next
                    async with self._tick:  # vehicle time advanced, whatever the cycle did
                        self._tick.notify_all()
                late = self.loop_period.late_cycles - late
                window.push(thread_times.read(), self.link.take_longest_socket_wait_s())
                if late > 0 or dropped > 0:
                    self._attribute_gap(window.gap(), late, dropped)

    def _attribute_gap(self, gap: GapTimes, late: int, dropped: int) -> None:
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

    def _cycle(self, pose: VehiclePose, received: float, received_cpu: float) -> None:
        """One control cycle on a new pose (see the module docstring), taken off the link
        at ``received`` (perf_counter) and ``received_cpu`` (thread_time) [s]."""
        if pose.time_usec <= self._t_us:
            return
        self._t_us = pose.time_usec
        t_s = self.t_s = pose.time_s
        period = self.loop_period.update(t_s)
        dt = period.period_s if period is not None else None
        if period is not None and period.late and t_s - self._late_noted_s >= 1.0:
            self._late_noted_s = t_s
            self._note("loop", f"late cycle: {period.period_s * 1e3:.1f} ms since the last")
        self._sense(pose, dt)
        joints = self._fuse_joints()
        a = self.assembler
        if not a.ready or dt is None:
            return
        state = a.estimate
        command = None
        if self.offboard.flying:
            command = self._check_carry(t_s, self.mission.update(t_s, state.q, self._confident()))
            desired = command.desired
            self._apply_estimator(command)
        else:
            desired = self._hold_desired(state.q)
        out = self.control.step(dt, state, desired, self._applied_force(state.q, period, joints))
        self._last_output = out
        if self.offboard.flying:
            self._last_desired = out.desired
        sp = self.offboard.setpoint(
            out.setpoint, state.q, self.control.weight_n(), self.control.thrust
        )
        if self.offboard.stream in (Stream.OFF, Stream.HOLD) and self._in_hold():
            q = state.q
            force = thrust_force_world(
                float(q[PHI]), float(q[THETA]), float(q[PSI]), self.control.weight_n()
            )
            self.hold_bias.record(t_s, force[HORIZONTAL], state.q_dot[HORIZONTAL])
        setpoint_us = setpoint_cpu_us = None
        if sp is not None:
            self.link.send_setpoint(sp, pose.time_boot_ms)
            setpoint_us = (time.perf_counter() - received) * 1e6
            setpoint_cpu_us = (time.thread_time() - received_cpu) * 1e6
            self.report.setpoint_latency_us.append(setpoint_us)
            self.report.setpoint_cpu_us.append(setpoint_cpu_us)
        if self._collecting:
            gc.enable()  # garbage collection may run from here on, after the setpoint
        self._last_thrust_n = sp.thrust_n if sp is not None and self.offboard.flying else math.nan
        tau_cmd = self.arm.command(out.tau[JOINTS])
        if command is not None:
            self.arm.grip(command.gripper)
        cycle_us = (time.perf_counter() - received) * 1e6
        self.report.cycle_latency_us.append(cycle_us)
        self.report.control_cycles += 1
        if self.offboard.flying:
            self._watch_flight(t_s, state.q, out, period, command)
        phase = command.phase.value if command else self.offboard.stream.value
        timing = (dt * 1e3, setpoint_us, cycle_us, setpoint_cpu_us)
        self._log_row(t_s, state, out, sp, joints, phase, tau_cmd, timing)

    def _sense(self, pose: VehiclePose, dt: float | None) -> None:
        """Feed one pose to the state filter, after the navigation watch: an estimator reset
        restarts the position rows, a lasting invalid estimate is the navigation fault."""
        a = self.assembler
        if dt is not None and a.ready:
            a.predict(dt)
        check = self.navigation.update(pose.time_s, pose)
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
        rates = self.link.latest(BodyRates)
        if rates is not None:
            a.body_rates(rates.omega_flu_rad_s)
        if check.fault is not None and self.offboard.flying:
            self._fault(Fault.NAVIGATION, check.fault)

    def _fuse_joints(self) -> dict[str, JointState] | None:
        """Fuse the joint state the arm task read since the last cycle, with its age
        (bounded); returns it, or None if none came."""
        taken = self.arm.take()
        if taken is None:
            return None
        joints, age_s = taken
        age_s = min(age_s, _MAX_JOINT_AGE_S)
        names = self.arm.names
        self.assembler.joints([joints[n].position_rad for n in names], age_s)
        self.assembler.joint_rates([joints[n].velocity_rad_s for n in names], age_s)
        return joints

    def _applied_force(
        self, q: FloatArray, period: CyclePeriod | None, joints: dict[str, JointState] | None
    ) -> FloatArray | Skip:
        """The force applied over the last cycle for the estimator, or why it is unknown:
        outside CONTROL PX4 flies its own thrust; a late cycle is not the period the
        estimator's forward-Euler step is tuned for."""
        if period is None or period.late:
            return Skip.LATE_CYCLE
        if not math.isfinite(self._last_thrust_n):
            return Skip.NO_FORCE
        if joints is None:
            return Skip.NO_SERVO_READ
        servo_tau = np.array([joints[n].torque_n_m for n in self.arm.names])
        return self.control.applied_force(q, self._last_thrust_n, servo_tau)

    def _in_hold(self) -> bool:
        """PX4 holds the vehicle in the air in its own Hold (before the handover)."""
        return self._mode() == "LOITER" and self._armed()

    def _watch_flight(
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
        ground = self.sequence.ground_z_m + self.config.flight.ground_margin_m
        if landed is not None and landed.on_ground:
            self._fault(Fault.GROUND_CONTACT, "PX4's land detector reports the vehicle landed")
        elif float(q[Z]) < ground:
            self._fault(
                Fault.GROUND_CONTACT,
                f"height {q[Z]:.2f} m below the take-off height + margin ({ground:.2f} m)",
            )
        sp = out.setpoint
        for event in self.failsafe.update(
            t_s,
            on_bound=self._on_bound(out),
            tilt_saturated=sp.tilt_saturated,
            thrust_saturated=sp.thrust_saturated,
        ):
            self._on_fault(event)
        self.figures.update(t_s, q, command)

    def _hold_desired(self, q: FloatArray) -> DesiredState:
        """Outside CONTROL: the controller tracks where the vehicle is (its output is not
        flown) and the joints where the mission last put them (stowed before)."""
        target = np.array(q, dtype=float)
        target[TILT] = 0.0
        last = self._last_desired
        target[JOINTS] = self._q_stow[JOINTS] if last is None else last.q[JOINTS]
        zero = np.zeros(N_Q)
        return DesiredState(target, zero, zero.copy())

    def _check_carry(self, t_s: float, command: MissionCommand) -> MissionCommand:
        """Watch the gripper from the grasp to the release and whether the object is carried
        (:mod:`companion.carry_check`); an object not carried abandons the pickup: this
        cycle's command is the mission's way home."""
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
        if verdict is None and carrying(phase) and not command.phase_changed:
            if holds is not None:
                verdict = self.carry.gripper(holds)
            out = self._last_output
            if verdict is None and out is not None and self.config.flight.carry_check_estimate:
                verdict = self.carry.estimate(float(out.estimate.theta[0]), self._confident())
        if verdict is None:
            return command
        arm.watch_gripper(False)
        reactions = ["reset_estimate", "return_home", "land"]
        if verdict.outcome == Outcome.GRASP_FAILED:
            reactions.insert(0, "open_gripper")
        self.report.faults.append(
            {
                "t_s": t_s,
                "fault": verdict.outcome.value,
                "detail": verdict.detail,
                "reactions": reactions,
            }
        )
        self._note("fault", f"{verdict.outcome.value}: {verdict.detail}")
        return self.mission.abandon(t_s, verdict.outcome, verdict.detail)

    def _confident(self) -> bool:
        return bool(self._last_output is not None and self._last_output.estimate.confident)

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
        self.report.payload_mass_kg = float(theta[0]) - empty.m2_kg
        # Payload CoM along link 2: (m3 - m3_empty) / (m2 - m2_empty), a point mass.
        mass = self.report.payload_mass_kg
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
        names = self.arm.names
        nan = [math.nan] * len(names)
        torques = nan if joints is None else [joints[n].torque_n_m for n in names]
        positions = nan if joints is None else [joints[n].position_rad for n in names]
        self._log(
            CycleRecord(
                t_vehicle_s=t_s,
                q=state.q,
                q_dot=state.q_dot,
                q_ddot=state.q_ddot,
                q_d=out.desired.q,
                theta_hat=out.estimate.theta,
                theta_excitation=out.estimate.excitation,
                theta_spread=out.estimate.spread,
                theta_confident=out.estimate.confident,
                theta_frozen=out.estimate.frozen,
                thrust_scale_hat=out.estimate.thrust_scale,
                tau=out.tau,
                setpoint=sp,
                servo_torque_cmd_n_m=tau_cmd,
                servo_torque_meas_n_m=torques,
                servo_position_rad=positions,
                loop_period_ms=timing[0],
                setpoint_latency_us=timing[1],
                cycle_latency_us=timing[2],
                setpoint_cpu_us=timing[3],
                px4_mode=self._mode() or "",
                armed=self._armed(),
                phase=phase,
                faults=[e.fault.value for e in self.failsafe.raised],
            )
        )

    def _finish_report(self) -> None:
        report = self.report
        report.late_cycles = self.loop_period.late_cycles
        report.longest_period_ms = self.loop_period.longest_period_s * 1e3
        estimator = self.control.estimator
        report.estimator_skipped_steps = estimator.skipped_steps
        report.estimator_skipped = {reason.value: n for reason, n in estimator.skipped.items()}
        report.navigation_resets = self.navigation.resets
        self.figures.finish(report)
        report.phases = [(t, p.value) for t, p in self.mission.phase_log] or report.phases
        outcome = self.mission.outcome
        if outcome != Outcome.COMPLETED:
            report.outcome = outcome.value
        elif report.completed:
            report.outcome = Outcome.COMPLETED.value
        else:
            report.outcome = "aborted" if self.failsafe.aborted else "failed"

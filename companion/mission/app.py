"""The flight application: a payload-pickup mission over MAVLink and the arm's servo bus.

:class:`PickupApp` is the asyncio shell (links, clock, tasks, log) around pure parts. Tasks
(one event loop):

- the MAVLink link's own reader, heartbeat and watchdog tasks (:mod:`companion.link`);
- the **control loop**: clocked by the vehicle's ODOMETRY stream, so a cycle runs on every
  new pose at the rate PX4 publishes it (measured at preflight: PX4 sends ODOMETRY no
  faster than its estimator, 125 Hz, whatever is asked), timestamped with the estimate's
  ``time_usec`` (a SITL faster than real time just makes the cycles come faster); what one
  cycle does is :mod:`companion.mission.cycle`;
- the **arm task** (:class:`~companion.mission.arm_supervisor.ArmSupervisor`): after each cycle it
  writes that cycle's joint torques (and a gripper action), then reads the joints (one
  Sync Read): the setpoint never waits for the bus;
- the **mission sequence**: preflight (:mod:`companion.mission.preflight`: the streams read
  asked and the others stopped, :mod:`companion.mission.streams`; the vehicle's parameters
  against the config, the pose rate against the gains, a global origin; then the arm),
  then the flight as the pure state machine
  :mod:`companion.mission.sequence` decides it (arm, PX4 take-off, the OFFBOARD handover,
  the pickup of :mod:`companion.mission.pickup`, PX4 landing and disarm (then the joints
  hold their pose on the servos' position loop), and each aborting
  fault's reactions): the app observes after every control cycle and carries out its
  commands.

Faults (:mod:`companion.mission.failsafe`: each fault's reactions in one table) are raised by the
control cycle, the arm task and the link watch, and carried out by the sequence. An object
not carried (``grasp_failed``, ``payload_lost``: :mod:`companion.mission.carry_check`) ends the
pickup where it is (:meth:`~companion.mission.pickup.PickupMission.abandon`): climb, estimator
back at the empty arm, home, land; the report says which and ``run`` raises
:class:`MissionError` after the landing, so the mission never reports ``completed`` for an
object it did not carry.
"""

from __future__ import annotations

import asyncio
import gc
import time
from collections.abc import Callable
from contextlib import closing, suppress

import numpy as np

from arm_driver.bus import ArmBus
from companion.config import CompanionConfig
from companion.control.flight import FlightControl, FlightControllerName
from companion.link import LinkLost, LinkRegained, MavlinkLink
from companion.link.errors import CommandError, LinkClosedError, ParamError
from companion.link.telemetry import VehiclePose, VehicleStatus
from companion.mission.announce import announcement
from companion.mission.arm_supervisor import BUS_FAILURES, SERVO_FAILURE_S, ArmSupervisor
from companion.mission.cycle import ControlCycle, CycleLog
from companion.mission.failsafe import FailsafeMonitor, Fault, FaultEvent, Reaction
from companion.mission.loop_period import CycleWindow, LoopPeriodMonitor
from companion.mission.offboard import Offboard, Stream
from companion.mission.pickup import (
    Outcome,
    PickupMission,
    PickupPlan,
)
from companion.mission.preflight import PreflightError, check_arm, check_vehicle
from companion.mission.px4_requests import ask_px4
from companion.mission.report import MissionReport
from companion.mission.scheduling import ThreadTimes, enter_real_time
from companion.mission.sequence import (
    WAIT,
    AwaitLink,
    CheckServos,
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
from companion.mission.servo_check import torque_constant_sources
from companion.mission.streams import OnboardStreams

__all__ = [
    "BUS_FAILURES",
    "SERVO_FAILURE_S",
    "MissionAborted",
    "MissionError",
    "MissionInterrupted",
    "MissionReport",
    "PickupApp",
    "Stream",
]


class MissionError(RuntimeError):
    """The mission could not start or go on (preflight, rejected command); one line."""


class MissionAborted(RuntimeError):
    """A failsafe ended the mission; the report says which."""


class MissionInterrupted(RuntimeError):
    """The user stopped the mission (Ctrl-C, SIGINT) at vehicle time ``t_s`` [s]; the
    arm's safe state and the logs were still written."""

    def __init__(self, t_s: float) -> None:
        super().__init__(f"interrupted at t = {t_s:.2f} s")
        self.t_s = t_s


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
        Where each cycle's row (a flight log's row to fill and commit; None: none) and each
        event (kind, text, vehicle time [s]) go.
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
        log: CycleLog | None = None,
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
        q_stow = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, *plan.stow_joints_rad])
        self.control.check_rate(control_rate_hz, q_stow)
        self.mission = PickupMission(plan, config)
        self.failsafe = FailsafeMonitor()
        self.offboard = Offboard()
        """What the control loop streams to PX4 (the handover state)."""
        self.arm = ArmSupervisor(
            bus,
            vehicle_time=lambda: self.t_s,
            note=self._note,
            on_failure=lambda reason: self._fault(Fault.SERVO_BUS, reason),
        )
        self.report = MissionReport(controller=controller)
        self._event = event or (lambda kind, detail, t_s: None)
        flight = config.flight
        self.sequence = FlightSequence(
            SequenceTimes.of_flight(
                flight, plan.cruise_altitude_m, takeoff_timeout_s, land_timeout_s
            ),
            lambda z_m, dz_m: self.mission.start_from(z_m, dz_m, flight.ground_margin_m),
        )
        """Arming, take-off, handover, landing and fault reactions (pure)."""
        self.cycle = ControlCycle(
            config,
            link,
            self.arm,
            self.control,
            self.mission,
            self.offboard,
            self.failsafe,
            self.report,
            q_stow=q_stow,
            loop_period=LoopPeriodMonitor(1.0 / control_rate_hz, self.control.max_period_s(q_stow)),
            ground_z=lambda: self.sequence.ground_z_m,
            note=self._note,
            fault=self._fault,
            on_fault=self._on_fault,
            log=log,
        )
        """What the control loop does on each pose."""
        self._mission_clock: tuple[float, float] | None = None
        """(process_time, perf_counter) [s] at the handover, for the CPU share of the
        mission."""
        self._mission_messages: tuple[int, float] | None = None
        """(messages received, vehicle time [s]) at the handover, for the link's rate over
        the mission."""
        self.streams = OnboardStreams(link, self._note)
        """The link's streams: set at preflight, given back to PX4's defaults at the end."""
        self._faults: asyncio.Queue[FaultEvent] = asyncio.Queue()
        self.control.estimator.freeze()  # until the mission flies in OFFBOARD
        self._tick = asyncio.Event()
        """Set after every control cycle (vehicle time advanced); the sequence clears it
        before it waits for the next."""

    @property
    def t_s(self) -> float:
        """Vehicle time of the last control cycle [s]."""
        return self.cycle.t_s

    @t_s.setter
    def t_s(self, value: float) -> None:
        self.cycle.t_s = value

    @property
    def loop_period(self) -> LoopPeriodMonitor:
        """The control loop's period watch."""
        return self.cycle.loop_period

    # ----------------------------------------------------------------- events

    def _note(self, kind: str, text: str) -> None:
        self._event(kind, text, self.t_s)
        told = announcement(kind, text)
        if told is not None:
            with suppress(LinkClosedError):  # at the end: the log has it
                self.link.send_message(self.link.mav.statustext_encode(*told))

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
        (``flight.realtime_priority``, :mod:`companion.mission.scheduling`), its policy given back
        at the end."""
        scheduling = enter_real_time(self.config.flight.realtime_priority)
        self.report.scheduling = scheduling.policy
        self._note("loop", scheduling.note or f"control loop under {scheduling.policy}")
        try:
            return await self._fly()
        finally:
            await self.streams.restore()  # also after an abort or Ctrl-C
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
                if self.cycle.armed():
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
            if self.report.landed and self.report.disarmed:
                await self.arm.hold_after_landing()
            self.cycle.finish_report()
            self.report.servo_retries = self.arm.bus.retried_replies
            self.report.servo_failures = self.arm.failed_transactions
            self.report.servo_rearmed = self.arm.rearmed

    # ------------------------------------------------------------- preflight

    async def _preflight(self) -> None:
        """Checks before arming: the vehicle's (:func:`~companion.mission.preflight.check_vehicle`),
        then the joints answer."""
        try:
            self.cycle.loop_period = await check_vehicle(
                self.link,
                self.config,
                self.control,
                self.report,
                self._note,
                rate_hz=self.control_rate_hz,
                q_stow=self.cycle.q_stow,
                loop_period=self.cycle.loop_period,
                streams=self.streams,
            )
            await check_arm(self.arm)
        except PreflightError as exc:
            raise MissionError(f"preflight: {exc}") from None
        sources = torque_constant_sources(self.config)
        self.report.servo_torque = sources.per_joint
        if sources.note is not None:
            self._note("preflight", sources.note)
        self.sequence.check_servos = sources.check

    # -------------------------------------------------------------- sequence

    async def _sequence(self) -> None:
        """The pickup from the ground to the landing (:mod:`companion.mission.sequence`)."""
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
                self._tick.clear()
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
                received0, t0_s = self._mission_messages or (0, self.t_s)
                if self.t_s > t0_s:
                    received = self._link_messages() - received0
                    self.report.link_messages_per_s = received / (self.t_s - t0_s)

    def _carry_out(self, command: Command) -> None:
        """A command of the sequence that takes no time."""
        if isinstance(command, Note):
            self._note(command.kind, command.text)
        elif isinstance(command, StreamTo):
            self.offboard.to(command.stream)
        elif isinstance(command, CheckServos):
            self.cycle.start_servo_check()
        elif isinstance(command, StartMission):
            self.cycle.start_mission()
            self._note("phase", self.mission.phase.value)  # the first: no change announces it
            self._mission_clock = (time.process_time(), time.perf_counter())
            self._mission_messages = (self._link_messages(), self.t_s)
        elif isinstance(command, Landed):
            self.report.landed = self.report.disarmed = True
        elif isinstance(command, OffboardLost):
            self._fault(Fault.OFFBOARD_LOST, command.detail)

    async def _ask_px4(self, command: Px4Request) -> str | None:
        """Ask PX4 and wait for its acknowledgement, streaming ``command.stream`` meanwhile
        (OFF after it); returns PX4's refusal, None when accepted."""
        request = command.request
        if request == Request.ARM:
            gc.freeze()  # collections in flight skip everything built before it
        if command.stream is not None:
            self.offboard.to(command.stream)
            self.control.trim_active = False
        try:
            await ask_px4(self.link, command)
        except (CommandError, ParamError) as exc:
            return str(exc)
        finally:
            if command.stream is not None:
                self.offboard.to(Stream.OFF)
        if request == Request.ARM:
            self.cycle.status_at_arm = self.link.latest(VehicleStatus)
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

    def _observe(self) -> Observation:
        """What the sequence decides on, after the last control cycle."""
        return self.cycle.observe(self.sequence.watches_height)

    # ---------------------------------------------------------------- helpers

    def _link_messages(self) -> int:
        """Messages received on the link so far (those outside pymavlink's dialect too)."""
        stats = self.link.stats
        return stats.messages_received + stats.unknown_messages

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
                received_process = time.process_time()
                dropped = poses.dropped - self.report.poses_dropped
                self.report.poses_dropped = poses.dropped
                late = self.loop_period.late_cycles
                if self.link.lost is None:
                    self.cycle.collecting = gc.isenabled()
                    gc.disable()  # _cycle enables it again once the setpoint is sent
                    try:
                        self.cycle.run(pose, received, received_cpu, received_process)
                    finally:
                        if self.cycle.collecting:
                            gc.enable()
                    self.arm.due()  # write this cycle's torques, read for the next
                    self._tick.set()  # vehicle time advanced, whatever the cycle did
                late = self.loop_period.late_cycles - late
                window.push(thread_times.read(), self.link.take_longest_socket_wait_s())
                if late > 0 or dropped > 0:
                    self.cycle.attribute_gap(window.gap(), late, dropped)

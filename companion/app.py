"""The flight application: a payload-pickup mission over MAVLink and the arm's servo bus.

Tasks (asyncio, one event loop):

- the MAVLink link's own reader, heartbeat and watchdog tasks (:mod:`companion.link`);
- the **control loop**: clocked by the vehicle's ODOMETRY stream, requested at the control
  rate, so a cycle runs on every new pose, timestamped with the vehicle's ``time_boot_ms``
  (a SITL faster than real time just makes the cycles come faster). Each cycle reads the
  joints (one Sync Read), filters q, q_dot, q_ddot, asks the mission for q_d, runs
  :class:`~companion.flight_control.FlightControl`, streams SET_ATTITUDE_TARGET when the
  mission flies in OFFBOARD, writes the joint torques, and logs one row;
- the **mission sequence**: preflight checks, arm, PX4 take-off, OFFBOARD handshake,
  the pickup (:mod:`companion.mission`), PX4 landing and disarm.

Faults (:mod:`companion.failsafe`) are raised by the control loop and carried out by the
sequence. The generalized force handed to the estimator is the one applied over the last
cycle: the thrust commanded to PX4 along the measured attitude, and the servos' torque
read-back.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from arm_driver.bus import ArmBus, BusFailedError, OperatingMode
from arm_driver.errors import ArmDriverError
from companion.config import Scenario
from companion.control import DesiredState
from companion.failsafe import FailsafeMonitor, Fault, FaultEvent, Reaction
from companion.flight_control import ControlOutput, FlightControl, FlightControllerName
from companion.flightlog import CycleRecord
from companion.link import LinkLost, LinkRegained, MavlinkLink
from companion.link.errors import CommandError
from companion.link.px4_modes import px4_mode
from companion.link.telemetry import BodyRates, LandedState, VehiclePose, VehicleStatus
from companion.loop_period import LoopPeriodMonitor
from companion.mission import EstimatorAction, GripperAction, Phase, PickupMission, PickupPlan
from companion.state import StateAssembler

__all__ = [
    "BUS_FAILURES",
    "SERVO_FAILURE_S",
    "MissionAborted",
    "MissionError",
    "MissionReport",
    "PickupApp",
]

_ODOMETRY_ID = mavlink2.MAVLINK_MSG_ID_ODOMETRY
_HANDOVER_STREAM_S = 1.0
"""Vehicle time the setpoint stream runs before OFFBOARD is requested [s] (PX4 wants
proof of life first)."""
SERVO_FAILURE_S = 0.3
"""Vehicle time over which every joint transaction failed that raises the servo_bus fault
[s] (at least three failures): a transient stall is ridden through with the servos holding
their last goal current; a servo that stopped answering is not. Open the bus with a
``max_consecutive_failures`` that covers this time (see :data:`BUS_FAILURES`)."""
BUS_FAILURES = 30
"""``max_consecutive_failures`` for the arm bus: more than the transactions in
:data:`SERVO_FAILURE_S`, so the app's fault, not the bus's, decides."""


class MissionError(RuntimeError):
    """The mission could not start or go on (preflight, rejected command); one line."""


class MissionAborted(RuntimeError):
    """A failsafe ended the mission; the report says which."""


@dataclass
class MissionReport:
    """What the mission did (written as the summary JSON)."""

    controller: str
    completed: bool = False
    phases: list[tuple[float, str]] = field(default_factory=list)
    faults: list[dict[str, Any]] = field(default_factory=list)
    payload_mass_kg: float | None = None
    payload_com_m: float | None = None
    theta_hat: list[float] | None = None
    confident: bool = False
    position_rms_with_payload_m: float | None = None
    landed: bool = False
    disarmed: bool = False
    control_cycles: int = 0
    cycle_latency_us: list[float] = field(default_factory=list)
    """Pose taken from the link -> joint torques written, per cycle [us]."""
    setpoint_latency_us: list[float] = field(default_factory=list)
    """Pose taken from the link -> SET_ATTITUDE_TARGET sent (joint read included) [us]."""
    cpu_share: float | None = None
    """Process CPU time / wall time over the OFFBOARD part (1.0 = one core)."""
    late_cycles: int = 0
    """Cycles later than 2.5 control periods (vehicle time); the estimator skipped them."""
    longest_period_ms: float | None = None
    """Longest vehicle-time gap between two control cycles [ms]."""
    estimator_skipped_steps: int = 0
    """Estimator steps skipped in flight (late cycles, no applied force known)."""

    def as_dict(self) -> dict[str, Any]:
        return {
            "controller": self.controller,
            "completed": self.completed,
            "phases": [{"t_s": t, "phase": p} for t, p in self.phases],
            "faults": self.faults,
            "payload_mass_kg": self.payload_mass_kg,
            "payload_com_along_link2_m": self.payload_com_m,
            "theta_hat": self.theta_hat,
            "estimate_confident": self.confident,
            "position_rms_with_payload_m": self.position_rms_with_payload_m,
            "landed": self.landed,
            "disarmed": self.disarmed,
            "control_cycles": self.control_cycles,
            "cycle_latency_us": _percentiles(self.cycle_latency_us),
            "setpoint_latency_us": _percentiles(self.setpoint_latency_us),
            "cpu_share_of_one_core": self.cpu_share,
            "late_cycles": self.late_cycles,
            "longest_period_ms": self.longest_period_ms,
            "estimator_skipped_steps": self.estimator_skipped_steps,
        }


def _percentiles(samples: list[float]) -> dict[str, float] | None:
    if not samples:
        return None
    arr = np.asarray(samples)
    return {"median": float(np.median(arr)), "p99": float(np.percentile(arr, 99))}


LogSink = Callable[[CycleRecord], None]
EventSink = Callable[[str, str, float], None]
"""(kind, detail, vehicle time [s]), as :meth:`FlightLogWriter.event`."""


class PickupApp:
    """One pickup mission; ``await app.run()`` returns the report.

    Parameters
    ----------
    scenario
        Vehicle, arm, gains and estimator settings (the companion's knowledge: the
        ``[payload]`` section is never read).
    link
        An open MAVLink link with the vehicle detected.
    bus
        An open arm bus (joints eta1, eta2 and a gripper); its torque limits and watchdog
        timeout, final once it is open, are read here once.
    plan
        Mission geometry.
    controller
        ``"passivity"`` or ``"nonadaptive"``.
    control_rate_hz
        Rate of the control loop (the ODOMETRY stream requested from PX4) [Hz].
    log, event
        Where each cycle's row and each event (time [s], kind, text) go.
    """

    def __init__(
        self,
        scenario: Scenario,
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
        self.scenario = scenario
        self.link = link
        self.bus = bus
        self.plan = plan
        self.control_rate_hz = control_rate_hz
        self.control = FlightControl(scenario, controller)
        q_stow = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, *plan.stow_joints_rad])
        self.control.check_rate(control_rate_hz, q_stow)
        self.loop_period = LoopPeriodMonitor(
            1.0 / control_rate_hz, self.control.max_period_s(q_stow)
        )
        self.mission = PickupMission(plan, scenario)
        self.failsafe = FailsafeMonitor()
        self.assembler = StateAssembler.from_sensors(scenario.sensors)
        self.report = MissionReport(controller=controller)
        self._log = log or (lambda row: None)
        self._event = event or (lambda kind, detail, t_s: None)
        self.takeoff_timeout_s = takeoff_timeout_s
        self.land_timeout_s = land_timeout_s
        self._joint_names = [j.name for j in bus.joints]
        self._torque_limits = np.array([bus.torque_limit_n_m(n) for n in self._joint_names])
        self._watchdog_s = bus.watchdog_s
        self._stow = np.array(plan.stow_joints_rad)
        self._streaming = False
        self._offboard = False
        self._mission_started = False
        self._hold: np.ndarray | None = None
        self._t_s = math.nan
        self._last_output: ControlOutput | None = None
        self._last_thrust_n = math.nan
        self._servo_failures = 0
        self._servo_failing_since = math.nan
        self._faults: asyncio.Queue[FaultEvent] = asyncio.Queue()
        self._payload_errors: list[float] = []
        self._late_noted_s = -math.inf
        self._bus_last_s = time.monotonic()
        """Wall-clock time of the last joint transaction [s] (the servos' watchdog clock)."""
        self.control.estimator.freeze()  # until the mission flies in OFFBOARD
        self._estimate_frozen = True
        self._tick = asyncio.Condition()
        """Notified after every control cycle (vehicle time advanced)."""

    # ----------------------------------------------------------------- events

    def _note(self, kind: str, text: str) -> None:
        self._event(kind, text, self._t_s)

    def _fault(self, fault: Fault, detail: str) -> None:
        event = self.failsafe.raise_fault(self._t_s, fault, detail)
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
            self._estimate_frozen = True
        if event.aborts:
            self._faults.put_nowait(event)

    # ------------------------------------------------------------------- run

    async def run(self) -> MissionReport:
        """Fly the mission; returns the report, raises MissionError or MissionAborted."""
        await self._preflight()
        control = asyncio.create_task(self._control_loop(), name="control-loop")
        watch = asyncio.create_task(self._watch_link(), name="link-watch")
        try:
            sequence = asyncio.create_task(self._sequence(), name="mission-sequence")
            fault_wait = asyncio.create_task(self._faults.get(), name="failsafe")
            done, _ = await asyncio.wait(
                {sequence, fault_wait, control}, return_when=asyncio.FIRST_COMPLETED
            )
            if control in done:
                sequence.cancel()
                fault_wait.cancel()
                control.result()
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
                    await self._land()
                raise
            self.report.completed = True
            return self.report
        finally:
            control.cancel()
            watch.cancel()
            await asyncio.gather(control, watch, return_exceptions=True)
            self._finish_report()

    async def _preflight(self) -> None:
        """Checks before arming: telemetry flows, on the ground, joints answer."""
        await self.link.set_message_interval(_ODOMETRY_ID, self.control_rate_hz)
        await self.link.set_message_interval(mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 5.0)
        await self._check_pose_rate()
        landed = self.link.latest(LandedState)
        if landed is not None and not landed.on_ground:
            raise MissionError(f"preflight: the vehicle is not on the ground ({landed.name})")
        status = self.link.latest(VehicleStatus)
        if status is not None and status.armed:
            raise MissionError("preflight: the vehicle is already armed")
        try:
            states = await self.bus.read_joint_states()
            await self.bus.set_operating_mode(OperatingMode.CURRENT)
            await self.bus.enable_torque()
            await self.bus.open_gripper()
            self._bus_last_s = time.monotonic()
        except ArmDriverError as exc:
            raise MissionError(f"preflight: arm bus: {exc}") from None
        missing = set(self._joint_names) - set(states)
        if missing:
            raise MissionError(f"preflight: joints {sorted(missing)} did not answer")

    async def _check_pose_rate(self) -> None:
        """The ODOMETRY stream that clocks the control loop comes fast enough: its mean
        period over 1 s of vehicle time is one the velocity gains tolerate. A stream
        slower than asked (PX4 publishes it no faster than its estimator) becomes the
        nominal period that late cycles are judged against."""
        limit = self.loop_period
        probe = LoopPeriodMonitor(limit.period_s, limit.max_period_s, window_s=1.0)
        last_s = -math.inf
        with self.link.subscribe(VehiclePose) as poses:
            try:
                async with asyncio.timeout(5.0):
                    pose = await poses.get()
            except TimeoutError:
                raise MissionError("preflight: no ODOMETRY from the vehicle within 5 s") from None
            try:
                async with asyncio.timeout(10.0):
                    while math.isnan(probe.mean_period_s):
                        t_s = pose.time_boot_ms / 1000.0
                        if t_s > last_s:
                            probe.update(t_s)
                            last_s = t_s
                        pose = await poses.get()
            except TimeoutError:
                raise MissionError(
                    "preflight: ODOMETRY stopped or its time_boot_ms did not advance 1 s in 10 s"
                ) from None
        mean_ms, max_ms = probe.mean_period_s * 1e3, limit.max_period_s * 1e3
        if mean_ms > max_ms:
            raise MissionError(
                f"preflight: ODOMETRY arrives every {mean_ms:.1f} ms (vehicle time); the "
                f"velocity gains need a control period below {max_ms:.1f} ms: raise the "
                "link's data rate (MAV_1_RATE, SER_TEL2_BAUD) or lower the gains k"
            )
        if mean_ms > 1.2 * limit.period_s * 1e3:
            self._note(
                "loop",
                f"ODOMETRY every {mean_ms:.1f} ms, slower than the "
                f"{self.control_rate_hz:g} Hz asked: the loop runs at the stream's rate",
            )
            self.loop_period = LoopPeriodMonitor(probe.mean_period_s, limit.max_period_s)

    async def _sequence(self) -> None:
        link, plan = self.link, self.plan
        self._note("mode", "arming")
        try:
            await link.arm()
            await self._set_param("MIS_TAKEOFF_ALT", plan.cruise_altitude_m)
            await link.command_long(mavlink2.MAV_CMD_NAV_TAKEOFF, [0, 0, 0] + [math.nan] * 4)
        except CommandError as exc:
            raise MissionError(f"take-off refused: {exc}") from None
        self._note("mode", "take-off")
        await self._wait_for(
            lambda: self._altitude() >= 0.9 * plan.cruise_altitude_m and self._mode() == "LOITER",
            self.takeoff_timeout_s,
            "take-off did not reach the cruise altitude",
        )
        pose = self.assembler.estimate.q.copy()
        self._hold = pose
        self.control.tilt.reset(float(pose[3]), float(pose[4]))
        self._streaming = True
        await self._wait_vehicle_time(_HANDOVER_STREAM_S)
        try:
            await link.set_mode_px4(*px4_mode("OFFBOARD"))
        except CommandError as exc:
            self._streaming = False
            raise MissionError(f"PX4 refused OFFBOARD: {exc}") from None
        await self._wait_for(
            lambda: self._mode() == "OFFBOARD", 2.0, "PX4 accepted OFFBOARD but did not enter it"
        )
        self._offboard = True
        self._note("mode", "OFFBOARD")
        self.mission.start(self._t_s, self.assembler.estimate.q)
        self._mission_started = True
        cpu0, wall0 = time.process_time(), time.perf_counter()
        async with self._tick:
            await self._tick.wait_for(
                lambda: self.mission.phase == Phase.DONE or self._mode() not in ("OFFBOARD", None)
            )
        self.report.cpu_share = (time.process_time() - cpu0) / (time.perf_counter() - wall0)
        if self.mission.phase != Phase.DONE:
            self._fault(Fault.OFFBOARD_LOST, f"PX4 left OFFBOARD (now {self._mode()})")
            return
        await self._land()

    async def _land(self) -> None:
        self._streaming = False
        self._offboard = False
        try:
            await self.link.command_long(mavlink2.MAV_CMD_NAV_LAND, [0, 0, 0] + [math.nan] * 4)
        except CommandError as exc:
            raise MissionError(f"PX4 refused to land: {exc}") from None
        self._note("mode", "landing")
        await self._wait_for(
            lambda: not self._armed(), self.land_timeout_s, "the vehicle did not land and disarm"
        )
        self.report.landed = True
        self.report.disarmed = True
        self._note("mode", "disarmed")

    async def _react(self, event: FaultEvent) -> None:
        """Carry out an aborting fault's reactions (the mission is already stopped)."""
        self._streaming = False
        self._offboard = False
        if Reaction.RELEASE_TO_PX4 in event.reactions:
            return
        if Reaction.HOLD_THEN_LAND in event.reactions:
            try:
                await self.link.set_mode_px4(*px4_mode("LOITER"))
                await self._wait_vehicle_time(2.0)
            except CommandError as exc:
                self._note("fault", f"hold refused: {exc}")
        if event.fault == Fault.LINK_LOST and self.link.lost is not None:
            try:
                async with asyncio.timeout(60.0):
                    with self.link.subscribe(LinkRegained) as regained:
                        await regained.get()
            except TimeoutError:
                raise MissionError("the MAVLink link did not return within 60 s") from None
            self._note("link", "regained")
        await self._land()

    # ---------------------------------------------------------------- helpers

    async def _set_param(self, name: str, value: float) -> None:
        link = self.link
        vehicle = link.vehicle
        assert vehicle is not None
        with link.subscribe("PARAM_VALUE") as values:
            for _ in range(3):
                link.send_message(
                    link.mav.param_set_encode(
                        vehicle.system_id,
                        vehicle.component_id,
                        name.encode(),
                        float(value),
                        mavlink2.MAV_PARAM_TYPE_REAL32,
                    )
                )
                try:
                    async with asyncio.timeout(0.5):
                        while True:
                            msg = await values.get()
                            if msg.param_id == name:
                                return
                except TimeoutError:
                    continue
        raise MissionError(f"parameter {name} could not be set")

    def _mode(self) -> str | None:
        status = self.link.latest(VehicleStatus)
        return None if status is None else status.mode.name

    def _armed(self) -> bool:
        status = self.link.latest(VehicleStatus)
        return bool(status and status.armed)

    def _altitude(self) -> float:
        return float(self.assembler.estimate.q[2]) if self.assembler.ready else -math.inf

    async def _wait_for(self, condition: Callable[[], bool], vehicle_s: float, what: str) -> None:
        """Wait until ``condition()`` holds, checked every control cycle, at most
        ``vehicle_s`` of vehicle time; raises MissionError on the time limit."""
        start = self._t_s

        def settled() -> bool:
            nonlocal start
            if not math.isfinite(start):
                start = self._t_s
            return condition() or self._t_s - start > vehicle_s

        async with self._tick:
            await self._tick.wait_for(settled)
        if not condition():
            raise MissionError(f"{what} within {vehicle_s:g} s")

    async def _wait_vehicle_time(self, seconds: float) -> None:
        start = self._t_s
        async with self._tick:
            await self._tick.wait_for(lambda: self._t_s - start >= seconds)

    async def _watch_link(self) -> None:
        """Raise link_lost when the link's watchdog reports a loss."""
        with self.link.subscribe(LinkLost) as losses:
            lost = await losses.get()
            self._fault(Fault.LINK_LOST, f"{lost.reason} silent for {lost.silent_s:.1f} s")

    # ----------------------------------------------------------- control loop

    async def _control_loop(self) -> None:
        with self.link.subscribe(VehiclePose, maxsize=4) as poses:
            while True:
                pose = await poses.get()
                received = time.perf_counter()
                if self.link.lost is not None:
                    continue
                await self._cycle(pose, received)
                async with self._tick:  # vehicle time advanced, whatever the cycle did
                    self._tick.notify_all()

    async def _cycle(self, pose: VehiclePose, received: float) -> None:
        t_s = pose.time_boot_ms / 1000.0
        if t_s <= self._t_s:  # False while _t_s is NaN (first cycle)
            return
        self._t_s = t_s
        period = self.loop_period.update(t_s)
        dt = period.period_s if period is not None else None
        if period is not None and period.late and t_s - self._late_noted_s >= 1.0:
            self._late_noted_s = t_s
            self._note("loop", f"late cycle: {period.period_s * 1e3:.1f} ms since the last")
        a = self.assembler
        if dt is not None and a.ready:
            a.predict(dt)
        a.pose(pose.position_enu_m, pose.euler_zyx_rad())
        rates = self.link.latest(BodyRates)
        if rates is not None:
            a.body_rates(rates.omega_flu_rad_s)
        if self.failsafe.has(Fault.SERVO_BUS):
            return  # the bus is in its safe state; PX4 lands the vehicle
        await self._rearm_after_silence()
        joints = await self._read_joints()
        if joints is None:
            return
        a.joints([joints[n].position_rad for n in self._joint_names])
        a.joint_rates([joints[n].velocity_rad_s for n in self._joint_names])
        if not a.ready or dt is None:
            return
        state = a.estimate
        command = None
        if self._mission_started:
            command = self.mission.update(t_s, state.q, self._confident())
            desired = command.desired
            await self._apply(command)
        else:
            desired = self._hold_desired(state.q)
        servo_tau = np.array([joints[n].torque_n_m for n in self._joint_names])
        # NaN (no force known) makes the estimator skip the step: before OFFBOARD, and on a
        # late cycle (its forward-Euler step is not tuned for the gap).
        known = (
            self.control.applied_force(state.q, self._last_thrust_n, servo_tau)
            if math.isfinite(self._last_thrust_n) and period is not None and not period.late
            else np.full(8, math.nan)
        )
        out = self.control.step(dt, state, desired, known)
        self._last_output = out
        sp = out.setpoint
        if self._streaming:
            self.link.send_setpoint(sp, pose.time_boot_ms)
            self.report.setpoint_latency_us.append((time.perf_counter() - received) * 1e6)
        # The thrust is known only while PX4 flies our setpoints (in OFFBOARD); before, PX4's
        # own position loop decides it, and the estimator must not see ours as applied.
        self._last_thrust_n = sp.thrust_n if self._streaming and self._offboard else math.nan
        tau_cmd = await self._write_joints(out.tau[6:8])
        self.report.cycle_latency_us.append((time.perf_counter() - received) * 1e6)
        self.report.control_cycles += 1
        if self._offboard:
            if self.loop_period.overrun:
                watch = self.loop_period
                self._fault(
                    Fault.LOOP_OVERRUN,
                    f"{watch.long_cycles} control periods in {watch.window_s:g} s longer than "
                    f"the {watch.max_period_s * 1e3:.1f} ms the velocity gains tolerate "
                    f"(this one {period.period_s * 1e3:.0f} ms)",
                )
            for event in self.failsafe.update(
                t_s,
                on_bound=self._on_bound(out),
                tilt_saturated=sp.tilt_saturated,
                thrust_saturated=sp.thrust_saturated,
            ):
                self._on_fault(event)
        if command is not None and _carrying(command.phase):
            self._payload_errors.append(float(np.linalg.norm(state.q[0:3] - desired.q[0:3])))
        phase = command.phase.value if command else "hold"
        self._log_row(t_s, state, out, joints, phase, tau_cmd)

    def _hold_desired(self, q: np.ndarray) -> DesiredState:
        hold = self._hold if self._hold is not None else q
        target = np.array(hold, dtype=float)
        target[3:5] = 0.0
        target[6:8] = self._stow
        zero = np.zeros(8)
        return DesiredState(target, zero, zero.copy())

    def _confident(self) -> bool:
        return bool(self._last_output is not None and self._last_output.estimate.confident)

    def _on_bound(self, out: ControlOutput) -> bool:
        low, high = self.scenario.estimator.m2_bounds_kg
        m2 = float(out.estimate.theta[0])
        return m2 <= low * (1 + 1e-6) or m2 >= high * (1 - 1e-6)

    async def _apply(self, command) -> None:
        est = self.control.estimator
        if command.phase_changed:
            self._note("phase", command.phase.value)
            self.report.phases.append((self._t_s, command.phase.value))
            if command.phase == Phase.TO_PLACE and self._last_output is not None:
                self._record_estimate(self._last_output)
        if command.estimator == EstimatorAction.RESTART:
            est.reset(est.theta)
        elif command.estimator == EstimatorAction.RESET_EMPTY:
            est.reset(self.scenario.estimator.initial_theta.as_tuple())
        frozen = command.estimator == EstimatorAction.FREEZE or self.failsafe.has(
            Fault.ESTIMATE_BOUND
        )
        if frozen and not self._estimate_frozen:
            est.freeze()
        elif not frozen and self._estimate_frozen and not self.failsafe.aborted:
            est.resume()
        self._estimate_frozen = frozen
        try:
            if command.gripper == GripperAction.CLOSE:
                await self.bus.close_gripper()
                self._note("gripper", "close")
            elif command.gripper == GripperAction.OPEN:
                await self.bus.open_gripper()
                self._note("gripper", "open")
        except ArmDriverError as exc:
            self._fault(Fault.SERVO_BUS, f"gripper: {exc}")

    def _record_estimate(self, out: ControlOutput) -> None:
        theta = out.estimate.theta
        empty = self.scenario.nominal_theta
        self.report.theta_hat = [float(v) for v in theta]
        self.report.payload_mass_kg = float(theta[0]) - empty.m2_kg
        # Payload CoM along link 2: (m3 - m3_empty) / (m2 - m2_empty), a point mass.
        mass = self.report.payload_mass_kg
        self.report.payload_com_m = (
            (float(theta[1]) - empty.m3_kg_m) / mass if mass > 1e-6 else None
        )
        self.report.confident = bool(out.estimate.confident)

    def _servo_failed(self, exc: ArmDriverError) -> None:
        self._servo_failures += 1
        if math.isnan(self._servo_failing_since):
            self._servo_failing_since = self._t_s
        lasting = self._t_s - self._servo_failing_since >= SERVO_FAILURE_S
        if self._servo_failures >= 3 and (lasting or isinstance(exc, BusFailedError)):
            self._fault(Fault.SERVO_BUS, str(exc))

    def _servo_ok(self) -> None:
        self._servo_failures = 0
        self._servo_failing_since = math.nan

    async def _rearm_after_silence(self) -> None:
        """Enable torque again if the bus was silent long enough (a link loss, a stall)
        for the servos' watchdog to have stopped the joints: they would refuse torque
        commands without a word. 0.8 of the timeout: the servos' clock is not ours."""
        watchdog_s = self._watchdog_s
        silent_s = time.monotonic() - self._bus_last_s
        if watchdog_s <= 0.0 or silent_s < 0.8 * watchdog_s:
            return
        try:
            await self.bus.enable_torque()
        except ArmDriverError as exc:
            self._servo_failed(exc)
            return
        finally:
            self._bus_last_s = time.monotonic()
        self._note(
            "servo",
            f"bus silent for {silent_s * 1e3:.0f} ms (servo watchdog "
            f"{watchdog_s * 1e3:.0f} ms): torque enabled again",
        )

    async def _read_joints(self):
        try:
            joints = await self.bus.read_joint_states()
        except ArmDriverError as exc:
            self._servo_failed(exc)
            return None
        finally:
            self._bus_last_s = time.monotonic()
        self._servo_ok()
        return joints

    async def _write_joints(self, tau: np.ndarray) -> np.ndarray:
        """Send the joint torques (clipped to the joints' limits); returns what was sent."""
        sent = np.clip(tau, -self._torque_limits, self._torque_limits)
        if self.failsafe.has(Fault.SERVO_BUS):
            return np.full(len(sent), math.nan)
        try:
            await self.bus.write_joint_torques(
                dict(zip(self._joint_names, sent.tolist(), strict=True))
            )
        except ArmDriverError as exc:
            self._servo_failed(exc)
            return np.full(len(sent), math.nan)
        finally:
            self._bus_last_s = time.monotonic()
        return sent

    def _log_row(
        self, t_s: float, state, out: ControlOutput, joints, phase: str, tau_cmd: np.ndarray
    ) -> None:
        names = self._joint_names
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
                theta_frozen=self._estimate_frozen,
                tau=out.tau,
                setpoint=out.setpoint if self._streaming else None,
                servo_torque_cmd_n_m=tau_cmd,
                servo_torque_meas_n_m=[joints[n].torque_n_m for n in names],
                servo_position_rad=[joints[n].position_rad for n in names],
                px4_mode=self._mode() or "",
                armed=self._armed(),
                phase=phase,
                faults=[e.fault.value for e in self.failsafe.raised],
            )
        )

    def _finish_report(self) -> None:
        self.report.late_cycles = self.loop_period.late_cycles
        self.report.longest_period_ms = self.loop_period.longest_period_s * 1e3
        self.report.estimator_skipped_steps = self.control.estimator.skipped_steps
        if self._payload_errors:
            errors = np.asarray(self._payload_errors)
            self.report.position_rms_with_payload_m = float(np.sqrt(np.mean(errors**2)))
        self.report.phases = [(t, p.value) for t, p in self.mission.phase_log] or self.report.phases


def _carrying(phase: Phase) -> bool:
    """Phases flown with the payload in the gripper."""
    return phase in (Phase.LIFT, Phase.EXCITE, Phase.TO_PLACE, Phase.LOWER)

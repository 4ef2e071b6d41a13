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
  OFFBOARD stage (below), hands the joint torques to the arm task, and logs one row;
- the **arm task**: after each cycle it writes that cycle's joint torques (and a gripper
  action), then reads the joints (one Sync Read): the setpoint never waits for the bus;
- the **mission sequence**: preflight (streams, the vehicle's parameters against the
  config, the pose rate against the gains, a global origin, the arm), arm, PX4 take-off,
  the OFFBOARD handover, the pickup (:mod:`companion.mission`), PX4 landing and disarm.

OFFBOARD stages (:class:`Stream`), explicit because PX4 flies the last SET_ATTITUDE_TARGET
the moment it accepts OFFBOARD, and its HEARTBEAT shows the mode up to 1 s later:

``OFF``      nothing is streamed; PX4 flies its own modes (take-off, hold, land).
``HOLD``     the handover: the attitude the vehicle has and the hover thrust of the model,
             fresh every cycle, so what PX4 flies at the switch is what it already does.
             DO_SET_MODE OFFBOARD goes out after ``flight.handover_stream_s`` of it.
``CONTROL``  from the COMMAND_ACK of OFFBOARD on (not the next heartbeat): the
             controller's setpoints; the mission starts from the pose at that moment.
``LEVEL``    the way out in the air: level at the current yaw with the model's hover
             thrust, until PX4 acknowledges the landing or hold command.
``GROUND``   the way out on the ground: level with the thrust floor (no tilt, no lift).

Faults (:mod:`companion.failsafe`) are raised by the control loop and carried out by the
sequence. The generalized force handed to the estimator is the one applied over the last
cycle: the thrust commanded to PX4 along the measured attitude while the stage is
``CONTROL`` (PX4 flies it), and the servos' torque read-back.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from arm_driver.bus import ArmBus, BusFailedError, OperatingMode
from arm_driver.errors import ArmDriverError, BusTimeoutError, CommunicationError
from companion.config import CompanionConfig
from companion.control import ControlRateError, DesiredState
from companion.failsafe import FailsafeMonitor, Fault, FaultEvent, Reaction
from companion.flight_control import ControlOutput, FlightControl, FlightControllerName
from companion.flightlog import CycleRecord
from companion.link import LinkLost, LinkRegained, MavlinkLink
from companion.link.errors import CommandError, ParamError
from companion.link.px4_modes import px4_mode
from companion.link.telemetry import BodyRates, LandedState, VehiclePose, VehicleStatus
from companion.loop_period import LoopPeriodMonitor
from companion.mission import EstimatorAction, GripperAction, Phase, PickupMission, PickupPlan
from companion.navigation import NavigationWatch
from companion.setpoints import AttitudeThrustSetpoint, ThrustModel, fixed_setpoint
from companion.state import StateAssembler, thrust_force_world
from companion.vehicle_params import OPTIONAL, REQUIRED, VehicleParams, contradictions

__all__ = [
    "BUS_FAILURES",
    "SERVO_FAILURE_S",
    "MissionAborted",
    "MissionError",
    "MissionReport",
    "PickupApp",
    "Stream",
]

_ODOMETRY_ID = mavlink2.MAVLINK_MSG_ID_ODOMETRY
SERVO_FAILURE_S = 0.3
"""Vehicle time over which every joint transaction failed that raises the servo_bus fault
[s] (at least three failures): a transient stall is ridden through with the servos holding
their last goal current; a servo that stopped answering is not. Open the bus with a
``max_consecutive_failures`` that covers this time (see :data:`BUS_FAILURES`)."""
BUS_FAILURES = 30
"""``max_consecutive_failures`` for the arm bus: more than the transactions in
:data:`SERVO_FAILURE_S`, so the app's fault, not the bus's, decides."""
_PREFLIGHT_BUS_ATTEMPTS = 3
"""Tries of the preflight's servo set-up; a reply that came late once is not a broken bus."""
_HOVER_WINDOW_S = 3.0
"""Vehicle time of PX4's hold before the handover the horizontal bias is taken over [s]."""
_MAX_JOINT_AGE_S = 0.05
"""Age [s] a joint state is fused with at most (a cycle that waited on the link)."""


class MissionError(RuntimeError):
    """The mission could not start or go on (preflight, rejected command); one line."""


class MissionAborted(RuntimeError):
    """A failsafe ended the mission; the report says which."""


class Stream(StrEnum):
    """What the control loop streams to PX4 (see the module docstring)."""

    OFF = "off"
    HOLD = "hold"
    CONTROL = "control"
    LEVEL = "level"
    GROUND = "ground"


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
    position_rms_m: float | None = None
    """Position error against the vehicle's own estimate over the OFFBOARD flight [m]."""
    max_tilt_deg: float | None = None
    """Largest measured tilt in OFFBOARD outside the excitation [deg]."""
    handover_tilt_deg: float | None = None
    """Largest change of the tilt in the 2 s after OFFBOARD was accepted [deg]."""
    landed: bool = False
    disarmed: bool = False
    control_cycles: int = 0
    control_rate_hz: float | None = None
    """Rate the pose stream arrived at (the loop's rate), measured at preflight [Hz]."""
    vehicle_params: str | None = None
    """The PX4 parameters the model depends on, as read at preflight."""
    navigation_resets: int = 0
    """Jumps of PX4's estimate (its reset counter) seen in flight."""
    cycle_latency_us: list[float] = field(default_factory=list)
    """Pose taken from the link -> joint torques written, per cycle [us]."""
    setpoint_latency_us: list[float] = field(default_factory=list)
    """Pose taken from the link -> SET_ATTITUDE_TARGET sent (joint read included) [us]."""
    cpu_share: float | None = None
    """Process CPU time / wall time over the OFFBOARD part (1.0 = one core)."""
    late_cycles: int = 0
    """Cycles later than 2.5 control periods (vehicle time); the estimator skipped them."""
    poses_dropped: int = 0
    """Poses the control loop was too slow to take (its queue of 4 overflowed): late cycles
    the companion caused itself, as opposed to gaps in the vehicle's stream."""
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
            "position_rms_m": self.position_rms_m,
            "max_tilt_outside_excitation_deg": self.max_tilt_deg,
            "handover_tilt_change_deg": self.handover_tilt_deg,
            "landed": self.landed,
            "disarmed": self.disarmed,
            "control_cycles": self.control_cycles,
            "control_rate_hz": self.control_rate_hz,
            "vehicle_params": self.vehicle_params,
            "navigation_resets": self.navigation_resets,
            "cycle_latency_us": _percentiles(self.cycle_latency_us),
            "setpoint_latency_us": _percentiles(self.setpoint_latency_us),
            "cpu_share_of_one_core": self.cpu_share,
            "late_cycles": self.late_cycles,
            "poses_dropped": self.poses_dropped,
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
        Vehicle, arm, gains, estimator and flight settings (the companion's knowledge:
        the ``[payload]`` section is never read).
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
        Rate of the ODOMETRY stream asked of PX4 [Hz]; the loop runs at the rate that
        arrives (measured at preflight, the gains checked for it).
    log, event
        Where each cycle's row and each event (time [s], kind, text) go.
    """

    def __init__(
        self,
        scenario: CompanionConfig,
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
        self._q_stow = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, *plan.stow_joints_rad])
        self.control.check_rate(control_rate_hz, self._q_stow)
        self.loop_period = LoopPeriodMonitor(
            1.0 / control_rate_hz, self.control.max_period_s(self._q_stow)
        )
        self.mission = PickupMission(plan, scenario)
        self.failsafe = FailsafeMonitor()
        self.assembler = StateAssembler.from_sensors(scenario.sensors)
        flight = scenario.flight
        self.navigation = NavigationWatch(
            flight.nav_max_position_std_m,
            flight.nav_max_velocity_std_m_s,
            flight.nav_invalid_hold_s,
        )
        self.report = MissionReport(controller=controller)
        self._log = log or (lambda row: None)
        self._event = event or (lambda kind, detail, t_s: None)
        self.takeoff_timeout_s = takeoff_timeout_s
        self.land_timeout_s = land_timeout_s
        self._joint_names = [j.name for j in bus.joints]
        self._torque_limits = np.array([bus.torque_limit_n_m(n) for n in self._joint_names])
        self._watchdog_s = bus.watchdog_s
        self._stow = np.array(plan.stow_joints_rad)
        self.stream = Stream.OFF
        """What the control loop streams to PX4 now."""
        self._offboard_since_s = math.nan
        """Vehicle time of the OFFBOARD acknowledgement [s]."""
        self._ground_z = math.nan
        """Height of the vehicle standing on the ground, taken at arming [m]."""
        self._t_us = -1
        self._t_s = math.nan
        self._last_output: ControlOutput | None = None
        self._last_desired: DesiredState | None = None
        self._last_thrust_n = math.nan
        self._joints: dict | None = None
        """Joint states read after the last cycle (fused by the next one), or None."""
        self._torque_command: np.ndarray | None = None
        """Joint torques of the last cycle, not written yet [N m]."""
        self._gripper_action: GripperAction | None = None
        self._arm_safe = False
        self._hover: deque[tuple[float, np.ndarray, np.ndarray]] = deque()
        """(vehicle time [s], horizontal thrust force, velocity), world x, y [N, m/s], while
        PX4 holds the vehicle in Hold before the handover (the last _HOVER_WINDOW_S)."""
        self._arm_due = asyncio.Event()
        """Set after each control cycle: the arm task writes and reads."""
        self._joints_read_s = math.nan
        """Wall-clock time of that read [s]."""
        self._servo_failures = 0
        self._servo_failing_since = math.nan
        self._faults: asyncio.Queue[FaultEvent] = asyncio.Queue()
        self._errors: list[tuple[float, bool]] = []
        """(position error [m], payload carried) per OFFBOARD cycle."""
        self._max_tilt = 0.0
        self._handover_tilt0 = math.nan
        self._handover_tilt = 0.0
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
        arm = asyncio.create_task(self._arm_loop(), name="arm")
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
            self.report.completed = True
            return self.report
        finally:
            self.stream = Stream.OFF
            for task in (control, arm, watch):
                task.cancel()
            await asyncio.gather(control, arm, watch, return_exceptions=True)
            self._finish_report()

    # ------------------------------------------------------------- preflight

    async def _preflight(self) -> None:
        """Checks before arming: the vehicle's parameters fit the config, the pose stream
        comes fast enough for the gains, the vehicle is on the ground, disarmed and has a
        global origin, the joints answer."""
        await self.link.set_message_interval(_ODOMETRY_ID, self.control_rate_hz)
        await self.link.set_message_interval(mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 5.0)
        await self._check_vehicle_params()
        await self._check_pose_rate()
        landed = self.link.latest(LandedState)
        if landed is not None and not landed.on_ground:
            raise MissionError(f"preflight: the vehicle is not on the ground ({landed.name})")
        status = self.link.latest(VehicleStatus)
        if status is not None and status.armed:
            raise MissionError("preflight: the vehicle is already armed")
        await self._ensure_global_origin()
        if self._mode() != "LOITER":
            # PX4 restores the mode selected before a landing (OFFBOARD after a mission),
            # where arming fails without a setpoint stream: arm in Hold.
            try:
                await self.link.set_mode_px4(*px4_mode("LOITER"))
            except CommandError as exc:
                raise MissionError(f"preflight: PX4 refused Hold (AUTO.LOITER): {exc}") from None
            self._note("preflight", f"mode {self._mode()} -> Hold (AUTO.LOITER) to arm in")
        await self._wait_ready_to_arm()
        for attempt in range(1, _PREFLIGHT_BUS_ATTEMPTS + 1):
            try:
                states = await self.bus.read_joint_states()
                # The joints may still hold torque from an earlier run (an abort leaves the
                # bus's safe state): limp for a moment on the ground, then current mode.
                await self.bus.disable_torque()
                await self.bus.set_operating_mode(OperatingMode.CURRENT)
                await self.bus.enable_torque()
                await self.bus.open_gripper()
                self._bus_last_s = time.monotonic()
                break
            except (BusTimeoutError, CommunicationError) as exc:
                if attempt == _PREFLIGHT_BUS_ATTEMPTS:
                    raise MissionError(f"preflight: arm bus: {exc}") from None
                self._note("preflight", f"arm bus: {exc}; trying again")
            except ArmDriverError as exc:
                raise MissionError(f"preflight: arm bus: {exc}") from None
        missing = set(self._joint_names) - set(states)
        if missing:
            raise MissionError(f"preflight: joints {sorted(missing)} did not answer")

    async def _check_vehicle_params(self) -> None:
        """Read the PX4 parameters the model depends on (:mod:`companion.vehicle_params`);
        refuse a vehicle that contradicts the config; take PX4's MPC_THR_MIN as the
        thrust floor."""
        values: dict[str, float | None] = {}
        for name in REQUIRED + OPTIONAL:
            try:
                values[name] = (await self.link.param_read(name, timeout_s=0.3))[0]
            except ParamError:
                values[name] = None
        try:
            params = VehicleParams.from_values(values)
        except KeyError as exc:
            raise MissionError(
                f"preflight: the vehicle does not answer parameter(s) {exc.args[0]} (not PX4?)"
            ) from None
        problems = contradictions(params, self.scenario)
        for problem in problems[1:]:
            self._note("preflight", problem)
        if problems:
            raise MissionError(f"preflight: {problems[0]}")
        self.control.thrust = ThrustModel(
            self.control.thrust.max_thrust_n, params.thrust_min_relative
        )
        self.report.vehicle_params = params.describe()
        self._note("preflight", f"vehicle parameters: {self.report.vehicle_params}")

    async def _check_pose_rate(self) -> None:
        """Measure the ODOMETRY stream over 1 s of vehicle time: the loop runs at the rate
        that arrives (PX4 publishes no faster than its estimator, whatever was asked), so
        its mean period becomes the nominal period, and the gains are checked for it."""
        limit = self.loop_period
        probe = LoopPeriodMonitor(limit.period_s, limit.max_period_s, window_s=1.0)
        last_us = -1
        with self.link.subscribe(VehiclePose) as poses:
            try:
                async with asyncio.timeout(5.0):
                    pose = await poses.get()
            except TimeoutError:
                raise MissionError("preflight: no ODOMETRY from the vehicle within 5 s") from None
            try:
                async with asyncio.timeout(10.0):
                    while math.isnan(probe.mean_period_s):
                        if pose.time_usec > last_us:
                            probe.update(pose.time_s)
                            last_us = pose.time_usec
                        pose = await poses.get()
            except TimeoutError:
                raise MissionError(
                    "preflight: ODOMETRY stopped or its time did not advance 1 s in 10 s"
                ) from None
        period_s = probe.mean_period_s
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

    async def _ensure_global_origin(self) -> None:
        """Without GPS (motion capture indoors) PX4 has no global origin, and refuses Hold
        and arming in it; set ``flight.global_origin_deg_m`` as the origin then."""
        if await self._global_origin() is not None:
            return
        lat, lon, alt = self.scenario.flight.global_origin_deg_m
        vehicle = self.link.vehicle
        assert vehicle is not None
        with self.link.subscribe("GPS_GLOBAL_ORIGIN") as origins:
            self.link.send_message(
                self.link.mav.set_gps_global_origin_encode(
                    vehicle.system_id, round(lat * 1e7), round(lon * 1e7), round(alt * 1e3), 0
                )
            )
            try:  # PX4 echoes the origin it took (measured: within about 1 s)
                async with asyncio.timeout(3.0):
                    await origins.get()
                echoed = True
            except TimeoutError:
                echoed = False
        if not echoed and await self._global_origin() is None:
            self._note("preflight", "the vehicle has no global origin and did not report ours")
            return
        self._note("preflight", f"global origin set to {lat:.7f}, {lon:.7f}, {alt:.1f} m")

    async def _wait_ready_to_arm(self, timeout_s: float = 20.0) -> None:
        """PX4's HEARTBEAT says MAV_STATE_STANDBY once its arming checks pass (UNINIT while
        they fail: the estimator still converging, a new global origin settling)."""
        with self.link.subscribe(VehicleStatus) as statuses:
            try:
                async with asyncio.timeout(timeout_s):
                    status = self.link.latest(VehicleStatus)
                    while status is None or status.system_status != mavlink2.MAV_STATE_STANDBY:
                        status = await statuses.get()
            except TimeoutError:
                state = "no heartbeat" if status is None else _mav_state(status.system_status)
                raise MissionError(
                    f"preflight: PX4 did not report ready to arm within {timeout_s:g} s "
                    f"({state}: its arming checks fail; see its messages on a ground station)"
                ) from None

    async def _global_origin(self) -> Any:
        """The vehicle's GPS_GLOBAL_ORIGIN (asked for with REQUEST_MESSAGE), or None."""
        with self.link.subscribe("GPS_GLOBAL_ORIGIN") as origins:
            try:
                await self.link.command_long(
                    mavlink2.MAV_CMD_REQUEST_MESSAGE,
                    [mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN],
                    timeout_s=0.3,
                    attempts=2,
                )
            except CommandError:
                return None
            try:
                async with asyncio.timeout(1.0):
                    return await origins.get()
            except TimeoutError:
                return None

    # -------------------------------------------------------------- sequence

    async def _sequence(self) -> None:
        link, plan, flight = self.link, self.plan, self.scenario.flight
        await self._wait_for(lambda: self.assembler.ready, 2.0, "no state estimate")
        self._ground_z = self._altitude()
        if plan.cruise_altitude_m - self._ground_z < 0.5:
            raise MissionError(
                f"the cruise altitude {plan.cruise_altitude_m:g} m is less than 0.5 m above "
                f"where the vehicle stands (z = {self._ground_z:.2f} m in PX4's local frame)"
            )
        self._note("mode", f"arming (standing at z = {self._ground_z:.2f} m)")
        try:
            await link.arm()
            # MIS_TAKEOFF_ALT is above home (where PX4 armed): the cruise altitude is in the
            # local frame, whose origin need not be on the ground.
            await link.param_set("MIS_TAKEOFF_ALT", plan.cruise_altitude_m - self._ground_z)
            await link.command_long(mavlink2.MAV_CMD_NAV_TAKEOFF, [0, 0, 0] + [math.nan] * 4)
        except (CommandError, ParamError) as exc:
            raise MissionError(f"take-off refused: {exc}") from None
        self._note("mode", "take-off")
        await self._wait_for(
            lambda: (
                self._altitude() - self._ground_z >= 0.9 * (plan.cruise_altitude_m - self._ground_z)
                and self._mode() == "LOITER"
            ),
            self.takeoff_timeout_s,
            "take-off did not reach the cruise altitude",
        )
        settled = self._holding(
            lambda: abs(self._climb_rate()) < flight.settle_climb_rate_m_s, flight.settle_s
        )
        await self._wait_for(settled, 20.0, "the vehicle did not stop climbing after take-off")
        await self._enter_offboard()
        cpu0, wall0 = time.process_time(), time.perf_counter()
        async with self._tick:
            await self._tick.wait_for(
                lambda: self.mission.phase == Phase.DONE or self._left_offboard()
            )
        self.report.cpu_share = (time.process_time() - cpu0) / (time.perf_counter() - wall0)
        if self.mission.phase != Phase.DONE:
            self._fault(Fault.OFFBOARD_LOST, f"PX4 left OFFBOARD (now {self._mode()})")
            return
        await self._land(Stream.LEVEL)

    async def _enter_offboard(self) -> None:
        """The handover: stream the hold setpoint, ask for OFFBOARD, close the loop on the
        acknowledgement (PX4 flies the streamed setpoint from that moment)."""
        self.stream = Stream.HOLD
        await self._wait_vehicle_time(self.scenario.flight.handover_stream_s)
        try:
            await self.link.set_mode_px4(*px4_mode("OFFBOARD"))
        except CommandError as exc:
            self.stream = Stream.OFF
            raise MissionError(f"PX4 refused OFFBOARD: {exc}") from None
        state = self.assembler.estimate
        q = state.q
        self.control.tilt.reset(float(q[3]), float(q[4]))
        self.mission.start(self._t_s, q, state.q_dot)
        if self.control.trim.gain > 0.0:
            self.control.trim.start(self._hover_bias_n())
        self.control.trim_active = True
        self._offboard_since_s = self._t_s
        self._handover_tilt0 = math.hypot(float(q[3]), float(q[4]))
        self.stream = Stream.CONTROL
        self._note("mode", "OFFBOARD accepted: the control loop flies the vehicle")

    async def _land(self, stream: Stream) -> None:
        """Hand the vehicle to PX4's AUTO.LAND, streaming ``stream`` until it acknowledges;
        wait until it has landed and disarmed."""
        await self._release(
            stream,
            lambda: self.link.command_long(mavlink2.MAV_CMD_NAV_LAND, [0, 0, 0] + [math.nan] * 4),
            "land",
        )
        self._note("mode", "landing")
        await self._wait_for(
            lambda: not self._armed(), self.land_timeout_s, "the vehicle did not land and disarm"
        )
        self.report.landed = True
        self.report.disarmed = True
        self._note("mode", "disarmed")

    async def _release(
        self, stream: Stream, command: Callable[[], Awaitable[Any]], what: str
    ) -> None:
        """The way out of OFFBOARD: stream the safe setpoint ``stream`` while ``command``
        waits for its acknowledgement, then stop streaming."""
        self.stream = stream
        self.control.trim_active = False
        try:
            await command()
        except CommandError as exc:
            raise MissionError(f"PX4 refused to {what}: {exc}") from None
        finally:
            self.stream = Stream.OFF

    async def _react(self, event: FaultEvent) -> None:
        """Carry out an aborting fault's reactions (the mission is already stopped)."""
        if Reaction.RELEASE_TO_PX4 in event.reactions:
            self.stream = Stream.OFF
            return
        safe = Stream.GROUND if Reaction.LEVEL_ON_GROUND in event.reactions else Stream.LEVEL
        if Reaction.HOLD_THEN_LAND in event.reactions:
            try:
                await self._release(
                    safe, lambda: self.link.set_mode_px4(*px4_mode("LOITER")), "hold"
                )
                await self._wait_vehicle_time(2.0)
            except MissionError as exc:
                self._note("fault", str(exc))
        if event.fault == Fault.LINK_LOST and self.link.lost is not None:
            self.stream = Stream.OFF
            try:
                async with asyncio.timeout(60.0):
                    with self.link.subscribe(LinkRegained) as regained:
                        await regained.get()
            except TimeoutError:
                raise MissionError("the MAVLink link did not return within 60 s") from None
            self._note("link", "regained")
        await self._land(safe)

    # ---------------------------------------------------------------- helpers

    def _mode(self) -> str | None:
        status = self.link.latest(VehicleStatus)
        return None if status is None else status.mode.name

    def _armed(self) -> bool:
        status = self.link.latest(VehicleStatus)
        return bool(status and status.armed)

    def _left_offboard(self) -> bool:
        """A heartbeat sent after PX4 had time to show OFFBOARD shows another mode."""
        status = self.link.latest(VehicleStatus)
        if status is None or status.time_boot_ms is None:
            return False
        after = status.time_boot_ms * 1e-3 - self._offboard_since_s
        return after > 0.2 and status.mode.name != "OFFBOARD"

    def _altitude(self) -> float:
        return float(self.assembler.estimate.q[2]) if self.assembler.ready else -math.inf

    def _climb_rate(self) -> float:
        return float(self.assembler.estimate.q_dot[2]) if self.assembler.ready else math.inf

    def _holding(self, condition: Callable[[], bool], hold_s: float) -> Callable[[], bool]:
        """A condition that holds once ``condition()`` has held for ``hold_s`` of vehicle
        time (checked every control cycle)."""
        since = math.nan

        def held() -> bool:
            nonlocal since
            if not condition():
                since = math.nan
                return False
            if math.isnan(since):
                since = self._t_s
            return self._t_s - since >= hold_s

        return held

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
                self.report.poses_dropped = poses.dropped
                if self.link.lost is not None:
                    continue
                await self._cycle(pose, received)
                self._arm_due.set()  # write this cycle's torques, read for the next
                async with self._tick:  # vehicle time advanced, whatever the cycle did
                    self._tick.notify_all()

    async def _cycle(self, pose: VehiclePose, received: float) -> None:
        if pose.time_usec <= self._t_us:
            return
        self._t_us = pose.time_usec
        t_s = self._t_s = pose.time_s
        period = self.loop_period.update(t_s)
        dt = period.period_s if period is not None else None
        if period is not None and period.late and t_s - self._late_noted_s >= 1.0:
            self._late_noted_s = t_s
            self._note("loop", f"late cycle: {period.period_s * 1e3:.1f} ms since the last")
        self._sense(pose, dt)
        joints = self._joints
        a = self.assembler
        if joints is not None:
            age_s = min(max(time.monotonic() - self._joints_read_s, 0.0), _MAX_JOINT_AGE_S)
            a.joints([joints[n].position_rad for n in self._joint_names], age_s)
            a.joint_rates([joints[n].velocity_rad_s for n in self._joint_names], age_s)
            self._joints = None  # each read is fused once
        if not a.ready or dt is None:
            return
        state = a.estimate
        command = None
        if self.stream == Stream.CONTROL:
            command = self.mission.update(t_s, state.q, self._confident())
            desired = command.desired
            self._apply_estimator(command)
        else:
            desired = self._hold_desired(state.q)
        servo_tau = (
            np.array([joints[n].torque_n_m for n in self._joint_names])
            if joints is not None
            else np.full(len(self._joint_names), math.nan)
        )
        # NaN (no force known) makes the estimator skip the step: outside CONTROL (PX4 flies
        # its own thrust), and on a late cycle (its forward-Euler step is not tuned for it).
        known = (
            self.control.applied_force(state.q, self._last_thrust_n, servo_tau)
            if math.isfinite(self._last_thrust_n) and period is not None and not period.late
            else np.full(8, math.nan)
        )
        out = self.control.step(dt, state, desired, known)
        self._last_output = out
        self._last_desired = out.desired if self.stream == Stream.CONTROL else self._last_desired
        sp = self._stream_setpoint(out, state.q)
        if self.stream in (Stream.OFF, Stream.HOLD) and self._mode() == "LOITER" and self._armed():
            self._record_hover(t_s, state)
        if sp is not None:
            self.link.send_setpoint(sp, pose.time_boot_ms)
            self.report.setpoint_latency_us.append((time.perf_counter() - received) * 1e6)
        self._last_thrust_n = (
            sp.thrust_n if sp is not None and self.stream == Stream.CONTROL else (math.nan)
        )
        tau_cmd = self._command_joints(out.tau[6:8])
        if command is not None and command.gripper != GripperAction.HOLD:
            self._gripper_action = command.gripper
        self.report.cycle_latency_us.append((time.perf_counter() - received) * 1e6)
        self.report.control_cycles += 1
        if self.stream == Stream.CONTROL:
            self._watch_flight(t_s, state.q, out, period, command)
        phase = command.phase.value if command else self.stream.value
        self._log_row(t_s, state, out, sp, joints, phase, tau_cmd)

    def _sense(self, pose: VehiclePose, dt: float | None) -> None:
        """Feed one pose to the state filter, after the navigation watch: an estimator reset
        restarts the position rows, a lasting invalid estimate is the navigation fault."""
        a = self.assembler
        if dt is not None and a.ready:
            a.predict(dt)
        check = self.navigation.update(pose.time_s, pose)
        if check.reset and a.ready:
            a.reset_position(pose.position_enu_m)
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
        if check.fault is not None and self.stream == Stream.CONTROL:
            self._fault(Fault.NAVIGATION, check.fault)

    def _record_hover(self, t_s: float, state) -> None:
        q = state.q
        force = thrust_force_world(float(q[3]), float(q[4]), float(q[5]), self.control.weight_n())
        self._hover.append((t_s, force[0:2], np.array(state.q_dot[0:2])))
        while t_s - self._hover[0][0] > _HOVER_WINDOW_S:
            self._hover.popleft()

    def _hover_bias_n(self) -> np.ndarray:
        """The horizontal force PX4's hold needed beside the vehicle's acceleration, world
        x, y [N]: its velocity integrator's answer to the same bias of the attitude estimate
        the trim learns (mean thrust force minus mass x mean acceleration over the window).
        Starting the trim from it keeps the handover from letting go of that force: without
        it the vehicle drifted 15-20 cm off at the switch on PX4 SIH (tilt change 6 deg)."""
        if len(self._hover) < 2:
            return np.zeros(2)
        (t0, _, v0), (t1, _, v1) = self._hover[0], self._hover[-1]
        force = np.mean([f for _, f, _ in self._hover], axis=0)
        if t1 - t0 <= 0.0:
            return force
        mass = self.control.weight_n() / self.scenario.environment.gravity_m_s2
        return force - mass * (v1 - v0) / (t1 - t0)

    def _stream_setpoint(self, out: ControlOutput, q: np.ndarray) -> AttitudeThrustSetpoint | None:
        """The setpoint of the current stage (:class:`Stream`); None: nothing to send."""
        thrust = self.control.thrust
        yaw = float(q[5])
        if self.stream == Stream.CONTROL:
            return out.setpoint
        if self.stream == Stream.HOLD:
            weight = self.control.weight_n()
            return fixed_setpoint(float(q[3]), float(q[4]), yaw, weight, thrust)
        if self.stream == Stream.LEVEL:
            return fixed_setpoint(0.0, 0.0, yaw, self.control.weight_n(), thrust)
        if self.stream == Stream.GROUND:
            return fixed_setpoint(0.0, 0.0, yaw, 0.0, thrust)
        return None

    def _watch_flight(self, t_s: float, q: np.ndarray, out: ControlOutput, period, command) -> None:
        """Faults and figures of one OFFBOARD cycle: loop overrun, ground contact, the
        monitor's lasting conditions, tilt and tracking error."""
        if self.loop_period.overrun:
            watch = self.loop_period
            self._fault(
                Fault.LOOP_OVERRUN,
                f"{watch.long_cycles} control periods in {watch.window_s:g} s longer than "
                f"the {watch.max_period_s * 1e3:.1f} ms the velocity gains tolerate "
                f"(this one {period.period_s * 1e3:.0f} ms)",
            )
        landed = self.link.latest(LandedState)
        ground = self._ground_z + self.scenario.flight.ground_margin_m
        if landed is not None and landed.on_ground:
            self._fault(Fault.GROUND_CONTACT, "PX4's land detector reports the vehicle landed")
        elif float(q[2]) < ground:
            self._fault(
                Fault.GROUND_CONTACT,
                f"height {q[2]:.2f} m below the take-off height + margin ({ground:.2f} m)",
            )
        sp = out.setpoint
        for event in self.failsafe.update(
            t_s,
            on_bound=self._on_bound(out),
            tilt_saturated=sp.tilt_saturated,
            thrust_saturated=sp.thrust_saturated,
        ):
            self._on_fault(event)
        tilt = math.hypot(float(q[3]), float(q[4]))
        if command is not None and command.phase != Phase.EXCITE:
            self._max_tilt = max(self._max_tilt, tilt)
        if t_s - self._offboard_since_s <= 2.0:
            self._handover_tilt = max(self._handover_tilt, abs(tilt - self._handover_tilt0))
        if command is not None:
            error = float(np.linalg.norm(q[0:3] - command.desired.q[0:3]))
            self._errors.append((error, _carrying(command.phase)))

    def _hold_desired(self, q: np.ndarray) -> DesiredState:
        """Outside CONTROL: the controller tracks where the vehicle is (its output is not
        flown) and the joints where the mission last put them (stowed before)."""
        target = np.array(q, dtype=float)
        target[3:5] = 0.0
        last = self._last_desired
        target[6:8] = self._stow if last is None else last.q[6:8]
        zero = np.zeros(8)
        return DesiredState(target, zero, zero.copy())

    def _confident(self) -> bool:
        return bool(self._last_output is not None and self._last_output.estimate.confident)

    def _on_bound(self, out: ControlOutput) -> bool:
        low, high = self.scenario.estimator.m2_bounds_kg
        m2 = float(out.estimate.theta[0])
        return m2 <= low * (1 + 1e-6) or m2 >= high * (1 - 1e-6)

    def _command_joints(self, tau: np.ndarray) -> np.ndarray:
        """Hand the joint torques (clipped to the joints' limits) to the arm task; returns
        what will be sent (NaN once the bus has failed)."""
        sent = np.clip(tau, -self._torque_limits, self._torque_limits)
        if self.failsafe.has(Fault.SERVO_BUS):
            return np.full(len(sent), math.nan)
        self._torque_command = sent
        return sent

    async def _arm_loop(self) -> None:
        """The arm's own task: after each control cycle it writes that cycle's joint torques
        (and a gripper action), then reads the joints for the next cycle. The vehicle's
        setpoint never waits for the servo bus (a Sync Read over the pty beside the SITL
        took 1-25 ms, a timed-out one with its retries longer), and the cycle fuses the
        latest joint state with its age."""
        while True:
            await self._arm_due.wait()
            self._arm_due.clear()
            if self.failsafe.has(Fault.SERVO_BUS):
                await self._safe_arm()
                continue
            await self._rearm_after_silence()
            torques, self._torque_command = self._torque_command, None
            if torques is not None:
                await self._write_joints(torques)
            action, self._gripper_action = self._gripper_action, None
            if action is not None:
                await self._move_gripper(action)
            joints = await self._read_joints()
            if joints is not None:
                self._joints, self._joints_read_s = joints, time.monotonic()

    async def _safe_arm(self) -> None:
        """Once, after the servo_bus fault: the bus's safe state (current-mode joints limp,
        the gripper holding). A torque command held after the controller lost the bus
        drives the joints on and on: measured in the SITL, a silenced servo kept its last
        goal current and the arm spun up until the vehicle could not land."""
        if self._arm_safe:
            return
        self._arm_safe = True
        await self.bus.enter_safe_state()
        self._note("servo", "bus marked failed: joints limp, gripper holding")

    def _apply_estimator(self, command) -> None:
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

    async def _move_gripper(self, action: GripperAction) -> None:
        try:
            if action == GripperAction.CLOSE:
                await self.bus.close_gripper()
                self._note("gripper", "close")
            elif action == GripperAction.OPEN:
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
        self,
        t_s: float,
        state,
        out: ControlOutput,
        sp: AttitudeThrustSetpoint | None,
        joints,
        phase: str,
        tau_cmd: np.ndarray,
    ) -> None:
        names = self._joint_names
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
                theta_frozen=self._estimate_frozen,
                tau=out.tau,
                setpoint=sp,
                servo_torque_cmd_n_m=tau_cmd,
                servo_torque_meas_n_m=torques,
                servo_position_rad=positions,
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
        report.estimator_skipped_steps = self.control.estimator.skipped_steps
        report.navigation_resets = self.navigation.resets
        if self._errors:
            errors = np.asarray([e for e, _ in self._errors])
            report.position_rms_m = float(np.sqrt(np.mean(errors**2)))
            carried = np.asarray([e for e, carrying in self._errors if carrying])
            if carried.size:
                report.position_rms_with_payload_m = float(np.sqrt(np.mean(carried**2)))
            report.max_tilt_deg = math.degrees(self._max_tilt)
            report.handover_tilt_deg = math.degrees(self._handover_tilt)
        report.phases = [(t, p.value) for t, p in self.mission.phase_log] or report.phases


def _mav_state(value: int) -> str:
    entry = mavlink2.enums["MAV_STATE"].get(value)
    return entry.name if entry is not None else f"MAV_STATE {value}"


def _carrying(phase: Phase) -> bool:
    """Phases flown with the payload in the gripper."""
    return phase in (Phase.LIFT, Phase.EXCITE, Phase.TO_PLACE, Phase.LOWER)

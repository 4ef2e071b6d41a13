"""The SITL vehicle process: one simulation clock driving world, autopilot, links and logs.

Every plant step (``1 / plant.rate_hz`` of simulation time) the runner

1. hands each MAVLink message received on the two links to the simulated autopilot
   (:class:`~sitl.px4.Px4Vehicle`) and sends its replies (the onboard link's faults act on
   both: a message lost, or held back by a latency spike, :mod:`sitl.vehicle.link_faults`);
   after a PARAM_SET the plant's attitude loop takes the new gains and THR_MDL_FAC,
2. takes the estimate (:class:`~sitl.vehicle.navigation.Navigation`, EKF2-like, motion capture
   or GPS aiding; a new one at each estimator output, held between) and asks the autopilot
   for the attitude/thrust setpoint of this step (``None``: disarmed) when its control may
   decide something: a new estimate, a message handled, a decision at the last step or a
   deadline of the commander; at the other steps the setpoint is held (the call would
   return it and change nothing),
3. steps the world under the servo bus lock (the bus thread reads and writes the same
   servo models),
4. sends the telemetry due at this time, if any (built only for the links someone listens
   on: on simulated time the GCS link usually has no one), hands what PX4 would print to
   its console to the caller and, at its rate, writes a truth-log line.

Time is simulation time everywhere (message rates, offboard loss, auto-disarm,
``time_boot_ms``); the wall clock only paces the loop at ``speed`` times real time. When
the loop cannot keep up, it runs as fast as it can and the real-time factor it reached is
reported. Step jitter is the lateness of each step's start behind its wall-clock slot.

On simulated time (``RunOptions.memory``), nothing paces the steps: the links and the servo
bus are in-memory channels, and :class:`~sitl.vehicle.lockstep.LockstepLoop` calls
:meth:`SitlVehicle.step_until` and :meth:`SitlVehicle.serve` whenever the companion in the
same process waits: a step, and the steps after it with nothing due but the world's, which
run without the rest of the step.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from collections.abc import Callable
from typing import IO

import numpy as np

from arm_driver.joint import GripperConfig, JointConfig
from bytelink.memory import MemoryChannel, MemoryEnd, create_channel
from companion.config import arm_bus_configs
from companion.coordinates import POSITION
from companion.frames import ned_from_enu
from sitl.physics import AttitudeSetpoint, Plant, make_plant
from sitl.physics.jsbsim import GearGeometry, JsbsimPlant
from sitl.px4 import (
    GeoReference,
    MavlinkEndpoint,
    Px4Mode,
    Px4Params,
    Px4Vehicle,
    attitude_loop_params,
    load_signing_key,
)
from sitl.px4.measurement import VehicleMeasurement
from sitl.scenario import Scenario, servo_watchdog_option
from sitl.servo import PtyServoBus, XM430Parameters, XM430Servo
from sitl.servo.memory_bus import MemoryServoBus
from sitl.stepping import WallPacer, step_loop
from sitl.vehicle.link_faults import DelayLine, LinkFaults
from sitl.vehicle.mission_phases import MissionPhases
from sitl.vehicle.navigation import Navigation
from sitl.vehicle.options import LOCKSTEP_WAIT_S, RunOptions, RunStats
from sitl.vehicle.servo_bus_faults import ServoBusFaults, bus_faults
from sitl.vehicle.world import World, WorldSettings

__all__ = [
    "SitlVehicle",
    "build_world",
    "simulated_servo_ids",
    "truth_record",
    "world_settings",
]

_SWITCH_INTERVAL_S = 2e-4
"""Interpreter switch interval while running [s] (the servo bus thread's reply latency)."""
_MAX_LAG_S = 0.25
"""Wall-clock lag behind schedule [s] after which the schedule is re-based (overrun)."""
_STREAMING_S = 0.1
"""With ``RunOptions.lockstep``: simulated time after a setpoint (:data:`_SETPOINTS`) during
which the client counts as streaming (the vehicle waits for its setpoints) [s]."""
_READ_POLL_S = 5e-5
"""How often a lockstep wait looks whether the client's Sync Read was answered [s]."""
_ODOMETRY = "ODOMETRY"
_SETPOINTS = ("SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED")
"""The setpoints a lockstep client answers a pose with (stamped with its ``time_boot_ms``)."""

DEFAULT_JOINTS = (
    JointConfig("eta1", 1, 1.78, 4.1, position_min_rad=-2.6, position_max_rad=0.6),
    JointConfig("eta2", 2, 1.78, 4.1, position_min_rad=-2.1, position_max_rad=2.1),
)
"""Servos of a scenario without an ``[arm_bus]`` section: XM430-W350 ids 1 and 2."""
DEFAULT_GRIPPER = GripperConfig(3, open_position_rad=0.785, closed_position_rad=-0.26)
"""Gripper servo of a scenario without an ``[arm_bus]`` section: id 3."""


def simulated_servo_ids(scenario: Scenario) -> tuple[int, ...]:
    """The ids of the servos :func:`build_world` puts on the simulated bus: the joints and
    the gripper of the ``[arm_bus]`` section, or ids 1, 2 and 3."""
    if scenario.arm_bus is None:
        return (*(j.servo_id for j in DEFAULT_JOINTS), DEFAULT_GRIPPER.servo_id)
    joints, gripper = arm_bus_configs(scenario.arm_bus)
    return (*(j.servo_id for j in joints), (gripper or DEFAULT_GRIPPER).servo_id)


def _plant(scenario: Scenario, options: RunOptions) -> Plant:
    """The truth plant of the chosen backend; JSBSim's gear at the world's gear height."""
    if options.physics == "jsbsim":
        gear = GearGeometry(height_m=world_settings(scenario).landing_gear_height_m)
        return JsbsimPlant.from_scenario(scenario, "underactuated", wind=options.wind, gear=gear)
    if options.physics != "pinocchio":
        raise ValueError(f"physics must be pinocchio or jsbsim, got {options.physics!r}")
    return make_plant(scenario, "pinocchio", "underactuated", wind=options.wind)


def _local_origin(world_origin: GeoReference, navigation: Navigation, world: World) -> GeoReference:
    """The geodetic position of the estimator's local origin: the world origin with motion
    capture, the vehicle's start with GPS (where EKF2 starts its local frame)."""
    if navigation.mode != "gps":
        return world_origin
    east, north, up = (float(v) for v in world.state.q[POSITION])
    lat, lon, alt = world_origin.global_from_ned(*ned_from_enu((east, north, up)))
    return GeoReference(lat, lon, alt)


def build_world(
    scenario: Scenario, options: RunOptions
) -> tuple[World, PtyServoBus | MemoryServoBus, list[JointConfig], GripperConfig]:
    """The world of a scenario (truth plant of ``options.physics``, ``[world]`` settings)
    with its arm's XM430 servos on a pseudo-terminal bus, or the in-memory line
    ``MEMORY-servos`` with ``options.memory`` (not started): the servos of the
    ``[arm_bus]`` section (the joints' torque constants times
    ``plant.servo_torque_constant_mismatch``), or ids 1, 2 and gripper 3. Returns (world,
    servo bus, joint configs, gripper config); ValueError for an arm bus without two
    joints."""
    if scenario.arm_bus is not None:
        joints, gripper = arm_bus_configs(scenario.arm_bus)
        if len(joints) != 2:
            raise ValueError(f"the simulated arm has 2 joints, arm_bus lists {len(joints)}")
    else:
        joints, gripper = DEFAULT_JOINTS, DEFAULT_GRIPPER
    gripper = gripper if gripper is not None else DEFAULT_GRIPPER
    mismatch = scenario.plant.servo_torque_constant_mismatch
    servos = {
        j.servo_id: XM430Servo(
            j.servo_id,
            XM430Parameters(torque_constant_n_m_per_a=j.torque_constant_n_m_per_a * mismatch),
        )
        for j in joints
    }
    servos[gripper.servo_id] = XM430Servo(gripper.servo_id)
    servo_bus: PtyServoBus | MemoryServoBus
    if options.memory is not None:
        servo_bus = MemoryServoBus(
            servos, faults=bus_faults(options), name=f"{options.memory}-servos"
        )
    else:
        servo_bus = PtyServoBus(servos, faults=bus_faults(options), step_servos=False)
    world = World(
        _plant(scenario, options),
        [(j, servos[j.servo_id]) for j in joints],
        (gripper, servos[gripper.servo_id]),
        world_settings(scenario),
    )
    return world, servo_bus, list(joints), gripper


def world_settings(scenario: Scenario) -> WorldSettings:
    """World settings of a scenario (``[world]``), or defaults: standing at the origin."""
    world = scenario.world
    if world is None:
        return WorldSettings()
    payload = world.payload_position_m
    east, north = world.start_position_m
    shoulder, elbow = world.start_joints_rad
    slip = world.payload_slip
    return WorldSettings(
        landing_gear_height_m=world.landing_gear_height_m,
        payload_position_m=None if payload is None else (payload[0], payload[1], payload[2]),
        grasp_tolerance_m=world.grasp_tolerance_m,
        jaw_point_m=world.jaw_point_m,
        start_position_m=(east, north, 0.0),
        start_yaw_rad=world.start_yaw_rad,
        start_joints_rad=(shoulder, elbow),
        jaw_closure_on_object=world.jaw_closure_on_object,
        grasp_fails=world.grasp_fails,
        payload_slip_after_s=None if slip is None else slip.after_grasp_s,
    )


class SitlVehicle:
    """Everything of one SITL vehicle; open it as a context manager, then :meth:`run`.

    Nothing is opened in the constructor: ``__enter__`` starts the servo bus and binds the
    MAVLink ports, ``__exit__`` (safe twice) closes them and the truth log.
    """

    def __init__(self, scenario: Scenario, options: RunOptions) -> None:
        self.scenario = scenario
        self.options = options
        self.world, self.servo_bus, self.joints, self.gripper = build_world(scenario, options)
        overrides = dict(scenario.world.autopilot_params) if scenario.world else {}
        params = Px4Params.from_scenario(scenario, overrides)
        rng = np.random.default_rng(options.seed)
        self.navigation = Navigation(
            scenario,
            rng,
            mode=options.navigation,  # type: ignore[arg-type]
            noise=options.noise,
            imu_rate_hz=params["IMU_INTEG_RATE"],
        )
        self.autopilot = Px4Vehicle(
            params,
            system_id=int(params["MAV_SYS_ID"]),
            geo=_local_origin(GeoReference(), self.navigation, self.world),
            aiding=self.navigation.report.aiding,
            unix_time_at_boot_us=(
                round(time.time() * 1e6)
                if options.unix_time_at_boot_us is None
                else options.unix_time_at_boot_us
            ),
        )
        self._params_revision = -1
        self._key = load_signing_key(options.signing_key) if options.signing_key else None
        self._channels: list[MemoryChannel] = []
        self.links: dict[str, MavlinkEndpoint] = {}
        """The two MAVLink links, ``onboard`` and ``gcs`` (made when opened)."""
        self._truth_file: IO[str] | None = None
        self._truth_every = max(1, round(1.0 / (options.truth_rate_hz * self.world.dt_s)))
        self.phases = MissionPhases()
        """When the mission's phases began, as the onboard link and the autopilot told."""
        self.servo_faults = ServoBusFaults(options, self.phases)
        if options.low_battery is not None:
            raise ValueError(
                "a low battery is flown by PX4's own battery and failsafe: fly it with PX4 in "
                "the loop (--autopilot px4); the imitation has no low-battery failsafe"
            )
        if options.pose_dropout is not None or options.pose_jump is not None:
            raise ValueError(
                "a motion-capture dropout or jump is flown by PX4's own estimator (EKF2): fly "
                "it with PX4 in the loop (--autopilot px4); the imitation does not model it"
            )
        self.link_faults = LinkFaults.of_run(options, self.phases, self.autopilot.system_id)
        self._console: Callable[[str], None] | None = None
        self.steps = 0
        """Plant steps taken."""
        self._first_step_wall_s = self._last_step_wall_s = 0.0
        """Wall-clock times (``time.perf_counter``) [s] at the start of the first step and
        the end of the last: a measurement, never an input of the flight."""
        self._first_step_sim_s = 0.0
        """Simulation time at the start of the first step [s]."""
        self._lockstep_waits = 0
        self._lockstep_timeouts = 0
        """Of :meth:`run`'s steps, those after which the vehicle waited for a lockstep
        client's setpoint, and those waits that timed out."""
        self._held: list = []
        """Onboard messages received while waiting for a setpoint (``lockstep``), handed to
        the autopilot at the next step."""
        self._uplink: DelayLine = DelayLine()
        self._downlink: DelayLine = DelayLine()
        """The onboard link's messages held back by a latency spike, towards the autopilot
        and towards the companion."""
        self._pose_sent_ms: int | None = None
        """``time_boot_ms`` of the ODOMETRY sent this step (``lockstep``), else None."""
        self._reads_at_pose = 0
        """The servo bus's Sync Reads when that ODOMETRY went out."""
        self._reads_stopped_at = -1
        """The Sync Reads when a wait for one timed out: no wait for reads until the next."""
        self._setpoint_ms = -1
        """``time_boot_ms`` of the latest setpoint received (:data:`_SETPOINTS`)."""
        self._streaming_until_s = -math.inf
        self._mode_seen: Px4Mode | None = None
        """The autopilot's mode at the last step (:attr:`phases` sees each change)."""
        self._measurement: VehicleMeasurement | None = None
        """The estimate of the last estimator output (held until the next)."""
        self._setpoint: AttitudeSetpoint | None = None
        """The autopilot's setpoint, held while its control decides nothing new."""
        self._open = False

    def _make_links(self) -> dict[str, MavlinkEndpoint]:
        ports, key = self.options.ports, self._key
        return {
            "onboard": MavlinkEndpoint(
                ports.onboard_local,
                ports.onboard_remote,
                host=ports.host,
                signing_key=key,
                port=self._memory_end("onboard"),
            ),
            "gcs": MavlinkEndpoint(
                ports.gcs_local,
                ports.gcs_remote,
                host=ports.host,
                signing_key=key,
                link_id=1,
                port=self._memory_end("gcs"),
            ),
        }

    def _memory_end(self, link: str) -> MemoryEnd | None:
        """The vehicle's end of the in-memory channel ``MEMORY-link`` (created here), or
        None without ``options.memory``."""
        if self.options.memory is None:
            return None
        channel = create_channel(f"{self.options.memory}-{link}")
        self._channels.append(channel)
        return channel.server

    # ------------------------------------------------------------------ lifecycle

    def __enter__(self) -> SitlVehicle:
        try:
            self.servo_bus.start()
            self.links = self._make_links()
            for link in self.links.values():
                link.open()
            if self.options.truth_log is not None:
                self._truth_file = open(self.options.truth_log, "x", encoding="utf-8")
        except BaseException:
            self.close()
            raise
        self._open = True
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the servo bus, close the links and the truth log; safe twice."""
        self.servo_bus.stop()
        for link in self.links.values():
            link.close()
        for channel in self._channels:
            channel.close()
        self._channels.clear()
        if self._truth_file is not None:
            self._truth_file.close()
            self._truth_file = None
        self._open = False

    def describe(self) -> dict[str, str]:
        """Where to connect: MAVLink links and the servo bus URL."""
        p, memory = self.options.ports, self.options.memory
        if memory is not None:
            return {
                "onboard": f"memory {memory}-onboard",
                "gcs": f"memory {memory}-gcs",
                "connect": f"memory://{memory}-onboard",
                "arm_bus": f"dynamixel://{self.servo_bus.device}?baud=1000000{servo_watchdog_option(self.scenario)}",
            }
        onboard, gcs = (
            self._bound_port("onboard", p.onboard_local),
            self._bound_port("gcs", p.gcs_local),
        )
        return {
            "onboard": f"udp {p.host}:{onboard} -> {p.host}:{p.onboard_remote}",
            "gcs": f"udp {p.host}:{gcs} -> {p.host}:{p.gcs_remote}",
            "connect": f"udpin://0.0.0.0:{p.onboard_remote}",
            # The emulator answers from a Python thread: allow for scheduling delays.
            "arm_bus": (
                f"dynamixel://{self.servo_bus.device}?baud=1000000&timeout_margin_ms=20"
                f"{servo_watchdog_option(self.scenario)}"
            ),
        }

    def _bound_port(self, link: str, configured: int) -> int:
        """The local port ``link`` is bound to (the free one chosen for 0), once open."""
        endpoint = self.links.get(link)
        if endpoint is None or not endpoint.is_open:
            return configured
        return endpoint.local_address[1]

    # ---------------------------------------------------------------------- loop

    def run(
        self,
        stop: threading.Event,
        until_s: float | None = None,
        console: Callable[[str], None] | None = None,
    ) -> RunStats:
        """Step until ``stop`` is set or simulation time reaches ``until_s`` [s]; each line
        PX4 would print to its console goes to ``console`` (e.g. ``WARN  [commander]
        Arming denied: ...``).

        Raises :class:`~sitl.physics.PlantError` if the plant diverges.
        """
        if not self._open:
            raise RuntimeError("open the SitlVehicle (with ...) before running it")
        # The servo bus thread must get the interpreter within a fraction of a millisecond
        # to answer like a servo, not after Python's default 5 ms switch interval.
        sys.setswitchinterval(_SWITCH_INTERVAL_S)
        self._console = console
        self._lockstep_waits = self._lockstep_timeouts = 0  # of this run
        pacer = WallPacer(self.world.dt_s / self.options.speed, _MAX_LAG_S)
        loop = step_loop(self, stop, until_s, pacer)
        self.flush_truth()
        return RunStats(
            **vars(loop),
            lockstep_waits=self._lockstep_waits,
            lockstep_timeouts=self._lockstep_timeouts,
        )

    @property
    def dt_s(self) -> float:
        """Simulated time of one step [s]."""
        return self.world.dt_s

    paced = True
    """Every step of :meth:`run` keeps its wall-clock slot (:class:`~sitl.stepping.Stepped`)."""

    def advance(self) -> bool:
        """One step of :meth:`run`: :meth:`step`, then, with a lockstep client streaming
        setpoints, the wait for its setpoint answering the pose just sent; True when the
        client streams (it paces the steps, not the wall clock)."""
        self.step()
        if not (self.options.lockstep and self._streaming()):
            return False
        if self._pose_sent_ms is not None:
            self._lockstep_waits += 1
            if not self._await_setpoint():
                self._lockstep_timeouts += 1
        return True

    def step(self) -> None:
        """One plant step (see the module docstring): the messages received go to the
        autopilot, the world steps under its setpoint, the telemetry due goes out.

        Raises :class:`~sitl.physics.PlantError` if the plant diverges.
        """
        world, autopilot, links = self.world, self.autopilot, self.links
        now_s = world.time_s
        if not self.steps:
            self._first_step_wall_s, self._first_step_sim_s = time.perf_counter(), now_s
        faults = self.link_faults
        held, self._held = self._held, []
        for name, link in links.items():
            messages = link.receive()
            if name == "onboard":
                messages = self._uplink_messages(held + messages if held else messages, now_s)
            for message in messages:
                if message.get_type() == "STATUSTEXT":
                    self.phases.observe_text(message.text, now_s)
                for reply_link, reply in autopilot.handle(message, name, now_s):
                    self._send(reply_link, reply, now_s)
        if autopilot.params.revision != self._params_revision:
            self._params_revision = autopilot.params.revision
            world.plant.configure_autopilot(attitude_loop_params(autopilot.params))
        now_us = round(now_s * 1e6)
        next_estimate_us = self.navigation.next_output_us
        fresh = next_estimate_us is None or now_us >= next_estimate_us
        if fresh:
            self._measurement = self.navigation.measure(world)
        measurement = self._measurement
        assert measurement is not None  # made at the first step
        if fresh or now_s >= autopilot.control_held_until_s:
            self._setpoint = autopilot.control(now_s, measurement)
            mode = autopilot.mode
            if mode is not self._mode_seen:  # a phase begins with a mode, not in it
                self._mode_seen = mode
                self.phases.observe_mode(mode.name, now_s)
        with self.servo_bus.lock:
            world.advance(self._setpoint)
        self._pose_sent_ms = None
        takeover = faults.takeover(now_s)
        if takeover is not None:
            for reply_link, reply in autopilot.handle(takeover, "gcs", now_s):
                self._send(reply_link, reply, now_s)
        if self._downlink:
            for message in self._downlink.due(now_s):
                self._deliver("onboard", message)
        if fresh or now_us >= autopilot.next_telemetry_us:
            self._send_telemetry(now_s, measurement)
        if autopilot.console_waiting:
            lines = autopilot.console()
            if self._console is not None:
                for line in lines:
                    self._console(_console_text(line.severity, line.text))
        self.servo_faults.update(world.time_s, self.servo_bus)
        if self._truth_file is not None and self.steps % self._truth_every == 0:
            self._write_truth()
        self.steps += 1
        self._last_step_wall_s = time.perf_counter()

    def step_until(self, until_s: float) -> None:
        """Plant steps while simulation time is below ``until_s`` [s] and each changes
        nothing but the world (quiet steps, :meth:`_quiet_until_s`: no message in, no
        estimate, no decision or deadline of the autopilot, no telemetry, no servo reply or
        instruction, no fault or truth-log line due; the world steps under the setpoint
        held, which is what :meth:`step` does then); if there are none, one :meth:`step`,
        followed by quiet steps if it sent nothing (else the companion may have something
        to read). At least one step.

        Raises :class:`~sitl.physics.PlantError` if the plant diverges.
        """
        if self.steps and self._quiet_steps(until_s):
            return
        links = self.links.values()
        sent = [link.sent for link in links]
        self.step()
        if all(link.sent == before for link, before in zip(links, sent, strict=True)):
            self._quiet_steps(until_s)

    def _quiet_steps(self, until_s: float) -> int:
        """The quiet steps from now on, while simulation time is below ``until_s`` [s];
        returns how many."""
        world = self.world
        limit_s = min(until_s, self._quiet_until_s())
        steps = start = self.steps
        if self._truth_file is not None:
            last = steps + (-steps) % self._truth_every  # the next truth-log line's step
        else:
            last = -1
        setpoint, lock = self._setpoint, self.servo_bus.lock
        while world.time_s < limit_s and steps != last:
            with lock:
                world.advance(setpoint)
            steps += 1
        if steps != start:
            self.steps = steps
            self._last_step_wall_s = time.perf_counter()
        return steps - start

    def _quiet_until_s(self) -> float:
        """Simulation time [s] before which, with the companion waiting, a plant step
        changes nothing but the world (1 us early for the times in microseconds); -inf
        when the next may (a message waiting, a console line, a fault to come, a bus
        that answers from its own thread)."""
        bus, autopilot = self.servo_bus, self.autopilot
        if (
            self._held
            or self._uplink
            or self._downlink
            or not isinstance(bus, MemoryServoBus)
            or autopilot.console_waiting
            or self.servo_faults.pending
            or self.link_faults.takeover_pending
            or not all(link.idle for link in self.links.values())
        ):
            return -math.inf
        estimate_us = self.navigation.next_output_us
        assert estimate_us is not None  # after a step
        due_us = min(estimate_us, autopilot.next_telemetry_us)
        return min((due_us - 1) * 1e-6, autopilot.control_held_until_s, bus.quiet_until_s)

    def _send_telemetry(self, now_s: float, measurement: VehicleMeasurement) -> None:
        """Send the telemetry due at ``now_s`` [s] on the links someone listens on (the
        link faults may drop it); note the pose a lockstep client answers."""
        links, faults = self.links, self.link_faults
        unheard = [name for name, link in links.items() if not link.heard]
        for link_name, message in self.autopilot.telemetry(now_s, measurement, unheard):
            if not faults.drops(link_name, now_s):
                self._send(link_name, message, now_s)

    def _uplink_messages(self, messages: list, now_s: float) -> list:
        """The onboard link's messages the autopilot takes at ``now_s`` [s]: those the link
        does not lose (a setpoint noted as it comes, for the lockstep), after a latency
        spike's delay, in order."""
        faults, lockstep, line = self.link_faults, self.options.lockstep, self._uplink
        delay_s = faults.delay_s("onboard", now_s)
        now = []
        for message in messages:
            if faults.drops("onboard", now_s):
                continue
            if lockstep and message.get_type() in _SETPOINTS:
                self._note_setpoint(message, now_s)
            if not line.hold(message, now_s, delay_s):
                now.append(message)
        return now + line.due(now_s) if line else now

    def _send(self, link_name: str, message, now_s: float) -> None:
        """Send ``message`` on ``link_name`` at ``now_s`` [s], or hold it back on the
        onboard link for a latency spike's delay (:meth:`step` delivers it when due)."""
        if link_name == "onboard" and self._downlink.hold(
            message, now_s, self.link_faults.delay_s("onboard", now_s)
        ):
            return
        self._deliver(link_name, message)

    def _deliver(self, link_name: str, message) -> None:
        """Put ``message`` on the wire of ``link_name``; note the pose a lockstep client
        answers."""
        self.links[link_name].send(message)
        if self.options.lockstep and link_name == "onboard" and message.get_type() == _ODOMETRY:
            self._pose_sent_ms = message.time_usec // 1000
            self._reads_at_pose = self.servo_bus.sync_reads

    def flight_times(self) -> dict[str, float]:
        """The flight's simulated and wall-clock seconds from the start of the first plant
        step to the end of the last (``flight_sim_s``, ``flight_wall_s``; 0 before a
        step)."""
        if not self.steps:
            return {"flight_sim_s": 0.0, "flight_wall_s": 0.0}
        return {
            "flight_sim_s": round(self.world.time_s - self._first_step_sim_s, 6),
            "flight_wall_s": round(self._last_step_wall_s - self._first_step_wall_s, 6),
        }

    def _note_setpoint(self, message, now_s: float) -> None:
        self._setpoint_ms = max(self._setpoint_ms, int(message.time_boot_ms))
        self._streaming_until_s = now_s + _STREAMING_S

    def _streaming(self) -> bool:
        """The client streams setpoints (one came within :data:`_STREAMING_S`)."""
        return self.world.time_s < self._streaming_until_s

    def _await_setpoint(self) -> bool:
        """Hold the onboard messages until the setpoint for the pose sent is among them,
        then wait for the client's Sync Read of the joints; False (and the stream counted
        as stopped) when either takes longer than :data:`LOCKSTEP_WAIT_S`."""
        assert self._pose_sent_ms is not None
        link = self.links["onboard"]
        deadline = time.perf_counter() + LOCKSTEP_WAIT_S
        while self._setpoint_ms < self._pose_sent_ms:
            remaining = deadline - time.perf_counter()
            if remaining <= 0.0:
                self._streaming_until_s = -math.inf
                return False
            link.wait_readable(remaining)
            for message in link.receive():
                self._held.append(message)
                if message.get_type() in _SETPOINTS:
                    self._note_setpoint(message, self.world.time_s)
        if self.servo_bus.sync_reads == self._reads_stopped_at:
            return True  # the client stopped reading the joints (e.g. landed)
        deadline = time.perf_counter() + LOCKSTEP_WAIT_S
        while self.servo_bus.sync_reads <= self._reads_at_pose:
            if time.perf_counter() > deadline:
                self._reads_stopped_at = self.servo_bus.sync_reads
                return False
            time.sleep(_READ_POLL_S)  # the bus thread answers meanwhile
        return True

    @property
    def time_s(self) -> float:
        """Simulation time [s]."""
        return self.world.time_s

    def serve(self) -> None:
        """Answer the servo instructions written on the in-memory bus, now (the pty bus
        answers from its own thread)."""
        bus = self.servo_bus
        if isinstance(bus, MemoryServoBus) and not bus.idle:
            bus.serve(self.world.time_s)

    def flush_truth(self) -> None:
        """Hand the truth log's buffered lines to the operating system."""
        if self._truth_file is not None:
            self._truth_file.flush()

    def _write_truth(self) -> None:
        assert self._truth_file is not None
        record = truth_record(self.world, self.autopilot.armed, self.autopilot.mode.name)
        self._truth_file.write(json.dumps(record) + "\n")


def truth_record(world: World, armed: bool, mode: str | None) -> dict:
    """One truth-log line (JSON object) of the world now: q, q_dot, the autopilot's arming
    state and mode name (``None`` while unknown), ground contact, payload, object
    position, gripper angle, joint torques, true theta, battery voltage and current, and
    the true thrust scale (thrust per command over the believed rotors')."""
    truth = world.truth()
    state = truth.plant
    obj = truth.object_position_m
    return {
        "t_s": round(truth.time_s, 6),
        "q": state.q.tolist(),
        "q_dot": state.q_dot.tolist(),
        "armed": bool(armed),
        "mode": mode,
        "on_ground": bool(truth.on_ground),
        "payload_attached": bool(truth.payload_attached),
        "object_position_m": None if obj is None else obj.tolist(),
        "gripper_angle_rad": truth.gripper_angle_rad,
        "joint_torques_n_m": truth.joint_torques_n_m.tolist(),
        "true_theta": list(truth.true_theta),
        "battery_v": round(world.battery.voltage_v, 3),
        "battery_a": round(world.battery.current_a, 3),
        "thrust_scale": world.plant.thrust_per_command if world.plant.flies_rotors else 1.0,
    }


_LEVELS = {4: "WARN ", 5: "WARN ", 6: "INFO "}
"""PX4 console levels of MAV_SEVERITY_WARNING, _NOTICE and _INFO; more severe: ERROR."""


def _console_text(severity: int, text: str) -> str:
    """A console line as PX4 prints it, e.g. ``INFO  [commander] Armed by external command``."""
    return f"{_LEVELS.get(severity, 'ERROR')} [commander] {text}"

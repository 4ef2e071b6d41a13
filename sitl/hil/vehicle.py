"""``sitl run --autopilot px4``: the real PX4 flies our physics through ``simulator_mavlink``.

One :class:`Px4InTheLoop` holds PX4 (:class:`~sitl.px4_sitl.Px4Sitl`, airframe
:data:`~sitl.hil.airframe.AUTOSTART` with :func:`~sitl.hil.airframe.px4_parameters`), the
simulator link PX4 connects to (:class:`~sitl.hil.link.SimulatorLink`, TCP 4560 + its
instance), the world of ``sitl run`` (truth plant, arm servos on a pty, gripper, object,
ground, :func:`sitl.vehicle.runner.build_world`) and PX4's sensors (:mod:`sitl.hil.sensors`).

Lockstep, one clock. Every IMU period (``1 / [sensors] gyro_rate_hz``, 4 ms at 250 Hz;
a whole number of plant steps) the loop

1. steps the world that many plant steps with PX4's last motor commands held (PX4's
   output i drives rotor i, :mod:`sitl.hil.airframe`), averaging the specific force and
   body rate for the IMU;
2. sends HIL_SENSOR stamped with the world's time (PX4's clock is set from it: PX4 time
   = world time = the truth log's ``t_s``), the magnetometer and barometer in every fifth
   one (50 Hz), then what is due of the motion-capture pose (ODOMETRY, the scenario's
   rate, latency and noise), the GPS fix (HIL_GPS) and the ground truth
   (HIL_STATE_QUATERNION, at the interval PX4 asks for);
3. waits for PX4's HIL_ACTUATOR_CONTROLS for that time: PX4's EKF2, commander,
   position, attitude and rate loops, control allocation and motor linearization ran on
   it. Until PX4 first answers (its start-up), the loop does not wait;
4. with the companion relay, waits until the companion has answered the last pose PX4
   sent it (:mod:`sitl.hil.companion_relay`).

Until PX4 is ready (its start-up script done, its links on the requested ports, "Ready for
takeoff!") the loop runs as fast as PX4 and the physics go; then it is paced at ``speed``
times real time (as ``sitl run``), and PX4's console lines go to ``console``.

Links: PX4's onboard and GCS links are moved onto the ports of ``RunOptions.ports`` (the
companion connects where ``sitl run`` says, as with the imitation); the onboard link's
ports are this process's :class:`~sitl.hil.companion_relay.CompanionRelay`, PX4's link
moved onto an internal pair (the relay reads the mission's phases and carries the link's
faults); with ``companion_lockstep`` (the default) after each frame's motor commands the
loop waits for the companion's answer to the last pose (4. above: the companion in the
lockstep), without it the relay only forwards, at the end of each frame; a third PX4 link
(mode ``minimal``) sends its heartbeats to this process, whose flight mode the truth log
records (PX4's 1 Hz heartbeat: up to a second late); ``armed`` comes with every
HIL_ACTUATOR_CONTROLS.

Faults (``RunOptions``), at a simulated time or a phase: the servo bus's, as with the
imitation; a motion-capture dropout (no vision ODOMETRY to PX4 for a while) or jump (the
poses moved east from then on); on the relayed onboard link a cut, a lossy stretch or a
latency spike; from the mode link, as a ground station, the pilot's mode switch and a
battery falling low (:mod:`sitl.vehicle.link_faults`). The mission's phases are the
companion's STATUSTEXT, read by the relay as it passes.

Not simulated: MAVLink signing (PX4's own), RC, a range finder, airspeed, and the battery:
PX4 reports its own simulated one, held full (``SIM_BAT_MIN_PCT = 100``,
:mod:`sitl.px4_sitl.launcher`) unless a low-battery fault lowers it, so the plant flies on
an ideal supply whatever the scenario's ``plant.battery`` (the thrust per command steady,
while the voltage PX4 reports may fall).
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sitl.hil.airframe import AUTOSTART, navigation_parameters, px4_parameters
from sitl.hil.boot import Px4Boot, forward_log
from sitl.hil.companion_relay import CompanionRelay
from sitl.hil.link import SimulatorLink
from sitl.hil.messages import (
    hil_gps,
    hil_sensor,
    hil_state_quaternion,
    motor_commands,
    vision_odometry,
)
from sitl.hil.options import HilOptions, HilStats
from sitl.hil.sensors import (
    ACCEL_STD_M_S2,
    BARO_STD_PA,
    GPS_GRADES,
    MAG_STD_GAUSS,
    Barometer,
    GpsReceiver,
    Imu,
    Magnetometer,
)
from sitl.physics.rotors import N_ROTORS
from sitl.px4 import GeoReference, MavlinkEndpoint, Px4Mode
from sitl.px4_sitl.launcher import (
    Px4NotReadyError,
    Px4Ports,
    Px4Sitl,
    free_instance,
    release_instance,
)
from sitl.scenario import Scenario, servo_watchdog_option
from sitl.servo.pty_server import REPLY_SWITCH_INTERVAL_S
from sitl.stepping import WallPacer, step_loop
from sitl.vehicle.link_faults import LinkFaults
from sitl.vehicle.mission_phases import MissionPhases
from sitl.vehicle.options import LOCKSTEP_WAIT_S, RunOptions
from sitl.vehicle.runner import build_world, truth_record
from sitl.vehicle.sensors import PoseMeasurement, PoseSensor
from sitl.vehicle.servo_bus_faults import ServoBusFaults

__all__ = ["VALIDATED_SPEED", "Px4Exited", "Px4InTheLoop"]

VALIDATED_SPEED = 2.0
"""The highest speed (simulated s per wall s) at which the pickup with PX4 in the loop and
the companion beside it on 2 cores gave the results of speed 1, within their seed-to-seed
spread (``docs/px4_speed.md``, ``benchmarks/compare_demos.py --preset px4-speed``). With
the companion held in the lockstep, 3x completed all four flights but moved the mean
centre-of-mass error by 2.5 of speed 1's standard deviations, and 2 cores reach only about
2.3x anyway (the whole command 1.7x against 2x's 1.6x)."""

_SIMULATOR_WAITING = "Waiting for simulator to accept connection"
_SLOW_SENSORS_HZ = 50.0
"""Rate of the magnetometer and barometer samples in HIL_SENSOR [Hz]."""
_ANSWER_TIMEOUT_S = 30.0
"""Longest wall time PX4 may take to answer one HIL_SENSOR once in lockstep [s]."""
_HOUSEKEEPING_S = 0.1
"""Wall time between looks at PX4's log and heartbeats [s]."""
_MAX_LAG_S = 0.02
"""Wall-clock lag behind schedule [s] after which the schedule is re-based (overrun)
instead of caught up. Catching up means running faster than ``speed``: PX4 follows and
sends its poses faster than real time, and a companion that keeps up only at ``speed``
drops them and sees long control periods in vehicle time (``loop_overrun``: the
suspected cause of such faults that came with step-start lateness p99 of 0.2 s under the
imitation's 0.25 s). In lockstep nothing needs the lost wall time back."""


class Px4Exited(RuntimeError):
    """PX4 stopped (or stopped answering) while flying; the message ends with its log."""


class Px4InTheLoop:
    """PX4 SITL flying the scenario's vehicle with our physics (module docstring).

    Nothing starts in the constructor. ``__enter__`` starts the servo bus, opens the truth
    log and the simulator link, starts PX4 (until it waits for the simulator) and accepts
    its connection; :meth:`run` boots PX4 in lockstep and flies; ``__exit__`` / :meth:`close`
    (idempotent) stops PX4 (its directory kept with ``keep_dir`` or when the run failed)
    and closes the rest.

    Raises ValueError for options this mode cannot honour (MAVLink signing: configure
    PX4's own) and for an IMU rate that is not a whole number of plant steps.
    """

    def __init__(self, scenario: Scenario, options: RunOptions, hil: HilOptions) -> None:
        if options.signing_key is not None:
            raise ValueError(
                "MAVLink signing is the imitation's: configure PX4's own (MAV_SIGN_CFG)"
            )
        plant_rate_hz = scenario.plant.rate_hz
        imu_rate_hz = scenario.sensors.gyro_rate_hz
        steps = plant_rate_hz / imu_rate_hz
        if imu_rate_hz < 250.0 or abs(steps - round(steps)) > 1e-9:
            raise ValueError(
                f"[sensors] gyro_rate_hz = {imu_rate_hz:g} is PX4's IMU rate here: it must be "
                f">= 250 Hz and divide plant.rate_hz = {plant_rate_hz:g}"
            )
        # PX4's battery is the one reported, held full: the thrust must not sag under it
        plant = scenario.plant.model_copy(update={"battery": None})
        scenario = scenario.model_copy(update={"plant": plant})
        self.scenario = scenario
        self.options = options
        self.hil = hil
        self.world, self.servo_bus, self.joints, self.gripper = build_world(scenario, options)
        self.steps_per_frame = round(steps)
        self.frame_s = 1.0 / imu_rate_hz
        self.origin = GeoReference()
        rng = np.random.default_rng(options.seed)
        noise = options.noise
        s = scenario.sensors
        self._imu = Imu(
            rng,
            gyro_std_rad_s=s.gyro_std_rad_s if noise else 0.0,
            accel_std_m_s2=ACCEL_STD_M_S2 if noise else 0.0,
        )
        self._mag = Magnetometer(rng, std_gauss=MAG_STD_GAUSS if noise else 0.0)
        self._baro = Barometer(rng, self.origin, std_pa=BARO_STD_PA if noise else 0.0)
        self._slow_every = max(1, round(imu_rate_hz / _SLOW_SENSORS_HZ))
        half_frame_s = 0.5 * self.frame_s  # a sample's mean extra age on the frame grid
        self._pose: PoseSensor | None = None
        self._gps: GpsReceiver | None = None
        if options.navigation == "mocap":
            self._pose = PoseSensor(
                rng,
                position_std_m=s.position_std_m if noise else 0.0,
                attitude_std_rad=s.attitude_std_rad if noise else 0.0,
                rate_hz=s.pose_rate_hz,
                latency_s=s.pose_latency_s,
            )
            navigation = navigation_parameters(
                "mocap", vision_delay_s=s.pose_latency_s + half_frame_s
            )
        else:
            grade = GPS_GRADES[hil.gps]
            self._gps = GpsReceiver(rng, grade, self.origin, noise=noise)
            navigation = navigation_parameters(
                "gps",
                gps_delay_s=grade.latency_s + half_frame_s,
                gps_position_std_m=grade.horizontal_std_m if grade.name == "rtk" else None,
            )
        self.params = px4_parameters(scenario, navigation, imu_rate_hz=imu_rate_hz)
        self.ports: Px4Ports | None = None
        self.px4: Px4Sitl | None = None
        self._link: SimulatorLink | None = None
        self._relay: CompanionRelay | None = None
        self._mode_link: MavlinkEndpoint | None = None
        self._truth_file: IO[str] | None = None
        self._unix_time_at_boot_us = 0
        self._commands = [0.0] * N_ROTORS
        self.armed = False
        self.mode: str | None = None
        """PX4's flight mode from its last heartbeat (a :class:`~sitl.px4.Px4Mode` name)."""
        self.phases = MissionPhases()
        """When PX4's take-off and landing (from its modes) and the mission's phases (the
        companion's STATUSTEXT, read by the relay) began."""
        self.servo_faults = ServoBusFaults(options, self.phases)
        self.link_faults = LinkFaults.of_run(options, self.phases)
        """The onboard link's cut, loss or latency (acted by the relay), and what the ground
        station sends PX4 (the pilot's mode switch, the battery's parameters) on the mode
        link."""
        self._lockstep = False
        self._truth_interval_us = 0
        self._next_truth_us = 0
        self._failed = False
        self._open = False
        self.kept_dir: Path | None = None
        """PX4's working directory after :meth:`close`, when kept."""
        self.stats: HilStats | None = None
        """What the running (or last) :meth:`run` achieved so far."""
        self._frame: _FrameLoop | None = None
        """The run's state between plant steps (:meth:`run`)."""

    # ------------------------------------------------------------------ lifecycle

    def __enter__(self) -> Px4InTheLoop:
        try:
            self.servo_bus.start()
            if self.options.truth_log is not None:
                self._truth_file = open(self.options.truth_log, "x", encoding="utf-8")
            self.ports = ports = free_instance()
            self._link = SimulatorLink(ports.simulator_tcp)
            self._link.open()
            p = self.options.ports
            self._relay = CompanionRelay(
                (p.onboard_local, p.onboard_remote),
                lambda: self.servo_bus.sync_reads,
                answer_timeout_s=LOCKSTEP_WAIT_S,
                on_text=self._companion_text,
                drops=lambda: self.link_faults.drops("onboard", self.world.time_s),
                delay=lambda: self.link_faults.delay_s("onboard", self.world.time_s),
                clock=lambda: self.world.time_s,
            )
            self._relay.open()
            self._mode_link = MavlinkEndpoint(0, 0, system_id=255, component_id=190)
            self._mode_link.open()
            speed = self.options.speed
            self.px4 = Px4Sitl(
                self.hil.build,
                autostart=AUTOSTART,
                simulator=None,
                model=None,
                params=self.params,
                env={"PX4_SIM_SPEED_FACTOR": f"{speed:g}"} if speed != 1.0 else None,
                ports=ports,
                keep_dir=self.hil.keep_dir,
                ready_lines=(_SIMULATOR_WAITING,),
            )
            self.px4.start(self.hil.ready_timeout_s)
            if self.hil.nice:
                os.nice(self.hil.nice)  # after PX4 started: PX4 keeps the normal priority
            self._link.accept(self.hil.ready_timeout_s)
            self._unix_time_at_boot_us = round(time.time() * 1e6)
        except BaseException:
            self._failed = True
            self.close()
            raise
        self._open = True
        return self

    def __exit__(self, exc_type: object, *exc_info: object) -> None:
        if exc_type is not None:
            self._failed = True
        self.close()

    def close(self) -> Path | None:
        """Stop PX4 and close everything; returns PX4's working directory if kept (asked
        for with ``keep_dir``, or the run failed). Safe twice."""
        if self.px4 is not None:
            kept = self.px4.stop(keep=self.hil.keep_dir is not None or self._failed)
            self.kept_dir = kept or self.kept_dir
        if self.ports is not None:
            release_instance(self.ports)
        for closable in (self._link, self._relay, self._mode_link):
            if closable is not None:
                closable.close()
        self.servo_bus.stop()
        if self._truth_file is not None:
            self._truth_file.close()
            self._truth_file = None
        self._open = False
        return self.kept_dir

    def describe(self) -> dict[str, str]:
        """Where to connect: MAVLink links, the companion's URL, the servo bus, PX4's log and
        the simulator link (the ``ready`` line of ``sitl run``)."""
        if self.px4 is None or self.ports is None:
            raise RuntimeError("PX4 is not started")
        p = self.options.ports
        return {
            "onboard": f"udp {p.host}:{p.onboard_local} -> {p.host}:{p.onboard_remote}",
            "gcs": f"udp {p.host}:{p.gcs_local} -> {p.host}:{p.gcs_remote}",
            "connect": f"udpin://0.0.0.0:{p.onboard_remote}",
            # The emulator answers from a Python thread: allow for scheduling delays.
            "arm_bus": (
                f"dynamixel://{self.servo_bus.device}?baud=1000000&timeout_margin_ms=20"
                f"{servo_watchdog_option(self.scenario)}"
            ),
            "px4_log": str(self.px4.log_path),
            "simulator": f"tcp 127.0.0.1:{self.ports.simulator_tcp} "
            f"(PX4 instance {self.ports.instance}, airframe {AUTOSTART})",
        }

    # ---------------------------------------------------------------------- loop

    def run(
        self,
        stop: threading.Event,
        until_s: float | None = None,
        console: Callable[[str], None] | None = None,
        on_ready: Callable[[dict[str, str]], None] | None = None,
    ) -> HilStats:
        """Boot PX4 in lockstep, call ``on_ready(describe())`` once it is ready, and fly
        until ``stop`` is set or simulation time reaches ``until_s`` [s]; PX4's console
        lines after ready go to ``console``.

        Raises :class:`~sitl.px4_sitl.Px4NotReadyError` when PX4 does not get ready in
        ``ready_timeout_s``, :class:`Px4Exited` when PX4 exits or stops answering, and the
        plant's :class:`~sitl.physics.PlantError` if it diverges.
        """
        if not self._open:
            raise RuntimeError("open the vehicle (with ...) before running it")
        try:
            return self._run(stop, until_s, console, on_ready)
        except BaseException:
            self._failed = True
            raise

    def _run(self, stop, until_s, console, on_ready) -> HilStats:
        assert self.px4 is not None and self._link is not None
        sys.setswitchinterval(REPLY_SWITCH_INTERVAL_S)
        self.stats = stats = HilStats()
        relay = self._relay
        onboard = (
            relay.px4_ports
            if relay is not None
            else (self.options.ports.onboard_local, self.options.ports.onboard_remote)
        )
        self._frame = _FrameLoop(
            boot=Px4Boot(self.px4, self.options, onboard, self._mode_link_port()),
            truth_every=max(1, round(1.0 / (self.options.truth_rate_hz * self.world.dt_s))),
            stop=stop,
            console=console,
            on_ready=on_ready,
            wall0=time.perf_counter(),
            sim0=self.world.time_s,
        )
        pacer = WallPacer(self.world.dt_s / self.options.speed, _MAX_LAG_S)
        loop = step_loop(self, stop, until_s, pacer)
        if relay is not None:
            stats.companion_holds = relay.holds
            stats.companion_wait_s = relay.held_s
            stats.companion_releases = relay.releases
        for name, value in vars(loop).items():
            setattr(stats, name, value)
        if self._truth_file is not None:
            self._truth_file.flush()
        return stats

    @property
    def dt_s(self) -> float:
        """Simulated time of one plant step [s]."""
        return self.world.dt_s

    @property
    def time_s(self) -> float:
        """Simulation time [s]."""
        return self.world.time_s

    @property
    def paced(self) -> bool:
        """Whether PX4 is ready: it boots as fast as it can, then each plant step keeps
        its wall-clock slot, as the imitation's (:class:`~sitl.stepping.Stepped`)."""
        return self._frame is not None and self._frame.ready

    def advance(self) -> bool:
        """One plant step under PX4's motor outputs (:class:`~sitl.stepping.Stepped`): the
        servo fault and the truth log when due; after the frame's last step, the frame's
        sensors to PX4 and its answer awaited (:meth:`_end_frame`). True when PX4 just got
        ready (the slots start then)."""
        frame, stats, world = self._frame, self.stats, self.world
        assert frame is not None and stats is not None
        t0 = time.perf_counter()
        if frame.step_in_frame == 0:
            frame.force, frame.omega = np.zeros(3), np.zeros(3)
            frame.commands = self._commands
        with self.servo_bus.lock:
            state = world.step_motors(frame.commands)
        frame.force += world.specific_force_flu_m_s2()
        frame.omega += state.omega_body_rad_s
        self.servo_faults.update(world.time_s, self.servo_bus)
        if self._truth_file is not None and frame.steps % frame.truth_every == 0:
            self._truth_file.write(json.dumps(truth_record(world, self.armed, self.mode)) + "\n")
        frame.steps += 1
        frame.step_in_frame += 1
        stats.physics_s += time.perf_counter() - t0
        if frame.step_in_frame < self.steps_per_frame:
            return False
        frame.step_in_frame = 0
        return self._end_frame(frame, stats)

    def _end_frame(self, frame: _FrameLoop, stats: HilStats) -> bool:
        """The frame's mean specific force and body rate to PX4 and its answer awaited (the
        companion held or pumped); every :data:`_HOUSEKEEPING_S` PX4's heartbeats, life,
        boot and console. True when PX4 just got ready."""
        assert self.px4 is not None and self._link is not None
        relay = self._relay
        t1 = time.perf_counter()
        time_us = round(self.world.time_s * 1e6)
        n = self.steps_per_frame
        self._link.send(
            *self._sensor_messages(stats.frames, time_us, frame.force / n, frame.omega / n)
        )
        t2 = time.perf_counter()
        self._await_px4(time_us, frame.stop)
        if relay is not None:
            if frame.ready and self.hil.companion_lockstep:
                relay.hold(frame.stop)
            else:
                relay.pump()
        self._ground_station(self.world.time_s)
        t3 = time.perf_counter()
        stats.frames += 1
        stats.sensors_s += t2 - t1
        stats.px4_wait_s += t3 - t2
        if t3 < frame.next_look:
            return False
        frame.next_look = t3 + _HOUSEKEEPING_S
        self._read_heartbeats()
        if not self.px4.alive():
            raise Px4Exited(f"PX4 exited:\n{self.px4.log_tail(15)}")
        if frame.ready:
            if frame.console is not None:
                frame.log_offset = forward_log(self.px4.log_path, frame.log_offset, frame.console)
            return False
        if frame.boot.advance():
            frame.ready = True
            stats.boot_sim_s = self.world.time_s - frame.sim0
            stats.boot_wall_s = t3 - frame.wall0
            frame.log_offset = self.px4.log_path.stat().st_size
            if frame.on_ready is not None:
                frame.on_ready(self.describe())
            return True
        if t3 - frame.wall0 > self.hil.ready_timeout_s:
            raise Px4NotReadyError(
                f"PX4 was not ready within {self.hil.ready_timeout_s:g} s "
                f"({frame.boot.waiting_for}):\n{self.px4.log_tail(15)}"
            )
        return False

    def _pose_lost(self, now_s: float) -> bool:
        """A motion-capture dropout (``RunOptions.pose_dropout``) at ``now_s`` [s]."""
        dropout = self.options.pose_dropout
        if dropout is None:
            return False
        return self.phases.within(*dropout, now_s)

    def _pose_moved(self, pose: PoseMeasurement) -> PoseMeasurement:
        """The pose after a jump of the motion-capture frame (``RunOptions.pose_jump``),
        once its start has come: that far east (world x, ENU)."""
        jump = self.options.pose_jump
        if jump is None:
            return pose
        if not self.phases.reached(jump[0], pose.t_s):
            return pose
        moved = pose.position_m + np.array([jump[1], 0.0, 0.0])
        return replace(pose, position_m=moved)

    def _companion_text(self, text: str) -> None:
        """A STATUSTEXT of the companion, relayed: a mission phase begins (told on the
        console as ``phase NAME at T s``, where a harness that kills the companion at a
        phase reads it)."""
        now_s = self.world.time_s
        phase = self.phases.observe_text(text, now_s)
        frame = self._frame
        if phase is not None and frame is not None and frame.console is not None:
            frame.console(f"phase {phase} at {now_s:.3f} s")

    def _ground_station(self, now_s: float) -> None:
        """What the ground station sends PX4 when its time has come [s]: the pilot's mode
        switch, the battery's parameters (on the mode link, from system 255 as
        QGroundControl)."""
        assert self._mode_link is not None
        takeover = self.link_faults.takeover(now_s)
        if takeover is not None:
            self._mode_link.send(takeover)
        for message in self.link_faults.battery(now_s):
            self._mode_link.send(message)

    def _mode_link_port(self) -> int:
        assert self._mode_link is not None
        return self._mode_link.local_address[1]

    def _sensor_messages(
        self, frame: int, time_us: int, force_flu: np.ndarray, omega_flu: np.ndarray
    ) -> list[mavlink.MAVLink_message]:
        """HIL_SENSOR of this frame first (it sets PX4's clock), then what is due."""
        state = self.world.state
        t_s = state.time_s
        imu = self._imu.measure(force_flu, omega_flu)
        if frame % self._slow_every == 0:
            mag = self._mag.measure(state.rotation_world_body)
            baro = self._baro.measure(float(state.q[2]))
            messages: list[mavlink.MAVLink_message] = [hil_sensor(time_us, imu, mag, baro)]
        else:
            messages = [hil_sensor(time_us, imu)]
        if self._pose is not None:
            pose = self._pose.sample(t_s, state.q)
            if pose is not None and not self._pose_lost(t_s):
                pose = self._pose_moved(pose)
                s = self.scenario.sensors
                messages.append(
                    vision_odometry(time_us, pose, s.position_std_m, s.attitude_std_rad)
                )
        if self._gps is not None:
            fix = self._gps.sample(t_s, state.q[0:3], state.q_dot[0:3])
            if fix is not None:
                messages.append(hil_gps(self._unix_time_at_boot_us + time_us, fix))
        if self._truth_interval_us > 0 and time_us >= self._next_truth_us:
            self._next_truth_us = time_us + self._truth_interval_us
            messages.append(
                hil_state_quaternion(time_us, state, np.asarray(state.q_ddot[0:3]), self.origin)
            )
        return messages

    def _await_px4(self, time_us: int, stop: threading.Event) -> None:
        """Take PX4's messages; in lockstep, wait for the motor commands of ``time_us``."""
        assert self._link is not None and self.px4 is not None
        answered = not self._lockstep
        deadline = time.monotonic() + _ANSWER_TIMEOUT_S
        while True:
            for message in self._link.receive(0.0 if answered else 0.05):
                kind = message.get_type()
                if kind == "HIL_ACTUATOR_CONTROLS":
                    self._commands, self.armed = motor_commands(message)
                    self._lockstep = True
                    answered = answered or message.time_usec >= time_us
                elif (
                    kind == "COMMAND_LONG"
                    and message.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
                ):
                    if int(message.param1) == mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION:
                        self._truth_interval_us = max(0, round(message.param2))
            if answered or stop.is_set():
                return
            if time.monotonic() > deadline or not self.px4.alive():
                what = "stopped answering" if self.px4.alive() else "exited"
                raise Px4Exited(f"PX4 {what} on the simulator link:\n{self.px4.log_tail(15)}")

    def _read_heartbeats(self) -> None:
        assert self._mode_link is not None
        for message in self._mode_link.receive():
            if message.get_type() == "HEARTBEAT" and message.autopilot == mavlink.MAV_AUTOPILOT_PX4:
                mode = Px4Mode.from_custom_mode(message.custom_mode)
                self.mode = None if mode is None else mode.name
                if self.mode is not None:
                    self.phases.observe_mode(self.mode, self.world.time_s)


@dataclass
class _FrameLoop:
    """What :meth:`Px4InTheLoop.run` carries from one plant step to the next: the frame
    being summed (its steps so far, specific force and body rate, PX4's motor outputs at
    its start), PX4's boot, the housekeeping's next wall-clock time, and the run's
    options."""

    boot: Px4Boot
    truth_every: int
    """Plant steps between two truth lines."""
    stop: threading.Event
    console: Callable[[str], None] | None
    on_ready: Callable[[dict[str, str]], None] | None
    wall0: float
    """perf_counter at the start [s]."""
    sim0: float
    """Simulation time at the start [s]."""
    ready: bool = False
    next_look: float = 0.0
    """perf_counter of the next housekeeping [s] (0: at the first frame's end)."""
    log_offset: int = 0
    """PX4's console log read up to here (bytes)."""
    steps: int = 0
    step_in_frame: int = 0
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    omega: np.ndarray = field(default_factory=lambda: np.zeros(3))
    commands: list[float] = field(default_factory=list)

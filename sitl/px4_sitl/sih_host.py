"""The host behind ``sitl sih``: PX4's own SIH flies the scenario's vehicle, the arm hangs on
a stand, and optionally a motion-capture system feeds PX4 instead of GPS.

One :class:`SihHost` holds the three parts and starts them in order:

1. in motion-capture mode, the :class:`~sitl.px4_sitl.mocap.MocapFeeder`'s UDP ports (the SIH
   display link's truth port, and its own);
2. PX4 (:class:`~sitl.px4_sitl.Px4Sitl`) with :func:`sitl.px4_sitl.sih.sih_parameters` of the
   scenario (plus :func:`sitl.px4_sitl.mocap.mocap_parameters`), ``PX4_SIM_SPEED_FACTOR`` = the
   speed; in motion-capture mode PX4 cannot become ready without poses, so the host waits
   for the end of its start-up script, starts a MAVLink link for the feeder in PX4
   (``mavlink start``, mode minimal, on a free port), starts the feeder, then waits for
   "Ready for takeoff!";
3. the :class:`~sitl.servo.arm_stand.ArmStand` with its servos on a pty, at the same speed.

:meth:`SihHost.stop` (idempotent) stops them in reverse order and keeps PX4's working
directory (``px4.log``, ULog flight logs) when asked.
"""

from __future__ import annotations

import math
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

from sitl.px4_sitl.launcher import (
    Px4Build,
    Px4NotReadyError,
    Px4Ports,
    Px4Sitl,
    free_instance,
    release_instance,
)
from sitl.px4_sitl.mocap import DEFAULT_ORIGIN, MocapFeeder, mocap_parameters, sih_origin
from sitl.px4_sitl.sih import sih_parameters
from sitl.scenario import Scenario, servo_watchdog_option
from sitl.servo.arm_stand import ArmStand
from sitl.servo.pty_server import REPLY_SWITCH_INTERVAL_S
from sitl.vehicle.launch import free_udp_port

__all__ = ["NAVIGATION_MODES", "STARTUP_DONE", "SihHost"]

NAVIGATION_MODES = ("gps", "mocap")
"""How PX4 navigates: SIH's simulated GPS, or motion capture (external vision) without GPS."""
STARTUP_DONE = "Startup script returned successfully"
"""PX4's log line at the end of its start-up script (all modules and links started)."""
_READY = "Ready for takeoff!"
_MOCAP_LINK_RATE_B_S = 200_000
"""Data rate PX4 may send on the mocap link [B/s] (it sends only heartbeats there)."""


class SihHost:
    """PX4 SIH, the arm stand and (``navigation="mocap"``) the motion-capture feeder.

    Parameters
    ----------
    scenario
        Validated scenario: SIH's vehicle (:func:`~sitl.px4_sitl.sih.sih_parameters` raises
        :class:`~sitl.px4_sitl.sih.SihMismatchError` for one SIH cannot fly) and the arm's
        ``[arm_bus]`` servos (ValueError without).
    build
        The PX4 SITL build.
    navigation
        ``gps`` or ``mocap`` (:data:`NAVIGATION_MODES`).
    speed
        PX4's ``PX4_SIM_SPEED_FACTOR`` and the arm stand's speed (> 0).
    keep_dir
        Where PX4's working directory goes (default: a temporary directory).
    seed
        Seed of the motion-capture noise.
    mocap_rate_hz
        Motion-capture poses per second (PX4 time).
    timeout_s
        Longest wait for each of PX4's start-up stages [s].
    """

    def __init__(
        self,
        scenario: Scenario,
        build: Px4Build,
        *,
        navigation: str = "gps",
        speed: float = 1.0,
        keep_dir: Path | None = None,
        seed: int = 0,
        mocap_rate_hz: float = 100.0,
        timeout_s: float = 60.0,
    ) -> None:
        if navigation not in NAVIGATION_MODES:
            raise ValueError(f"navigation must be one of {NAVIGATION_MODES}, got {navigation!r}")
        if not (math.isfinite(speed) and speed > 0.0):
            raise ValueError(f"the speed factor must be positive, got {speed!r}")
        self.scenario = scenario
        self.build = build
        self.navigation = navigation
        self.speed = float(speed)
        self.params = sih_parameters(scenario)
        if navigation == "mocap":
            self.params.update(mocap_parameters(DEFAULT_ORIGIN, self.speed))
        self.stand = ArmStand(scenario, speed=self.speed)
        self._keep_dir = keep_dir
        self._seed = seed
        self._mocap_rate_hz = float(mocap_rate_hz)
        self._timeout_s = float(timeout_s)
        self.ports: Px4Ports | None = None
        self.px4: Px4Sitl | None = None
        self.feeder: MocapFeeder | None = None
        self._px4_mocap_port: int | None = None

    def start(self, ports: Px4Ports | None = None) -> None:
        """Start PX4 on ``ports`` (default: the first free instance), the feeder and the
        stand; on any failure, stop what started (PX4's directory kept) and re-raise.
        Raises :class:`~sitl.px4_sitl.Px4NotReadyError` when PX4 does not get ready (or
        no instance is free) and OSError when a port is taken."""
        if self.px4 is not None:
            raise RuntimeError("this SihHost was already started")
        try:
            self.ports = ports if ports is not None else free_instance()
            mocap = self.navigation == "mocap"
            if mocap:
                self.feeder = MocapFeeder(
                    self.ports,
                    sih_origin(DEFAULT_ORIGIN),
                    np.random.default_rng(self._seed),
                    rate_hz=self._mocap_rate_hz,
                    speed=self.speed,
                )
                self.feeder.open()
            self.px4 = Px4Sitl(
                self.build,
                params=self.params,
                env={"PX4_SIM_SPEED_FACTOR": f"{self.speed:g}"} if self.speed != 1.0 else None,
                ports=self.ports,
                keep_dir=self._keep_dir,
                ready_lines=(STARTUP_DONE,) if mocap else (_READY,),
            )
            self.px4.start(self._timeout_s)
            if self.feeder is not None:
                self._start_mocap(self.px4, self.feeder)
            sys.setswitchinterval(REPLY_SWITCH_INTERVAL_S)
            self.stand.start()
        except BaseException:
            self.stop(keep=True)
            raise

    def _start_mocap(self, px4: Px4Sitl, feeder: MocapFeeder) -> None:
        port = free_udp_port()
        link = ["-u", str(port), "-o", str(feeder.local_port), "-m", "minimal"]
        try:
            px4.command("mavlink", "start", *link, "-r", str(_MOCAP_LINK_RATE_B_S))
        except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as exc:
            raise Px4NotReadyError(f"PX4 did not start the mocap link: {exc}") from None
        self._px4_mocap_port = port
        feeder.connect(port)
        feeder.start()
        px4.wait_for_log((_READY,), self._timeout_s)

    def describe(self) -> dict[str, str]:
        """Where to connect: PX4's links, the companion's MAVLink URL (``connect``), the
        servo bus URL (``arm_bus``), PX4's log (``px4_log``) and the mocap link."""
        if self.px4 is None or self.ports is None:
            raise RuntimeError("the SihHost is not started")
        p = self.ports
        where = {
            "onboard": f"udp 127.0.0.1:{p.onboard_local} -> 127.0.0.1:{p.onboard_remote}",
            "gcs": f"udp 127.0.0.1:{p.gcs_local} -> 127.0.0.1:14550",
            "connect": p.connect_url,
            # The emulator answers from a Python thread: allow for scheduling delays.
            "arm_bus": (
                f"dynamixel://{self.stand.device}?baud=1000000&timeout_margin_ms=20"
                f"{servo_watchdog_option(self.scenario)}"
            ),
            "px4_log": str(self.px4.log_path),
        }
        if self.feeder is not None:
            where["mocap"] = (
                f"udp 127.0.0.1:{self.feeder.local_port} -> 127.0.0.1:{self._px4_mocap_port} "
                f"(ODOMETRY, {self._mocap_rate_hz:g} Hz)"
            )
        return where

    def run(self, stop: threading.Event) -> str | None:
        """Wait until ``stop`` is set (None) or PX4 exits (returns why, with its log's tail)."""
        if self.px4 is None:
            raise RuntimeError("the SihHost is not started")
        while not stop.wait(0.5):
            if not self.px4.alive():
                return f"PX4 exited:\n{self.px4.log_tail(10)}"
        return None

    def stop(self, *, keep: bool = False) -> Path | None:
        """Stop the stand, the feeder and PX4; returns PX4's working directory if kept
        (``keep``), else None. Safe to call twice."""
        self.stand.stop()
        if self.feeder is not None:
            self.feeder.close()
        kept = self.px4.stop(keep=keep) if self.px4 is not None else None
        if self.ports is not None:
            release_instance(self.ports)
        return kept

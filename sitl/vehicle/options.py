"""How one run of the SITL vehicle is set up (:class:`RunOptions`, with its links' UDP ports
in :class:`LinkPorts`) and what it achieved (:class:`RunStats`). The vehicle that runs is
:class:`sitl.vehicle.runner.SitlVehicle`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from arm_driver.errors import HardwareErrorStatus
from sitl.physics.jsbsim import Wind
from sitl.stepping import LoopStats
from sitl.vehicle.link_faults import LinkLatency, LinkLoss, LowBattery, PilotTakeover
from sitl.vehicle.mission_phases import FaultStart, valid_start
from sitl.vehicle.navigation import ERROR_MODELS
from sitl.vehicle.servo_bus_faults import BusCorruption, ServoReboot

__all__ = ["LOCKSTEP_WAIT_S", "SERVO_ERRORS", "LinkPorts", "RunOptions", "RunStats", "ServoError"]

SERVO_ERRORS: dict[str, HardwareErrorStatus] = {
    "overload": HardwareErrorStatus.OVERLOAD,
    "overheating": HardwareErrorStatus.OVERHEATING,
    "input_voltage": HardwareErrorStatus.INPUT_VOLTAGE,
    "electrical_shock": HardwareErrorStatus.ELECTRICAL_SHOCK,
    "motor_encoder": HardwareErrorStatus.MOTOR_ENCODER,
}
"""A servo's hardware errors by name (bits of Hardware Error Status(70))."""

LOCKSTEP_WAIT_S = 0.1
"""With ``RunOptions.lockstep``: wall time the vehicle waits for the setpoint of a pose
before it goes on without it (counted; the stream counts as stopped) [s]: well inside the
companion's telemetry timeout (0.5 s), so that a stream the client stops on purpose (after
the landing) costs one short wait, not a lost link."""


@dataclass(frozen=True)
class LinkPorts:
    """UDP ports of the two MAVLink links, as PX4 SITL's defaults.

    The onboard (API) link sends from ``onboard_local`` to ``host:onboard_remote``; the
    ground-station link from ``gcs_local`` to ``host:gcs_remote``.
    """

    host: str = "127.0.0.1"
    onboard_local: int = 14580
    onboard_remote: int = 14540
    gcs_local: int = 18570
    gcs_remote: int = 14550


@dataclass(frozen=True)
class ServoError:
    """Fault injection: servo ``servo_id`` detects the hardware error ``error`` (a name of
    :data:`SERVO_ERRORS`) at ``start`` and acts as an XM430 does: the bit in Hardware Error
    Status(70), the alert bit in every status packet after, and torque off where its
    Shutdown(63) has the bit (the factory default: overheating, electrical shock,
    overload), until it is rebooted."""

    servo_id: int
    error: str
    start: FaultStart

    def __post_init__(self) -> None:
        if self.error not in SERVO_ERRORS:
            raise ValueError(f"error must be one of {', '.join(SERVO_ERRORS)}, got {self.error!r}")
        if not valid_start(self.start):
            raise ValueError(
                f"a servo error starts at a time >= 0 s or a phase, got {self.start!r}"
            )

    @property
    def bits(self) -> HardwareErrorStatus:
        """The error's bit of Hardware Error Status(70)."""
        return SERVO_ERRORS[self.error]


@dataclass(frozen=True)
class RunOptions:
    """How to run the vehicle.

    Attributes
    ----------
    speed
        Simulation seconds per wall-clock second (> 0).
    seed
        Seed of the sensor noise.
    noise
        The estimator's errors (:mod:`sitl.vehicle.navigation`) or an exact estimate.
    navigation
        The estimator's aiding: ``mocap`` (external vision, motion capture indoors; no
        global position until SET_GPS_GLOBAL_ORIGIN) or ``gps`` (GPS and baro).
    ports
        MAVLink UDP ports.
    signing_key
        32-byte MAVLink 2 signing key file; ``None``: signing off.
    truth_log
        JSON-lines ground-truth file, created (never overwritten); ``None``: none written.
    truth_rate_hz
        Truth-log lines per simulated second.
    """

    speed: float = 1.0
    seed: int = 0
    noise: bool = True
    navigation: str = "mocap"
    ports: LinkPorts = field(default_factory=LinkPorts)
    signing_key: Path | None = None
    truth_log: Path | None = None
    truth_rate_hz: float = 50.0
    physics: str = "pinocchio"
    """Truth physics backend: ``pinocchio`` or ``jsbsim`` (``sitl.physics.make_plant``)."""
    wind: Wind | None = None
    """Steady wind and turbulence in place of the scenario's steady ``plant.wind_m_s``
    (turbulence: JSBSim only)."""
    servo_silent: tuple[int, FaultStart] | None = None
    """Fault injection: (servo id, simulation time [s] or a mission phase) from which that
    servo carries out instructions but never answers again (a broken TX line)."""
    servo_error: ServoError | None = None
    """Fault injection: a servo's hardware error (overload, overheating, ...) and when."""
    bus_corruption: BusCorruption | None = None
    """Fault injection: a stretch of the servo bus's replies corrupted at a rate."""
    servo_reboot: ServoReboot | None = None
    """Fault injection: a servo rebooting by itself (RAM at defaults, torque off) and
    answering nothing while it boots."""
    servo_reply_delay_s: float = 0.0
    """Extra delay before every servo reply [s] (a USB-serial adapter's latency timer: an
    FTDI chip's default is 16 ms): wall time on the pty bus, simulated time in memory."""
    link_cut: tuple[FaultStart, float] | None = None
    """Fault injection: (simulation time [s] or a mission phase, duration [s]) of a silence
    of the onboard link, both ways (a radio or cable lost for a while)."""
    link_loss: LinkLoss | None = None
    """Fault injection: a stretch of the onboard link dropping a fraction of its messages,
    both ways (a weak radio)."""
    pilot_takeover: PilotTakeover | None = None
    """Fault injection: the pilot switching PX4's mode from the ground station."""
    link_latency: LinkLatency | None = None
    """Fault injection: a stretch of the onboard link held back, both ways (PX4 in the loop
    only)."""
    low_battery: LowBattery | None = None
    """Fault injection: PX4's simulated battery falling low (PX4 in the loop only)."""
    pose_dropout: tuple[FaultStart, float] | None = None
    """Fault injection: (simulation time [s] or a mission phase, duration [s]) of a
    motion-capture dropout: no pose reaches PX4's estimator (PX4 in the loop only)."""
    pose_jump: tuple[FaultStart, float] | None = None
    """Fault injection: (simulation time [s] or a mission phase, distance [m]) of a jump of
    the motion-capture frame: from then on every pose lies that far east (world x, ENU) of
    the truth, as after a re-calibration or a swapped marker (PX4 in the loop only)."""
    memory: str | None = None
    """Serve the links and the servo bus on in-memory channels ``NAME-onboard``,
    ``NAME-gcs`` and ``NAME-servos`` (:mod:`bytelink.memory`) instead of UDP and a pty:
    a flight on simulated time in one process (:mod:`sitl.vehicle.lockstep`), stepped by its
    caller; ``None``: UDP and a pty, paced by :meth:`sitl.vehicle.runner.SitlVehicle.run`."""
    unix_time_at_boot_us: int | None = None
    """The Unix time the autopilot booted at [us] (its SYSTEM_TIME); ``None``: now."""
    lockstep: bool = False
    """Step in lockstep with a client in another process (``sitl run --lockstep``): while
    it streams setpoints (SET_ATTITUDE_TARGET, or SET_POSITION_TARGET_LOCAL_NED) on the
    onboard link, the vehicle does not step past an
    ODOMETRY until a setpoint stamped with that pose's time (``time_boot_ms``) is in and
    the client has read the joints since (a Sync Read on the servo bus: the joint state of
    the next cycle), and runs as fast as the two go; it waits at most
    :data:`LOCKSTEP_WAIT_S` of wall time for each, then goes on (counted). Before the
    stream starts and after it stops: at ``speed``."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speed) and self.speed > 0.0):
            raise ValueError(f"speed must be a positive factor, got {self.speed!r}")
        if not (math.isfinite(self.truth_rate_hz) and self.truth_rate_hz > 0.0):
            raise ValueError(f"truth_rate_hz must be positive, got {self.truth_rate_hz!r}")
        if not (math.isfinite(self.servo_reply_delay_s) and 0.0 <= self.servo_reply_delay_s < 1.0):
            raise ValueError(
                f"servo_reply_delay_s must be 0 to 1 s, got {self.servo_reply_delay_s!r}"
            )
        for name, stretch in (("link_cut", self.link_cut), ("pose_dropout", self.pose_dropout)):
            if stretch is not None and not (
                valid_start(stretch[0]) and math.isfinite(stretch[1]) and stretch[1] > 0.0
            ):
                raise ValueError(f"{name} must be (time, positive duration), got {stretch!r}")
        if self.navigation not in ERROR_MODELS:
            raise ValueError(
                f"navigation must be one of {sorted(ERROR_MODELS)}, got {self.navigation!r}"
            )


@dataclass
class RunStats(LoopStats):
    """What one run achieved (printed by ``sitl run`` when it stops)."""

    lockstep_waits: int = 0
    """Poses after which the vehicle waited for the client's setpoint (``lockstep``)."""
    lockstep_timeouts: int = 0
    """Of those, the waits that ended without the setpoint after :data:`LOCKSTEP_WAIT_S`."""

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else 0.0

    def jitter_us(self) -> tuple[float, float]:
        """Median and 99th percentile of the step-start lateness [us]."""
        if not self.lateness_us:
            return (0.0, 0.0)
        arr = np.asarray(self.lateness_us)
        return float(np.median(arr)), float(np.percentile(arr, 99))

"""How to run PX4 in the loop of our physics (:class:`HilOptions`) and what such a run
achieved, and where its wall time went (:class:`HilStats`); the run is
:class:`sitl.hil.vehicle.Px4InTheLoop`'s."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from sitl.hil.sensors import GPS_GRADES
from sitl.px4_sitl.launcher import Px4Build
from sitl.vehicle.options import RunStats

__all__ = ["HilOptions", "HilStats"]


@dataclass(frozen=True)
class HilOptions:
    """How to run PX4 (``sitl run --autopilot px4``).

    Attributes
    ----------
    build
        The PX4 SITL build (``PX4_SITL_DIR`` or ``--px4-dir``).
    keep_dir
        Keep PX4's working directory (``px4.log``, parameters, ULog) in this directory;
        ``None``: a temporary directory, removed at the end.
    gps
        The GPS receiver with ``navigation="gps"`` (:data:`~sitl.hil.sensors.GPS_GRADES`).
    ready_timeout_s
        Longest wall time from starting PX4 until it is ready [s].
    companion_lockstep
        Hold PX4's clock after each frame until the companion has answered the last pose
        (:mod:`sitl.hil.companion_relay`, which relays PX4's onboard link through this
        process either way): the companion's computing then takes no vehicle time, on an
        idle or a busy machine. Off: the companion runs beside the lockstep (a companion
        starved of CPU then loses vehicle time, as on the vehicle).
    nice
        Lower this process's CPU priority by this much (``os.nice``) once PX4 has started
        (PX4 keeps the normal priority: with PX4 niced as well, one GPS flight on a loaded
        machine had EKF2 reset its yaw after take-off; the cause is not established). The
        physics drive the lockstep
        clock: when the CPU is short, slowing them costs only wall time. The companion (on
        the same machine in SITL; on its own computer on the vehicle) cannot slow down: a
        companion starved of CPU drops PX4's poses and sees long control periods in vehicle
        time (``loop_overrun``). 0: leave the priority alone.
    """

    build: Px4Build
    keep_dir: Path | None = None
    gps: str = "standard"
    ready_timeout_s: float = 120.0
    companion_lockstep: bool = True
    nice: int = 5

    def __post_init__(self) -> None:
        if self.gps not in GPS_GRADES:
            raise ValueError(f"gps must be one of {sorted(GPS_GRADES)}, got {self.gps!r}")
        if not 0 <= self.nice <= 19:
            raise ValueError(f"nice must be 0-19, got {self.nice!r}")


@dataclass
class HilStats(RunStats):
    """:class:`~sitl.vehicle.options.RunStats` of a run with PX4, and where the wall time went."""

    frames: int = 0
    """IMU periods simulated."""
    px4_wait_s: float = 0.0
    """Wall time spent waiting for PX4's answers [s] (PX4 computing, or descheduled)."""
    physics_s: float = 0.0
    """Wall time in the world's steps (plant, servos, gripper, truth log) [s]."""
    sensors_s: float = 0.0
    """Wall time making and sending the sensor messages [s]."""
    companion_holds: int = 0
    """Frames PX4's clock was held for the companion's answer (companion lockstep)."""
    companion_wait_s: float = 0.0
    """Wall time PX4's clock was held for the companion [s]."""
    companion_releases: int = 0
    """Holds released because the companion did not answer in time (it stopped streaming)."""
    boot_sim_s: float = 0.0
    """Simulated time until PX4 was ready [s]."""
    boot_wall_s: float = 0.0
    """Wall time until PX4 was ready [s]."""

"""What a pickup mission did: the report (written as the summary JSON) and the flight
figures it is made of (tracking error, tilt, the handover's tilt change)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.coordinates import PHI, POSITION, THETA
from companion.mission.pickup import MissionCommand, Phase

__all__ = ["FlightFigures", "MissionReport", "carrying"]

FloatArray = NDArray[np.float64]


@dataclass
class MissionReport:
    """What the mission did (written as the summary JSON)."""

    controller: str
    completed: bool = False
    """The object was carried to the place point and released there, and the vehicle
    landed (``outcome`` ``completed``)."""
    outcome: str | None = None
    """How the mission ended: ``completed``, ``grasp_failed`` (the gripper closed on
    nothing: nothing carried, flew home), ``payload_lost`` (the object left the gripper
    before the place point: carry stopped, flew home), ``beyond_authority`` (refused in the
    grasp or the lift: more thrust or servo torque than allowed; let go, flew home),
    ``aborted`` (a failsafe ended it), ``interrupted`` (the user stopped it: Ctrl-C) or
    ``failed`` (it could not start or go on)."""
    phases: list[tuple[float, str]] = field(default_factory=list)
    faults: list[dict[str, Any]] = field(default_factory=list)
    payload_mass_kg: float | None = None
    payload_mass_std_kg: float | None = None
    """Standard deviation of the payload's mass [kg], the thrust scale's in it (None
    without a fitted thrust scale)."""
    thrust_scale: dict[str, float | None] | None = None
    """The thrust scale carried with the battery (:meth:`~companion.control.flight
    .FlightControl.supply_summary`): its value, relative standard deviation, the
    calibration's voltage and the voltage now; None without one."""
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
    servo_torque: dict[str, dict[str, str | float]] = field(default_factory=dict)
    """Per joint, the torque constant flown: ``n_m_per_a`` [N m/A] and its ``source``:
    ``measured`` by the servo check before take-off (with its relative ``uncertainty``),
    ``calibrated`` on this servo (``companion arm calibrate``), or the ``datasheet``'s."""
    navigation_resets: int = 0
    """Jumps of PX4's estimate (its reset counter) seen in flight."""
    round_trip_ms: list[float] = field(default_factory=list)
    """The link's round trip per TIMESYNC reply, in vehicle time [ms]
    (:mod:`companion.mission.round_trip`)."""
    cycle_latency_us: list[float] = field(default_factory=list)
    """Pose taken from the link -> joint torques written, per cycle [us]."""
    setpoint_latency_us: list[float] = field(default_factory=list)
    """Pose taken from the link -> SET_ATTITUDE_TARGET sent (joint read included) [us]."""
    setpoint_cpu_us: list[float] = field(default_factory=list)
    """The control thread's CPU time over the same span [us] (the rest: waiting for a
    core)."""
    cycle_cpu_us: list[float] = field(default_factory=list)
    """The process's CPU time from the pose taken from the link to the cycle's log row
    written, per cycle that logged one [us]: every thread (the log's writer included)."""
    scheduling: str | None = None
    """The control thread's scheduling over the mission: ``SCHED_FIFO 50``, ``normal``."""
    cpu_share: float | None = None
    """Process CPU time / wall time over the OFFBOARD part (1.0 = one core)."""
    link_messages_per_s: float | None = None
    """Messages received on the MAVLink link per second of vehicle time over the OFFBOARD
    part."""
    streams: dict[str, Any] = field(default_factory=dict)
    """The link's streams asked (``asked_hz``: name -> rate [Hz]) and turned off
    (``stopped``) at preflight, given back to PX4's defaults at the end."""
    late_cycles: int = 0
    """Cycles later than 2.5 control periods (vehicle time); the estimator skipped them."""
    poses_dropped: int = 0
    """Poses dropped because the control loop's queue of 4 overflowed: the loop too slow to
    take them, or poses held up before the process saw them and delivered together
    (``poses_dropped_by_cause`` says which)."""
    late_cycles_by_cause: dict[str, int] = field(default_factory=dict)
    """Late cycles by who held them up (:class:`~companion.mission.loop_period.GapCause`:
    companion, host, blocked, arrival, unknown)."""
    poses_dropped_by_cause: dict[str, int] = field(default_factory=dict)
    """Dropped poses by who held them up, as ``late_cycles_by_cause``."""
    servo_retries: int = 0
    """Damaged servo replies (CRC, framing) asked for again by the arm bus."""
    servo_failures: int = 0
    """Servo bus transactions that failed (timed out, or damaged past the retries)."""
    servo_rearmed: int = 0
    """Times joints answered with their torque off after failed transactions (a servo
    rebooted by itself) and had it enabled again."""
    longest_period_ms: float | None = None
    """Longest vehicle-time gap between two control cycles [ms]."""
    estimator_skipped_steps: int = 0
    """Estimator steps skipped while it ran (late cycles, no applied force known)."""
    estimator_skipped: dict[str, int] = field(default_factory=dict)
    """The same by reason (:class:`~companion.estimation.estimator.Skip`)."""

    def as_dict(self) -> dict[str, Any]:
        return {
            "controller": self.controller,
            "completed": self.completed,
            "outcome": self.outcome,
            "phases": [{"t_s": t, "phase": p} for t, p in self.phases],
            "faults": self.faults,
            "payload_mass_kg": self.payload_mass_kg,
            "payload_mass_std_kg": self.payload_mass_std_kg,
            "payload_com_along_link2_m": self.payload_com_m,
            "thrust_scale": self.thrust_scale,
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
            "servo_torque_constants": self.servo_torque,
            "navigation_resets": self.navigation_resets,
            "round_trip_ms": _percentiles(self.round_trip_ms, longest=True),
            "cycle_latency_us": _percentiles(self.cycle_latency_us),
            "setpoint_latency_us": _percentiles(self.setpoint_latency_us),
            "setpoint_cpu_us": _percentiles(self.setpoint_cpu_us),
            "cycle_cpu_us": _percentiles(self.cycle_cpu_us),
            "scheduling": self.scheduling,
            "cpu_share_of_one_core": self.cpu_share,
            "link_messages_per_s": self.link_messages_per_s,
            "streams": self.streams,
            "late_cycles": self.late_cycles,
            "poses_dropped": self.poses_dropped,
            "late_cycles_by_cause": self.late_cycles_by_cause,
            "poses_dropped_by_cause": self.poses_dropped_by_cause,
            "servo_retries": self.servo_retries,
            "servo_failures": self.servo_failures,
            "servo_rearmed": self.servo_rearmed,
            "longest_period_ms": self.longest_period_ms,
            "estimator_skipped_steps": self.estimator_skipped_steps,
            "estimator_skipped_by_reason": self.estimator_skipped,
        }


def _percentiles(samples: list[float], longest: bool = False) -> dict[str, float] | None:
    """Median and 99th percentile of ``samples`` (and the ``max`` if ``longest``)."""
    if not samples:
        return None
    arr = np.asarray(samples)
    out = {"median": float(np.median(arr)), "p99": float(np.percentile(arr, 99))}
    if longest:
        out["max"] = float(arr.max())
    return out


class FlightFigures:
    """Figures of the OFFBOARD flight, one update per cycle flown by the controller."""

    def __init__(self) -> None:
        self._errors: list[tuple[float, bool]] = []
        """(position error [m], payload carried) per cycle."""
        self._max_tilt_rad = 0.0
        self._handover_tilt0_rad = math.nan
        self._handover_tilt_rad = 0.0
        self._accepted_s = math.nan

    def handover(self, t_s: float, q: FloatArray) -> None:
        """OFFBOARD accepted at vehicle time ``t_s`` [s] with the vehicle at ``q``."""
        self._accepted_s = t_s
        self._handover_tilt0_rad = math.hypot(float(q[PHI]), float(q[THETA]))

    def update(self, t_s: float, q: FloatArray, command: MissionCommand | None) -> None:
        """One cycle: measured state ``q`` against the mission's command."""
        tilt = math.hypot(float(q[PHI]), float(q[THETA]))
        if command is not None and command.phase != Phase.EXCITE:
            self._max_tilt_rad = max(self._max_tilt_rad, tilt)
        if t_s - self._accepted_s <= 2.0:
            change = abs(tilt - self._handover_tilt0_rad)
            self._handover_tilt_rad = max(self._handover_tilt_rad, change)
        if command is not None:
            d = q[POSITION] - command.desired.q[POSITION]
            error = math.sqrt(d.dot(d))  # np.linalg.norm's own sum, without its checks
            self._errors.append((error, carrying(command.phase)))

    def finish(self, report: MissionReport) -> None:
        """Write the figures into ``report`` (nothing if no cycle was flown)."""
        if not self._errors:
            return
        errors = np.asarray([e for e, _ in self._errors])
        report.position_rms_m = float(np.sqrt(np.mean(errors**2)))
        carried = np.asarray([e for e, with_payload in self._errors if with_payload])
        if carried.size:
            report.position_rms_with_payload_m = float(np.sqrt(np.mean(carried**2)))
        report.max_tilt_deg = math.degrees(self._max_tilt_rad)
        report.handover_tilt_deg = math.degrees(self._handover_tilt_rad)


def carrying(phase: Phase) -> bool:
    """Phases flown with the payload in the gripper."""
    return phase in (Phase.LIFT, Phase.EXCITE, Phase.TO_PLACE, Phase.LOWER)

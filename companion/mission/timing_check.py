"""Whether this computer keeps up with the control cycle: ``companion check --timing``.

Replays a recorded flight's inputs (:data:`RECORDING_PATH`: 750 cycles, 6 s of the default
virtual pickup from the grasp on, the estimator running with the payload; made by
``benchmarks/record_cycle_inputs.py``) through the flight's own parts, built from the
user's configuration, one cycle per control period:

- **sense**: the cycle's ODOMETRY (made from the recording before the replay) read from
  its frame (:mod:`companion.link.cycle_codec`) and decoded into the pose, its ZYX angles
  taken (what the link's reader and the cycle do with a pose);
- **filters**: the state filter's calls of the cycle, in its order
  (:class:`~companion.estimation.state.StateAssembler`: predict, pose, velocity, body
  rates, joints and their rates; once the filter is started in one call, as the flight's
  cycle makes them) and the battery voltage for the thrust scale;
- **step**: :meth:`FlightControl.step <companion.control.flight.FlightControl.step>`
  (estimator, control law, tilt and thrust mapping);
- **setpoint**: SET_ATTITUDE_TARGET built as the link builds it (the quaternion NED/FRD
  the compiled step made, or the link's conversion on the Python step; its MAVLink 2
  frame and CRC, :mod:`companion.link.cycle_codec`), written to nowhere;
- **log**: the cycle's row into the flight log (``flight.csv`` and ``flight.mcap``, in a
  temporary directory removed afterwards).

The replay runs under the flight loop's scheduling (``flight.realtime_priority``:
SCHED_FIFO where permitted, :func:`~companion.mission.scheduling.enter_real_time`), so
that other processes delay it no more than they would delay the flight. Each part is
timed with ``time.perf_counter``; the verdict is on the whole cycle's 99th percentile
against half the control period (the other half is the link's, the arm task's
and the event loop's: the other messages, the servo bus, the wake-ups). What the replay
leaves out (the mission's logic, the link's reader, the servo bus) is the same on every
computer, so the headroom it reports is an upper bound of what flight leaves.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import common as mavlink2

from companion.config import CompanionConfig
from companion.control.flight import FlightControl
from companion.control.laws import DesiredState
from companion.coordinates import JOINTS
from companion.estimation.estimator import Skip
from companion.estimation.state import StateAssembler
from companion.frames import ned_from_enu, quaternion_ned_frd_from_enu_flu
from companion.link.cycle_codec import attitude_target_frame, odometry_frame
from companion.link.setpoint import (
    ATTITUDE_ONLY_TYPE_MASK,
    attitude_target_ned_frd,
    checked_thrust,
    quaternion_from_euler_zyx,
)
from companion.link.telemetry import TelemetryDecoder, VehiclePose
from companion.logs.mcap_log import ArmGeometry, FlightLogWithMcap
from companion.mission.cycle import log_cycle
from companion.mission.scheduling import enter_real_time

__all__ = [
    "PARTS",
    "RECORDING",
    "RECORDING_PATH",
    "SKIP_CODES",
    "CycleInputs",
    "TimingResult",
    "check_timing",
]

RECORDING_PATH = Path(__file__).with_name("cycle_inputs.npz")
"""The shipped recording (float32 arrays, one row per cycle; NaN: no such call)."""
RECORDING = (
    "predict_dt_s", "position_m", "euler_rad", "velocity_m_s", "omega_rad_s", "voltage_v",
    "eta_rad", "eta_dot_rad_s", "joint_age_s", "step_dt_s", "qd", "qd_dot", "qd_ddot",
    "applied", "skip",
)  # fmt: skip
"""The recording's arrays: the filter's inputs, the voltage, step's period [s], desired
state, applied force (NaN row when unknown) and ``skip`` (0, else 1 + the index of the
reason in :data:`SKIP_CODES`)."""
SKIP_CODES: tuple[Skip, ...] = tuple(Skip)
PARTS = ("sense", "filters", "step", "setpoint", "log", "cycle")
"""The parts timed, the whole cycle last."""
HEADROOM_LIMIT = 0.5
"""The cycle's p99 may take at most this share of the control period."""


class _Discard:
    """A file that forgets what is written (the setpoint's bytes)."""

    def write(self, data: bytes) -> int:
        return len(data)


@dataclass(frozen=True)
class CycleInputs:
    """A recording of the cycle's inputs (see :data:`RECORDING`), one row per cycle."""

    arrays: dict[str, NDArray[np.float64]]

    @classmethod
    def load(cls, path: Path = RECORDING_PATH) -> CycleInputs:
        with np.load(path) as data:
            missing = set(RECORDING) - set(data.files)
            if missing:
                raise ValueError(f"{path}: no {sorted(missing)} in the recording")
            return cls({key: np.asarray(data[key], dtype=np.float64) for key in RECORDING})

    def __len__(self) -> int:
        return len(self.arrays["step_dt_s"])


@dataclass(frozen=True)
class TimingResult:
    """What the replay measured: each part's times per cycle [us], the rate checked, the
    scheduling it ran under (and why not real-time, if not)."""

    rate_hz: float
    times_us: dict[str, NDArray[np.float64]]
    scheduling: str = "normal"
    scheduling_note: str | None = None

    @property
    def period_us(self) -> float:
        return 1e6 / self.rate_hz

    def percentile_us(self, part: str, q: float) -> float:
        return float(np.percentile(self.times_us[part], q))

    @property
    def headroom(self) -> float:
        """The share of the control period the cycle's p99 leaves free."""
        return 1.0 - self.percentile_us("cycle", 99) / self.period_us

    @property
    def keeps_up(self) -> bool:
        """The cycle's p99 takes at most :data:`HEADROOM_LIMIT` of the period."""
        return self.percentile_us("cycle", 99) <= HEADROOM_LIMIT * self.period_us

    def verdict(self) -> str:
        """One line: the p99 cycle against the period."""
        p99, period = self.percentile_us("cycle", 99), self.period_us
        share = f"{100 * p99 / period:.0f} % of the {period:.0f} us control period"
        if self.keeps_up:
            return f"keeps up at {self.rate_hz:g} Hz: the cycle's p99 is {p99:.0f} us, {share}"
        return (
            f"too slow for {self.rate_hz:g} Hz: the cycle's p99 is {p99:.0f} us, {share} "
            f"(at most {100 * HEADROOM_LIMIT:.0f} %); fly a lower --control-rate or a faster "
            "computer"
        )


def odometry_frames(inputs: dict[str, NDArray[np.float64]], period_s: float) -> list[bytes]:
    """Each cycle's ODOMETRY as PX4 sends it (MAVLink 2 frame; NED, the velocity in the
    world's NED too, as ``child_frame_id`` says; FRD) from the recording's position,
    velocity (zero where it has none) and ZYX angles (ENU / FLU) at ``period_s`` [s]
    apart."""
    mav = mavlink2.MAVLink(_Discard(), 1, 1)
    frames = []
    unknown = [math.nan] * 21
    for i, (position, velocity, euler) in enumerate(
        zip(inputs["position_m"], inputs["velocity_m_s"], inputs["euler_rad"], strict=True)
    ):
        q_ned = quaternion_ned_frd_from_enu_flu(quaternion_from_euler_zyx(*euler))
        x, y, z = ned_from_enu(position)
        vx, vy, vz = ned_from_enu(np.nan_to_num(velocity))
        message = mav.odometry_encode(
            int(1e6 + i * period_s * 1e6), mavlink2.MAV_FRAME_LOCAL_NED,
            mavlink2.MAV_FRAME_LOCAL_NED, x, y, z, q_ned, vx, vy, vz, 0.0, 0.0, 0.0,
            unknown, unknown,
        )  # fmt: skip
        frames.append(bytes(message.pack(mav)))
    return frames


def _sense(frame: bytes, decoder: TelemetryDecoder) -> None:
    """One ODOMETRY's bytes to the pose's position and ZYX angles (the sense part: what
    the link's reader does with a datagram holding one ODOMETRY frame)."""
    fields = odometry_frame(frame)
    if fields is None:
        raise ValueError("the recording's ODOMETRY frames are not plain MAVLink 2 frames")
    for sample in decoder.odometry(fields):
        if isinstance(sample, VehiclePose):
            sample.euler_zyx_rad()


def _replay_one(
    inputs: dict[str, NDArray[np.float64]],
    i: int,
    assembler: StateAssembler,
    control: FlightControl,
) -> None:
    """The filter's calls of cycle ``i`` and the voltage (the filters part): on a started
    filter the cycle in one call, as the flight's cycle makes it
    (:meth:`StateAssembler.cycle`), before that one by one."""
    dt = float(inputs["predict_dt_s"][i])
    position, euler = inputs["position_m"][i], inputs["euler_rad"][i]
    velocity, omega = inputs["velocity_m_s"][i], inputs["omega_rad_s"][i]
    eta, eta_dot = inputs["eta_rad"][i], inputs["eta_dot_rad_s"][i]
    age = float(inputs["joint_age_s"][i])
    measured_velocity = velocity if math.isfinite(velocity[0]) else None
    measured_omega = omega if math.isfinite(omega[0]) else None
    joints = math.isfinite(eta[0])
    if math.isfinite(dt) and assembler.ready:
        assembler.cycle(
            dt, position, euler, measured_velocity, measured_omega,
            eta.tolist() if joints else None, eta_dot.tolist() if joints else None, age,
        )  # fmt: skip
    else:
        if math.isfinite(dt):
            assembler.predict(dt)
        assembler.pose(position, euler)
        if measured_velocity is not None:
            assembler.velocity(measured_velocity)
        if measured_omega is not None:
            assembler.body_rates(measured_omega)
        if joints:
            assembler.joints(eta, age)
            assembler.joint_rates(eta_dot, age)
    voltage = float(inputs["voltage_v"][i])
    control.supply(voltage if math.isfinite(voltage) else None)


def check_timing(
    config: CompanionConfig,
    rate_hz: float,
    *,
    inputs: CycleInputs | None = None,
    sleep: Callable[[float], None] = time.sleep,
) -> TimingResult:
    """Replay ``inputs`` (default: the shipped recording) through the parts built from
    ``config``, one cycle per ``1 / rate_hz`` of wall time (cycles that overrun start the
    next at once), under the flight loop's scheduling; returns each part's times. The
    replay's numbers are the recording's (its own periods): the rate paces it and sets
    the budget."""
    if not rate_hz > 0.0:
        raise ValueError(f"rate_hz must be positive, got {rate_hz}")
    recording = inputs or CycleInputs.load()
    data = recording.arrays
    n = len(recording)
    control = FlightControl(config, "passivity")
    control.estimator.resume()
    assembler = StateAssembler.from_sensors(config.sensors)
    sink = _Discard()
    times = {part: np.zeros(n) for part in PARTS}
    period_s = 1.0 / rate_hz
    frames = odometry_frames(data, period_s)
    decoder = TelemetryDecoder()
    clock = time.perf_counter
    with tempfile.TemporaryDirectory(prefix="companion-timing-") as tmp:
        log = FlightLogWithMcap(Path(tmp) / "flight.csv", ArmGeometry.from_config(config))
        log.open()
        scheduling = enter_real_time(config.flight.realtime_priority)
        try:
            next_s = clock()
            for i in range(n):
                wait = next_s - clock()
                if wait > 0.0:
                    sleep(wait)
                next_s = max(next_s + period_s, clock())
                ts = clock()
                _sense(frames[i], decoder)
                t0 = clock()
                _replay_one(data, i, assembler, control)
                t1 = clock()
                out = None
                step_dt = float(data["step_dt_s"][i])
                if math.isfinite(step_dt) and assembler.ready:
                    skip = int(data["skip"][i])
                    applied = SKIP_CODES[skip - 1] if skip else data["applied"][i]
                    desired = DesiredState(data["qd"][i], data["qd_dot"][i], data["qd_ddot"][i])
                    out = control.step(step_dt, assembler.estimate, desired, applied)
                t2 = clock()
                if out is not None:
                    sp = out.setpoint
                    q_ned: tuple[float, float, float, float] | list[float]
                    if sp.q_ned_frd is None:
                        q = quaternion_from_euler_zyx(sp.roll_rad, sp.pitch_rad, sp.yaw_rad)
                        q_ned, thrust = attitude_target_ned_frd(q, sp.thrust_relative)
                    else:
                        q_ned, thrust = sp.q_ned_frd, checked_thrust(sp.thrust_relative)
                    frame = attitude_target_frame(
                        i % 256, 1, mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER, i, 1, 1,
                        ATTITUDE_ONLY_TYPE_MASK, q_ned, thrust,
                    )  # fmt: skip
                    sink.write(frame)
                t3 = clock()
                if out is not None:
                    state = assembler.estimate
                    latency_us = (t3 - ts) * 1e6
                    log_cycle(
                        log,
                        i * period_s,
                        state,
                        out,
                        out.setpoint,
                        (out.tau[JOINTS], out.tau[JOINTS], state.q[JOINTS]),
                        (period_s * 1e3, latency_us, latency_us, latency_us),
                        px4_mode="OFFBOARD",
                        armed=True,
                        phase="lift",
                        faults=[],
                    )
                t4 = clock()
                for part, (a, b) in zip(
                    PARTS,
                    ((ts, t0), (t0, t1), (t1, t2), (t2, t3), (t3, t4), (ts, t4)),
                    strict=True,
                ):
                    times[part][i] = (b - a) * 1e6
        finally:
            scheduling.restore()
            log.close()
    return TimingResult(rate_hz, times, scheduling.policy, scheduling.note)

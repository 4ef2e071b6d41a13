"""What the flight app asks of PX4 before it arms, each a procedure over the link.

- :func:`read_vehicle_params`: the PX4 parameters the model depends on
  (:mod:`companion.mission.vehicle_params`), missing optional ones as None;
- :func:`measure_pose_period`: the mean vehicle-time period of the ODOMETRY stream over
  1 s (PX4 sends it no faster than its estimator, 125 Hz on PX4 main, whatever is asked);
- :func:`ensure_global_origin`: without GPS (motion capture indoors) PX4 has no global
  origin and refuses Hold and arming in it: set one;
- :func:`ensure_hold`: PX4 restores the mode selected before a landing (OFFBOARD after a
  mission), where arming fails without a setpoint stream: arm in Hold;
- :func:`wait_ready_to_arm`: PX4's HEARTBEAT says MAV_STATE_STANDBY once its arming
  checks pass (UNINIT while they fail: the estimator converging, a new origin settling).

Each raises :class:`PreflightError` with one line for the user, or returns what it found;
:func:`check_vehicle` runs them in order for the pickup app.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import common as mavlink2

from arm_driver.errors import ArmDriverError, BusTimeoutError
from companion.config import CompanionConfig
from companion.control.flight import FlightControl
from companion.control.laws import ControlRateError
from companion.control.setpoints import ThrustModel
from companion.link import MavlinkLink
from companion.link.errors import CommandError, ParamError
from companion.link.px4_modes import px4_mode
from companion.link.telemetry import LandedState, VehiclePose, VehicleStatus
from companion.mission.arm_supervisor import ArmSupervisor
from companion.mission.loop_period import LoopPeriodMonitor
from companion.mission.report import MissionReport
from companion.mission.streams import OnboardStreams, read_streams
from companion.mission.vehicle_params import OPTIONAL, REQUIRED, VehicleParams, contradictions

__all__ = [
    "PreflightError",
    "check_pose_rate",
    "check_vehicle",
    "ensure_global_origin",
    "ensure_hold",
    "measure_pose_period",
    "read_vehicle_params",
    "wait_ready_to_arm",
]

Note = Callable[[str, str], None]


class PreflightError(RuntimeError):
    """The vehicle is not ready to fly the mission; the message is one line."""


NO_REPLY_HINT = (
    "check the servos' power, ids and baud rate, and the USB adapter's latency timer "
    "(1 ms: README, 'Deploying on an onboard computer')"
)
"""Added to a preflight servo timeout: replies held by an FTDI adapter's default 16 ms
latency timer come after the bus's deadline as surely as none at all."""


async def check_arm(arm: ArmSupervisor) -> None:
    """The arm's check before arming: every joint answers
    (:meth:`~companion.mission.arm_supervisor.ArmSupervisor.prepare`); PreflightError
    with what to check when one does not."""
    try:
        states = await arm.prepare()
    except BusTimeoutError as exc:
        raise PreflightError(f"arm bus: {exc}; {NO_REPLY_HINT}") from None
    except ArmDriverError as exc:
        raise PreflightError(f"arm bus: {exc}") from None
    missing = set(arm.names) - set(states)
    if missing:
        raise PreflightError(f"joints {sorted(missing)} did not answer")


async def check_vehicle(
    link: MavlinkLink,
    config: CompanionConfig,
    control: FlightControl,
    report: MissionReport,
    note: Note,
    *,
    rate_hz: float,
    q_stow: NDArray[np.float64],
    loop_period: LoopPeriodMonitor,
    streams: OnboardStreams,
) -> LoopPeriodMonitor:
    """The vehicle's checks before arming, in order: the streams the companion reads
    asked (:func:`~companion.mission.streams.read_streams`: the pose at ``rate_hz``, the
    battery, the landed state), PX4's parameters against the config (its MPC_THR_MIN
    becomes ``control``'s thrust floor), the pose rate against the gains, on the ground,
    disarmed, a global origin, Hold, ready to arm. The streams it does not read are turned
    off meanwhile (``streams``, which the caller restores at the end). Returns the loop's
    period watch for the measured pose rate (the loop runs at the rate the stream
    arrives: PX4 publishes no faster than its estimator, whatever was asked)."""
    await streams.ask(read_streams(link.pose_from, rate_hz))
    stopping = asyncio.create_task(streams.stop_unread(), name="stop-unread-streams")
    try:
        params = await read_vehicle_params(link)
        problems = contradictions(params, config)
        for problem in problems[1:]:
            note("preflight", problem)
        if problems:
            raise PreflightError(problems[0])
        control.thrust = ThrustModel(control.thrust.max_thrust_n, params.thrust_min_relative)
        report.vehicle_params = params.describe()
        note("preflight", f"vehicle parameters: {report.vehicle_params}")
        watch = await check_pose_rate(
            link, control, report, note, rate_hz=rate_hz, q_stow=q_stow, loop_period=loop_period
        )
    except BaseException:
        stopping.cancel()
        await asyncio.gather(stopping, return_exceptions=True)
        raise
    await stopping
    report.streams = streams.describe()
    landed = link.latest(LandedState)
    if landed is not None and not landed.on_ground:
        raise PreflightError(f"the vehicle is not on the ground ({landed.name})")
    status = link.latest(VehicleStatus)
    if status is not None and status.armed:
        raise PreflightError("the vehicle is already armed")
    await ensure_global_origin(link, config.flight.global_origin_deg_m, note)
    await ensure_hold(link, note)
    await wait_ready_to_arm(link)
    return watch


async def check_pose_rate(
    link: MavlinkLink,
    control: FlightControl,
    report: MissionReport,
    note: Note,
    *,
    rate_hz: float,
    q_stow: NDArray[np.float64],
    loop_period: LoopPeriodMonitor,
) -> LoopPeriodMonitor:
    """The pose rate against the gains: the loop runs at the rate ODOMETRY arrives (asked at
    ``rate_hz``; PX4 publishes no faster than its estimator), its mean period becomes the
    nominal period of the returned watch."""
    period_s = await measure_pose_period(link)
    measured_hz = 1.0 / period_s
    report.control_rate_hz = measured_hz
    try:
        control.check_rate(measured_hz, q_stow)
    except ControlRateError as exc:
        raise PreflightError(
            f"ODOMETRY arrives at {measured_hz:.0f} Hz (vehicle time): {exc}; "
            "raise the link's data rate (MAV_1_RATE, SER_TEL2_BAUD) or lower the gains k"
        ) from None
    if period_s > 1.2 * loop_period.period_s:
        note(
            "loop",
            f"ODOMETRY arrives at {measured_hz:.0f} Hz, not the {rate_hz:g} Hz "
            "asked (PX4 sends it at its estimator's rate): the loop runs at that rate",
        )
    report.late_cycles_by_cause.clear()  # the new watch counts from zero
    return LoopPeriodMonitor(period_s, max(loop_period.max_period_s, period_s))


async def read_vehicle_params(link: MavlinkLink) -> VehicleParams:
    """The PX4 parameters of :mod:`companion.mission.vehicle_params`; PreflightError when a
    required one does not answer."""
    values: dict[str, float | None] = {}
    for name in REQUIRED + OPTIONAL:
        try:
            values[name] = (await link.param_read(name, timeout_s=0.3))[0]
        except ParamError:
            values[name] = None
    try:
        return VehicleParams.from_values(values)
    except KeyError as exc:
        raise PreflightError(
            f"the vehicle does not answer parameter(s) {exc.args[0]} (not PX4?)"
        ) from None


async def measure_pose_period(link: MavlinkLink) -> float:
    """Mean vehicle-time period [s] of the pose stream over 1 s (repeated timestamps are
    one pose); PreflightError when it does not come or does not advance."""
    probe = LoopPeriodMonitor(1.0, 1.0, window_s=1.0)
    last_us = -1
    with link.subscribe(VehiclePose) as poses:
        try:
            async with asyncio.timeout(5.0):
                pose = await poses.get()
        except TimeoutError:
            raise PreflightError("no ODOMETRY from the vehicle within 5 s") from None
        try:
            async with asyncio.timeout(10.0):
                while math.isnan(probe.mean_period_s):
                    if pose.time_usec > last_us:
                        probe.update(pose.time_s)
                        last_us = pose.time_usec
                    pose = await poses.get()
        except TimeoutError:
            raise PreflightError(
                "ODOMETRY stopped or its time did not advance 1 s in 10 s"
            ) from None
    return probe.mean_period_s


async def ensure_global_origin(
    link: MavlinkLink, origin_deg_m: tuple[float, ...], note: Note
) -> None:
    """Set (latitude [deg], longitude [deg], altitude AMSL [m]) as PX4's global origin
    when it has none (SET_GPS_GLOBAL_ORIGIN; PX4 echoes the one it took)."""
    if await _global_origin(link) is not None:
        return
    lat, lon, alt = origin_deg_m
    vehicle = link.vehicle
    assert vehicle is not None
    with link.subscribe("GPS_GLOBAL_ORIGIN") as origins:
        link.send_message(
            link.mav.set_gps_global_origin_encode(
                vehicle.system_id, round(lat * 1e7), round(lon * 1e7), round(alt * 1e3), 0
            )
        )
        try:  # measured: the echo comes within about 1 s
            async with asyncio.timeout(3.0):
                await origins.get()
            echoed = True
        except TimeoutError:
            echoed = False
    if not echoed and await _global_origin(link) is None:
        note("preflight", "the vehicle has no global origin and did not report ours")
        return
    note("preflight", f"global origin set to {lat:.7f}, {lon:.7f}, {alt:.1f} m")


async def _global_origin(link: MavlinkLink) -> object | None:
    """The vehicle's GPS_GLOBAL_ORIGIN (asked for with REQUEST_MESSAGE), or None."""
    with link.subscribe("GPS_GLOBAL_ORIGIN") as origins:
        try:
            await link.command_long(
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


async def ensure_hold(link: MavlinkLink, note: Note) -> None:
    """Switch PX4 to Hold (AUTO.LOITER) unless it is in it."""
    status = link.latest(VehicleStatus)
    mode = None if status is None else status.mode.name
    if mode == "LOITER":
        return
    try:
        await link.set_mode_px4(*px4_mode("LOITER"))
    except CommandError as exc:
        raise PreflightError(f"PX4 refused Hold (AUTO.LOITER): {exc}") from None
    note("preflight", f"mode {mode} -> Hold (AUTO.LOITER) to arm in")


async def wait_ready_to_arm(link: MavlinkLink, timeout_s: float = 20.0) -> None:
    """Wait for a HEARTBEAT with MAV_STATE_STANDBY; PreflightError after ``timeout_s``."""
    status = link.latest(VehicleStatus)
    with link.subscribe(VehicleStatus) as statuses:
        try:
            async with asyncio.timeout(timeout_s):
                while status is None or status.system_status != mavlink2.MAV_STATE_STANDBY:
                    status = await statuses.get()
        except TimeoutError:
            state = "no heartbeat" if status is None else _mav_state(status.system_status)
            raise PreflightError(
                f"PX4 did not report ready to arm within {timeout_s:g} s ({state}: its "
                "arming checks fail; see its messages on a ground station)"
            ) from None


def _mav_state(value: int) -> str:
    entry = mavlink2.enums["MAV_STATE"].get(value)
    return entry.name if entry is not None else f"MAV_STATE {value}"

"""The Dynamixel backend of :class:`~arm_driver.bus.ArmBus`: XM430-W350 servos, Protocol 2.0.

URL: ``dynamixel:///dev/ttyUSB0?baud=1000000`` with options ``baud`` [bit/s],
``timeout_margin_ms`` [ms], ``crc_retries``, ``low_latency`` (``0``/``1``) and
``watchdog_ms`` [ms] (0: off, the default; else 20-2540, rounded up to 20 ms).

Transactions (one at a time; the base class holds the lock):

- open: Ping every servo (model number checked), then one Read of addresses 9-70 each:
  Return Delay Time(9), Operating Mode(11), Current Limit(38), Torque Enable(64),
  Status Return Level(68), Hardware Error Status(70). A joint's torque limit is lowered
  to what its Current Limit allows;
- joint states: one Sync Read of Present Current/Velocity/Position (addresses 126-135,
  10 bytes) from every joint servo; the torque is the link's, the torque constant times
  the current less the joint's calibrated gearbox friction at the read velocity
  (:meth:`~arm_driver.joint.JointConfig.link_torque_n_m`);
- torques and positions: one Sync Write of Goal Current(102) or Goal Position(116)
  (never answered, so it costs only its own bytes on the line);
- torque on/off, operating mode, gripper, Bus Watchdog, Profile Velocity
  (:meth:`DynamixelBus.set_profile_velocity`, bench use): a Write per servo, each
  answered and checked when Status Return Level(68) is 2; torque off is written to
  every servo even when one fails, then the first error is raised. The mode is in EEPROM: a
  servo with torque on refuses it (Access Error), reported as
  :class:`~arm_driver.errors.InstructionError`.
  Entering current-based position mode writes each joint's torque limit as its Goal
  Current, which that mode uses as its current limit.

Deadlines: each transaction waits at most the time its bytes take on the line (request
and every expected reply, 10 bits per byte), plus each replying servo's Return Delay
Time, plus ``timeout_margin_s`` (default 3 ms: USB latency with low-latency mode and
scheduling). At 1 Mbit/s a missing servo in a Sync Read of two costs about 4.5 ms, then
:class:`~arm_driver.errors.BusTimeoutError`. Timeouts are not retried: a retry doubles
the stall of the control cycle, and the caller decides (the base class counts them).
Against the Python emulator (:mod:`sitl.servo.pty_server`), whose replies depend on
thread scheduling, use a larger margin, e.g. ``timeout_margin_ms=20``: measured on a
loaded two-core machine, a Sync Read of two emulated servos took 1.4 ms median and up
to 5 ms.

Late replies: a reply that comes after its request timed out (a USB-serial adapter holds
received bytes up to its latency timer, 16 ms by default on FTDI chips) arrives during a
later transaction. Input is discarded before each request, and a status packet from a
servo not asked, a second one from the same servo, or one without error whose parameter
count is not the one asked for is skipped and counted (``stale_replies``); the Dynamixel
SDK likewise reads on past a reply from another id. A late reply that looks like the one
asked for (same servo, same length) cannot be told apart: it is one transaction old.

Damaged replies (CRC, framing) and a servo's own CRC Error are retried up to
``crc_retries`` times (default 2), then raised as
:class:`~arm_driver.errors.CommunicationError`. A reply with the Alert bit makes the bus
read Hardware Error Status(70) and raise :class:`~arm_driver.errors.HardwareError` with
the decoded bits.

Safe state (see :mod:`arm_driver.bus`): joints in current or unknown mode get a Sync
Write of Goal Current 0, then of Torque Enable 0 (then of Bus Watchdog 0 with
``watchdog_ms``); all are unanswered, so they work even when only the servos' replies
are lost.

Bus Watchdog(98) (``watchdog_s``, firmware v38 and later, checked at open): the safe
state needs the host, so a host that crashes or hangs would leave current-mode joints
at their last Goal Current. With the watchdog, a joint servo that hears no instruction
packet for longer than the timeout stops by itself (e-Manual: it "will stop", Bus
Watchdog reads -1, goal writes get a Data Range Error until 0 is written; Torque
Enable is not said to change). The Sync Read and Sync Write of each control cycle
list every joint, so they keep it alive. :meth:`enable_torque` arms it on the joints
in current mode only, after this sequence per joint: Torque Enable 0, Bus Watchdog 0
(clears a trip), Goal Current 0 (the manual does not say whether a cleared servo goes
back to its old goal: this one has none), then Torque Enable 1, then the timeout.
Joints in a position mode get Bus Watchdog 0 and the gripper is not touched: their
goals come only when the caller moves them, a trip would refuse the next goal, and
holding the last goal is already their safe state. After a trip, torque commands are
refused without a word (a Sync Write is never answered) and the joints read zero
torque; call :meth:`enable_torque` to resume. A process that crashed with the watchdog
on leaves Bus Watchdog -1 behind: open the bus with ``watchdog_ms`` set (any value) so
that :meth:`enable_torque` clears it, or power-cycle the servos. Off by default: older
firmware has no address 98, and a caller that pauses longer than the timeout between
torque commands (bench tools, a SITL faster than real time) would find them refused;
a flight configuration turns it on in its bus URL.
"""

from __future__ import annotations

import asyncio
import dataclasses
import functools
import math
import time
from collections.abc import Callable, Coroutine, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Concatenate, ParamSpec, TypeVar

from arm_driver.bus import (
    ArmBus,
    BusStateError,
    DeviceInfo,
    GripperConfig,
    GripperState,
    JointConfig,
    JointState,
    OperatingMode,
)
from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units
from arm_driver.dynamixel.instructions import (
    SyncWriteFrame,
    encode_ping,
    encode_read,
    encode_sync_read,
    encode_write,
    parse_ping_reply,
    parse_read_reply,
    parse_sync_read_replies,
    parse_write_reply,
)
from arm_driver.dynamixel.protocol import MAX_ID, StatusPacket
from arm_driver.dynamixel.stream import StatusParser
from arm_driver.dynamixel.transport import open_transport
from arm_driver.errors import (
    ArmDriverError,
    BusTimeoutError,
    CommunicationError,
    HardwareError,
    HardwareErrorStatus,
    InstructionError,
    StatusError,
)
from arm_driver.url import convert_options, flag, milliseconds

__all__ = ["DynamixelBus"]

_STATUS_OVERHEAD = 11
"""Bytes of a status packet besides its parameters: header 4, id, length 2, 0x55, error, CRC 2."""
_UNKNOWN_RETURN_DELAY_S = 255 * 2e-6
"""Return delay assumed before a servo's Return Delay Time(9) is read: the largest [s]."""
_WATCHDOG_FIRMWARE = 38
"""First firmware version with Bus Watchdog(98) (e-Manual)."""
_INFO_START = ct.RETURN_DELAY_TIME.address
_INFO_LENGTH = ct.HARDWARE_ERROR_STATUS.end - _INFO_START
_STATE = ct.block_struct((ct.PRESENT_CURRENT, ct.PRESENT_VELOCITY, ct.PRESENT_POSITION))
"""Present Current, Velocity and Position, read in one Sync Read [raw units]."""
_STATE_START = ct.PRESENT_CURRENT.address
_STATE_LENGTH = _STATE.size
_MODES = {
    OperatingMode.CURRENT: ct.OperatingMode.CURRENT,
    OperatingMode.POSITION: ct.OperatingMode.POSITION,
    OperatingMode.CURRENT_BASED_POSITION: ct.OperatingMode.CURRENT_BASED_POSITION,
}
_POSITION_MODES = {
    ct.OperatingMode.POSITION,
    ct.OperatingMode.EXTENDED_POSITION,
    ct.OperatingMode.CURRENT_BASED_POSITION,
}

T = TypeVar("T")
P = ParamSpec("P")
_MODEL_NAMES = {ct.XM430_W350_MODEL_NUMBER: "XM430-W350"}


@dataclass(frozen=True)
class _Servo:
    """What the bus learnt about a servo when it opened."""

    return_delay_s: float
    mode: int
    current_limit_units: int
    torque_enabled: bool
    answers_writes: bool


def _field(data: bytes, entry: ct.ControlTableEntry) -> int:
    return entry.decode(data[entry.address - _INFO_START : entry.end - _INFO_START])


def _hardware_details(
    method: Callable[Concatenate[DynamixelBus, P], Coroutine[Any, Any, T]],
) -> Callable[Concatenate[DynamixelBus, P], Coroutine[Any, Any, T]]:
    """On an Alert, read Hardware Error Status(70) and raise HardwareError with its bits."""

    @functools.wraps(method)
    async def wrapper(self: DynamixelBus, /, *args: P.args, **kwargs: P.kwargs) -> T:
        try:
            return await method(self, *args, **kwargs)
        except HardwareError as error:
            servo_id = error.servo_id
            if error.status is not None or servo_id is None:
                raise
            data = await self._read(servo_id, ct.HARDWARE_ERROR_STATUS, ignore_alert=True)
            bits = HardwareErrorStatus(ct.HARDWARE_ERROR_STATUS.decode(data))
            raise HardwareError(servo_id, bits, error_number=error.error_number) from error

    return wrapper


class DynamixelBus(ArmBus):
    """XM430-W350 servos on a Protocol 2.0 serial bus, in joint space.

    Parameters
    ----------
    device
        Serial device, e.g. ``/dev/ttyUSB0``.
    joints
        The arm's joints (servo ids 0-252).
    gripper
        The gripper's servo, if any (in a position mode, set in its EEPROM).
    baudrate
        Line rate [bit/s]; must match the servos' Baud Rate(8).
    timeout_margin_s
        Added to each transaction's computed deadline [s].
    crc_retries
        Retries of a transaction whose reply was damaged.
    max_consecutive_failures
        Link failures in a row that mark the bus failed.
    model_number
        Model Number(0) every servo must report (1020: XM430-W350).
    low_latency
        Ask for the serial driver's low-latency mode.
    watchdog_s
        Bus Watchdog(98) timeout of the current-mode joints [s]: 0 (off) or 0.02-2.54,
        rounded up to a multiple of 0.02.
    """

    def __init__(
        self,
        device: str,
        joints: Sequence[JointConfig],
        *,
        gripper: GripperConfig | None = None,
        baudrate: int = 1_000_000,
        timeout_margin_s: float = 0.003,
        crc_retries: int = 2,
        max_consecutive_failures: int = 3,
        model_number: int = ct.XM430_W350_MODEL_NUMBER,
        low_latency: bool = True,
        watchdog_s: float = 0.0,
    ) -> None:
        super().__init__(joints, gripper=gripper, max_consecutive_failures=max_consecutive_failures)
        ids = [joint.servo_id for joint in self.joints] + ([gripper.servo_id] if gripper else [])
        for servo_id in ids:
            if not 0 <= servo_id <= MAX_ID:
                raise ValueError(f"Dynamixel servo id {servo_id} out of range (0-{MAX_ID})")
        if not timeout_margin_s >= 0.0:
            raise ValueError(f"timeout_margin_s {timeout_margin_s} must be >= 0")
        if crc_retries < 0:
            raise ValueError(f"crc_retries {crc_retries} must be >= 0")
        self._watchdog_units = _watchdog_units(watchdog_s)
        self._ids = ids
        self._joint_ids = [joint.servo_id for joint in self.joints]
        self._margin_s = timeout_margin_s
        self._crc_retries = crc_retries
        self._model_number = model_number
        self._transport = open_transport(device, baudrate, low_latency=low_latency)
        self._parser = StatusParser()
        self._servos: dict[int, _Servo] = {}
        self._state_request = encode_sync_read(_STATE_START, _STATE_LENGTH, self._joint_ids)
        self._sync_writes: dict[tuple[int, tuple[int, ...]], SyncWriteFrame] = {}
        self.stale_replies = 0
        """Status packets skipped as late answers to an earlier request (see the module
        docstring)."""

    @property
    def watchdog_s(self) -> float:
        """Bus Watchdog(98) timeout of the current-mode joints [s] (0: off)."""
        return self._watchdog_units * ct.BUS_WATCHDOG_UNIT_S

    @classmethod
    def options_from_url(cls, options: Mapping[str, str]) -> dict[str, Any]:
        """``baud``, ``timeout_margin_ms``, ``crc_retries``, ``low_latency``,
        ``watchdog_ms`` -> keywords."""
        convert: dict[str, tuple[str, Callable[[str], Any]]] = {
            "baud": ("baudrate", int),
            "timeout_margin_ms": ("timeout_margin_s", milliseconds),
            "crc_retries": ("crc_retries", int),
            "low_latency": ("low_latency", flag),
            "watchdog_ms": ("watchdog_s", milliseconds),
        }
        return convert_options("dynamixel", options, convert)

    @classmethod
    async def scan(cls, device: str, ids: Sequence[int], **options: Any) -> list[DeviceInfo]:
        """Ping each id in ``ids`` (those above 252 are skipped); one deadline per id."""
        ids = [i for i in ids if 0 <= i <= MAX_ID]
        probe = cls(device, [JointConfig("probe", 0, 1.0, 0.0)], **options)
        found = []
        await probe._transport.open()
        try:
            for servo_id in ids:
                try:
                    (reply,) = await probe._exchange(encode_ping(servo_id), [servo_id], 3)
                except BusTimeoutError:
                    continue
                info = parse_ping_reply(reply, servo_id, ignore_alert=True)
                name = _MODEL_NAMES.get(info.model_number, "unknown model")
                found.append(
                    DeviceInfo(
                        servo_id,
                        f"Dynamixel model {info.model_number} ({name})",
                        str(info.firmware_version),
                    )
                )
        finally:
            probe._transport.close()
        return found

    async def set_profile_velocity(self, rates_rad_s: Mapping[str, float]) -> None:
        """Profile Velocity(112) of joints [rad/s, joint rate magnitude]; 0 turns it off.

        In a position mode a servo with a Profile Velocity moves to each new Goal Position
        along a ramp it generates itself at that rate (velocity-based profile; Profile
        Acceleration(108) is left as it is, 0 from the factory: no ramp of the rate). A
        smooth constant-speed move, without a stream of goals from the host (each new goal
        jerks the arm by the position loop's stiffness times the goal's step). Bench use
        (``companion arm calibrate``); one answered Write per joint.

        Raises
        ------
        ValueError
            A rate that is negative, not finite, or beyond the register's range.
        """
        commands = self._joint_commands(rates_rad_s)
        values = {}
        for joint, rate in commands.items():
            if not (math.isfinite(rate) and rate >= 0.0):
                raise ValueError(f"joint {joint.name!r}: profile velocity {rate} rad/s")
            value = max(units.rad_s_to_velocity_units(rate), 1 if rate > 0.0 else 0)
            if value > ct.PROFILE_VELOCITY_MAX:
                raise ValueError(
                    f"joint {joint.name!r}: profile velocity {rate:g} rad/s above the "
                    f"register's {ct.PROFILE_VELOCITY_MAX} x 0.229 rev/min"
                )
            values[joint.servo_id] = value
        await self._transact(self._write_profile_velocities, values)

    @_hardware_details
    async def _write_profile_velocities(self, values: Mapping[int, int]) -> None:
        for servo_id, value in values.items():
            await self._write(servo_id, ct.PROFILE_VELOCITY, value)

    # -- transactions -------------------------------------------------------------------

    def _timeout_s(self, request_bytes: int, repliers: Sequence[int], reply_params: int) -> float:
        line_bytes = request_bytes + len(repliers) * (_STATUS_OVERHEAD + reply_params)
        delays = sum(
            self._servos[i].return_delay_s if i in self._servos else _UNKNOWN_RETURN_DELAY_S
            for i in repliers
        )
        return line_bytes * self._transport.byte_time_s + delays + self._margin_s

    async def _exchange(
        self, packet: bytes, repliers: Sequence[int], reply_params: int
    ) -> list[StatusPacket]:
        """Send ``packet``; return one status packet per id in ``repliers`` (retrying CRC)."""
        for attempt in range(self._crc_retries + 1):
            try:
                return await self._exchange_once(packet, repliers, reply_params)
            except BusTimeoutError:
                raise
            except (CommunicationError, InstructionError) as error:
                retry = isinstance(error, CommunicationError) or error.error is StatusError.CRC
                if not retry:
                    raise
                if attempt == self._crc_retries:
                    error.add_note(f"gave up after {attempt + 1} attempt(s)")
                    raise
                self.retried_replies += 1
        raise AssertionError("unreachable")

    async def _exchange_once(
        self, packet: bytes, repliers: Sequence[int], reply_params: int
    ) -> list[StatusPacket]:
        transport, parser = self._transport, self._parser
        transport.discard_input()
        parser.clear()
        transport.write(packet)
        if not repliers:
            return []
        timeout_s = self._timeout_s(len(packet), repliers, reply_params)
        deadline = asyncio.get_running_loop().time() + timeout_s
        replies: list[StatusPacket] = []
        damaged: CommunicationError | None = None
        while len(replies) < len(repliers):
            chunk = await transport.read(deadline)
            if not chunk:
                break
            parser.feed(chunk)
            while True:
                try:
                    reply = parser.next_packet()
                except CommunicationError as error:
                    damaged = damaged or error
                    continue
                if reply is None:
                    break
                if _stale(reply, repliers, replies, reply_params):
                    self.stale_replies += 1
                    continue
                replies.append(reply)
        if damaged is not None:
            raise damaged
        if len(replies) < len(repliers):
            answered = {reply.servo_id for reply in replies}
            missing = [i for i in repliers if i not in answered]
            timeout = BusTimeoutError(missing[0], timeout_s, received_bytes=parser.buffered)
            if len(missing) > 1:
                timeout.add_note(f"servos {missing} did not answer")
            raise timeout
        for reply in replies:
            if reply.error == StatusError.CRC:  # the servo got our packet damaged
                raise InstructionError(reply.servo_id, reply.error)
        return replies

    async def _read(
        self, servo_id: int, entry: ct.ControlTableEntry, *, ignore_alert: bool = False
    ) -> bytes:
        return await self._read_range(
            servo_id, entry.address, entry.size, ignore_alert=ignore_alert
        )

    async def _read_range(
        self, servo_id: int, address: int, length: int, *, ignore_alert: bool = False
    ) -> bytes:
        (reply,) = await self._exchange(encode_read(servo_id, address, length), [servo_id], length)
        return parse_read_reply(reply, servo_id, length, ignore_alert=ignore_alert)

    async def _write(self, servo_id: int, entry: ct.ControlTableEntry, value: int) -> None:
        answers = self._servos[servo_id].answers_writes
        packet = encode_write(servo_id, entry.address, entry.encode(value))
        replies = await self._exchange(packet, [servo_id] if answers else [], 0)
        for reply in replies:
            parse_write_reply(reply, servo_id)

    async def _sync_write(self, entry: ct.ControlTableEntry, values: Mapping[int, int]) -> None:
        ids = tuple(values)
        frame = self._sync_writes.get((entry.address, ids))
        if frame is None:
            frame = SyncWriteFrame(entry.address, entry.size, ids)
            self._sync_writes[entry.address, ids] = frame
        packet = frame.packet([entry.encode(value) for value in values.values()])
        await self._exchange(packet, [], 0)

    # -- hooks ------------------------------------------------------------------------------

    async def _open_hook(self) -> tuple[OperatingMode | None, bool | None]:
        self._servos.clear()
        await self._transport.open()
        for servo_id in self._ids:
            (reply,) = await self._exchange(encode_ping(servo_id), [servo_id], 3)
            ping = parse_ping_reply(reply, servo_id, ignore_alert=True)
            if ping.model_number != self._model_number:
                raise ArmDriverError(
                    f"servo {servo_id} is model {ping.model_number}, expected {self._model_number}",
                    servo_id=servo_id,
                )
            watched = self._watchdog_units and servo_id in self._joint_ids
            if watched and ping.firmware_version < _WATCHDOG_FIRMWARE:
                raise ArmDriverError(
                    f"servo {servo_id} has firmware v{ping.firmware_version}, without "
                    f"Bus Watchdog(98) (v{_WATCHDOG_FIRMWARE} and later): update it or "
                    "open the bus without watchdog_ms",
                    servo_id=servo_id,
                )
            info = await self._read_range(servo_id, _INFO_START, _INFO_LENGTH, ignore_alert=True)
            bits = HardwareErrorStatus(_field(info, ct.HARDWARE_ERROR_STATUS))
            if bits:
                raise HardwareError(servo_id, bits)
            self._servos[servo_id] = _Servo(
                return_delay_s=_field(info, ct.RETURN_DELAY_TIME) * 2e-6,
                mode=_field(info, ct.OPERATING_MODE),
                current_limit_units=_field(info, ct.CURRENT_LIMIT),
                torque_enabled=_field(info, ct.TORQUE_ENABLE) == 1,
                answers_writes=_field(info, ct.STATUS_RETURN_LEVEL) == ct.StatusReturnLevel.ALL,
            )
        for joint in self.joints:
            limit_a = units.current_units_to_a(self._servos[joint.servo_id].current_limit_units)
            self._limit_torque(joint.name, limit_a * joint.torque_constant_n_m_per_a)
        modes = {self._servos[i].mode for i in self._joint_ids}
        by_raw: dict[int, OperatingMode] = {raw: mode for mode, raw in _MODES.items()}
        mode = by_raw.get(modes.pop()) if len(modes) == 1 else None
        torques = {servo.torque_enabled for servo in self._servos.values()}
        return mode, (torques.pop() if len(torques) == 1 else None)

    async def _close_hook(self) -> None:
        self._transport.close()

    @_hardware_details
    async def _set_torque_hook(self, enabled: bool) -> None:
        if not enabled:
            await self._torque_off_every_servo()
            return
        watch = self._watchdog_units > 0
        if watch:
            await self._clear_watchdogs()
        for servo_id in self._ids:
            await self._write(servo_id, ct.TORQUE_ENABLE, 1)
        if watch:
            for servo_id in self._current_mode_joints():
                await self._write(servo_id, ct.BUS_WATCHDOG, self._watchdog_units)

    async def _torque_off_every_servo(self) -> None:
        """Torque Enable 0 written to every servo, even after one did not answer or answered
        garbled (the late reply of an interrupted read); then the first error is raised."""
        failure: ArmDriverError | None = None
        for servo_id in self._ids:
            try:
                await self._write(servo_id, ct.TORQUE_ENABLE, 0)
            except ArmDriverError as error:
                failure = failure or error
        if failure is not None:
            raise failure

    def _current_mode_joints(self) -> list[int]:
        return [i for i in self._joint_ids if self._servos[i].mode == ct.OperatingMode.CURRENT]

    async def _clear_watchdogs(self) -> None:
        """Bus Watchdog 0 on every joint; a current-mode one gets torque off before and
        Goal Current 0 after, so a trip is cleared without its old goal coming back."""
        limp = self._current_mode_joints()
        for servo_id in self._joint_ids:
            if servo_id in limp:
                await self._write(servo_id, ct.TORQUE_ENABLE, 0)
            await self._write(servo_id, ct.BUS_WATCHDOG, 0)
            if servo_id in limp:
                await self._write(servo_id, ct.GOAL_CURRENT, 0)

    @_hardware_details
    async def _set_mode_hook(self, mode: OperatingMode) -> None:
        for servo_id in self._joint_ids:
            try:
                await self._write(servo_id, ct.OPERATING_MODE, _MODES[mode])
            except InstructionError as error:
                if error.error is StatusError.ACCESS:
                    error.add_note("Operating Mode(11) is in EEPROM: the servo's torque is on")
                raise
            self._servos[servo_id] = dataclasses.replace(self._servos[servo_id], mode=_MODES[mode])
        if mode is OperatingMode.CURRENT_BASED_POSITION:
            await self._sync_write(
                ct.GOAL_CURRENT,
                {
                    joint.servo_id: self._current_units(joint, self.torque_limit_n_m(joint.name))
                    for joint in self.joints
                },
            )

    def _current_units(self, joint: JointConfig, torque_n_m: float) -> int:
        """Goal Current [2.69 mA] for a joint torque [N m] (the motor's: no friction
        feed-forward, see :mod:`arm_driver.joint`), within the Current Limit."""
        current_a = joint.servo_current_a(torque_n_m)
        limit = self._servos[joint.servo_id].current_limit_units
        return max(-limit, min(limit, units.a_to_current_units(current_a)))

    @_hardware_details
    async def _write_torques_hook(self, torques_n_m: Mapping[JointConfig, float]) -> None:
        values = {joint.servo_id: self._current_units(joint, t) for joint, t in torques_n_m.items()}
        await self._sync_write(ct.GOAL_CURRENT, values)

    @_hardware_details
    async def _write_positions_hook(self, positions_rad: Mapping[JointConfig, float]) -> None:
        values = {
            joint.servo_id: units.rad_to_ticks(joint.servo_angle_rad(angle))
            for joint, angle in positions_rad.items()
        }
        await self._sync_write(ct.GOAL_POSITION, values)

    @_hardware_details
    async def _read_states_hook(self) -> dict[str, JointState]:
        ids = self._joint_ids
        replies = await self._exchange(self._state_request, ids, _STATE_LENGTH)
        stamp = time.monotonic()
        data = parse_sync_read_replies(replies, ids, _STATE_LENGTH)
        states = {}
        for joint in self.joints:
            current, velocity, position = _STATE.unpack(data[joint.servo_id])
            rate_rad_s = joint.direction * units.velocity_units_to_rad_s(velocity)
            states[joint.name] = JointState(
                name=joint.name,
                position_rad=joint.joint_angle_rad(units.ticks_to_rad(position)),
                velocity_rad_s=rate_rad_s,
                torque_n_m=joint.link_torque_n_m(units.current_units_to_a(current), rate_rad_s),
                timestamp_s=stamp,
            )
        return states

    @_hardware_details
    async def _torque_off_hook(self) -> list[str]:
        off = []
        for joint in self.joints:
            data = await self._read(joint.servo_id, ct.TORQUE_ENABLE)
            if ct.TORQUE_ENABLE.decode(data) == 0:
                off.append(joint.name)
        return off

    @_hardware_details
    async def _write_gripper_hook(self, servo_angle_rad: float) -> None:
        gripper = self.gripper
        assert gripper is not None
        if self._servos[gripper.servo_id].mode not in _POSITION_MODES:
            raise BusStateError(
                f"gripper servo {gripper.servo_id} is not in a position mode "
                f"(Operating Mode(11) = {self._servos[gripper.servo_id].mode})"
            )
        await self._write(gripper.servo_id, ct.GOAL_POSITION, units.rad_to_ticks(servo_angle_rad))

    @_hardware_details
    async def _read_gripper_hook(self) -> GripperState:
        gripper = self.gripper
        assert gripper is not None
        # A Sync Read of one servo, as the joints': a late reply of an earlier read that
        # arrives with this one is a CommunicationError (a counted link failure).
        ids = [gripper.servo_id]
        packet = encode_sync_read(_STATE_START, _STATE_LENGTH, ids)
        replies = await self._exchange(packet, ids, _STATE_LENGTH)
        raw = parse_sync_read_replies(replies, ids, _STATE_LENGTH)[gripper.servo_id]
        current, _, position = _STATE.unpack(raw)
        return GripperState(
            position_rad=units.ticks_to_rad(position),
            current_a=units.current_units_to_a(current),
            timestamp_s=time.monotonic(),
        )

    async def _safe_state_hook(self) -> None:
        if self.operating_mode not in (OperatingMode.CURRENT, None):
            return
        if not self._transport.is_open:
            return
        await self._sync_write(ct.GOAL_CURRENT, dict.fromkeys(self._joint_ids, 0))
        await self._sync_write(ct.TORQUE_ENABLE, dict.fromkeys(self._joint_ids, 0))
        if self._watchdog_units:  # after torque off, so that clearing a trip moves nothing
            await self._sync_write(ct.BUS_WATCHDOG, dict.fromkeys(self._joint_ids, 0))


def _watchdog_units(watchdog_s: float) -> int:
    """Bus Watchdog(98) value for a timeout [s] (0: off), rounded up to 20 ms."""
    unit_s = ct.BUS_WATCHDOG_UNIT_S
    if not (watchdog_s == 0.0 or unit_s <= watchdog_s <= ct.BUS_WATCHDOG_MAX * unit_s):
        raise ValueError(
            f"bus watchdog {watchdog_s * 1e3:g} ms must be 0 (off) or 20-2540 ms "
            "(Bus Watchdog(98) counts 1-127 x 20 ms)"
        )
    return math.ceil(round(watchdog_s / unit_s, 6))


def _stale(
    reply: StatusPacket,
    repliers: Sequence[int],
    taken: Sequence[StatusPacket],
    reply_params: int,
) -> bool:
    """True if ``reply`` cannot answer this request: from a servo not asked or already
    answered, or without error and not carrying the ``reply_params`` bytes asked for."""
    if reply.servo_id not in repliers or any(r.servo_id == reply.servo_id for r in taken):
        return True
    return reply.error == 0 and not reply.alert and len(reply.params) != reply_params

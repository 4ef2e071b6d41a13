"""COMMAND_LONG with retries and COMMAND_ACK, the PX4 commands built on it, and parameters.

This is the command half of :class:`companion.link.mavlink.MavlinkLink` (a base class
of it, kept in its own module); it uses only the link's public surface: ``subscribe``,
``send_message``, ``mav``, ``vehicle`` and the ids.

The MAVLink command protocol: send COMMAND_LONG with ``confirmation`` 0, and 1, 2, ...
on retransmissions; the target answers COMMAND_ACK with the command id and a MAV_RESULT.
ACCEPTED succeeds; IN_PROGRESS means a final ACK follows (no retransmission after it);
any other result raises :class:`CommandDenied`. No final ACK after the attempts raises
:class:`CommandTimeout`. Commands with the same id are serialized, as the protocol
requires; different ids may run at once.

The parameter protocol: PARAM_REQUEST_READ by name is answered with PARAM_VALUE; PARAM_SET
is answered with the PARAM_VALUE the vehicle kept. PX4 carries an INT32 parameter's four
bytes in the float field unchanged ("bytewise", MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE),
so values are decoded and encoded by ``param_type`` (:func:`decode_param_value`,
:func:`encode_param_value`).
"""

from __future__ import annotations

import asyncio
import math
import struct
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Literal, TypedDict, Unpack, overload

from pymavlink.dialects.v20 import common as mavlink2

from companion.link.errors import (
    CommandDenied,
    CommandTimeout,
    ParamRefused,
    ParamTimeout,
    VehicleNotFoundError,
)
from companion.link.events import VehicleId
from companion.link.fanout import Key, Subscription
from companion.link.messages import CommandAck, MavlinkMessage, MessageInterval, ParamValue

__all__ = [
    "ARM_FORCE_MAGIC",
    "CommandOptions",
    "Px4Commands",
    "decode_param_value",
    "encode_param_value",
]

ARM_FORCE_MAGIC = 21196.0
"""param2 of MAV_CMD_COMPONENT_ARM_DISARM that overrides PX4's pre-arm / landed checks."""


_INT_TYPES = {
    mavlink2.MAV_PARAM_TYPE_UINT8: "<B",
    mavlink2.MAV_PARAM_TYPE_INT8: "<b",
    mavlink2.MAV_PARAM_TYPE_UINT16: "<H",
    mavlink2.MAV_PARAM_TYPE_INT16: "<h",
    mavlink2.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink2.MAV_PARAM_TYPE_INT32: "<i",
}
"""Integer parameter types and the little-endian layout of their bytes in the float."""


def decode_param_value(wire: float, param_type: int) -> float:
    """The value a PARAM_VALUE / PARAM_SET float ``wire`` carries for ``param_type``
    (bytewise for integer types, as PX4 encodes them)."""
    layout = _INT_TYPES.get(param_type)
    if layout is None:
        return float(wire)
    raw = struct.pack("<f", wire)
    return float(struct.unpack(layout, raw[: struct.calcsize(layout)])[0])


def encode_param_value(value: float, param_type: int) -> float:
    """The float to put in PARAM_SET for ``value`` of ``param_type`` (bytewise for
    integer types); ValueError for a non-integer value of an integer type."""
    layout = _INT_TYPES.get(param_type)
    if layout is None:
        return float(value)
    if not float(value).is_integer():
        raise ValueError(f"{value!r} is not an integer")
    raw = struct.pack(layout, int(value)).ljust(4, b"\0")
    return struct.unpack("<f", raw)[0]


class CommandOptions(TypedDict, total=False):
    """Keywords of :meth:`Px4Commands.command_long` that the commands built on it pass on."""

    timeout_s: float
    attempts: int
    target_component: int | None
    confirm_s: float


def _enum_name(enum: str, value: int) -> str:
    entry = mavlink2.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else f"{enum}({value})"


class Px4Commands(ABC):
    """Commands of :class:`MavlinkLink` (see the module docstring); the abstract methods
    are the link's."""

    system_id: int
    component_id: int
    _command_locks: dict[int, asyncio.Lock]

    @overload
    def subscribe(
        self, key: Literal["COMMAND_ACK"], /, *, maxsize: int = 64
    ) -> Subscription[CommandAck]: ...
    @overload
    def subscribe(
        self, key: Literal["PARAM_VALUE"], /, *, maxsize: int = 64
    ) -> Subscription[ParamValue]: ...
    @overload
    def subscribe(
        self, key: Literal["MESSAGE_INTERVAL"], /, *, maxsize: int = 64
    ) -> Subscription[MessageInterval]: ...
    @abstractmethod
    def subscribe(self, *keys: Key, maxsize: int = 64) -> Subscription[object]: ...

    @abstractmethod
    def send_message(self, msg: MavlinkMessage) -> None: ...

    @property
    @abstractmethod
    def mav(self) -> mavlink2.MAVLink: ...

    @property
    @abstractmethod
    def vehicle(self) -> VehicleId | None: ...

    async def command_long(
        self,
        command: int,
        params: Sequence[float] = (),
        *,
        timeout_s: float = 0.5,
        attempts: int = 3,
        target_component: int | None = None,
        confirm_s: float = 0.0,
    ) -> CommandAck:
        """Send MAV_CMD ``command`` with up to 7 ``params`` (the rest 0) to the vehicle
        and wait for its final COMMAND_ACK, resending after each ``timeout_s`` [s] up to
        ``attempts`` times in all. Returns the ACCEPTED ack (a pymavlink message).

        ``confirm_s`` [s] > 0 keeps listening that long after an ACCEPTED ack: another ack
        of the same command that does not accept it wins (PX4 answers DO_SET_MODE twice,
        and the two can disagree: measured on PX4 main, a refused Hold came as ACCEPTED
        then TEMPORARILY_REJECTED).

        Raises ``CommandDenied`` (``.result``), ``CommandTimeout``, or
        ``VehicleNotFoundError`` before the vehicle is detected.
        """
        if len(params) > 7:
            raise ValueError(f"COMMAND_LONG has 7 params, got {len(params)}")
        if attempts < 1 or not timeout_s > 0.0:
            raise ValueError("attempts must be >= 1 and timeout_s positive")
        vehicle = self.vehicle
        if vehicle is None:
            raise VehicleNotFoundError("no vehicle detected yet")
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        component = vehicle.component_id if target_component is None else target_component
        name = _enum_name("MAV_CMD", command)
        loop = asyncio.get_running_loop()
        lock = self._command_locks.setdefault(command, asyncio.Lock())
        async with lock:
            with self.subscribe("COMMAND_ACK", maxsize=16) as acks:
                in_progress = False
                attempt = 0
                while attempt < attempts:
                    if not in_progress:
                        self.send_message(
                            self.mav.command_long_encode(
                                vehicle.system_id, component, command, attempt, *p
                            )
                        )
                        attempt += 1
                    ack = await self._await_ack(acks, command, vehicle, loop.time() + timeout_s)
                    if ack is None:
                        if in_progress:
                            break
                        continue
                    if ack.result == mavlink2.MAV_RESULT_ACCEPTED:
                        if confirm_s > 0.0:
                            later = await self._await_ack(
                                acks, command, vehicle, loop.time() + confirm_s
                            )
                            if later is not None and later.result not in (
                                mavlink2.MAV_RESULT_ACCEPTED,
                                mavlink2.MAV_RESULT_IN_PROGRESS,
                            ):
                                result = later.result
                                raise CommandDenied(
                                    command, result, name, _enum_name("MAV_RESULT", result)
                                )
                        return ack
                    if ack.result == mavlink2.MAV_RESULT_IN_PROGRESS:
                        in_progress = True
                        continue
                    raise CommandDenied(
                        command, ack.result, name, _enum_name("MAV_RESULT", ack.result)
                    )
        raise CommandTimeout(command, name, attempt, timeout_s)

    async def _await_ack(
        self, acks: Subscription[CommandAck], command: int, vehicle: VehicleId, deadline: float
    ) -> CommandAck | None:
        """The next COMMAND_ACK of ``command`` from the vehicle to us, or None at the
        deadline (loop time [s])."""
        try:
            async with asyncio.timeout_at(deadline):
                while True:
                    ack = await acks.get()
                    if (
                        ack.command == command
                        and ack.get_srcSystem() == vehicle.system_id
                        and ack.target_system in (0, self.system_id)
                        and ack.target_component in (0, self.component_id)
                    ):
                        return ack
        except TimeoutError:
            return None

    async def set_mode_px4(
        self, main: int, sub: int = 0, **kwargs: Unpack[CommandOptions]
    ) -> CommandAck:
        """MAV_CMD_DO_SET_MODE to a PX4 main / sub mode (see
        :mod:`companion.link.px4_modes`; e.g. ``set_mode_px4(*px4_mode("OFFBOARD"))``).
        PX4 refuses OFFBOARD in the air unless setpoints are already streaming (> 2 Hz).
        PX4 acknowledges DO_SET_MODE twice; the second ack is awaited for 0.1 s
        (``confirm_s``), and a refusal in it raises. ``kwargs`` go to :meth:`command_long`."""
        params = (float(mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub))
        kwargs.setdefault("confirm_s", 0.1)
        return await self.command_long(mavlink2.MAV_CMD_DO_SET_MODE, params, **kwargs)

    async def arm(self, force: bool = False, **kwargs: Unpack[CommandOptions]) -> CommandAck:
        """MAV_CMD_COMPONENT_ARM_DISARM(1); ``force`` skips PX4's pre-arm checks."""
        params = (1.0, ARM_FORCE_MAGIC if force else 0.0)
        return await self.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, params, **kwargs)

    async def disarm(self, force: bool = False, **kwargs: Unpack[CommandOptions]) -> CommandAck:
        """MAV_CMD_COMPONENT_ARM_DISARM(0); PX4 refuses in the air unless ``force``
        (which stops the motors: a flight termination)."""
        params = (0.0, ARM_FORCE_MAGIC if force else 0.0)
        return await self.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, params, **kwargs)

    async def set_message_interval(
        self, msg_id: int, rate_hz: float, **kwargs: Unpack[CommandOptions]
    ) -> CommandAck:
        """MAV_CMD_SET_MESSAGE_INTERVAL: stream message ``msg_id`` at ``rate_hz`` [Hz];
        0 stops it (interval -1)."""
        if not rate_hz >= 0.0:
            raise ValueError(f"rate_hz must be >= 0, got {rate_hz}")
        interval_us = -1.0 if rate_hz == 0.0 else 1e6 / rate_hz
        params = (float(msg_id), interval_us)
        return await self.command_long(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, params, **kwargs)

    async def default_message_interval(
        self, msg_id: int, **kwargs: Unpack[CommandOptions]
    ) -> CommandAck:
        """MAV_CMD_SET_MESSAGE_INTERVAL with interval 0: message ``msg_id`` back at the
        vehicle's default rate for this link (PX4: its link mode's, none for a message that
        mode does not stream)."""
        params = (float(msg_id), 0.0)
        return await self.command_long(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, params, **kwargs)

    async def get_message_interval(
        self, msg_id: int, *, timeout_s: float = 0.5, attempts: int = 3
    ) -> int:
        """MAV_CMD_GET_MESSAGE_INTERVAL: the interval [us] the vehicle streams message
        ``msg_id`` at on this link, from its MESSAGE_INTERVAL answer (sent before the
        COMMAND_ACK); -1 not streamed (PX4: also a stream sent on every update). Raises
        ``CommandDenied``, ``CommandTimeout``, or ``CommandTimeout`` as well when the ack
        came without the MESSAGE_INTERVAL."""
        command = mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL
        with self.subscribe("MESSAGE_INTERVAL", maxsize=16) as answers:
            await self.command_long(
                command, (float(msg_id),), timeout_s=timeout_s, attempts=attempts
            )
            try:
                async with asyncio.timeout(timeout_s):
                    while True:
                        answer = await answers.get()
                        if answer.message_id == msg_id:
                            return int(answer.interval_us)
            except TimeoutError:
                name = _enum_name("MAV_CMD", command)
                raise CommandTimeout(command, name, 1, timeout_s) from None

    # --- parameters ------------------------------------------------------------------

    async def param_read(
        self, name: str, *, timeout_s: float = 0.5, attempts: int = 3
    ) -> tuple[float, int]:
        """Read parameter ``name`` of the vehicle: (value, MAV_PARAM_TYPE). Raises
        :class:`ParamTimeout` when no PARAM_VALUE of it arrives."""
        vehicle = self._vehicle_or_raise()
        with self.subscribe("PARAM_VALUE", maxsize=64) as values:
            for _ in range(attempts):
                self.send_message(
                    self.mav.param_request_read_encode(
                        vehicle.system_id, vehicle.component_id, name.encode(), -1
                    )
                )
                msg = await self._await_param(values, name, timeout_s)
                if msg is not None:
                    return decode_param_value(msg.param_value, msg.param_type), msg.param_type
        raise ParamTimeout(name, attempts, timeout_s)

    async def param_set(
        self, name: str, value: float, *, timeout_s: float = 0.5, attempts: int = 3
    ) -> float:
        """Set parameter ``name`` to ``value`` and return what the vehicle kept; its type
        is read first. Raises :class:`ParamTimeout`, or :class:`ParamRefused` when the
        vehicle kept another value (beyond float rounding)."""
        _, param_type = await self.param_read(name, timeout_s=timeout_s, attempts=attempts)
        vehicle = self._vehicle_or_raise()
        wire = encode_param_value(value, param_type)
        with self.subscribe("PARAM_VALUE", maxsize=64) as values:
            for _ in range(attempts):
                self.send_message(
                    self.mav.param_set_encode(
                        vehicle.system_id, vehicle.component_id, name.encode(), wire, param_type
                    )
                )
                msg = await self._await_param(values, name, timeout_s)
                if msg is None:
                    continue
                kept = decode_param_value(msg.param_value, msg.param_type)
                if not math.isclose(kept, value, rel_tol=1e-6, abs_tol=1e-6):
                    raise ParamRefused(name, value, kept)
                return kept
        raise ParamTimeout(name, attempts, timeout_s)

    def _vehicle_or_raise(self) -> VehicleId:
        vehicle = self.vehicle
        if vehicle is None:
            raise VehicleNotFoundError("no vehicle detected yet")
        return vehicle

    async def _await_param(
        self, values: Subscription[ParamValue], name: str, timeout_s: float
    ) -> ParamValue | None:
        """The next PARAM_VALUE of ``name`` from the vehicle, or None after ``timeout_s``."""
        vehicle = self._vehicle_or_raise()
        try:
            async with asyncio.timeout(timeout_s):
                while True:
                    msg = await values.get()
                    if msg.param_id == name and msg.get_srcSystem() == vehicle.system_id:
                        return msg
        except TimeoutError:
            return None

"""COMMAND_LONG with retries and COMMAND_ACK, and the PX4 commands built on it.

This is the command half of :class:`companion.link.mavlink.MavlinkLink` (a base class
of it, kept in its own module); it uses only the link's public surface: ``subscribe``,
``send_message``, ``mav``, ``vehicle`` and the ids.

The MAVLink command protocol: send COMMAND_LONG with ``confirmation`` 0, and 1, 2, ...
on retransmissions; the target answers COMMAND_ACK with the command id and a MAV_RESULT.
ACCEPTED succeeds; IN_PROGRESS means a final ACK follows (no retransmission after it);
any other result raises :class:`CommandDenied`. No final ACK after the attempts raises
:class:`CommandTimeout`. Commands with the same id are serialized, as the protocol
requires; different ids may run at once.
"""

from __future__ import annotations

import asyncio
from abc import ABC, abstractmethod
from collections.abc import Hashable, Sequence
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from companion.link.errors import CommandDenied, CommandTimeout, VehicleNotFoundError
from companion.link.events import VehicleId
from companion.link.fanout import Subscription

__all__ = ["ARM_FORCE_MAGIC", "Px4Commands"]

ARM_FORCE_MAGIC = 21196.0
"""param2 of MAV_CMD_COMPONENT_ARM_DISARM that overrides PX4's pre-arm / landed checks."""


def _enum_name(enum: str, value: int) -> str:
    entry = mavlink2.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else f"{enum}({value})"


class Px4Commands(ABC):
    """Commands of :class:`MavlinkLink` (see the module docstring); the abstract methods
    are the link's."""

    system_id: int
    component_id: int
    _command_locks: dict[int, asyncio.Lock]

    @abstractmethod
    def subscribe(self, *keys: Hashable, maxsize: int = 64) -> Subscription: ...

    @abstractmethod
    def send_message(self, msg: Any) -> None: ...

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
    ) -> Any:
        """Send MAV_CMD ``command`` with up to 7 ``params`` (the rest 0) to the vehicle
        and wait for its final COMMAND_ACK, resending after each ``timeout_s`` [s] up to
        ``attempts`` times in all. Returns the ACCEPTED ack (a pymavlink message).

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
                        return ack
                    if ack.result == mavlink2.MAV_RESULT_IN_PROGRESS:
                        in_progress = True
                        continue
                    raise CommandDenied(
                        command, ack.result, name, _enum_name("MAV_RESULT", ack.result)
                    )
        raise CommandTimeout(command, name, attempt, timeout_s)

    async def _await_ack(
        self, acks: Subscription, command: int, vehicle: VehicleId, deadline: float
    ) -> Any:
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

    async def set_mode_px4(self, main: int, sub: int = 0, **kwargs: Any) -> Any:
        """MAV_CMD_DO_SET_MODE to a PX4 main / sub mode (see
        :mod:`companion.link.px4_modes`; e.g. ``set_mode_px4(*px4_mode("OFFBOARD"))``).
        PX4 refuses OFFBOARD unless setpoints are already streaming (> 2 Hz).
        ``kwargs`` go to :meth:`command_long`."""
        params = (float(mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub))
        return await self.command_long(mavlink2.MAV_CMD_DO_SET_MODE, params, **kwargs)

    async def arm(self, force: bool = False, **kwargs: Any) -> Any:
        """MAV_CMD_COMPONENT_ARM_DISARM(1); ``force`` skips PX4's pre-arm checks."""
        params = (1.0, ARM_FORCE_MAGIC if force else 0.0)
        return await self.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, params, **kwargs)

    async def disarm(self, force: bool = False, **kwargs: Any) -> Any:
        """MAV_CMD_COMPONENT_ARM_DISARM(0); PX4 refuses in the air unless ``force``
        (which stops the motors: a flight termination)."""
        params = (0.0, ARM_FORCE_MAGIC if force else 0.0)
        return await self.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, params, **kwargs)

    async def set_message_interval(self, msg_id: int, rate_hz: float, **kwargs: Any) -> Any:
        """MAV_CMD_SET_MESSAGE_INTERVAL: stream message ``msg_id`` at ``rate_hz`` [Hz];
        0 stops it (interval -1)."""
        if not rate_hz >= 0.0:
            raise ValueError(f"rate_hz must be >= 0, got {rate_hz}")
        interval_us = -1.0 if rate_hz == 0.0 else 1e6 / rate_hz
        params = (float(msg_id), interval_us)
        return await self.command_long(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, params, **kwargs)

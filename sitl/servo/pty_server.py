"""Simulated Dynamixel bus on a pseudo-terminal: XM430 models answering Protocol 2.0.

:class:`PtyServoBus` opens a pty pair (:func:`os.openpty`), and a background thread
reads instruction packets from the master side, hands them to the
:class:`~sitl.servo.xm430.XM430Servo` models and writes their status packets back.
Clients (our driver, the official DynamixelSDK) open :attr:`PtyServoBus.device`, the
slave side, as they would open ``/dev/ttyUSB0``; a pty accepts any baud rate::

    with PtyServoBus({1: XM430Servo(1), 2: XM430Servo(2)}) as sim:
        ...  # open sim.device with a client

Protocol rules honoured (e-Manual, Protocol 2.0): a Ping is always answered, a
broadcast Ping by every servo in id order; a Read needs Status Return Level(68) >= 1 and
a Write or Reboot needs 2; nothing sent to the broadcast id is answered except Ping and
Sync Read; a Sync Write is never answered; a Sync Read is answered by each listed servo
in the listed order. Each reply waits the servo's Return Delay Time(9) first. Frames
that fail their CRC are dropped without a reply, as a servo cannot trust their id.

Time: before each instruction, and every 5 ms on a silent bus, the servos' loops
advance by the wall time elapsed (:meth:`~sitl.servo.xm430.XM430Servo.step`), so goal
writes take effect and a Bus Watchdog(98) trips in real time. Every packet a servo
carries out counts as communication for its watchdog: one to its id, a broadcast, or
a Sync Read/Write that lists it; a Sync Write's refused goal (watchdog tripped) is
dropped without a reply, as on the real bus.
A SITL drives the servos through :class:`~sitl.servo.xm430.ServoJoint` instead, under
:attr:`PtyServoBus.lock`.

Faults (:class:`Faults`, changeable while running with :meth:`PtyServoBus.set_faults`):
servos that do not answer, replies whose CRC is corrupted at a given rate (seeded
generator), extra reply delay. Hardware errors are injected on the servo model
(:meth:`~sitl.servo.xm430.XM430Servo.inject_hardware_error`).
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from arm_driver.dynamixel.protocol import (
    BROADCAST_ID,
    Instruction,
    InstructionPacket,
    encode_status,
)
from arm_driver.dynamixel.stream import InstructionParser
from arm_driver.errors import CommunicationError
from sitl.servo.xm430 import ServoReply, XM430Servo

__all__ = ["Faults", "PtyServoBus"]

_MAX_STEP_S = 0.1
"""Largest wall-time gap the servo loops are advanced by at once [s]."""
_IDLE_STEP_S = 0.005
"""Longest wait for a packet before the servos are stepped anyway [s], so that a Bus
Watchdog(98) trips on time on a silent bus (its unit is 20 ms)."""


@dataclass(frozen=True)
class Faults:
    """Faults the simulated bus injects.

    Attributes
    ----------
    silent_ids
        Servos that carry out instructions but never answer (a broken TX line).
    crc_corruption_rate
        Probability that a reply's CRC is corrupted [-], 0 to 1.
    reply_delay_s
        Extra delay before every reply [s].
    seed
        Seed of the generator deciding which replies are corrupted.
    """

    silent_ids: frozenset[int] = field(default_factory=frozenset)
    crc_corruption_rate: float = 0.0
    reply_delay_s: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "silent_ids", frozenset(self.silent_ids))
        if not 0.0 <= self.crc_corruption_rate <= 1.0:
            raise ValueError(f"crc_corruption_rate {self.crc_corruption_rate} not in [0, 1]")
        if not self.reply_delay_s >= 0.0:
            raise ValueError(f"reply_delay_s {self.reply_delay_s} must be >= 0")


class PtyServoBus:
    """Servo models behind a pseudo-terminal, served by a background thread.

    Parameters
    ----------
    servos
        Servo models by id (their ID(7) must match the key).
    faults
        Faults to inject from the start.
    step_servos
        Advance the servos' loops by wall time before each instruction. Turn off when a
        SITL steps them with its physics.
    """

    def __init__(
        self,
        servos: Mapping[int, XM430Servo],
        *,
        faults: Faults | None = None,
        step_servos: bool = True,
    ) -> None:
        for servo_id, servo in servos.items():
            if servo.servo_id != servo_id:
                raise ValueError(f"servo keyed {servo_id} has ID(7) {servo.servo_id}")
        self.servos = dict(servos)
        self.lock = threading.Lock()
        """Held while the thread touches the servos; hold it to touch them from outside."""
        self._faults = faults if faults is not None else Faults()
        self._rng = np.random.default_rng(self._faults.seed)
        self._step_servos = step_servos
        self._thread: threading.Thread | None = None
        self._last_step = 0.0
        self._fds: tuple[int, int, int, int] | None = None
        self._device: str | None = None
        self.corrupted_replies = 0
        """Replies sent with a corrupted CRC."""
        self.dropped_instructions = 0
        """Instruction frames dropped for a bad CRC or bad framing."""

    @property
    def device(self) -> str:
        """Path of the pty's slave side, for clients to open."""
        if self._device is None:
            raise RuntimeError("the simulated bus is not started")
        return self._device

    def set_faults(self, faults: Faults) -> None:
        """Replace the injected faults (re-seeds the corruption generator)."""
        with self.lock:
            self._faults = faults
            self._rng = np.random.default_rng(faults.seed)

    def start(self) -> str:
        """Open the pty pair and start serving; return the slave device path."""
        if self._thread is not None:
            raise RuntimeError("the simulated bus is already started")
        master, slave = os.openpty()
        tty.setraw(slave)
        wake_read, wake_write = os.pipe()
        self._fds = (master, slave, wake_read, wake_write)
        self._device = os.ttyname(slave)
        self._thread = threading.Thread(target=self._serve, name="pty-servo-bus", daemon=True)
        self._thread.start()
        return self._device

    def stop(self) -> None:
        """Stop the thread and close the pty; safe to call twice."""
        if self._thread is None or self._fds is None:
            return
        os.write(self._fds[3], b"x")
        self._thread.join(timeout=5.0)
        for fd in self._fds:
            os.close(fd)
        self._thread = None
        self._fds = None

    def __enter__(self) -> PtyServoBus:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    # -- the serving thread -----------------------------------------------------------

    def _serve(self) -> None:
        assert self._fds is not None
        master, _, wake, _ = self._fds
        parser = InstructionParser()
        self._last_step = time.monotonic()
        idle_s = _IDLE_STEP_S if self._step_servos else None
        while True:
            readable, _, _ = select.select([master, wake], [], [], idle_s)
            if wake in readable:
                return
            if not readable:
                with self.lock:
                    self._advance()
                continue
            try:
                chunk = os.read(master, 4096)
            except OSError:  # EIO: no process has the slave open; poll again shortly
                time.sleep(0.001)
                continue
            parser.feed(chunk)
            while True:
                try:
                    packet = parser.next_packet()
                except CommunicationError:
                    self.dropped_instructions += 1
                    continue
                if packet is None:
                    break
                with self.lock:
                    self._advance()
                    replies = self._answer(packet)
                for delay_s, frame in replies:
                    if delay_s > 0.0:
                        time.sleep(delay_s)
                    os.write(master, frame)

    def _advance(self) -> None:
        """Step the servos by the wall time since the last step (with ``step_servos``)."""
        now = time.monotonic()
        if self._step_servos:
            for servo in self.servos.values():
                servo.step(min(now - self._last_step, _MAX_STEP_S))
        self._last_step = now

    def _answer(self, packet: InstructionPacket) -> list[tuple[float, bytes]]:
        """Carry out one instruction; return (delay before [s], frame) per reply."""
        instruction, params = packet.instruction, packet.params
        if instruction == Instruction.SYNC_WRITE:
            self._sync_write(params)
            return []
        if instruction == Instruction.SYNC_READ:
            if packet.servo_id != BROADCAST_ID or len(params) < 5:
                return []
            address = int.from_bytes(params[:2], "little")
            length = int.from_bytes(params[2:4], "little")
            targets = [self.servos[i] for i in params[4:] if i in self.servos]
            frames = [self._frame(servo, servo.read(address, length), level=1) for servo in targets]
            return [frame for frame in frames if frame[1]]
        if packet.servo_id == BROADCAST_ID:
            targets = sorted(self.servos.values(), key=lambda servo: servo.servo_id)
        elif packet.servo_id in self.servos:
            targets = [self.servos[packet.servo_id]]
        else:
            return []
        out = []
        for servo in targets:
            old_id = servo.servo_id
            reply = servo.handle(packet)
            if servo.servo_id != old_id:
                self.servos[servo.servo_id] = self.servos.pop(old_id)
            levels: dict[int, int] = {Instruction.PING: 0, Instruction.READ: 1}
            level = levels.get(instruction, 2)
            if packet.servo_id == BROADCAST_ID and instruction != Instruction.PING:
                continue
            out.append(self._frame(servo, reply, level=level))
        return [reply for reply in out if reply[1]]

    def _sync_write(self, params: bytes) -> None:
        if len(params) < 4:
            return
        address = int.from_bytes(params[:2], "little")
        length = int.from_bytes(params[2:4], "little")
        body = params[4:]
        if length < 1 or len(body) % (length + 1):
            return
        for start in range(0, len(body), length + 1):
            servo = self.servos.get(body[start])
            if servo is not None:
                servo.write(address, body[start + 1 : start + 1 + length])

    def _frame(self, servo: XM430Servo, reply: ServoReply, *, level: int) -> tuple[float, bytes]:
        """Frame a reply if Status Return Level and the faults allow it (else b"")."""
        faults = self._faults
        if servo.status_return_level < level or servo.servo_id in faults.silent_ids:
            return (0.0, b"")
        frame = bytearray(
            encode_status(servo.servo_id, reply.error, reply.params, alert=reply.alert)
        )
        if faults.crc_corruption_rate and self._rng.random() < faults.crc_corruption_rate:
            frame[-1] ^= 0xFF
            self.corrupted_replies += 1
        return (servo.return_delay_s + faults.reply_delay_s, bytes(frame))

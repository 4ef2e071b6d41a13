"""Servo models answering Dynamixel Protocol 2.0, whatever carries the bytes.

:class:`ServoResponder` carries out one instruction packet on the
:class:`~sitl.servo.xm430.XM430Servo` models and returns the status packets to send back,
each with the delay before it (the servo's Return Delay Time(9) and the injected delay).
The pty bus (:class:`~sitl.servo.pty_server.PtyServoBus`, a thread on a pseudo-terminal)
and the in-memory bus (:class:`~sitl.servo.memory_bus.MemoryServoBus`, stepped with the
simulation clock) both answer through it.

Protocol rules honoured (e-Manual, Protocol 2.0): a Ping is always answered, a
broadcast Ping by every servo in id order; a Read needs Status Return Level(68) >= 1 and
a Write or Reboot needs 2; nothing sent to the broadcast id is answered except Ping and
Sync Read; a Sync Write is never answered; a Sync Read is answered by each listed servo
in the listed order. Every packet a servo carries out counts as communication for its
watchdog: one to its id, a broadcast, or a Sync Read/Write that lists it; a Sync Write's
refused goal (watchdog tripped) is dropped without a reply, as on the real bus.

Faults (:class:`Faults`): servos that do not answer, replies whose CRC is corrupted at a
given rate (seeded generator), extra reply delay.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from arm_driver.dynamixel.protocol import (
    BROADCAST_ID,
    Instruction,
    InstructionPacket,
    encode_status,
)
from sitl.servo.xm430 import ServoReply, XM430Servo

__all__ = ["Faults", "RespondingBus", "ServoResponder"]


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


class ServoResponder:
    """Servo models by id, answering instruction packets.

    Parameters
    ----------
    servos
        Servo models by id (their ID(7) must match the key).
    faults
        Faults to inject from the start.
    """

    def __init__(self, servos: Mapping[int, XM430Servo], faults: Faults | None = None) -> None:
        for servo_id, servo in servos.items():
            if servo.servo_id != servo_id:
                raise ValueError(f"servo keyed {servo_id} has ID(7) {servo.servo_id}")
        self.servos = dict(servos)
        self.faults = faults if faults is not None else Faults()
        self._rng = np.random.default_rng(self.faults.seed)
        self.corrupted_replies = 0
        """Replies sent with a corrupted CRC."""
        self.sync_reads = 0
        """Sync Read instructions carried out (a lockstep host waits for the client's)."""

    def set_faults(self, faults: Faults) -> None:
        """Replace the injected faults (re-seeds the corruption generator)."""
        self.faults = faults
        self._rng = np.random.default_rng(faults.seed)

    def answer(self, packet: InstructionPacket) -> list[tuple[float, bytes]]:
        """Carry out one instruction; return (delay before [s], frame) per reply."""
        instruction, params = packet.instruction, packet.params
        if instruction == Instruction.SYNC_WRITE:
            self._sync_write(params)
            return []
        if instruction == Instruction.SYNC_READ:
            self.sync_reads += 1
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
        faults = self.faults
        if servo.status_return_level < level or servo.servo_id in faults.silent_ids:
            return (0.0, b"")
        frame = bytearray(
            encode_status(servo.servo_id, reply.error, reply.params, alert=reply.alert)
        )
        if faults.crc_corruption_rate and self._rng.random() < faults.crc_corruption_rate:
            frame[-1] ^= 0xFF
            self.corrupted_replies += 1
        return (servo.return_delay_s + faults.reply_delay_s, bytes(frame))


class RespondingBus:
    """What a simulated Dynamixel bus answering through a :class:`ServoResponder` shows of
    it (the pty bus and the in-memory bus)."""

    _responder: ServoResponder
    lock: threading.Lock
    """Held around the servos' steps and answers; hold it to change a servo from outside."""

    @property
    def servos(self) -> dict[int, XM430Servo]:
        """The servo models by id."""
        return self._responder.servos

    def set_faults(self, faults: Faults) -> None:
        """Replace the injected faults (re-seeds the corruption generator)."""
        with self.lock:
            self._responder.set_faults(faults)

    @property
    def corrupted_replies(self) -> int:
        """Replies sent with a corrupted CRC."""
        return self._responder.corrupted_replies

    @property
    def sync_reads(self) -> int:
        """Sync Read instructions carried out."""
        return self._responder.sync_reads

"""Simulated Dynamixel bus on a pseudo-terminal: XM430 models answering Protocol 2.0.

:class:`PtyServoBus` opens a pty pair (:func:`os.openpty`), and a background thread
reads instruction packets from the master side, hands them to the
:class:`~sitl.servo.xm430.XM430Servo` models and writes their status packets back.
Clients (our driver, the official DynamixelSDK) open :attr:`PtyServoBus.device`, the
slave side, as they would open ``/dev/ttyUSB0``; a pty accepts any baud rate::

    with PtyServoBus({1: XM430Servo(1), 2: XM430Servo(2)}) as sim:
        ...  # open sim.device with a client

The packets are answered by :class:`~sitl.servo.responder.ServoResponder` (the protocol
rules it honours are listed there). Each reply waits the servo's Return Delay Time(9)
first. Frames that fail their CRC are dropped without a reply, as a servo cannot trust
their id.

Time: before each instruction, and every 5 ms on a silent bus, the servos' loops
advance by the wall time elapsed (:meth:`~sitl.servo.xm430.XM430Servo.step`), so goal
writes take effect and a Bus Watchdog(98) trips in real time.
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

from arm_driver.dynamixel.stream import InstructionParser
from arm_driver.errors import CommunicationError
from sitl.servo.responder import Faults, RespondingBus, ServoResponder
from sitl.servo.xm430 import XM430Servo

__all__ = ["REPLY_SWITCH_INTERVAL_S", "Faults", "PtyServoBus"]

REPLY_SWITCH_INTERVAL_S = 2e-4
"""Interpreter switch interval [s] for a process whose pty bus thread answers beside a busy
Python thread (a plant stepped at 1 kHz): at Python's default of 5 ms the reply waits for
the interpreter lock for longer than a client's 20 ms margin on a loaded machine."""
_MAX_STEP_S = 0.1
"""Largest wall-time gap the servo loops are advanced by at once [s]."""
_IDLE_STEP_S = 0.005
"""Longest wait for a packet before the servos are stepped anyway [s], so that a Bus
Watchdog(98) trips on time on a silent bus (its unit is 20 ms)."""


class PtyServoBus(RespondingBus):
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
        self._responder = ServoResponder(servos, faults)
        self.lock = threading.Lock()
        """Held while the thread touches the servos; hold it to touch them from outside."""
        self._step_servos = step_servos
        self._thread: threading.Thread | None = None
        self._last_step = 0.0
        self._fds: tuple[int, int, int, int] | None = None
        self._device: str | None = None
        self.dropped_instructions = 0
        """Instruction frames dropped for a bad CRC or bad framing."""

    @property
    def device(self) -> str:
        """Path of the pty's slave side, for clients to open."""
        if self._device is None:
            raise RuntimeError("the simulated bus is not started")
        return self._device

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
                    replies = self._responder.answer(packet)
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

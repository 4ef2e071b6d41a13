"""Simulated Dynamixel bus on an in-memory serial line, answered on the simulation clock.

:class:`MemoryServoBus` is :class:`~sitl.servo.pty_server.PtyServoBus` for a flight on
simulated time: the same servo models answer the same Protocol 2.0 bytes through the same
:class:`~sitl.servo.responder.ServoResponder`, but over the in-memory line ``memory:NAME``
(:mod:`bytelink.memory`; the companion's bus opens ``dynamixel://memory:NAME``) and
without a thread. The simulation calls :meth:`MemoryServoBus.serve` whenever the companion
has written or time has advanced: instructions are carried out at once, and each reply is
released once the simulation clock has passed its delay (Return Delay Time(9) plus the
injected delay), so a reply that comes late on the real bus comes late here too, and
always by the same amount. The servos' loops are stepped by the physics (the world), not
here.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping

from arm_driver.dynamixel.stream import InstructionParser
from arm_driver.errors import CommunicationError
from bytelink.memory import MemoryChannel, create_channel
from sitl.servo.responder import Faults, RespondingBus, ServoResponder
from sitl.servo.xm430 import XM430Servo

__all__ = ["MemoryServoBus"]


class MemoryServoBus(RespondingBus):
    """Servo models behind the in-memory line ``name``; :meth:`start`, then
    :meth:`serve` on every turn of the simulation.

    Parameters
    ----------
    servos
        Servo models by id (their ID(7) must match the key).
    faults
        Faults to inject from the start.
    name
        Name of the in-memory line (unique in the process while started).
    """

    def __init__(
        self, servos: Mapping[int, XM430Servo], *, faults: Faults | None = None, name: str
    ) -> None:
        self._responder = ServoResponder(servos, faults)
        self.name = name
        self.lock = threading.Lock()
        """Taken by the simulation around the physics step, as for the pty bus (nothing
        else runs concurrently here)."""
        self._channel: MemoryChannel | None = None
        self._parser = InstructionParser()
        self._pending: list[tuple[float, bytes]] = []
        """Replies not yet on the line: (simulation time they go out [s], frame)."""
        self.dropped_instructions = 0
        """Instruction frames dropped for a bad CRC or bad framing."""

    @property
    def device(self) -> str:
        """The device a client opens: ``memory:NAME``."""
        return f"memory:{self.name}"

    def start(self) -> str:
        """Create the in-memory line; return the device name."""
        if self._channel is not None:
            raise RuntimeError("the simulated bus is already started")
        self._channel = create_channel(self.name)
        return self.device

    def stop(self) -> None:
        """Close the line; safe to call twice."""
        if self._channel is not None:
            self._channel.close()
            self._channel = None
        self._pending.clear()

    def __enter__(self) -> MemoryServoBus:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    @property
    def idle(self) -> bool:
        """:meth:`serve` has nothing to do: no instruction written since, no reply waiting
        (the usual plant step), or the line is stopped."""
        channel = self._channel
        return channel is None or (not channel.server.readable and not self._pending)

    @property
    def quiet_until_s(self) -> float:
        """Simulation time [s] before which :meth:`serve` has nothing to do: 1 us before
        the first reply waiting goes out, inf for none; -inf while an instruction waits to
        be read."""
        channel = self._channel
        if channel is not None and channel.server.readable:
            return -math.inf
        return self._pending[0][0] - 1e-6 if self._pending else math.inf

    def serve(self, now_s: float) -> None:
        """Carry out the instructions written since the last call, at simulation time
        ``now_s`` [s], and put on the line every reply whose time has come."""
        if self.idle:
            return
        assert self._channel is not None
        end = self._channel.server
        data = end.receive_all()
        if data:
            self._parser.feed(data)
            while True:
                try:
                    packet = self._parser.next_packet()
                except CommunicationError:
                    self.dropped_instructions += 1
                    continue
                if packet is None:
                    break
                out_s = now_s
                for delay_s, frame in self._responder.answer(packet):
                    out_s += delay_s
                    self._pending.append((out_s, frame))
            self._pending.sort(key=lambda pending: pending[0])
        while self._pending and self._pending[0][0] <= now_s + 1e-9:
            if not end.closed and end.peer is not None and not end.peer.closed:
                end.send(self._pending[0][1])
            del self._pending[0]

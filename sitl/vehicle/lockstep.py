"""Flights on simulated time: the companion and the simulated vehicle in lockstep, in one
process, on one clock.

Mechanism: a virtual-time asyncio event loop. :class:`LockstepLoop` is the standard
selector event loop with two parts replaced:

- its clock (``loop.time()``) is the simulation's (:attr:`Lockstep.time_s`), so every
  ``asyncio.sleep``, ``asyncio.timeout_at`` and link or servo deadline of the flight code
  runs on simulated time, unchanged;
- its selector (:class:`LockstepSelector`) watches in-memory channel ends
  (:mod:`bytelink.memory`) instead of file descriptors. When the loop would block (every
  task of the companion waits for a message or a timer), the selector steps the
  simulation until a message for the companion arrives or the earliest timer is due: a
  plant step and those after it that make nothing readable, in one call
  (:meth:`Lockstep.step_until`), then again.

So the vehicle never steps while the companion has work to do: the setpoint the companion
computes from a pose is in before the step that follows it, as PX4 and its simulator do in
lockstep through HIL_SENSOR / HIL_ACTUATOR_CONTROLS. The companion's work takes no
simulated time; the servo bus answers on the simulation clock after the servos' reply
delays (:class:`~sitl.servo.memory_bus.MemoryServoBus`). A flight is then a function of
the scenario, the seed and the code: the same bytes on any machine, at any load.

Why this and not explicit stepping of the app: the app is the flight code, written as
asyncio tasks that wait on links, buses and timers; a loop whose clock and selector are
the simulation runs that code as it is, with no second implementation of the mission for
simulation, and the bytes between the parts stay MAVLink 2 and Dynamixel Protocol 2.0.
"""

from __future__ import annotations

import asyncio
import math
import selectors
import signal
import threading
from collections.abc import Coroutine, Mapping
from typing import Any, Protocol, TypeVar

from bytelink.memory import MemoryEnd, end_for_fd

__all__ = ["Lockstep", "LockstepLoop", "LockstepSelector", "LockstepStall", "run_lockstep"]

_T = TypeVar("_T")

MAX_IDLE_S = 120.0
"""Simulated time the selector steps with nothing for the companion before it gives up
[s]: a flight whose companion waits for nothing that can come."""


class LockstepStall(RuntimeError):
    """The companion waited for more than :data:`MAX_IDLE_S` of simulated time with no
    message and no timer due (e.g. it waited on a thread, which never runs here)."""


class Lockstep(Protocol):
    """What the loop drives: a clock, its steps, and the devices answering at once."""

    @property
    def time_s(self) -> float:
        """Simulation time [s]."""
        ...

    def step_until(self, until_s: float) -> None:
        """Advance the simulation by one step, then by more while its time is below
        ``until_s`` [s] and they make nothing readable nor need the host (the vehicle's
        steps with nothing due but the world's)."""
        ...

    def serve(self) -> None:
        """Answer what the companion wrote to the simulated devices, at :attr:`time_s`."""
        ...


class LockstepSelector(selectors.BaseSelector):
    """A selector over in-memory channel ends that steps the simulation while nothing is
    ready (see the module docstring)."""

    def __init__(self, sim: Lockstep, max_idle_s: float = MAX_IDLE_S) -> None:
        self._sim = sim
        self._max_idle_s = max_idle_s
        self._keys: dict[int, selectors.SelectorKey] = {}
        self._readers: list[tuple[selectors.SelectorKey, MemoryEnd]] = []
        """The registered keys watched for reading, each with its open end (an end
        closed since has an empty inbox for good, and its descriptor is never reused)."""

    def register(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        fd = fileobj if isinstance(fileobj, int) else fileobj.fileno()
        if end_for_fd(fd) is None:
            raise ValueError(
                f"descriptor {fd} is not an in-memory channel: a flight on simulated time "
                "talks to its vehicle and servos only through memory:// channels"
            )
        if fd in self._keys:
            raise KeyError(f"{fileobj!r} is already registered")
        key = selectors.SelectorKey(fileobj, fd, events, data)
        self._keys[fd] = key
        self._watch()
        return key

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        fd = fileobj if isinstance(fileobj, int) else fileobj.fileno()
        key = self._keys.pop(fd)
        self._watch()
        return key

    def _watch(self) -> None:
        """:attr:`_readers` from the keys now."""
        self._readers = []
        for fd, key in self._keys.items():
            end = end_for_fd(fd)
            if end is not None and key.events & selectors.EVENT_READ:
                self._readers.append((key, end))

    def get_map(self) -> Mapping[Any, selectors.SelectorKey]:
        return self._keys

    def close(self) -> None:
        self._keys.clear()
        self._readers = []

    def _ready(self) -> list[tuple[selectors.SelectorKey, int]]:
        return [(key, selectors.EVENT_READ) for key, end in self._readers if end.readable]

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        """What is readable now; if nothing and ``timeout`` allows, step the simulation
        until something is, or until ``timeout`` [s] of simulated time has passed."""
        sim = self._sim
        sim.serve()
        ready = self._ready()
        if ready or (timeout is not None and timeout <= 0.0):
            return ready
        start_s = sim.time_s
        until_s = math.inf if timeout is None else start_s + timeout - 1e-9
        while True:
            sim.step_until(until_s)
            sim.serve()
            ready = self._ready()
            if ready:
                return ready
            now_s = sim.time_s
            if now_s >= until_s:
                return []
            if now_s - start_s > self._max_idle_s:
                raise LockstepStall(
                    f"the companion waited {now_s - start_s:.0f} s of simulated time for "
                    "nothing that can come (a thread, or a channel nobody writes)"
                )


class LockstepLoop(asyncio.SelectorEventLoop):
    """An asyncio event loop on the simulation's clock (see the module docstring).

    It has no self-pipe: nothing from another thread can wake it, and nothing here needs
    a thread. ``serves_memory_ports`` tells the in-memory transports they may open.
    """

    serves_memory_ports = True

    def __init__(self, sim: Lockstep, max_idle_s: float = MAX_IDLE_S) -> None:
        self._sim = sim
        super().__init__(LockstepSelector(sim, max_idle_s))

    def time(self) -> float:
        """Simulation time [s]."""
        return self._sim.time_s

    def _make_self_pipe(self) -> None:
        self._ssock = self._csock = None

    def _close_self_pipe(self) -> None:
        return None


def run_lockstep(sim: Lockstep, main: Coroutine[Any, Any, _T]) -> _T:
    """Run ``main`` to completion on a :class:`LockstepLoop` over ``sim``; the loop is
    closed afterwards (its remaining tasks cancelled), as ``asyncio.run`` does. Ctrl-C
    (SIGINT, in the main thread) also goes as ``asyncio.run`` takes it: the first cancels
    ``main``'s task, which may finish its clean-up and return (a mission writes its logs
    and summary); a task that ends cancelled, or a second Ctrl-C, raises
    KeyboardInterrupt."""
    loop = LockstepLoop(sim)
    task = loop.create_task(main)
    interrupts = 0

    def on_sigint(signum: int, frame: object) -> None:
        nonlocal interrupts
        interrupts += 1
        if interrupts == 1 and not task.done():
            task.cancel()
            loop.call_soon_threadsafe(lambda: None)  # wake the loop
            return
        raise KeyboardInterrupt()

    handled = (
        threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    )
    if handled:
        signal.signal(signal.SIGINT, on_sigint)
    try:
        asyncio.set_event_loop(loop)
        try:
            return loop.run_until_complete(task)
        except asyncio.CancelledError:
            if interrupts:
                raise KeyboardInterrupt() from None
            raise
    finally:
        if handled:
            signal.signal(signal.SIGINT, signal.default_int_handler)
        try:
            pending = [task for task in asyncio.all_tasks(loop) if not task.done()]
            for task in pending:
                task.cancel()
            if pending:
                loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
            loop.run_until_complete(loop.shutdown_asyncgens())
        finally:
            asyncio.set_event_loop(None)
            loop.close()

"""Control-loop period watch in vehicle time (pure, no clock): late cycles and overrun.

The control loop runs once per vehicle pose, so the vehicle-time gap between two cycles is
the period the filters, the estimator and the controller actually ran at. Two things can go
wrong on a loaded onboard computer:

- a **late cycle** (a gap longer than ``late_factor`` nominal periods: a scheduling stall, a
  burst of dropped poses). The estimator's forward-Euler step would integrate over the gap,
  so the estimator skips that cycle (:attr:`CyclePeriod.late`); the controller flies on.
- a **lasting overrun**: ``overrun_cycles`` or more cycles within the last ``window_s``
  each longer than ``max_period_s``, the longest period the velocity gains tolerate with
  margin (:meth:`companion.control.flight.FlightControl.max_period_s`). The discrete
  damping loop goes unstable through repeated long steps, so the joints' loop is then no
  longer stable with margin: the app raises ``loop_overrun`` (:mod:`companion.mission.failsafe`).
  A single long gap is one held command, not that instability: the estimator skips it,
  and a silence of 0.5 s is the link watchdog's ``link_lost``.

Who held up a late cycle or a dropped pose (:class:`GapCause`) is read from what the control
thread did over its last two cycles (:class:`CycleWindow`): its own CPU time, its time
waiting for a CPU, and how long the vehicle's datagrams waited in its socket.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from enum import StrEnum

__all__ = ["CyclePeriod", "CycleWindow", "GapCause", "GapTimes", "LoopPeriodMonitor"]


@dataclass(frozen=True)
class CyclePeriod:
    """One cycle's timing."""

    period_s: float
    """Vehicle time since the previous cycle [s]."""
    late: bool
    """Longer than ``late_factor`` nominal periods."""


class LoopPeriodMonitor:
    """Watches the vehicle-time period of the control loop.

    Parameters
    ----------
    period_s
        Nominal control period [s].
    max_period_s
        Longest period the controller tolerates [s] (>= ``period_s``).
    late_factor
        A cycle longer than this many nominal periods is late.
    window_s
        Window of :attr:`mean_period_s` and of the overrun count [s].
    overrun_cycles
        Cycles longer than ``max_period_s`` within ``window_s`` that make an overrun.
    """

    def __init__(
        self,
        period_s: float,
        max_period_s: float,
        *,
        late_factor: float = 2.5,
        window_s: float = 1.0,
        overrun_cycles: int = 3,
    ) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period_s must be positive, got {period_s}")
        if not max_period_s >= period_s:
            raise ValueError(f"max_period_s ({max_period_s}) must be >= period_s ({period_s})")
        if not (late_factor > 1.0 and window_s > 0.0 and overrun_cycles >= 1):
            raise ValueError("late_factor must be > 1, window_s > 0 and overrun_cycles >= 1")
        self.period_s = period_s
        self.max_period_s = max_period_s
        self.late_factor = late_factor
        self.window_s = window_s
        self.overrun_cycles = overrun_cycles
        self.late_cycles = 0
        self.longest_period_s = 0.0
        self._times: deque[float] = deque()
        self._long: deque[float] = deque()
        """Vehicle times [s] of the cycles within the window longer than max_period_s."""

    def update(self, t_s: float) -> CyclePeriod | None:
        """Record a cycle at vehicle time ``t_s`` [s] (increasing); None for the first."""
        t_s = float(t_s)
        times = self._times
        previous = times[-1] if times else None
        times.append(t_s)
        while len(times) > 2 and t_s - times[1] >= self.window_s:
            times.popleft()
        if previous is None:
            return None
        period = t_s - previous
        late = period > self.late_factor * self.period_s
        self.late_cycles += late
        self.longest_period_s = max(self.longest_period_s, period)
        long = self._long
        if period > self.max_period_s:
            long.append(t_s)
        while long and t_s - long[0] > self.window_s:
            long.popleft()
        return CyclePeriod(period, late)

    @property
    def mean_period_s(self) -> float:
        """Mean period over the last ``window_s`` (NaN until a full window) [s]."""
        times = self._times
        span = times[-1] - times[0] if len(times) > 1 else 0.0
        return span / (len(times) - 1) if span >= self.window_s else math.nan

    @property
    def long_cycles(self) -> int:
        """Cycles longer than ``max_period_s`` within ``window_s`` of the latest one."""
        return len(self._long)

    @property
    def overrun(self) -> bool:
        """At least ``overrun_cycles`` cycles within the window were too long."""
        return len(self._long) >= self.overrun_cycles


class GapCause(StrEnum):
    """Who held up a late cycle or dropped poses (:meth:`GapTimes.cause`): the largest of
    three shares of the control thread's last two cycles, if it reaches a control period."""

    COMPANION = "companion"
    """The thread itself running on a CPU."""
    HOST = "host"
    """The thread ready to run and not run: the computer's other work or a hypervisor held
    its CPU."""
    BLOCKED = "blocked"
    """Datagrams waiting in the socket while the thread neither ran nor waited for a CPU:
    blocked in a system call or a lock (its own, possibly), or its CPU stopped under it."""
    ARRIVAL = "arrival"
    """None of the three reached a period: the poses came late or together."""
    UNKNOWN = "unknown"
    """The OS does not account the thread's times, or (serial, TCP: no arrival times)
    neither of the thread's times reached a period."""


@dataclass(frozen=True)
class GapTimes:
    """What the control thread did over a window of its cycles [s] (None: not known)."""

    run_s: float | None
    """Time on a CPU."""
    cpu_wait_s: float | None
    """Time ready to run, waiting for a CPU."""
    socket_wait_s: float | None
    """Longest wait of a datagram in the socket, arrival to read."""

    def cause(self, period_s: float) -> GapCause:
        """Who held the cycles up, against the control period ``period_s`` [s]: the
        largest of the time run, the time waiting for a CPU and the socket wait beyond
        both (blocked), when it reaches a period; ties go to the companion. The largest,
        not the first over a period: after a stall the thread's run includes the backlog
        the stall left (in flight, 5-8 ms of catching up after stalls of 45-100 ms)."""
        run, cpu_wait = self.run_s, self.cpu_wait_s
        if run is None or cpu_wait is None:
            return GapCause.UNKNOWN
        socket_wait = self.socket_wait_s
        blocked = 0.0 if socket_wait is None else max(0.0, socket_wait - run - cpu_wait)
        largest = max(run, cpu_wait, blocked)
        if largest < period_s:
            return GapCause.UNKNOWN if socket_wait is None else GapCause.ARRIVAL
        if run == largest:
            return GapCause.COMPANION
        return GapCause.HOST if cpu_wait == largest else GapCause.BLOCKED


class CycleWindow:
    """The control thread's times over its last two cycles: the window in which the delay
    behind a late cycle or a dropped pose happened (the cycle before the one that sees it
    may be the slow one)."""

    def __init__(self) -> None:
        self._times: deque[tuple[float, float] | None] = deque(maxlen=3)
        self._socket_waits: deque[float | None] = deque(maxlen=2)

    def push(self, times: tuple[float, float] | None, socket_wait_s: float | None) -> None:
        """Record the end of a cycle: the thread's cumulative (run, CPU wait) [s], None if
        not known, and the longest socket wait since the previous cycle [s]."""
        self._times.append(times)
        self._socket_waits.append(socket_wait_s)

    def gap(self) -> GapTimes:
        """The window from the end of the cycle before the previous one to the last push
        (computed only when asked: a late cycle or a drop)."""
        first, last = self._times[0], self._times[-1]
        if first is None or last is None:
            run_s = cpu_wait_s = None
        else:
            run_s, cpu_wait_s = last[0] - first[0], last[1] - first[1]
        waits = [w for w in self._socket_waits if w is not None]
        return GapTimes(run_s, cpu_wait_s, max(waits) if waits else None)

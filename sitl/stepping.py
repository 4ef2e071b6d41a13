"""The simulator's one stepping loop: fixed steps of simulated time, each in its
wall-clock slot or back to back, until stopped or until a simulated time.

:func:`step_loop` runs a :class:`Stepped` host: the simulated vehicle
(:class:`~sitl.vehicle.runner.SitlVehicle`: the imitation's autopilot, the world, the
telemetry, a lockstep client's waits), PX4 in the loop of our physics
(:class:`~sitl.hil.Px4InTheLoop`: the world under PX4's motor outputs, a sensor frame to
PX4 every few steps), the arm stand beside PX4's SIH
(:class:`~sitl.servo.arm_stand.ArmStand`: the servos and the arm alone) and the offline
simulator (:mod:`sitl.offline.simulation`: the companion's control period over several
plant steps). The host says what one step is; the loop holds the pace
(:class:`WallPacer`, when given), restarts it after a wait outside the slots, ends the run
(:func:`running`) and counts (:class:`LoopStats`). On simulated time with the companion in
the same process, the event loop's selector steps the vehicle instead, whenever the
companion waits (:mod:`sitl.vehicle.lockstep`).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Protocol

__all__ = ["LoopStats", "Stepped", "WallPacer", "running", "step_loop"]


class WallPacer:
    """Holds a loop's steps to wall-clock slots ``wall_step_s`` apart (the simulated step
    over the speed factor).

    :meth:`wait` sleeps until the next step's slot and says how late the step starts. A
    step more than ``max_lag_s`` behind its slot is an overrun: the slots start again from
    now, and the simulation slows down instead of running the backlog at full speed.

    Parameters
    ----------
    wall_step_s : float
        Wall-clock time between two steps' slots [s].
    max_lag_s : float
        Largest lateness run down at full speed [s].
    stop : threading.Event, optional
        Wakes a sleeping :meth:`wait` when set (the loop's own stop).
    """

    def __init__(
        self, wall_step_s: float, max_lag_s: float, stop: threading.Event | None = None
    ) -> None:
        if not wall_step_s > 0.0:
            raise ValueError(f"wall_step_s must be positive, got {wall_step_s!r}")
        if not max_lag_s > 0.0:
            raise ValueError(f"max_lag_s must be positive, got {max_lag_s!r}")
        self.wall_step_s = wall_step_s
        self.max_lag_s = max_lag_s
        self.overruns = 0
        """Steps that started more than ``max_lag_s`` late (the slots started again)."""
        self.slept_s = 0.0
        """Wall-clock time spent waiting for slots [s]."""
        self._stop = stop
        self._slot = time.perf_counter()

    def restart(self) -> None:
        """The next step's slot is now (after a wait the slots do not account for: a
        lockstep client's setpoint, PX4's start-up)."""
        self._slot = time.perf_counter()

    def wait(self) -> float:
        """Sleep until the next step's slot; how late the step starts [s] (0 after an
        overrun, and when the stop event ended the sleep early)."""
        wait = self._slot - time.perf_counter()
        if wait > 0.0:
            if self._stop is not None:
                self._stop.wait(wait)
            else:
                time.sleep(wait)
            self.slept_s += wait
        now = time.perf_counter()
        lateness = max(0.0, now - self._slot)
        if lateness > self.max_lag_s:
            self.overruns += 1
            self._slot = now
            lateness = 0.0
        self._slot += self.wall_step_s
        return lateness


def running(
    stop: threading.Event | None, time_s: float, dt_s: float, until_s: float | None = None
) -> bool:
    """Whether a loop at simulated ``time_s`` [s], stepping ``dt_s`` [s], takes another
    step: not stopped, and not yet at ``until_s`` (half a step of rounding allowed)."""
    if stop is not None and stop.is_set():
        return False
    return until_s is None or time_s < until_s - 0.5 * dt_s


class Stepped(Protocol):
    """What :func:`step_loop` steps."""

    @property
    def dt_s(self) -> float:
        """Simulated time of one step [s]."""
        ...

    @property
    def time_s(self) -> float:
        """Simulated time now [s]."""
        ...

    @property
    def paced(self) -> bool:
        """Whether the next step keeps its wall-clock slot (PX4 in the loop boots as fast
        as it can)."""
        ...

    def advance(self) -> bool:
        """One step; True when it waited outside its wall-clock slot (a lockstep client's
        setpoint, PX4's boot), so that the slots start again after it."""
        ...


@dataclass
class LoopStats:
    """What one run of :func:`step_loop` did."""

    steps: int = 0
    sim_time_s: float = 0.0
    """Simulated time stepped [s]."""
    wall_time_s: float = 0.0
    lateness_us: list[float] = field(default_factory=list)
    """Each paced step's lateness after its slot [us]."""
    overruns: int = 0
    """Paced steps beyond the pacer's largest lag (:class:`WallPacer`)."""
    paced_s: float = 0.0
    """Wall time slept to hold the pace [s]."""


def step_loop(
    host: Stepped,
    stop: threading.Event | None = None,
    until_s: float | None = None,
    pacer: WallPacer | None = None,
) -> LoopStats:
    """Step ``host`` until ``stop`` is set or its simulated time reaches ``until_s`` [s]
    (:func:`running`); with ``pacer``, each step the host wants :attr:`~Stepped.paced`
    waits for its wall-clock slot first (no step after a stop that woke the wait), and
    the slots start again after a step that waited outside them. Without one the steps
    run back to back. Raises what the host's step raises."""
    stats = LoopStats()
    sim0, wall0 = host.time_s, time.perf_counter()
    try:
        while running(stop, host.time_s, host.dt_s, until_s):
            if pacer is not None and host.paced:
                stats.lateness_us.append(pacer.wait() * 1e6)
                if stop is not None and stop.is_set():
                    break
            if host.advance() and pacer is not None:
                pacer.restart()
            stats.steps += 1
    finally:
        stats.sim_time_s = host.time_s - sim0
        stats.wall_time_s = time.perf_counter() - wall0
        if pacer is not None:
            stats.overruns, stats.paced_s = pacer.overruns, pacer.slept_s
    return stats

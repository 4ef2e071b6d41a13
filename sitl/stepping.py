"""Fixed steps on the wall clock: the pace and the end of the simulator's loops.

The simulated vehicle (:class:`~sitl.vehicle.runner.SitlVehicle`), PX4 in the loop of our
physics (:class:`~sitl.hil.Px4InTheLoop`) and the arm stand beside PX4's SIH
(:class:`~sitl.servo.arm_stand.ArmStand`) step their plant in fixed steps of simulated
time, each in its wall-clock slot (:class:`WallPacer`), until stopped or until a simulated
time (:func:`running`). On simulated time nothing paces the steps: their caller steps them
(:mod:`sitl.vehicle.lockstep`), and the offline simulator (:mod:`sitl.offline.simulation`)
runs its control periods back to back.
"""

from __future__ import annotations

import threading
import time

__all__ = ["WallPacer", "running"]


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
    stop: threading.Event, time_s: float, dt_s: float, until_s: float | None = None
) -> bool:
    """Whether a loop at simulated ``time_s`` [s], stepping ``dt_s`` [s], takes another
    step: not stopped, and not yet at ``until_s`` (half a step of rounding allowed)."""
    return not stop.is_set() and (until_s is None or time_s < until_s - 0.5 * dt_s)

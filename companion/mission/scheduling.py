"""Real-time scheduling of the control thread for the mission (Linux SCHED_FIFO).

Under normal scheduling any other process on the computer can hold the control loop off
its core; measured with two CPU-bound processes beside the demo on 2 cores, 3 of 9 flights
dropped poses under normal scheduling, none of 4 under SCHED_FIFO; with this module
the pose -> setpoint p99 was 0.49-0.67 ms in 6 flights against 0.61-1.52 ms under
normal scheduling (docs/performance.md, "The flight loop").

The app asks for SCHED_FIFO at ``flight.realtime_priority`` for the thread that runs the
mission (the asyncio loop: link, control cycle, arm) and gives the previous policy back
when the mission ends. Linux allows it to root, to a process with CAP_SYS_NICE, or up to
the user's RLIMIT_RTPRIO (systemd ``LimitRTPRIO=``, limits.conf ``rtprio``); the kernel's
real-time throttling (``sched_rt_runtime_us``, 95 % by default) keeps a runaway loop from
starving the computer.

:class:`ThreadTimes` reads the thread's time on a CPU and waiting for one, from which the
control loop tells who held up a late cycle (:mod:`companion.mission.loop_period`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

_REAL_TIME_POLICIES = frozenset(
    getattr(os, name) for name in ("SCHED_FIFO", "SCHED_RR") if hasattr(os, name)
)
"""Linux's real-time policies."""

_DEPLOY_HINT = "README 'Deploying on an onboard computer'"


@dataclass(frozen=True)
class Scheduling:
    """The control thread's scheduling for the mission: ``policy`` as said (``SCHED_FIFO
    50``, ``normal``, ``unknown``), and a note for the flight's events when the loop runs
    without real-time scheduling or the OS cannot say (None otherwise)."""

    policy: str
    note: str | None
    _restore: tuple[int, os.sched_param] | None = None

    def restore(self) -> None:
        """Give the calling thread back the policy it had before :func:`enter_real_time`
        changed it (nothing when it did not)."""
        if self._restore is not None:
            policy, param = self._restore
            os.sched_setscheduler(0, policy, param)


def enter_real_time(priority: int) -> Scheduling:
    """Put the calling thread under SCHED_FIFO at ``priority`` (1-99; 0: leave the
    scheduling alone) unless it already runs under a real-time policy (``chrt``, a
    systemd unit's ``CPUSchedulingPolicy=``), which is kept. Never raises for a refusal:
    the result's note says what happened."""
    if not 0 <= priority <= 99:
        raise ValueError(f"a SCHED_FIFO priority is 1-99 (0: none), not {priority}")
    if not hasattr(os, "sched_getscheduler"):
        return Scheduling(
            "unknown", "this OS cannot set the control thread's scheduling: it runs as started"
        )
    policy = os.sched_getscheduler(0)
    if policy in _REAL_TIME_POLICIES:
        name = "SCHED_FIFO" if policy == os.SCHED_FIFO else "SCHED_RR"
        return Scheduling(f"{name} {os.sched_getparam(0).sched_priority}", None)
    delay = (
        "the control loop runs under normal scheduling: other processes on this computer "
        "can delay it"
    )
    if priority == 0:
        return Scheduling(
            "normal",
            f"{delay} (flight.realtime_priority = 0; chrt --fifo 50 gives it real-time "
            f"scheduling, {_DEPLOY_HINT})",
        )
    previous = os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        why = (
            "(flight.realtime_priority) is not permitted to this user (root, CAP_SYS_NICE "
            f"or an rtprio limit: {_DEPLOY_HINT})"
            if isinstance(exc, PermissionError)
            else f"refused ({exc.strerror})"
        )
        return Scheduling("normal", f"{delay}: SCHED_FIFO priority {priority} {why}")
    return Scheduling(f"SCHED_FIFO {priority}", None, (policy, previous))


class ThreadTimes:
    """The calling thread's time on a CPU and time waiting for one, from Linux's
    ``/proc/thread-self/schedstat`` (the scheduler's own accounting, in ns).

    Open it in the thread to watch (the file belongs to the thread that opened it) and
    :meth:`close` it there when done; :meth:`read` is one ``pread``, about 1 us.
    """

    def __init__(self) -> None:
        try:
            self._fd: int | None = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
        except OSError:
            self._fd = None

    def read(self) -> tuple[float, float] | None:
        """(time run, time runnable but waiting for a CPU) since the thread started [s];
        None where the kernel does not account them (not Linux, no CONFIG_SCHED_INFO)."""
        if self._fd is None:
            return None
        run_ns, wait_ns, _ = os.pread(self._fd, 64, 0).split()
        return int(run_ns) * 1e-9, int(wait_ns) * 1e-9

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

"""The local engine: a pool of worker processes on this machine, each flying one flight at
a time (:func:`sitl.campaign.fly.fly_flight`), no server to start.

Workers are started with ``spawn`` (a fresh interpreter: no threads or locks copied from the
campaign's process) and ignore Ctrl-C; the campaign's process hands each idle worker one
flight over a pipe and gets its row back on the same pipe. It alone writes the results
(the ``on_row`` callback commits each row as it arrives), so a worker that dies loses only
the flight it was flying. That flight is given to a new worker once more; if its worker
dies again it is recorded as an error (a flight that kills its process is not retried
forever). Ctrl-C in the campaign's process stops the workers and returns: the rows already
committed stay, the rest is flown by the next run.
"""

from __future__ import annotations

import multiprocessing
import signal
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from typing import Any

from sitl.campaign.flights import Flight

__all__ = ["WORKER_DEATHS", "FlightTask", "run_local"]

WORKER_DEATHS = 2
"""Times a flight's worker may die under it before the flight is recorded as an error."""

FlightTask = tuple[Flight, dict[str, Any]]
"""A flight and its scenario document."""


def _worker(conn: Connection) -> None:
    """A worker's loop: fly each task received, send its row; stop on ``None``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from sitl.campaign.fly import fly_flight

    while True:
        try:
            task = conn.recv()
        except EOFError:
            return
        if task is None:
            return
        flight, document = task
        conn.send(fly_flight(flight, document))


@dataclass
class _Worker:
    number: int
    process: BaseProcess
    conn: Connection
    task: FlightTask | None = None


def _start(number: int) -> _Worker:
    context = multiprocessing.get_context("spawn")
    ours, theirs = context.Pipe()
    process = context.Process(target=_worker, args=(theirs,), name=f"campaign-worker-{number}")
    # Started with Ctrl-C ignored: the interpreter keeps that while it boots, so a Ctrl-C
    # meant for the campaign never interrupts a worker's start-up.
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        process.start()
    finally:
        signal.signal(signal.SIGINT, previous)
    theirs.close()
    return _Worker(number, process, ours)


def _stop(workers: Sequence[_Worker]) -> None:
    for w in workers:
        if w.process.is_alive():
            w.process.terminate()
    for w in workers:
        w.process.join(timeout=5.0)
        if w.process.is_alive():
            w.process.kill()
            w.process.join()
        w.conn.close()


def run_local(
    tasks: Sequence[FlightTask],
    workers: int,
    on_row: Callable[[Flight, dict[str, Any]], None],
) -> None:
    """Fly ``tasks`` on ``workers`` processes; ``on_row(flight, row)`` for each as it
    finishes (in this process, in finishing order; ``row['worker']`` says which worker).

    Returns when every flight has a row; KeyboardInterrupt (Ctrl-C) stops the workers,
    calls nothing more and propagates.
    """
    if workers < 1:
        raise ValueError(f"workers must be 1 or more, got {workers}")
    pending: deque[FlightTask] = deque(tasks)
    deaths: dict[str, int] = {}
    pool: list[_Worker] = []
    started = 0
    try:
        for _ in range(min(workers, len(pending))):
            started += 1
            pool.append(_start(started))
        while True:
            for i, w in enumerate(pool):
                if w.task is None and pending:
                    if not w.process.is_alive():  # it died idle: no flight lost
                        w.conn.close()
                        started += 1
                        pool[i] = w = _start(started)
                    w.task = pending.popleft()
                    w.conn.send(w.task)
            busy = [w for w in pool if w.task is not None]
            if not busy:
                break
            ready = wait([w.conn for w in busy] + [w.process.sentinel for w in busy])
            for w in busy:
                if w.conn not in ready and w.process.sentinel not in ready:
                    continue
                flight = w.task[0] if w.task is not None else None
                assert flight is not None
                try:
                    row = w.conn.recv()
                except (EOFError, OSError):
                    row = None
                if row is not None:
                    row["worker"] = w.number
                    w.task = None
                    on_row(flight, row)
                    continue
                # The worker died under this flight.
                w.process.join()
                code = w.process.exitcode
                deaths[flight.flight_id] = deaths.get(flight.flight_id, 0) + 1
                if deaths[flight.flight_id] >= WORKER_DEATHS:
                    on_row(
                        flight,
                        {
                            "status": "error",
                            "error": f"its worker process died {WORKER_DEATHS} times while "
                            f"flying it (last exit code {code})",
                            "worker": w.number,
                        },
                    )
                else:
                    pending.appendleft(w.task)  # type: ignore[arg-type]
                w.conn.close()
                pool.remove(w)
                if pending:
                    started += 1
                    pool.append(_start(started))
        for w in pool:
            w.conn.send(None)
    finally:
        _stop(pool)

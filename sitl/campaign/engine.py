"""The local engine: a pool of worker processes on this machine, each flying one flight at
a time (:func:`sitl.campaign.fly.fly_flight`), no server to start.

Workers are started with ``spawn`` (a fresh interpreter: no threads or locks copied from the
campaign's process) and ignore Ctrl-C; the campaign's process hands each idle worker one
flight over a pipe and gets its row back on the same pipe. It alone writes the results
(the ``on_row`` callback commits each row as it arrives), so a worker that dies loses only
the flight it was flying. That flight is given to a new worker once more; if its worker
dies again it is recorded as an error (a flight that kills its process is not retried
forever). A flight that runs past a wall-clock timeout has its worker stopped, which
counts the same. Ctrl-C in the campaign's process stops the workers and returns: the rows already
committed stay, the rest is flown by the next run.
"""

from __future__ import annotations

import multiprocessing
import signal
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from typing import Any

from sitl.campaign.flights import Flight

__all__ = ["WORKER_DEATHS", "FlightTask", "death_row", "run_local"]

WORKER_DEATHS = 2
"""Times a flight's worker may die under it before the flight is recorded as an error."""

FlightTask = tuple[Flight, dict[str, Any]]
"""A flight and its scenario document."""


def death_row(deaths: dict[str, int], flight: Flight, why: str) -> dict[str, Any] | None:
    """Count one more worker death under ``flight`` in ``deaths`` (flight id -> deaths);
    None: fly it once more; else, at :data:`WORKER_DEATHS`, its error row."""
    deaths[flight.flight_id] = deaths.get(flight.flight_id, 0) + 1
    if deaths[flight.flight_id] < WORKER_DEATHS:
        return None
    error = f"not flown: {why}, {WORKER_DEATHS} times (a flight is not retried forever)"
    return {"status": "error", "error": error}


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
    since: float = 0.0
    """When the worker got its flight (monotonic clock) [s]."""


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
    *,
    flight_timeout_s: float | None = None,
) -> None:
    """Fly ``tasks`` on ``workers`` processes; ``on_row(flight, row)`` for each as it
    finishes (in this process, in finishing order; ``row['worker']`` says which worker).

    A flight still flying after ``flight_timeout_s`` of wall time has its worker stopped,
    which counts as the worker dying under it. Returns when every flight has a row;
    KeyboardInterrupt (Ctrl-C) stops the workers, calls nothing more and propagates.
    """
    if workers < 1:
        raise ValueError(f"workers must be 1 or more, got {workers}")
    if flight_timeout_s is not None and not flight_timeout_s > 0.0:
        raise ValueError(f"flight_timeout_s must be positive, got {flight_timeout_s}")
    pool = _Pool(tasks, on_row, flight_timeout_s)
    try:
        pool.run(workers)
    finally:
        _stop(pool.workers)


class _Pool:
    """The loop of :func:`run_local`: hand out flights, collect rows, replace dead workers."""

    def __init__(
        self,
        tasks: Sequence[FlightTask],
        on_row: Callable[[Flight, dict[str, Any]], None],
        timeout_s: float | None,
    ) -> None:
        self.pending: deque[FlightTask] = deque(tasks)
        self.on_row = on_row
        self.timeout_s = timeout_s
        self.deaths: dict[str, int] = {}
        self.workers: list[_Worker] = []
        self.started = 0

    def _new_worker(self) -> _Worker:
        self.started += 1
        return _start(self.started)

    def run(self, workers: int) -> None:
        for _ in range(min(workers, len(self.pending))):
            self.workers.append(self._new_worker())
        while True:
            for i, w in enumerate(self.workers):
                if w.task is None and self.pending:
                    if not w.process.is_alive():  # it died idle: no flight lost
                        w.conn.close()
                        self.workers[i] = w = self._new_worker()
                    w.task = self.pending.popleft()
                    w.since = time.monotonic()
                    w.conn.send(w.task)
            busy = [w for w in self.workers if w.task is not None]
            if not busy:
                break
            timeout = None
            if self.timeout_s is not None:
                first = min(w.since for w in busy)
                timeout = max(0.0, first + self.timeout_s - time.monotonic())
            ready = wait([w.conn for w in busy] + [w.process.sentinel for w in busy], timeout)
            for w in busy:
                if w.conn in ready or w.process.sentinel in ready:
                    self._collect(w)
                elif self.timeout_s is not None and time.monotonic() - w.since > self.timeout_s:
                    w.process.kill()
                    self._died(w, f"it flew longer than {self.timeout_s:g} s of wall time")
        for w in self.workers:
            w.conn.send(None)

    def _collect(self, w: _Worker) -> None:
        assert w.task is not None
        try:
            row = w.conn.recv()
        except (EOFError, OSError):
            row = None
        if row is None:
            w.process.join()
            self._died(w, f"its worker process died (exit code {w.process.exitcode})")
            return
        row["worker"] = w.number
        flight, w.task = w.task[0], None
        self.on_row(flight, row)

    def _died(self, w: _Worker, why: str) -> None:
        """The worker ``w`` is gone with its flight: fly that once more, or record it."""
        assert w.task is not None
        w.process.join()
        flight = w.task[0]
        error = death_row(self.deaths, flight, why)
        if error is not None:
            self.on_row(flight, {**error, "worker": w.number})
        else:
            self.pending.appendleft(w.task)
        w.conn.close()
        self.workers.remove(w)
        if self.pending:
            self.workers.append(self._new_worker())

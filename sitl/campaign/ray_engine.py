"""The Ray engine: a campaign's flights as Ray tasks (``sitl campaign --engine ray``), on
an existing Ray cluster or on a local Ray runtime started for the campaign.

Each task flies one flight with :func:`sitl.campaign.fly.fly_flight` (the local engine's
worker does the same) and returns its row; the campaign's process alone writes the rows,
as they finish. The engine keeps as many tasks in flight as the cluster has CPUs (one per
flight), so that a task's start is its submission and the wall-clock timeout is the
flight's own. A task whose worker dies (``kill -9``, a node lost) or that runs past the
timeout (cancelled, its worker killed) is flown once more, then recorded as an error, as
on the local engine (:data:`~sitl.campaign.engine.WORKER_DEATHS`); Ray's own retries are
off so that the two engines count alike. Ctrl-C cancels what is in flight and returns.

Ray is an optional extra (``pip install -e ".[campaign]"``), imported only here. On a
cluster every node needs this package installed (the tasks import ``sitl``); the row's
``worker`` is the slot of the engine's window that flew it (1 to the cluster's CPUs).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from sitl.campaign.engine import FlightTask, death_row
from sitl.campaign.flights import Flight

__all__ = ["RayUnavailableError", "fly_task", "run_ray"]

_WAIT_S = 1.0
"""Longest wall time between looks at the flights' timeouts [s]."""
_LOOPBACK = "127.0.0.1"
"""The local runtime's node address: nothing of it listens beyond this machine."""
_LOCAL_RUNTIME_ENV = {"RAY_worker_niceness": "0"}
"""Ray starts its workers at nice 15 by default (the raylet first): on a machine shared
with other work a flight then waits for the CPU most of its time (a 28 s CPU flight took
570 s of wall time beside a test run). The local runtime's workers keep the normal
priority, as the local engine's do."""


@contextmanager
def _environment(values: dict[str, str]) -> Iterator[None]:
    """These environment variables set while the block runs (the local runtime's
    processes inherit them), the previous values back after it."""
    before = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


class RayUnavailableError(RuntimeError):
    """Ray is not installed, or the cluster cannot be reached (one line)."""


def fly_task(flight: Flight, document: dict[str, Any]) -> dict[str, Any]:
    """The body of a Ray task: fly one flight (:func:`sitl.campaign.fly.fly_flight`)."""
    from sitl.campaign.fly import fly_flight

    return fly_flight(flight, document)


@dataclass
class _Running:
    task: FlightTask
    slot: int
    since: float
    """When the task was submitted (monotonic clock) [s]."""


def run_ray(
    tasks: Sequence[FlightTask],
    on_row: Callable[[Flight, dict[str, Any]], None],
    *,
    address: str | None = None,
    cpus: int = 1,
    flight_timeout_s: float | None = None,
) -> int:
    """Fly ``tasks`` as Ray tasks; ``on_row(flight, row)`` for each as it finishes.

    ``address``: a running cluster (``"auto"``, ``"ray://HOST:PORT"``, ``"HOST:PORT"``);
    ``None`` starts a local Ray runtime of ``cpus`` CPUs for the campaign and stops it at
    the end. Returns the number of flights flown at once (the cluster's CPUs). Raises
    :class:`RayUnavailableError` when Ray is missing or the cluster does not answer;
    KeyboardInterrupt (Ctrl-C) cancels the tasks in flight and propagates.
    """
    if cpus < 1:
        raise ValueError(f"cpus must be 1 or more, got {cpus}")
    if flight_timeout_s is not None and not flight_timeout_s > 0.0:
        raise ValueError(f"flight_timeout_s must be positive, got {flight_timeout_s}")
    try:
        import ray
    except ImportError:
        raise RayUnavailableError(
            'the Ray engine needs Ray: pip install -e ".[campaign]"'
        ) from None
    try:
        if address is None:
            with _environment(_LOCAL_RUNTIME_ENV):
                ray.init(
                    num_cpus=cpus,
                    include_dashboard=False,
                    log_to_driver=False,
                    logging_level=logging.ERROR,
                    _node_ip_address=_LOOPBACK,
                )
        else:
            ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        where = address or "a local runtime"
        raise RayUnavailableError(f"cannot start or reach Ray at {where}: {first}") from None
    try:
        window = max(1, int(ray.cluster_resources().get("CPU", 1)))
        _Window(ray, tasks, on_row, window, flight_timeout_s).run()
        return window
    finally:
        ray.shutdown()


class _Window:
    """The loop of :func:`run_ray`: keep ``size`` tasks in flight, collect rows."""

    def __init__(
        self,
        ray: Any,
        tasks: Sequence[FlightTask],
        on_row: Callable[[Flight, dict[str, Any]], None],
        size: int,
        timeout_s: float | None,
    ) -> None:
        self.ray = ray
        self.remote = ray.remote(num_cpus=1, max_retries=0)(fly_task)
        self.pending = list(reversed(tasks))
        self.on_row = on_row
        self.free = list(range(size, 0, -1))
        self.timeout_s = timeout_s
        self.deaths: dict[str, int] = {}
        self.running: dict[Any, _Running] = {}

    def run(self) -> None:
        ray = self.ray
        try:
            while self.pending or self.running:
                while self.pending and self.free:
                    task = self.pending.pop()
                    ref = self.remote.remote(*task)
                    self.running[ref] = _Running(task, self.free.pop(), time.monotonic())
                done, _ = ray.wait(list(self.running), num_returns=1, timeout=_WAIT_S)
                for ref in done:
                    self._collect(ref)
                self._stop_overdue()
        except KeyboardInterrupt:
            for ref in self.running:
                ray.cancel(ref, force=True)
            raise

    def _collect(self, ref: Any) -> None:
        ray = self.ray
        running = self.running.pop(ref)
        self.free.append(running.slot)
        flight = running.task[0]
        try:
            row = ray.get(ref)
        except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as exc:
            self._died(running, f"its worker process died ({type(exc).__name__})")
            return
        except ray.exceptions.TaskCancelledError:
            self._died(running, f"it flew longer than {self.timeout_s:g} s of wall time")
            return
        except ray.exceptions.RayError as exc:
            row = {"status": "error", "error": f"the Ray task failed: {exc}"}
        row["worker"] = running.slot
        self.on_row(flight, row)

    def _stop_overdue(self) -> None:
        if self.timeout_s is None:
            return
        now = time.monotonic()
        for ref, running in self.running.items():
            if now - running.since > self.timeout_s:
                self.ray.cancel(ref, force=True)  # its ray.get raises TaskCancelledError

    def _died(self, running: _Running, why: str) -> None:
        """Fly the flight of a task that is gone once more, or record it as an error."""
        flight = running.task[0]
        error = death_row(self.deaths, flight, why)
        if error is not None:
            self.on_row(flight, {**error, "worker": running.slot})
        else:
            self.pending.append(running.task)

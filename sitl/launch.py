"""Start ``sitl run`` as a child process on free loopback ports and wait until it is ready.

Used by ``companion demo`` and the end-to-end tests: the vehicle runs in its own process,
as a user runs it, and prints a ``ready {json}`` line with the servo bus URL; a thread
keeps its output pipe drained.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["SitlNotReadyError", "SitlProcess", "free_udp_port", "start_sitl"]


class SitlNotReadyError(RuntimeError):
    """The vehicle process exited or printed no ``ready`` line in time."""


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nothing is bound to right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@dataclass
class SitlProcess:
    """A running ``sitl run`` and where to reach it."""

    process: subprocess.Popen
    onboard_port: int
    """Where the vehicle's onboard link sends (the API/companion side binds it)."""
    gcs_port: int
    """Where the vehicle's GCS link sends (the ground station binds it)."""
    onboard_local_port: int
    gcs_local_port: int
    arm_bus: str
    truth_log: Path | None
    output: queue.Queue
    """Lines the process printed after ``ready`` (None at its end)."""

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self, timeout_s: float = 10.0) -> str:
        """SIGINT, wait, return what it printed after ``ready`` (the run's statistics)."""
        if self.alive():
            self.process.send_signal(signal.SIGINT)
        try:
            self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        out = []
        while True:
            try:
                line = self.output.get(timeout=2.0)
            except queue.Empty:
                break
            if line is None:
                break
            out.append(line)
        return "".join(out)


def start_sitl(
    config: str | Path,
    *extra: str,
    speed: float = 1.0,
    truth_log: Path | None = None,
    timeout_s: float = 60.0,
) -> SitlProcess:
    """Start ``sitl run --config config *extra`` at ``speed`` on four free loopback UDP
    ports and wait for its ``ready`` line; raises :class:`SitlNotReadyError` with what
    it printed otherwise."""
    ports = [free_udp_port() for _ in range(4)]
    args = [
        sys.executable,
        "-c",
        "from sitl.cli import main; main()",
        "run",
        "--config",
        str(config),
        "--speed",
        str(speed),
        "--onboard-port",
        str(ports[0]),
        "--gcs-port",
        str(ports[1]),
        "--onboard-local-port",
        str(ports[2]),
        "--gcs-local-port",
        str(ports[3]),
        *extra,
    ]
    if truth_log is not None:
        args += ["--truth-log", str(truth_log)]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
    )
    lines: queue.Queue[str | None] = queue.Queue()

    def pump() -> None:  # readline blocks; a thread keeps the pipe drained
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line)
        lines.put(None)

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    seen = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            continue
        if line is None:
            break
        seen.append(line)
        if line.startswith("ready "):
            where = json.loads(line[len("ready ") :])
            return SitlProcess(
                proc, *ports, arm_bus=where["arm_bus"], truth_log=truth_log, output=lines
            )
    proc.kill()
    raise SitlNotReadyError("sitl run did not become ready:\n" + "".join(seen))

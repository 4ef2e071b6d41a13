"""Start ``sitl run`` or ``sitl sih`` as a child process and wait until it is ready.

Used by ``sitl demo`` and the end-to-end tests: the vehicle runs in its own process,
as a user runs it, and prints a ``ready {json}`` line saying where to connect (the servo
bus URL, and for ``sitl sih`` the companion's MAVLink URL and PX4's log); a thread keeps
its output pipe drained. Both commands stop cleanly on SIGINT (``sitl sih`` stops the PX4
it started), which is how a child that does not get ready is stopped too.
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

__all__ = [
    "SihProcess",
    "SitlNotReadyError",
    "SitlProcess",
    "free_udp_port",
    "start_sih",
    "start_sitl",
]

_SITL_CLI = ("-c", "from sitl.cli import main; main()")


class SitlNotReadyError(RuntimeError):
    """The vehicle process exited or printed no ``ready`` line in time."""


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nothing is bound to right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@dataclass
class _ReadyChild:
    """A ``sitl`` child process that printed its ``ready`` line."""

    process: subprocess.Popen
    where: dict[str, str]
    """The ``ready`` line's JSON: where to connect."""
    output: queue.Queue
    """Lines the process printed after ``ready`` (None at its end)."""

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self, timeout_s: float = 20.0) -> str:
        """SIGINT, wait (then SIGKILL), return what it printed after ``ready``."""
        _interrupt(self.process, timeout_s)
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


@dataclass
class SitlProcess(_ReadyChild):
    """A running ``sitl run`` and where to reach it."""

    onboard_port: int
    """Where the vehicle's onboard link sends (the API/companion side binds it)."""
    gcs_port: int
    """Where the vehicle's GCS link sends (the ground station binds it)."""
    onboard_local_port: int
    gcs_local_port: int
    arm_bus: str
    truth_log: Path | None


@dataclass
class SihProcess(_ReadyChild):
    """A running ``sitl sih`` (PX4 SIH and the arm's servos) and where to reach it."""

    connect: str
    """The companion's MAVLink URL (PX4's onboard link)."""
    arm_bus: str
    """The servo bus URL."""
    px4_log: Path
    """PX4's console log (removed at stop unless ``--keep-log``)."""


PX4_READY_TIMEOUT_S = 180.0
"""How long ``sitl run --autopilot px4`` may take to get ready [s]: PX4 boots, the EKF
aligns and the vehicle is armable (about 20 s here, much more on a loaded machine)."""


def start_sitl(
    config: str | Path,
    *extra: str,
    speed: float = 1.0,
    truth_log: Path | None = None,
    px4_dir: Path | None = None,
    px4_log: Path | None = None,
    timeout_s: float | None = None,
) -> SitlProcess:
    """Start ``sitl run --config config *extra`` at ``speed`` on four free loopback UDP
    ports and wait for its ``ready`` line; raises :class:`SitlNotReadyError` with what
    it printed otherwise. With ``px4_dir`` the real PX4 of that build flies it
    (``--autopilot px4``), its logs kept in ``px4_log`` if given; ``timeout_s`` defaults
    to 60 s, :data:`PX4_READY_TIMEOUT_S` with PX4."""
    ports = [free_udp_port() for _ in range(4)]
    args = ["run", "--config", str(config), "--speed", str(speed)]
    for option, port in zip(
        ("--onboard-port", "--gcs-port", "--onboard-local-port", "--gcs-local-port"),
        ports,
        strict=True,
    ):
        args += [option, str(port)]
    args += extra
    if truth_log is not None:
        args += ["--truth-log", str(truth_log)]
    if px4_dir is not None:
        args += ["--autopilot", "px4", "--px4-dir", str(px4_dir)]
        if px4_log is not None:
            args += ["--keep-log", str(px4_log)]
    elif px4_log is not None:
        raise ValueError("px4_log needs px4_dir: only PX4 writes that log")
    if timeout_s is None:
        timeout_s = 60.0 if px4_dir is None else PX4_READY_TIMEOUT_S
    process, where, output = _start_ready(args, timeout_s)
    onboard, gcs, onboard_local, gcs_local = ports
    return SitlProcess(
        process,
        where,
        output,
        onboard_port=onboard,
        gcs_port=gcs,
        onboard_local_port=onboard_local,
        gcs_local_port=gcs_local,
        arm_bus=where["arm_bus"],
        truth_log=truth_log,
    )


def start_sih(
    config: str | Path,
    *extra: str,
    px4_dir: str | Path | None = None,
    timeout_s: float = 120.0,
) -> SihProcess:
    """Start ``sitl sih --config config *extra`` (e.g. ``--navigation mocap``) with the
    PX4 build ``px4_dir`` (default ``$PX4_SITL_DIR``) and wait for its ``ready`` line;
    raises :class:`SitlNotReadyError` with what it printed otherwise."""
    args = ["sih", "--config", str(config), *extra]
    if px4_dir is not None:
        args += ["--px4-dir", str(px4_dir)]
    process, where, output = _start_ready(args, timeout_s)
    return SihProcess(
        process,
        where,
        output,
        connect=where["connect"],
        arm_bus=where["arm_bus"],
        px4_log=Path(where["px4_log"]),
    )


def _start_ready(
    args: list[str], timeout_s: float
) -> tuple[subprocess.Popen, dict[str, str], queue.Queue]:
    """Run ``sitl *args`` and wait for its ``ready {json}`` line; return the process, the
    line's JSON and the queue of the lines it prints next. A child that exits or stays
    silent is interrupted (SIGINT, then SIGKILL) and :class:`SitlNotReadyError` raised."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, *_SITL_CLI, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        # its own session: a terminal's Ctrl-C reaches the caller alone, which puts the
        # arm in its safe state over the simulator's bus before it stops the simulator
        start_new_session=True,
    )
    lines: queue.Queue[str | None] = queue.Queue()

    def pump() -> None:  # readline blocks; a thread keeps the pipe drained
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
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
            return proc, json.loads(line[len("ready ") :]), lines
    _interrupt(proc, 20.0)
    raise SitlNotReadyError(f"sitl {args[0]} did not become ready:\n" + "".join(seen))


def _interrupt(process: subprocess.Popen, timeout_s: float) -> None:
    """SIGINT (the commands clean up: ``sitl sih`` stops its PX4), then SIGKILL."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()

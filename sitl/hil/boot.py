"""PX4's way to ready in the loop of our physics: its start-up script done, then its links
moved onto the requested ports and a heartbeat link started (PX4 ``mavlink`` commands, in a
thread: they need PX4's lockstep clock to move), then "Ready for takeoff!"; and PX4's
console log handed on line by line. :class:`sitl.hil.vehicle.Px4InTheLoop` advances it
from its loop."""

from __future__ import annotations

import subprocess
import threading
from collections.abc import Callable
from pathlib import Path

from sitl.px4_sitl.launcher import Px4NotReadyError, Px4Ports, Px4Sitl
from sitl.vehicle.launch import free_udp_port
from sitl.vehicle.options import RunOptions

__all__ = ["Px4Boot", "forward_log", "link_commands"]

_STARTUP_DONE = "Startup script returned successfully"
_READY = "Ready for takeoff!"
_ONBOARD_RATE_B_S = 4_000_000
_MODE_LINK_RATE_B_S = 20_000


class Px4Boot:
    """PX4's way to ready, advanced from the loop: start-up script done, then its links
    moved onto the requested ports and the heartbeat link started (PX4 commands, in a
    thread: they need PX4's lockstep clock to move), then "Ready for takeoff!"."""

    def __init__(
        self, px4: Px4Sitl, options: RunOptions, onboard: tuple[int, int], mode_port: int
    ) -> None:
        self._px4 = px4
        self._options = options
        self._onboard = onboard
        self._mode_port = mode_port
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self.waiting_for = "its start-up script"

    def advance(self) -> bool:
        """True once PX4 is ready; raises Px4NotReadyError when a link does not start."""
        if self._error is not None:
            raise Px4NotReadyError(f"PX4 did not start its links: {self._error}")
        text = self._px4.log_path.read_text(errors="replace")
        if self._thread is None:
            if _STARTUP_DONE in text:
                self.waiting_for = "its links"
                self._thread = threading.Thread(target=self._links, name="px4-links", daemon=True)
                self._thread.start()
            return False
        if self._thread.is_alive():
            return False
        self.waiting_for = '"Ready for takeoff!"'
        return _READY in text

    def _links(self) -> None:
        try:
            for args in link_commands(
                self._px4.ports, self._options, self._onboard, self._mode_port
            ):
                self._px4.command("mavlink", *args, timeout_s=30.0)
        except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as exc:
            self._error = exc


def link_commands(
    ports: Px4Ports | None, options: RunOptions, onboard: tuple[int, int], mode_port: int
) -> list[list[str]]:
    """PX4 ``mavlink`` commands that move the onboard link of PX4 instance ``ports`` onto
    ``onboard`` (local, remote: the companion's ports of ``options.ports``, or the
    companion relay's) and the GCS link onto ``options.ports`` (when they differ), and
    start the heartbeat link to ``mode_port``, with the flags of PX4's own
    ``px4-rc.mavlink``."""
    assert ports is not None
    want = options.ports
    commands: list[list[str]] = []
    if onboard != (ports.onboard_local, ports.onboard_remote):
        commands.append(["stop", "-u", str(ports.onboard_local)])
        commands.append(
            ["start", "-x", "-u", str(onboard[0]), "-r", str(_ONBOARD_RATE_B_S), "-f",
             "-m", "onboard", "-o", str(onboard[1])]
        )  # fmt: skip
    if (want.gcs_local, want.gcs_remote) != (ports.gcs_local, 14550):
        commands.append(["stop", "-u", str(ports.gcs_local)])
        commands.append(
            ["start", "-x", "-u", str(want.gcs_local), "-r", str(_ONBOARD_RATE_B_S), "-f",
             "-o", str(want.gcs_remote)]
        )  # fmt: skip
    commands.append(
        ["start", "-u", str(free_udp_port()), "-o", str(mode_port), "-m", "minimal",
         "-r", str(_MODE_LINK_RATE_B_S)]
    )  # fmt: skip
    return commands


def forward_log(path: Path, offset: int, console: Callable[[str], None]) -> int:
    """Hand the complete lines PX4 wrote after ``offset`` to ``console``; the new offset."""
    with open(path, "rb") as log:
        log.seek(offset)
        data = log.read()
    end = data.rfind(b"\n") + 1
    for line in data[:end].decode(errors="replace").splitlines():
        if line.strip():
            console(line)
    return offset + end

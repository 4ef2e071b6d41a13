"""Start the real PX4 autopilot built for SITL (``make px4_sitl``) and wait until it flies.

The companion's PX4 behaviour is judged against PX4 itself, not only against ``sitl run``
(the imitation was written from the same beliefs as the companion). This module starts a
PX4 SITL build the way its start-up script expects, once per test or run:

- the build is a directory with ``bin/px4`` and ``etc/`` (``PX4_SITL_DIR``; PX4's own
  ``build/px4_sitl_default`` has the same layout). PX4 calls its modules through
  ``bin/px4-<module>`` links to the binary; a copy of the build whose links became plain
  files (a read-only share, an archive) still runs, because every start makes its own
  ``bin/`` of symbolic links in a fresh working directory;
- an instance number whose ports are all free is chosen (PX4 derives every port from it:
  onboard link UDP 14580 + N -> 14540 + N, GCS link 18570 + N -> 14550, camera and gimbal
  links, SIH display 19450 + N -> 19410 + N, simulator TCP 4560 + N) and claimed with a
  lock file until PX4 stops, so that processes starting PX4 at the same time (parallel
  tests, two ``sitl`` commands) never pick the same instance in the window between the
  choice and the binding of its ports;
- parameters go in as ``PX4_PARAM_<NAME>`` (set after the airframe file); PX4's battery
  simulator is held full (``SIM_BAT_MIN_PCT = 100``, :data:`DEFAULT_PARAMS`) unless asked
  otherwise: its voltage would fall while the simulated thrust does not follow it (SIH's
  rotors ignore the battery, and so does our physics in the loop), and the companion's
  thrust scale follows the voltage it reports;
- the process's output is written to ``px4.log`` in the working directory, which is kept
  when asked (a failed test) and removed otherwise.

Instances above 9 send their onboard link to 14549 whatever their number (PX4's
``px4-rc.mavlink``), so only instances 0-9 are used.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO

__all__ = [
    "DEFAULT_PARAMS",
    "PX4_SITL_DIR_ENV",
    "Px4Build",
    "Px4BuildError",
    "Px4NotReadyError",
    "Px4Ports",
    "Px4Sitl",
    "free_instance",
    "interrupts_held",
    "release_instance",
]

PX4_SITL_DIR_ENV = "PX4_SITL_DIR"
"""Environment variable naming the PX4 SITL build directory."""
DEFAULT_PARAMS: dict[str, float] = {"SIM_BAT_MIN_PCT": 100.0}
"""Parameters every start sets unless the caller gives them: PX4's simulated battery held
full (its thrust does not follow it; see the module docstring)."""

_INSTANCES = range(10)
_CLAIMS: dict[int, IO[bytes]] = {}
"""Instance -> the open lock file holding this process's claim on it."""
_READY_LINES = ("Ready for takeoff!",)
_FAILED_LINES = ("Startup script returned with return value", "ERROR [init]")


class Px4BuildError(RuntimeError):
    """No usable PX4 SITL build at the given place."""


class Px4NotReadyError(RuntimeError):
    """PX4 exited or did not report ready in time; the message ends with its log's tail."""


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold SIGINT and SIGTERM raised as ``KeyboardInterrupt`` until the block is done, then
    raise it: a process started in the block is then known to whoever cleans up. Only in the
    main thread, and only the signals whose handler is Python's default one."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    signums = [
        signum
        for signum in (signal.SIGINT, signal.SIGTERM)
        if signal.getsignal(signum) is signal.default_int_handler
    ]
    held: list[int] = []
    for signum in signums:
        signal.signal(signum, lambda signum, _frame: held.append(signum))
    try:
        yield
    finally:
        for signum in signums:
            signal.signal(signum, signal.default_int_handler)
    if held:
        raise KeyboardInterrupt()


@dataclass(frozen=True)
class Px4Build:
    """A PX4 SITL build directory: ``bin/px4`` and the ``etc`` data directory."""

    root: Path

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Px4Build | None:
        """The build named by ``PX4_SITL_DIR``, or None when the variable is unset or
        empty. Raises :class:`Px4BuildError` when it names no usable build."""
        value = (os.environ if environ is None else environ).get(PX4_SITL_DIR_ENV, "")
        if not value:
            return None
        return cls.at(value)

    @classmethod
    def at(cls, path: str | Path) -> Px4Build:
        """The build at ``path``; raises :class:`Px4BuildError` if it is not one."""
        build = cls(Path(path).resolve())
        build.check()
        return build

    @property
    def binary(self) -> Path:
        return self.root / "bin" / "px4"

    @property
    def etc(self) -> Path:
        return self.root / "etc"

    def check(self) -> None:
        """Raise :class:`Px4BuildError` unless the binary runs and the start-up script
        and airframes are there."""
        if not self.binary.is_file() or not os.access(self.binary, os.X_OK):
            raise Px4BuildError(f"{self.root}: no executable bin/px4 (is this a PX4 SITL build?)")
        if not (self.etc / "init.d-posix" / "rcS").is_file():
            raise Px4BuildError(f"{self.root}: no etc/init.d-posix/rcS")

    def module_names(self) -> list[str]:
        """Names PX4's start-up script calls (``px4-<module>`` and ``px4-alias.sh``)."""
        return sorted(p.name for p in (self.root / "bin").iterdir() if p.name.startswith("px4-"))

    def airframe(self, autostart: int) -> Path:
        """The airframe file of ``SYS_AUTOSTART`` = ``autostart``; Px4BuildError if none."""
        folder = self.etc / "init.d-posix" / "airframes"
        matches = sorted(folder.glob(f"{autostart}_*"))
        if not matches:
            raise Px4BuildError(f"{self.root}: no airframe {autostart} in {folder}")
        return matches[0]


@dataclass(frozen=True)
class Px4Ports:
    """The loopback ports of PX4 instance ``instance`` (all derived from it by PX4)."""

    instance: int

    @property
    def onboard_local(self) -> int:
        """PX4 binds this for its onboard (API/offboard) link."""
        return 14580 + self.instance

    @property
    def onboard_remote(self) -> int:
        """PX4's onboard link sends here: the companion binds it (``udpin``)."""
        return 14540 + self.instance

    @property
    def gcs_local(self) -> int:
        """PX4 binds this for its ground-station link (it sends to 14550)."""
        return 18570 + self.instance

    @property
    def sih_display_remote(self) -> int:
        """SIH sends its ground truth (HIL_STATE_QUATERNION) here."""
        return 19410 + self.instance

    @property
    def sih_display_local(self) -> int:
        """PX4 binds this for the SIH display link (SET_MESSAGE_INTERVAL goes here)."""
        return 19450 + self.instance

    @property
    def simulator_tcp(self) -> int:
        """An external simulator listens here for PX4's ``simulator_mavlink``."""
        return 4560 + self.instance

    def bound_by_px4(self) -> list[int]:
        """UDP ports PX4 binds itself for this instance."""
        n = self.instance
        return [14580 + n, 18570 + n, 14280 + n, 13030 + n, self.sih_display_local]

    @property
    def connect_url(self) -> str:
        """The companion's MAVLink URL for the onboard link."""
        return f"udpin://127.0.0.1:{self.onboard_remote}"


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _tcp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _claim(instance: int) -> bool:
    """Take the instance's lock file (released by :func:`release_instance` or when this
    process ends); False when another process or an earlier claim here holds it."""
    path = Path(tempfile.gettempdir()) / f"px4-sitl-instance-{instance}.lock"
    lock = open(path, "ab")  # closed by release_instance()
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        lock.close()
        return False
    _CLAIMS[instance] = lock
    return True


def free_instance() -> Px4Ports:
    """The ports of the lowest instance 0-9 that no one has claimed and whose ports are
    all free, claimed for this process until :func:`release_instance`;
    Px4NotReadyError when every instance is taken, saying what took each."""
    taken = []
    for n in _INSTANCES:
        if n in _CLAIMS:
            taken.append(f"{n}: claimed by this process")
            continue
        if not _claim(n):
            taken.append(f"{n}: claimed by another process")
            continue
        ports = Px4Ports(n)
        udp = [*ports.bound_by_px4(), ports.onboard_remote, ports.sih_display_remote]
        busy = [f"udp {p}" for p in udp if not _udp_free(p)]
        busy += [] if _tcp_free(ports.simulator_tcp) else [f"tcp {ports.simulator_tcp}"]
        if not busy:
            return ports
        release_instance(ports)
        taken.append(f"{n}: {', '.join(busy)} in use")
    raise Px4NotReadyError("no PX4 instance 0-9 has all its ports free (" + "; ".join(taken) + ")")


def release_instance(ports: Px4Ports) -> None:
    """Give up this process's claim on ``ports``' instance (none held: nothing to do)."""
    lock = _CLAIMS.pop(ports.instance, None)
    if lock is not None:
        lock.close()


class Px4Sitl:
    """One PX4 SITL process in a fresh working directory; a context manager.

    Parameters
    ----------
    build
        The PX4 SITL build.
    autostart
        ``SYS_AUTOSTART`` airframe (10044: SIH hexacopter; 3011: hexa-X for an external
        simulator through ``simulator_mavlink``).
    simulator, model
        ``PX4_SIMULATOR`` and ``PX4_SIM_MODEL`` (``sihsim``/``hex`` for SIH; None lets the
        airframe decide).
    params
        Parameters set after the airframe file (``PX4_PARAM_<NAME>``).
    env
        More environment variables for PX4 (e.g. ``PX4_SIM_SPEED_FACTOR``).
    ports
        The instance to run; default the first one whose ports are free.
    keep_dir
        Where to put the working directory (created); default a temporary directory.
    ready_lines
        Log lines that mean PX4 is up (default ``Ready for takeoff!``).
    """

    def __init__(
        self,
        build: Px4Build,
        *,
        autostart: int = 10044,
        simulator: str | None = "sihsim",
        model: str | None = "hex",
        params: Mapping[str, float] | None = None,
        env: Mapping[str, str] | None = None,
        ports: Px4Ports | None = None,
        keep_dir: Path | None = None,
        ready_lines: tuple[str, ...] = _READY_LINES,
    ) -> None:
        build.airframe(autostart)
        for name in params or {}:
            if not name.replace("_", "").isalnum() or name.upper() != name:
                raise ValueError(f"{name!r} is not a PX4 parameter name")
        self.build = build
        self.autostart = autostart
        self.simulator = simulator
        self.model = model
        self.params = {**DEFAULT_PARAMS, **(params or {})}
        self.extra_env = dict(env or {})
        self._requested_ports = ports
        self.ports: Px4Ports | None = None
        self._keep_dir = keep_dir
        self.ready_lines = ready_lines
        self.workdir: Path | None = None
        self.process: subprocess.Popen[bytes] | None = None
        self._log_file: IO[bytes] | None = None

    # ---------------------------------------------------------------- lifecycle

    def __enter__(self) -> Px4Sitl:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop(keep=exc[0] is not None)

    @property
    def log_path(self) -> Path:
        if self.workdir is None:
            raise RuntimeError("PX4 has not been started")
        return self.workdir / "px4.log"

    def _environment(self, ports: Px4Ports) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith("PX4_")}
        env["PX4_SYS_AUTOSTART"] = str(self.autostart)
        if self.simulator is not None:
            env["PX4_SIMULATOR"] = self.simulator
        if self.model is not None:
            env["PX4_SIM_MODEL"] = self.model
        for name, value in self.params.items():
            env[f"PX4_PARAM_{name}"] = _param_text(value)
        env.update(self.extra_env)
        return env

    def start(self, timeout_s: float = 60.0) -> None:
        """Start PX4 and wait for a ready line in its log; raises
        :class:`Px4NotReadyError` (the process stopped, its directory kept)."""
        if self.process is not None:
            raise RuntimeError("this Px4Sitl was already started")
        ports = self._requested_ports or free_instance()
        self.ports = ports
        if self._keep_dir is not None:
            self._keep_dir.mkdir(parents=True, exist_ok=True)
            self.workdir = Path(tempfile.mkdtemp(prefix="px4-", dir=self._keep_dir))
        else:
            self.workdir = Path(tempfile.mkdtemp(prefix="px4-sitl-"))
        bin_dir = self.workdir / "bin"
        bin_dir.mkdir()
        (bin_dir / "px4").symlink_to(self.build.binary)
        for name in self.build.module_names():
            target = self.build.root / "bin" / name if name.endswith(".sh") else self.build.binary
            (bin_dir / name).symlink_to(target)
        self._log_file = open(self.log_path, "wb")  # closed in stop()
        args = [str(bin_dir / "px4"), "-d", "-w", str(self.workdir / "run"), str(self.build.etc)]
        if ports.instance:
            args[1:1] = ["-i", str(ports.instance)]
        with interrupts_held():  # an interrupt inside Popen would leak PX4 unstopped
            self.process = subprocess.Popen(
                args,
                cwd=self.workdir,
                env=self._environment(ports),
                stdin=subprocess.DEVNULL,
                stdout=self._log_file,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        self.wait_for_log(self.ready_lines, timeout_s)

    def wait_for_log(self, lines: tuple[str, ...], timeout_s: float) -> None:
        """Wait until PX4's log holds one of ``lines``; raises :class:`Px4NotReadyError`
        (PX4 stopped, its directory kept) when it exits, its start-up script fails, or
        ``timeout_s`` [s] pass first. E.g. ``("Ready for takeoff!",)`` after starting with
        the start-up script's end as the ready line, when PX4 needs an input (motion
        capture) before it can become ready."""
        if self.process is None:
            raise RuntimeError("PX4 has not been started")
        deadline = time.monotonic() + timeout_s
        while True:
            text = self.log_path.read_text(errors="replace")
            if any(line in text for line in lines):
                return
            failed = [line for line in _FAILED_LINES if line in text]
            if self.process.poll() is not None or failed:
                reason = "exited" if self.process.poll() is not None else failed[0]
                self.stop(keep=True)
                raise Px4NotReadyError(f"PX4 {reason}:\n{self.log_tail()}")
            if time.monotonic() >= deadline:
                tail = self.log_tail()
                self.stop(keep=True)
                raise Px4NotReadyError(f"PX4 was not ready within {timeout_s:g} s:\n{tail}")
            time.sleep(0.2)

    def command(self, module: str, *args: str, timeout_s: float = 10.0) -> None:
        """Run a command in the running PX4 as its shell would (``px4-<module> --instance
        N args``, e.g. ``mavlink start ...``); its output goes to PX4's log. Raises
        :class:`subprocess.CalledProcessError` when PX4 reports a failure."""
        if self.process is None or self.ports is None or self.workdir is None:
            raise RuntimeError("PX4 has not been started")
        client = self.workdir / "bin" / f"px4-{module}"
        subprocess.run(
            [str(client), "--instance", str(self.ports.instance), *args],
            cwd=self.workdir,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            timeout=timeout_s,
            check=True,
        )

    def log_tail(self, lines: int = 30) -> str:
        """The last lines PX4 printed."""
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return "\n".join(text.splitlines()[-lines:])

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def ulogs(self) -> list[Path]:
        """The ULog flight logs PX4 wrote so far."""
        if self.workdir is None:
            return []
        return sorted((self.workdir / "run" / "log").rglob("*.ulg"))

    def stop(self, *, keep: bool = False, timeout_s: float = 10.0) -> Path | None:
        """Stop PX4 (SIGINT, then SIGKILL) and remove its working directory unless
        ``keep``; returns the kept directory (None when removed). Idempotent."""
        process, self.process = self.process, None
        if process is not None:
            if process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGINT)
                try:
                    process.wait(timeout=timeout_s)
                except subprocess.TimeoutExpired:
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(process.pid, signal.SIGKILL)
                    process.wait()
        if self._log_file is not None:
            self._log_file.close()
            self._log_file = None
        if self.ports is not None:
            release_instance(self.ports)
        workdir = self.workdir
        if workdir is None or not workdir.exists():
            return None
        if keep:
            return workdir
        shutil.rmtree(workdir, ignore_errors=True)
        return None


def _param_text(value: float) -> str:
    """A parameter value as PX4's ``param set`` reads it (integers without a point)."""
    if float(value).is_integer() and abs(value) < 2**31:
        return str(int(value))
    return repr(float(value))

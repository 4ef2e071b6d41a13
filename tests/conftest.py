"""Shared test fixtures."""

import asyncio
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from arm_driver.bus import open_buses

Runner = Callable[..., subprocess.CompletedProcess]

ROOT = Path(__file__).parent.parent


def _command_line(module: str) -> Runner:
    """Run ``module.main()`` (a console script's entry point) in a subprocess, as a user
    would run the command."""

    def run(*args: str, timeout: float = 600.0) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-c", f"from {module} import main; main()", *args],
            capture_output=True,
            text=True,
            timeout=timeout,
        )

    return run


@pytest.fixture
def run_cli() -> Runner:
    """The ``companion`` command line."""
    return _command_line("companion.cli.main")


@pytest.fixture
def run_sitl() -> Runner:
    """The ``sitl`` command line."""
    return _command_line("sitl.cli")


@pytest.fixture
def no_leaked_bus() -> Iterator[None]:
    """Fail a test that leaves an arm bus open, and close it so the next test is clean (as
    python-can's conftest does); modules opt in with ``usefixtures``."""
    yield
    leaked = open_buses()
    for bus in leaked:
        asyncio.run(bus.close())
    if leaked:
        pytest.fail(f"test left {len(leaked)} bus(es) open: {leaked}")


@pytest.fixture(scope="session")
def px4_build():
    """The PX4 SITL build named by ``PX4_SITL_DIR``; the test is skipped where there is
    none (a user without a PX4 build; CI points it at ``../shared/px4-sitl``)."""
    from sitl.px4_sitl.launcher import PX4_SITL_DIR_ENV, Px4Build

    build = Px4Build.from_env()
    if build is None:
        pytest.skip(f"no PX4 SITL build: set {PX4_SITL_DIR_ENV} to run the tests against real PX4")
    return build


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that runs PX4 (it needs ``px4_build``, directly or through a fixture) is
    ``slow``: the test command runs those after the rest, two at a time (PX4 boots in real
    time and takes free ports)."""
    for item in items:
        if "px4_build" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item, call):
    """Record each phase's report on the test item (``item.rep_call.failed``), so that
    fixtures can keep a failed test's process logs."""
    report = yield
    setattr(item, f"rep_{report.when}", report)
    return report


@pytest.fixture(scope="session")
def flight_install(tmp_path_factory, worker_id: str) -> Path:
    """The python of a fresh venv holding only the flight install (``pip install .``, no
    extra), as on the vehicle's companion computer; built once per run from the
    repository's files (tracked and new, not ignored: no stale ``build/``), the xdist
    workers sharing it (the first builds it under a file lock, the others wait for it)."""
    from filelock import FileLock  # here: the flight install runs this conftest without it

    base = tmp_path_factory.getbasetemp()
    shared = base if worker_id == "master" else base.parent
    where = shared / "flight-install"
    python = where / "venv" / "bin" / "python"
    with FileLock(str(shared / "flight-install.lock")):
        if not (where / "built").exists():
            shutil.rmtree(where, ignore_errors=True)
            _build_flight_install(where)
            (where / "built").touch()
    return python


def _build_flight_install(where: Path) -> None:
    """``pip install .`` of a copy of the repository into a fresh venv at ``where``."""
    source = where / "source"
    listed = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "-z"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.decode()
    for name in filter(None, listed.split("\0")):
        origin, copy = ROOT / name, source / name
        copy.parent.mkdir(parents=True, exist_ok=True)
        if origin.is_symlink():
            copy.symlink_to(origin.readlink())
        elif origin.is_file():
            shutil.copy2(origin, copy)
    venv = where / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    python = venv / "bin" / "python"
    # --no-compile: no byte-code for the thousands of modules of SciPy and Matplotlib the
    # tests never import (half the install's CPU time); Python compiles what they import.
    done = subprocess.run(
        [
            python,
            "-m",
            "pip",
            "install",
            "--quiet",
            "--disable-pip-version-check",
            "--no-compile",
            str(source),
        ],
        capture_output=True,
        text=True,
        timeout=1200,
    )
    if done.returncode != 0:
        output = done.stdout[-3000:] + done.stderr[-3000:]
        pytest.fail(f"pip install . failed in a fresh venv:\n{output}")

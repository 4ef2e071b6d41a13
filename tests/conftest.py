"""Shared test fixtures."""

import asyncio
import subprocess
import sys
from collections.abc import Callable, Iterator

import pytest

from arm_driver.bus import open_buses

Runner = Callable[..., subprocess.CompletedProcess]


def _command_line(module: str) -> Runner:
    """Run ``module.main()`` (a console script's entry point) in a subprocess, as a user
    would run the command."""

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-c", f"from {module} import main; main()", *args],
            capture_output=True,
            text=True,
            timeout=600,
        )

    return run


@pytest.fixture
def run_cli() -> Runner:
    """The ``companion`` command line."""
    return _command_line("companion.cli")


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

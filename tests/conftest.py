"""Shared test fixtures."""

import subprocess
import sys
from collections.abc import Callable

import pytest

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

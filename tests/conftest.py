"""Shared test fixtures."""

import subprocess
import sys
from collections.abc import Callable

import pytest


@pytest.fixture
def run_cli() -> Callable[..., subprocess.CompletedProcess]:
    """Run the ``companion`` command line in a subprocess, as a user would."""

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-c", "from companion.cli import main; main()", *args],
            capture_output=True,
            text=True,
            timeout=600,
        )

    return run

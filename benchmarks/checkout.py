"""Measuring an earlier checkout beside this one: the benchmarks' ``--before DIR``.

The script runs itself again with ``--json`` and the earlier checkout first on
``PYTHONPATH`` (so its packages, not this one's, are imported), and the two are measured
alternately, before, now, before, now, keeping the best of each (the machine's noise only
ever adds time).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

_ROOT = Path(__file__).resolve().parent.parent

Figures = dict
"""A benchmark's figures as its ``--json`` prints them."""


def measure_checkout(before: Path, script: str, args: Sequence[str]) -> Figures:
    """``script`` (the benchmark's ``__file__``) run with ``args`` and ``--json`` against the
    code of the checkout ``before``."""
    done = subprocess.run(
        [sys.executable, script, *args, "--json"],
        env={**os.environ, "PYTHONPATH": str(before)},
        check=True,
        capture_output=True,
        text=True,
        cwd=before,
    )
    return json.loads(done.stdout)


def now_and_before(
    measure: Callable[[], Figures],
    before: Path | None,
    script: str,
    args: Sequence[str],
    best: Callable[[Figures, Figures], Figures],
) -> tuple[Figures, Figures | None]:
    """This checkout's figures and, with ``before``, the earlier checkout's, each the
    ``best`` of two runs taken alternately (module docstring)."""
    now = measure()
    if before is None:
        return now, None
    then = measure_checkout(before, script, args)
    now = best(now, measure())
    then = best(then, measure_checkout(before, script, args))
    return now, then


def written_by(command: str) -> str:
    """The first sentence of a page a benchmark writes into ``docs/``: the command, the
    machine, Python and the commit."""
    return (
        f"Written by `benchmarks/{command}` on {platform.node()} ({platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}), commit {this_commit()}."
    )


def this_commit() -> str:
    """The short hash of this checkout's HEAD, for the tables a benchmark writes into
    ``docs/`` ("unknown" outside a git checkout)."""
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=_ROOT,
            check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "unknown"

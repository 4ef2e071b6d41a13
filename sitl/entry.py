"""The ``sitl`` console script: the simulator's command line, or one line saying how to
install it where only the flight install is (``pip install .`` on a companion computer
ships the ``sitl`` package but none of its dependencies)."""

from __future__ import annotations

import importlib.util
import sys

from companion.cli.usage import EXIT_USAGE

__all__ = ["SIMULATOR_PACKAGES", "main"]

SIMULATOR_PACKAGES = ("pinocchio", "jsbsim", "matplotlib")
"""Import names the simulator needs beyond the flight install (the ``sim`` extra)."""


def main() -> None:
    """Run ``sitl.cli.main``, or exit with status 2 if the ``sim`` extra is missing."""
    missing = [name for name in SIMULATOR_PACKAGES if importlib.util.find_spec(name) is None]
    if missing:
        print(
            f"error: the simulator needs {', '.join(missing)}, which this install does not "
            "have: install it with the sim extra, pip install 'aerial-manipulator-companion[sim]' "
            "(from a checkout: pip install -e '.[sim]')",
            file=sys.stderr,
        )
        sys.exit(EXIT_USAGE)
    from sitl.cli import main as cli_main

    cli_main()

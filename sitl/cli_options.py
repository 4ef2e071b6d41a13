"""Options that several ``sitl`` commands take, declared once (``Annotated`` aliases).

A command's own options stay with the command; one that two commands share lives here, so
that its name, type and help are the same wherever it appears.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from companion.cli.usage import fail

__all__ = ["AutopilotOpt", "ConfigOpt", "Px4DirOpt", "SeedOpt", "check_seed"]

ConfigOpt = Annotated[Path, typer.Option("--config", help="Scenario TOML file.")]
"""``--config``: the scenario of ``sitl run``, ``sitl sih`` and ``sitl authority``."""

Px4DirOpt = Annotated[
    Path | None,
    typer.Option(
        envvar="PX4_SITL_DIR",
        show_envvar=False,
        help="The PX4 SITL build to fly (a directory with bin/px4 and etc/; default "
        "$PX4_SITL_DIR).",
    ),
]
"""``--px4-dir``, the same in every command that starts the real PX4."""

SeedOpt = Annotated[int, typer.Option(help="Seed of the sensor-noise generator, 0 or more.")]
"""``--seed``: the simulated sensors' noise (a numpy seed)."""

AutopilotOpt = Annotated[
    str,
    typer.Option(
        help="imitation (our PX4-like autopilot) or px4 (the real PX4 SITL build flies "
        "our physics through simulator_mavlink, in lockstep)."
    ),
]
"""``--autopilot``: who flies the simulated vehicle."""


def check_seed(seed: int) -> None:
    """``--seed`` is a numpy seed; else one ``error:`` line, exit status 2."""
    if seed < 0:
        fail(f"--seed must be a whole number 0 or more (a numpy seed), got {seed}")

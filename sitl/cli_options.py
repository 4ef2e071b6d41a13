"""Options that several ``sitl`` commands take, declared once (``Annotated`` aliases).

A command's own options stay with the command; one that two commands share lives here, so
that its name, type and help are the same wherever it appears.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

__all__ = ["ConfigOpt", "Px4DirOpt"]

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

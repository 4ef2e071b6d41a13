"""The ``sitl`` command line: tools around the simulated vehicle.

``sitl authority`` reports the torque the simulated vehicle can produce at hover. The
MAVLink vehicle process (``sitl run``) is not part of this package yet.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from companion.cli import load_or_exit
from sitl.authority import hover_authority

app = typer.Typer(
    name="sitl",
    help="Simulated PX4-like vehicle with a 2-DOF arm (truth plant tools).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


@app.callback()
def _root() -> None:
    """Simulated PX4-like vehicle with a 2-DOF arm (truth plant tools)."""


@app.command()
def authority(
    config: Annotated[Path, typer.Option("--config", help="Scenario TOML file.")],
) -> None:
    """Hover thrust and the largest body torques the mixer can make at hover."""
    cfg = load_or_exit(config)
    table = Table(title=escape(f"{cfg.name}: control authority at hover (body FLU)"))
    for column in ("", "empty arm", "with payload"):
        table.add_column(column, justify="right")
    empty, loaded = hover_authority(cfg, False), hover_authority(cfg, True)
    rows = [
        ("mass [kg]", lambda a: f"{a.mass_kg:.3f}"),
        ("hover thrust [N]", lambda a: f"{a.hover_thrust_n:.2f}"),
        ("hover motor command [0-1]", lambda a: f"{a.hover_command:.3f}"),
    ]
    for i, axis in enumerate(("roll", "pitch", "yaw")):
        rows.append(
            (
                f"{axis} torque, unsaturated / max [N m]",
                lambda a, i=i: f"{a.unsaturated_torque_n_m[i]:.2f} / {a.max_torque_n_m[i]:.2f}",
            )
        )
    for label, fmt in rows:
        table.add_row(escape(label), fmt(empty), fmt(loaded))
    Console().print(table)


def main() -> None:
    """Console-script entry point."""
    app()

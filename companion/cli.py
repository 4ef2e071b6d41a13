"""The ``companion`` command line.

User mistakes (a bad config, a missing file) print one line naming the file, the key and
the reason and exit with status 2; they never print a traceback.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from companion.config import ConfigError, Scenario, load_scenario

EXIT_USAGE = 2
"""Exit status for a user mistake (same as a command-line usage error)."""

app = typer.Typer(
    name="companion",
    help="Aerial-manipulator companion: payload estimation and control for a PX4 hexacopter.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


@app.callback()
def _root() -> None:
    """Aerial-manipulator companion: payload estimation and control for a PX4 hexacopter."""


def load_or_exit(path: Path) -> Scenario:
    """Load a scenario, turning a ConfigError into a one-line message and exit status 2."""
    try:
        return load_scenario(path)
    except ConfigError as exc:
        for line in str(exc).splitlines():
            typer.echo(f"error: {line}", err=True)
        raise typer.Exit(EXIT_USAGE) from None


@app.command()
def check(
    config: Annotated[Path, typer.Argument(help="Scenario TOML file to validate.")],
) -> None:
    """Validate a scenario file and print the values the model will use."""
    cfg = load_or_exit(config)
    table = Table(title=escape(f"{cfg.name}: {cfg.description}"), show_header=True)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    total = cfg.vehicle.mass_kg + cfg.arm.link1.mass_kg + cfg.true_theta.m2_kg
    table.add_row(escape("total mass with payload [kg]"), f"{total:.4g}")
    for label, theta in (("empty link 2", cfg.nominal_theta), ("with payload", cfg.true_theta)):
        table.add_row(
            escape(f"{label}: m2 [kg], m3 [kg m], m4 [kg m^2], lc [m]"),
            f"{theta.m2_kg:.4g}, {theta.m3_kg_m:.4g}, {theta.m4_kg_m2:.4g}, {theta.lc_m:.4g}",
        )
    out = Console()
    out.print(table)
    out.print(f"{config}: OK", markup=False, highlight=False)


def main() -> None:
    """Console-script entry point."""
    app()

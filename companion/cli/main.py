"""The ``companion`` command line: what runs on the onboard computer.

``check`` (a configuration; with ``--timing``, whether this computer keeps up with the
control cycle), ``mission pickup``, ``arm`` (servo bus bring-up), ``plot``
(figures of a flight log) and ``log info`` (what an MCAP flight log holds). The simulator's
commands (``sim``, ``compare``, ``demo``) are ``sitl``'s. User mistakes print one line
naming the file, the key and the reason and exit with status 2 (:mod:`companion.cli.usage`);
they never print a traceback. A usage error (an unknown option, a missing argument) is one
line too, and ``companion --version`` prints the installed version
(:mod:`companion.cli.entry`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from companion.cli.arm import app as arm_app
from companion.cli.entry import VersionOption, run
from companion.cli.mission import mission_app
from companion.cli.plot import plot as plot_command
from companion.cli.usage import check_range, config_or_exit, fail
from companion.config import CompanionConfig

app = typer.Typer(
    name="companion",
    help="Aerial-manipulator companion: payload estimation and control for a PX4 hexacopter.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    # Help texts are plain text: units such as [m] and section names such as [arm_bus] are
    # not Rich markup (typer hands this mode down to every subcommand).
    rich_markup_mode=None,
)


@app.callback()
def _root(version: VersionOption = False) -> None:
    """Aerial-manipulator companion: payload estimation and control for a PX4 hexacopter."""


@app.command()
def check(
    config: Annotated[Path, typer.Argument(help="Configuration TOML file to validate.")],
    timing: Annotated[
        bool,
        typer.Option(
            "--timing",
            help="Also time the control cycle on this computer: replay a recorded flight's "
            "inputs (750 cycles) through the pose's decoding, the filters, the control step, "
            "the setpoint's encoding and the log row at --control-rate; exit 1 when the "
            "cycle's p99 takes more than half the control period.",
        ),
    ] = False,
    control_rate: Annotated[
        float,
        typer.Option(
            help="Control loop rate for --timing [Hz]: PX4 sends ODOMETRY, which clocks "
            "the loop, at its estimator's 125 Hz."
        ),
    ] = 125.0,
) -> None:
    """Validate the companion's part of a configuration file and print what it believes
    (the simulator's sections are checked by ``sitl check``); with ``--timing``, whether
    this computer keeps up with the control cycle."""
    cfg = config_or_exit(config)
    if timing:
        check_range(control_rate, "--control-rate", 1.0, 1e9, "Hz", "a positive rate")
    table = Table(title=escape(f"{cfg.name}: {cfg.description}"), show_header=True)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    empty = cfg.vehicle.mass_kg + cfg.arm.link1.mass_kg + cfg.nominal_theta.m2_kg
    table.add_row(escape("mass with the empty arm [kg]"), f"{empty:.4g}")
    theta = cfg.nominal_theta
    table.add_row(
        escape("empty link 2: m2 [kg], m3 [kg m], m4 [kg m^2], lc [m]"),
        f"{theta.m2_kg:.4g}, {theta.m3_kg_m:.4g}, {theta.m4_kg_m2:.4g}, {theta.lc_m:.4g}",
    )
    out = Console()
    out.print(table)
    out.print(f"{config}: OK", markup=False, highlight=False)
    if timing:
        raise typer.Exit(_check_timing(cfg, control_rate, out))


def _check_timing(cfg: CompanionConfig, rate_hz: float, out: Console) -> int:
    """``check --timing``: the table and the verdict; the exit status (0: keeps up)."""
    from companion.mission.timing_check import HEADROOM_LIMIT, PARTS, check_timing

    result = check_timing(cfg, rate_hz)
    table = Table(
        title=escape(f"control cycle at {rate_hz:g} Hz ({result.scheduling})"), show_header=True
    )
    table.add_column("part")
    for heading in ("p50 [us]", "p99 [us]", "p99 [% of period]"):
        table.add_column(escape(heading), justify="right")
    for part in PARTS:
        p50, p99 = result.percentile_us(part, 50), result.percentile_us(part, 99)
        share = 100.0 * p99 / result.period_us
        table.add_row(part, f"{p50:.0f}", f"{p99:.0f}", f"{share:.1f}")
    out.print(table)
    if result.scheduling_note is not None:
        typer.echo(f"note: {result.scheduling_note}")
    headroom = max(0.0, 100.0 * result.headroom)
    typer.echo(
        f"headroom at the cycle's p99: {headroom:.0f} % of the {result.period_us:g} us control "
        f"period (at least {100.0 * (1.0 - HEADROOM_LIMIT):.0f} % needed)"
    )
    if result.keeps_up:
        typer.echo(result.verdict())
        return 0
    typer.echo(result.verdict(), err=True)
    return 1


log_app = typer.Typer(
    name="log", help="Flight logs.", no_args_is_help=True, pretty_exceptions_enable=False
)


@log_app.command("info")
def log_info(
    flight: Annotated[Path, typer.Argument(help="A flight's MCAP log (flight.mcap).")],
) -> None:
    """Print the channels of an MCAP flight log: topic, schema, encodings, message count,
    and the time range (vehicle time)."""
    from companion.logs.flightlog import FlightLogError
    from companion.logs.mcap_log import describe_mcap

    try:
        info = describe_mcap(flight)
    except FlightLogError as exc:
        fail(str(exc))
    for line in info.lines():
        typer.echo(line)


@log_app.command("export")
def log_export(
    columns: Annotated[Path, typer.Argument(help="The columns a flight left (flight.columns).")],
) -> None:
    """Write flight.csv and flight.timing.csv from the flight.columns a flight left when it
    did not close its log (a crash, kill -9, a power cut): every row up to the last block
    written. A flight that closed its log wrote them itself and removed flight.columns."""
    from companion.logs.flightlog import FlightLogError, export_columns

    try:
        rows = export_columns(columns)
    except FlightLogError as exc:
        fail(str(exc))
    typer.echo(f"{columns.with_suffix('.csv')}: {rows} rows from {columns}")


@log_app.command("add-ulog")
def log_add_ulog(
    flight: Annotated[Path, typer.Argument(help="A flight's MCAP log (flight.mcap).")],
    ulog: Annotated[Path, typer.Argument(help="PX4's ULog of the same flight (.ulg).")],
) -> None:
    """Merge PX4's attitude setpoint, attitude, local position, motor commands, status and
    battery from its ULog into the flight's MCAP log, on the same time axis (time since
    PX4 booted): one view shows PX4 and the companion together."""
    from companion.logs.ulog_mcap import UlogError, add_ulog

    try:
        added = add_ulog(flight, ulog)
    except (UlogError, ValueError, OSError) as exc:
        fail(str(exc))
    typer.echo(f"{flight}: {added} PX4 messages added from {ulog}")


app.add_typer(arm_app, name="arm")
app.command(name="plot")(plot_command)
app.add_typer(mission_app, name="mission")
app.add_typer(log_app, name="log")


def main() -> None:
    """Console-script entry point: ``--version``, usage errors in one line
    (:mod:`companion.cli.entry`)."""
    run(app, "companion")

"""The ``sitl`` command line: the simulated vehicle and tools around it.

``sitl run`` runs the PX4-like vehicle process (MAVLink on UDP, servos on a pty);
``sitl authority`` reports the torque the simulated vehicle can produce at hover.
"""

from __future__ import annotations

import contextlib
import json
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from companion.cli.entry import VersionOption
from companion.cli.entry import run as run_app
from companion.cli.options import options_command
from companion.cli.usage import fail as _fail
from companion.cli.usage import load_or_exit as _load_or_exit
from sitl.campaign.cli import campaign
from sitl.cli_options import ConfigOpt, Px4DirOpt
from sitl.cli_sim import sim_app
from sitl.hil import HilStats, Px4Exited, Px4InTheLoop
from sitl.hil.link import SimulatorLinkError
from sitl.offline.authority import Authority, hover_authority
from sitl.physics import PlantError
from sitl.px4_sitl.launcher import Px4NotReadyError
from sitl.run_command import RunCommand
from sitl.scenario import Scenario, load_scenario
from sitl.vehicle.options import RunStats
from sitl.vehicle.runner import SitlVehicle

app = typer.Typer(
    name="sitl",
    help="Simulated PX4-like vehicle with a 2-DOF arm (truth plant tools).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode=None,  # plain help: [m/s], [arm_bus] are units and sections, not markup
)


@app.callback()
def _root(version: VersionOption = False) -> None:
    """Simulated PX4-like vehicle with a 2-DOF arm (truth plant tools)."""


@app.command()
def authority(
    config: ConfigOpt,
) -> None:
    """Hover thrust and the largest body torques the mixer can make at hover."""
    cfg = load_or_exit(config)
    table = Table(title=escape(f"{cfg.name}: control authority at hover (body FLU)"))
    for column in ("", "empty arm", "with payload"):
        table.add_column(column, justify="right")
    empty, loaded = hover_authority(cfg, False), hover_authority(cfg, True)
    rows: list[tuple[str, Callable[[Authority], str]]] = [
        ("mass [kg]", lambda a: f"{a.mass_kg:.3f}"),
        ("hover thrust [N]", lambda a: f"{a.hover_thrust_n:.2f}"),
        (
            "hover relative thrust (SET_ATTITUDE_TARGET) [0-1]",
            lambda a: f"{a.hover_relative_thrust:.3f}",
        ),
        ("hover motor command [0-1]", lambda a: f"{a.hover_command:.3f}"),
    ]
    for i, axis in enumerate(("roll", "pitch", "yaw")):
        rows.append((f"{axis} torque, unsaturated / max [N m]", _torque_cell(i)))
    rows.append(
        (
            "torque per normalized torque 1, roll / pitch / yaw [N m]",
            lambda a: " / ".join(f"{t:.3f}" for t in a.torque_per_normalized_n_m),
        )
    )
    for label, fmt in rows:
        table.add_row(escape(label), fmt(empty), fmt(loaded))
    Console().print(table)


def _torque_cell(axis: int) -> Callable[[Authority], str]:
    def cell(a: Authority) -> str:
        return f"{a.unsaturated_torque_n_m[axis]:.2f} / {a.max_torque_n_m[axis]:.2f}"

    return cell


@contextlib.contextmanager
def _signals_handled(handler: Callable[..., object]) -> Iterator[None]:
    """SIGINT and SIGTERM go to ``handler`` inside the block; the handlers before it after
    it (the commands also run in-process, from tests and other commands)."""
    signums = (signal.SIGINT, signal.SIGTERM)
    previous = [signal.signal(signum, handler) for signum in signums]
    try:
        yield
    finally:
        for signum, before in zip(signums, previous, strict=True):
            signal.signal(signum, before)


def _print_ready(title: str, where: dict[str, str]) -> None:
    """The title line, where to connect, and the machine-readable ``ready`` line."""
    typer.echo(title)
    for key, value in where.items():
        typer.echo(f"  {key:<8} {value}")
    typer.echo("ready " + json.dumps(where), color=False)


@app.command()
@options_command(RunCommand)
def run(options: RunCommand) -> None:
    """Run the simulated vehicle until interrupted (Ctrl-C) or --duration."""
    cfg, vehicle = options.vehicle()

    def announce(where: dict[str, str]) -> None:
        _print_ready(
            f"sitl: {cfg.name} on {options.physics} physics flown by {options.flown_by}, "
            f"{options.navigation} navigation, at {options.speed:g}x real time",
            where,
        )

    stop = threading.Event()
    with _signals_handled(lambda *_: stop.set()):
        stats: RunStats
        try:
            with vehicle:
                if isinstance(vehicle, Px4InTheLoop):
                    stats = vehicle.run(
                        stop, until_s=options.duration, console=typer.echo, on_ready=announce
                    )
                else:
                    announce(vehicle.describe())
                    stats = vehicle.run(stop, until_s=options.duration, console=typer.echo)
        except OSError as exc:
            _fail(f"cannot open the vehicle's links: {exc}")
        except PlantError as exc:
            typer.echo(f"error: the simulated vehicle's physics failed: {exc}", err=True)
            raise typer.Exit(1) from None
        except (Px4NotReadyError, Px4Exited, SimulatorLinkError) as exc:
            typer.echo(f"error: {exc}", err=True)
            _kept(vehicle)
            raise typer.Exit(1) from None
        _kept(vehicle)
        typer.echo(_stopped(stats, options.lockstep))


def _stopped(stats: RunStats, lockstep: bool) -> str:
    """The run's closing line: where it stopped, its pace, and the lockstep's waits."""
    median, p99 = stats.jitter_us()
    return (
        f"sitl: stopped at t = {stats.sim_time_s:.3f} s; real-time factor "
        f"{stats.real_time_factor:.2f}; step jitter median {median:.0f} us, p99 {p99:.0f} us; "
        f"{stats.overruns} overruns"
        + (
            f"; lockstep: waited for {stats.lockstep_waits} setpoints, "
            f"{stats.lockstep_timeouts} timed out"
            if lockstep
            else ""
        )
        + (
            f"; companion lockstep: PX4 held for the companion in {stats.companion_holds} "
            f"frames ({stats.companion_wait_s:.1f} s), released {stats.companion_releases} "
            "times"
            if isinstance(stats, HilStats)
            else ""
        )
    )


def _kept(vehicle: SitlVehicle | Px4InTheLoop) -> None:
    if isinstance(vehicle, Px4InTheLoop) and vehicle.kept_dir is not None:
        kept = vehicle.kept_dir
        typer.echo(f"sitl: PX4's working directory kept in {kept}")


def load_or_exit(path: Path) -> Scenario:
    """The whole scenario in ``path`` (truth included); each problem one ``error:`` line,
    exit status 2."""
    return _load_or_exit(path, load_scenario)


app.add_typer(sim_app)
app.command()(campaign)


def main() -> None:
    """Console-script entry point: ``--version``, usage errors in one line
    (:mod:`companion.cli.entry`)."""
    run_app(app, "sitl")  # not `run`: that name is the `sitl run` command


@app.command()
def sih(
    config: ConfigOpt,
    px4_dir: Px4DirOpt = None,
    navigation: Annotated[
        str, typer.Option(help="gps (SIH's GPS) or mocap (motion capture, no GPS).")
    ] = "gps",
    speed_factor: Annotated[
        float, typer.Option(help="PX4_SIM_SPEED_FACTOR: simulated seconds per wall-clock second.")
    ] = 1.0,
    keep_log: Annotated[
        Path | None,
        typer.Option(help="Keep PX4's working directory (logs, ULog) in this directory."),
    ] = None,
) -> None:
    """Fly the real PX4 with its SIH vehicle, the arm's servos on a pty, until interrupted."""
    from sitl.px4_sitl.launcher import Px4Build, Px4BuildError, Px4NotReadyError, free_instance
    from sitl.px4_sitl.sih import SihMismatchError
    from sitl.px4_sitl.sih_host import SihHost

    cfg = load_or_exit(config)
    if px4_dir is None:
        _fail("no PX4 SITL build: pass --px4-dir DIR or set PX4_SITL_DIR")
    try:
        build = Px4Build.at(px4_dir)
        host = SihHost(cfg, build, navigation=navigation, speed=speed_factor, keep_dir=keep_log)
        ports = free_instance()
    except (Px4BuildError, SihMismatchError, ValueError) as exc:
        _fail(str(exc))
    except Px4NotReadyError as exc:  # every instance's ports taken
        _fail(f"{exc} (another PX4 or sitl is running?)")
    stop = threading.Event()
    try:  # until ready, an interrupt stops the start-up too
        with _signals_handled(signal.default_int_handler):
            host.start(ports)
    except KeyboardInterrupt:
        typer.echo("sitl: interrupted before PX4 was ready", err=True)
        raise typer.Exit(1) from None
    except OSError as exc:
        _fail(f"cannot open PX4's ports (instance {ports.instance}): {exc}")
    except Px4NotReadyError as exc:
        typer.echo(f"error: PX4 did not get ready: {exc}", err=True)
        raise typer.Exit(1) from None
    with _signals_handled(lambda *_: stop.set()):
        try:
            _print_ready(
                f"sitl: {cfg.name} on PX4 SIH (instance {ports.instance}, {navigation} "
                f"navigation) at {speed_factor:g}x real time",
                host.describe(),
            )
            failure = host.run(stop)
        finally:
            kept = host.stop(keep=keep_log is not None)
    stand = host.stand
    typer.echo(
        f"sitl: stopped; arm stand ran {stand.time_s:.1f} s in {stand.steps} steps, "
        f"{stand.overruns} overruns"
    )
    if kept is not None:
        typer.echo(f"sitl: PX4's working directory kept in {kept}")
    if failure is not None:
        typer.echo(f"error: {failure}", err=True)
        raise typer.Exit(1)

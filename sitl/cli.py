"""The ``sitl`` command line: the simulated vehicle and tools around it.

``sitl run`` runs the PX4-like vehicle process (MAVLink on UDP, servos on a pty);
``sitl authority`` reports the torque the simulated vehicle can produce at hover.
"""

from __future__ import annotations

import json
import math
import signal
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from companion.cli.entry import VersionOption
from companion.cli.entry import run as run_app
from companion.cli.usage import fail as _fail
from companion.cli.usage import load_or_exit as _load_or_exit
from sitl.campaign.cli import campaign
from sitl.cli_sim import Px4DirOpt, sim_app
from sitl.hil import HilOptions, HilStats, Px4Exited, Px4InTheLoop
from sitl.hil.link import SimulatorLinkError
from sitl.hil.sensors import GPS_GRADES
from sitl.offline.authority import Authority, hover_authority
from sitl.physics import PlantError
from sitl.physics.jsbsim import Wind
from sitl.px4 import ParamError, SigningKeyError, load_signing_key
from sitl.px4_sitl.launcher import Px4Build, Px4BuildError, Px4NotReadyError
from sitl.scenario import MAX_DURATION_S, PayloadSlip, Scenario, load_scenario
from sitl.vehicle.runner import LinkPorts, RunOptions, RunStats, SitlVehicle

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
    config: Annotated[Path, typer.Option("--config", help="Scenario TOML file.")],
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


@app.command()
def run(
    config: Annotated[Path, typer.Option("--config", help="Scenario TOML file.")],
    speed: Annotated[
        float, typer.Option(help="Simulated seconds per wall-clock second (e.g. 5 for 5x).")
    ] = 1.0,
    seed: Annotated[int, typer.Option(help="Seed of the sensor noise.")] = 0,
    noise: Annotated[
        bool, typer.Option("--noise/--no-noise", help="The estimator's errors (or exact).")
    ] = True,
    navigation: Annotated[
        str,
        typer.Option(
            help="Estimator aiding: mocap (motion capture; set the global origin to hold) "
            "or gps (GPS and baro)."
        ),
    ] = "mocap",
    duration: Annotated[
        float | None, typer.Option(help="Stop after this many simulated seconds.")
    ] = None,
    truth_log: Annotated[
        Path | None, typer.Option(help="Write ground truth here (JSON lines).")
    ] = None,
    onboard_port: Annotated[
        int, typer.Option(help="Remote UDP port of the onboard (API) link.")
    ] = 14540,
    onboard_local_port: Annotated[int, typer.Option(help="Local UDP port of that link.")] = 14580,
    gcs_port: Annotated[int, typer.Option(help="Remote UDP port of the GCS link.")] = 14550,
    gcs_local_port: Annotated[int, typer.Option(help="Local UDP port of that link.")] = 18570,
    signing_key: Annotated[
        Path | None,
        typer.Option(help="MAVLink 2 signing key file (32 bytes); unsigned input is rejected."),
    ] = None,
    physics: Annotated[
        str, typer.Option(help="Truth physics: pinocchio (our plant) or jsbsim.")
    ] = "pinocchio",
    wind: Annotated[
        str | None,
        typer.Option(
            help="Steady wind 'E,N,U' [m/s], world ENU, in place of the scenario's plant.wind_m_s."
        ),
    ] = None,
    turbulence: Annotated[
        float,
        typer.Option(help="Dryden turbulence, MIL-F-8785C wind speed at 20 ft [m/s] (jsbsim)."),
    ] = 0.0,
    servo_silent: Annotated[
        str | None,
        typer.Option(help="Fault injection 'ID@T': servo ID stops answering at T [s, sim time]."),
    ] = None,
    servo_reply_delay_ms: Annotated[
        float,
        typer.Option(
            help="Extra delay before every servo reply [ms], as a USB-serial adapter's latency "
            "timer adds (an FTDI chip's default is 16 ms)."
        ),
    ] = 0.0,
    grasp_fails: Annotated[
        bool,
        typer.Option(
            "--grasp-fails", help="Fault injection: the gripper closes on nothing (no grasp)."
        ),
    ] = False,
    payload_slip: Annotated[
        float | None,
        typer.Option(
            help="Fault injection: the grasped object slips out this many seconds after "
            "the grasp [s, sim time]."
        ),
    ] = None,
    autopilot: Annotated[
        str,
        typer.Option(
            help="imitation (our PX4-like autopilot) or px4 (the real PX4 SITL build flies "
            "our physics through simulator_mavlink, in lockstep)."
        ),
    ] = "imitation",
    px4_dir: Px4DirOpt = None,
    keep_log: Annotated[
        Path | None,
        typer.Option(help="--autopilot px4: keep PX4's working directory (log, ULog) here."),
    ] = None,
    gps: Annotated[
        str,
        typer.Option(help="--autopilot px4 --navigation gps: the receiver, standard or rtk."),
    ] = "standard",
    lockstep: Annotated[
        bool,
        typer.Option(
            "--lockstep",
            help="While the client streams setpoints (SET_ATTITUDE_TARGET or "
            "SET_POSITION_TARGET_LOCAL_NED), step past a pose only once its setpoint is in, as "
            "fast as the two go (the imitation; PX4 keeps its own).",
        ),
    ] = False,
    companion_lockstep: Annotated[
        bool,
        typer.Option(
            "--companion-lockstep/--no-companion-lockstep",
            help="--autopilot px4: relay the onboard link and hold PX4's clock after each "
            "frame until the companion has answered the last pose (a SET_ATTITUDE_TARGET or "
            "SET_POSITION_TARGET_LOCAL_NED stamped with its time) and read the joints: its "
            "computing takes no vehicle time, on an idle or a busy machine.",
        ),
    ] = True,
    nice: Annotated[
        int,
        typer.Option(
            help="--autopilot px4: lower the simulator's CPU priority (not PX4's) by this "
            "much (0-19), so that a companion on the same machine keeps its real-time "
            "period; the lockstep pair only slows down."
        ),
    ] = 5,
) -> None:
    """Run the simulated vehicle until interrupted (Ctrl-C) or --duration."""
    cfg = load_or_exit(config)
    if autopilot not in ("imitation", "px4"):
        _fail(f"--autopilot must be imitation or px4, got {autopilot!r}")
    if autopilot == "px4" and px4_dir is None:
        _fail("--autopilot px4 needs a PX4 SITL build: pass --px4-dir DIR or set PX4_SITL_DIR")
    if autopilot == "px4" and lockstep:
        _fail("--lockstep is the imitation's: PX4 in the loop runs in its own lockstep")
    if autopilot == "px4" and signing_key is not None:
        _fail("--signing-key is the imitation's: configure PX4's own signing (MAV_SIGN_CFG)")
    if gps not in GPS_GRADES:
        _fail(f"--gps must be one of {', '.join(GPS_GRADES)}, got {gps!r}")
    build = None
    if px4_dir is not None and autopilot == "px4":
        try:
            build = Px4Build.at(px4_dir)
        except Px4BuildError as exc:
            _fail(str(exc))
    if duration is not None and not duration > 0.0:
        _fail(f"--duration must be positive, got {duration:g}")
    if seed < 0:
        _fail(f"--seed must be a whole number 0 or more (a numpy seed), got {seed}")
    if truth_log is not None:
        if truth_log.exists():
            _fail(
                f"--truth-log {truth_log}: exists; an earlier run's truth is never "
                "overwritten: name a new file"
            )
        if not truth_log.parent.is_dir():
            _fail(f"--truth-log {truth_log}: no directory {truth_log.parent}")
    ports = (
        ("--onboard-port", onboard_port),
        ("--onboard-local-port", onboard_local_port),
        ("--gcs-port", gcs_port),
        ("--gcs-local-port", gcs_local_port),
    )
    for option, port in ports:
        if not 0 <= port <= 65535:
            _fail(f"{option} must be a UDP port number 0-65535, got {port}")
    if signing_key is not None:
        try:
            load_signing_key(signing_key)
        except OSError as exc:
            _fail(f"--signing-key {signing_key}: cannot read: {exc.strerror or exc}")
        except SigningKeyError as exc:
            _fail(f"--signing-key {exc}")
    silent = _servo_fault(servo_silent) if servo_silent is not None else None
    if not (math.isfinite(servo_reply_delay_ms) and 0.0 <= servo_reply_delay_ms < 1000.0):
        _fail(f"--servo-reply-delay-ms must be 0 to 999 ms, got {servo_reply_delay_ms:g}")
    cfg = _pickup_faults(cfg, config, grasp_fails, payload_slip)
    if physics not in ("pinocchio", "jsbsim"):
        _fail(f"--physics must be pinocchio or jsbsim, got {physics!r}")
    if navigation not in ("mocap", "gps"):
        _fail(f"--navigation must be mocap or gps, got {navigation!r}")
    try:
        air = Wind.from_text(wind, turbulence, seed, cfg.plant.wind_m_s)
    except ValueError as exc:
        _fail(str(exc))
    if turbulence != 0.0 and physics != "jsbsim":
        _fail("--turbulence needs --physics jsbsim")
    vehicle: SitlVehicle | Px4InTheLoop
    try:
        options = RunOptions(
            speed=speed,
            seed=seed,
            noise=noise,
            navigation=navigation,
            ports=LinkPorts(
                onboard_local=onboard_local_port,
                onboard_remote=onboard_port,
                gcs_local=gcs_local_port,
                gcs_remote=gcs_port,
            ),
            signing_key=signing_key,
            truth_log=truth_log,
            servo_silent=silent,
            servo_reply_delay_s=servo_reply_delay_ms * 1e-3,
            physics=physics,
            wind=air,
            lockstep=lockstep,
        )
        if build is not None:
            vehicle = Px4InTheLoop(
                cfg,
                options,
                HilOptions(
                    build,
                    keep_dir=keep_log,
                    gps=gps,
                    companion_lockstep=companion_lockstep,
                    nice=nice,
                ),
            )
        else:
            vehicle = SitlVehicle(cfg, options)
    except (ValueError, ParamError, SigningKeyError) as exc:
        _fail(f"{config}: {exc}")
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    flown_by = "the PX4 imitation" if autopilot == "imitation" else "PX4"

    def announce(where: dict[str, str]) -> None:
        typer.echo(
            f"sitl: {cfg.name} on {physics} physics flown by {flown_by}, {navigation} "
            f"navigation, at {speed:g}x real time"
        )
        for key, value in where.items():
            typer.echo(f"  {key:<8} {value}")
        typer.echo("ready " + json.dumps(where), color=False)

    stats: RunStats
    try:
        with vehicle:
            if isinstance(vehicle, Px4InTheLoop):
                stats = vehicle.run(stop, until_s=duration, console=typer.echo, on_ready=announce)
            else:
                announce(vehicle.describe())
                stats = vehicle.run(stop, until_s=duration, console=typer.echo)
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
    median, p99 = stats.jitter_us()
    typer.echo(
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


def _pickup_faults(
    cfg: Scenario, config: Path, grasp_fails: bool, slip_after_s: float | None
) -> Scenario:
    """The scenario with the pickup faults of the options (``--grasp-fails``,
    ``--payload-slip``) in its ``[world]``; one ``error:`` line for a bad value."""
    if not grasp_fails and slip_after_s is None:
        return cfg
    if cfg.world is None or cfg.world.payload_position_m is None:
        _fail(f"--grasp-fails and --payload-slip need an object: {config} has no [world] "
              "payload_position_m")  # fmt: skip
    update: dict[str, object] = {}
    if grasp_fails:
        update["grasp_fails"] = True
    if slip_after_s is not None:
        if not (math.isfinite(slip_after_s) and 0.0 <= slip_after_s <= MAX_DURATION_S):
            _fail(
                f"--payload-slip must be 0-{MAX_DURATION_S:g} s after the grasp, "
                f"got {slip_after_s:g}"
            )
        update["payload_slip"] = PayloadSlip(after_grasp_s=slip_after_s)
    return cfg.model_copy(update={"world": cfg.world.model_copy(update=update)})


def _servo_fault(text: str) -> tuple[int, float]:
    servo, _, at = text.partition("@")
    try:
        return int(servo), float(at)
    except ValueError:
        _fail(f"--servo-silent needs ID@SECONDS, e.g. 2@30, got {text!r}")


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
    config: Annotated[Path, typer.Option("--config", help="Scenario TOML file.")],
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
    for signum in (signal.SIGINT, signal.SIGTERM):  # until ready: stop the start-up too
        signal.signal(signum, signal.default_int_handler)
    try:
        host.start(ports)
    except KeyboardInterrupt:
        typer.echo("sitl: interrupted before PX4 was ready", err=True)
        raise typer.Exit(1) from None
    except OSError as exc:
        _fail(f"cannot open PX4's ports (instance {ports.instance}): {exc}")
    except Px4NotReadyError as exc:
        typer.echo(f"error: PX4 did not get ready: {exc}", err=True)
        raise typer.Exit(1) from None
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    try:
        where = host.describe()
        typer.echo(
            f"sitl: {cfg.name} on PX4 SIH (instance {ports.instance}, {navigation} navigation) "
            f"at {speed_factor:g}x real time"
        )
        for key, value in where.items():
            typer.echo(f"  {key:<8} {value}")
        typer.echo("ready " + json.dumps(where), color=False)
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

"""``companion mission pickup`` and ``companion demo``: payload-pickup missions.

``mission pickup`` flies one mission against a vehicle (PX4 or ``sitl run``) and an arm
bus given by URL, and writes into ``--out``: ``flight.csv`` / ``flight.events.csv`` (the
flight log), ``summary.json`` and the figures of ``companion plot``.

``demo`` starts the simulated vehicle (``sitl run``) on free loopback ports with the
built-in scenario (``configs/sitl_pickup.toml``: a 0.25 kg object the companion does not
know), flies the same mission against it, stops it, and reports the estimate beside the
truth it never saw.

Exit status: 0 mission completed; 1 the mission failed or a failsafe aborted it (the log
and summary are still written); 2 a user mistake (config, URL, unreachable vehicle or bus).
"""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path
from typing import Annotated

import typer

from arm_driver.bus import open_bus
from arm_driver.errors import ArmDriverError
from companion.app import BUS_FAILURES, MissionAborted, MissionError, MissionReport, PickupApp
from companion.cli_plot import plot_flight_log
from companion.config import Scenario, arm_bus_configs
from companion.control import ControlRateError
from companion.flight_control import FlightControl, FlightControllerName
from companion.flightlog import FlightLogWriter, read_flight_log
from companion.link import LinkError, MavlinkLink, SigningConfig
from companion.mission import PickupPlan
from sitl.launch import SitlNotReadyError, start_sitl

__all__ = ["demo", "mission_app"]

EXIT_USAGE = 2
DEFAULT_SCENARIO = Path(__file__).resolve().parent.parent / "configs" / "sitl_pickup.toml"
"""The demo's built-in scenario (in the source tree; ``pip install -e .`` keeps it there)."""

mission_app = typer.Typer(
    name="mission",
    help="Payload-pickup missions against PX4 or the SITL.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


class UsageError(Exception):
    """A user mistake: one line, exit status 2."""


def _fail(message: str, status: int = EXIT_USAGE) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(status)


def _xyz(text: str, option: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        _fail(f"{option} needs three numbers X,Y,Z in metres (ENU), got {text!r}")
    return values  # type: ignore[return-value]


async def fly_pickup(
    scenario: Scenario,
    connect: str,
    arm_bus_url: str,
    plan: PickupPlan,
    controller: FlightControllerName,
    out_dir: Path,
    *,
    signing_key: Path | None = None,
    control_rate_hz: float = 250.0,
    vehicle_timeout_s: float = 10.0,
) -> tuple[MissionReport, BaseException | None]:
    """Open the link and the arm bus, fly, write log and summary.

    Returns the report and the mission's failure (MissionError / MissionAborted) or None.
    Raises :class:`UsageError` when the vehicle or the bus cannot be reached.
    """
    if scenario.arm_bus is None:
        raise UsageError(f"{scenario.name}: the scenario has no [arm_bus] section (joints)")
    joints, gripper = arm_bus_configs(scenario.arm_bus)
    q_stow = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, *plan.stow_joints_rad]
    try:
        FlightControl(scenario, controller).check_rate(control_rate_hz, q_stow)
    except ControlRateError as exc:
        raise UsageError(f"{scenario.name}: {exc}") from None
    signing = SigningConfig.from_file(signing_key) if signing_key is not None else None
    log_path = out_dir / "flight.csv"
    try:
        link = MavlinkLink(connect, signing=signing)
    except (LinkError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    try:
        bus = open_bus(arm_bus_url, joints, gripper=gripper, max_consecutive_failures=BUS_FAILURES)
    except (ArmDriverError, ValueError) as exc:
        raise UsageError(f"arm bus {arm_bus_url}: {exc}") from None
    failure: BaseException | None = None
    try:
        async with link:
            try:
                await link.wait_vehicle(vehicle_timeout_s)
            except LinkError as exc:
                raise UsageError(str(exc)) from None
            try:
                await bus.open()
            except ArmDriverError as exc:
                raise UsageError(f"arm bus {arm_bus_url}: {exc}") from None
            try:
                with FlightLogWriter(log_path) as writer:
                    app = PickupApp(
                        scenario,
                        link,
                        bus,
                        plan,
                        controller=controller,
                        control_rate_hz=control_rate_hz,
                        log=writer.write,
                        event=writer.event,
                    )
                    try:
                        report = await app.run()
                    except (MissionError, MissionAborted, ArmDriverError, LinkError) as exc:
                        failure = exc
                        report = app.report
                        writer.event("failure", str(exc), app._t_s)
            finally:
                await bus.close()
    except OSError as exc:
        raise UsageError(f"cannot open {connect}: {exc}") from None
    summary = report.as_dict()
    summary["failure"] = None if failure is None else f"{type(failure).__name__}: {failure}"
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if log_path.stat().st_size > 0:
        try:
            plot_flight_log(read_flight_log(log_path), out_dir)
        except Exception as exc:  # a figure must never hide the mission's result
            typer.echo(f"warning: figures not drawn: {exc}", err=True)
    return report, failure


def _print_report(report: MissionReport, failure: BaseException | None) -> None:
    if report.payload_mass_kg is not None:
        com = "unknown" if report.payload_com_m is None else f"{report.payload_com_m:.3f} m"
        typer.echo(
            f"estimated payload: {report.payload_mass_kg:.3f} kg, centre of mass {com} along "
            f"link 2 ({'confident' if report.confident else 'NOT confident'})"
        )
    if report.position_rms_with_payload_m is not None:
        typer.echo(
            f"position error with the payload: {report.position_rms_with_payload_m:.3f} m RMS"
        )
    for fault in report.faults:
        typer.echo(f"fault at t = {fault['t_s']:.2f} s: {fault['fault']}: {fault['detail']}")
    if failure is not None:
        typer.echo(f"mission failed: {failure}", err=True)
    else:
        typer.echo("mission completed: landed and disarmed")


ControllerOpt = Annotated[
    str, typer.Option(help="passivity (adaptive, the paper's) or nonadaptive (empty-arm values).")
]


@mission_app.command("pickup")
def pickup(
    config: Annotated[Path, typer.Option("--config", help="Scenario TOML with [arm_bus].")],
    payload_at: Annotated[str, typer.Option(help="Object's position X,Y,Z [m, ENU].")],
    place_at: Annotated[str, typer.Option(help="Where to put it, X,Y,Z [m, ENU].")],
    connect: Annotated[
        str,
        typer.Option(
            help="MAVLink URL, e.g. udpin://0.0.0.0:14540 or serial:///dev/ttyAMA0:921600."
        ),
    ] = "udpin://0.0.0.0:14540",
    arm_bus: Annotated[
        str | None, typer.Option(help="Arm bus URL [default: the config's arm_bus.url].")
    ] = None,
    controller: ControllerOpt = "passivity",
    out: Annotated[Path, typer.Option(help="Directory for log, summary and figures.")] = Path(
        "out/mission"
    ),
    signing_key: Annotated[Path | None, typer.Option(help="MAVLink 2 signing key file.")] = None,
    control_rate: Annotated[float, typer.Option(help="Control loop rate [Hz].")] = 250.0,
    cruise_altitude: Annotated[float, typer.Option(help="Transit altitude [m].")] = 1.5,
) -> None:
    """Fly a payload pickup: take off, grasp, learn the payload, carry, place, land."""
    from companion.cli import load_or_exit

    scenario = load_or_exit(config)
    plan = _plan(scenario, _xyz(payload_at, "--payload-at"), _xyz(place_at, "--place-at"),
                 cruise_altitude)  # fmt: skip
    bus_url = arm_bus or (scenario.arm_bus.url if scenario.arm_bus else None)
    if bus_url is None:
        _fail(f"{config}: no --arm-bus and no [arm_bus] url in the config")
    status = _run_mission(scenario, connect, bus_url, plan, controller, out, signing_key,
                          control_rate)  # fmt: skip
    raise typer.Exit(status)


def _plan(scenario: Scenario, payload_at, place_at, cruise_altitude: float) -> PickupPlan:
    if not cruise_altitude > 0.5:
        _fail(f"--cruise-altitude must be above 0.5 m, got {cruise_altitude:g}")
    stow = scenario.world.start_joints_rad if scenario.world else (0.0, -0.5 * math.pi)
    return PickupPlan(
        home_m=(0.0, 0.0),
        payload_at_m=payload_at,
        place_at_m=place_at,
        cruise_altitude_m=cruise_altitude,
        stow_joints_rad=tuple(stow),  # type: ignore[arg-type]
    )


def _run_mission(scenario, connect, bus_url, plan, controller, out, signing_key, rate) -> int:
    if controller not in ("passivity", "nonadaptive"):
        _fail(f"--controller must be passivity or nonadaptive, got {controller!r}")
    out.mkdir(parents=True, exist_ok=True)
    try:
        report, failure = asyncio.run(
            fly_pickup(
                scenario,
                connect,
                bus_url,
                plan,
                controller,
                out,
                signing_key=signing_key,
                control_rate_hz=rate,
            )
        )
    except UsageError as exc:
        _fail(str(exc))
    _print_report(report, failure)
    typer.echo(f"log, summary and figures: {out}/")
    return 0 if failure is None else 1


# --------------------------------------------------------------------------- demo


def demo(
    out: Annotated[Path, typer.Option(help="Directory for log, summary and figures.")] = Path(
        "out/demo"
    ),
    config: Annotated[
        Path, typer.Option(help="Scenario with [world] and [arm_bus].")
    ] = DEFAULT_SCENARIO,
    controller: ControllerOpt = "passivity",
    speed: Annotated[float, typer.Option(help="SITL speed (simulated s per wall s).")] = 1.0,
    seed: Annotated[int, typer.Option(help="Seed of the SITL's sensor noise.")] = 0,
    place_at: Annotated[
        str, typer.Option(help="Where to put the object, X,Y,Z [m, ENU].")
    ] = "-1.0,0.5,0.05",
) -> None:
    """Start the SITL, fly the pickup mission against it, write log, summary and figures."""
    from companion.cli import load_or_exit

    scenario = load_or_exit(config)
    if scenario.world is None or scenario.world.payload_position_m is None:
        _fail(f"{config}: the demo needs a [world] section with payload_position_m")
    out.mkdir(parents=True, exist_ok=True)
    plan = _plan(scenario, scenario.world.payload_position_m, _xyz(place_at, "--place-at"), 1.5)
    try:
        sitl = start_sitl(config, "--seed", str(seed), speed=speed, truth_log=out / "truth.jsonl")
    except SitlNotReadyError as exc:
        _fail(str(exc), 1)
    connect = f"udpin://127.0.0.1:{sitl.onboard_port}"
    typer.echo(f"sitl: running ({sitl.arm_bus}, MAVLink {connect})")
    try:
        status = _run_mission(scenario, connect, sitl.arm_bus, plan, controller, out, None, 250.0)
    finally:
        sitl.stop()
    _print_truth(scenario, out, plan)
    raise typer.Exit(status)


def _print_truth(scenario: Scenario, out: Path, plan: PickupPlan) -> None:
    """The demo knows the truth the companion never saw: compare."""
    summary = json.loads((out / "summary.json").read_text())
    mass, com = summary.get("payload_mass_kg"), summary.get("payload_com_along_link2_m")
    true_mass, true_com = scenario.payload.mass_kg, scenario.payload.position_m
    if mass is not None:
        com_error = f", {100 * (com - true_com) / true_com:+.1f} % centre of mass" if com else ""
        typer.echo(
            f"truth: payload {true_mass:.3f} kg at {true_com:.3f} m; estimate error "
            f"{100 * (mass - true_mass) / true_mass:+.1f} % mass{com_error}"
        )
    truth_log = out / "truth.jsonl"
    if truth_log.exists():
        lines = truth_log.read_text().splitlines()
        if lines:
            last = json.loads(lines[-1])
            obj = last.get("object_position_m")
            if obj is not None:
                err = math.dist(obj[:2], plan.place_at_m[:2])
                typer.echo(f"truth: object ended {err:.3f} m from the place point (horizontal)")

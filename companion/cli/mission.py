"""``companion mission pickup``: the payload-pickup mission.

Flies one mission against a vehicle (PX4, ``sitl run``, ``sitl sih``) and an arm bus given
by URL, and writes into ``--out``: ``flight.csv`` / ``flight.events.csv`` (the flight log),
``flight.timing.csv`` (what the wall clock measured), ``flight.mcap`` (the same flight for
Foxglove and PlotJuggler, :mod:`companion.logs.mcap_log`), ``summary.json`` and, when matplotlib
is installed, the figures of ``companion plot``.
(``sitl demo`` runs the same mission against the simulator: :func:`run_mission`.)

Exit status: 0 mission completed; 1 the mission failed or a failsafe aborted it (the log
and summary are still written); 2 a user mistake (config, option out of range, URL,
signing key, output directory, unreachable vehicle or bus), one ``error:`` line found
before anything flies. A flight log is never overwritten: when ``--out`` holds an earlier
flight, this one goes to ``OUT-2``, ``OUT-3``, ... (:func:`companion.cli.usage.output_dir_or_exit`).
"""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from arm_driver.bus import open_bus
from arm_driver.errors import ArmDriverError
from companion.cli.flight_page import FLIGHT_PAGE, write_flight_page
from companion.cli.plot import FIGURES, TruthLines, figures_available, plot_flight_log
from companion.cli.usage import (
    check_range,
    config_or_exit,
    fail,
    output_dir_or_exit,
    remove_if_unused,
)
from companion.config import CompanionConfig, arm_bus_configs
from companion.control.flight import FlightControl, FlightControllerName
from companion.control.laws import ControlRateError
from companion.link import LinkError, MavlinkLink, SigningConfig, SigningKeyError
from companion.logs.flightlog import FlightLogError, FlightLogWriter, read_flight_log
from companion.logs.live_view import LiveView, LiveViewError, check_port
from companion.logs.mcap_log import ArmGeometry, FlightLogWithMcap
from companion.mission.app import (
    BUS_FAILURES,
    MissionAborted,
    MissionError,
    MissionInterrupted,
    MissionReport,
    PickupApp,
)
from companion.mission.pickup import PickupPlan

__all__ = [
    "INTERRUPTED",
    "MISSION_FILES",
    "ControllerOpt",
    "check_mission_options",
    "finish_mission",
    "fly_pickup",
    "mission_app",
    "parse_xyz",
    "plan_for",
    "run_mission",
]

MISSION_FILES = (
    "flight.csv",
    "flight.events.csv",
    "flight.timing.csv",
    "flight.mcap",
    "summary.json",
    FLIGHT_PAGE,
    *FIGURES,
)
"""What a mission writes into its output directory."""

HORIZONTAL_RANGE_M = 1000.0
"""Largest |x|, |y| of a mission point from home [m]: a battery flight of a hexacopter
(about 15 minutes at the mission's 0.5 m/s is 450 m there and back)."""
ALTITUDE_RANGE_M = (0.0, 120.0)
"""Transit altitude [m; above the ground with ``[flight] standing_height_m``, else PX4's
local Z]: below the 120 m ceiling of open-category drone flight."""
POINT_HEIGHT_RANGE_M = (-120.0, 120.0)
"""Z of a mission point [m]: above the ground the vehicle takes off from with ``[flight]
standing_height_m`` (the companion moves it into PX4's frame before take-off), else PX4's
local Z (with GPS, EKF2's origin is the standing vehicle's CoM, so an object on the ground
lies about minus the landing gear's height below it); whether the arm reaches a point is
checked against where the vehicle stands, before
arming (:meth:`~companion.mission.pickup.PickupMission.unreachable`)."""
CONTROL_RATE_RANGE_HZ = (2.0, 1000.0)
"""--control-rate: PX4 leaves OFFBOARD below a 2 Hz setpoint stream, and the loop is paced
by PX4's ODOMETRY, which comes at most at the estimator's 1 kHz IMU rate."""

mission_app = typer.Typer(
    name="mission",
    help="Payload-pickup missions against PX4 or the SITL.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


class UsageError(Exception):
    """A user mistake: one line, exit status 2."""


def parse_xyz(text: str, option: str) -> tuple[float, float, float]:
    """X,Y,Z [m, ENU] of a mission point: |X|, |Y| within :data:`HORIZONTAL_RANGE_M` of
    home, Z in :data:`POINT_HEIGHT_RANGE_M`; one ``error:`` line and exit 2 otherwise."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        fail(f"{option} needs three numbers X,Y,Z in metres (ENU), got {text!r}")
    x, y, z = values
    reach, (low, high) = HORIZONTAL_RANGE_M, POINT_HEIGHT_RANGE_M
    if max(abs(x), abs(y)) > reach or not low <= z <= high:
        fail(
            f"{option} {text}: a mission point lies within {reach:g} m of home "
            f"(|X|, |Y|: one battery's flight) and {low:g} to {high:g} m in Z (PX4's local "
            "frame; the 120 m ceiling)"
        )
    return x, y, z


async def fly_pickup(
    scenario: CompanionConfig,
    connect: str,
    arm_bus_url: str,
    plan: PickupPlan,
    controller: FlightControllerName,
    out_dir: Path,
    *,
    signing_key: Path | None = None,
    control_rate_hz: float = 250.0,
    vehicle_timeout_s: float = 10.0,
    figures: bool = True,
    mcap: bool = True,
    live_port: int | None = None,
) -> tuple[MissionReport, BaseException | None]:
    """Open the link and the arm bus, fly, write log and summary (and, with ``figures``,
    the figures; with ``mcap``, ``flight.mcap`` beside the CSV; with ``live_port``, the
    MCAP's channels on a Foxglove WebSocket server there, 0: a free port, and
    ``flight.mcap`` written, as its writer serves them).

    Returns the report and the mission's failure (MissionError / MissionAborted /
    MissionInterrupted: the task was cancelled, as ``asyncio.run`` does on Ctrl-C, and the
    arm's safe state, the log and the summary were still written) or None.
    Raises :class:`UsageError` when the vehicle or the bus cannot be reached.
    """
    if scenario.arm_bus is None:
        raise UsageError(f"{scenario.name}: the scenario has no [arm_bus] section (joints)")
    joints, gripper = arm_bus_configs(scenario.arm_bus)
    q_stow = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, *plan.stow_joints_rad])
    try:
        FlightControl(scenario, controller).check_rate(control_rate_hz, q_stow)
    except ControlRateError as exc:
        raise UsageError(f"{scenario.name}: {exc}") from None
    try:
        signing = SigningConfig.from_file(signing_key) if signing_key is not None else None
    except SigningKeyError as exc:
        raise UsageError(f"--signing-key: {exc}") from None
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
        await link.open()
    except LinkError as exc:  # refused, no such device, unknown host: nothing flew
        raise UsageError(f"--connect {exc}") from None
    except OSError as exc:
        raise UsageError(f"--connect {connect}: cannot open: {exc}") from None
    try:
        try:
            await link.wait_vehicle(vehicle_timeout_s)
        except LinkError as exc:
            raise UsageError(str(exc)) from None
        try:
            await bus.open()
        except (ArmDriverError, OSError) as exc:
            raise UsageError(f"arm bus {arm_bus_url}: {exc}") from None
        try:
            writer = (
                FlightLogWithMcap(log_path, ArmGeometry.from_config(scenario))
                if mcap or live_port is not None
                else FlightLogWriter(log_path)
            )
            try:
                writer.open()
            except FlightLogError as exc:
                raise UsageError(str(exc)) from None
            live = None
            if live_port is not None and isinstance(writer, FlightLogWithMcap):
                live = _open_live_view(live_port, writer)
            event = writer.event
            try:
                app = PickupApp(
                    scenario,
                    link,
                    bus,
                    plan,
                    controller=controller,
                    control_rate_hz=control_rate_hz,
                    log=writer,
                    event=event,
                )
                try:
                    report = await app.run()
                except (MissionError, MissionAborted, ArmDriverError, LinkError) as exc:
                    failure = exc
                    report = app.report
                    event("failure", str(exc), app.t_s)
                except asyncio.CancelledError:  # Ctrl-C: the runner cancels this task
                    task = asyncio.current_task()
                    if task is not None:
                        task.uncancel()  # handled here: the clean-up's timeouts work again
                    failure = MissionInterrupted(app.t_s)
                    report = app.report
                    report.outcome = "interrupted"
                    event("failure", str(failure), app.t_s)
            finally:
                writer.close()
                if live is not None:
                    live.close()
        finally:
            await bus.close()
    finally:
        await link.close()
    summary = report.as_dict()
    summary["failure"] = None if failure is None else f"{type(failure).__name__}: {failure}"
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if figures:
        draw_figures(log_path, out_dir)
        write_flight_page(out_dir)
    return report, failure


def _open_live_view(port: int, writer: FlightLogWithMcap) -> LiveView:
    """The live view of ``writer``'s MCAP on ``port``, open and announced; UsageError when
    it cannot start."""
    context = writer.mcap.context
    assert context is not None  # the writer is open
    live = LiveView(port, context)
    try:
        live.open()
    except LiveViewError as exc:
        writer.close()
        raise UsageError(f"--live: {exc}") from None
    typer.echo(f"live view: {live.url} (Foxglove: Open connection)")
    return live


def draw_figures(log_path: Path, out_dir: Path, truth: TruthLines | None = None) -> list[Path]:
    """The figures of ``companion plot`` into ``out_dir`` (with ``truth`` beside the
    estimate, if given) when the flight log holds a control cycle and matplotlib is
    installed (the flight install need not have it); the paths drawn. A figure must never
    hide the mission's result: a failure to draw is one warning line."""
    if not log_path.exists() or log_path.stat().st_size == 0:
        return []
    if not figures_available():
        typer.echo("note: figures not drawn (matplotlib not installed: pip install '.[plot]')")
        return []
    try:
        flight = read_flight_log(log_path)
        if len(flight) == 0:
            typer.echo("note: no figures: the flight log has no control cycle")
            return []
        return plot_flight_log(flight, out_dir, truth)
    except Exception as exc:
        typer.echo(f"warning: figures not drawn: {exc}", err=True)
        return []


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


LiveOpt = Annotated[
    int | None,
    typer.Option(
        "--live",
        metavar="PORT",
        help="Serve the flight log's channels live to Foxglove on ws://127.0.0.1:PORT "
        "(8765 is Foxglove's default; 0: any free port), every cycle, a block of "
        "cycles at a time (80 ms at 125 Hz).",
    ),
]

ControllerOpt = Annotated[
    str,
    typer.Option(
        help="passivity (adaptive, the paper's), nonadaptive (empty-arm values) or "
        "px4_position (PX4's own position controller flies the vehicle on position "
        "setpoints; the companion drives the arm)."
    ),
]


@mission_app.command("pickup")
def pickup(
    config: Annotated[Path, typer.Option("--config", help="Scenario TOML with [arm_bus].")],
    payload_at: Annotated[
        str,
        typer.Option(
            help="Object's centre of mass X,Y,Z [m, ENU]: X, Y in PX4's local frame, Z above "
            "the ground (config [flight] standing_height_m; else PX4's local Z)."
        ),
    ],
    place_at: Annotated[
        str, typer.Option(help="Where to put it, X,Y,Z [m, ENU], as --payload-at.")
    ],
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
    out: Annotated[
        Path,
        typer.Option(
            help="Directory for log, summary and figures; if it holds an earlier flight, "
            "this one goes to OUT-2, OUT-3, ... (never overwritten)."
        ),
    ] = Path("out/mission"),
    signing_key: Annotated[Path | None, typer.Option(help="MAVLink 2 signing key file.")] = None,
    control_rate: Annotated[float, typer.Option(help="Control loop rate [Hz], 2-1000.")] = 250.0,
    cruise_altitude: Annotated[
        float, typer.Option(help="Transit altitude [m], above 0.5 and at most 120.")
    ] = 1.5,
    live: LiveOpt = None,
) -> None:
    """Fly a payload pickup: take off, grasp, learn the payload, carry, place, land."""
    scenario = config_or_exit(config)
    payload = parse_xyz(payload_at, "--payload-at")
    plan = plan_for(scenario, payload, parse_xyz(place_at, "--place-at"), cruise_altitude)
    bus_url = arm_bus or (scenario.arm_bus.url if scenario.arm_bus else None)
    if bus_url is None:
        fail(f"{config}: no --arm-bus and no [arm_bus] url in the config")
    check_mission_options(controller, control_rate, signing_key, live)
    out = output_dir_or_exit(out, MISSION_FILES)
    status = run_mission(scenario, connect, bus_url, plan, controller, out, signing_key,
                          control_rate, live_port=live)  # fmt: skip
    raise typer.Exit(status)


def check_mission_options(
    controller: str, control_rate_hz: float, signing_key: Path | None, live_port: int | None = None
) -> None:
    """The options every mission command shares; one ``error:`` line and exit 2 for a bad
    one, before anything is opened."""
    if live_port is not None:
        try:
            check_port(live_port)
        except LiveViewError as exc:
            fail(f"--live {exc}")
    if controller not in ("passivity", "nonadaptive", "px4_position"):
        fail(f"--controller must be passivity, nonadaptive or px4_position, got {controller!r}")
    low, high = CONTROL_RATE_RANGE_HZ
    check_range(control_rate_hz, "--control-rate", low, high, "Hz",
                "PX4 drops OFFBOARD below 2 Hz; its ODOMETRY comes at most at 1 kHz")  # fmt: skip
    if signing_key is not None:
        try:
            SigningConfig.from_file(signing_key)
        except SigningKeyError as exc:
            fail(f"--signing-key: {exc}")


def plan_for(scenario: CompanionConfig, payload_at, place_at, cruise_altitude: float) -> PickupPlan:
    """The mission's plan from the options (one ``error:`` line and exit 2 for a bad one)."""
    top = ALTITUDE_RANGE_M[1]
    if not 0.5 < cruise_altitude <= top:
        fail(
            f"--cruise-altitude must lie above 0.5 m (clear of the payload on the ground) and "
            f"at most {top:g} m (the open-category ceiling), got {cruise_altitude:g}"
        )
    stow = scenario.flight.stow_joints_rad
    return PickupPlan(
        home_m=(0.0, 0.0),
        payload_at_m=payload_at,
        place_at_m=place_at,
        cruise_altitude_m=cruise_altitude,
        stow_joints_rad=tuple(stow),  # type: ignore[arg-type]
        excite_eta1_rad=scenario.flight.excite_eta1_rad,
        excite_payload_kg=scenario.flight.excite_payload_kg,
    )


def run_mission(
    scenario,
    connect,
    bus_url,
    plan,
    controller,
    out,
    signing_key,
    rate,
    live_port=None,
    figures: bool = True,
) -> int:
    """Fly, print the report; the exit status (0 completed, 1 failed). ``out`` is the
    directory :func:`companion.cli.usage.output_dir_or_exit` chose (created if missing);
    ``live_port``, ``figures``: see :func:`fly_pickup`."""
    check_mission_options(controller, rate, signing_key, live_port)
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
                live_port=live_port,
                figures=figures,
            )
        )
    except UsageError as exc:
        remove_if_unused(out)  # nothing flew: no empty --out is left behind
        fail(str(exc))
    return finish_mission(report, failure, out)


INTERRUPTED = 130
"""Exit status of a mission the user stopped (Ctrl-C), as a shell reports SIGINT."""


def finish_mission(report: MissionReport, failure: BaseException | None, out: Path) -> int:
    """Print the report of a flown mission; the exit status (0 completed, 1 failed,
    :data:`INTERRUPTED` stopped by the user: one line, where the partial log is)."""
    if isinstance(failure, MissionInterrupted):
        typer.echo(f"stopped: {failure}; partial log and summary in {out}/", err=True)
        return INTERRUPTED
    _print_report(report, failure)
    typer.echo(f"log, summary and figures: {out}/")
    return 0 if failure is None else 1

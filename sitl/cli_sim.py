"""The ``sitl`` commands that run the companion's math or app against the simulator.

``sitl sim`` and ``sitl compare`` (the offline closed loop, :mod:`sitl.offline.simulation`, and the
paper's comparison), ``sitl check`` (a whole scenario file, truth included) and
``sitl demo`` (``sitl run`` plus the pickup mission, compared with the truth).

Options and the output directory are checked before anything runs (one ``error:`` line,
exit status 2); results are never overwritten: an ``--out`` that holds an earlier run's
results gets this run's in ``OUT-2``, ``OUT-3``, ...
(:func:`companion.cli.usage.output_dir_or_exit`).
"""

from __future__ import annotations

import json
import math
import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from companion.cli.flight_page import write_flight_page
from companion.cli.mission import (
    INTERRUPTED,
    MISSION_FILES,
    run_mission,
)
from companion.cli.options import options_command
from companion.cli.usage import (
    EXIT_USAGE,
    check_range,
    fail,
    load_or_exit,
    output_dir_or_exit,
    remove_if_unused,
)
from companion.mission.pickup import PickupPlan
from sitl.cli_options import SeedOpt, check_seed
from sitl.demo_command import CONTROL_RATE_HZ, DemoCommand
from sitl.flight_figures import draw_with_truth
from sitl.scenario import MAX_DURATION_S, Scenario, load_scenario
from sitl.truth_mcap import add_flight_truth
from sitl.vehicle.launch import SitlNotReadyError, start_sitl

__all__ = ["COMPARE_FILES", "DEMO_FILES", "SIM_FILES", "sim_app"]

SIM_FILES = ("summary.json", "timeseries.csv", "tracking.png", "estimation.png", "parameters.png")
"""What ``sitl sim`` writes into ``--out``."""
COMPARE_FILES = ("compare.md", "summaries.json", "compare.png")
"""What ``sitl compare`` writes into ``--out``."""
DEMO_FILES = (*MISSION_FILES, "truth.jsonl")
"""What ``sitl demo`` writes into ``--out``."""

sim_app = typer.Typer(add_completion=False)
"""The commands of this module; ``sitl.cli`` adds them to ``sitl``."""


@sim_app.command()
def check(
    config: Annotated[Path, typer.Argument(help="Scenario TOML file to validate.")],
) -> None:
    """Validate a whole scenario file (the companion's sections and the simulator's) and
    print the values the model and the truth use."""
    cfg = load_or_exit(config, load_scenario)
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


class ControllerChoice(StrEnum):
    passivity = "passivity"
    nonadaptive = "nonadaptive"
    asmc = "asmc"


class EstimatorChoice(StrEnum):
    paper = "paper"
    rls = "rls"


class PlantChoice(StrEnum):
    ideal = "ideal"
    underactuated = "underactuated"


class PhysicsChoice(StrEnum):
    pinocchio = "pinocchio"
    jsbsim = "jsbsim"


ScenarioOpt = Annotated[
    Path, typer.Option("--scenario", help="Scenario TOML file (see configs/).", show_default=False)
]
OutOpt = Annotated[
    Path,
    typer.Option(
        "--out",
        help="Output directory (created if missing); if it holds an earlier run's results, "
        "this run's go to OUT-2, OUT-3, ... (never overwritten).",
        show_default=False,
    ),
]
PlantOpt = Annotated[PlantChoice, typer.Option(help="Truth plant: tau on all 8 rows, or PX4-like.")]
DurationOpt = Annotated[
    float | None,
    typer.Option(
        help="Simulated seconds, one control step to 3600 [default: the scenario's "
        "simulation.duration_s]."
    ),
]
PhysicsOpt = Annotated[
    PhysicsChoice,
    typer.Option(help="Truth physics: our Pinocchio plant, or JSBSim (underactuated only)."),
]
WindOpt = Annotated[
    str | None,
    typer.Option(
        help="Steady wind 'E,N,U' [m/s], world ENU, e.g. '3,0,0', in place of the scenario's "
        "plant.wind_m_s (underactuated plant)."
    ),
]
TurbulenceOpt = Annotated[
    float,
    typer.Option(
        help="Dryden turbulence intensity: MIL-F-8785C wind speed at 20 ft [m/s] "
        "(jsbsim only; 0 = none; light 7.7, moderate 15)."
    ),
]
NoiseOpt = Annotated[
    bool, typer.Option("--noise/--no-noise", help="Noisy sensors ([sensors]) or exact ones.")
]


def _run(cfg: Scenario, options, label: str):
    """Simulate with a progress bar on a terminal; plant failures exit 1 with a message."""
    from rich.progress import Progress

    from companion.control.laws import ControlRateError
    from sitl.offline.simulation import simulate
    from sitl.physics import PlantError

    duration = options.duration_s or cfg.simulation.duration_s
    with Progress(
        transient=True, disable=not sys.stderr.isatty(), console=Console(stderr=True)
    ) as bar:
        task = bar.add_task(label, total=duration)
        try:
            return simulate(cfg, options, progress=lambda t: bar.update(task, completed=t))
        except ControlRateError as exc:
            typer.echo(f"error: {label}: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        except (PlantError, FloatingPointError) as exc:
            typer.echo(f"error: {label}: the simulation failed: {exc}", err=True)
            raise typer.Exit(1) from None


def _check_physics(
    cfg: Scenario,
    physics: PhysicsChoice,
    plant: PlantChoice,
    wind: str | None,
    turbulence: float,
    seed: int,
):
    """The ``Wind`` of the options, else the scenario's steady ``plant.wind_m_s`` (None
    when calm); usage errors exit 2."""
    from sitl.physics.jsbsim.wind import Wind

    if physics is PhysicsChoice.jsbsim and plant is PlantChoice.ideal:
        typer.echo(
            "error: --physics jsbsim needs --plant underactuated (ideal mode, tau on all 8 "
            "rows, exists only on the Pinocchio plant)",
            err=True,
        )
        raise typer.Exit(EXIT_USAGE)
    if turbulence != 0.0 and physics is not PhysicsChoice.jsbsim:
        typer.echo("error: --turbulence needs --physics jsbsim", err=True)
        raise typer.Exit(EXIT_USAGE)
    try:
        air = Wind.from_text(wind, turbulence, seed, cfg.plant.wind_m_s)
    except ValueError as exc:
        typer.echo(f"error: --wind {wind!r} / --turbulence {turbulence:g}: {exc}", err=True)
        raise typer.Exit(EXIT_USAGE) from None
    if air is None and any(cfg.plant.wind_m_s):
        air = Wind(cfg.plant.wind_m_s)
    if plant is PlantChoice.ideal and air is not None:
        typer.echo(
            "error: wind needs --plant underactuated (the ideal plant, tau on all 8 rows, has "
            "no drag for the wind to act through)",
            err=True,
        )
        raise typer.Exit(EXIT_USAGE)
    return air


def _wind_label(air) -> str:
    if air is None:
        return ""
    east, north, up = air.velocity_enu_m_s
    label = f", wind ({east:g}, {north:g}, {up:g}) m/s ENU"
    if air.turbulence != "none":
        label += f" + Dryden turbulence (W20 = {air.windspeed_20ft_m_s:g} m/s)"
    return label


def _check_times(cfg: Scenario, duration: float | None, *times: float | None) -> None:
    step = 1.0 / cfg.simulation.control_rate_hz
    if duration is not None:
        rate = cfg.simulation.control_rate_hz
        why = f"one control step at the scenario's {rate:g} Hz; a battery lasts under an hour"
        check_range(duration, "--duration", step, MAX_DURATION_S, "s", why)
    end = duration if duration is not None else cfg.simulation.duration_s
    for t in times:
        if t is not None and not 0.0 <= t <= end:
            fail(f"event time {t:g} s lies outside the run [0, {end:g}] s")


@sim_app.command()
def sim(
    scenario: ScenarioOpt,
    out: OutOpt,
    controller: Annotated[
        ControllerChoice, typer.Option(help="Control law.")
    ] = ControllerChoice.passivity,
    estimator: Annotated[
        EstimatorChoice | None,
        typer.Option(help="Payload estimator [default: the scenario's estimator.kind]."),
    ] = None,
    plant: PlantOpt = PlantChoice.ideal,
    physics: PhysicsOpt = PhysicsChoice.pinocchio,
    wind: WindOpt = None,
    turbulence: TurbulenceOpt = 0.0,
    duration: DurationOpt = None,
    seed: SeedOpt = 0,
    noise: NoiseOpt = False,
    pickup_at: Annotated[
        float | None,
        typer.Option(
            help="Grasp the payload at this time [s]; until then the arm is known empty "
            "(the estimator learns only the thrust scale, or holds)."
        ),
    ] = None,
    release_at: Annotated[
        float | None, typer.Option(help="Release the payload at this time [s].")
    ] = None,
) -> None:
    """Simulate the aerial manipulator offline; writes summary.json, timeseries.csv, figures."""
    from sitl.offline.plots import plot_run
    from sitl.offline.results import write_summary, write_timeseries
    from sitl.offline.simulation import SimOptions

    cfg = load_or_exit(scenario, load_scenario)
    _check_times(cfg, duration, pickup_at, release_at)
    if pickup_at is not None and release_at is not None and not release_at > pickup_at:
        fail(
            f"--release-at {release_at:g} s must come after --pickup-at {pickup_at:g} s "
            "(the payload is released once it is held)"
        )
    check_seed(seed)
    air = _check_physics(cfg, physics, plant, wind, turbulence, seed)
    out = output_dir_or_exit(out, SIM_FILES)
    options = SimOptions(
        controller=controller.value,
        estimator=estimator.value if estimator else None,
        plant=plant.value,
        physics=physics.value,
        wind=air,
        duration_s=duration,
        seed=seed,
        noise=noise,
        pickup_at_s=pickup_at,
        release_at_s=release_at,
    )
    result = _run(cfg, options, f"{cfg.name}: {controller.value}")
    write_summary(result.summary, out / "summary.json")
    write_timeseries(result, out / "timeseries.csv")
    plot_run(result, out)
    s = result.summary
    Console().print(
        f"{cfg.name} ({s['controller']}, {s['estimator']}, {s['plant']} plant, "
        f"{s['physics']}{', wind' if air else ''}"
        f"{', noisy' if noise else ''}): m2 = {s['estimates']['m2']:.4f} kg "
        f"({s['errors_pct']['m2']:+.1f} %), lc = {s['estimates']['lc']:.4f} m "
        f"({s['errors_pct']['lc']:+.1f} %), RMS position error "
        f"{s['rms_position_error_m'] * 100:.1f} cm; wrote {out}",
        markup=False,
        highlight=False,
    )


COMPARED = (
    ("passivity + paper estimator", ControllerChoice.passivity, EstimatorChoice.paper),
    ("passivity + rls", ControllerChoice.passivity, EstimatorChoice.rls),
    ("non-adaptive", ControllerChoice.nonadaptive, EstimatorChoice.paper),
    ("adaptive sliding mode", ControllerChoice.asmc, EstimatorChoice.paper),
)
"""Runs of ``companion compare``: the paper's controller with both estimators, and its two
baselines (paper section IV)."""
LEFT_OUT = {
    (PlantChoice.underactuated, ControllerChoice.asmc): (
        "adaptive sliding mode: left out on the underactuated plant. Its law (eq. asc1) asks "
        "for a force on every row of q, and the tilt rows take none directly (the attitude "
        "comes from PX4's loop): it diverges there (over 100 m RMS on "
        "configs/paper_sim.toml). Run it on the ideal plant, or alone with `sitl sim --controller "
        "asmc` to see it."
    ),
}
"""Runs ``compare`` leaves out, by plant and controller, with the reason it gives."""


@sim_app.command()
def compare(
    scenario: ScenarioOpt,
    out: OutOpt,
    plant: PlantOpt = PlantChoice.ideal,
    physics: PhysicsOpt = PhysicsChoice.pinocchio,
    wind: WindOpt = None,
    turbulence: TurbulenceOpt = 0.0,
    duration: DurationOpt = None,
    seed: SeedOpt = 0,
    noise: NoiseOpt = False,
) -> None:
    """Run every controller and estimator on one scenario; writes compare.md and overlays."""
    from sitl.offline.plots import plot_comparison
    from sitl.offline.results import comparison_markdown, write_summary
    from sitl.offline.simulation import SimOptions

    cfg = load_or_exit(scenario, load_scenario)
    _check_times(cfg, duration)
    check_seed(seed)
    air = _check_physics(cfg, physics, plant, wind, turbulence, seed)
    out = output_dir_or_exit(out, COMPARE_FILES)
    runs = []
    left_out = []
    for name, ctl, est in COMPARED:
        reason = LEFT_OUT.get((plant, ctl))
        if reason is not None:
            left_out.append(reason)
            typer.echo(reason, err=True)
            continue
        options = SimOptions(
            controller=ctl.value,
            estimator=est.value,
            plant=plant.value,
            physics=physics.value,
            wind=air,
            duration_s=duration,
            seed=seed,
            noise=noise,
        )
        runs.append((name, _run(cfg, options, f"{cfg.name}: {name}")))
    title = (
        f"# {cfg.name}: {plant.value} plant, {physics.value} physics"
        f"{_wind_label(air)}, {'noisy' if noise else 'exact'} sensors, seed {seed}\n\n"
    )
    table = comparison_markdown([(name, r.summary) for name, r in runs])
    notes = "".join(f"\n{reason}\n" for reason in left_out)
    (out / "compare.md").write_text(title + table + notes)
    write_summary({name: r.summary for name, r in runs}, out / "summaries.json")
    plot_comparison(runs, out)
    Console().print(table, markup=False, highlight=False)


@sim_app.command()
@options_command(DemoCommand)
def demo(options: DemoCommand) -> None:
    """Start the simulated vehicle (``sitl run``), fly the pickup mission against it
    (``companion mission pickup``'s code, given only the companion's part of the scenario),
    write log, summary and figures, and compare the estimate with the truth. With
    ``--autopilot px4`` the real PX4 flies our physics; its log and ULog stay in
    ``OUT/px4``. With ``--clock virtual`` the vehicle and the companion run in this
    process on simulated time (:mod:`sitl.vehicle.lockstep`)."""
    factor = options.speed_factor()
    scenario, plan, place_world = options.pickup()
    out = output_dir_or_exit(options.out, DEMO_FILES)
    if options.clock == "virtual":
        status = _fly_virtual(options, scenario, plan, out)
    else:
        status = _fly_wall(options, factor, scenario, plan, out)
    if status == INTERRUPTED:  # its one line said where the partial log is
        raise typer.Exit(status)
    _print_truth(scenario, out, place_world)
    draw_with_truth(out)
    write_flight_page(out)
    raise typer.Exit(status)


def _fly_wall(
    options: DemoCommand, factor: float, scenario: Scenario, plan: PickupPlan, out: Path
) -> int:
    """The demo against ``sitl run`` in its own process at ``factor`` times real time;
    the truth (and PX4's log) merged into the flight's MCAP; the exit status."""
    px4 = options.px4
    try:
        sitl = start_sitl(
            options.config,
            "--seed",
            str(options.seed),
            *options.sitl_arguments(),
            speed=factor,
            truth_log=out / "truth.jsonl",
            px4_dir=options.px4_dir if px4 else None,
            px4_log=out / "px4" if px4 else None,
        )
    except SitlNotReadyError as exc:
        fail(str(exc), 1)
    connect = f"udpin://127.0.0.1:{sitl.onboard_port}"
    typer.echo(f"sitl: running ({sitl.arm_bus}, MAVLink {connect})")
    try:
        status = run_mission(
            scenario.beliefs,
            connect,
            sitl.arm_bus,
            plan,
            options.controller,
            out,
            None,
            CONTROL_RATE_HZ,
            live_port=options.live,
            figures=False,  # drawn once the truth is in
        )
    finally:
        sitl.stop()
    add_flight_truth(out, out / "truth.jsonl")
    if px4:
        _add_px4_log(out)
    return status


def _fly_virtual(options: DemoCommand, scenario: Scenario, plan: PickupPlan, out: Path) -> int:
    """The demo on simulated time; the exit status (0 completed, 1 failed)."""
    from companion.cli.mission import UsageError, finish_mission
    from sitl.physics import PlantError
    from sitl.vehicle.options import RunOptions
    from sitl.vehicle.virtual_flight import fly_virtual

    run = RunOptions(
        seed=options.seed, navigation=options.navigation, truth_log=out / "truth.jsonl"
    )
    typer.echo("sitl: vehicle and companion in lockstep on simulated time (memory links)")
    out.mkdir(parents=True, exist_ok=True)
    try:
        report, failure = fly_virtual(
            scenario,
            plan,
            out,
            run,
            controller=options.controller,  # type: ignore[arg-type]
            control_rate_hz=CONTROL_RATE_HZ,
            figures=False,  # drawn once the truth is in
            live_port=options.live,
        )
    except UsageError as exc:
        remove_if_unused(out)
        fail(str(exc))
    except PlantError as exc:
        typer.echo(f"error: the simulated vehicle's physics failed: {exc}", err=True)
        return 1
    return finish_mission(report, failure, out)


def _add_px4_log(out: Path) -> None:
    """PX4's ULog of the flight (the newest in ``OUT/px4``) into ``OUT/flight.mcap``."""
    from companion.logs.ulog_mcap import UlogError, add_ulog

    ulogs = sorted((out / "px4").rglob("*.ulg"), key=lambda p: p.stat().st_mtime)
    flight = out / "flight.mcap"
    if not ulogs or not flight.exists():
        return
    try:
        added = add_ulog(flight, ulogs[-1])
    except (UlogError, ValueError) as exc:
        typer.echo(f"PX4's log not merged into {flight}: {exc}", err=True)
        return
    typer.echo(f"PX4's log: {added} messages of {ulogs[-1].name} in {flight}")


def _print_truth(scenario: Scenario, out: Path, place_world: tuple[float, float, float]) -> None:
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
                err = math.dist(obj[:2], place_world[:2])
                typer.echo(f"truth: object ended {err:.3f} m from the place point (horizontal)")

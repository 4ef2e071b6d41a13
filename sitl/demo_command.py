"""``sitl demo``'s options, declared once, and the pickup they describe.

:class:`DemoCommand` is the command's options (its fields, with their ``typer.Option``, are
the command line: :func:`companion.cli.options.options_command`) and their checks:
:meth:`DemoCommand.speed_factor` the pace, :meth:`DemoCommand.pickup` the scenario and the
mission's plan in the autopilot's local frame. Every mistake is one ``error:`` line and
exit status 2, before anything flies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path
from typing import Annotated

import typer

from companion.cli.mission import (
    ControllerOpt,
    LiveOpt,
    check_mission_options,
    parse_xyz,
    plan_for,
)
from companion.cli.usage import fail, load_or_exit
from companion.mission.pickup import PickupPlan
from sitl.cli_options import AutopilotOpt, Px4DirOpt, SeedOpt, check_seed
from sitl.scenario import Scenario, load_scenario

__all__ = ["CONTROL_RATE_HZ", "CRUISE_ALTITUDE_M", "DEFAULT_SCENARIO", "DemoCommand"]

DEFAULT_SCENARIO = Path(str(files("sitl.configs") / "sitl_pickup.toml"))
"""The demo's built-in scenario (package data: configs/ is also ``sitl.configs``)."""
CRUISE_ALTITUDE_M = 1.5
"""The demo's cruise height above the ground [m]."""
CONTROL_RATE_HZ = 250.0
"""The demo's control loop rate [Hz] (``companion mission pickup``'s default)."""


@dataclass(frozen=True)
class DemoCommand:
    """The options of ``sitl demo`` (units in the help of each)."""

    out: Annotated[
        Path,
        typer.Option(
            help="Directory for log, summary, truth and figures; if it holds an earlier "
            "run, this one goes to OUT-2, OUT-3, ... (never overwritten)."
        ),
    ] = Path("out/demo")
    config: Annotated[Path, typer.Option(help="Scenario with [world] and [arm_bus].")] = (
        DEFAULT_SCENARIO
    )
    controller: ControllerOpt = "passivity"
    speed: Annotated[
        str,
        typer.Option(
            help="SITL speed (simulated s per wall s), or 'validated': with --autopilot px4 "
            "the highest speed whose results stay within speed 1's (docs/px4_speed.md)."
        ),
    ] = "1"
    seed: SeedOpt = 0
    place_at: Annotated[str, typer.Option(help="Where to put the object, X,Y,Z [m, ENU].")] = (
        "-1.0,0.5,0.05"
    )
    autopilot: AutopilotOpt = "imitation"
    px4_dir: Px4DirOpt = None
    navigation: Annotated[
        str, typer.Option(help="mocap (motion capture) or gps (with --autopilot px4: RTK).")
    ] = "mocap"
    clock: Annotated[
        str,
        typer.Option(
            help="wall (sitl run in its own process, paced at --speed, over UDP and a pty) "
            "or virtual (vehicle and companion in one process on the simulation's clock, "
            "in lockstep, as fast as the machine goes: the same flight log every time)."
        ),
    ] = "wall"
    live: LiveOpt = None

    @property
    def px4(self) -> bool:
        """Whether the real PX4 flies (``--autopilot px4``)."""
        return self.autopilot == "px4"

    def speed_factor(self) -> float:
        """The wall-clock pace (simulated s per wall s) of the autopilot and clock named
        right; ``--speed validated`` is PX4 in the loop's validated speed."""
        if self.autopilot not in ("imitation", "px4"):
            fail(f"--autopilot must be imitation or px4, got {self.autopilot!r}")
        if self.clock not in ("wall", "virtual"):
            fail(f"--clock must be wall or virtual, got {self.clock!r}")
        if self.clock == "virtual" and self.px4:
            fail("--clock virtual flies the PX4 imitation; PX4 keeps its own lockstep clock")
        factor = self._speed()
        if self.clock == "virtual" and factor != 1.0:
            fail("--speed paces the wall clock; --clock virtual runs as fast as it can")
        if self.navigation not in ("mocap", "gps"):
            fail(f"--navigation must be mocap or gps, got {self.navigation!r}")
        if self.px4 and self.px4_dir is None:
            fail("--autopilot px4 needs a PX4 SITL build: pass --px4-dir DIR or set PX4_SITL_DIR")
        return factor

    def sitl_arguments(self) -> list[str]:
        """``sitl run``'s options for this demo's navigation (beside the seed)."""
        extra = ["--navigation", self.navigation]
        if self.px4 and self.navigation == "gps":
            extra += ["--gps", "rtk"]
        return extra

    def pickup(self) -> tuple[Scenario, PickupPlan, tuple[float, float, float]]:
        """The scenario, the mission's plan (its points in the autopilot's local frame) and
        the place point in the world [m, ENU]; the mission's options and the seed checked."""
        scenario = load_or_exit(self.config, load_scenario)
        if scenario.world is None or scenario.world.payload_position_m is None:
            fail(f"{self.config}: the demo needs a [world] section with payload_position_m")
        beliefs = scenario.beliefs
        payload_at = scenario.world.payload_position_m
        place_world = parse_xyz(self.place_at, "--place-at")
        place = place_world
        if self.navigation == "gps":
            # EKF2 starts its local frame where the vehicle stands (its CoM at its first GPS
            # fix), not at the world's origin: the mission's points move into that frame,
            # horizontally; their heights too unless the companion knows its standing height
            # ([flight] standing_height_m: heights above the ground, moved by the companion).
            east, north = scenario.world.start_position_m
            up = (
                0.0
                if beliefs.flight.standing_height_m is not None
                else scenario.world.landing_gear_height_m
            )
            payload_at = (payload_at[0] - east, payload_at[1] - north, payload_at[2] - up)
            place = (place[0] - east, place[1] - north, place[2] - up)
            typer.echo(
                f"GPS: PX4's local frame starts at the standing vehicle ({east}, {north}, "
                f"{scenario.world.landing_gear_height_m}) m"
            )
        plan = plan_for(beliefs, payload_at, place, CRUISE_ALTITUDE_M)
        check_mission_options(self.controller, CONTROL_RATE_HZ, None, self.live)
        check_seed(self.seed)
        return scenario, plan, place_world

    def _speed(self) -> float:
        """``--speed``: a positive factor, or ``validated`` (PX4 in the loop's validated
        speed)."""
        if self.speed == "validated":
            if not self.px4:
                fail("--speed validated is PX4 in the loop's (--autopilot px4)")
            from sitl.hil.vehicle import VALIDATED_SPEED

            return VALIDATED_SPEED
        try:
            factor = float(self.speed)
        except ValueError:
            fail(f"--speed must be a positive number or 'validated', got {self.speed!r}")
        if not (math.isfinite(factor) and factor > 0.0):
            fail(f"--speed must be a positive number or 'validated', got {self.speed!r}")
        return factor

"""A pickup on simulated time: the simulated vehicle and the companion's mission in one
process, in lockstep (:mod:`sitl.vehicle.lockstep`).

The companion's side is :func:`companion.cli.mission.fly_pickup`, the code of
``companion mission pickup``, given only the companion's part of the scenario; it talks to
the vehicle over the in-memory MAVLink link ``memory://NAME-onboard`` and to the servos
over ``dynamixel://memory:NAME-servos``. The vehicle is :class:`~sitl.vehicle.runner.SitlVehicle`
on in-memory channels, stepped whenever the companion waits. Nothing reads the wall clock
for a decision, so the flight log (``flight.csv``, ``flight.events.csv``) and the truth
log are the same bytes for the same scenario, options and seed, at any load.

The companion runs under normal scheduling here (``flight.realtime_priority`` = 0): on
simulated time its latency does not matter, and a campaign's workers must share the cores.
"""

from __future__ import annotations

import itertools
import json
import os
from dataclasses import replace
from pathlib import Path

from companion.cli.mission import fly_pickup
from companion.config import CompanionConfig
from companion.control.flight import FlightControllerName
from companion.mission.pickup import PickupPlan
from companion.mission.report import MissionReport
from sitl.scenario import Scenario
from sitl.truth_mcap import add_flight_truth
from sitl.vehicle.lockstep import run_lockstep
from sitl.vehicle.options import RunOptions
from sitl.vehicle.runner import SitlVehicle

__all__ = ["BOOT_UNIX_TIME_US", "fly_virtual", "normally_scheduled"]

BOOT_UNIX_TIME_US = 1_767_225_600_000_000
"""The Unix time the simulated autopilot boots at on simulated time (2026-01-01 00:00 UTC)
[us]: a constant, so that nothing of the wall clock enters the flight."""

_flights = itertools.count(1)


def normally_scheduled(scenario: Scenario) -> CompanionConfig:
    """The companion's part of ``scenario`` with ``flight.realtime_priority`` 0: a
    simulated flight's companion shares the cores with the vehicle and other flights."""
    beliefs = scenario.beliefs
    return beliefs.model_copy(
        update={"flight": beliefs.flight.model_copy(update={"realtime_priority": 0})}
    )


def fly_virtual(
    scenario: Scenario,
    plan: PickupPlan,
    out_dir: Path,
    options: RunOptions,
    *,
    controller: FlightControllerName = "passivity",
    control_rate_hz: float = 250.0,
    figures: bool = True,
    mcap: bool = True,
    live_port: int | None = None,
) -> tuple[MissionReport, BaseException | None]:
    """Fly one pickup on simulated time; write the flight log, summary (and figures) into
    ``out_dir`` and, with ``options.truth_log``, the truth (also into ``flight.mcap``; with
    ``mcap`` off no MCAP is written: a campaign's flights, about 10 % faster; ``live_port``:
    the live view, as ``fly_pickup``'s). The summary also gets the flight's simulated and
    wall seconds, first plant step to the last (``flight_sim_s``, ``flight_wall_s``).

    Returns the mission's report and its failure (None: completed), as
    :func:`~companion.cli.mission.fly_pickup`. ``options.speed`` is not used (nothing
    paces the steps). Raises what ``fly_pickup`` raises for a scenario the companion
    refuses (:class:`~companion.cli.mission.UsageError`), and
    :class:`~sitl.physics.PlantError` if the physics diverge.
    """
    name = f"flight-{os.getpid()}-{next(_flights)}"
    boot_us = options.unix_time_at_boot_us
    options = replace(
        options, memory=name, unix_time_at_boot_us=BOOT_UNIX_TIME_US if boot_us is None else boot_us
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    beliefs = normally_scheduled(scenario)
    with SitlVehicle(scenario, options) as vehicle:
        where = vehicle.describe()
        result = run_lockstep(
            vehicle,
            fly_pickup(
                beliefs,
                where["connect"],
                where["arm_bus"],
                plan,
                controller,
                out_dir,
                control_rate_hz=control_rate_hz,
                figures=figures,
                mcap=mcap,
                live_port=live_port,
            ),
        )
    add_flight_truth(out_dir, options.truth_log)  # the truth log is closed now
    _add_flight_times(out_dir / "summary.json", vehicle.flight_times())
    return result


def _add_flight_times(summary: Path, times: dict[str, float]) -> None:
    """The flight's simulated and wall seconds (:meth:`SitlVehicle.flight_times`) added to
    the mission's ``summary`` (JSON; nothing when the mission wrote none)."""
    if not summary.exists():
        return
    record = json.loads(summary.read_text())
    record.update(times)
    summary.write_text(json.dumps(record, indent=2) + "\n")

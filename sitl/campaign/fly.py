"""One flight of a campaign, flown and measured: what a worker does with a :class:`Flight`.

The flight is ``sitl demo --clock virtual``'s (:func:`sitl.vehicle.virtual_flight.fly_virtual`: the
companion's mission code against the simulated vehicle, in lockstep on simulated time), or,
on the ``px4`` autopilot, ``sitl demo --autopilot px4 --speed validated``'s (``sitl run``
with the real PX4 SITL build found through ``PX4_SITL_DIR``, the companion's mission over
UDP on loopback), in a fresh temporary directory that is removed afterwards; what stays is
one row of figures (:func:`flight_row`). A flight that raises becomes a row with ``status``
``error`` and its traceback, never an exception out of the worker.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import shutil
import tempfile
import time
import traceback
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit

from companion.cli.mission import plan_for
from companion.logs.flightlog import read_flight_log
from companion.mission.pickup import Phase, PickupPlan
from companion.mission.report import MissionReport
from sitl.campaign.flights import CRUISE_ALTITUDE_M, Flight, scenario_of
from sitl.campaign.safety import handover_s, judge
from sitl.scenario import Scenario
from sitl.vehicle.link_faults import LinkLatency, LinkLoss, PilotTakeover
from sitl.vehicle.mission_phases import FaultStart, PhaseStart
from sitl.vehicle.options import RunOptions, ServoError
from sitl.vehicle.servo_bus_faults import BusCorruption, ServoReboot
from sitl.vehicle.virtual_flight import fly_virtual, normally_scheduled

__all__ = [
    "CARRY_PHASES",
    "WORK_DIR_VARIABLE",
    "flight_row",
    "fly_flight",
    "package_version",
]

WORK_DIR_VARIABLE = "SITL_CAMPAIGN_WORK_DIR"
"""The environment variable that names the directory a worker's flights write their logs
in (each in a directory of its own, removed when it ends): the campaign's, which it removes
at its end, so that a worker killed under its flight leaves nothing behind. Unset, or not
a directory on this machine (a Ray node): the system's temporary directory."""

CARRY_PHASES = (Phase.LIFT.value, Phase.TO_PLACE.value, Phase.LOWER.value)
"""The carry from lift to place, the excitation left out: where carry RMS and maximum
error are taken."""


def package_version() -> str:
    """The installed version of this project (``unknown`` outside an install)."""
    try:
        return version("aerial-manipulator-companion")
    except PackageNotFoundError:
        return "unknown"


def _percent(estimate: float | None, truth: float) -> float | None:
    if estimate is None or truth == 0.0:
        return None
    return 100.0 * (estimate - truth) / truth


def _read_log(flight_csv: Path) -> dict[str, np.ndarray] | None:
    """The flight log's columns, or None when it is missing, empty or does not read."""
    if not flight_csv.exists() or flight_csv.stat().st_size == 0:
        return None
    try:
        return read_flight_log(flight_csv).columns
    except (OSError, ValueError):
        return None


def _carry_errors(c: dict[str, np.ndarray] | None) -> tuple[float | None, float | None]:
    """(RMS, max) of the position error against the plan over the carry [m] (``c`` the
    flight log's columns)."""
    if c is None:
        return None, None
    rows = np.isin(c["phase"], CARRY_PHASES)
    if not rows.any():
        return None, None
    error = np.stack([c[f"q_{a}_m"][rows] - c[f"qd_{a}_m"][rows] for a in "xyz"])
    norm = np.sqrt(np.sum(error**2, axis=0))
    norm = norm[np.isfinite(norm)]
    if norm.size == 0:
        return None, None
    return math.sqrt(float(np.mean(norm**2))), float(np.max(norm))


def flight_row(
    flight: Flight,
    scenario: Scenario,
    report: MissionReport,
    failure: BaseException | None,
    out_dir: Path,
) -> dict[str, Any]:
    """The figures of a flown flight: outcome, estimate against the truth, placement, carry
    errors, tilt, loop statistics, and whether it ended safe
    (:func:`sitl.campaign.safety.judge`; the timing columns are the caller's)."""
    truth = [json.loads(line) for line in (out_dir / "truth.jsonl").read_text().splitlines()]
    last = truth[-1] if truth else {}
    obj = last.get("object_position_m")
    place = flight.place_at_m
    log = _read_log(out_dir / "flight.csv")
    carry_rms, carry_max = _carry_errors(log)
    summary = report.as_dict()
    latency = summary["cycle_latency_us"] or {}
    log_end_s = None if log is None or not len(log["t_vehicle_s"]) else log["t_vehicle_s"][-1]
    # With PX4 in the loop PX4 flies on while the mission winds up: the log reaches the handover.
    verdict = judge(
        truth,
        summary,
        place,
        None if log_end_s is None else float(log_end_s),
        handover_s(truth) if flight.autopilot == "px4" else None,
    )
    return {
        "status": "ok",
        "outcome": report.outcome,
        "completed": int(failure is None and report.completed),
        "faults": json.dumps([f.get("fault") for f in report.faults]),
        "failure": None if failure is None else f"{type(failure).__name__}: {failure}",
        "true_mass_kg": scenario.payload.mass_kg,
        "mass_kg": report.payload_mass_kg,
        "mass_std_kg": report.payload_mass_std_kg,
        "mass_error_pct": _percent(report.payload_mass_kg, scenario.payload.mass_kg),
        "true_com_m": scenario.payload.position_m,
        "com_m": report.payload_com_m,
        "com_error_pct": _percent(report.payload_com_m, scenario.payload.position_m),
        "estimate_confident": int(report.confident),
        "placement_error_m": None if obj is None else math.dist(obj[:2], place[:2]),
        "carry_rms_m": carry_rms,
        "carry_max_error_m": carry_max,
        "position_rms_m": report.position_rms_m,
        "max_tilt_deg": report.max_tilt_deg,
        "handover_tilt_deg": report.handover_tilt_deg,
        "landed": int(report.landed),
        "sim_s": last.get("t_s"),
        "control_cycles": report.control_cycles,
        "late_cycles": report.late_cycles,
        "poses_dropped": report.poses_dropped,
        "servo_retries": report.servo_retries,
        "servo_failures": report.servo_failures,
        "longest_period_ms": report.longest_period_ms,
        "estimator_skipped_steps": report.estimator_skipped_steps,
        "cycle_latency_median_us": latency.get("median"),
        "cycle_latency_p99_us": latency.get("p99"),
        "safe": int(verdict.safe),
        "unsafe": "; ".join(verdict.broken) or None,
        "end_state": verdict.end,
        "touchdown_m_s": verdict.touchdown_m_s,
        "payload_end": verdict.payload,
    }


def fly_flight(
    flight: Flight, document: dict[str, Any], keep: Path | None = None
) -> dict[str, Any]:
    """Fly ``flight`` (its scenario ``document``) and return its row: the figures of
    :func:`flight_row`, or ``status`` ``error`` with the traceback; wall and CPU time and
    the version in both. The logs go to a temporary directory, removed afterwards, or to
    ``keep`` (with figures)."""
    work = keep if keep is not None else _work_dir()
    wall0, cpu0 = time.perf_counter(), time.process_time()
    try:
        scenario = scenario_of(flight, document)
        assert scenario.world is not None and scenario.world.payload_position_m is not None
        plan = plan_for(
            scenario.beliefs, scenario.world.payload_position_m, flight.place_at_m,
            CRUISE_ALTITUDE_M,
        )  # fmt: skip
        if flight.autopilot == "px4":
            report, failure = _fly_px4(flight, scenario, document, plan, work, keep is not None)
        else:
            report, failure = fly_virtual(
                scenario,
                plan,
                work,
                _run_options(flight, work),
                controller=flight.controller,  # type: ignore[arg-type]
                figures=keep is not None,
                mcap=keep is not None,  # a replay keeps its log; a campaign's row is what stays
            )
        row = flight_row(flight, scenario, report, failure, work)
    except Exception:  # a crashed flight is a row, not a crashed worker
        row = {"status": "error", "error": traceback.format_exc()}
    finally:
        if keep is None:
            shutil.rmtree(work, ignore_errors=True)
    row["wall_s"] = time.perf_counter() - wall0
    row["cpu_s"] = time.process_time() - cpu0
    row["version"] = package_version()
    return row


def _work_dir() -> Path:
    """A new directory for a flight's logs, in the campaign's (:data:`WORK_DIR_VARIABLE`)."""
    root = os.environ.get(WORK_DIR_VARIABLE)
    where = root if root and os.path.isdir(root) else None
    return Path(tempfile.mkdtemp(prefix="campaign-flight-", dir=where))


def _run_options(flight: Flight, work: Path) -> RunOptions:
    """The imitation's run options: seed, motion capture, the truth log, the link faults."""
    fault = flight.fault
    start: FaultStart | None = (
        PhaseStart(fault.at_phase, fault.offset_s or 0.0)
        if fault.at_phase is not None
        else fault.at_s
    )
    return RunOptions(
        seed=flight.seed,
        navigation="mocap",
        truth_log=work / "truth.jsonl",
        link_cut=(start, fault.duration_s)  # type: ignore[arg-type]
        if fault.kind == "link_cut"
        else None,
        servo_silent=(fault.servo_id, start)  # type: ignore[arg-type]
        if fault.kind == "servo_silent"
        else None,
        servo_error=ServoError(fault.servo_id, fault.error, start)  # type: ignore[arg-type]
        if fault.kind == "servo_error"
        else None,
        servo_reboot=ServoReboot(fault.servo_id, start, fault.boot_s)  # type: ignore[arg-type]
        if fault.kind == "servo_reboot"
        else None,
        bus_corruption=BusCorruption(start, fault.duration_s, fault.corrupt_fraction)  # type: ignore[arg-type]
        if fault.kind == "bus_corruption"
        else None,
        link_loss=LinkLoss(start, fault.duration_s, fault.drop_fraction)  # type: ignore[arg-type]
        if fault.kind == "link_loss"
        else None,
        link_latency=LinkLatency(start, fault.duration_s, fault.delay_s)  # type: ignore[arg-type]
        if fault.kind == "link_latency"
        else None,
        pilot_takeover=PilotTakeover(start, fault.mode)  # type: ignore[arg-type]
        if fault.kind == "pilot_takeover"
        else None,
    )


def _fly_px4(
    flight: Flight,
    scenario: Scenario,
    document: dict[str, Any],
    plan: PickupPlan,
    work: Path,
    keep: bool,
) -> tuple[MissionReport, BaseException | None]:
    """The flight with the real PX4 in the loop: ``sitl run --autopilot px4`` at the
    validated speed on the flight's scenario (written to ``work/scenario.toml``), the
    mission flown against it from this process. The CPU time of the row is the mission's
    only (PX4 and the simulator run in their own processes)."""
    from companion.cli.mission import fly_pickup
    from sitl.hil.vehicle import VALIDATED_SPEED
    from sitl.px4_sitl.launcher import PX4_SITL_DIR_ENV, Px4Build
    from sitl.vehicle.launch import start_sitl

    build = Px4Build.from_env()  # the campaign's --px4-dir, set for its workers
    if build is None:
        raise RuntimeError(f"a px4 flight needs the PX4 SITL build: set {PX4_SITL_DIR_ENV}")
    config = work / "scenario.toml"
    config.write_text(tomlkit.dumps(document), encoding="utf-8")
    extra = ["--seed", str(flight.seed), "--navigation", "mocap"]
    fault = flight.fault
    at = None  # the start, as sitl run's options take it (faults that have one)
    if fault.at_phase is not None:
        at = f"{fault.at_phase}+{fault.offset_s or 0.0:g}"
    elif fault.at_s is not None:
        at = f"{fault.at_s:g}"
    if fault.kind == "servo_silent":
        extra += ["--servo-silent", f"{fault.servo_id}@{at}"]
    if fault.kind == "servo_error":
        extra += ["--servo-error", f"{fault.servo_id}:{fault.error}@{at}"]
    if fault.kind == "servo_reboot":
        extra += ["--servo-reboot", f"{fault.servo_id}:{fault.boot_s:g}@{at}"]
    if fault.kind == "link_cut":
        extra += ["--link-cut", f"{fault.duration_s:g}@{at}"]
    if fault.kind == "link_latency":
        extra += ["--link-latency", f"{fault.delay_s:g}:{fault.duration_s:g}@{at}"]
    if fault.kind == "pilot_takeover":
        extra += ["--pilot-takeover", f"{fault.mode}@{at}"]
    sitl = start_sitl(
        config,
        *extra,
        speed=VALIDATED_SPEED,
        truth_log=work / "truth.jsonl",
        px4_dir=build.root,
        px4_log=work / "px4" if keep else None,
    )
    try:
        return asyncio.run(
            fly_pickup(
                normally_scheduled(scenario),
                f"udpin://127.0.0.1:{sitl.onboard_port}",
                sitl.arm_bus,
                plan,
                flight.controller,  # type: ignore[arg-type]
                work,
                figures=keep,
                mcap=keep,
            )
        )
    finally:
        sitl.stop()

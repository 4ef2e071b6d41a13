"""The default pickup on simulated time: how fast, and where the time goes.

Flies ``sitl demo --clock virtual``'s flight (``sitl.vehicle.virtual_flight.fly_virtual``, no
figures) ``--flights`` times in this process, one core, and prints per flight the
simulated duration, the wall and CPU time, the real-time factor (simulated / wall), the
flight's own (``flight_sim_s`` / ``flight_wall_s`` of its summary: first plant step to the
last) and the pickups per hour per core (3600 / CPU seconds per pickup); then the split of
the wall time between the simulated vehicle's steps, the servo bus's answers and the rest
(the companion, its links and the event loop), and the first flight part by part (the
vehicle's steps, the world's within them, the truth plant's with the joint servos, the
PX4 imitation's estimates, commander and telemetry, the servo emulator's answers,
pymavlink's encoding and decoding on both sides, the
flight log's CSV rows and MCAP messages, the control cycles and steps) against the wall
time a pickup at 30x real time may take. ``--profile`` adds cProfile's 25 most expensive
functions (the profile itself slows the flight down about twice). ``--write`` puts the
table in ``docs/virtual_speed.md`` with the machine and the commit::

    python benchmarks/bench_virtual_flight.py --flights 3 --write
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import platform
import pstats
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from checkout import this_commit
from pymavlink.dialects.v20 import common as mavlink2

import companion.link.mavlink as companion_link
from companion.cli.mission import plan_for
from companion.control.flight import FlightControl
from companion.logs.flightlog import FlightLogWriter
from companion.logs.mcap_log import McapLogWriter
from companion.mission.cycle import ControlCycle
from sitl.physics.plant import TruthPlant
from sitl.px4.vehicle import Px4Vehicle
from sitl.scenario import load_scenario
from sitl.servo.memory_bus import MemoryServoBus
from sitl.vehicle.navigation import Navigation
from sitl.vehicle.options import RunOptions
from sitl.vehicle.runner import SitlVehicle
from sitl.vehicle.virtual_flight import fly_virtual
from sitl.vehicle.world import World

ROOT = Path(__file__).resolve().parent.parent
PLACE_AT = (-1.0, 0.5, 0.05)


class Timed:
    """Wall time [s] and calls of methods, wrapped around them while in the ``with``.

    ``parts`` maps a label to ``(class or module, name)``; a method called inside another
    timed one counts in both (the parts are not a partition of the flight).
    """

    def __init__(self, parts: dict[str, tuple[object, str]]) -> None:
        self.seconds = dict.fromkeys(parts, 0.0)
        self.calls = dict.fromkeys(parts, 0)
        self._parts = parts
        self._originals = {label: getattr(cls, name) for label, (cls, name) in parts.items()}

    def __enter__(self) -> Timed:
        for label, (cls, name) in self._parts.items():
            setattr(cls, name, self._timed(label, self._originals[label]))
        return self

    def _timed(self, label: str, method: Callable[..., Any]) -> Callable[..., Any]:
        seconds, calls, clock = self.seconds, self.calls, time.perf_counter

        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = clock()
            try:
                return method(*args, **kwargs)
            finally:
                seconds[label] += clock() - t0
                calls[label] += 1

        return timed

    def __exit__(self, *exc: object) -> None:
        for label, (cls, name) in self._parts.items():
            setattr(cls, name, self._originals[label])


VEHICLE = "vehicle steps (SitlVehicle.step_until: a step, and the quiet ones after it)"
WORLD_STEPS = "world steps (World.advance: the servos, the plant, ground and payload)"
PARTS: dict[str, tuple[object, str]] = {
    VEHICLE: (SitlVehicle, "step_until"),
    "servo bus answers": (SitlVehicle, "serve"),
    "the vehicle's full steps (SitlVehicle.step: messages, estimate, control, telemetry)": (
        SitlVehicle,
        "step",
    ),
    WORLD_STEPS: (World, "advance"),
    "truth plant steps (and the joint servos)": (TruthPlant, "advance_coupled"),
    "the imitation's estimates (Navigation.measure, at its outputs)": (Navigation, "measure"),
    "the imitation's commander (Px4Vehicle.control, when it may decide)": (
        Px4Vehicle,
        "control",
    ),
    "the imitation's telemetry (Px4Vehicle.telemetry, when due)": (Px4Vehicle, "telemetry"),
    "the servo emulator's answers (MemoryServoBus.serve, with instructions waiting)": (
        MemoryServoBus,
        "serve",
    ),
    "MAVLink framing and CRC (pymavlink _pack, both sides)": (mavlink2.MAVLink_message, "_pack"),
    "MAVLink decoding (pymavlink parse_buffer, both sides)": (mavlink2.MAVLink, "parse_buffer"),
    "the companion's ODOMETRY frames (cycle_codec.odometry_frame, without pymavlink)": (
        companion_link,
        "odometry_frame",
    ),
    "flight log rows (FlightLogWriter.commit: the row in, and its block when full)": (
        FlightLogWriter,
        "commit",
    ),
    "flight log MCAP blocks handed over (McapLogWriter.write_block; its thread not timed)": (
        McapLogWriter,
        "write_block",
    ),
    "control cycles (ControlCycle.run: sense, control, send, log)": (ControlCycle, "run"),
    "control steps (FlightControl.step)": (FlightControl, "step"),
}
"""What :func:`floor` reports: the simulation's own parts (the two first are the
split of the table), and the fixed costs of the flight code's bytes and logs."""


def fly_once(seed: int, work: Path, profile: cProfile.Profile | None) -> dict[str, float]:
    scenario = load_scenario(ROOT / "configs" / "sitl_pickup.toml")
    assert scenario.world is not None and scenario.world.payload_position_m is not None
    plan = plan_for(scenario.beliefs, scenario.world.payload_position_m, PLACE_AT, 1.5)
    out = work / f"seed-{seed}"
    with Timed(PARTS) as timed:
        wall0, cpu0 = time.perf_counter(), time.process_time()
        if profile is not None:
            profile.enable()
        report, failure = fly_virtual(scenario, plan, out, RunOptions(seed=seed), figures=False)
        if profile is not None:
            profile.disable()
        wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
    steps = timed.calls[WORLD_STEPS]
    sim_s = steps * 1e-3
    summary = json.loads((out / "summary.json").read_text())
    parts = {f"{label} [s]": seconds for label, seconds in timed.seconds.items()}
    parts |= {f"{label} [calls]": float(calls) for label, calls in timed.calls.items()}
    return {
        "seed": seed,
        "completed": float(failure is None and report.completed),
        "sim_s": sim_s,
        "wall_s": wall_s,
        "cpu_s": cpu_s,
        "factor": sim_s / wall_s,
        "flight_factor": summary["flight_sim_s"] / summary["flight_wall_s"],
        "per_hour": 3600.0 / cpu_s,
        "step_share": timed.seconds[VEHICLE] / wall_s,
        "serve_share": timed.seconds["servo bus answers"] / wall_s,
        "step_us": timed.seconds[VEHICLE] / max(steps, 1) * 1e6,
        "cycles": float(report.control_cycles),
        **parts,
    }


def table(runs: list[dict[str, float]]) -> str:
    lines = [
        "# The default pickup on simulated time: speed",
        "",
        f"Written by `benchmarks/bench_virtual_flight.py` on {platform.node()} "
        f"({os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the end, Python "
        f"{platform.python_version()}), commit {this_commit()}. One process, one core; the "
        "flight without figures (`sitl.vehicle.virtual_flight.fly_virtual`).",
        "",
        "| seed | completed | simulated [s] | wall [s] | CPU [s] | real-time factor "
        "| flight's real-time factor | pickups / hour / core | vehicle steps [% wall] "
        "| step [us] | servo bus [% wall] | companion and loop [% wall] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        rest = 1.0 - r["step_share"] - r["serve_share"]
        lines.append(
            f"| {r['seed']:.0f} | {'yes' if r['completed'] else 'no'} | {r['sim_s']:.1f} | "
            f"{r['wall_s']:.2f} | {r['cpu_s']:.2f} | {r['factor']:.1f}x | "
            f"{r['flight_factor']:.1f}x | {r['per_hour']:.0f} | "
            f"{100 * r['step_share']:.0f} | {r['step_us']:.1f} | {100 * r['serve_share']:.0f} | "
            f"{100 * rest:.0f} |"
        )
    factors = [r["factor"] for r in runs]
    lines += [
        "",
        f"Real-time factor: median {statistics.median(factors):.1f}x, best {max(factors):.1f}x.",
        "",
        *floor(runs[0]),
    ]
    return "\n".join(lines) + "\n"


def floor(run: dict[str, float], factor: float = 30.0) -> list[str]:
    """Where seed ``run``'s wall time went, part by part (:data:`PARTS`), beside the wall
    time a ``factor`` x real-time pickup may take in all (its budget)."""
    budget_s = run["sim_s"] / factor
    lines = [
        f"## Seed {run['seed']:.0f}, part by part, against a {factor:g}x budget",
        "",
        f"A pickup of {run['sim_s']:.1f} simulated seconds at {factor:g}x real time has "
        f"{budget_s:.2f} s of wall time in all. Each part's wall time is measured around its "
        "calls in the same flight (a part called inside another counts in both; the timers "
        "add about 0.3 us a call). The flight writes the demo's logs (CSV and MCAP).",
        "",
        f"| part | calls | wall [s] | per call [us] | % of the flight's wall | % of the "
        f"{factor:g}x budget |",
        "|---|---|---|---|---|---|",
    ]
    for label in PARTS:
        seconds, calls = run[f"{label} [s]"], run[f"{label} [calls]"]
        lines.append(
            f"| {label} | {calls:.0f} | {seconds:.2f} | {seconds / max(calls, 1.0) * 1e6:.1f} | "
            f"{100 * seconds / run['wall_s']:.0f} | {100 * seconds / budget_s:.0f} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flights", type=int, default=3, help="flights, seeds 0..N-1")
    parser.add_argument("--profile", action="store_true", help="cProfile the first flight")
    parser.add_argument("--write", action="store_true", help="write docs/virtual_speed.md")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-virtual-"))
    runs = []
    try:
        for seed in range(args.flights):
            profile = cProfile.Profile() if args.profile and seed == 0 else None
            runs.append(fly_once(seed, work, profile))
            print({k: round(v, 3) for k, v in runs[-1].items() if "[" not in k}, flush=True)
            if profile is not None:
                text = io.StringIO()
                pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(25)
                print(text.getvalue())
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if args.profile:
        runs = runs[1:] or runs  # the profiled flight's times are not the flight's
    text = table(runs)
    print(text)
    if args.write:
        (ROOT / "docs" / "virtual_speed.md").write_text(text)


if __name__ == "__main__":
    main()

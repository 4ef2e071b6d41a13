"""The default pickup on simulated time: how fast, and where the time goes.

Flies ``sitl demo --clock virtual``'s flight (``sitl.vehicle.virtual_flight.fly_virtual``, no
figures) ``--flights`` times in this process, one core, and prints per flight the
simulated duration, the wall and CPU time, the real-time factor (simulated / wall) and the
pickups per hour per core (3600 / CPU seconds per pickup); then the split of the wall time
between the simulated vehicle's steps, the servo bus's answers and the rest (the
companion, its links and the event loop). ``--profile`` adds cProfile's 25 most expensive
functions (the profile itself slows the flight down about twice). ``--write`` puts the
table in ``docs/virtual_speed.md`` with the machine and the commit::

    python benchmarks/bench_virtual_flight.py --flights 3 --write
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import platform
import pstats
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from checkout import this_commit

from companion.cli.mission import plan_for
from sitl.scenario import load_scenario
from sitl.vehicle.runner import RunOptions, SitlVehicle
from sitl.vehicle.virtual_flight import fly_virtual

ROOT = Path(__file__).resolve().parent.parent
PLACE_AT = (-1.0, 0.5, 0.05)


class Split:
    """Wall time inside SitlVehicle.step and SitlVehicle.serve [s], wrapped around them."""

    def __init__(self) -> None:
        self.step_s = self.serve_s = 0.0
        self.steps = 0
        self._step, self._serve = SitlVehicle.step, SitlVehicle.serve

    def __enter__(self) -> Split:
        step, serve, split = self._step, self._serve, self

        def timed_step(vehicle: SitlVehicle) -> None:
            t0 = time.perf_counter()
            step(vehicle)
            split.step_s += time.perf_counter() - t0
            split.steps += 1

        def timed_serve(vehicle: SitlVehicle) -> None:
            t0 = time.perf_counter()
            serve(vehicle)
            split.serve_s += time.perf_counter() - t0

        SitlVehicle.step, SitlVehicle.serve = timed_step, timed_serve  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: object) -> None:
        SitlVehicle.step, SitlVehicle.serve = self._step, self._serve  # type: ignore[method-assign]


def fly_once(seed: int, work: Path, profile: cProfile.Profile | None) -> dict[str, float]:
    scenario = load_scenario(ROOT / "configs" / "sitl_pickup.toml")
    assert scenario.world is not None and scenario.world.payload_position_m is not None
    plan = plan_for(scenario.beliefs, scenario.world.payload_position_m, PLACE_AT, 1.5)
    out = work / f"seed-{seed}"
    with Split() as split:
        wall0, cpu0 = time.perf_counter(), time.process_time()
        if profile is not None:
            profile.enable()
        report, failure = fly_virtual(scenario, plan, out, RunOptions(seed=seed), figures=False)
        if profile is not None:
            profile.disable()
        wall_s, cpu_s = time.perf_counter() - wall0, time.process_time() - cpu0
    sim_s = split.steps * 1e-3
    return {
        "seed": seed,
        "completed": float(failure is None and report.completed),
        "sim_s": sim_s,
        "wall_s": wall_s,
        "cpu_s": cpu_s,
        "factor": sim_s / wall_s,
        "per_hour": 3600.0 / cpu_s,
        "step_share": split.step_s / wall_s,
        "serve_share": split.serve_s / wall_s,
        "step_us": split.step_s / max(split.steps, 1) * 1e6,
        "cycles": float(report.control_cycles),
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
        "| pickups / hour / core | vehicle steps [% wall] | step [us] | servo bus [% wall] "
        "| companion and loop [% wall] |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        rest = 1.0 - r["step_share"] - r["serve_share"]
        lines.append(
            f"| {r['seed']:.0f} | {'yes' if r['completed'] else 'no'} | {r['sim_s']:.1f} | "
            f"{r['wall_s']:.2f} | {r['cpu_s']:.2f} | {r['factor']:.1f}x | {r['per_hour']:.0f} | "
            f"{100 * r['step_share']:.0f} | {r['step_us']:.1f} | {100 * r['serve_share']:.0f} | "
            f"{100 * rest:.0f} |"
        )
    factors = [r["factor"] for r in runs]
    lines += [
        "",
        f"Real-time factor: median {statistics.median(factors):.1f}x, best {max(factors):.1f}x.",
    ]
    return "\n".join(lines) + "\n"


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
            print({k: round(v, 3) for k, v in runs[-1].items()}, flush=True)
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

"""The whole control cycle by part: sense, filters, step, setpoint, log (p50 / p99 [us]).

Replays the shipped recording of the cycle's inputs (``companion/mission/cycle_inputs.npz``,
750 cycles of the default virtual pickup from the grasp on) through the flight's own parts,
as ``companion check --timing`` does (:func:`companion.mission.timing_check.check_timing`,
paced at the control rate, under the flight loop's scheduling), ``--repeat`` times, and
prints per part the median and 99th percentile [us] over all cycles (wall time under the
flight loop's scheduling; the summary.json of a demo has the cycle's CPU time):

- ``sense``: the cycle's ODOMETRY read from its frame and decoded into the pose;
- ``filters``: the state filter's calls and the battery voltage;
- ``step``: ``FlightControl.step`` (the compiled step and what runs around it);
- ``setpoint``: SET_ATTITUDE_TARGET built and encoded;
- ``log``: the cycle's row into ``flight.csv`` / ``flight.mcap`` (its blocks written);
- ``cycle``: all of them.

Numbers only, no pass/fail. ``--write`` puts the table in ``docs/cycle_parts.md`` with the
machine and the commit (run it on an idle machine).

Run: ``python benchmarks/bench_cycle_parts.py [--config configs/sitl_pickup.toml]
[--rate 125] [--repeat 4] [--write]``.
"""

from __future__ import annotations

import argparse
import os
import platform
from pathlib import Path

import numpy as np
from checkout import this_commit

from companion.config import load_config
from companion.mission.timing_check import PARTS, check_timing

ROOT = Path(__file__).resolve().parent.parent


def table(times: dict[str, np.ndarray]) -> list[str]:
    """The part table in Markdown."""
    lines = ["| part | p50 [us] | p99 [us] |", "|---|---:|---:|"]
    for part in PARTS:
        values = times[part]
        lines.append(
            f"| {part} | {np.percentile(values, 50):.1f} | {np.percentile(values, 99):.1f} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "sitl_pickup.toml")
    parser.add_argument("--rate", type=float, default=125.0, help="control rate [Hz]")
    parser.add_argument("--repeat", type=int, default=4, help="replays of the recording")
    parser.add_argument("--write", action="store_true", help="write docs/cycle_parts.md")
    args = parser.parse_args()
    config = load_config(args.config)
    runs = []
    cycles = 0
    for _ in range(args.repeat):
        result = check_timing(config, args.rate)
        runs.append(result.times_us)
        cycles += len(result.times_us["cycle"])
    times = {part: np.concatenate([run[part] for run in runs]) for part in PARTS}
    lines = table(times)
    head = (
        f"{cycles} cycles ({args.repeat} replays of the recording at {args.rate:g} Hz, "
        f"{result.scheduling}), {args.config.name}; {platform.processor() or platform.machine()}"
        f", {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}"
    )
    print(head)
    print("\n".join(lines))
    if args.write:
        page = [
            "# The control cycle by part",
            "",
            "Written by `benchmarks/bench_cycle_parts.py` (see its docstring for the parts) at "
            f"{this_commit()}: {head}.",
            "",
            *lines,
            "",
        ]
        (ROOT / "docs" / "cycle_parts.md").write_text("\n".join(page))


if __name__ == "__main__":
    main()

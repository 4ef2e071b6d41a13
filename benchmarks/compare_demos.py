"""The default pickup flown several ways over many seeds, and where each way's flights lie
against the first way's seed-to-seed spread.

Presets:

- ``clocks``: ``sitl demo --clock wall`` and ``sitl demo --clock virtual`` (the simulated
  clock must give the wall clock's results); writes ``docs/clocks.md``;
- ``px4-speed``: ``sitl demo --autopilot px4`` at ``--speed`` 1, 2 and 3 (PX4 in the loop
  faster than real time, with the companion on the wall clock beside it: the highest
  speed whose results stay within speed 1's spread); needs ``PX4_SITL_DIR``; writes
  ``docs/px4_speed.md``.

For each seed every way is run as a user runs it, one after the other, alone on the
machine, and judged from what it writes: the estimate's mass and centre-of-mass errors
against the truth, the object's horizontal distance from the place point (truth log), the
carry RMS (flight log, lift to place), the wall time of the command and the simulated
duration. Writes the table (with the machine and the commit) and prints it::

    python benchmarks/compare_demos.py --preset clocks --seeds 10
    PX4_SITL_DIR=../shared/px4-sitl python benchmarks/compare_demos.py --preset px4-speed --seeds 4
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
from checkout import this_commit  # noqa: E402
from flight_checks import carry_rms_m  # noqa: E402

from companion.logs.flightlog import read_flight_log  # noqa: E402

PLACE_AT = (-1.0, 0.5)
TRUE_MASS_KG, TRUE_COM_M = 0.25, 0.15
METRICS = ("mass_err_pct", "com_err_pct", "placed_m", "carry_rms_cm")
PRESETS: dict[str, tuple[str, str, dict[str, tuple[str, ...]]]] = {
    "clocks": (
        "The default pickup on the wall clock and on simulated time",
        "clocks.md",
        {"wall": ("--clock", "wall"), "virtual": ("--clock", "virtual")},
    ),
    "px4-speed": (
        "The default pickup with PX4 in the loop, faster than real time",
        "px4_speed.md",
        {f"px4 {speed}x": ("--autopilot", "px4", "--speed", speed) for speed in ("1", "2", "3")},
    ),
}
"""Preset -> (title, file in docs/, way -> its ``sitl demo`` options)."""


def fly(options: tuple[str, ...], seed: int, out: Path) -> dict[str, float]:
    """One ``sitl demo`` and its figures."""
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", "from sitl.entry import main; main()", "demo", *options,
         "--seed", str(seed), "--out", str(out)],
        capture_output=True, text=True, cwd=out.parent,
    )  # fmt: skip
    wall_s = time.perf_counter() - t0
    if done.returncode != 0:
        lines = (done.stderr or done.stdout).strip().splitlines()
        print(f"failed (exit {done.returncode}): {lines[-1] if lines else ''}", flush=True)
        return {"failed": 1.0, "wall_s": wall_s}
    summary = json.loads((out / "summary.json").read_text())
    last = json.loads((out / "truth.jsonl").read_text().splitlines()[-1])
    log = read_flight_log(out / "flight.csv")
    return {
        "failed": 0.0,
        "mass_err_pct": 100 * (summary["payload_mass_kg"] - TRUE_MASS_KG) / TRUE_MASS_KG,
        "com_err_pct": 100 * (summary["payload_com_along_link2_m"] - TRUE_COM_M) / TRUE_COM_M,
        "placed_m": math.dist(last["object_position_m"][:2], PLACE_AT),
        "carry_rms_cm": 100 * carry_rms_m(log.columns),
        "wall_s": wall_s,
        "sim_s": float(log["t_vehicle_s"][-1]),
    }


def _spread(values: list[float]) -> str:
    if not values:
        return "none completed"
    sd = statistics.stdev(values) if len(values) > 1 else math.nan
    return f"{statistics.fmean(values):.3f} ± {sd:.3f} ({min(values):.3f}..{max(values):.3f})"


def table(
    title: str, ways: dict[str, tuple[str, ...]], runs: dict[str, list[dict[str, float]]],
    seeds: list[int],
) -> str:  # fmt: skip
    names = list(ways)
    reference = names[0]
    lines = [
        f"# {title} ({len(seeds)} seeds)",
        "",
        f"Written by `benchmarks/compare_demos.py` on {platform.node()} "
        f"({os.cpu_count()} cores, Python {platform.python_version()}), commit {this_commit()}.",
        "Each seed S flown by "
        + ", ".join(f"`sitl demo {' '.join(o)} --seed S`" for o in ways.values())
        + ", one after the other; errors against the simulator's truth.",
        "",
        "| seed | way | mass error [%] | centre-of-mass error [%] | placed from point [m] "
        "| carry RMS [cm] | simulated [s] | wall [s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for i, seed in enumerate(seeds):
        for name in names:
            r = runs[name][i]
            if r["failed"]:
                lines.append(f"| {seed} | {name} | failed | | | | | {r['wall_s']:.1f} |")
                continue
            lines.append(
                f"| {seed} | {name} | {r['mass_err_pct']:+.2f} | {r['com_err_pct']:+.2f} | "
                f"{r['placed_m']:.3f} | {r['carry_rms_cm']:.2f} | {r['sim_s']:.1f} | "
                f"{r['wall_s']:.1f} |"
            )
    lines += [
        "",
        "Over the seeds (flights that completed): mean ± standard deviation (min..max); the "
        f"last columns: each way's mean minus {reference}'s, in {reference}'s standard "
        "deviations.",
        "",
        "| metric | " + " | ".join(names) + " | "
        + " | ".join(f"{n} vs {reference}" for n in names[1:]) + " |",
        "|---|" + "---|" * (2 * len(names) - 1),
    ]  # fmt: skip
    for metric in METRICS:
        values = {n: [r[metric] for r in runs[n] if not r["failed"]] for n in names}
        ref = values[reference]
        ref_sd = statistics.stdev(ref) if len(ref) > 1 else math.nan
        shifts = [
            f"{(statistics.fmean(values[n]) - statistics.fmean(ref)) / ref_sd:+.2f}"
            if values[n] and ref else "n/a"
            for n in names[1:]
        ]  # fmt: skip
        cells = [_spread(values[n]) for n in names]
        lines.append(f"| {metric} | " + " | ".join(cells + shifts) + " |")
    lines.append("")
    for name in names:
        done = [r for r in runs[name] if not r["failed"]]
        factor = statistics.fmean(r["sim_s"] / r["wall_s"] for r in done) if done else math.nan
        lines.append(
            f"- {name}: {len(done)} of {len(runs[name])} completed; simulated / wall time of "
            f"the whole command (start-up and figures included): {factor:.1f}x"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=sorted(PRESETS), default="clocks")
    parser.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1")
    args = parser.parse_args()
    title, doc, ways = PRESETS[args.preset]
    seeds = list(range(args.seeds))
    runs: dict[str, list[dict[str, float]]] = {name: [] for name in ways}
    work = Path(tempfile.mkdtemp(prefix="demos-"))
    try:
        for seed in seeds:
            for name, options in ways.items():
                out = work / f"{name.replace(' ', '-')}-{seed}"
                runs[name].append(fly(options, seed, out))
                print(name, seed, runs[name][-1], flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    text = table(title, ways, runs, seeds)
    (ROOT / "docs" / doc).write_text(text)
    print(text)


if __name__ == "__main__":
    main()

"""The default pickup on both clocks: ``sitl demo --clock wall`` and ``--clock virtual`` over
many seeds, and where the virtual flights lie against the wall-clock flights' spread.

For each seed both commands are run as a user runs them (wall first, alone on the machine)
and judged from what they write: the estimate's mass and centre-of-mass errors against the
truth, the object's horizontal distance from the place point (truth log), the carry RMS
(flight log, lift to place), the wall time of the command and the simulated duration.
Writes the table to ``docs/clocks.md`` (with the machine and the commit) and prints it::

    python benchmarks/compare_clocks.py --seeds 10
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
from flight_checks import carry_rms_m  # noqa: E402

from companion.flightlog import read_flight_log  # noqa: E402

PLACE_AT = (-1.0, 0.5)
TRUE_MASS_KG, TRUE_COM_M = 0.25, 0.15
METRICS = ("mass_err_pct", "com_err_pct", "placed_m", "carry_rms_cm")


def fly(clock: str, seed: int, out: Path) -> dict[str, float]:
    """One ``sitl demo`` and its figures."""
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", "from sitl.entry import main; main()", "demo", "--clock", clock,
         "--seed", str(seed), "--out", str(out)],
        capture_output=True, text=True, cwd=out.parent,
    )  # fmt: skip
    wall_s = time.perf_counter() - t0
    if done.returncode != 0:
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


def _commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT,
            check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def table(runs: dict[str, list[dict[str, float]]], seeds: list[int]) -> str:
    lines = [
        f"# The default pickup on the wall clock and on simulated time ({len(seeds)} seeds)",
        "",
        f"Written by `benchmarks/compare_clocks.py` on {platform.node()} "
        f"({os.cpu_count()} cores, Python {platform.python_version()}), commit {_commit()}.",
        "Each seed flown by `sitl demo --clock wall --seed S` and `sitl demo --clock virtual "
        "--seed S`; errors against the simulator's truth.",
        "",
        "| seed | clock | mass error [%] | centre-of-mass error [%] | placed from point [m] "
        "| carry RMS [cm] | simulated [s] | wall [s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for i, seed in enumerate(seeds):
        for clock in ("wall", "virtual"):
            r = runs[clock][i]
            if r["failed"]:
                lines.append(f"| {seed} | {clock} | failed | | | | | {r['wall_s']:.1f} |")
                continue
            lines.append(
                f"| {seed} | {clock} | {r['mass_err_pct']:+.2f} | {r['com_err_pct']:+.2f} | "
                f"{r['placed_m']:.3f} | {r['carry_rms_cm']:.2f} | {r['sim_s']:.1f} | "
                f"{r['wall_s']:.1f} |"
            )
    lines += [
        "",
        "Over the seeds (flights that completed): mean, standard deviation, min..max.",
        "",
        "| metric | wall clock | simulated time | difference of means / wall sd |",
        "|---|---|---|---|",
    ]
    for metric in METRICS:
        cells = []
        values = {}
        for clock in ("wall", "virtual"):
            v = [r[metric] for r in runs[clock] if not r["failed"]]
            values[clock] = v
            sd = statistics.stdev(v) if len(v) > 1 else math.nan
            cells.append(f"{statistics.fmean(v):.3f} ± {sd:.3f} ({min(v):.3f}..{max(v):.3f})")
        wall_sd = statistics.stdev(values["wall"]) if len(values["wall"]) > 1 else math.nan
        diff = statistics.fmean(values["virtual"]) - statistics.fmean(values["wall"])
        lines.append(f"| {metric} | {cells[0]} | {cells[1]} | {diff / wall_sd:+.2f} |")
    for clock in ("wall", "virtual"):
        done = [r for r in runs[clock] if not r["failed"]]
        factor = statistics.fmean(r["sim_s"] / r["wall_s"] for r in done)
        lines.append(
            f"\n{clock}: {len(done)} of {len(runs[clock])} completed; simulated / wall time of "
            f"the whole command (start-up and figures included): {factor:.1f}x"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "clocks.md")
    args = parser.parse_args()
    seeds = list(range(args.seeds))
    runs: dict[str, list[dict[str, float]]] = {"wall": [], "virtual": []}
    work = Path(tempfile.mkdtemp(prefix="clocks-"))
    try:
        for seed in seeds:
            for clock in ("wall", "virtual"):
                runs[clock].append(fly(clock, seed, work / f"{clock}-{seed}"))
                print(clock, seed, runs[clock][-1], flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    text = table(runs, seeds)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()

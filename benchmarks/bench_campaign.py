"""Campaigns on the local and the Ray engine: pickups per hour on this machine and each
engine's cost.

Runs ``sitl campaign SPEC --out TMP --workers W --limit N --engine E`` (the command a user
runs, in a subprocess; Ray on a local runtime of W CPUs) and reads its results table: the
pickups per hour the campaign reached (flights over its wall time), the per-flight overhead
of the engine (the worker slots' time not spent inside a flight: starting the workers,
handing flights over, committing rows, writing the report; ``(wall x workers - sum of the
flights' wall time) / flights``), and the pickups per hour per core the flights themselves
need (3600 / CPU seconds per flight). From those it estimates the whole spec's duration
here, and on paper on a 1,000-core Ray cluster. ``--write`` puts the table in
``docs/campaign.md`` with the machine and the commit::

    python benchmarks/bench_campaign.py --limit 8 --workers 2 --engines local,ray --write
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import platform
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from checkout import this_commit

from sitl.campaign.flights import expand
from sitl.campaign.spec import load_spec

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SPEC = ROOT / "configs" / "campaigns" / "envelope.toml"


def run_campaign(
    spec: Path, workers: int, limit: int, out: Path, engine: str
) -> dict[str, float | str]:
    """Fly the first ``limit`` flights of ``spec`` on ``workers`` processes (or a local Ray
    runtime of ``workers`` CPUs); the figures."""
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "from sitl.cli import main; main()", "campaign", str(spec),
         "--out", str(out), "--workers", str(workers), "--limit", str(limit),
         "--engine", engine],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    with sqlite3.connect(out / "results.sqlite") as db:
        rows = db.execute("SELECT wall_s, cpu_s, completed, sim_s FROM flights").fetchall()
    flights = len(rows)
    flight_wall = sum(r[0] for r in rows)
    cpu = [r[1] for r in rows]
    slots = min(workers, flights)
    return {
        "engine": engine,
        "flights": flights,
        "workers": slots,
        "completed": sum(1 for r in rows if r[2]),
        "wall_s": wall,
        "per_hour": 3600.0 * flights / wall,
        "overhead_s": (wall * slots - flight_wall) / flights,
        "flight_wall_s": flight_wall / flights,
        "flight_cpu_s": statistics.mean(cpu),
        "flight_cpu_max_s": max(cpu),
        "per_hour_per_core": 3600.0 / statistics.mean(cpu),
        "sim_s": statistics.mean(r[3] for r in rows if r[3] is not None),
    }


def _ready(conn) -> None:
    import sitl.campaign.fly  # noqa: F401  (what a worker imports before its first flight)

    conn.send(True)


def worker_start_s() -> float:
    """Time to start one worker process (spawn) and import the simulator in it [s]."""
    context = multiprocessing.get_context("spawn")
    ours, theirs = context.Pipe()
    t0 = time.perf_counter()
    process = context.Process(target=_ready, args=(theirs,))
    process.start()
    ours.recv()
    elapsed = time.perf_counter() - t0
    process.join()
    return elapsed


def store_commit_ms(rows: int = 200) -> float:
    """Mean time to commit one row to a results table [ms] (its own transaction)."""
    with tempfile.TemporaryDirectory() as tmp:
        db = sqlite3.connect(Path(tmp) / "t.sqlite", isolation_level=None)
        db.execute("CREATE TABLE flights (flight_id TEXT PRIMARY KEY, value REAL)")
        t0 = time.perf_counter()
        for i in range(rows):
            db.execute("INSERT OR IGNORE INTO flights VALUES (?, ?)", (f"{i:016x}", float(i)))
        elapsed = time.perf_counter() - t0
        db.close()
    return 1e3 * elapsed / rows


CLUSTER_CORES = 1000
"""The Ray cluster of the estimate on paper."""


def table(
    spec: Path,
    runs: list[dict[str, Any]],
    expand_ms: float,
    commit_ms: float,
    start_s: float,
) -> str:
    total = len(expand(load_spec(spec), spec))
    name = spec.relative_to(ROOT) if spec.is_relative_to(ROOT) else spec
    first = runs[0]
    rows = [
        f"| {r['engine']} | {r['flights']:.0f} | {r['completed']:.0f} | {r['workers']:.0f} | "
        f"{r['wall_s']:.1f} | {r['per_hour']:.0f} | {r['overhead_s']:.1f} | "
        f"{r['flight_wall_s']:.1f} | {r['flight_cpu_s']:.1f} | "
        f"{r['per_hour_per_core']:.0f} | {r['sim_s']:.0f} |"
        for r in runs
    ]
    estimates = [
        f"At {r['per_hour']:.0f} pickups per hour ({r['engine']}), the whole spec's {total} "
        f"flights take about {total / r['per_hour'] * 60.0:.0f} minutes here at this load."
        for r in runs
    ]
    ray = [r for r in runs if r["engine"] == "ray"]
    cluster = []
    if ray:
        r = ray[0]
        per_flight_s = r["flight_cpu_s"] + r["overhead_s"]
        cluster = [
            "",
            f"On paper, a {CLUSTER_CORES:,}-core Ray cluster of cores as fast as these: each "
            f"of the spec's {total} flights on a core of its own, the spec lasts about as "
            f"long as its longest flight plus the runtime's start (the longest measured here "
            f"took {r['flight_cpu_max_s']:.0f} s of CPU); a study of 30,000 pickups, at "
            f"{per_flight_s:.0f} s per flight (mean CPU time and the Ray engine's overhead "
            f"per flight), about {30000 * per_flight_s / CLUSTER_CORES / 60.0:.0f} minutes "
            f"({CLUSTER_CORES * 3600.0 / per_flight_s:,.0f} pickups per hour), if the "
            "campaign's one writing process keeps up (it commits a row in about "
            f"{commit_ms:.1f} ms: {3600e3 / commit_ms:,.0f} rows per hour).",
        ]
    return "\n".join(
        [
            "# Campaigns on the local and the Ray engine: speed",
            "",
            f"Written by `benchmarks/bench_campaign.py` on {platform.node()} "
            f"({os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the end, "
            f"Python {platform.python_version()}), commit {this_commit()}: `sitl campaign "
            f"{name} --workers {first['workers']:.0f} --limit {first['flights']:.0f} "
            f"--engine ENGINE` (the first {first['flights']:.0f} of its {total} flights; Ray "
            "on a local runtime of as many CPUs), in a subprocess, timed from start to exit "
            "(the report included).",
            "",
            "| engine | flights | completed | workers | wall [s] | pickups / hour | engine "
            "overhead per flight [s] | flight wall [s] | flight CPU [s] | pickups / hour / "
            "core (CPU) | simulated per flight [s] |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
            "",
            "The engine overhead per flight is the worker slots' time outside a flight: "
            "(wall x workers - the flights' wall time) / flights. It holds the workers' start "
            "(a fresh interpreter importing the simulator), handing each flight over a pipe, "
            "committing its row, writing the report, and a slot idle at the end while the "
            "other worker finishes the last flight; a larger campaign spreads the start, the "
            "report and that tail over more flights. On Ray it holds starting the local "
            "runtime (its processes and workers) as well. A flight's wall time above its CPU "
            "time is time it waited for a core.",
            "",
            f"Parts of it measured alone: starting a worker (spawn, importing the simulator) "
            f"{start_s:.1f} s, once per worker; expanding the spec {expand_ms:.1f} ms per "
            f"flight (each draw's scenario validated); committing one row {commit_ms:.2f} ms.",
            "",
            *estimates,
            f"The flights' CPU time bounds an otherwise idle machine at "
            f"{first['workers'] * first['per_hour_per_core']:.0f} pickups per hour on "
            f"{first['workers']:.0f} cores: the spec in about "
            f"{total / (first['workers'] * first['per_hour_per_core']) * 60.0:.0f} minutes.",
            *cluster,
            "",
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=Path, default=DEFAULT_SPEC, help="campaign spec")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--limit", type=int, default=8, help="flights of the spec to fly")
    parser.add_argument(
        "--engines", default="local,ray", help="engines to run, comma-separated (local, ray)"
    )
    parser.add_argument("--write", action="store_true", help="write docs/campaign.md")
    args = parser.parse_args()
    spec = args.spec.resolve()
    t0 = time.perf_counter()
    n = len(expand(load_spec(spec), spec))
    expand_ms = 1e3 * (time.perf_counter() - t0) / n
    runs = []
    for engine in args.engines.split(","):
        with tempfile.TemporaryDirectory(prefix="bench-campaign-") as tmp:
            runs.append(run_campaign(spec, args.workers, args.limit, Path(tmp) / "out", engine))
    text = table(spec, runs, expand_ms, store_commit_ms(), worker_start_s())
    print(text)
    if args.write:
        (ROOT / "docs" / "campaign.md").write_text(text)


if __name__ == "__main__":
    main()

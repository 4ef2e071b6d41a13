"""What the flight log costs the control loop per cycle, writer included.

Writes the same records (a seeded random walk of every field, as a flight's values vary)
two ways and prints, per cycle, the wall time of the log call the control cycle makes
(median, 99th percentile, maximum) and the process CPU time per cycle over the whole run
(every thread of the process: foxglove-sdk's writer included), and the files' sizes:

- ``csv``: :class:`companion.logs.flightlog.FlightLogWriter` alone (the CSV files);
- ``csv + mcap``: :class:`companion.logs.mcap_log.FlightLogWithMcap`, what the app runs.

A call fills one row of the block of columns (:mod:`companion.logs.columns`); the call that
fills the block writes it to ``flight.columns`` and hands it to the MCAP's writer thread
(which encodes its cycles' messages and writes them, one chunk): the maximum. The CPU per
cycle, the writer thread's included, is the log's share of the control cycle; the close
writes ``flight.csv`` and ``flight.timing.csv`` from the columns after the flight.
``--write`` puts the table in ``docs/log_speed.md`` with the machine and the commit.

Run: ``python benchmarks/bench_mcap_log.py [--cycles N] [--write]``.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
from checkout import this_commit

from companion.control.setpoints import AttitudeThrustSetpoint
from companion.logs.flightlog import CycleRecord, FlightLogWriter
from companion.logs.mcap_log import ArmGeometry, FlightLogWithMcap

GEOMETRY = ArmGeometry((0.0, 0.0, -0.08), 0.2, 0.2)
PERIOD_S = 0.008
"""A 125 Hz control loop's period [s]."""
ROOT = Path(__file__).resolve().parent.parent


def records(n: int, seed: int = 1) -> list[CycleRecord]:
    """``n`` cycles of a random walk in every field."""
    rng = np.random.default_rng(seed)

    def walk(size: int, scale: float) -> np.ndarray:
        return np.cumsum(rng.normal(0.0, scale, (n, size)), axis=0)

    q, q_dot, q_ddot, q_d = walk(8, 1e-3), walk(8, 1e-2), walk(8, 1e-1), walk(8, 1e-3)
    theta = 0.1 + np.abs(walk(3, 1e-4))
    sp = walk(4, 1e-3)
    servo = walk(6, 1e-3)
    out = []
    for k in range(n):
        out.append(
            CycleRecord(
                t_vehicle_s=10.0 + k * PERIOD_S,
                q=q[k],
                q_dot=q_dot[k],
                q_ddot=q_ddot[k],
                q_d=q_d[k],
                theta_hat=theta[k],
                theta_excitation=float(abs(sp[k, 0])),
                theta_spread=float(abs(sp[k, 1])),
                theta_confident=bool(k % 2),
                theta_frozen=False,
                thrust_scale_hat=1.0 + float(sp[k, 2]),
                tau=q_ddot[k],
                setpoint=AttitudeThrustSetpoint(
                    float(sp[k, 0]),
                    float(sp[k, 1]),
                    float(sp[k, 2]),
                    20.0 + float(sp[k, 3]),
                    0.4,
                    False,
                    False,
                ),
                servo_torque_cmd_n_m=servo[k, :2],
                servo_torque_meas_n_m=servo[k, 2:4],
                servo_position_rad=servo[k, 4:],
                loop_period_ms=PERIOD_S * 1e3,
                setpoint_latency_us=300.0 + float(sp[k, 0]),
                cycle_latency_us=400.0,
                setpoint_cpu_us=200.0,
                px4_mode="OFFBOARD",
                armed=True,
                phase="lift",
                faults=(),
                t_wall_s=1.7e9 + k * PERIOD_S,
            )
        )
    return out


def measure(writer, rows: list[CycleRecord]) -> tuple[np.ndarray, float, float]:
    """Microseconds of each ``writer.write`` call (wall), the process CPU time per call
    over the flight [us], and the process CPU time of the close [s] (the CSV written)."""
    durations = np.empty(len(rows))
    writer.open()
    try:
        cpu0 = time.process_time_ns()
        for k, record in enumerate(rows):
            t0 = time.perf_counter_ns()
            writer.write(record)
            durations[k] = (time.perf_counter_ns() - t0) * 1e-3
        cpu1 = time.process_time_ns()
    finally:
        writer.close()
    cpu2 = time.process_time_ns()
    return durations, (cpu1 - cpu0) * 1e-3 / len(rows), (cpu2 - cpu1) * 1e-9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cycles", type=int, default=10_000, help="cycles per writer")
    parser.add_argument("--write", action="store_true", help="write docs/log_speed.md")
    args = parser.parse_args()
    rows = records(args.cycles)
    lines = [
        f"{args.cycles} cycles per writer (a 125 Hz loop: {args.cycles * PERIOD_S:g} s)",
        "",
        "| writer | call median [us] | call p99 [us] | call max [us] | "
        "process CPU per cycle [us] | close: CSV written [s] | files |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("csv", "csv + mcap"):
            folder = Path(tmp) / name.replace(" + ", "_")
            folder.mkdir()
            log = folder / "flight.csv"
            writer = FlightLogWriter(log) if name == "csv" else FlightLogWithMcap(log, GEOMETRY)
            us, cpu_us, close_s = measure(writer, rows)
            sizes = ", ".join(
                f"{p.name} {p.stat().st_size / 1e6:.2f} MB" for p in sorted(folder.iterdir())
            )
            lines.append(
                f"| {name} | {np.median(us):.1f} | {np.percentile(us, 99):.1f} | "
                f"{us.max():.1f} | {cpu_us:.1f} | {close_s:.2f} | {sizes} |"
            )
    print("\n".join(lines))
    if args.write:
        doc = [
            "# The flight log's cost per control cycle",
            "",
            f"Written by `benchmarks/bench_mcap_log.py` on {platform.node()} "
            f"({platform.machine()}, {os.cpu_count()} cores, Python "
            f"{platform.python_version()}) at commit {this_commit()}. A call fills one row "
            "of the block of columns; the call that fills a block writes it to the columns "
            "file and hands it to the MCAP's writer thread (the maximum). The process CPU "
            "per cycle counts every thread (the MCAP's writer thread and foxglove-sdk's "
            "included): the log's share of the control cycle. The close writes the CSV "
            "files from the columns, after the flight.",
            "",
            *lines,
            "",
        ]
        (ROOT / "docs" / "log_speed.md").write_text("\n".join(doc))


if __name__ == "__main__":
    main()

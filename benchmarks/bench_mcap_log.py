"""What writing ``flight.mcap`` beside ``flight.csv`` costs the control loop per cycle.

Writes the same records (a seeded random walk of every field, as a flight's values vary)
three ways and prints per-cycle microseconds (median, 99th percentile, maximum) of the
log call the control cycle makes, and the files' sizes:

- ``csv``: :class:`companion.logs.flightlog.FlightLogWriter` alone (the CSV log);
- ``mcap``: :class:`companion.logs.mcap_log.McapLogWriter` alone;
- ``csv + mcap``: :class:`companion.logs.mcap_log.FlightLogWithMcap`, what the app runs.

The maximum is a cycle that hands a buffer to the operating system: the CSV's every
``flush_every_rows`` rows, the MCAP's when a chunk is full (compressed then). The log call
comes after the setpoint and the joint torques are sent, so it delays neither; it spends
the cycle's spare time.

Run: ``python benchmarks/bench_mcap_log.py [--cycles N]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from companion.control.setpoints import AttitudeThrustSetpoint
from companion.logs.flightlog import CycleRecord, FlightLogWriter
from companion.logs.mcap_log import ArmGeometry, FlightLogWithMcap, McapLogWriter

GEOMETRY = ArmGeometry((0.0, 0.0, -0.08), 0.2, 0.2)
PERIOD_S = 0.004
"""A 250 Hz control loop's period [s]."""


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


def measure(writer, rows: list[CycleRecord]) -> np.ndarray:
    """Microseconds of each ``writer.write`` call."""
    durations = np.empty(len(rows))
    writer.open()
    try:
        for k, record in enumerate(rows):
            t0 = time.perf_counter_ns()
            writer.write(record)
            durations[k] = (time.perf_counter_ns() - t0) * 1e-3
    finally:
        writer.close()
    return durations


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cycles", type=int, default=10_000, help="cycles per writer")
    args = parser.parse_args()
    rows = records(args.cycles)
    print(f"{args.cycles} cycles per writer (a 250 Hz loop: {args.cycles * PERIOD_S:g} s)")
    print(f"{'writer':<12} {'median':>9} {'p99':>9} {'max':>9}   files")
    medians = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("csv", "mcap", "csv + mcap"):
            folder = Path(tmp) / name.replace(" + ", "_")
            folder.mkdir()
            log = folder / "flight.csv"
            if name == "csv":
                writer = FlightLogWriter(log)
            elif name == "mcap":
                writer = McapLogWriter(folder / "flight.mcap", GEOMETRY)
            else:
                writer = FlightLogWithMcap(log, GEOMETRY)
            us = measure(writer, rows)
            medians[name] = float(np.median(us))
            sizes = ", ".join(
                f"{p.name} {p.stat().st_size / 1e6:.2f} MB" for p in sorted(folder.iterdir())
            )
            print(
                f"{name:<12} {np.median(us):>7.1f}us {np.percentile(us, 99):>7.1f}us "
                f"{us.max():>7.1f}us   {sizes}"
            )
    extra = medians["csv + mcap"] - medians["csv"]
    print(
        f"the MCAP adds {extra:.1f} us per cycle (median), "
        f"{100 * extra * 1e-6 / PERIOD_S:.1f} % of a 250 Hz cycle"
    )


if __name__ == "__main__":
    main()

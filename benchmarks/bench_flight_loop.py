"""Latency and CPU cost of the companion's flight loop at 250 Hz, against the SITL.

Runs ``companion demo`` (the SITL vehicle process and the pickup mission, speed 1) into a
temporary directory and prints, from its summary.json:

- pose taken from the MAVLink link -> SET_ATTITUDE_TARGET sent (includes the joints' Sync
  Read over the pty, which comes first in the cycle): median and p99 [us];
- pose -> joint torques written (the whole cycle): median and p99 [us];
- CPU share of one core of the companion process over the OFFBOARD part;
- control cycles run.

The SITL process runs on the same two cores, so these are upper bounds for a dedicated
onboard computer. Usage: ``python benchmarks/bench_flight_loop.py``
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "demo"
        result = subprocess.run(
            [sys.executable, "-c", "from companion.cli import main; main()", "demo",
             "--out", str(out)],
            capture_output=True, text=True, timeout=900,
        )  # fmt: skip
        if not (out / "summary.json").exists():
            print(result.stdout, result.stderr)
            raise SystemExit("the demo wrote no summary")
        summary = json.loads((out / "summary.json").read_text())
    print(result.stdout.strip())
    print()
    print(f"{'measure':<48} {'median us':>10} {'p99 us':>10}")
    for key, label in (
        ("setpoint_latency_us", "pose received -> setpoint sent"),
        ("cycle_latency_us", "pose received -> joint torques written"),
    ):
        stats = summary.get(key) or {}
        print(f"{label:<48} {stats.get('median', float('nan')):10.0f} "
              f"{stats.get('p99', float('nan')):10.0f}")  # fmt: skip
    share = summary.get("cpu_share_of_one_core")
    print(f"CPU share of one core (companion, OFFBOARD part): {share:.2f}" if share else "")
    print(f"control cycles: {summary['control_cycles']}; mission completed: {summary['completed']}")


if __name__ == "__main__":
    main()

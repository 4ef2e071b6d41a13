"""The flight loop on a busy computer: the demo flown with N CPU-bound processes beside it.

For each N in ``--busy`` (default 0, 1, 2) starts N processes that spin on the CPU (plain
Python loops, as a user's other work would), flies ``sitl demo`` (the SITL vehicle process
and the pickup mission, speed 1, imitation unless ``--autopilot px4``) into a temporary
directory, stops the busy processes and prints, from the demo's summary.json:

- whether the mission completed, and its faults;
- late cycles (control cycles later than 2.5 periods in vehicle time: the SITL's stream or
  the companion) and poses dropped (the loop's queue of 4 overflowed: the loop too slow, or
  poses delivered together after the process did not run), the longest period [ms];
- pose taken from the MAVLink link -> SET_ATTITUDE_TARGET sent, and -> joint torques written
  (the whole cycle): median and p99 [us]; the control thread's CPU time from the pose to
  the setpoint, median and p99 [us] (the rest of the latency it waited for a core);
- the companion's CPU share of one core over the OFFBOARD part;
- estimator steps skipped because no new joint read had come back by the pose;
- who held up the late cycles and dropped poses (the summary's ``*_by_cause``: companion,
  host, blocked, arrival; ``companion/mission/loop_period.py`` ``GapCause``), as late/dropped.

The SITL runs on the same cores, so these are upper bounds for a dedicated onboard
computer. Numbers only, no pass/fail. The load average before each flight is printed.
The companion gives its control thread SCHED_FIFO for the mission where it may
(``flight.realtime_priority``, 50 by default; root here): ``--priority P`` flies the demo
with that key set to P, ``--priority 0`` under normal scheduling; the table's ``sched``
column says what the flight had. ``--fifo P`` runs the whole demo, the SITL vehicle too,
under ``chrt --fifo P``; ``--repeat K`` flies K times per N.
Usage: ``python benchmarks/bench_flight_loop.py [--busy 0,1,2] [--autopilot imitation]
[--priority 50] [--fifo 50] [--repeat 1]``
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import tomlkit

from sitl.demo_command import DEFAULT_SCENARIO

SPIN = "while True:\n    pass\n"


def scenario_with_priority(priority: int, tmp: Path) -> Path:
    """The demo's scenario with ``flight.realtime_priority`` set, written into ``tmp``."""
    doc = tomlkit.parse(DEFAULT_SCENARIO.read_text())
    doc["flight"]["realtime_priority"] = priority  # type: ignore[index]
    path = tmp / f"scenario-priority-{priority}.toml"
    path.write_text(tomlkit.dumps(doc))
    return path


def fly(
    busy: int, autopilot: str, tmp: Path, fifo_priority: int | None, scenario: Path
) -> tuple[dict | None, str, list[str]]:
    """The demo with ``busy`` spinning processes; (summary or None, the demo's output, its
    notes on late cycles and dropped poses)."""
    spinners = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(busy)]
    prefix = [] if fifo_priority is None else ["chrt", "--fifo", str(fifo_priority)]
    try:
        out = Path(tempfile.mkdtemp(prefix=f"busy{busy}-", dir=tmp)) / "demo"
        result = subprocess.run(
            [*prefix, sys.executable, "-c", "from sitl.cli import main; main()", "demo",
             "--out", str(out), "--autopilot", autopilot, "--config", str(scenario)],
            capture_output=True, text=True, timeout=900,
        )  # fmt: skip
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()
    summary_path = out / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else None
    return summary, result.stdout + result.stderr, gap_notes(out / "flight.events.csv")


def gap_notes(events: Path) -> list[str]:
    """The flight's notes on late cycles and dropped poses, with their causes' figures."""
    if not events.exists():
        return []
    with events.open(newline="") as f:
        return [
            f"t {e['t_vehicle_s']} s: {e['detail']}"
            for e in csv.DictReader(f)
            if e["kind"] == "loop"
            and ("late cycle" in e["detail"] or "dropped pose" in e["detail"])
        ]


def row(busy: int, summary: dict) -> str:
    def pct(key: str, which: str) -> float:
        return (summary.get(key) or {}).get(which, float("nan"))

    faults = ",".join(f["fault"] for f in summary["faults"]) or "-"
    share = summary.get("cpu_share_of_one_core") or float("nan")
    no_read = (summary.get("estimator_skipped_by_reason") or {}).get("no_servo_read", 0)
    late_by, dropped_by = (
        summary.get(f"{k}_by_cause") or {} for k in ("late_cycles", "poses_dropped")
    )
    causes = " ".join(
        f"{cause} {late_by.get(cause, 0)}/{dropped_by.get(cause, 0)}"
        for cause in sorted(set(late_by) | set(dropped_by))
    )
    return (
        f"{busy:>4} {'yes' if summary['completed'] else 'NO':>9} {faults:<14} "
        f"{summary['late_cycles']:>6} {summary['poses_dropped']:>7} "
        f"{summary.get('longest_period_ms') or float('nan'):>8.1f} "
        f"{pct('setpoint_latency_us', 'median'):>8.0f} {pct('setpoint_latency_us', 'p99'):>8.0f} "
        f"{pct('cycle_latency_us', 'median'):>8.0f} {pct('cycle_latency_us', 'p99'):>8.0f} "
        f"{pct('setpoint_cpu_us', 'median'):>8.0f} {pct('setpoint_cpu_us', 'p99'):>8.0f} "
        f"{share:>5.2f} {no_read:>7} {summary.get('scheduling') or '?':>13} {causes or '-'}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--busy", default="0,1,2", help="numbers of busy processes")
    parser.add_argument("--autopilot", default="imitation", choices=("imitation", "px4"))
    parser.add_argument(
        "--fifo",
        type=int,
        default=None,
        metavar="PRIORITY",
        help="run the demo (companion and SITL) under chrt --fifo PRIORITY (needs the "
        "privilege to set real-time priorities)",
    )
    parser.add_argument(
        "--priority",
        type=int,
        default=None,
        help="the companion's flight.realtime_priority (default: the scenario's; 0: normal "
        "scheduling)",
    )
    parser.add_argument("--repeat", type=int, default=1, help="flights per number of busy")
    args = parser.parse_args()
    counts = [int(n) for n in args.busy.split(",")]
    policy = "" if args.fifo is None else f", the demo under chrt --fifo {args.fifo}"
    print(f"{os.cpu_count()} cores; sitl demo --autopilot {args.autopilot}, speed 1{policy}")
    print(
        f"{'busy':>4} {'completed':>9} {'faults':<14} {'late':>6} {'dropped':>7} "
        f"{'max ms':>8} {'set p50':>8} {'set p99':>8} {'cyc p50':>8} {'cyc p99':>8} "
        f"{'cpu p50':>8} {'cpu p99':>8} {'cpu':>5} {'no read':>7} {'sched':>13} cause late/dropped"
    )
    with tempfile.TemporaryDirectory() as tmp:
        scenario = DEFAULT_SCENARIO
        if args.priority is not None:
            scenario = scenario_with_priority(args.priority, Path(tmp))
        for busy in (n for n in counts for _ in range(args.repeat)):
            load = os.getloadavg()[0]
            summary, output, notes = fly(busy, args.autopilot, Path(tmp), args.fifo, scenario)
            if summary is None:
                print(f"{busy:>4} the demo wrote no summary (load {load:.1f}):\n{output[-2000:]}")
                continue
            print(f"{row(busy, summary)}   (load before {load:.1f})")
            for note in notes:
                print(f"       {note}")
    print(
        "latencies in us: set = pose -> setpoint sent, cyc = pose -> joint torques written, "
        "cpu p50/p99 = the control thread's CPU time over set; cpu = share of one core; "
        "no read = estimator steps skipped for want of a new joint read (the arm task's Sync "
        "Read not back by the next pose); sched = the control thread's scheduling; cause = "
        "who held up the late cycles / dropped poses, the largest share of the control "
        "thread's last two cycles if it reaches a period (companion: it ran; host: it "
        "waited for a CPU; blocked: datagrams waited in its socket beyond both; arrival: "
        "none reached a period)"
    )


if __name__ == "__main__":
    main()
